"""The reduced model (docs/theory.md s. 8): kept modes dynamically, the truncated ones statically.

``U = Y1 Z + S_k (R(t) - P^T lam)`` with ``S_k = K^-1 - Y1 diag(1/w1^2) Y1^T`` on the elastic
subspace. The modal equations ``Z'' + diag(mu1) Z' + diag(w1^2) Z + (P Y1)^T lam = Y1^T R`` are
handed to the same Newmark integrator and contact law as the full model, as small operators
replicated on every rank; the residual flexibility makes the contact rows compliant
(``P S_k P^T``). Nothing of size N is touched in the loop: physical fields are rebuilt from
precomputed columns only for probes (a few dofs) and output frames.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from petsc4py import PETSc

from .. import cache
from ..errors import ModelInputError
from ..linalg.factor import direct_solver_settings, factorize
from .fields import StateFields
from .specs import ReductionSpec
from .model import Model, load_factor
from .modes import ModeCountError, Modes, compute_modes, free_dof_count, solver_settings, warn_if_split
from ..parallel import allsum

if TYPE_CHECKING:   # (type hints only: the contact rows this model is built for)
    from ..nonsmooth.relation import Constraints

log = logging.getLogger(__name__)

RIGID_ROW = 1e-9   # neglected flexibility ratio below which a row counts as rigid (no compliance)
INITIAL_KEPT = 1e-3   # the share of the initial kinetic energy the kept modes may miss without a warning
# Friction with the static correction: the rows' compliance H S_k H^T must be symmetric positive
# semi-definite to this fraction of the rows' flexibility (round-off of S_k = K^+ - kept modes' part).
PSD_TOLERANCE = 1e-9
AUTO_LIMIT = 400   # most modes `modes: auto` will consider
# Static solves of free bodies: the shift is FLEX_SHIFT times the first elastic w^2, and each of
# the FLEX_SWEEPS sweeps divides the error by 1 + w_1^2/shift = 1001 (converged: the shift does not
# change the result, so the first w^2 is not part of the cache key).
FLEX_SHIFT = 1e-3
FLEX_SWEEPS = 8


class Flexibility:
    """Static solves on the elastic subspace: ``x = K^+ f`` with rigid-body modes projected out.

    For free bodies ``K`` is singular: the load is first freed of its rigid-body resultant
    (inertia relief, ``f - M Phi_r Phi_r^T f``), then ``(K + sigma M) x = f + sigma M x`` is
    iterated from a shifted factorization (each sweep divides the error by ``1 + w_1^2/sigma``)
    and the result is made mass-orthogonal to the rigid modes.
    """

    def __init__(self, K: PETSc.Mat, M: PETSc.Mat, rigid_local: np.ndarray, first_elastic_w2: float):
        self.M, self.rigid = M, rigid_local
        self.comm = K.getComm().tompi4py()
        self.sigma = FLEX_SHIFT * first_elastic_w2 if rigid_local.shape[1] else 0.0
        A = K.copy()
        if self.sigma:
            A.axpy(self.sigma, M, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        self.solve = factorize(A)
        self.b, self.x = K.createVecs()
        self.Mx = K.createVecs()[0]

    def _remove_rigid(self, local: np.ndarray, use_mass_on_left: bool) -> np.ndarray:
        """``f - M Phi (Phi^T f)`` (loads) or ``x - Phi (Phi^T M x)`` (displacements)."""
        if not self.rigid.shape[1]:
            return local
        if use_mass_on_left:
            coef = allsum(self.comm, self.rigid.T @ local)
            return local - self._mass(self.rigid @ coef)
        coef = allsum(self.comm, self.rigid.T @ self._mass(local))
        return local - self.rigid @ coef

    def _mass(self, local: np.ndarray) -> np.ndarray:
        self.b.array[:] = local
        self.M.mult(self.b, self.Mx)
        return self.Mx.array_r.copy()

    def apply(self, f_local: np.ndarray) -> np.ndarray:
        """K^+ f for one column (owned entries)."""
        f = self._remove_rigid(f_local, use_mass_on_left=True)
        x = np.zeros_like(f)
        for _ in range(FLEX_SWEEPS if self.sigma else 1):
            self.b.array[:] = f + self.sigma * self._mass(x) if self.sigma else f
            self.solve(self.b, self.x)
            x = self.x.array_r.copy()
        return self._remove_rigid(x, use_mass_on_left=False)


class ModalLoad:
    """``Y1^T R(t)`` from the projected load vectors, on a small replicated vector."""

    def __init__(self, constant: np.ndarray, varying: list):
        self.constant, self.varying = constant, varying
        self.time_dependent = bool(varying)

    def evaluate(self, t: float, out: np.ndarray) -> np.ndarray:
        out[:] = self.constant
        for f, r in self.varying:
            out += load_factor(f, t) * r
        return out

    def evaluate_block(self, times: np.ndarray) -> np.ndarray:
        """``Y1^T R(t)`` at each of ``times`` (L x n1), the time functions evaluated on all at once; a
        value that overflows is left inf or nan (the caller stops before it)."""
        out = np.empty((times.size, self.constant.size))
        out[:] = self.constant
        for f, r in self.varying:
            out += f.at_times(times)[:, None] * r
        return out


@dataclass
class StaticCorrection:
    """The quasi-static part ``S_k (R(t) - H^T lam)`` seen from the contact rows (``StaticPart``).

    Without friction ``H = P``. With friction ``H = [P; P_T]``: the rows' compliance is the whole block
    ``H S_k H^T``, normal and tangent rows coupled, and the forces passed to ``energy``, ``work`` and
    ``displacement`` are then either the normal ones (p: no tangential force) or all (p + pt).
    """

    compliance: np.ndarray         # P S_k P^T
    rigid_rows: np.ndarray
    load_offsets: np.ndarray       # P S_k [R_c, b_1, ...]           (p x nl)
    load_gram: np.ndarray          # [R_c, b_i]^T S_k [R_c, b_i]      (nl x nl)
    functions: list                # the time functions of b_1, ... (R_c has 1)
    rows_compliance: np.ndarray | None = None   # H S_k H^T with friction ((p + pt)^2), else None
    rows_offsets: np.ndarray | None = None      # H S_k [R_c, b_1, ...] with friction ((p + pt) x nl)
    _recent: dict = field(default_factory=dict, repr=False)   # t -> coefficients, last two times

    def coefficients(self, t: float) -> np.ndarray:
        """(1, f_1(t), ...): asked for several times per step, so the last two times are kept."""
        cache = self._recent
        if t not in cache:
            if len(cache) >= 2:
                cache.pop(next(iter(cache)))
            cache[t] = np.array([1.0] + [load_factor(f, t) for f in self.functions])
        return cache[t]

    def __post_init__(self):
        # Constant loads only (the common case): the load terms are constants, computed once.
        self._constant = not self.functions
        self.p = self.compliance.shape[0]
        if self.rows_compliance is None:   # (without friction the rows are the normal ones)
            self.rows_compliance, self.rows_offsets = self.compliance, self.load_offsets
        self._offset0 = self.load_offsets[:, 0].copy()
        self._rows_offset0 = self.rows_offsets[:, 0].copy()
        self._energy0 = 0.5 * float(self.load_gram[0, 0])

    @property
    def tangents(self) -> bool:
        """Whether the rows include tangent rows (friction: ``H = [P; P_T]``)."""
        return self.rows_compliance.shape[0] > self.p

    def _on(self, force: np.ndarray):
        """(offsets, their constant column, compliance) of the rows ``force`` acts on: normal or all."""
        if force.size == self.p:
            return self.load_offsets, self._offset0, self.compliance
        return self.rows_offsets, self._rows_offset0, self.rows_compliance

    def offset(self, t: float) -> np.ndarray:
        if self._constant:
            return self._offset0
        return self.load_offsets @ self.coefficients(t)

    def rows_offset(self, t: float) -> np.ndarray:
        """``H S_k R(t)`` on every row, normal and tangent (``offset`` without friction)."""
        if self._constant:
            return self._rows_offset0
        return self.rows_offsets @ self.coefficients(t)

    def displacement(self, t: float, force: np.ndarray) -> np.ndarray:
        """The static part's displacement on the rows ``force`` acts on, ``H S_k (R(t) - H^T force)``."""
        offsets, offset0, C = self._on(force)
        return (offset0 if self._constant else offsets @ self.coefficients(t)) - C.dot(force)

    def energy(self, t: float, force: np.ndarray) -> float:
        """1/2 f^T S_k f with f = R(t) - H^T force."""
        offsets, offset0, C = self._on(force)
        if self._constant:
            return self._energy0 - force @ offset0 + 0.5 * force @ (C @ force)
        c = self.coefficients(t)
        return 0.5 * (c @ self.load_gram @ c) - force @ (offsets @ c) + 0.5 * force @ C @ force

    def work(self, t0: float, t1: float, f0: np.ndarray, f1: np.ndarray, gamma: float) -> float:
        """Work of the loads on the static displacement over a step: R_mean^T S_k H^T (f1 - f0)."""
        offsets, offset0, _ = self._on(f1)
        if self._constant:
            return -float(offset0 @ (f1 - f0))
        c0, c1 = self.coefficients(t0), self.coefficients(t1)
        c_mean = (1.0 - gamma) * c0 + gamma * c1
        return c_mean @ self.load_gram @ (c1 - c0) - c_mean @ offsets.T @ (f1 - f0)

    def contact_loss(self, t0: float, t1: float, f0: np.ndarray, f1: np.ndarray) -> float:
        """What the forces lose on the static part over a step, ``mean(f) . Delta(H U_s)``: with the static
        part's energy and the loads' work on it (trapezoidal weights) an exact identity (C symmetric)."""
        C = self._on(f1)[2]
        offset = self.offset if f1.size == self.p else self.rows_offset
        loss = 0.5 * float((f0 + f1).dot(offset(t1) - offset(t0)))
        return loss - 0.5 * float(f1.dot(C.dot(f1)) - f0.dot(C.dot(f0)))

    # -- the same for a block of steps without contact force (fem_impact/integrators/blocks.py) --
    def coefficients_block(self, times: np.ndarray) -> np.ndarray:
        """(1, f_1(t), ...) at each of ``times`` (L x nl); a value that overflows is left inf or nan."""
        out = np.ones((times.size, 1 + len(self.functions)))
        for i, f in enumerate(self.functions):
            out[:, 1 + i] = f.at_times(times)
        return out

    def offsets_for(self, c: np.ndarray) -> np.ndarray:
        """``offset`` at each step of a block, from its coefficients (L x nl): L x p."""
        if self._constant:
            return np.broadcast_to(self._offset0, (c.shape[0], self._offset0.size))
        return c @ self.load_offsets.T

    def energies_for(self, c: np.ndarray, force: np.ndarray | None = None) -> np.ndarray:
        """``energy`` at each step of a block, from its coefficients (L x nl) and its forces (L x p; None:
        without contact force)."""
        if self._constant:
            stored = np.full(c.shape[0], self._energy0)
        else:
            stored = 0.5 * np.einsum("ji,ik,jk->j", c, self.load_gram, c)
        if force is not None:
            stored = stored - np.einsum("ji,ji->j", force, self.offsets_for(c))
            stored += 0.5 * np.einsum("ji,ji->j", force, force @ self.compliance.T)
        return stored

    def works_for(self, c0: np.ndarray, c1: np.ndarray, gamma: float, f0: np.ndarray | None = None,
                  f1: np.ndarray | None = None) -> np.ndarray:
        """``work`` over each step of a block (coefficients and forces at the steps' starts and ends;
        forces None: without contact force)."""
        if self._constant:
            work = np.zeros(c1.shape[0])
            if f0 is not None:
                work = work - (f1 - f0) @ self._offset0
            return work
        c_mean = (1.0 - gamma) * c0 + gamma * c1
        work = np.einsum("ji,ik,jk->j", c_mean, self.load_gram, c1 - c0)
        if f0 is not None:
            work -= np.einsum("ji,ji->j", c_mean @ self.load_offsets.T, f1 - f0)
        return work

    def contact_losses(self, c: np.ndarray, f0: np.ndarray, f1: np.ndarray) -> np.ndarray:
        """What the static part adds to the contact loss over each step of a block (MoreauJean's
        ``_static_contact_loss``): ``c`` the coefficients at the block's start and its steps' ends
        (L + 1 x nl), ``f0``, ``f1`` the forces at the steps' starts and ends (L x p)."""
        offsets = self.offsets_for(c)
        loss = 0.5 * np.einsum("ji,ji->j", f0 + f1, offsets[1:] - offsets[:-1])
        C = self.compliance.T
        return loss - 0.5 * (np.einsum("ji,ji->j", f1, f1 @ C) - np.einsum("ji,ji->j", f0, f0 @ C))


