"""A modal body beside rigid bodies (``bodies: {NAME: {model: modal, modes: N}}``, docs/theory.md s. 12.6):
the body alone reduced to its lowest modes plus the static correction of the others at its contact rows,
coupled to the rigid bodies through the rows' one problem.

Exact answer: a heavy rigid hammer (1000 times the rod's mass) on a rod held at its far end
(cases/hammer_rod.yaml, 3D, nu = 0) presses it quasi-statically, a mass on the rod's spring EA / L: the
contact lasts pi sqrt(M C), C = L / (E A) the rod's compliance at its end (its inertia adds 1.7e-4 of that,
below a step here), and the hammer leaves at -v0. The modal rod keeps only bending modes (the strike excites
none of them): its static correction alone carries the contact, exactly. Its compliant row takes the gap at
each step's end, which loses a little energy at the closing and opening steps, first order in the step.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

import fem_impact as fi
from conftest import CASES
from fem_impact.errors import CaseError
from test_rigid import assert_continues_exactly, check_budget

E, RHO, A, L = 210e9, 7800.0, 1e-4, 0.2     # the rod's (cases/hammer_rod.yaml, meshes/hammer_rod.py)
MASS_RATIO = 1000.0
M = MASS_RATIO * RHO * A * L                 # the hammer's mass
COMPLIANCE = L / (E * A)                    # the rod's end, m/N
V0 = 1.0


def heavy_hammer(rod: dict, dt: float, t_end: float = 4.5e-3, **more):
    """cases/hammer_rod.yaml with the hammer 1000 times the rod's mass and the rod modelled as ``rod``."""
    changes = {"bodies": {"hammer": {"model": "rigid"}, "rod": rod}, "materials.hammer.rho": 7.8e7 * MASS_RATIO / 1000,
               "solver.dt": dt, "solver.t_end": t_end, "output.every": 1000, "output.vtk": False, **more}
    return fi.load_case(CASES / "hammer_rod.yaml").with_changes(changes)


def contact_time(h) -> float:
    on = np.flatnonzero(h["strike.force"] > 0.0)
    return float(h["t"][on[-1]] - h["t"][on[0]])


@pytest.fixture(scope="module")
def modal_runs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("modal")
    return {dt: fi.run(heavy_hammer({"model": "modal", "modes": 2}, dt), folder / f"dt{dt:g}") for dt in (8e-6, 2e-6)}


def test_a_heavy_hammer_presses_a_modal_rod_as_a_mass_on_its_spring(modal_runs):
    """Contact time pi sqrt(M C) within two steps, the hammer back at -v0 to first order in the step, the
    balance closed with every loss >= 0."""
    expected = np.pi * np.sqrt(M * COMPLIANCE)
    for dt, result in modal_runs.items():
        h = result.history
        assert result.summary["modes"] == 2 and result.summary["modal_body"] == "rod"
        assert abs(contact_time(h) - expected) <= 2.0 * dt
        assert h["strike.force"].max() == pytest.approx(V0 * np.sqrt(M / COMPLIANCE), rel=5e-3)
        check_budget(h, 0.5 * M * V0 ** 2)
        assert h["impact_loss"][-1] == 0.0   # (a compliant row: no Carnot correction, its loss is the contact's)
    coarse, fine = (modal_runs[dt].history for dt in (8e-6, 2e-6))
    peak = [abs(h["strike.force"].max() / (V0 * np.sqrt(M / COMPLIANCE)) - 1.0) for h in (coarse, fine)]
    assert peak[1] < peak[0]
    lost = [1.0 + h["hammer.vx"][-1] / V0 for h in (coarse, fine)]
    assert 0.0 < lost[1] < lost[0] < 2e-2
    assert lost[0] / lost[1] == pytest.approx(4.0, rel=0.1)   # first order in the step
    for h in (coarse, fine):   # what the hammer lost is the contact's loss
        assert 0.5 * M * (V0 ** 2 - h["hammer.vx"][-1] ** 2) == pytest.approx(h["contact_loss"][-1], rel=1e-6)


def test_the_modal_rod_is_the_full_rods_quasi_static_answer(tmp_path, modal_runs):
    """The rod modelled in full at the same step (Courant number 17: its waves, ringing on the quasi-static force
    by a few percent of it, shift the separation by a few steps): the same contact time within 1 %, each
    within 0.6 % of pi sqrt(M C)."""
    full = fi.run(heavy_hammer({"model": "elastic"}, 8e-6), tmp_path / "full").history
    modal = modal_runs[8e-6].history
    assert contact_time(full) == pytest.approx(contact_time(modal), rel=1e-2)
    for h in (full, modal):
        assert contact_time(h) == pytest.approx(np.pi * np.sqrt(M * COMPLIANCE), rel=6e-3)


def test_a_modal_scenes_run_continues_from_its_checkpoint_exactly(tmp_path):
    case = heavy_hammer({"model": "modal", "modes": 2}, 8e-6, t_end=1.6e-3, **{"output.checkpoint_every": 50})
    assert_continues_exactly(case, 3.2e-3, tmp_path)


