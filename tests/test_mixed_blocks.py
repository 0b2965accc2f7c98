"""A modal body's scene stepped many steps at a time (``bodies.NAME.blocks``, fem_impact/rigid/blocks.py,
docs/theory.md s. 12.7): one compiled loop runs the mixed step of rigid bodies beside a modal body whose
static part makes every contact row compliant.

What it must show: the single steps' histories to round-off (not to the bit: the loop sums in its own order),
the physics the single steps are tested for (a rigid block sliding on a modal slab stops where Coulomb's law
says), a restart from a checkpoint inside the blocks, and every scene it cannot take stepped singly, told
where the case asked for blocks.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from test_mixed import MU_SLAB, V0_SLAB, G, slab_scene
from test_rigid import assert_continues_exactly, check_budget

import fem_impact as fi
from conftest import CASES
from fem_impact.errors import CaseError

ENERGY = ("kinetic", "strain", "external_work", "damping_loss", "contact_loss", "friction_loss", "energy_error")


def vibromotor(blocks, t_end: float = 1.5e-3, **more):
    """cases/vibromotor_modal.yaml over 600 steps, its driver's blocks as given."""
    changes = {"bodies.driver.blocks": blocks, "solver.t_end": t_end, "output.vtk": False, **more}
    return fi.load_case(CASES / "vibromotor_modal.yaml").with_changes(changes)


@pytest.fixture(scope="module")
def vibromotor_runs():
    return {blocks: fi.run(vibromotor(blocks)) for blocks in (True, False)}


def test_blocks_give_the_single_steps_history(vibromotor_runs):
    """Every column of the history (the rows, the probe, the slider, the friction, the energies) is the single
    steps' to round-off: within 1e-8 of the column's own scale (the contact row's gap, 1e-17 m in a closed
    contact, to 1e-8 of the probe's displacement), the energies within 1e-10 of the energy scale."""
    blocks, single = (vibromotor_runs[k] for k in (True, False))
    assert blocks.summary["steps_in_blocks"] == blocks.summary["steps"] == 600
    assert single.summary["steps_in_blocks"] == 0
    a, b = blocks.history, single.history
    assert list(a) == list(b)
    scale = max(np.abs(b["external_work"]).max(), np.abs(b["kinetic"] + b["strain"]).max())
    displacement = np.abs(b["tip.uy"]).max()
    for name in b:
        reference = displacement if name.endswith(".gap") else scale if name in ENERGY else np.abs(b[name]).max()
        tolerance = 1e-10 if name in ENERGY else 1e-8
        assert np.abs(a[name] - b[name]).max() <= tolerance * max(reference, 1e-300), name


def test_blocks_keep_the_balance_and_lose_energy(vibromotor_runs):
    """The budget as the single steps book it: the balance closes, friction and damping only take energy,
    E <= E0 + W_ext. (The contact's loss has no sign of its own here: on a compliant row under loads that vary
    the static part's compliance stores and gives back: docs/theory.md s. 5 bounds it for constant loads only;
    single steps book the same.)"""
    h = vibromotor_runs[True].history
    scale = np.abs(h["external_work"]).max()
    assert np.abs(h["energy_error"]).max() <= 1e-10 * scale
    for loss in ("friction_loss", "damping_loss"):
        assert np.diff(h[loss]).min() >= -1e-12 * scale, loss
    assert np.all(h["kinetic"] + h["strain"] <= h["external_work"] + 1e-10 * scale)


def test_switching_blocks_on_a_restart_continues_the_run(tmp_path):
    """How the steps are taken is not the model: a run saved in blocks continues one step at a time (and back),
    the same history to round-off."""
    first = vibromotor(True, 0.75e-3, **{"output.checkpoint_every": 100})
    fi.run(first, tmp_path / "first")
    whole = fi.run(vibromotor(True)).history
    for blocks in (False, True):
        rest = fi.run(vibromotor(blocks), tmp_path / f"rest{blocks}", restart=tmp_path / "first").history
        at = np.searchsorted(whole["t"], rest["t"][0])
        for name in ("slider.vx", "drive.force", "kinetic"):
            assert np.abs(rest[name] - whole[name][at:]).max() <= 1e-8 * np.abs(whole[name]).max(), name


def test_a_rigid_block_slides_on_a_modal_slab_in_blocks_and_stops_where_coulomb_says(tmp_path):
    """The block of test_modal_body's slab scene (21 compliant rows with friction, 4 modes), all its steps in
    blocks: it stops at v0 / (mu g) within 0.2 %, its friction force mu times the normal one while it slides,
    the friction loss 1/2 m v0^2; the single steps' history to round-off."""
    g, mu, v0 = G, MU_SLAB, V0_SLAB
    slab = {"model": "modal", "modes": 4}
    runs = {blocks: fi.run(fi.Case.from_dict(slab_scene(tmp_path, dict(slab, blocks=blocks))))
            for blocks in (True, False)}
    # (a step whose cone problem the loop's Newton method does not finish is the integrator's own: one here)
    assert runs[True].summary["steps_in_blocks"] >= 0.99 * runs[True].summary["steps"]
    h = runs[True].history
    t, v = h["t"], h["block.vx"]
    stop = t[np.flatnonzero(v <= 1e-3 * v0)[0]]
    assert stop == pytest.approx(v0 / (mu * g), rel=2e-3)
    sliding = np.flatnonzero((v[:-1] > 1e-2 * v0) & (v[1:] > 1e-2 * v0)) + 1
    pushed = sliding[h["face.force"][sliding] > 0.0]
    assert pushed.size > 0.9 * sliding.size
    assert h["face.tangential_force"][pushed] == pytest.approx(mu * h["face.force"][pushed], rel=1e-9)
    m = 0.2 * 0.05 * 0.01 * 7800.0
    scale = 0.5 * m * v0 ** 2
    assert h["friction_loss"][-1] == pytest.approx(scale, rel=1e-3)
    check_budget(h, scale)
    single = runs[False].history
    for name in ("block.x", "block.vx", "block.angle", "face.force", "friction_loss"):
        assert np.abs(h[name] - single[name]).max() <= 1e-8 * np.abs(single[name]).max(), name


