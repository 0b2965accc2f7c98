"""The reduced model's steps with impulses in compiled blocks (fem_impact/integrators/kernels.py,
nonsmooth/lcp_kernel.py, docs/theory.md s. 8.8): on rows the static correction makes compliant,
every history column, impacts.csv and the summary as single steps give them, to 1e-10 of each column's
scale; the compiled LCP as ``Delassus.solve``; what the compiled step does not take (Carnot's
correction, elastic stops, moving obstacles) stepped one at a time as before."""

from __future__ import annotations

import numpy as np
import pytest

import fem_impact as fi
from conftest import CASES
from fem_impact.nonsmooth import lcp_kernel
from fem_impact.nonsmooth.lcp import Delassus

TOLERANCE = 1e-10   # of each column's scale: blocks against single steps


def strip(cells=60, steps=1500, **changes):
    """cases/strip_on_stop.yaml on fewer cells: a clamped steel strip (1 x 0.1 m) whose end section rests on a
    stop at zero gap, pressed onto it by a force on the section and a body load that varies (the rows closed
    every step); ten modes with the static correction, which makes every row compliant."""
    case = fi.load_case(CASES / "strip_on_stop.yaml")
    return case.with_changes({"mesh.cells": cells, "solver.t_end": steps * case.solver.dt, "output.vtk": False,
                              **changes})


def both(case, tmp_path=None):
    """(single steps, blocks): the results of the same case."""
    return tuple(fi.run(case.with_changes({"solver.blocks": blocks}),
                        None if tmp_path is None else tmp_path / str(blocks)) for blocks in (False, True))


def assert_same_histories(single, fast, tolerance=TOLERANCE):
    """Every column to ``tolerance`` of its scale: the energies' on the energy scale (the balance residual
    is round-off of the static part's stored energy, 1e-10 of it in either run: checked to 1e-9), a
    vector's components on its largest one's."""
    a, b = single.history, fast.history
    assert list(a) == list(b)
    energy = max(np.abs(a[k]).max() for k in ("kinetic", "strain", "external_work", "contact_loss"))
    for name in a:
        if name == "energy_error":
            assert np.abs(a[name] - b[name]).max() <= 10 * tolerance * energy
            continue
        scale = max(np.abs(a[name]).max(), energy if name in ("damping_loss", "numerical_loss") else 1e-300)
        # A vector's components, and the gaps (zero to round-off in a persisting contact), on the scale of the
        # largest displacement, velocity or momentum component of the probes and bodies.
        for group in ((".gap", ".ux", ".uy"), (".vx", ".vy"), (".px", ".py")):
            if name.endswith(group):
                scale = max(scale, *(np.abs(a[k]).max() for k in a if k.endswith(group[-2:])))
        assert np.abs(a[name] - b[name]).max() <= tolerance * scale, name
    displacement = max(np.abs(a[k]).max() for k in a if k.endswith((".ux", ".uy")))
    for key, scale in (("max_penetration", displacement), ("contact_loss", energy)):   # (round-off where held)
        assert fast.summary[key] == pytest.approx(single.summary[key], abs=tolerance * scale), key
    for key in ("steps", "impacts", "energy_created_at"):
        assert fast.summary[key] == single.summary[key], key
    for name, impulse in single.summary["total_impulse"].items():
        assert fast.summary["total_impulse"][name] == pytest.approx(impulse, rel=tolerance), name


def test_a_strip_pressed_on_its_stop_takes_its_contact_steps_in_blocks():
    single, fast = both(strip())
    assert_same_histories(single, fast)
    h = fast.history
    assert h["stop.force"][1:].min() > 400.0 and fast.summary["impacts"]["stop"] == 1   # held every step
    assert single.summary["steps_in_blocks"] == 0
    assert fast.summary["steps_in_blocks"] >= 0.99 * fast.summary["steps"]
    # the balance closes, every loss has its sign, and no energy is created (E <= E0 + W_ext)
    assert np.abs(h["energy_error"]).max() <= 1e-9 * h["strain"].max()
    assert h["contact_loss"].min() >= -1e-9 * h["strain"].max()
    total = h["kinetic"] + h["strain"]
    assert (total - total[0] - h["external_work"]).max() <= 1e-9 * h["strain"].max()
    assert fast.summary["energy_created_at"] is None


