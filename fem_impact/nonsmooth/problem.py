"""The one-step contact problem, assembled from the rows' laws and an integrator's weights, and
Carnot's impact correction (docs/theory.md s. 2.5, 3.3, 4.2).

An integrator supplies its Delassus matrix ``W`` (``P S^-1 P^T`` of its step matrix), the weight
it enters with, the scales of its unknown and of its rows, and each step the free gaps (or
velocities) of its rows; the laws supply their compliance on the diagonal and their memory of
the penetration at the step's start. The row condition of every law is then one LCP:

``w = (a W + (C_s + diag c) / (tau sigma)) x + q_free + m max(-g0, 0) / sigma >= 0 _|_ x >= 0``

with ``x = tau lam`` (the unknown: a force, ``tau = 1``, or an impulse, ``tau = h``), the rows'
gap condition divided by ``sigma`` (Moreau-Jean's ``theta h``, 1 elsewhere) and ``C_s`` a static
part's compliance (the reduced model's).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .laws import RowLaws
from .lcp import ALL, Delassus, delassus_solver


class OneStepProblem:
    """The normal one-step problem of an integrator's rows (see the module's docstring).

    ``solve``, ``dot``, ``matrix`` and ``shape`` are the LCP solver's (a ``Delassus`` or, for a
    sparse diagonal ``W``, a ``DiagonalDelassus``); ``compliance`` the p x p matrix the laws and a
    static part add before scaling, ``elastic`` the rows with a compliance over the step.
    """

    def __init__(self, W, laws: RowLaws, h: float, weight: float = 1.0, compliance_scale: float = 1.0,
                 row_scale: float = 1.0, static: np.ndarray | None = None):
        c, self._memory = laws.terms(h)
        self.laws, self.h, self.row_scale, self._scale = laws, h, row_scale, compliance_scale
        self.stop_compliance = c
        A = W if weight == 1.0 else weight * W
        self.elastic = c > 0.0
        if static is None:
            self.compliance = np.diag(c)
            self.solver = delassus_solver(A, c if compliance_scale == 1.0 else c / compliance_scale)
        else:
            self.compliance = np.diag(c) + static
            self.elastic = np.diag(self.compliance) > 0.0
            shift = self.compliance if compliance_scale == 1.0 else self.compliance / compliance_scale
            self.solver = Delassus.regularized(A + shift)
        self.matrix = self.solver.matrix
        self.dot, self.solve = self.solver.dot, self.solver.solve

    @property
    def shape(self) -> tuple[int, int]:
        return self.solver.shape

    def shift_normal_block(self, W_all: np.ndarray, p: int) -> np.ndarray | None:
        """Add the laws' (and a static part's) compliance to the normal block of a frictional problem's
        ``W_all`` (normal rows first), in place; returns the scaled compliance, or None without one."""
        shift = self.compliance if self._scale == 1.0 else self.compliance / self._scale
        W_all[:p, :p] += shift
        return shift if np.any(self.compliance) else None

    @property
    def has_memory(self) -> bool:
        return self._memory is not None

    def q(self, q_free: np.ndarray, gap0: np.ndarray) -> np.ndarray:
        """The problem's ``q``: the integrator's free part plus what the laws remember of the
        penetration ``max(-g0, 0)`` at the step's start (``q_free`` itself when none does)."""
        if self._memory is None:
            return q_free
        extra = self._memory * np.maximum(-gap0, 0.0)
        return q_free + (extra if self.row_scale == 1.0 else extra / self.row_scale)


# -- Carnot's impact correction -----------------------------------------------------------------

@dataclass
class ImpactResult:
    """Outcome of the velocity and acceleration projections on the closed contacts."""

    lam1: np.ndarray     # velocity-correction impulses, dV = -M^-1 P^T lam1 (may be negative:
                         # they remove the spurious rebound of the trapezoidal rule)
    lam2: np.ndarray     # acceleration-correction forces, dA = -M^-1 P^T lam2
    force: np.ndarray    # F_N = lam0 + lam2 at the end of the step


