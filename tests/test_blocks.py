"""The reduced model's steps between contacts in blocks (fem_impact/integrators/blocks.py, docs/theory.md
s. 8.8; issue 19): every history column, the summary and the fields as single steps give them, to
round-off, on a one-mode impact oscillator, on B3's beam (ten modes, static correction, elastic stop)
with a time-dependent load and damping, in both schemes; the blocks are taken; what cannot be taken
in blocks (friction, moving supports, no Numba) runs one step at a time; the energy watch and the
history file see the same steps."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import fem_impact as fi
from conftest import CASES, read_history
from fem_impact.errors import SimulationError
from fem_impact.mechanics.energy import EnergyBudget, EnergyWatch

ROUND_OFF = 1e-12   # of each column's scale


def oscillator(scheme="moreau_jean", periods=20, per_period=150, **solver):
    """A clamped-free rod (first mode 0.25 Hz) reduced to one mode, driven at its tip at 0.5 Hz onto a
    rigid stop at zero gap (restitution 0.8): one impact a period once settled."""
    return fi.Case.from_dict({
        "name": "oscillator",
        "mesh": {"shape": "bar", "dim": 1, "cells": 20},
        "material": {"E": 1.0, "rho": 1.0, "nu": 0.0},
        "supports": [{"nodes": "left", "fix": ["x"]}],
        "loads": [{"nodes": "right", "force": ["0.1*sin(2*pi*0.5*t)"]}],
        "contacts": [{"name": "stop", "type": "obstacle", "nodes": "right", "normal": [1.0], "gap": 0.0,
                      "restitution": 0.8}],
        "solver": {"method": "modal", "scheme": scheme, "modes": 1, "static_correction": False,
                   "dt": 2.0 / per_period, "t_end": 2.0 * periods, **solver},   # (blocks: auto)
        "output": {"vtk": False, "probes": {"tip": [1.0], "middle": [0.5]}},
    })


def beam(scheme, **changes):
    """B3 (cases/beam_stop.yaml) with ten modes and the static correction: its elastic stop on the tip."""
    case = fi.load_case(CASES / "beam_stop.yaml")
    return case.with_changes({"solver.method": "modal", "solver.scheme": scheme, "solver.modes": 10,
                              "output.vtk": False, **changes})


def both(case):
    """(single steps, blocks): the results of the same case."""
    return fi.run(case.with_changes({"solver.blocks": False})), fi.run(case.with_changes({"solver.blocks": True}))


def assert_same_histories(single, fast, tolerance=ROUND_OFF):
    a, b = single.history, fast.history
    assert list(a) == list(b)
    energy = max(np.abs(a["kinetic"]).max(), np.abs(a["strain"]).max(), np.abs(a["external_work"]).max())
    for name in a:
        # (the balance residual is round-off itself: on the scale of the energy)
        scale = energy if name == "energy_error" else max(np.abs(a[name]).max(), 1e-300)
        assert np.abs(a[name] - b[name]).max() <= tolerance * scale, name
    for key in ("steps", "impacts", "max_penetration", "max_stop_compression", "total_impulse", "impact_loss",
                "contact_loss", "energy_created_at"):
        if isinstance(single.summary[key], float) or key == "total_impulse":
            assert fast.summary[key] == pytest.approx(single.summary[key], rel=tolerance, abs=1e-300), key
        else:
            assert fast.summary[key] == single.summary[key], key


@pytest.mark.parametrize("scheme, solver", [("moreau_jean", {}), ("moreau_jean", {"level": "velocity"}),
                                            ("newmark", {})])
def test_the_one_mode_impact_oscillator_is_the_same_in_blocks(scheme, solver):
    single, fast = both(oscillator(scheme, **solver))
    assert_same_histories(single, fast)
    h = single.history
    assert single.summary["impacts"]["stop"] >= 15 and h["stop.impulse"].max() > 0.0   # impacts
    assert single.summary["steps_in_blocks"] == single.summary["blocks"] == 0
    # most steps in blocks: all but the impacts and the steps after them (and the first held ones)
    assert fast.summary["steps_in_blocks"] >= 0.9 * fast.summary["steps"]
    assert fast.summary["blocks"] >= single.summary["impacts"]["stop"] - 1


@pytest.mark.parametrize("scheme", ["moreau_jean", "newmark"])
@pytest.mark.parametrize("changes", [
    {},                                                                             # B3 as it is
    {"loads.0.force": [0.0, "-1000*(1 - cos(2*pi*30*t))"], "damping.alpha": 2.0,    # a varying load, damping
     "damping.beta": 1e-5},
], ids=["step-load", "varying-load-damped"])
def test_the_beam_with_static_correction_and_elastic_stop_is_the_same_in_blocks(scheme, changes):
    """Newmark's contact steps are single steps (the same to round-off); Moreau-Jean's go in compiled blocks too
    (tests/test_contact_blocks.py: the same to 1e-10, not to the bit)."""
    single, fast = both(beam(scheme, **changes))
    assert_same_histories(single, fast, ROUND_OFF if scheme == "newmark" else 1e-10)
    h = single.history
    assert h["stop.force"].max() > 100.0 and h["stop.gap"].min() < 0.0   # the stop was reached and pressed
    assert fast.summary["steps_in_blocks"] >= 300
    if changes:
        assert h["damping_loss"][-1] > 0.0 and np.ptp(h["external_work"]) > 0.0


def test_observers_without_blocks_get_every_step():
    """An observer that only has ``write`` gets each step of a block as a StepState, in order, with the
    values single steps give."""
    from fem_impact.build import build_system, make_integrator
    from fem_impact.integrators import integrate
    from fem_impact.integrators.blocks import BlockStepper
    from mpi4py import MPI

    case = oscillator(periods=6)
    system = build_system(case, MPI.COMM_SELF)

    class Record:
        def __init__(self):
            self.rows = []

        def write(self, state):
            self.rows.append([state.step, state.t, *state.U, *state.V, *state.A, *state.gap, *state.impulse,
                              state.energy.kinetic, state.energy.strain, state.energy.external_work])

    runs = {}
    for name in ("single", "blocks"):
        integrator = make_integrator(case, system.operators)
        stepper = BlockStepper.of(integrator) if name == "blocks" else None
        record = Record()
        integrate(integrator, system.U0, system.V0, case.solver.t_end, [record], blocks=stepper)
        runs[name] = np.array(record.rows)
        if stepper is not None:
            assert stepper.steps > 0.8 * len(record.rows)
    np.testing.assert_array_equal(runs["blocks"][:, 0], np.arange(len(runs["single"])))
    scale = np.abs(runs["single"]).max(axis=0)
    assert np.all(np.abs(runs["blocks"] - runs["single"]) <= ROUND_OFF * np.maximum(scale, 1e-300))


def test_blocks_end_where_an_observer_reads_the_integrator():
    """An observer that reads the integrator's own state at given steps (a checkpoint) says which
    (``next_stop``): no block runs past them, and there the integrator holds that step's state."""
    from fem_impact.build import build_system, make_integrator
    from fem_impact.integrators import integrate
    from fem_impact.integrators.blocks import BlockStepper
    from mpi4py import MPI

    case = oscillator(periods=6)
    system = build_system(case, MPI.COMM_SELF)
    integrator = make_integrator(case, system.operators)
    stepper = BlockStepper.of(integrator)

    class Checkpoint:
        every, seen = 100, {}

        def next_stop(self, step):
            return (step // self.every + 1) * self.every

        def write(self, state):
            if state.step % self.every == 0:
                self.seen[state.step] = (state.U.copy(), integrator.state.step, integrator.U.copy())

        def write_block(self, block):
            if block.step[-1] % self.every == 0:
                self.write(block.state(len(block) - 1))

    check = Checkpoint()
    integrate(integrator, system.U0, system.V0, case.solver.t_end, [check], blocks=stepper)
    assert sorted(check.seen) == list(range(0, 901, 100)) and stepper.steps > 700
    for step, (U, integrator_step, integrator_U) in check.seen.items():
        assert integrator_step == step and np.array_equal(U, integrator_U)


def test_files_and_fields_are_the_same_in_blocks(tmp_path):
    """history.csv, summary.json and the xdmf frames (u, v, a with the static part's rate) of B3 with a
    probe, written by the command's path."""
    case = beam("moreau_jean", **{"output.vtk": True, "output.format": "xdmf", "output.every": 100})
    runs = {name: fi.run(case.with_changes({"solver.blocks": name == "blocks"}), tmp_path / name)
            for name in ("single", "blocks")}
    a, b = (read_history(tmp_path / name) for name in ("single", "blocks"))
    assert a.dtype.names == b.dtype.names and a.shape == b.shape
    energy = max(np.abs(a["kinetic"]).max(), np.abs(a["strain"]).max())
    for name in a.dtype.names:
        scale = energy if name == "energy_error" else max(np.abs(a[name]).max(), 1e-300)
        assert np.abs(a[name] - b[name]).max() <= 1e-11 * scale, name   # (12 digits in the file)
    fa, fb = runs["single"].fields(), runs["blocks"].fields()
    np.testing.assert_array_equal(fa.t, fb.t)
    assert fa.t.size == 17 and runs["blocks"].summary["vtk_frames"] == 17
    for name in ("u", "v", "a", "contact_force"):
        scale = np.abs(fa.values[name]).max()
        assert np.abs(fa.values[name] - fb.values[name]).max() <= ROUND_OFF * scale, name
    assert runs["blocks"].summary["steps_in_blocks"] > 0


def test_history_rows_are_formatted_as_before():
    """csv_rows writes what csv.writer wrote of f"{v:.12g}" for every value, ints included."""
    import csv
    import io

    from fem_impact.app.output import csv_rows

    rng = np.random.default_rng(1)
    values = np.concatenate([rng.standard_normal(40) * 10.0 ** rng.integers(-300, 300, 40),
                             [0.0, -0.0, 1.0, 3.0, 1e16, 123456789012.5, np.inf, -np.inf, np.nan, 1e-320]])
    data = values.reshape(5, 10)
    before = io.StringIO(newline="")
    csv.writer(before).writerows([[f"{v:.12g}" for v in row] for row in data.tolist()])
    assert csv_rows(data) == before.getvalue()
    before = io.StringIO(newline="")
    csv.writer(before).writerows([[3, 0, 12]])
    assert csv_rows(np.array([[3, 0, 12]], dtype=float)) == before.getvalue()


def budget(kinetic, strain, work, **terms):
    n = len(kinetic)
    fields = dict(kinetic=np.asarray(kinetic, float), strain=np.asarray(strain, float),
                  external_work=np.asarray(work, float))
    for name in ("damping_loss", "impact_loss", "contact_loss", "initial", "scheme", "load_scale", "friction_loss"):
        fields[name] = np.broadcast_to(np.asarray(terms.get(name, 0.0), float), (n,)).copy()
    from fem_impact.integrators.blocks import BlockEnergy

    return BlockEnergy(**fields)


@pytest.mark.parametrize("stop", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_the_energy_watch_sees_a_block_as_its_steps(seed, stop):
    """check_block updates the watch as check() on each step would, and stops before the step on which
    check() would stop the run (energy created with stop_on_energy_gain, blow-up, not finite)."""
    from types import SimpleNamespace

    from fem_impact.integrators.blocks import StepBlock

    rng = np.random.default_rng(seed)
    n = 40
    kinetic = np.abs(rng.normal(1.0, 0.3, n))
    kinetic[rng.integers(0, n)] *= 1.0 + rng.choice([1e-7, 1e-5, 1e-3])        # energy created (or round-off)
    if seed % 3 == 1:
        kinetic[rng.integers(n // 2, n)] = 300.0                              # a blow-up
    if seed % 3 == 2:
        kinetic[rng.integers(n // 2, n)] = np.nan                             # not finite
    strain = np.abs(rng.normal(0.5, 0.1, n))
    work = np.cumsum(np.abs(rng.normal(0.01, 0.01, n)))
    initial = 1.5 if seed % 2 else 0.0
    e = budget(kinetic, strain, work, initial=initial, damping_loss=np.cumsum(np.abs(rng.normal(0, 0.01, n))),
               load_scale=np.abs(rng.normal(0.0, 1e-3, n)))
    t = np.arange(1, n + 1) * 0.1
    zeros = np.zeros((n, 0))
    block = StepBlock(np.arange(1, n + 1), t, zeros, zeros, zeros, zeros, zeros, zeros, e, zeros, zeros, None)
    sequential, at_once = EnergyWatch(stop), EnergyWatch(stop)
    for watch in (sequential, at_once):
        watch.check(SimpleNamespace(t=0.0, step=0, energy=EnergyBudget(kinetic=1.0, strain=0.2, initial=initial)))
    passed = 0
    try:
        for j in range(n):
            sequential.check(block.state(j))
            passed += 1
    except SimulationError:
        pass
    assert at_once.check_block(block) == passed
    if passed < n:   # the loop then takes that step alone: check() stops the run there
        with pytest.raises(SimulationError):
            at_once.check(block.state(passed))
    assert vars(at_once) == pytest.approx(vars(sequential), rel=1e-15, nan_ok=True)


def test_friction_and_moving_supports_step_one_at_a_time():
    """Friction (a cone problem every step) and moving supports (the run seen through a view of the
    integrator) are not taken in blocks: the summary says 0 steps."""
    data = {"name": "pushed", "mesh": {"shape": "bar", "dim": 1, "cells": 40},
            "material": {"E": 1.0, "rho": 1.0, "nu": 0.0},
            "supports": [{"nodes": "left", "fix": ["x"], "displacement": ["0.01*t"]}],
            "contacts": [{"name": "wall", "type": "obstacle", "nodes": "right", "normal": [1.0], "gap": 0.1}],
            "solver": {"method": "modal", "modes": 8, "dt": 0.0125, "t_end": 1.0}, "output": {"vtk": False}}
    result = fi.run(fi.Case.from_dict(data))
    assert result.summary["steps_in_blocks"] == 0 and result.summary["steps"] == 80
    sliding = fi.load_case(CASES / "sliding_block.yaml")
    friction = fi.run(sliding.with_changes({"solver.method": "modal", "solver.modes": 30,
                                            "solver.static_correction": False, "solver.t_end": 0.05,
                                            "output.vtk": False}))
    assert friction.summary["steps_in_blocks"] == 0 and friction.summary["friction_loss"] >= 0.0


def test_without_numba_the_steps_are_taken_one_at_a_time(monkeypatch):
    import fem_impact.integrators

    monkeypatch.setitem(sys.modules, "fem_impact.integrators.kernels", None)   # (as if Numba could not be imported)
    monkeypatch.delattr(fem_impact.integrators, "kernels", raising=False)
    result = fi.run(oscillator(periods=2, blocks=True))
    assert result.summary["steps_in_blocks"] == 0 and result.summary["steps"] == 300


def test_blocks_auto_takes_them_from_4000_steps():
    """``blocks: auto`` (the default): a short run one step at a time (loading the compiled steps would
    cost more than they save), a run of 4000 steps or more in blocks."""
    short, long = fi.run(oscillator(periods=2)), fi.run(oscillator(periods=27))   # 300 and 4050 steps
    assert short.summary["steps_in_blocks"] == 0 and long.summary["steps_in_blocks"] > 3500
    with pytest.raises(fi.CaseError, match="expected true, false or 'auto'"):
        oscillator().with_changes({"solver.blocks": "often"})


def test_a_load_that_overflows_stops_the_run_at_the_same_step():
    """The block stops before the first step whose load is not finite; the single step there stops the
    run with the load's message."""
    case = oscillator(periods=2).with_changes({"loads.0.force": ["0.1*sin(pi*t)*sqrt(0.95 - t)"]})   # nan after 0.95
    messages = []
    for blocks in (False, True):
        with pytest.raises(SimulationError) as error:
            fi.run(case.with_changes({"solver.blocks": blocks}))
        messages.append(str(error.value))
    assert messages[0] == messages[1] and "is no longer finite at t = 0.96 (nan)" in messages[0]
