"""Exact solutions by name (the ``reference:`` key of a case file) and the error measures of a run
against them, or against another run (the finest level of a study).

Known references (docs/benchmarks.md), each on the built-in bar (``mesh.shape: bar``; 1D, or a 2D
strip or 3D box with ``nu = 0``, which behave as the rod), one material, no damping, no loads:

- ``b1``: the Dirichlet-Signorini bar. Clamped at one end, an obstacle with gap 0 at the other,
  released at rest from ``w0(s) = a (1 - s/L)`` (``s`` the distance from the obstacle end, ``w``
  the distance from the obstacle, ``a > 0``). The exact solution is d'Alembert's,
  ``w = F(S - T) + G(S + T)`` with ``S = s/L``, ``T = c t/L``, piecewise linear and periodic with
  period 3: the end falls at speed ``a c/L`` for ``L/c``, rests on the obstacle with the force
  ``E A a/L`` for ``L/c``, rises for ``L/c``. Energy ``E A a^2 / (2 L)``.
- ``b2``: a free bar moving at ``v0`` toward a rigid wall at gap ``g0`` from its end. With ``w``
  the displacement toward the wall, ``w(s, t) = min(v0 t, g0 + v0 s/c, 2 g0 + 2 v0 L/c - v0 t)``
  (a compression wave from the wall, its reflection from the free end, rigid flight away):
  contact on ``[g0/v0, g0/v0 + 2L/c]`` with the force ``rho c A v0``, total impulse
  ``2 rho A L v0``, energy ``rho A L v0^2 / 2`` whatever the restitution at the node.
- ``bar_mode``: free vibration without contact, released at rest in one of the bar's modes:
  ``u(x, t) = u0(x) cos(w t)``; free-free ``cos(k pi x/L)``, ``w = k pi c/L``; clamped at one end
  ``cos((2k - 1) pi s/(2L))`` (``s`` from the free end), ``w = (2k - 1) pi c/(2L)``; clamped at
  both ends ``sin(k pi x/L)``, ``w = k pi c/L``. Energy ``rho A w^2 a^2 L / 4``.

Each reads its parameters from the case (length, E, rho, section, initial fields, gap) and refuses
a case it does not fit with a CaseError on the key ``reference``: the one definition of what fits,
for the case files (fem_impact.case) and the studies. Units are those of the case.

Error measures (``errors``), all relative and dimensionless:

- ``err_displacement``: RMS over time of the error of each probe's x displacement, relative to
  the displacement scale (B2: ``v0 L/c``, B1: ``a``, bar_mode: ``a``; a run: its largest probe
  displacement); the largest over the probes;
- ``err_impulse``: total contact impulse, relative to the exact one;
- ``err_force``: mean contact force over the contact phases, relative to the force scale
  (B2: ``rho c A v0``, B1: ``E A a/L``);
- ``force_oscillation``: RMS deviation of the contact force from the reference over the contact
  phases, relative to the force scale (ringing, or the step-to-step oscillation of
  position-level multipliers);
- ``err_energy``: largest deviation of kinetic + strain energy from the reference's, relative to
  the energy scale (initial energy + largest external work); with ``e = 0`` it is the impact loss;
- ``energy_growth``: largest ``E(t) - E(0) - W_ext(t)``, relative to the energy scale (energy the
  scheme created; physically never positive), from the run alone.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .errors import CaseError

if TYPE_CHECKING:   # the case format validates the names of the references against this module: no import back
    from .config.case import Case

ERROR_MEASURES = ("err_displacement", "err_impulse", "err_force", "force_oscillation", "err_energy")


# --- the references ------------------------------------------------------------------------


class Reference:
    """What a run is compared with: exact functions of time, or another run's history.

    Attributes: ``label`` (for CSV and plots), ``probes`` (name -> x coordinate, the probes it
    can evaluate), ``contacts`` (contact names whose force and impulse it gives),
    ``length_scale``, ``force_scale`` (None without contact), ``energy_scale``, ``t_max``.
    """

    label = "reference"
    probes: dict[str, float]
    contacts: list[str]
    length_scale: float
    force_scale: float | None
    energy_scale: float
    t_max = math.inf

    def displacement(self, probe: str, t: np.ndarray) -> np.ndarray:
        """x displacement of a probe at the times ``t``."""
        raise NotImplementedError

    def force(self, t: np.ndarray) -> np.ndarray:
        """Sum of the normal contact forces over ``contacts`` at the times ``t``."""
        return np.zeros_like(np.asarray(t, dtype=float))

    def impulse_total(self, t_end: float) -> float:
        """Total contact impulse over ``[0, t_end]``."""
        return 0.0

    def energy(self, t: np.ndarray) -> np.ndarray:
        """Kinetic + strain energy at the times ``t``."""
        raise NotImplementedError

    def phases(self, t_end: float) -> list[tuple[float, float]]:
        """Contact phases ``(start, end)`` within ``[0, t_end]``."""
        return []


@dataclass
class _Bar:
    """What the bar references share, read from the case."""

    length: float
    E: float
    rho: float
    section: float
    probes: dict[str, float]

    @property
    def c(self) -> float:
        return math.sqrt(self.E / self.rho)


def _holds_x(support) -> bool:
    """Whether a support holds the x component (``fix: all`` holds every one)."""
    return support.all_components or 0 in support.fix


def _refuse(case: Case, message: str) -> CaseError:
    return case.error(("reference",), f"{case.reference}: {message}")


def _bar(case: Case) -> _Bar:
    """The checks every bar reference makes; returns the bar's data."""
    mesh = case.mesh
    if mesh.shape != "bar":
        raise _refuse(case, "needs the built-in bar (mesh.shape: bar), not a mesh file")
    if case.material is None:
        raise _refuse(case, "needs one material for the whole bar ('material', not 'materials')")
    mat = case.material
    dim = mesh.bar_dim
    if dim > 1 and mat.nu != 0.0:
        raise _refuse(case, f"in {dim}D the strip or box behaves as the rod only with nu = 0, got nu = {mat.nu:g}")
    if case.damping.alpha or case.damping.beta:
        raise _refuse(case, "has no damping: set damping.alpha and damping.beta to 0")
    if case.loads:
        raise _refuse(case, "has no loads: remove 'loads'")
    if any(model == "rigid" for model in case.bodies.values()):
        raise _refuse(case, "is the elastic bar: remove 'bodies' (or make it elastic)")
    if any(c.motion is not None for c in case.contacts):
        raise _refuse(case, "has fixed obstacles: remove the contacts' 'motion'")
    height, width = mesh.bar_dimensions()
    section = {1: mat.area, 2: height * mat.area, 3: height * width}[dim]
    if dim == 2 and mesh.hypothesis == "axisymmetric":   # the strip turned about x: a cylinder of radius height
        if mesh.axis != "x":
            raise _refuse(case, "an axisymmetric bar is the cylinder about its own axis: mesh.axis: x")
        section = np.pi * height**2
    probes = {name: float(point[0]) for name, point in case.output.probes.items()}
    return _Bar(mesh.length, mat.E, mat.rho, section, probes)