@dataclass
class ReducedModel:
    """The modal equations ``Z'' + C Z' + diag(w1^2) Z + (P Y1)^T lam = Y1^T R(t)`` (M = I) and how to
    read physical fields from Z; the builder makes them the integrators' ``Operators``
    (fem_impact/build.py)."""

    stiffness: np.ndarray               # w1^2 (n1)
    damping: np.ndarray | None          # alpha + beta w1^2 (n1), None without damping
    load: ModalLoad                     # Y1^T R(t)
    rows: np.ndarray                    # (P Y1)^T (n1 x p)
    tangents: np.ndarray | None         # (P_T Y1)^T (n1 x pt) with friction, else None
    static: StaticCorrection | None     # the truncated modes' static part seen from the rows
    fields: StateFields
    Z0: np.ndarray
    Zdot0: np.ndarray
    modes: int
    cutoff_hz: float
    neglected_flexibility: np.ndarray   # per contact row: (P S_k P^T)_jj / ((P K^+ P^T)_jj + c_j)
    flexibility_columns: np.ndarray     # K^+ [P^T, R_c, b_1, ...] (owned rows): reusable


def static_load_columns(model: Model, cons: Constraints, tangents: bool = False) -> np.ndarray:
    """[P^T, R_c, b_1, ...]: the load patterns whose static response the reduction needs (owned rows);
    with ``tangents`` (friction with the static correction) the tangent rows' P_T^T after them."""
    load = model.load
    R_cols = [load.constant.array_r.copy()] + [b.array_r.copy() for _, b in load.varying]
    T_cols = [cons.tangent_local.toarray()] if tangents and cons.pt else []
    return np.column_stack([cons.P_local.toarray()] + R_cols + T_cols)


