"""Observers reading a block of steps (fem_impact/integrators/blocks.py) in scenes with friction and rigid
bodies: a block stacked from a run's own steps gives history.csv the rows its steps give one by one, to the
bit for the friction and rigid-body columns (also for the block's head); ``block.state(j)`` gives back the
step's friction and bodies; the other observers (statistics, impacts, periods, the fields' frames and the
rows' states) read it as they read its steps; a block without friction or bodies is refused where the scene
has them."""

from __future__ import annotations

import copy
from types import SimpleNamespace

import numpy as np
import pytest

import fem_impact as fi
from conftest import CASES
from fem_impact.app import output
from fem_impact.app.output import NOT_IN_BLOCKS, HistoryWriter, ImpactLog, RunStatistics
from fem_impact.app.periods import PeriodLog
from fem_impact.integrators.blocks import _ENERGY, _OPTIONAL, BlockEnergy, StepBlock
from fem_impact.nonsmooth.relation import row_states, tangent_sums

ROUND_OFF = 1e-12   # of a column's scale: the bodies' momenta (a matrix product over the block)
SCENES = {
    # a rigid slider driven by friction from a modal driver (rigid-body columns, one friction row)
    "vibromotor_modal": (CASES / "vibromotor_modal.yaml", ["output.vtk=false", "solver.t_end=3e-4"]),
    # an elastic block sliding on a floor: nine friction rows, the full model's nodal fields
    "sliding_block": (CASES / "sliding_block.yaml", ["output.vtk=false", "solver.t_end=0.04"]),
}


def recorded(path, overrides) -> SimpleNamespace:
    """Run a case (no files): every state history.csv was given (copies), the writer's arguments, the history;
    and the model (kept: the communicator the run's readers use lives with it)."""
    seen = SimpleNamespace(states=[], writer=None)
    init, write, momenta = HistoryWriter.__init__, HistoryWriter.write, output.BodyMomenta.__init__
    write_block = HistoryWriter.write_block

    def hooked_momenta(self, model, fields):
        momenta(self, model, fields)
        seen.model = model

    def hooked_init(self, *args, **kwargs):
        init(self, *args, **kwargs)
        seen.writer, seen.args, seen.kwargs = self, args, kwargs

    def hooked_write(self, state):
        seen.states.append(copy.deepcopy(state))
        write(self, state)

    def hooked_write_block(self, block):   # (where the run takes its steps in blocks: each of its steps)
        seen.states.extend(copy.deepcopy(state) for state in block.states())
        write_block(self, block)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(HistoryWriter, "__init__", hooked_init)
        patch.setattr(HistoryWriter, "write", hooked_write)
        patch.setattr(HistoryWriter, "write_block", hooked_write_block)
        patch.setattr(output.BodyMomenta, "__init__", hooked_momenta)
        seen.result = fi.run(fi.load_case(path, overrides))
    return seen


def stacked(states, previous) -> StepBlock:
    """The StepBlock of consecutive steps: their arrays stacked over the steps."""
    arrays = {name: np.array([getattr(s, name) for s in states]) for name in
              ("step", "t", "U", "V", "A", "gap", "force", "impulse", "normal_displacement", "normal_velocity")}
    optional = {name: None if getattr(states[0], name) is None else np.array([getattr(s, name) for s in states])
                for name in _OPTIONAL}
    energy = BlockEnergy(**{name: np.array([getattr(s.energy, name) for s in states]) for name in _ENERGY},
                         losses=dict(states[-1].energy.losses))
    return StepBlock(**arrays, energy=energy, previous=previous, **optional)


def writer(run) -> HistoryWriter:
    """A new history writer (no file) as the run's."""
    return HistoryWriter(None, *run.args[1:], **run.kwargs)


def rows_one_by_one(run, states) -> dict:
    w = writer(run)
    for state in states:
        w.write(state)
    return w.columns_data()


def rows_in_block(run, block: StepBlock, head: int | None = None) -> dict:
    w = writer(run)
    w.write(block.previous)
    w.write_block(block if head is None else block.head(head))
    return w.columns_data()


@pytest.fixture(scope="module", params=list(SCENES))
def run(request):
    seen = recorded(*SCENES[request.param])
    seen.block = stacked(seen.states[1:], seen.states[0])
    seen.name = request.param
    return seen