def _initial(case: Case, which: str, x: np.ndarray) -> np.ndarray:
    """The x component of an initial field along the bar's axis (y = z = 0); other components must vanish."""
    entries = getattr(case.initial, which)
    out = np.zeros_like(x)
    for entry in entries:
        if entry.body not in (None, "bar"):
            raise _refuse(case, f"initial.{which}: give one field for the bar, not per body")
        for comp, expr in enumerate(entry.value):
            try:
                value = expr.evaluate(x=x, y=0.0 * x, z=0.0 * x, shape=x.shape)
            except ValueError as err:
                raise _refuse(case, f"initial.{which}: {err}") from None
            if comp == 0:
                out = value
            elif np.any(value != 0.0):
                raise _refuse(case, f"initial.{which}: only an axial (x) field fits, component {comp} is not 0")
    return out


def _end_contact(case: Case, contact, what: str) -> float:
    """The x component (+1 or -1) of an obstacle contact's normal at an end node group."""
    if contact.type != "obstacle" or contact.nodes[0] not in ("left", "right"):
        raise _refuse(case, f"{what} must be an obstacle contact on the node group left or right")
    if contact.gap is None:
        raise _refuse(case, f"{what} must give its gap (not a point of the obstacle's plane)")
    normal = np.asarray(contact.normal)
    outward = -1.0 if contact.nodes[0] == "left" else 1.0
    if abs(normal[0] - outward) > 1e-12 or np.any(normal[1:] != 0.0):
        raise _refuse(case, f"{what}: the normal at {contact.nodes[0]} must be [{outward:+g}] "
                            f"(the end approaches the obstacle along the axis)")
    return outward