def build_reduced(model: Model, cons: Constraints, modes, n1: int, static_correction: bool, alpha: float,
                  beta: float, dt: float, flexibility_columns: np.ndarray | None = None) -> ReducedModel:
    """The reduced operators for the first ``n1`` modes of ``modes`` (rigid ones included).

    ``flexibility_columns`` (K^+ applied to ``static_load_columns``, from an earlier run of the
    same scene) skips the static solves.
    """
    comm = model.comm
    Y1 = np.ascontiguousarray(modes.Y_local[:, :n1])
    w2 = np.asarray(modes.omega2[:n1], dtype=float)
    P_local = cons.P_local
    Pr = allsum(comm, (P_local.T @ Y1))                       # P Y1 (p x n1)
    load = model.load
    static_tangents = static_correction and cons.pt > 0   # (friction: the static part on the tangent rows too)
    columns = static_load_columns(model, cons, static_tangents)
    nl = 1 + len(load.varying)
    R_cols = [columns[:, k] for k in range(cons.p, cons.p + nl)]
    R_modal = [allsum(comm, Y1.T @ r) for r in R_cols]
    modal_load = ModalLoad(R_modal[0], [(f, r) for (f, _), r in zip(load.varying, R_modal[1:], strict=True)])

    M_U0, M_V0 = model.M.createVecs()
    model.M.mult(model.U0, M_U0)
    model.M.mult(model.V0, M_V0)
    Z0 = allsum(comm, Y1.T @ M_U0.array_r)
    Zdot0 = allsum(comm, Y1.T @ M_V0.array_r)
    _initial_velocity_kept(model, Zdot0, M_V0)

    # Residual flexibility of the truncated modes, from static solves on the elastic subspace.
    elastic = ~modes.rigid
    full = static_solves(model, modes, columns) if flexibility_columns is None else flexibility_columns
    kept_elastic = elastic[:n1]
    Y1e, w1e = Y1[:, kept_elastic], w2[kept_elastic]
    P_dense = columns[:, : cons.p]
    X = full - Y1e @ (allsum(comm, Y1e.T @ columns) / w1e[:, None])
    XP, XR, XT = X[:, : cons.p], X[:, cons.p: cons.p + nl], X[:, cons.p + nl:]
    flex_full = np.diag(allsum(comm, P_dense.T @ full[:, : cons.p])) if cons.p else np.zeros(0)
    compliance = allsum(comm, P_dense.T @ XP)
    compliance = 0.5 * (compliance + compliance.T)
    # Against the whole compliance the contact sees: the structure's and an elastic stop's in series.
    seen = flex_full + cons.compliance
    neglected = np.divide(np.diag(compliance), seen, out=np.zeros(cons.p), where=seen > 0)

    static = None
    if static_correction:
        rigid_rows = neglected <= RIGID_ROW
        load_offsets = allsum(comm, P_dense.T @ XR).reshape(cons.p, XR.shape[1])
        load_gram = allsum(comm, np.column_stack(R_cols).T @ XR)
        if static_tangents:
            static = _static_with_tangents(comm, cons, full, columns, X, nl, neglected, load_offsets, load_gram,
                                           [f for f, _ in load.varying])
        else:
            static = StaticCorrection(
                compliance=np.where(np.outer(rigid_rows, rigid_rows), 0.0, compliance),
                rigid_rows=rigid_rows, load_offsets=load_offsets, load_gram=load_gram,
                functions=[f for f, _ in load.varying],
            )
    # The modal equations are diagonal: M = I, K = diag(w1^2), C = diag(alpha + beta w1^2).
    C = (alpha + beta * w2) if (alpha or beta) else None
    # tangent rows on the modes (friction)
    tangents = allsum(comm, cons.tangent_local.T @ Y1).T.copy() if cons.pt else None
    # (with friction the static part's columns S_k [P^T, P_T^T]: the fields read it under [F_N, F_T])
    XH = np.hstack([XP, XT]) if static_tangents else XP
    fields = StateFields(cons, Y1, XR if static else None, XH if static else None, static, dt)
    cutoff = float(np.sqrt(w2[-1]) / (2 * np.pi))
    log.info("reduced model: %d modes (cut-off %.4g Hz), static correction %s", n1, cutoff, static_correction)
    return ReducedModel(w2.copy(), C, modal_load, Pr.T.copy(), tangents, static, fields, Z0, Zdot0, n1, cutoff,
                        neglected, full)