def exact_columns(run) -> list[str]:
    """The friction columns and the rigid bodies' (and every column but the bodies' momenta)."""
    momenta = set(run.writer.momenta.columns())
    return [name for name in run.writer.columns if name not in momenta]


def assert_same(single: dict, block: dict, run) -> None:
    assert list(single) == list(block)
    for name in exact_columns(run):
        assert np.array_equal(single[name], block[name]), name
    for name in run.writer.momenta.columns():
        scale = max(np.abs(single[name]).max(), 1e-300)
        assert np.abs(single[name] - block[name]).max() <= ROUND_OFF * scale, name


def test_the_scenes_carry_friction_and_bodies(run):
    friction = run.writer.friction.columns()
    assert friction and set(friction) <= set(exact_columns(run))
    h = run.result.history
    assert np.count_nonzero(h[friction[0]]) > 0
    assert np.count_nonzero(h[f"{run.writer.friction.contacts[0].name}.slipping"]) > 0
    if run.name == "vibromotor_modal":
        assert run.writer.rigid is not None and run.block.bodies is not None
        assert np.count_nonzero(h["drive.sticking"]) > 0   # (both states met in the steps)
    else:
        assert run.block.sliding is None or run.block.sliding.shape == run.block.tangential.shape


def test_a_blocks_rows_are_its_steps_rows_to_the_bit(run):
    single = rows_one_by_one(run, run.states)
    assert_same(run.result.history, single, run)   # (the states kept are the run's: its own history)
    assert_same(single, rows_in_block(run, run.block), run)


@pytest.mark.parametrize("head", [1, 7])
def test_a_blocks_head_gives_its_first_rows(run, head):
    single = rows_one_by_one(run, run.states[:head + 1])
    assert_same(single, rows_in_block(run, run.block, head), run)


def test_a_step_of_a_block_is_the_state_it_was_made_of(run):
    block = run.block
    for j in (0, len(block) // 2, len(block) - 1):
        state, original = block.state(j), run.states[j + 1]
        for name in ("U", "V", "gap", "force", "impulse", *_OPTIONAL):
            a, b = getattr(state, name), getattr(original, name)
            assert (a is None and b is None) or np.array_equal(a, b), name
    head = block.head(3)
    for name in _OPTIONAL:
        whole, cut = getattr(block, name), getattr(head, name)
        assert (whole is None and cut is None) or np.array_equal(cut, whole[:3]), name
    sliding = StepBlock(**{f: getattr(block, f) for f in block.__dataclass_fields__ if f != "sliding"},
                       sliding=2.0 * block.tangential_velocity)   # (a static part's whole sliding, where set)
    assert np.array_equal(sliding.state(2).sliding, 2.0 * block.tangential_velocity[2])
    assert np.array_equal(sliding.head(3).sliding, 2.0 * block.tangential_velocity[:3])


def test_a_block_without_friction_or_bodies_is_refused_in_a_scene_with_them(run):
    fields = {f: getattr(run.block, f) for f in run.block.__dataclass_fields__}
    for missing in ("tangential", "bodies") if run.writer.rigid is not None else ("tangential",):
        block = StepBlock(**dict(fields, **{missing: None}))
        with pytest.raises(ValueError, match=NOT_IN_BLOCKS):
            writer(run).write_block(block)


def test_the_other_observers_read_a_block_as_its_steps(run):
    cons, fields, block = run.writer.cons, run.writer.fields, run.block
    dt = run.writer.friction.dt
    one, many = (RunStatistics(cons), ImpactLog(cons)), (RunStatistics(cons), ImpactLog(cons))
    for state in run.states:
        for obs in one:
            obs.write(state)
    for obs in many:
        obs.write(run.states[0])
        obs.write_block(block)
    for name in RunStatistics.__checkpoint__:
        assert getattr(one[0], name) == getattr(many[0], name), name
    assert one[1].close() == many[1].close()
    # the fields' frames and the rows' states (VTKWriter's) at each step of the block
    states = row_states(cons, block, dt)
    for j in range(len(block)):
        state = run.states[j + 1]
        assert np.array_equal(states[j], row_states(cons, state, dt))
        frame, framed = fields.frame(state), fields.frame_in(block, j)
        for name, values in frame.items():
            assert np.array_equal(values, framed[name]), name
    # periods: the bodies' momenta through the block (round-off: a matrix product)
    period = run.states[-1].t / 2.5
    logs = [PeriodLog(period, cons.contacts, run.writer.momenta) for _ in range(2)]
    for state in run.states:
        logs[0].write(state)
    logs[1].write(run.states[0])
    logs[1].write_block(block)
    a, b = np.array(logs[0].rows, dtype=float), np.array(logs[1].rows, dtype=float)
    assert a.shape == b.shape and len(a) == 2
    assert np.allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(a).max())


