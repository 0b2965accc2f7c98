"""The exact references moved to fem_impact.references (they are not configuration); this name stays for
the code that imports them from here."""

from ..references import (B1, B2, ERROR_MEASURES, REFERENCES, BarMode, Reference, RunReference,  # noqa: F401
                          column, contact_spells, energy_growth, errors, from_case)
