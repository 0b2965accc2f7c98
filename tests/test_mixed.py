"""Scenes mixing rigid and elastic bodies (docs/theory.md s. 12.5), against exact answers: a rigid hammer
striking an elastic rod (cases/hammer_rod.yaml: the contact force Z v0 exp(-Z t / M) until the wave
returns, first order in the mesh), a rigid block sliding on an elastic slab (Coulomb's law on the shared
rows, the stop where mu g says), a rigid scene continued from its checkpoint; the balance closes, the
losses are >= 0, E <= E0 + W_ext.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import fem_impact as fi
from conftest import CASES, ROOT
from test_rigid import assert_continues_exactly, check_budget

HAMMER_ROD = CASES / "hammer_rod.yaml"
E, RHO, A, L = 210e9, 7800.0, 1e-4, 0.2     # the rod's (cases/hammer_rod.yaml, meshes/hammer_rod.py)
C = np.sqrt(E / RHO)
Z = RHO * C * A                             # the rod's impedance, kg/s
M, V0, GAP = RHO * A * L, 1.0, 1e-5         # the hammer's mass (the rod's), speed and distance
T0 = GAP / V0                               # the contact's start
RETURN = 2.0 * L / C                        # the wave's return to the struck end


def _mesh_script():
    spec = importlib.util.spec_from_file_location("hammer_rod_mesh", ROOT / "meshes" / "hammer_rod.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def strike(folder, cells: int = 80, dt: float = 4e-7):
    overrides = ["output.vtk=false", f"solver.dt={dt}", "solver.t_end=1e-4"]
    if cells != 80:
        mesh = _mesh_script().build(folder / f"hammer_rod_{cells}.msh", cells=cells)
        overrides.append(f"mesh.file={mesh}")
    return fi.run(fi.load_case(HAMMER_ROD, overrides), folder / "run")


def force_error(h, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Each step's contact force against the exact one's mean over the step, in units of Z v0; and the
    steps' times from the contact's start."""
    s = h["t"] - T0
    a, b = np.maximum(s - dt, 0.0), np.maximum(s, 0.0)
    exact = M * V0 * (np.exp(-Z * a / M) - np.exp(-Z * b / M)) / dt
    return np.abs(h["strike.force"] - exact) / (Z * V0), s


@pytest.fixture(scope="module")
def hammer(tmp_path_factory):
    return strike(tmp_path_factory.mktemp("hammer"))


def test_the_hammers_mass_is_the_one_its_mesh_and_density_give(hammer):
    body = hammer.summary["rigid_bodies"]["hammer"]
    assert body["mass"] == pytest.approx(M, rel=1e-12)
    assert body["centre"] == pytest.approx([-GAP - 0.01, 0.005, 0.005], rel=1e-12)


def test_a_rigid_hammer_on_an_elastic_rod_sends_the_impedance_force_until_the_wave_returns(hammer):
    """The rod's end takes the hammer's speed: force Z v0 exp(-Z t / M), within 2 % of Z v0 at every step
    from six cell transits h / c after the contact's start until six before the reflected wave returns
    (the discrete wave's front spreads over a few cells: the force there is the mesh's, not the
    continuum's); the impulse until then within 1 % of M v0 (1 - exp(-2 Z L / (c M)))."""
    h, dt = hammer.history, 4e-7
    error, s = force_error(h, dt)
    transit = L / 80 / C
    inside = (s > 6 * transit) & (s <= RETURN - 6 * transit)
    assert error[inside].max() <= 0.02
    assert h["strike.force"][s <= 0.0].max() == 0.0   # (nothing before the gap closes)
    impulse = h["strike.impulse"][s <= RETURN].sum()
    assert impulse == pytest.approx(M * V0 * (1.0 - np.exp(-Z * RETURN / M)), rel=0.01)
    check_budget(h, 0.5 * M * V0 ** 2)
    assert h["contact_loss"][-1] > 0.0   # (e = 0 on the struck nodes: the first steps lose a little)


