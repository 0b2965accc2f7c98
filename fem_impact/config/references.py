"""The exact references moved to fem_impact.references (they are not configuration); this name stays
for the code that imports them from here."""

from ..references import *  # noqa: F401,F403
from ..references import (ERROR_MEASURES, REFERENCES, B1, B2, BarMode, Reference, RunReference,  # noqa: F401
                          column, contact_spells, energy_growth, errors, from_case)