def _static_with_tangents(comm, cons: Constraints, full: np.ndarray, columns: np.ndarray, X: np.ndarray, nl: int,
                          neglected: np.ndarray, load_offsets: np.ndarray, load_gram: np.ndarray,
                          functions: list) -> StaticCorrection:
    """The static part on the rows ``H = [P; P_T]`` (friction): the compliance ``H S_k H^T`` over normal and
    tangent rows, coupled, and the offsets ``H S_k R``. A row is rigid when its normal and its tangents all
    are (neglected flexibility at most RIGID_ROW); a rigid row's unknowns take no compliance at all (their
    rows and columns zero: a principal block of a positive semi-definite matrix stays so). A compliance that
    is not symmetric positive semi-definite beyond round-off is refused: its energy would have no sign."""
    p = cons.p
    H = np.hstack([columns[:, :p], columns[:, p + nl:]])
    XH = np.hstack([X[:, :p], X[:, p + nl:]])
    C = allsum(comm, H.T @ XH)
    flex = np.diag(allsum(comm, H.T @ np.hstack([full[:, :p], full[:, p + nl:]])))
    scale = max(float(np.abs(flex).max()), float(np.abs(C).max()), 1e-300)
    asymmetry = float(np.abs(C - C.T).max())
    C = 0.5 * (C + C.T)
    try:   # (a Cholesky factor of C shifted by the tolerance exists iff no eigenvalue is below -tolerance)
        np.linalg.cholesky(C + PSD_TOLERANCE * scale * np.eye(C.shape[0]))
        smallest = 0.0
    except np.linalg.LinAlgError:
        smallest = float(np.linalg.eigvalsh(C).min())
    if asymmetry > PSD_TOLERANCE * scale or smallest < 0.0:
        raise ModelInputError(("solver", "static_correction"),
                              f"the static correction's compliance on the rows with friction is not symmetric "
                              f"positive semi-definite (asymmetry {asymmetry / scale:.2g}, smallest eigenvalue "
                              f"{smallest / scale:.2g} of the rows' flexibility): friction cannot act through it; "
                              "set solver.static_correction: false or use solver.method: moreau_jean")
    tangent = np.divide(np.diag(C)[p:], flex[p:], out=np.zeros(cons.pt), where=flex[p:] > 0)
    soft = np.bincount(cons.tangent_of, weights=(tangent > RIGID_ROW).astype(float), minlength=p) > 0
    rigid_rows = (neglected <= RIGID_ROW) & ~soft
    compliant = ~np.concatenate([rigid_rows, rigid_rows[cons.tangent_of]])
    C = np.where(np.outer(compliant, compliant), C, 0.0)
    offsets = allsum(comm, H.T @ X[:, p: p + nl]).reshape(p + cons.pt, nl)   # (its normal rows: load_offsets)
    return StaticCorrection(compliance=C[:p, :p].copy(), rigid_rows=rigid_rows, load_offsets=load_offsets,
                            load_gram=load_gram, functions=functions, rows_compliance=C, rows_offsets=offsets)