@pytest.mark.slow
def test_the_hammers_force_converges_at_first_order_in_the_mesh(tmp_path, hammer):
    """On a fixed time window (5 us after the contact to 5 us before the wave returns), the largest error
    of the step force falls with the cell size and the step (Courant number kept) at order one."""
    coarse, fine = hammer.history, strike(tmp_path, cells=160, dt=2e-7).history
    errors = []
    for h, dt in ((coarse, 4e-7), (fine, 2e-7)):
        error, s = force_error(h, dt)
        errors.append(error[(s > 5e-6) & (s <= RETURN - 5e-6)].max())
    assert errors[1] <= errors[0] / 1.7, errors
    check_budget(fine, 0.5 * M * V0 ** 2)


def test_a_mixed_scenes_run_continues_from_its_checkpoint_exactly(tmp_path):
    case = fi.load_case(HAMMER_ROD, ["output.vtk=false", "solver.t_end=3e-5", "output.checkpoint_every=10"])
    assert_continues_exactly(case, 6e-5, tmp_path)


def slab_mesh(folder):
    """meshes/block_on_slab.py's slab and block."""
    spec = importlib.util.spec_from_file_location("block_on_slab", ROOT / "meshes" / "block_on_slab.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.build(folder / "slab.msh")


G, MU_SLAB, V0_SLAB = 9.81, 0.3, 0.5


def slab_scene(folder, slab: dict | None = None) -> dict:
    """A rigid steel block launched at V0_SLAB on a steel slab held at its base (``slab``: its model, default
    elastic), mu = MU_SLAB, under gravity, the faces' 21 node pairs: the case as a dict."""
    return {"name": "slab", "mesh": {"file": str(slab_mesh(folder))},
            "material": {"E": 210e9, "rho": 7800.0, "nu": 0.3, "area": 0.01},
            "bodies": {"block": {"model": "rigid"}, **({"slab": slab} if slab else {})},
            "initial": {"velocity": [{"body": "block", "value": [V0_SLAB, 0.0]}]},
            "supports": [{"nodes": "base", "fix": "all"}],
            "loads": [{"body": b, "acceleration": [0.0, -G]} for b in ("slab", "block")],
            "contacts": [{"name": "face", "type": "pair", "nodes": ["top", "bottom"], "normal": [0.0, 1.0],
                          "restitution": 0.0, "friction": MU_SLAB}],
            "solver": {"dt": 2e-4, "t_end": 0.25}, "output": {"vtk": False}}


def test_a_rigid_block_slides_on_an_elastic_slab_and_stops_where_coulomb_says(tmp_path):
    """A rigid steel block launched at 0.5 m/s on a steel slab held at its base, mu = 0.3, under gravity,
    one row between the faces' mean motions (coupling: mean): while it slides every step's friction
    impulse is mu times the normal one, against the motion; it stops near v0 / (mu g) (the slab's
    vibration under the block makes the normal force ring about m g), and rests; the balance closes."""
    g, mu, v0 = G, MU_SLAB, V0_SLAB
    h = fi.run(fi.Case.from_dict(slab_scene(tmp_path)), tmp_path / "out").history
    t, v = h["t"], h["block.vx"]
    m = 0.2 * 0.05 * 0.01 * 7800.0
    stop = t[np.flatnonzero(v <= 1e-3 * v0)[0]]
    assert stop == pytest.approx(v0 / (mu * g), rel=0.01)
    assert np.abs(v[t > stop + 0.01]).max() <= 1e-3 * v0   # (it rides the slab's ringing surface)
    sliding = np.flatnonzero((v[:-1] > 1e-2 * v0) & (v[1:] > 1e-2 * v0)) + 1
    pushed = sliding[h["face.force"][sliding] > 0.0]
    assert pushed.size > 0.9 * sliding.size
    assert h["face.tangential_force"][pushed] == pytest.approx(mu * h["face.force"][pushed], rel=1e-9)
    assert np.all(np.diff(v[:sliding[-1] + 1]) <= 1e-12)
    assert np.abs(h["block.angle"]).max() <= 1e-5
    scale = 0.5 * m * v0 ** 2
    # Coulomb's law acts on the velocity at the step's end, the work is booked on the mean velocity: a row
    # that sticks on a ringing elastic surface may book a step of negative work, within 1e-6 of the scale
    # (docs/theory.md s. 12.5); the balance closes and the loss only grows beyond that.
    friction = h["friction_loss"]
    assert np.diff(friction).min() >= -1e-6 * scale and friction[-1] == pytest.approx(scale, rel=0.01)
    check_budget({k: v for k, v in h.items() if k != "friction_loss"}, scale)


def plot(outdir: Path, png: Path) -> Path:
    """The hammer's contact force against Z v0 exp(-Z t / M), and the hammer's speed, from a run of
    cases/hammer_rod.yaml (its history.csv)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from fem_impact.app.plots import history_columns

    h = history_columns(outdir)
    s = (h["t"] - T0) * 1e6
    exact = np.where(s >= 0.0, Z * V0 * np.exp(-Z * np.maximum(s, 0.0) * 1e-6 / M), 0.0)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    top.plot(s, h["strike.force"], lw=1.0, label="fem-impact (a step's force)")
    top.plot(s[s <= RETURN * 1e6], exact[s <= RETURN * 1e6], "k--", lw=1.0, label="Z v0 exp(-Z t / M) until 2 L / c")
    top.axvline(RETURN * 1e6, color="grey", lw=0.5)
    top.set_ylabel("contact force (N)")
    top.legend()
    bottom.plot(s, h["hammer.vx"], lw=1.0)
    bottom.set_ylabel("hammer speed (m/s)")
    bottom.set_xlabel("time from the contact (us)")
    fig.suptitle("A rigid hammer strikes an elastic rod (cases/hammer_rod.yaml)")
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return png


def main(argv=None) -> None:
    import argparse

    parser = argparse.ArgumentParser(description="The figure of a hammer_rod run.")
    parser.add_argument("outdir", type=Path, help="a run's output folder (history.csv)")
    parser.add_argument("--plot", type=Path, metavar="PNG", required=True, help="where to draw the force")
    args = parser.parse_args(argv)
    print(f"wrote {plot(args.outdir, args.plot)}")


if __name__ == "__main__":
    main()


def test_a_spinning_hammer_strikes_as_one_that_does_not_spin(tmp_path, hammer):
    """The hammer spun at 300 rad/s about its own axis (x, a principal axis through its centre) and struck
    head on, frictionless: the spin moves no face node along x and the four rows share the force equally, so
    the strike is the one without spin step by step (the 3D step's spin iteration with the rod's share of the
    rows) while the spin stays 300 rad/s; the balance closes, E <= E0 + W_ext."""
    w, (cy, cz) = 300.0, (0.005, 0.005)
    velocity = [{"body": "hammer", "value": [str(V0), f"-{w}*(z - {cz})", f"{w}*(y - {cy})"]}]
    spun = fi.run(fi.load_case(HAMMER_ROD, ["output.vtk=false", "solver.t_end=1e-4", f"initial.velocity={velocity}"]),
                  tmp_path / "spun").history
    still = hammer.history
    assert spun["hammer.wx"] == pytest.approx(w, rel=1e-10)
    assert np.abs(spun["hammer.wy"]).max() <= 1e-9 * w and np.abs(spun["hammer.wz"]).max() <= 1e-9 * w
    assert spun["strike.force"] == pytest.approx(still["strike.force"], rel=1e-8, abs=1e-8 * Z * V0)
    assert spun["hammer.vx"] == pytest.approx(still["hammer.vx"], rel=1e-9, abs=1e-12)
    J = M * (2 * 0.01 ** 2) / 12.0   # the hammer's inertia about its axis (a square section of side 1 cm)
    check_budget(spun, 0.5 * M * V0 ** 2 + 0.5 * J * w * w)
