"""Observers of the time loop: history CSV, ParaView time series, run statistics (the progress bar: progress.py)."""

from __future__ import annotations

import contextlib
import csv
import os
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from ..fem import dolfinx_api as dx
from ..nonsmooth.relation import OPEN, STUCK, Constraints, nodal_states, row_states, tangent_sums
from ..integrators import StepState
from ..fem.model import AXES, Model
from ..fem.probes import Probes  # noqa: F401  (HistoryWriter reads them)
from .outdir.writes import writing
from .progress import Progress, duration  # noqa: F401  (re-exported: pipeline, sweep, cli)

# history.csv's energy columns: (column, EnergyBudget's attribute, meaning). Kinetic and strain energy at
# the step; the work and loss terms cumulative from t = 0 (docs/theory.md s. 9).
ENERGIES = (
    ("kinetic", "kinetic", "kinetic energy"),
    ("strain", "strain", "strain energy"),
    ("external_work", "external_work", "work of the loads (and of moving supports)"),
    ("damping_loss", "damping_loss", "energy the damping dissipated"),
    ("impact_loss", "impact_loss", "energy the impacts' velocity jumps took (Carnot's loss)"),
    ("contact_loss", "contact_loss", "work absorbed by the contact forces"),
    ("energy_error", "error", "the residual of the energy balance"),
)
ENERGY_COLUMNS = tuple(column for column, _, _ in ENERGIES)
NOT_IN_BLOCKS = "a block of steps carries no friction or support reactions"


def energy_columns(cons: Constraints) -> list[str]:
    """The energy columns of a run's history: the budget's, then the loss columns its contact laws
    declare (nonsmooth/laws.py, ``ContactLaw.column``), after every other column."""
    return list(ENERGY_COLUMNS) + cons.laws.extra_columns()


@dataclass
class ColumnGroup:
    """Columns of history.csv filled by one reader: their names, what they hold, and their values at a
    step (``step(state)``: a list) and over a block of steps (``block(block)``: a list of arrays, L or
    L x k; None where a block of steps cannot carry them)."""

    names: list[str]
    meaning: str
    step: Callable[[StepState], list]
    block: Callable[[object], list] | None


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


class FrictionColumns:
    """history.csv's friction columns, after the others: per contact with friction
    ``NAME.tangential_force`` (the magnitude of the summed friction force on the body, the first node
    group of a pair), its components ``NAME.tx``, ``NAME.ty`` (``NAME.tz``) along the global axes,
    ``NAME.slip`` (the largest sliding speed of its rows in contact), ``NAME.sticking`` and ``NAME.slipping``
    (rows carrying a normal impulse, strictly inside the friction cone or on it); then ``friction_loss``.

    The friction forces are the step's whole tangential impulses over dt (with a Carnot correction's, as
    the normal impulse column holds it): the cone a row sticks inside is that of its whole normal
    impulse, ``mu S_N / dt`` (``dt``; without it, ``mu F_N``: the same where no correction acts)."""

    def __init__(self, cons: Constraints, dt: float | None = None):
        self.dt = dt
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
        speed = state.tangential_velocity if state.sliding is None else state.sliding
        columns = self._columns(state.tangential[None], speed[None], row_states(self.cons, state, self.dt)[None],
                                np.array([state.energy.friction_loss]))
        return [column[0].item() for column in columns]

    def values_block(self, block) -> list[np.ndarray]:
        """``values`` at every step of a block of steps (integrators/blocks.py), column by column (L each)."""
        if block.tangential is None or block.tangential_velocity is None:
            raise ValueError(NOT_IN_BLOCKS)
        speed = block.tangential_velocity if block.sliding is None else block.sliding
        return self._columns(block.tangential, speed, row_states(self.cons, block, self.dt),
                             np.broadcast_to(block.energy.friction_loss, block.t.shape))

    def _columns(self, f: np.ndarray, speed: np.ndarray, states: np.ndarray, loss: np.ndarray) -> list[np.ndarray]:
        """The columns over steps (first axis) from the friction forces and sliding speeds (L x pt), the rows'
        states (L x p) and the friction loss (L): one step's the same bits as each step's of a block."""
        cons = self.cons
        per_row_speed = np.sqrt(tangent_sums(cons, speed * speed))
        on_body = -(f[:, :, None] * cons.tangent_dirs)   # the friction force on the body, per tangent row
        loaded, sticking = states != OPEN, states == STUCK
        per_row_speed = np.where(loaded, per_row_speed, 0.0)   # sliding: of the rows in contact only
        columns = []
        for c in self.contacts:
            mine = np.flatnonzero((cons.tangent_of >= c.rows.start) & (cons.tangent_of < c.rows.stop))
            total = np.cumsum(on_body[:, mine], axis=1)[:, -1]   # (added in the rows' order, whatever L)
            magnitude = total[:, 0] * total[:, 0]
            for a in range(1, self.dim):
                magnitude = magnitude + total[:, a] * total[:, a]
            columns += [np.sqrt(magnitude), *total.T, per_row_speed[:, c.rows].max(axis=1),
                        np.count_nonzero(sticking[:, c.rows], axis=1),
                        np.count_nonzero(loaded[:, c.rows] & ~sticking[:, c.rows], axis=1)]
        return columns + [loss]


