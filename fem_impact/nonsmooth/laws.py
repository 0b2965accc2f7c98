"""Contact laws as data: what a contact adds to the one-step problem on its rows, and to the budget.

A law is chosen per contact of the case file (``law:``; by default ``newton`` for a rigid contact,
``elastic_stop`` when the contact gives a ``stiffness``). Each law declares its own keys (a
pydantic model: the case file validates a contact's law keys against it, so a key lives with its
law) and two hooks (docs/theory.md s. 2.2, 2.5):

- ``one_step(h)``: its terms of the one-step problem over a step of length ``h`` (``LawTerms``):
  Newton's restitution ``e`` (the velocity target of a rigid row), a compliance ``c`` on the
  diagonal (the row's gap condition ``g + c lam >= 0``), and a memory ``m`` of the penetration at
  the step's start (``g + c lam + m max(-g0, 0) >= 0``, a damper's);
- ``stored(force, gap)``: the energy its rows store at a step; the rest of the work the contact
  forces do on its rows is booked as lost, in the column the law declares (``column``).

Coulomb's friction is a law of the tangent rows (``Coulomb``: mu), beside the normal law.
A new law is a subclass and a :func:`register` call; the integrators read the rows' terms
(``RowLaws``), never the law's kind.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

CONTACT_LOSS = "contact_loss"   # the budget's column of the contact forces' work (EnergyBudget.contact_loss)


class LawKeys(BaseModel):
    """Keys of a contact law in the case file (none by default)."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)


@dataclass(frozen=True)
class LawTerms:
    """A law's terms of the one-step problem on each of its rows, for one step length."""

    restitution: float = 0.0   # Newton's e on a rigid row (0: plastic)
    compliance: float = 0.0    # c (m/N): added to the row's diagonal; 0 on a rigid row
    memory: float = 0.0        # m: the gap condition gains m times the penetration at the step's start


class ContactLaw:
    """A contact law on the rows of one contact (subclass it and :func:`register` it)."""

    name: ClassVar[str] = ""
    keys: ClassVar[type[LawKeys]] = LawKeys
    summary: ClassVar[str] = ""
    column: ClassVar[str] = CONTACT_LOSS   # where the work its rows absorb, less what they store, is booked

    def __init__(self, params: LawKeys | None = None):
        self.params = params if params is not None else self.keys()

    def restitution(self) -> float:
        """Newton's coefficient on the rows (0: plastic)."""
        return 0.0

    def compliance(self) -> float:
        """Compliance of the rows (m/N) with the step's own response left out, 0 when rigid."""
        return 0.0

    def one_step(self, h: float) -> LawTerms:
        """The law's terms of the one-step problem over a step ``h`` (the hook a new law overrides)."""
        return LawTerms(self.restitution(), self.compliance())

    def stored(self, force: np.ndarray, gap: np.ndarray) -> np.ndarray:
        """Energy each row stores at a step, from its force and its gap ``d0 - P U`` there."""
        return 0.5 * self.compliance() * force * force

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


@dataclass(frozen=True)
class Coulomb:
    """Coulomb's friction on the tangent rows of a contact: ``|r_T| <= mu r_N`` (docs/theory.md s. 11)."""

    mu: float = 0.0


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


def law_of(name: str, keys: dict) -> ContactLaw:
    """The registered law ``name`` with its keys (as the case file validated them)."""
    law = LAWS[name]
    return law(law.keys(**keys))


register(Newton)
register(ElasticStop)


class _Given(ContactLaw):
    """Rows given by their restitution and compliance alone (an ``Operators`` built from arrays)."""

    def __init__(self, e: float, c: float):
        super().__init__()
        self._e, self._c = e, c

    def restitution(self) -> float:
        return self._e

    def compliance(self) -> float:
        return self._c