class B2(Reference):
    """A free bar moving toward a rigid wall (docs/benchmarks.md B2)."""

    title = "free bar hitting a rigid wall"

    def __init__(self, case: Case):
        bar = _bar(case)
        if case.supports:
            raise _refuse(case, "is a free bar: remove 'supports'")
        if len(case.contacts) != 1:
            raise _refuse(case, f"needs exactly one contact (the wall), the case has {len(case.contacts)}")
        contact = case.contacts[0]
        self.n = _end_contact(case, contact, f"contact '{contact.name}'")
        x = np.linspace(0.0, bar.length, 21)
        if np.any(_initial(case, "displacement", x) != 0.0):
            raise _refuse(case, "starts undeformed: initial.displacement must be 0")
        v = _initial(case, "velocity", x)
        if np.ptp(v) > 1e-12 * np.abs(v).max() or v[0] * self.n <= 0.0:
            raise _refuse(case, f"needs one constant initial velocity toward the wall (x component of sign "
                                f"{self.n:+g}), got {v[0]:g}" + (" varying along the bar" if np.ptp(v) else ""))
        if contact.gap < 0.0:
            raise _refuse(case, f"needs a gap >= 0, got {contact.gap:g}")
        self.bar, self.v0, self.g0, self.contacts = bar, abs(float(v[0])), contact.gap, [contact.name]
        self.left = contact.nodes[0] == "left"
        self.probes = bar.probes
        L, c, rho, A = bar.length, bar.c, bar.rho, bar.section
        self.t0, self.duration, self.F = self.g0 / self.v0, 2.0 * L / c, rho * c * A * self.v0
        self.length_scale, self.force_scale = self.v0 * L / c, self.F
        self.energy_scale = 0.5 * rho * A * L * self.v0 ** 2
        self.label = (f"exact b2 (v0 = {self.v0:g}, gap {self.g0:g}, contact on [{self.t0:.6g}, "
                      f"{self.t0 + self.duration:.6g}], force {self.F:.6g})")

    def w(self, s: float, t: np.ndarray) -> np.ndarray:
        """Displacement toward the wall of the section at distance ``s`` from the contact end."""
        t = np.asarray(t, dtype=float)
        v0, g0, c, L = self.v0, self.g0, self.bar.c, self.bar.length
        return np.minimum(np.minimum(v0 * t, g0 + v0 * s / c), 2 * g0 + 2 * v0 * L / c - v0 * t)

    def displacement(self, probe, t):
        x = self.probes[probe]
        return self.n * self.w(x if self.left else self.bar.length - x, t)

    def force(self, t):
        t = np.asarray(t, dtype=float)
        return np.where((t > self.t0) & (t < self.t0 + self.duration), self.F, 0.0)

    def impulse_total(self, t_end):
        return self.F * min(max(t_end - self.t0, 0.0), self.duration)

    def energy(self, t):
        return np.full(np.shape(t), self.energy_scale)

    def phases(self, t_end):
        return [(self.t0, min(self.t0 + self.duration, t_end))] if t_end > self.t0 else []