def carried(values: np.ndarray | None) -> np.ndarray:
    """A block's field that only some scenes' steps carry; a ValueError where this block has none."""
    if values is None:
        raise ValueError(NOT_IN_BLOCKS)
    return values


class HistoryWriter:
    """``history.csv``: one row for t = 0 and one per step (docs/running.md, "What a run writes").

    With ``path`` None nothing is written: the rows are kept (on rank 0) for :meth:`columns_data`.
    """

    def __init__(self, path: Path | None, cons: Constraints, probes: Probes, comm: MPI.Comm, fields,
                 flush_every: int = 2000, momenta: BodyMomenta | None = None, scheme_energy: bool = False,
                 name: str = "run", reactions: list[str] = (), numerical_loss: bool = False, rigid=None,
                 dt: float | None = None):
        self.cons, self.probes, self.comm, self.fields = cons, probes, comm, fields
        self.rigid = rigid   # the rigid bodies of a rigid scene (their state: StepState.bodies)
        self.name = name
        # FEM_IMPACT_RECORD=DIR: every run also keeps its rows unrounded in DIR (tools/same_histories.py).
        self._recorded: list | None = [] if os.environ.get("FEM_IMPACT_RECORD") and comm.rank == 0 else None
        self.momenta = momenta
        self.rows: list[list[float]] = []   # rows of single steps since the last block or flush
        self._chunks: list[np.ndarray] = []  # kept rows before those, as arrays (blocks of steps)
        self._pending = 0                    # rows kept since the last flush
        self.flush_every = flush_every
        self.scheme_energy = scheme_energy   # a scheme that conserves more than kinetic + strain (central difference)
        self.friction = FrictionColumns(cons, dt) if cons.pt else None
        self.reactions = list(reactions)   # moving supports (fem/prescribed.py): N, the support's force on the body
        self.numerical_loss = numerical_loss   # a scheme that books its own dissipation (Moreau-Jean, theta > 1/2)
        # (groups without columns read nothing: no probes, no bodies)
        self.groups = [group for group in self._declare() if group.names]
        self.columns = [name for group in self.groups for name in group.names]
        self._keep = comm.rank == 0
        self.path = path
        self._file = open(path, "w", newline="") if comm.rank == 0 and path is not None else None
        if self._file:
            self._csv = CsvRows(self._file)
            with writing(path):
                self._csv.writerow(self.columns)

    def _declare(self) -> list[ColumnGroup]:
        """history.csv's columns, in their order (INTERFACE: columns added later come after the
        earlier ones, which keep their positions)."""
        probes, comm, fields, momenta = self.probes, self.comm, self.fields, self.momenta

        groups = [ColumnGroup(["t"], "time", lambda state: [state.t], lambda block: [block.t])]
        for c in self.cons.contacts:
            groups.append(ColumnGroup(
                [f"{c.name}.gap", f"{c.name}.force", f"{c.name}.impulse"],
                "per contact: the smallest gap over its rows, the sum of the normal forces F_N at the step, "
                "the sum of the impulses S_N over the step",
                lambda state, r=c.rows: [state.gap[r].min(), state.force[r].sum(), state.impulse[r].sum()],
                lambda block, r=c.rows: [block.gap[:, r].min(axis=1), block.force[:, r].sum(axis=1),
                                         block.impulse[:, r].sum(axis=1)]))
        groups.append(ColumnGroup(
            probes.columns(), "per probe P: displacement P.ux (P.uy, P.uz), then velocity P.vx (...)",
            lambda state: probes.values(state, comm, fields).tolist(),
            lambda block: [probes.values_block(block, comm, fields)]))
        groups.append(ColumnGroup(
            list(ENERGY_COLUMNS), "; ".join(f"{column}: {meaning}" for column, _, meaning in ENERGIES),
            lambda state: [getattr(state.energy, a) for _, a, _ in ENERGIES],
            lambda block: [getattr(block.energy, a) for _, a, _ in ENERGIES]))
        if momenta is not None:   # (after the energies: columns added later keep the earlier ones' positions)
            groups.append(ColumnGroup(momenta.columns(), "per body: its momentum BODY.px (BODY.py, BODY.pz)",
                                      lambda state: momenta.values(state).tolist(),
                                      lambda block: [momenta.values_block(block)]))
        if self.scheme_energy:
            groups.append(ColumnGroup(["scheme_energy"], "the energy a scheme conserves beyond kinetic + strain "
                                                         "(central difference's)",
                                      lambda state: [state.energy.scheme], lambda block: [block.energy.scheme]))
        if self.friction is not None:
            groups.append(ColumnGroup(self.friction.columns(), "per contact with friction (FrictionColumns), then "
                                                               "friction_loss", self.friction.values,
                                      self.friction.values_block))
        if self.reactions:
            groups.append(ColumnGroup(self.reactions, "per moving support: its force on the body (N)",
                                      lambda state: state.reaction.tolist(), None))
        if self.numerical_loss:
            groups.append(ColumnGroup(["numerical_loss"], "the scheme's own dissipation (Moreau-Jean, theta > 1/2)",
                                      lambda state: [state.energy.numerical_loss],
                                      lambda block: [block.energy.numerical_loss]))
        if self.rigid is not None:
            groups.append(ColumnGroup(rigid_columns(self.rigid), "per rigid body: its centre BODY.x (.y, .z), its "
                                      "velocity BODY.vx (...), 2D its angle BODY.angle and its rate BODY.omega, 3D "
                                      "its spin BODY.wx, BODY.wy, BODY.wz (global axes)",
                                      lambda state: state.bodies.tolist(), lambda block: [carried(block.bodies)]))
        laws = self.cons.laws.extra_columns()   # (constant over a block of steps: no contact acts in it)
        groups.append(ColumnGroup(laws, "per contact law with a column of its own: the work absorbed on its "
                                        "rows, less what they store (docs/theory.md s. 2.5)",
                                  lambda state: [state.energy.losses.get(name, 0.0) for name in laws],
                                  lambda block: [np.full(len(block), block.energy.losses.get(name, 0.0))
                                                 for name in laws]))
        return groups

    def write(self, state: StepState) -> None:
        row = []
        for group in self.groups:
            row += group.step(state)
        if self._keep:
            self.rows.append(row)
            self._pending += 1
            if self._file and self._pending >= self.flush_every:
                self.flush()

    def write_block(self, block) -> None:
        """The rows of a block of steps (fem_impact/integrators/blocks.py), column by column."""
        if any(group.block is None for group in self.groups):
            raise ValueError(NOT_IN_BLOCKS)
        columns = []
        for group in self.groups:
            columns += group.block(block)
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