@pytest.mark.parametrize("bodies, key, says", [
    ({"hammer": {"model": "rigid"}, "rod": {"model": "modal"}}, "bodies.rod", "needs its count of kept modes"),
    ({"hammer": {"model": "rigid", "modes": 3}}, "bodies.hammer.modes", "applies to model: modal only"),
    ({"hammer": {"model": "rigid"}, "rod": {"model": "modal", "modes": 0}}, "bodies.rod.modes", "must be in [1,"),
    ({"hammer": {"model": "modal", "modes": 2}}, "bodies.hammer.model", "beside rigid bodies only"),
], ids=["no modes", "modes on a rigid body", "no mode", "no rigid body"])
def test_a_modal_body_it_cannot_take_is_refused_naming_the_key(bodies, key, says):
    with pytest.raises(CaseError) as err:
        case = fi.load_case(CASES / "hammer_rod.yaml").with_changes({"bodies": bodies, "output.vtk": False})
        fi.run(case)
    assert key in str(err.value) and says in str(err.value)


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
def test_a_modal_scene_agrees_on_two_ranks(tmp_path):
    """The modal rod distributed over 2 ranks (its modes' rows and static columns, its modal state
    replicated), the rigid hammer replicated: the serial history to 1e-10 (the hammer's spin, round-off
    about zero, on 1 rad/s)."""
    from test_mpi import assert_same_history, read_history, run_serial_and_two_ranks

    sets = ["bodies={hammer: {model: rigid}, rod: {model: modal, modes: 2}}", "materials.hammer.rho=7.8e7",
            "solver.dt=8e-6", "solver.t_end=2e-3", "output.vtk=false", "output.every=1"]
    run_serial_and_two_ranks(str(CASES / "hammer_rod.yaml"), tmp_path, [a for s in sets for a in ("--set", s)])
    a, b = read_history(tmp_path / "serial"), read_history(tmp_path / "mpi")
    spins = [name for name in a.dtype.names if name.startswith("hammer_w")]
    for name in spins:
        assert np.abs(a[name] - b[name]).max() <= 1e-10, name
    assert_same_history(a[[n for n in a.dtype.names if n not in spins]], b[[n for n in a.dtype.names
                                                                            if n not in spins]], 1e-10)


def test_an_initial_velocity_the_kept_modes_miss_is_said_with_its_share(caplog):
    """The modal rod's 2 bending modes hold none of an axial initial velocity (the static correction has no
    velocity of its own): the run says so, naming initial.velocity, with the share kept."""
    import logging

    case = heavy_hammer({"model": "modal", "modes": 2}, 8e-6, t_end=8e-5, **{   # (the hammer at rest)
        "parameters": {}, "initial.velocity": [{"body": "rod", "value": [-1.0, 0.0, 0.0]}]})
    with caplog.at_level(logging.WARNING, logger="fem_impact.fem.reduced"):
        result = fi.run(case)
    said = [r.getMessage() for r in caplog.records if "initial.velocity" in r.getMessage()]
    assert len(said) == 1 and "the kept modes hold" in said[0]
    assert result.history["kinetic"][0] <= 1e-12 * 0.5 * RHO * A * L   # (what the reduced model keeps: nothing)


def test_a_free_modal_body_with_too_few_modes_is_told_its_rigid_modes_count():
    """The hammer modal and free (the rod rigid, without its support): 6 rigid-body modes in 3D; keeping 4 is
    refused with the count itself (the first 5 modes computed are all rigid: the count needs more)."""
    data = {"bodies": {"hammer": {"model": "modal", "modes": 4}, "rod": {"model": "rigid"}}, "supports": [],
            "output.vtk": False, "solver.t_end": 1e-5}
    with pytest.raises(CaseError) as err:
        fi.run(fi.load_case(CASES / "hammer_rod.yaml").with_changes(data))
    assert "bodies.hammer.modes" in str(err.value) and "in 6 rigid-body modes" in str(err.value)
    assert "(modes >= 6)" in str(err.value)


def test_a_rigid_block_slides_on_a_modal_slab_and_stops_where_coulomb_says(tmp_path):
    """Friction through the modal body's static part (docs/theory.md s. 8.9 and 12.6): a rigid steel block
    launched at 0.5 m/s on a steel slab held at its base (4 modes), mu = 0.3, under gravity, its 21 rows
    compliant in both directions: every step's friction impulse mu times the normal one while it slides, the
    stop at v0 / (mu g) within 0.2 %, then rest; the friction loss is 1/2 m v0^2 and never falls, the
    balance closes."""
    from test_mixed import G, MU_SLAB, V0_SLAB, slab_scene

    g, mu, v0 = G, MU_SLAB, V0_SLAB
    h = fi.run(fi.Case.from_dict(slab_scene(tmp_path, {"model": "modal", "modes": 4})), tmp_path / "out").history
    t, v = h["t"], h["block.vx"]
    m = 0.2 * 0.05 * 0.01 * 7800.0
    stop = t[np.flatnonzero(v <= 1e-3 * v0)[0]]
    assert stop == pytest.approx(v0 / (mu * g), rel=2e-3)
    assert np.abs(v[t > stop + 0.01]).max() <= 1e-3 * v0
    sliding = np.flatnonzero((v[:-1] > 1e-2 * v0) & (v[1:] > 1e-2 * v0)) + 1
    pushed = sliding[h["face.force"][sliding] > 0.0]   # (the block settles onto the slab in its first steps)
    assert pushed.size > 0.9 * sliding.size
    assert h["face.tangential_force"][pushed] == pytest.approx(mu * h["face.force"][pushed], rel=1e-9)
    scale = 0.5 * m * v0 ** 2
    assert h["friction_loss"][-1] == pytest.approx(scale, rel=1e-3)
    check_budget(h, scale)