def prepare_reduced(spec: ReductionSpec, model: Model, cons: Constraints) -> tuple[ReducedModel, dict]:
    """Modes (given or chosen), static solves (both cached) and the reduced model."""
    comm = model.comm
    if model.motion is not None and spec.beta:
        # Its kept modes carry their share of the support's quasi-static motion, which a stiffness-
        # proportional damping would book as dissipated although the whole structure's K-damping of
        # that motion cancels (fem/prescribed.py, docs/theory.md s. 2.4).
        raise ModelInputError(("damping", "beta"), "the reduced model with a moving support takes mass-proportional "
                                                   "damping only (alpha): set beta to 0, or use the full model")
    scene = cache.key(comm, model.K, model.M, model.fixed)
    reused = set()
    tangents = spec.static_correction and cons.pt > 0   # (friction: the tangent rows' static solves too)
    if spec.modes == "auto":
        available = free_dof_count(model)
        cap = max(1, min(available - 1, AUTO_LIMIT))
        n_try = min(cap, 32)
        f_scene, scene_why = scene_frequency(spec, model)
        while True:
            modes = _modes(model, n_try, scene, reused)
            columns = _flexibility(model, cons, modes, scene, reused, tangents)
            n1, reason = choose_mode_count(modes, cons, columns, spec.tolerance, f_scene, scene_why)
            if n1 is not None:
                break
            if n_try >= cap:
                raise ModelInputError(("solver", "tolerance"), f"no count of modes up to {n_try} meets it: {reason}; "
                                                               "loosen spec.tolerance, or use the full model "
                                                               "(method: moreau_jean)")
            n_try = min(cap, 2 * n_try)
    else:
        n1, reason = spec.modes, "as given (spec.modes)"
        # One mode more than kept tells whether a rigid-body mode would be left out.
        try:
            modes = _modes(model, n1 + 1, scene, reused)
        except ModeCountError as err:
            if err.requested != err.available + 1:
                raise ModelInputError(("solver", "modes"), str(err).replace(str(n1 + 1), str(n1), 1)) from None
            modes = _modes(model, n1, scene, reused)   # all modes of a small model
        if modes.n > n1 and modes.rigid[n1]:
            rigid = _rigid_mode_count(model, modes, scene, reused)
            raise ModelInputError(("solver", "modes"), f"keeps {n1} modes but the model moves freely in "
                                                       f"{rigid} rigid-body modes: keep them all "
                                                       f"(modes >= {rigid}), or add supports")
        columns = _flexibility(model, cons, modes, scene, reused, tangents)
    warn_if_split(modes, n1)
    red = build_reduced(model, cons, modes, n1, spec.static_correction, spec.alpha, spec.beta, spec.dt, columns)
    if reused:
        log.info("reused from the cache (%s): %s", cache.cache_dir(), " and ".join(sorted(reused)))
    summary = {
        "modes": red.modes, "modes_reason": reason, "rigid_modes": int(modes.rigid[:n1].sum()),
        "cutoff_hz": red.cutoff_hz, "static_correction": spec.static_correction,
        "neglected_flexibility": {c.name: float(red.neglected_flexibility[c.rows].max()) for c in cons.contacts},
        "reused_from_cache": sorted(reused),
    }
    return red, summary