def test_rows_tangent_sums_add_as_bincount_does():
    """Three tangent rows per row in 3D-like order and shuffled: the same bits as np.bincount, step or block."""
    rng = np.random.default_rng(3)
    of = np.repeat(np.arange(5), 3)
    for tangent_of in (of, rng.permutation(of)):
        cons = SimpleNamespace(tangent_of=tangent_of, p=6)
        values = rng.standard_normal((4, tangent_of.size)) * 10.0 ** rng.integers(-8, 8, (4, tangent_of.size))
        block = tangent_sums(cons, values)
        for j in range(4):
            step = np.bincount(tangent_of, weights=values[j], minlength=6)
            assert np.array_equal(block[j], step)
            assert np.array_equal(tangent_sums(cons, values[j]), step)


def before(friction, state) -> list[float]:
    """The friction columns of a step as their reader computed them before blocks carried friction."""
    cons, p = friction.cons, friction.cons.p
    speed = state.tangential_velocity if state.sliding is None else state.sliding
    per_row_speed = np.sqrt(np.bincount(cons.tangent_of, weights=speed ** 2, minlength=p))
    on_body = -(state.tangential[:, None] * cons.tangent_dirs)
    states = row_states(cons, state, friction.dt)
    loaded, sticking = states != 0, states == 1
    per_row_speed = np.where(loaded, per_row_speed, 0.0)
    values = []
    for c in friction.contacts:
        total = on_body[(cons.tangent_of >= c.rows.start) & (cons.tangent_of < c.rows.stop)].sum(axis=0)
        values += [float(np.linalg.norm(total)), *total.tolist(), float(per_row_speed[c.rows].max()),
                   int(np.count_nonzero(sticking[c.rows])), int(np.count_nonzero(loaded[c.rows] & ~sticking[c.rows]))]
    return values + [state.energy.friction_loss]


def test_a_steps_friction_columns_are_those_written_before(run):
    friction = run.writer.friction
    for state in run.states:
        assert friction.values(state) == before(friction, state)


class Slide:
    """Steps of one dof sliding 0.05 m a step (a block's U and V, L x 1)."""

    def __init__(self, steps: int):
        self.U = self.V = 0.05 * np.arange(steps, dtype=float)[:, None]
        self.t = 0.1 * np.arange(steps)

    def __len__(self) -> int:
        return self.t.size

    def state(self, j: int):
        return SimpleNamespace(t=float(self.t[j]), U=self.U[j], V=self.V[j])


def test_a_run_that_keeps_its_rows_stops_at_the_first_step_of_a_block_past_the_limit():
    """The sliding watch (surface contacts) stops a run at the block's step where a row passed its limit,
    as step by step, not where the block ends."""
    from mpi4py import MPI
    from scipy import sparse

    from fem_impact.app.sliding import SlidingWatch
    from fem_impact.errors import SimulationError
    from fem_impact.fem.fields import StateFields

    watch = object.__new__(SlidingWatch)   # (one row, its limit a quarter of a cell of 1 m)
    found = SimpleNamespace(r=1, x=np.zeros((1, 2)), size=np.ones(1))
    relation = SimpleNamespace(sliding_limit=np.array([0.25]), found=found)
    watch.parts = [(SimpleNamespace(name="face"), relation, np.array([0]), sparse.csr_matrix(np.ones((1, 1))))]
    watch.fields, watch.comm, watch.origin, watch.integrator = StateFields(None), MPI.COMM_SELF, {"face": 0.0}, None
    watch.write_block(Slide(5))   # (up to 0.2 m: within the limit)
    with pytest.raises(SimulationError, match=r"slid 0\.3 m along the surface by t = 0\.6 s"):
        watch.write_block(Slide(11))