# d'Alembert's functions of B1 for a = 1 on one period (S, T nondimensional: x/L, c t/L), from
# w(0, t) free for T in [0, 1], w(0, t) = 0 for T in [1, 2], free again for T in [2, 3], and
# w(1, t) = 0 (clamp): F on [-3, 1], G on [0, 4] (the derivation in the module docstring's terms:
# initial data give F = G = (1 - S)/2 on [0, 1]; each boundary condition extends one of them).
_B1_F = (np.array([-3.0, -1.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.5, 0.0]))
_B1_G = (np.array([0.0, 2.0, 3.0, 4.0]), np.array([0.5, -0.5, 0.0, -0.5]))


class B1(Reference):
    """A bar clamped at one end, released against an obstacle at the other (docs/benchmarks.md B1)."""

    title = "clamped bar released against an obstacle"

    def __init__(self, case: Case):
        bar = _bar(case)
        if len(case.contacts) != 1:
            raise _refuse(case, f"needs exactly one contact (the obstacle), the case has {len(case.contacts)}")
        contact = case.contacts[0]
        self.n = _end_contact(case, contact, f"contact '{contact.name}'")
        clamp = "right" if contact.nodes[0] == "left" else "left"
        if len(case.supports) != 1 or case.supports[0].nodes != clamp or not _holds_x(case.supports[0]):
            raise _refuse(case, f"needs one support holding x at the other end ({clamp})")
        if contact.gap != 0.0:
            raise _refuse(case, f"needs the obstacle at gap 0, got {contact.gap:g}")
        L = bar.length
        x = np.linspace(0.0, L, 21)
        if np.any(_initial(case, "velocity", x) != 0.0):
            raise _refuse(case, "starts at rest: initial.velocity must be 0")
        self.left = contact.nodes[0] == "left"
        s = x if self.left else L - x
        w0 = -self.n * _initial(case, "displacement", x)   # distance from the obstacle
        a = float(w0[np.argmin(s)])
        if a <= 0.0 or np.abs(w0 - a * (1.0 - s / L)).max() > 1e-9 * a:
            raise _refuse(case, f"needs the initial displacement a (1 - s/L) away from the obstacle (s from the "
                                f"obstacle end, a > 0), e.g. \"{'(1 - x)/2' if self.left else 'x/2'}\" for L = 1")
        self.bar, self.a, self.contacts, self.probes = bar, a, [contact.name], bar.probes
        self.F = bar.E * bar.section * a / L
        self.length_scale, self.force_scale = a, self.F
        self.energy_scale = bar.E * bar.section * a * a / (2.0 * L)
        self.label = f"exact b1 (a = {a:g}, period {3 * L / bar.c:.6g}, contact force {self.F:.6g})"

    def w(self, s: float, t: np.ndarray) -> np.ndarray:
        """Distance from the obstacle of the section at distance ``s`` from the obstacle end."""
        L = self.bar.length
        tau = np.mod(np.asarray(t, dtype=float) * self.bar.c / L, 3.0)
        S = s / L
        return self.a * (np.interp(S - tau, *_B1_F) + np.interp(S + tau, *_B1_G))

    def displacement(self, probe, t):
        x = self.probes[probe]
        return -self.n * self.w(x if self.left else self.bar.length - x, t)

    def _tau(self, t):
        return np.mod(np.asarray(t, dtype=float) * self.bar.c / self.bar.length, 3.0)

    def force(self, t):
        tau = self._tau(t)
        return np.where((tau > 1.0) & (tau < 2.0), self.F, 0.0)

    def phases(self, t_end):
        unit = self.bar.length / self.bar.c
        return [((3 * k + 1) * unit, min((3 * k + 2) * unit, t_end))
                for k in range(int(t_end / (3 * unit)) + 1) if (3 * k + 1) * unit < t_end]

    def impulse_total(self, t_end):
        return self.F * sum(b - a for a, b in self.phases(t_end))

    def energy(self, t):
        return np.full(np.shape(t), self.energy_scale)