class RowLaws:
    """The laws of a system's contact rows, row by row: the one-step terms and the energy booking
    the integrators read (``groups``: (law, row indices), each row in one group; ``friction``: mu
    per row, from the Coulomb laws ``cones`` of the tangent rows, 0 without)."""

    def __init__(self, groups: list[tuple[ContactLaw, np.ndarray]], p: int, friction: np.ndarray | None = None,
                 cones: list[tuple[Coulomb, np.ndarray]] = ()):
        self.groups = [(law, np.asarray(rows, dtype=np.int64)) for law, rows in groups]
        self.p = p
        self.friction = np.zeros(p) if friction is None else np.asarray(friction, dtype=float)
        for cone, rows in cones:
            self.friction[rows] = cone.mu
        self.restitution = self._per_row(lambda law: law.restitution())
        self.compliance = self._per_row(lambda law: law.compliance())   # the laws' own, without a step
        self.columns = list(dict.fromkeys(law.column for law, rows in self.groups if rows.size))
        # (the laws that keep the contact loss and store 1/2 c F^2: booked as one product over the rows)
        self._plain = all(law.column == CONTACT_LOSS and type(law).stored is ContactLaw.stored
                          for law, _ in self.groups)
        self._terms: dict[float, tuple] = {}

    @classmethod
    def from_arrays(cls, restitution: np.ndarray, compliance: np.ndarray | None = None,
                    friction: np.ndarray | None = None) -> RowLaws:
        """Row laws from per-row restitution and compliance (a row law per distinct pair)."""
        e = np.asarray(restitution, dtype=float)
        c = np.zeros(e.size) if compliance is None else np.asarray(compliance, dtype=float)
        pairs: dict[tuple[float, float], list[int]] = {}
        for i, pair in enumerate(zip(e.tolist(), c.tolist())):
            pairs.setdefault(pair, []).append(i)
        return cls([(_Given(*pair), np.array(rows)) for pair, rows in pairs.items()], e.size, friction)

    def _per_row(self, value) -> np.ndarray:
        out = np.zeros(self.p)
        for law, rows in self.groups:
            out[rows] = value(law)
        return out

    @property
    def plain(self) -> bool:
        """Every law keeps the contact loss and stores ``1/2 c F^2`` (an elastic stop's spring, or nothing)."""
        return self._plain

    def terms(self, h: float) -> tuple[np.ndarray, np.ndarray]:
        """(compliance, memory) per row of the one-step problem over a step ``h``."""
        if h not in self._terms:
            c, m = np.zeros(self.p), np.zeros(self.p)
            for law, rows in self.groups:
                t = law.one_step(h)
                c[rows], m[rows] = t.compliance, t.memory
            self._terms[h] = (c, m if np.count_nonzero(m) else None)
        return self._terms[h]

    def elastic(self, h: float) -> np.ndarray:
        """Rows with a compliance over a step ``h``: no impact law, their gap at the step's end."""
        return self.terms(h)[0] > 0.0

    def has_memory(self, h: float) -> bool:
        return self.terms(h)[1] is not None

    def memory(self, h: float, gap0: np.ndarray) -> np.ndarray | None:
        """What the gap condition of each row gains from the penetration at the step's start, or None."""
        m = self.terms(h)[1]
        return None if m is None else m * np.maximum(-gap0, 0.0)

    def stores(self, h: float) -> bool:
        """Whether any row stores energy (an elastic row): else booking ``stored`` can be skipped."""
        return bool(np.count_nonzero(self.terms(h)[0])) or not self._plain

    def stored(self, force: np.ndarray, gap: np.ndarray) -> dict[str, float]:
        """Energy the rows store at a step, per loss column of their laws."""
        if self._plain:   # (one product, as 1/2 c . F^2)
            return {CONTACT_LOSS: 0.5 * float(self.compliance @ (force * force))}
        out = dict.fromkeys(self.columns, 0.0)
        for law, rows in self.groups:
            if rows.size:
                out[law.column] += float(np.sum(law.stored(force[rows], gap[rows])))
        return out

    def work(self, force: np.ndarray, motion: np.ndarray, total: float | None = None) -> dict[str, float]:
        """The contact forces' work over a step, ``force . motion``, per loss column (``total``: the
        whole, when the step has it already)."""
        if len(self.columns) <= 1:
            return {self.columns[0] if self.columns else CONTACT_LOSS:
                    float(force.dot(motion)) if total is None else total}
        out = dict.fromkeys(self.columns, 0.0)
        for law, rows in self.groups:
            if rows.size:
                out[law.column] += float(force[rows].dot(motion[rows]))
        return out

    def extra_columns(self) -> list[str]:
        """The loss columns the laws declare beyond the budget's own contact loss."""
        return [c for c in self.columns if c != CONTACT_LOSS]
