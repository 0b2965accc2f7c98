"""Observers of the time loop: history CSV, ParaView time series, run statistics (the progress bar: progress.py)."""

from __future__ import annotations

import contextlib
import csv
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from ..fem import dolfinx_api as dx
from ..nonsmooth.relation import Constraints
from ..errors import ModelInputError
from ..integrators import StepState
from ..fem.model import AXES, Model, pad_vector
from .outdir import writing
from ..parallel import allsum
from .progress import Progress, duration  # noqa: F401  (re-exported: pipeline, sweep, cli)

# The budget's own columns; the contact laws of a run add theirs (``energy_columns``).
ENERGY_COLUMNS = ("kinetic", "strain", "external_work", "damping_loss", "impact_loss", "contact_loss", "energy_error")


def energy_columns(cons: Constraints) -> list[str]:
    """The energy columns of a run's history: the budget's, then the loss columns its contact laws
    declare (nonsmooth/laws.py, ``ContactLaw.column``), after every other column."""
    return list(ENERGY_COLUMNS) + cons.laws.extra_columns()


class NodalFields:
    """Physical fields of the full model: the state vectors are the nodal values.

    The reduced model has its own reader (``reduce.ReducedFields``) with the same two methods,
    so observers never need to know which model produced a step.
    """

    __checkpoint__ = ()   # (no state of its own: a checkpoint's part all the same, as the reduced model's reader)

    def __init__(self, cons: Constraints):
        self.cons = cons

    def at(self, state: StepState, dofs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Displacement and velocity at a few owned dofs."""
        return state.U[dofs], state.V[dofs]

    def inertial_at(self, state: StepState, dofs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Velocity and acceleration at a few owned dofs (of the dofs' mass: all of it here)."""
        return state.V[dofs], state.A[dofs]

    def frame(self, state: StepState) -> dict[str, np.ndarray]:
        """Owned values of u, v, a and the contact force on the structure (-P^T F_N, and -P_T^T F_T
        with friction: normal and tangential parts in one vector, as ParaView's arrows show it)."""
        force = -(self.cons.P_local @ state.force)
        if state.tangential is not None:
            force -= self.cons.tangent_local @ state.tangential
        return {"u": state.U, "v": state.V, "a": state.A, "contact_force": force}

    def velocity_functionals(self, rows: np.ndarray, comm: MPI.Comm):
        """A reader of ``rows^T v`` at each step, for a few fixed rows (owned entries, n_local x k):
        k dot products and one reduction per step."""
        rows = np.ascontiguousarray(rows.T)

        def read(state: StepState) -> np.ndarray:
            return allsum(comm, rows @ state.V)
        return read


@dataclass
class Probes:
    """Named points, each read at the mesh node nearest to it (one owner rank per probe)."""

    names: list[str]
    owned_dofs: np.ndarray     # (n_probes x dim) local dof of each component, -1 off-owner
    distance: np.ndarray       # distance from the asked point to the node used
    dim: int

    def values(self, state: StepState, comm: MPI.Comm, fields) -> np.ndarray:
        """(u, v) at every probe as one flat array [p0.ux, p0.uy, ..., p0.vx, ...]."""
        if hasattr(fields, "point_reader") and comm.size > 1:   # the reduced model: on every rank, no sum
            u, v = fields.point_reader(self.owned_dofs, comm)(state)
            return np.stack([u, v], axis=1).reshape(-1)
        out = np.zeros((len(self.names), 2, self.dim))
        mine = self.owned_dofs[:, 0] >= 0
        if mine.any():
            out[mine, 0], out[mine, 1] = fields.at(state, self.owned_dofs[mine])
        return allsum(comm, out).reshape(-1)

    def values_block(self, block, comm: MPI.Comm, fields) -> np.ndarray:
        """``values`` at every step of a block of steps (L x columns), one reduction."""
        out = np.zeros((len(block), len(self.names), 2, self.dim))
        mine = self.owned_dofs[:, 0] >= 0
        if mine.any():
            out[:, mine, 0], out[:, mine, 1] = fields.at_block(block, self.owned_dofs[mine])
        return allsum(comm, out).reshape(len(block), -1)

    def columns(self) -> list[str]:
        return [f"{name}.{q}{AXES[c]}" for name in self.names for q in "uv" for c in range(self.dim)]


class BodyMomenta:
    """Momentum of every body per component, ``p_b = m_b . V`` with ``m_b = 1_b^T M`` built once
    (``Model.momentum_rows``): columns ``BODY.px`` (``BODY.py``, ``BODY.pz``)."""

    def __init__(self, model: Model, fields):
        self.dim = model.meshdata.dim
        self.names = list(model.momentum_rows)
        self.mass = {name: float(model.comm.allreduce(rows[:, 0].sum())) for name, rows in model.momentum_rows.items()}
        rows = (np.column_stack([model.momentum_rows[name] for name in self.names]) if self.names
                else np.zeros((model.U0.getLocalSize(), 0)))
        self.read = fields.velocity_functionals(rows, model.comm)

    def values(self, state: StepState) -> np.ndarray:
        return self.read(state) if self.names else np.zeros(0)

    def values_block(self, block) -> np.ndarray:
        """``values`` at every step of a block of steps (L x columns)."""
        return self.read.block(block) if self.names else np.zeros((len(block), 0))

    def columns(self) -> list[str]:
        return [f"{name}.p{AXES[c]}" for name in self.names for c in range(self.dim)]


def find_probes(case, model: Model) -> Probes:
    dim, bs, comm = model.meshdata.dim, model.bs, model.comm
    coords = model.node_coords[: model.n_owned_nodes, :dim]
    names, dofs, distances = [], [], []
    for name, point in case.output.probes.items():
        key = ("output", "probes", name)
        point = np.asarray(pad_vector(point, dim, key, "probe"), dtype=float)
        if coords.size:
            d = np.linalg.norm(coords - point, axis=1)
            k = int(np.argmin(d))
            mine = (float(d[k]), model.first_node + k)
        else:
            mine = (np.inf, -1)
        best = min(comm.allgather(mine))  # nearest node; ties go to the lowest global index
        _check_inside(case, model, key, point)
        local = best[1] - model.first_node
        owned = 0 <= local < model.n_owned_nodes and best[1] >= 0
        names.append(name)
        dofs.append([local * bs + c if owned else -1 for c in range(dim)])
        distances.append(best[0])
    return Probes(names, np.array(dofs, dtype=np.int64).reshape(-1, dim), np.array(distances), dim)


def _check_inside(case, model: Model, key, point) -> None:
    """A probe farther from the mesh than 1e-6 of its size is a mistake (a unit, a sign), not the nearest node."""
    coords = model.node_coords[:, : model.meshdata.dim]
    dim = model.meshdata.dim
    lo = np.min(model.comm.allgather(coords.min(axis=0) if coords.size else np.full(dim, np.inf)), axis=0)
    hi = np.max(model.comm.allgather(coords.max(axis=0) if coords.size else np.full(dim, -np.inf)), axis=0)
    tol = 1e-6 * float(np.max(hi - lo))
    lo, hi = (np.where(np.abs(b) < tol, 0.0, b) for b in (lo, hi))   # (round-off of the mesh generator)
    full = np.zeros(3)
    full[: len(point)] = point
    distance = model.comm.allreduce(dx.distance_to_mesh(model.meshdata.mesh, full, tol), op=MPI.MIN)
    if distance > tol:
        box = ", ".join(f"[{a:g}, {b:g}]" for a, b in zip(lo, hi, strict=True))
        raise ModelInputError(key, f"the point {[float(v) for v in point]} is outside the mesh (which spans "
                                   f"{box}); a probe must lie on the structure")


class FrictionColumns:
    """history.csv's friction columns, after the others: per contact with friction
    ``NAME.tangential_force`` (the magnitude of the summed friction force on the body, the first node
    group of a pair), its components ``NAME.tx``, ``NAME.ty`` (``NAME.tz``) along the global axes,
    ``NAME.slip`` (the largest sliding speed of its rows in contact), ``NAME.sticking`` and ``NAME.slipping``
    (rows carrying a normal force, strictly inside the friction cone or on it); then ``friction_loss``."""

    STICK = 1e-9   # relative margin inside the cone that counts as sticking

    def __init__(self, cons: Constraints):
        self.cons, self.dim = cons, cons.tangent_dirs.shape[1]
        self.contacts = [c for c in cons.contacts if np.any(np.isin(cons.tangent_of, np.arange(cons.p)[c.rows]))]

    def columns(self) -> list[str]:
        axes = "xyz"[:self.dim]
        names = []
        for c in self.contacts:
            names += [f"{c.name}.tangential_force", *(f"{c.name}.t{a}" for a in axes), f"{c.name}.slip",
                      f"{c.name}.sticking", f"{c.name}.slipping"]
        return names + ["friction_loss"]

    def values(self, state: StepState) -> list[float]:
        cons, p = self.cons, self.cons.p
        f = state.tangential
        per_row_force = np.sqrt(np.bincount(cons.tangent_of, weights=f * f, minlength=p))
        per_row_speed = np.sqrt(np.bincount(cons.tangent_of, weights=state.tangential_velocity ** 2, minlength=p))
        on_body = -(f[:, None] * cons.tangent_dirs)   # the friction force on the body, per tangent row
        loaded = state.force > 0.0
        per_row_speed = np.where(loaded, per_row_speed, 0.0)   # sliding: of the rows in contact only
        sticking = loaded & (per_row_force < (1.0 - self.STICK) * cons.friction * state.force)
        values = []
        for c in self.contacts:
            mine = (cons.tangent_of >= c.rows.start) & (cons.tangent_of < c.rows.stop)
            total = on_body[mine].sum(axis=0)
            values += [float(np.linalg.norm(total)), *total.tolist(), float(per_row_speed[c.rows].max()),
                       int(np.count_nonzero(sticking[c.rows])),
                       int(np.count_nonzero(loaded[c.rows] & ~sticking[c.rows]))]
        return values + [state.energy.friction_loss]


class HistoryWriter:
    """``history.csv``: one row for t = 0 and one per step (README.md, "What a run writes").

    With ``path`` None nothing is written: the rows are kept (on rank 0) for :meth:`columns_data`.
    """

    def __init__(self, path: Path | None, cons: Constraints, probes: Probes, comm: MPI.Comm, fields,
                 flush_every: int = 2000, momenta: BodyMomenta | None = None, scheme_energy: bool = False,
                 name: str = "run", reactions: list[str] = (), numerical_loss: bool = False):
        self.cons, self.probes, self.comm, self.fields = cons, probes, comm, fields
        self.name = name
        # FEM_IMPACT_RECORD=DIR: every run also keeps its rows unrounded in DIR (tools/same_histories.py).
        self._recorded: list | None = [] if os.environ.get("FEM_IMPACT_RECORD") and comm.rank == 0 else None
        self.momenta = momenta
        self.rows: list[list[float]] = []   # rows of single steps since the last block or flush
        self._chunks: list[np.ndarray] = []  # kept rows before those, as arrays (blocks of steps)
        self._pending = 0                    # rows kept since the last flush
        self.flush_every = flush_every
        self.columns = ["t"]
        for c in cons.contacts:
            self.columns += [f"{c.name}.gap", f"{c.name}.force", f"{c.name}.impulse"]
        # Body momenta come last, after the energies: columns added later keep the
        # positions of the earlier ones.
        self.columns += probes.columns() + list(ENERGY_COLUMNS) + (momenta.columns() if momenta else [])
        self.scheme_energy = scheme_energy   # a scheme that conserves more than kinetic + strain (central difference)
        if scheme_energy:
            self.columns.append("scheme_energy")
        self.friction = FrictionColumns(cons) if cons.pt else None
        if self.friction is not None:
            self.columns += self.friction.columns()
        self.reactions = list(reactions)   # moving supports (fem/prescribed.py): N, the support's force on the body
        self.columns += self.reactions
        self.numerical_loss = numerical_loss   # a scheme that books its own dissipation (Moreau-Jean, theta > 1/2)
        if numerical_loss:
            self.columns.append("numerical_loss")
        self.law_losses = cons.laws.extra_columns()   # (columns added later keep the earlier ones' places)
        self.columns += self.law_losses
        self._keep = comm.rank == 0
        self.path = path
        self._file = open(path, "w", newline="") if comm.rank == 0 and path is not None else None
        if self._file:
            self._csv = CsvRows(self._file)
            with writing(path):
                self._csv.writerow(self.columns)

    def write(self, state: StepState) -> None:
        row = [state.t]
        for c in self.cons.contacts:
            r = c.rows
            row += [state.gap[r].min(), state.force[r].sum(), state.impulse[r].sum()]
        row += self.probes.values(state, self.comm, self.fields).tolist() if self.probes.names else []
        e = state.energy
        row += [e.kinetic, e.strain, e.external_work, e.damping_loss, e.impact_loss, e.contact_loss, e.error]
        if self.momenta is not None:
            row += self.momenta.values(state).tolist()
        if self.scheme_energy:
            row.append(e.scheme)
        if self.friction is not None:
            row += self.friction.values(state)
        if self.reactions:
            row += state.reaction.tolist()
        if self.numerical_loss:
            row.append(e.numerical_loss)
        row += [e.losses.get(name, 0.0) for name in self.law_losses]
        if self._keep:
            self.rows.append(row)
            self._pending += 1
            if self._file and self._pending >= self.flush_every:
                self.flush()

    def write_block(self, block) -> None:
        """The rows of a block of steps (fem_impact/integrators/blocks.py), column by column."""
        if self.friction is not None or self.reactions:
            raise ValueError("a block of steps carries no friction or support reactions")
        columns = [block.t]
        for c in self.cons.contacts:
            r = c.rows
            columns += [block.gap[:, r].min(axis=1), block.force[:, r].sum(axis=1), block.impulse[:, r].sum(axis=1)]
        if self.probes.names:
            columns.append(self.probes.values_block(block, self.comm, self.fields))
        e = block.energy
        columns += [e.kinetic, e.strain, e.external_work, e.damping_loss, e.impact_loss, e.contact_loss, e.error]
        if self.momenta is not None:
            columns.append(self.momenta.values_block(block))
        if self.scheme_energy:
            columns.append(e.scheme)
        if self.numerical_loss:
            columns.append(e.numerical_loss)
        columns += [np.full(len(block), e.losses.get(name, 0.0)) for name in self.law_losses]
        if self._keep:
            self._keep_rows()
            self._chunks.append(np.column_stack(columns))
            self._pending += len(block)
            if self._file and self._pending >= self.flush_every:
                self.flush()

    def _keep_rows(self) -> None:
        """The single steps' rows into the chunks (before a block's, in order)."""
        if self.rows:
            self._chunks.append(np.array(self.rows, dtype=float).reshape(len(self.rows), len(self.columns)))
            self.rows.clear()

    def _data(self) -> np.ndarray:
        """Every row kept since the last flush, as one array (rows x columns)."""
        self._keep_rows()
        data = np.concatenate(self._chunks) if self._chunks else np.zeros((0, len(self.columns)))
        self._chunks = [data] if len(self._chunks) > 1 else self._chunks
        return data

    def flush(self) -> None:
        if self._file:
            data = self._data()
            if self._recorded is not None:
                self._recorded.append(data)
            with writing(self.path):   # (a failed write names no file)
                self._csv.writerows(data)
            self._chunks.clear()
            self._pending = 0

    def close(self) -> None:
        """Write what is left and close the file; the file is closed even when that write fails."""
        file = self._file
        if file is None:
            self._record([self._data()] if self._keep else None)   # (a run that writes no file keeps its rows)
            return
        try:
            self.flush()
            with writing(self.path):
                file.close()
        except BaseException:
            with contextlib.suppress(OSError):
                file.close()
            raise
        finally:
            self._file = None
        self._record(self._recorded)

    def _record(self, chunks: list | None) -> None:
        """With FEM_IMPACT_RECORD, save the rows under ``$FEM_IMPACT_RECORD/<the pytest test running, if any>/``."""
        if self._recorded is None or chunks is None:
            return
        self._recorded = None   # (once)
        test = os.environ.get("PYTEST_CURRENT_TEST", "no-test").rsplit(" (", 1)[0]
        folder = Path(os.environ["FEM_IMPACT_RECORD"]) / re.sub(r"[^A-Za-z0-9_.-]+", "_", test)
        folder.mkdir(parents=True, exist_ok=True)
        data = np.concatenate(chunks) if chunks else np.zeros((0, len(self.columns)))
        stem = f"{re.sub(r'[^A-Za-z0-9_.-]+', '_', self.name)}-{os.getpid()}-{time.monotonic_ns()}"
        np.savez(folder / f"{stem}.npz", columns=np.array(self.columns), data=data)

    def columns_data(self) -> dict[str, np.ndarray] | None:
        """The kept rows as columns by name (a writer without a file; None on ranks other than 0)."""
        if not self._keep or self.path is not None:
            return None
        data = self._data()
        return {name: data[:, i].copy() for i, name in enumerate(self.columns)}


class CsvRows:
    """history.csv's writer: the header as the csv module writes it, the rows (an array of numbers)
    by :func:`csv_rows`, the same text written faster."""

    def __init__(self, file):
        self.file, self._header = file, csv.writer(file)

    def writerow(self, row) -> None:
        self._header.writerow(row)

    def writerows(self, data: np.ndarray) -> None:
        self.file.write(csv_rows(np.asarray(data, dtype=float)))


def csv_rows(data: np.ndarray) -> str:
    """Rows of numbers as history.csv writes them: 12 significant digits (``{:.12g}``), commas, CRLF
    line ends (the csv module's); one format string a row."""
    if not data.size:
        return ""
    line = ",".join(["%.12g"] * data.shape[1]) + "\r\n"
    return "".join([line % tuple(row) for row in data.tolist()])


class VTKWriter:
    """u, v, a and the contact force on the structure (-P^T F_N) every N steps: ``results.pvd``
    (ASCII VTU pieces, the default), or ``results.xdmf`` + ``results.h5`` (binary, ``xdmf``)."""

    FILES = {"vtu": "results.pvd", "xdmf": "results.xdmf"}

    def __init__(self, folder: Path, model: Model, fields, every: int, last_step: int, form: str = "vtu"):
        self.fields, self.every, self.last_step = fields, every, last_step
        series = dx.XDMFSeries if form == "xdmf" else dx.VTKSeries
        self.series = series(model.comm, folder / self.FILES[form], model.V, ("u", "v", "a", "contact_force"))
        self.frames = 0

    def write(self, state: StepState) -> None:
        if state.step % self.every and state.step != self.last_step:
            return
        self.series.write(state.t, self.fields.frame(state))
        self.frames += 1

    def write_block(self, block) -> None:
        """The frames that fall in a block of steps (the fields' ``frame_in``)."""
        for j in np.flatnonzero((block.step % self.every == 0) | (block.step == self.last_step)):
            self.series.write(float(block.t[j]), self.fields.frame_in(block, int(j)))
            self.frames += 1

    def close(self) -> None:
        # dolfinx 0.5's VTKFile writes its .pvd again when destroyed: drop it now, while its
        # folder (the staging folder) exists, not after that has been moved or removed.
        series, self.series = self.series, None
        if series is not None:
            series.close()


class ImpactLog:
    """``impacts.csv``: one row per impact of a contact, from the step where its rows start to carry an
    impulse to the last step before none does (README.md, "What a run writes").

    ``t`` is the end of the impact's first step (history.csv's time of it), ``impulse`` the contact's
    impulses summed over the impact, ``speed`` the largest normal approach speed (P V) among its rows
    at the step before, ``rows`` how many of its rows carried an impulse.
    """

    COLUMNS = ("t", "contact", "impulse", "speed", "rows")
    __checkpoint__ = ("_open", "_rows", "_approach")   # the impacts under way (a restart continues them)

    def __init__(self, cons: Constraints):
        self.cons = cons
        self.events: list[list] = []
        self._open: dict[str, list] = {}
        self._rows: dict[str, np.ndarray] = {}
        self._approach: np.ndarray | None = None

    def write(self, state: StepState) -> None:
        for c in self.cons.contacts:
            impulse = state.impulse[c.rows]
            carrying = impulse > 0.0
            event = self._open.get(c.name)
            if np.count_nonzero(carrying):
                if event is None:
                    before = self._approach[c.rows] if self._approach is not None else np.zeros(0)
                    event = self._open[c.name] = [state.t, c.name, 0.0, float(max(before.max(initial=0.0), 0.0)), 0]
                    self._rows[c.name] = np.zeros(impulse.size, dtype=bool)
                event[2] += float(impulse.sum())
                self._rows[c.name] |= carrying
            elif event is not None:
                self._finish(c.name)
        self._approach = np.array(state.normal_velocity, copy=True)

    def write_block(self, block) -> None:
        """A block of steps: without impulses it ends the impacts still open (else step by step)."""
        if np.count_nonzero(block.impulse):
            for state in block.states():
                self.write(state)
            return
        for name in list(self._open):
            self._finish(name)
        self._approach = np.array(block.normal_velocity[-1], copy=True)

    def _finish(self, name: str) -> None:
        event = self._open.pop(name)
        event[4] = int(np.count_nonzero(self._rows.pop(name)))
        self.events.append(event)

    def close(self) -> list[list]:
        """Finish the impacts still open at the end of the run; the rows in time order."""
        for name in list(self._open):
            self._finish(name)
        self.events.sort(key=lambda e: e[0])
        return self.events

    def save(self, path: Path) -> None:
        with open(path, "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(self.COLUMNS)
            for t, name, impulse, speed, rows in self.close():
                writer.writerow([f"{t:.12g}", name, f"{impulse:.12g}", f"{speed:.12g}", rows])


class RunStatistics:
    """Extremes and totals over the run for the summary: penetration (rigid rows), compression
    of the elastic stops, energy residual, impulses."""

    # (checkpointed: a restarted run's summary covers the whole run from t = 0, as its energy watch does)
    __checkpoint__ = ("max_penetration", "max_stop_compression", "max_energy_error", "energy_scale", "max_energy",
                      "total_impulse", "step")

    def __init__(self, cons: Constraints):
        self.cons = cons
        self.elastic = cons.compliance > 0.0
        self.max_penetration = 0.0
        self.max_stop_compression = 0.0
        self.max_energy_error = 0.0
        self.energy_scale = 0.0
        self.max_energy = 0.0
        self.total_impulse = {c.name: 0.0 for c in cons.contacts}
        self.step = -1   # the last step whose impulses are counted (a restart writes its checkpoint's step again)

    def write(self, state: StepState) -> None:
        e = state.energy
        if state.gap.size:
            # An elastic stop is meant to be pressed into: that is its compression, not a violation.
            self.max_penetration = max(self.max_penetration, float(-state.gap[~self.elastic].min(initial=0.0)))
            self.max_stop_compression = max(self.max_stop_compression,
                                            float(-state.gap[self.elastic].min(initial=0.0)))
        self.max_energy_error = max(self.max_energy_error, abs(e.error))
        # (with the load's own energy scale, as the energy watch: a body pressed on a stop at rest does no work)
        self.energy_scale = max(self.energy_scale, e.initial, abs(e.external_work), e.load_scale)
        self.max_energy = max(self.max_energy, e.total)
        if state.step > self.step:
            for c in self.cons.contacts:
                self.total_impulse[c.name] += float(state.impulse[c.rows].sum())
            self.step = state.step

    def write_block(self, block) -> None:
        """``write`` for every step of a block at once."""
        e = block.energy
        if block.gap.size:
            gap = block.gap
            if self.elastic.any():
                self.max_stop_compression = max(self.max_stop_compression,
                                                float(-gap[:, self.elastic].min(initial=0.0)))
                gap = gap[:, ~self.elastic]
            self.max_penetration = max(self.max_penetration, float(-gap.min(initial=0.0)))
        self.max_energy_error = max(self.max_energy_error, float(np.abs(e.error).max()))
        self.energy_scale = max(self.energy_scale, float(e.initial.max()), float(np.abs(e.external_work).max()))
        self.max_energy = max(self.max_energy, float(e.total.max()))
        if np.count_nonzero(block.impulse):
            for c in self.cons.contacts:   # (summed in the order step by step would)
                sums = np.concatenate(([self.total_impulse[c.name]], block.impulse[:, c.rows].sum(axis=1)))
                self.total_impulse[c.name] = float(np.cumsum(sums)[-1])
        self.step = int(block.step[-1])