class BarMode(Reference):
    """Free vibration of a bar released at rest in one of its modes, without contact."""

    title = "free vibration of a bar in one of its modes"

    def __init__(self, case: Case):
        bar = _bar(case)
        if case.contacts:
            raise _refuse(case, "is free vibration without contact: remove 'contacts'")
        L = bar.length
        ends = {s.nodes for s in case.supports if _holds_x(s)}
        if len(case.supports) != len(ends) or not ends <= {"left", "right"}:
            raise _refuse(case, "takes supports holding x at the end node groups left and/or right only")
        x = np.linspace(0.0, L, 201)
        if np.any(_initial(case, "velocity", x) != 0.0):
            raise _refuse(case, "starts at rest: initial.velocity must be 0")
        u0 = _initial(case, "displacement", x)
        c = bar.c
        k = np.arange(1, 41)[:, None]
        if not ends:                                                    # free-free
            shapes, omegas = np.cos(k * np.pi * x / L), k * np.pi * c / L
        elif ends == {"left", "right"}:                                 # clamped-clamped
            shapes, omegas = np.sin(k * np.pi * x / L), k * np.pi * c / L
        else:                                                           # clamped at one end
            s = x if ends == {"right"} else L - x
            shapes, omegas = np.cos((2 * k - 1) * np.pi * s / (2 * L)), (2 * k - 1) * np.pi * c / (2 * L)
        amplitudes = shapes @ u0 / np.einsum("ij,ij->i", shapes, shapes)
        residual = np.abs(u0 - amplitudes[:, None] * shapes).max(axis=1)
        best = int(np.argmin(residual))
        scale = np.abs(u0).max()
        if scale == 0.0 or residual[best] > 1e-9 * scale:
            raise _refuse(case, "needs initial.displacement in one mode of the bar (e.g. \"0.01*cos(pi*x/L)\" "
                                "for a free-free bar of length L)")
        self.bar, self.u0, self.x = bar, u0, x
        self.omega, self.a, self.mode = float(omegas.ravel()[best]), float(amplitudes[best]), best + 1
        self.contacts, self.probes = [], bar.probes
        self.length_scale, self.force_scale = abs(self.a), None
        self.energy_scale = bar.rho * bar.section * self.omega ** 2 * self.a ** 2 * L / 4.0
        self.label = f"exact bar_mode (mode {self.mode}, {self.omega / (2 * np.pi):.6g} Hz, amplitude {self.a:g})"

    def displacement(self, probe, t):
        return np.interp(self.probes[probe], self.x, self.u0) * np.cos(self.omega * np.asarray(t, dtype=float))

    def energy(self, t):
        return np.full(np.shape(t), self.energy_scale)


REFERENCES = {"b1": B1, "b2": B2, "bar_mode": BarMode}


def from_case(case: Case) -> Reference | None:
    """The case's declared reference (None without one); CaseError if the case does not fit it.

    Also a reference that changes of the case left behind (``reference:`` in its data, ``case.reference``
    None: fem_impact.case): the CaseError says why the changed case does not fit it.
    """
    name = case.reference
    if name is None:
        declared = case.source.get("reference") if isinstance(case.source, dict) else None
        if not isinstance(declared, str) or declared not in REFERENCES:
            return None
        REFERENCES[declared](dataclasses.replace(case, reference=declared))   # (raises: it was left behind)
        return None
    return REFERENCES[name](case)


# --- another run as the reference ------------------------------------------------------------


def column(h, name: str) -> np.ndarray:
    """A history column by its CSV name (``wall.force``), from a dict or a structured array (``wall_force``)."""
    if isinstance(h, dict):
        return h[name] if name in h else h[name.replace(".", "_")]
    return h[name.replace(".", "_")]


def contact_spells(closed: np.ndarray, merge: int = 0) -> list[tuple[int, int]]:
    """(first, last) indices of the runs of ``closed``; openings of at most ``merge`` samples are bridged."""
    idx = np.flatnonzero(closed)
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > merge + 1)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]])
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