def _rigid_mode_count(model: Model, modes: Modes, scene: str, reused: set) -> int:
    """How many rigid-body modes the model has (``modes``, the first few, may end among them): more modes until
    one is elastic, or there are no more."""
    available = free_dof_count(model)
    while modes.rigid.all() and modes.n < available:
        modes = _modes(model, min(available, 2 * modes.n), scene, reused)
    return int(modes.rigid.sum())


def _initial_velocity_kept(model: Model, Zdot0: np.ndarray, M_V0) -> float | None:
    """The share of the initial velocity's kinetic energy the kept modes hold (None: at rest); a warning
    where they miss more than INITIAL_KEPT of it (the static correction has no velocity of its own: the
    rest is lost at the start)."""
    kinetic = float(allsum(model.comm, np.array([model.V0.array_r @ M_V0.array_r]))[0])
    if not kinetic > 0.0:
        return None
    kept = float(Zdot0 @ Zdot0) / kinetic
    if kept < 1.0 - INITIAL_KEPT:
        log.warning("initial.velocity: the kept modes hold %.4g of its kinetic energy; the rest is lost at the "
                    "start (the static correction has no velocity): keep more modes, or model the body in full",
                    kept)
    return kept


def static_settings() -> dict:
    """What decides the static solves besides the operators and the load patterns: part of their cache key."""
    return {"shift": FLEX_SHIFT, "sweeps": FLEX_SWEEPS, **direct_solver_settings()}