@pytest.mark.parametrize("changes", [
    # lifts off and strikes again (3000 steps: the differences grow over many impacts as round-off does)
    {"loads.1.acceleration": [0.0, "-500*sin(2*pi*40*t)"], "loads.0.force": [0.0, 0.0], "solver.t_end": 0.03},
    {"solver.theta": 0.7, "damping.alpha": 20.0, "damping.beta": 2e-6},           # the scheme's and a damping loss
], ids=["lift-off-and-impacts", "theta-damped"])
def test_contacts_that_open_and_close_are_the_same_in_blocks(tmp_path, changes):
    single, fast = both(strip(**changes), tmp_path)
    assert_same_histories(single, fast)
    h = single.history
    if "loads.1.acceleration" in changes:
        assert single.summary["impacts"]["stop"] >= 2 and (h["stop.force"] == 0.0).any()
        a, b = (np.genfromtxt(tmp_path / str(blocks) / "impacts.csv", delimiter=",", names=True, dtype=None,
                              encoding="utf-8") for blocks in (False, True))
        assert a.shape == b.shape
        for name in ("t", "impulse", "speed", "rows", "t_contact"):
            np.testing.assert_allclose(b[name], a[name], rtol=TOLERANCE, atol=TOLERANCE * np.abs(a[name]).max())
    else:
        assert h["damping_loss"][-1] > 0.0 and h["numerical_loss"][-1] > 0.0
    assert fast.summary["steps_in_blocks"] >= 0.9 * fast.summary["steps"]


@pytest.mark.parametrize("static_correction", [True, False])
def test_an_elastic_stop_takes_its_contact_steps_in_blocks(static_correction):
    """B3's beam (cases/beam_stop.yaml: ten modes, its elastic stop's spring, 1e8 N/m) pressed on its stop: the
    spring's stored energy booked as the scheme books it, with or without the static correction."""
    beam = fi.load_case(CASES / "beam_stop.yaml", ["solver.method=modal", "solver.scheme=moreau_jean",
                                                   "solver.modes=10", "output.vtk=false", "solver.t_end=0.08",
                                                   f"solver.static_correction={str(static_correction).lower()}"])
    single, fast = both(beam)
    assert_same_histories(single, fast)
    h = single.history
    assert h["stop.force"].max() > 100.0 and (h["stop.force"] > 0.0).sum() >= 300   # pressed for many steps
    assert fast.summary["steps_in_blocks"] >= 0.95 * fast.summary["steps"]


def test_what_the_compiled_step_does_not_take_steps_one_at_a_time():
    """A moving obstacle (the rows' gaps move in time) and rigid rows (Carnot's correction: no static
    correction, no spring): the steps with impulses are the integrator's own, the same to round-off."""
    moving = strip(**{"contacts.0.motion": [0.0, "1e-6*sin(2*pi*100*t)"], "solver.t_end": 0.005})
    single, fast = both(moving)
    assert_same_histories(single, fast, 1e-12)
    assert fast.summary["steps_in_blocks"] == 0
    rigid = strip(**{"solver.static_correction": False, "solver.t_end": 0.005})
    single, fast = both(rigid)
    assert_same_histories(single, fast, 1e-12)
    assert single.history["stop.force"].max() > 0.0


@pytest.mark.parametrize("seed", range(6))
def test_the_compiled_lcp_is_delassus_solve(seed):
    """Random symmetric positive definite problems of 1 to 40 rows, from empty, full and random guesses
    (Murty's steps included): the same forces, gaps and active sets as ``Delassus.solve``."""
    rng = np.random.default_rng(seed)
    for n in (1, 2, 5, 11, 21, 40):
        B = rng.standard_normal((n, n + 3))
        A = B @ B.T / n + 1e-3 * np.eye(n)
        ws = (np.full(n, -1, dtype=np.int8), np.zeros((n, n)), np.zeros(n, dtype=np.int64), np.zeros(n), np.zeros(n),
              np.zeros(2 * n))
        for guess in (np.zeros(n, bool), np.ones(n, bool), rng.random(n) < 0.5):
            q = rng.standard_normal(n)
            x_ref, w_ref, active_ref = Delassus(A).solve(q, guess=guess)
            active = guess.copy()
            factored, L, rows, x, w, y = ws
            assert lcp_kernel.solve(A, q, active, factored, L, rows, x, w, y)
            np.testing.assert_array_equal(active, active_ref)
            np.testing.assert_allclose(x, x_ref, rtol=1e-12, atol=1e-13 * np.abs(x_ref).max(initial=1.0))
            np.testing.assert_allclose(w, w_ref, rtol=1e-12, atol=1e-13 * np.abs(q).max())
            assert (x >= 0.0).all() and (w >= 0.0).all() and abs(x @ w) <= 1e-12 * (np.abs(x) @ np.abs(q) + 1e-300)


