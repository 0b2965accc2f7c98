"""Contact laws: what a contact adds to the one-step contact problem on its rows.

A law is chosen per contact of the case file (``law:``; by default ``newton`` for a rigid contact,
``elastic_stop`` when the contact gives a ``stiffness``). Each law declares its own keys (a
pydantic model: the case file validates a contact's law keys against it, so a key lives with
its law) and says, per row:

- its Newton restitution coefficient ``e`` (the velocity target ``-e`` times the approach speed:
  the schemes' impact law, Carnot's correction at the position level; docs/theory.md s. 3.3, 4);
- its compliance ``c`` (m/N): a massless spring in series with the row, which shifts the
  one-step problem's diagonal and makes the gap condition ``d0 - P U + c lam >= 0``; 0 on a rigid
  row (s. 2.2);
- what it stores: ``1/2 c lam^2`` per row, strain energy of the budget (s. 9).

A new law is a subclass and a :func:`register` call; the integrators read the rows' data, not
the law's kind.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class LawKeys(BaseModel):
    """Keys of a contact law in the case file (none by default)."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)


class ContactLaw:
    """A contact law on the rows of one contact (subclass it and :func:`register` it)."""

    name: ClassVar[str] = ""
    keys: ClassVar[type[LawKeys]] = LawKeys
    summary: ClassVar[str] = ""

    def __init__(self, params: LawKeys | None = None):
        self.params = params if params is not None else self.keys()

    def restitution(self) -> float:
        """Newton's coefficient on the rows (0: plastic)."""
        return 0.0

    def compliance(self) -> float:
        """Compliance of the rows (m/N), 0 when rigid."""
        return 0.0

    def rows(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(restitution, compliance) for ``n`` rows."""
        return np.full(n, self.restitution()), np.full(n, self.compliance())


class NewtonKeys(LawKeys):
    restitution: float = Field(0.0, ge=0.0, le=1.0, description="Newton's coefficient e in [0, 1] at the node")


class Newton(ContactLaw):
    """A rigid unilateral contact with Newton's impact law (restitution e)."""

    name = "newton"
    keys = NewtonKeys
    summary = "rigid contact, Newton's impact law: the normal velocity after an impact is -e times before"

    def restitution(self) -> float:
        return self.params.restitution


class ElasticStopKeys(LawKeys):
    stiffness: float = Field(gt=0.0, description="spring stiffness in series with each row (N/m)",
                             json_schema_extra={"unit": "N/m"})


class ElasticStop(ContactLaw):
    """A massless spring in series with each row: ``n . u - F_N / k <= gap``."""

    name = "elastic_stop"
    keys = ElasticStopKeys
    summary = "an elastic stop: a massless spring of stiffness k in series with each row"

    def compliance(self) -> float:
        return 1.0 / self.params.stiffness


LAWS: dict[str, type[ContactLaw]] = {}


def register(law: type[ContactLaw]) -> type[ContactLaw]:
    """Make ``law`` a choice of the case file's ``contacts[i].law`` (usable as a class decorator)."""
    if not law.name:
        raise ValueError(f"{law.__name__} has no name")
    LAWS[law.name] = law
    return law


def unregister(name: str) -> None:
    """Remove a law registered by :func:`register` (a test's, a plugin's)."""
    del LAWS[name]


register(Newton)
register(ElasticStop)