def _modes(model: Model, n: int, scene: str, reused: set) -> Modes:
    comm = model.comm
    settings = solver_settings()
    name = f"modes-{cache.key(comm, scene, n, settings)}"
    stored = cache.load(name, comm)
    if stored is not None:
        reused.add("modes")
        return Modes(stored["omega2"], stored["Y_local"], stored["residual"], stored["rigid"],
                     float(stored["scale"]), float(stored["shift"]), comm)
    modes = compute_modes(model, n, tol=settings["tol"], check_count=settings["check_count"])
    cache.save(name, comm, omega2=modes.omega2, Y_local=modes.Y_local, residual=modes.residual,
               rigid=modes.rigid, scale=modes.scale, shift=modes.shift)
    return modes


def _flexibility(model: Model, cons: Constraints, modes: Modes, scene: str, reused: set,
                 tangents: bool = False) -> np.ndarray:
    """K^+ applied to the load and contact patterns (static solves; ``tangents``: the tangent rows' too), cached."""
    comm, columns = model.comm, static_load_columns(model, cons, tangents)
    name = f"static-{cache.key(comm, scene, modes.Y_local[:, modes.rigid], columns, static_settings())}"
    stored = cache.load(name, comm)
    if stored is not None:
        reused.add("static solves")
        return stored["columns"]
    result = static_solves(model, modes, columns)
    cache.save(name, comm, columns=result)
    return result


def static_solves(model: Model, modes: Modes, columns: np.ndarray) -> np.ndarray:
    """K^+ applied to each column, on the elastic subspace of ``modes`` (class Flexibility)."""
    elastic = ~modes.rigid
    first_w2 = float(modes.omega2[elastic][0]) if elastic.any() else 1.0
    flex = Flexibility(model.regular_stiffness(), model.M, modes.Y_local[:, modes.rigid], first_w2)
    return np.column_stack([flex.apply(columns[:, j]) for j in range(columns.shape[1])])


#: Kept modes must reach this many times the highest frequency of the loads (resonance and the
#: response just above it need the modes around and above the drive).
LOAD_BAND_FACTOR = 2.0
#: The loads' band: the frequency below which this fraction of their spectral energy lies.
LOAD_BAND_ENERGY = 0.99