def impact_correction(
    D: np.ndarray,
    closed: np.ndarray,
    s0: np.ndarray,
    v_star: np.ndarray,
    v_minus: np.ndarray,
    a_normal: np.ndarray,
    lam0: np.ndarray,
    restitution: np.ndarray,
) -> ImpactResult:
    """Carnot's velocity correction and the acceleration projection on the closed rows.

    The sign condition is put on the whole impulse of the step ``S = s0 + lam1 >= 0``
    (``s0`` = the impulse of the position-level forces), complementary to the separating
    velocity ``w = -(P V+) - e max(P V-, 0) >= 0``: an LCP in ``D = P M^-1 P^T``. Contacts
    that stay closed (w = 0) then get the force ``F >= 0`` that keeps their normal
    acceleration non-positive; separating contacts carry no force.

    All arguments are per-row p-vectors (``D`` is p x p, or a ``Delassus`` that keeps the factors
    of its active blocks between calls); only rows in ``closed`` change.
    """
    # (Small arrays: .dot and count_nonzero cost half of @ and .any().)
    solver = D if isinstance(D, Delassus) else Delassus(D)
    D = solver.matrix
    p = s0.size
    lam1, lam2, force = np.zeros(p), np.zeros(p), lam0.copy()
    a = _rows(closed)
    s0a, lam0a = s0[a], lam0[a]
    q1 = -(_block(D, a, a).dot(s0a) + v_star[a])
    if np.count_nonzero(restitution):
        q1 -= restitution[a] * np.maximum(v_minus[a], 0.0)
    S, w, active = solver.solve(q1, guess=lam0a > 0.0, rows=a)
    lam1[a] = S - s0a
    # Normal accelerations after the velocity change are unchanged by it: project them.
    stays = active | (w <= 0.0)
    n_stay = np.count_nonzero(stays)
    if n_stay == stays.size:
        b, lam0b = a, lam0a
        q2 = -(_block(D, b, b).dot(lam0b) + a_normal[b])
    else:
        rows = np.arange(p)[a]
        b, leaving = rows[stays], rows[~stays]
        force[leaving] = 0.0
        lam0b = lam0[b]
        q2 = -(D[b][:, b].dot(lam0b) + a_normal[b] + D[b][:, leaving].dot(lam0[leaving]))
    if n_stay:
        force[b] = solver.solve(q2, guess=lam0b > 0.0, rows=b)[0]
    lam2[a] = force[a] - lam0a
    return ImpactResult(lam1, lam2, force)


def _block(D: np.ndarray, rows, cols) -> np.ndarray:
    """``D[rows][:, cols]``: a view when both are ``ALL``."""
    return D if rows is ALL and cols is ALL else D[rows][:, cols]


def _rows(mask: np.ndarray):
    """The rows set in ``mask``: ``ALL`` when all are (the common case in a contact)."""
    return ALL if np.count_nonzero(mask) == mask.size else np.flatnonzero(mask)


def carnot_projection(carnot: Delassus, rows: np.ndarray, x: np.ndarray, target: np.ndarray,
                      restitution: np.ndarray, contact_loss: float, scale: float
                      ) -> tuple[np.ndarray, float] | None:
    """Carnot's correction at the position level: the smallest velocity change in the norm of M,
    ``dV = -M^-1 P_a^T lam``, ``lam = D_aa^-1 (x - target)``, that sets the normal velocities ``x``
    of the held rows ``rows`` to ``target``. Returns ``(lam, the kinetic energy it removes)``, or
    None when ``x`` is at the target to round-off (``scale``: the step's largest velocity change).

    Should the loss with the step's ``contact_loss`` be negative, the target becomes ``e x`` (e the
    smallest restitution of the rows), which loses ``(1 - e^2)/2 x . D^-1 x >= 0``: the contacts
    never give energy (docs/theory.md s. 4.2).
    """
    def loss_for(goal):   # (lam . D_aa lam = lam . (x - goal): no copy of D's block)
        lam = carnot.solve_block(rows, x - goal)
        return lam, float(lam.dot(x) - 0.5 * lam.dot(x - goal))

    if np.abs(x - target).max() <= ROUND_OFF * scale:
        return None
    lam, loss = loss_for(target)
    if contact_loss + loss < 0.0 and np.count_nonzero(restitution):
        lam, loss = loss_for(restitution.min() * x)
    return lam, loss


ROUND_OFF = 1e-12   # a velocity change below this fraction of the step's impulse's is no correction