def rigid_columns(bodies) -> list[str]:
    """history.csv's columns of rigid bodies, in the order of ``StepState.bodies``."""
    axes = AXES[:bodies.dim]
    spin = ["angle", "omega"] if bodies.dim == 2 else ["wx", "wy", "wz"]
    return [f"{name}.{what}" for name in bodies.names
            for what in [*axes, *(f"v{a}" for a in axes), *spin]]


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
    """u, v, a, the contact force on the structure (-P^T F_N) and each node's contact state every N
    steps: ``results.pvd`` (ASCII VTU pieces, the default), or ``results.xdmf`` + ``results.h5``
    (binary, ``xdmf``). ``contact_state`` (a scalar): 0 where no row in contact touches the node, 1
    where the rows that do stick, 2 where one slides (or has no friction): the stick and slip regions
    of a contact zone in ParaView and ``fem-impact animate --field state``."""

    FILES = {"vtu": "results.pvd", "xdmf": "results.xdmf"}

    def __init__(self, folder: Path, model: Model, fields, every: int, last_step: int, form: str = "vtu",
                 dt: float | None = None, cons: Constraints | None = None):
        self.fields, self.every, self.last_step, self.dt = fields, every, last_step, dt
        self.cons = cons if cons is not None else fields.cons
        series = dx.XDMFSeries if form == "xdmf" else dx.VTKSeries
        self.series = series(model.comm, folder / self.FILES[form], model.V, ("u", "v", "a", "contact_force"),
                             scalars=("contact_state",))
        self.bs = model.bs
        self.frames = 0

    def _frame(self, state: StepState, frame: dict) -> dict:
        cons = self.cons
        frame["contact_state"] = nodal_states(cons, row_states(cons, state, self.dt), self.bs)
        return frame

    def write(self, state: StepState) -> None:
        if state.step % self.every and state.step != self.last_step:
            return
        self.series.write(state.t, self._frame(state, self.fields.frame(state)))
        self.frames += 1

    def write_block(self, block) -> None:
        """The frames that fall in a block of steps (the fields' ``frame_in``)."""
        for j in np.flatnonzero((block.step % self.every == 0) | (block.step == self.last_step)):
            self.series.write(float(block.t[j]), self._frame(block.state(int(j)), self.fields.frame_in(block, int(j))))
            self.frames += 1

    def close(self) -> None:
        # dolfinx 0.5's VTKFile writes its .pvd again when destroyed: drop it now, while its
        # folder (the staging folder) exists, not after that has been moved or removed.
        series, self.series = self.series, None
        if series is not None:
            series.close()