def scene_frequency(spec: ReductionSpec, model: Model) -> tuple[float, str]:
    """The highest frequency the scene needs the kept modes to reach, and why.

    Half the output sampling rate (what the output resolves), and ``LOAD_BAND_FACTOR`` times
    the band of the time-dependent loads: their time functions sampled at dt over the run
    (at most 2^18 samples), the frequency below which ``LOAD_BAND_ENERGY`` of their spectral
    energy (mean removed, Hann window) lies.
    """
    f_output = 1.0 / (2.0 * spec.output_every * spec.dt)
    f_load, source = 0.0, None
    n = int(min(2**18, max(16, np.ceil(spec.t_end / spec.dt) + 1)))
    t = np.arange(n) * spec.dt
    for f, _ in model.load.varying:
        with np.errstate(all="ignore"):
            values = np.broadcast_to(np.asarray(f.evaluate(t=t), dtype=float), t.shape)
        if not np.all(np.isfinite(values)):
            continue   # a load that overflows stops the run with its own message
        spectrum = np.abs(np.fft.rfft((values - values.mean()) * np.hanning(n))) ** 2
        if spectrum.sum() <= 0.0:
            continue
        band = np.fft.rfftfreq(n, spec.dt)[np.searchsorted(np.cumsum(spectrum) / spectrum.sum(), LOAD_BAND_ENERGY)]
        if band > f_load:
            f_load, source = band, f.source
    if LOAD_BAND_FACTOR * f_load > f_output:
        return LOAD_BAND_FACTOR * f_load, (f"{LOAD_BAND_FACTOR:g} x the band of the load '{source}' "
                                           f"({f_load:.4g} Hz)")
    return f_output, "half the output rate"


def choose_mode_count(modes: Modes, cons: Constraints, columns: np.ndarray, tolerance: float,
                      f_scene: float, scene_why: str = "half the output rate") -> tuple[int | None, str]:
    """The smallest n1 (all rigid modes included) whose neglected flexibility at every contact
    row, ``(P S_k P^T)_jj / ((P K^+ P^T)_jj + c_j)`` (c: an elastic stop's compliance), is at
    most ``tolerance`` and whose cut-off frequency reaches ``f_scene`` (``scene_frequency``:
    what the output resolves, what the loads drive).

    Returns (n1, why) or (None, what falls short with all of ``modes``).
    """
    comm = modes.comm
    P = cons.P_local.toarray()
    freq = np.sqrt(modes.omega2) / (2 * np.pi)
    n_rigid = int(modes.rigid.sum())
    if cons.p:
        flex = np.diag(allsum(comm, P.T @ columns[:, : cons.p]))
        PY = allsum(comm, P.T @ modes.Y_local)
        contribution = np.where(modes.rigid, 0.0, PY**2 / np.where(modes.rigid, 1.0, modes.omega2))
        seen = flex + cons.compliance          # an elastic stop's compliance in series
        neglected = (flex[:, None] - np.cumsum(contribution, axis=1)) / np.where(seen > 0, seen, 1.0)[:, None]
        worst = neglected.max(axis=0)          # after keeping 1, 2, ... modes
    else:
        worst = np.zeros(modes.n)
    ok = (worst <= tolerance) & (freq >= f_scene) & (np.arange(1, modes.n + 1) >= max(n_rigid, 1))
    if not ok.any():
        return None, (f"with {modes.n} modes the neglected flexibility is {worst[-1]:.3g} (tolerance "
                      f"{tolerance:g}) and the cut-off {freq[-1]:.4g} Hz (the scene needs {f_scene:.4g} Hz: "
                      f"{scene_why})")
    n1 = int(np.argmax(ok)) + 1
    first_flex = int(np.argmax(worst <= tolerance)) + 1 if (worst <= tolerance).any() else modes.n
    binding = "neglected flexibility" if first_flex >= n1 else "cut-off frequency"
    return n1, (f"smallest count with neglected flexibility {worst[n1 - 1]:.3g} <= {tolerance:g} at every contact "
                f"row and cut-off {freq[n1 - 1]:.4g} Hz >= {f_scene:.4g} Hz ({scene_why}); "
                f"{binding} decided")