def test_a_run_in_blocks_continues_from_its_checkpoint_exactly(tmp_path):
    """Checkpoints fall between blocks: the run restarted from the middle one writes the rest as the whole run."""
    assert_continues_exactly(vibromotor(True, 0.75e-3, **{"output.checkpoint_every": 100}), 1.5e-3, tmp_path)


def test_a_scene_the_loop_cannot_take_is_stepped_singly_and_said(caplog):
    """The 3D hammer on its modal rod: 'blocks: true' takes single steps and says why; 'auto' says nothing."""
    changes = {"bodies": {"hammer": {"model": "rigid"}, "rod": {"model": "modal", "modes": 2, "blocks": True}},
               "solver.t_end": 2e-5, "solver.dt": 1e-5, "output.vtk": False}
    with caplog.at_level(logging.WARNING):
        result = fi.run(fi.load_case(CASES / "hammer_rod.yaml").with_changes(changes))
    assert result.summary["steps_in_blocks"] == 0
    assert "bodies.rod.blocks: true" in caplog.text and "3D" in caplog.text


@pytest.mark.parametrize("body, says", [
    ({"model": "rigid", "blocks": True}, "applies to model: modal only"),
    ({"model": "modal", "modes": 4, "blocks": "often"}, "expected true, false or 'auto'"),
], ids=["on a rigid body", "not a flag"])
def test_blocks_where_they_do_not_apply_are_refused_naming_the_key(tmp_path, body, says):
    with pytest.raises(CaseError, match=says) as err:
        fi.Case.from_dict(slab_scene(tmp_path, body if body["model"] == "modal" else None) |
                          {"bodies": {"block": body} if body["model"] == "rigid" else
                           {"block": {"model": "rigid"}, "slab": body}})
    assert "bodies." in str(err.value) and "blocks" in str(err.value)


def test_the_rows_and_loads_on_the_bodies_are_linear_in_cos_and_sin_at_any_angle():
    """The loop's H = H_t + cos H_c + sin H_s, the bodies' share of P U and the loads' moment (docs/theory.md
    s. 12.7) against the single step's own (the rows projected from B(q) and the nodes' displacement) at
    angles far from the meshed one: to round-off."""
    from mpi4py import MPI

    from fem_impact.build import build_system, make_integrator
    from fem_impact.rigid.blocks import MixedBlocks, _dense
    from fem_impact.rigid.bodies import rotation_2d

    case = vibromotor(True)
    system = build_system(case, MPI.COMM_SELF)
    it = make_integrator(case, system.operators, system.rigid, system.elastic, system.reduced)
    it.start(system.U0, system.V0, 0.0)
    mb = MixedBlocks.of(it)
    r = it.rigid
    x = r.bodies.centre + np.array([[1e-3, -2e-4]])
    R = np.zeros(r.U.size)
    for a in (1.3, -2.9, 40.0):
        rot = rotation_2d(a)[None]
        H = _dense(r._rows.project(r.map.columns(rot)))
        mine = mb.Ht.copy()
        mine[:, 2] = np.cos(a) * mb.Hc[:, 0] + np.sin(a) * mb.Hs[:, 0]
        assert np.abs(mine - H).max() <= 1e-12 * np.abs(H).max()
        r.map.displacement(x, rot, r.U)
        rows = r._rows.project_many(r.U)[0]
        ours = mb.Ht[:, :2] @ (x - r.bodies.centre)[0] + np.sin(a) * mb.Hc[:, 0] - (np.cos(a) - 1.0) * mb.Hs[:, 0]
        assert np.abs(ours - rows).max() <= 1e-12 * np.abs(rows).max()
        it.ops.load.evaluate(0.3e-3, R)
        force = r.map.columns(rot).T @ R
        terms = np.array([1.0] + [f.at_time(0.3e-3) for f in mb.functions])
        ours = terms @ mb.Qt
        ours[2] += np.cos(a) * (terms @ mb.Qc)[0] + np.sin(a) * (terms @ mb.Qs)[0]
        assert np.abs(ours - force).max() <= 1e-12 * np.abs(force).max()


def test_a_load_on_the_rigid_body_that_varies_in_blocks_as_in_single_steps():
    """The slider's load and preload varying in time (the loop's F_t, F_c, F_s times their time functions): the
    single steps' history to round-off."""
    loads = [{"nodes": "tip", "force": ["Fx*cos(2*pi*f*t)*(1 - exp(-f*t))", "Fy*sin(2*pi*f*t)*(1 - exp(-f*t))"]},
             {"nodes": "face", "force": ["-FL*(1 + 0.5*sin(2*pi*f*t/3))", "-P*(1 + 0.3*cos(2*pi*f*t/7))"]}]
    a, b = (fi.run(vibromotor(blocks, 0.5e-3, loads=loads)).history for blocks in (True, False))
    for name in ("slider.x", "slider.vx", "slider.vy", "slider.omega", "drive.force", "drive.tangential_force",
                 "external_work", "kinetic"):
        assert np.abs(a[name] - b[name]).max() <= 1e-8 * np.abs(b[name]).max(), name