def test_a_matrix_not_positive_definite_is_left_to_the_solver():
    """The compiled LCP refuses (False) where Cholesky fails; the caller then takes the step itself."""
    A = np.array([[1.0, 2.0], [2.0, 1.0]])
    n = 2
    ws = (np.full(n, -1, dtype=np.int8), np.zeros((n, n)), np.zeros(n, dtype=np.int64), np.zeros(n), np.zeros(n),
          np.zeros(2 * n))
    assert not lcp_kernel.solve(A, np.array([-1.0, -1.0]), np.ones(n, bool), *ws)


def test_periods_count_the_impacts_that_start_in_a_block(tmp_path):
    """periods.csv's impacts per period (an impact in the period of its contact time) as single steps count
    them, with the impulses, when the impacts start inside compiled contact blocks."""
    case = strip(**{"loads.1.acceleration": [0.0, "-500*sin(2*pi*40*t)"], "loads.0.force": [0.0, 0.0],
                    "solver.t_end": 0.05, "output.period": "1/40"})
    single, fast = both(case, tmp_path)
    a, b = (np.genfromtxt(tmp_path / str(blocks) / "periods.csv", delimiter=",", names=True)
            for blocks in (False, True))
    assert a.size == b.size == 2 and a["stopimpacts"].sum() >= 4
    np.testing.assert_array_equal(b["stopimpacts"], a["stopimpacts"])
    np.testing.assert_allclose(b["stopimpulse"], a["stopimpulse"], rtol=TOLERANCE)
    assert fast.summary["steps_in_blocks"] >= 0.9 * fast.summary["steps"]


@pytest.mark.parametrize("blocks", [False, True])
def test_the_balance_closes_at_theta_above_one_half_under_a_varying_load(blocks):
    """The static part's load work with the trapezoidal weights whatever theta (moreau_jean.STATIC_WEIGHT): the
    balance closes to round-off at theta = 0.7 (4.5e-7 of the energy scale with theta's weight), the scheme's
    own dissipation booked (over the run: a step's share with the impulses may be negative), E <= E0 + W_ext."""
    result = strip(**{"solver.theta": 0.7, "solver.t_end": 0.015, "solver.blocks": blocks})
    h = fi.run(result).history
    scale = max(h["strain"].max(), h["kinetic"].max())
    assert np.abs(h["energy_error"]).max() <= 1e-10 * scale
    assert h["numerical_loss"][-1] > 0.0
    total = h["kinetic"] + h["strain"]
    assert (total - total[0] - h["external_work"]).max() <= 1e-10 * scale


def test_a_restart_inside_a_persisting_contact_counts_its_impulse_once(tmp_path):
    """The checkpoint's step is written again to the observers of the continued run: its impulse must not count
    twice in impacts.csv nor in periods.csv."""
    case = strip(**{"solver.t_end": 0.015, "output.period": 0.005, "solver.blocks": True,
                    "output.checkpoint_every": 777})
    fi.run(case, tmp_path / "whole")
    fi.run(case.with_changes({"solver.t_end": 0.00777}), tmp_path / "half")
    fi.run(case, tmp_path / "continued", restart=tmp_path / "half")
    read = lambda run, name: np.genfromtxt(tmp_path / run / name, delimiter=",", names=True)   # noqa: E731
    whole, continued = read("whole", "impacts.csv"), read("continued", "impacts.csv")
    assert float(np.atleast_1d(continued["impulse"])[-1]) == pytest.approx(float(np.atleast_1d(whole["impulse"])[-1]),
                                                                           rel=1e-10)
    whole, continued = read("whole", "periods.csv"), read("continued", "periods.csv")
    np.testing.assert_allclose(continued["stopimpulse"], whole["stopimpulse"][-continued.size:], rtol=1e-10)


def test_a_run_that_blows_up_inside_a_contact_block_stops_in_one_line(tmp_path):
    """The energy watch cuts the block before the step that blows up; that step, single, stops the run (status 3)
    with the message single steps give."""
    from conftest import run_cli

    outs = []
    for blocks in ("true", "false"):
        outs.append(run_cli("run", str(CASES / "strip_on_stop.yaml"), "-q", "-o", str(tmp_path / blocks), "--set",
                            "output.vtk=false", "--set", "mesh.cells=60", "--set", f"solver.blocks={blocks}", "--set",
                            'loads.0.force=[0.0, "-1000 - 1e300*max(0, (t - 0.005)/1e-5)"]'))
    for out in outs:
        assert out.returncode == 3 and "Traceback" not in out.stderr, out.stderr
    assert outs[0].stderr == outs[1].stderr.replace(str(tmp_path / "false"), str(tmp_path / "true"))