class ImpactLog:
    """``impacts.csv``: one row per impact of a contact, from the step where its rows start to carry an
    impulse to the last step before none does (docs/running.md, "What a run writes").

    ``t`` is the end of the impact's first step (history.csv's time of it), ``impulse`` the contact's
    impulses summed over the impact, ``speed`` the largest normal approach speed among its rows at the
    step before (relative to a moving obstacle), ``rows`` how many of its rows carried an impulse,
    ``t_contact`` the time its first row closed, found within the step from that row's gap and approach
    speed at the step before (the step's end when no row was approaching), and, with a drive period
    (``output.period``), ``phase``: ``t_contact`` within the period, in [0, 1).
    """

    COLUMNS = ("t", "contact", "impulse", "speed", "rows", "t_contact")
    # the impacts under way (a restart continues them); the rows' gaps and time at the step before
    __checkpoint__ = ("_open", "_rows", "_approach", "_gap", "_t_prev")
    __checkpoint_added__ = ("_gap", "_t_prev")

    def __init__(self, cons: Constraints, period: float | None = None):
        self.cons, self.period = cons, period
        self.events: list[list] = []
        self._open: dict[str, list] = {}
        self._rows: dict[str, np.ndarray] = {}
        self._approach: np.ndarray | None = None
        self._gap: np.ndarray | None = None
        self._t_prev: float | None = None

    def _remember(self, t: float, gap: np.ndarray, normal_velocity: np.ndarray) -> None:
        """The step's gaps and approach speeds relative to the obstacles, for the next step's impacts."""
        relations = self.cons.relations
        moving = relations is not None and relations.time_dependent
        self._approach = np.array(normal_velocity - relations.gap_velocity(t) if moving else normal_velocity,
                                  dtype=float)
        self._gap = np.array(gap, dtype=float)
        self._t_prev = float(t)

    def _contact_time(self, rows: slice, carrying: np.ndarray, t: float) -> float:
        """When the first of the carrying rows closed: gap / approach speed after the step before, within
        the step (a first-order estimate: the row's relative acceleration within the step is left out)."""
        if self._gap is None or self._t_prev is None:
            return float(t)
        gap, speed = self._gap[rows][carrying], self._approach[rows][carrying]
        approaching = speed > 0.0
        if not np.count_nonzero(approaching):
            return float(t)
        when = self._t_prev + np.maximum(gap[approaching], 0.0) / speed[approaching]
        return float(np.clip(when.min(), self._t_prev, t))

    def write(self, state: StepState) -> None:
        if self._t_prev is not None and state.t <= self._t_prev:   # (a restart's first state: written before)
            return
        for c in self.cons.contacts:
            impulse = state.impulse[c.rows]
            carrying = impulse > 0.0
            event = self._open.get(c.name)
            if np.count_nonzero(carrying):
                if event is None:
                    before = self._approach[c.rows] if self._approach is not None else np.zeros(0)
                    event = self._open[c.name] = [state.t, c.name, 0.0, float(max(before.max(initial=0.0), 0.0)), 0,
                                                  self._contact_time(c.rows, carrying, state.t)]
                    self._rows[c.name] = np.zeros(impulse.size, dtype=bool)
                event[2] += float(impulse.sum())
                self._rows[c.name] |= carrying
            elif event is not None:
                self._finish(c.name)
        self._remember(state.t, state.gap, state.normal_velocity)

    def write_block(self, block) -> None:
        """A block of steps: ``write`` on each, by runs of steps with and without impulses (a contact that
        persists through the block is one run); step by step before moving obstacles."""
        relations = self.cons.relations
        if np.count_nonzero(block.impulse) and relations is not None and relations.time_dependent:
            for state in block.states():
                self.write(state)
            return
        for c in self.cons.contacts:
            impulse = block.impulse[:, c.rows]
            carrying = impulse > 0.0
            pushed = carrying.any(axis=1)
            # the runs of steps with and without impulses: [start, end) each, alternating
            edges = np.flatnonzero(np.diff(pushed.astype(np.int8))) + 1
            for start, end in zip(np.concatenate(([0], edges)), np.concatenate((edges, [pushed.size])), strict=True):
                if not pushed[start]:
                    if c.name in self._open:
                        self._finish(c.name)
                    continue
                if c.name not in self._open:   # (opened at the run's first step: the state before it)
                    if start:
                        self._remember(float(block.t[start - 1]), block.gap[start - 1],
                                       block.normal_velocity[start - 1])
                    before = self._approach[c.rows] if self._approach is not None else np.zeros(0)
                    t = float(block.t[start])
                    self._open[c.name] = [t, c.name, 0.0, float(max(before.max(initial=0.0), 0.0)), 0,
                                          self._contact_time(c.rows, carrying[start], t)]
                    self._rows[c.name] = np.zeros(carrying.shape[1], dtype=bool)
                event = self._open[c.name]
                # (summed step after step, as write does)
                event[2] = float(np.cumsum(np.concatenate(([event[2]], impulse[start:end].sum(axis=1))))[-1])
                self._rows[c.name] |= carrying[start:end].any(axis=0)
        self._remember(float(block.t[-1]), block.gap[-1], block.normal_velocity[-1])

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
            writer.writerow(self.COLUMNS + (("phase",) if self.period else ()))
            for t, name, impulse, speed, rows, t_contact in self.close():
                phase = [f"{phase_of(t_contact, self.period):.12g}"] if self.period else []
                writer.writerow([f"{t:.12g}", name, f"{impulse:.12g}", f"{speed:.12g}", rows, f"{t_contact:.12g}",
                                 *phase])


def phase_of(t: float, period: float) -> float:
    """The time ``t`` within a period, in [0, 1) (a time a hair below a period's end is its end: 0)."""
    phase = (t / period) % 1.0
    return 0.0 if phase >= 1.0 - 1e-12 else phase


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
        self.energy_scale = max(self.energy_scale, float(e.initial.max()), float(np.abs(e.external_work).max()),
                                float(np.max(e.load_scale)))
        self.max_energy = max(self.max_energy, float(e.total.max()))
        if np.count_nonzero(block.impulse):
            for c in self.cons.contacts:   # (summed in the order step by step would)
                sums = np.concatenate(([self.total_impulse[c.name]], block.impulse[:, c.rows].sum(axis=1)))
                self.total_impulse[c.name] = float(np.cumsum(sums)[-1])
        self.step = int(block.step[-1])