class RunReference(Reference):
    """Another run (the finest level of a study) as the reference, interpolated in time."""

    def __init__(self, history: dict, probes, contacts, label: str):
        self.h, self.label = history, label
        t = history["t"]
        self.t, self.t_max = t, float(t[-1])
        self.probes = {p: 0.0 for p in probes if f"{p}.ux" in history}
        self.contacts = list(contacts)
        self.F = sum((history[f"{c}.force"] for c in self.contacts), np.zeros_like(t))
        S = sum((history[f"{c}.impulse"] for c in self.contacts), np.zeros_like(t))
        self.I = np.cumsum(S)
        E = history["kinetic"] + history["strain"]
        self.E = E
        u = [np.abs(history[f"{p}.ux"]).max() for p in self.probes]
        self.length_scale = max(u) if u else 1.0
        self._phases = [(float(t[a]), float(t[b])) for a, b in contact_spells((self.F > 0) | (S > 0), merge=2)
                        if b > a]
        inside = _inside(t, self._phases)
        self.force_scale = float(self.F[inside].mean()) if inside.any() and self.F[inside].mean() > 0 else None
        self.energy_scale = float(E[0] + np.abs(history["external_work"]).max())

    def displacement(self, probe, t):
        return np.interp(t, self.t, self.h[f"{probe}.ux"])

    def force(self, t):
        return np.interp(t, self.t, self.F)

    def impulse_total(self, t_end):
        return float(np.interp(t_end, self.t, self.I))

    def energy(self, t):
        return np.interp(t, self.t, self.E)

    def phases(self, t_end):
        return [(a, min(b, t_end)) for a, b in self._phases if a < t_end]


def _inside(t: np.ndarray, phases) -> np.ndarray:
    inside = np.zeros(t.shape, dtype=bool)
    for a, b in phases:
        inside |= (t > a) & (t < b)
    return inside


# --- error measures --------------------------------------------------------------------------


def _rel(value: float, scale: float | None) -> float:
    return float(value / scale) if scale else math.nan


def errors(h: dict, ref: Reference) -> dict[str, float]:
    """The error measures of a run's history (columns by CSV name) against ``ref`` (module docstring).

    Measures that do not apply (no probe, no contact) are NaN. Times beyond ``ref.t_max`` are
    left out.
    """
    keep = h["t"] <= ref.t_max * (1 + 1e-12)
    t = h["t"][keep]
    out = dict.fromkeys(ERROR_MEASURES, math.nan)
    rms = [np.sqrt(np.mean((h[f"{p}.ux"][keep] - ref.displacement(p, t)) ** 2))
           for p in ref.probes if f"{p}.ux" in h]
    if rms:
        out["err_displacement"] = _rel(max(rms), ref.length_scale)
    if ref.contacts:
        F = sum(h[f"{c}.force"][keep] for c in ref.contacts)
        S = sum(h[f"{c}.impulse"][keep] for c in ref.contacts)
        exact_total = ref.impulse_total(float(t[-1]))
        if exact_total > 0:
            out["err_impulse"] = abs(float(S.sum()) - exact_total) / exact_total
        inside = _inside(t, ref.phases(float(t[-1])))
        if inside.any() and ref.force_scale:
            exact = ref.force(t[inside])
            out["err_force"] = _rel(abs(F[inside].mean() - exact.mean()), ref.force_scale)
            out["force_oscillation"] = _rel(np.sqrt(np.mean((F[inside] - exact) ** 2)), ref.force_scale)
    E = h["kinetic"][keep] + h["strain"][keep]
    out["err_energy"] = _rel(np.abs(E - ref.energy(t)).max(), ref.energy_scale)
    return out


def energy_growth(h: dict) -> float:
    """Largest ``E(t) - E(0) - W_ext(t)`` relative to ``E(0) + max |W_ext|``: energy the scheme created."""
    E = h["kinetic"] + h["strain"]
    W = h["external_work"]
    scale = E[0] + np.abs(W).max()
    return float(np.max(E - E[0] - W) / scale) if scale > 0 else 0.0
