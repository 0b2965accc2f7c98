"""The same history in serial and under ``mpirun -n 2`` (distributed matrices and vectors)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import CASES, read_history, run_cli

pytestmark = pytest.mark.mpi


def run_serial_and_two_ranks(case: str, folder, overrides) -> None:
    """``fem-impact run CASE`` into folder/serial, and under ``mpirun -n 2`` into folder/mpi."""
    serial = run_cli("run", case, "-o", str(folder / "serial"), "-q", *overrides)
    assert serial.returncode == 0, serial.stderr
    # This pytest process has initialized MPI itself (singleton): its OMPI_/PMIX_ variables
    # would make the child mpirun think it is nested, so they are not passed on.
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "OPAL_"))}
    parallel = subprocess.run(
        ["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2", sys.executable, "-m", "fem_impact",
         "run", case, "-o", str(folder / "mpi"), "-q", *overrides],
        capture_output=True, text=True, env=env,
    )
    assert parallel.returncode == 0, parallel.stderr


def assert_same_history(a, b, tol: float, on_energy=()) -> None:
    """Column by column to ``tol`` of its scale: an energy term on the energy's (the balance residual is
    round-off itself), a component of a vector (a probe's u or v, a body's momentum) on the vector's
    largest component (the plate's transverse motion is round-off about zero)."""
    assert a.dtype.names == b.dtype.names and a.shape == b.shape
    energy_scale = max(a["kinetic"].max() + a["strain"].max(), 1e-300)
    energy_terms = ("energy_error", "contact_loss", "impact_loss", "damping_loss", "external_work", "friction_loss",
                    "scheme_energy", *on_energy)
    for name in a.dtype.names:
        scale = energy_scale if name in energy_terms else max(np.abs(a[name]).max(), 1e-300)
        if name[-3:-1] in ("_u", "_v", "_p") and name[-1] in "xyz":
            scale = max(np.abs(a[c]).max() for c in a.dtype.names if c[:-1] == name[:-1])
        assert np.abs(a[name] - b[name]).max() <= tol * scale, name


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
@pytest.mark.parametrize("dim, cells, method", [(1, 100, "newmark"), (2, 60, "newmark"), (2, 60, "modal"),
                                               (2, 60, "moreau_jean"), (2, 60, "moreau_jean_velocity"),
                                               (2, 60, "central_difference"), (2, 60, "friction")])
def test_serial_and_two_ranks_agree(tmp_path, dim, cells, method):
    # "friction": moreau_jean, the bar sliding along the wall as it hits it (mu = 0.3).
    friction = ["--set", "contacts.0.friction=0.3", "--set", "initial.velocity=[-1.0, 0.5]"]
    name = {"friction": "moreau_jean", "moreau_jean_velocity": "moreau_jean"}.get(method, method)
    overrides = ["--set", f"mesh.dim={dim}", "--set", f"mesh.cells={cells}", "--set", f"solver.dt={0.5 / cells}",
                 "--set", "solver.t_end=2.5", "--set", "output.every=50", "--set", f"solver.method={name}",
                 *(["--set", "solver.modes=10"] if method == "modal" else []),
                 *(["--set", "solver.level=velocity"] if method == "moreau_jean_velocity" else []),
                 *(["--set", "solver.mass=lumped"] if method == "central_difference" else []),
                 *(friction if method == "friction" else [])]
    case = str(CASES / "impacting_bar.yaml")
    run_serial_and_two_ranks(case, tmp_path, overrides)
    a, b = read_history(tmp_path / "serial"), read_history(tmp_path / "mpi")
    assert a.dtype.names == b.dtype.names and a.shape == b.shape
    for name in ("left_ux", "right_ux", "left_vx", "right_vx", "kinetic", "strain"):   # (the momentum is round-off)
        assert np.abs(a[name] - b[name]).max() <= 1e-10 * np.abs(a[name]).max(), name
    # The contact really happened in both runs (the comparison is not of two empty histories).
    assert a["wall_impulse"].sum() > 0.9 * (1.0 / 20 if dim == 2 else 1.0) * 2
    if method == "friction":   # and the friction acted, on both
        assert a["friction_loss"][-1] > 0.0 and a["wall_tangential_force"].max() > 0.0
    if method == "modal":   # modes and static solves computed on 2 ranks, not read from the cache
        assert json.loads((tmp_path / "mpi" / "summary.json").read_text())["reused_from_cache"] == []


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
def test_reduced_contact_steps_in_compiled_blocks_agree_on_two_ranks(tmp_path):
    """The face on its stop, ten modes with the static correction, its steps with impulses in compiled blocks
    (integrators/kernels.py): on 2 ranks the single steps' history to 1e-10, every rank taking the same
    blocks of the replicated model; the serial run's to the modes' own agreement (SLEPc on 2 ranks gives
    modes that differ by round-off of its solve: 4e-8 of the force with single steps too)."""
    for blocks in ("true", "false"):
        overrides = ["--set", "mesh.cells=20", "--set", "solver.method=modal", "--set", "solver.modes=10",
                     "--set", f"solver.blocks={blocks}", "--set", "solver.t_end=0.6", "--set", "output.every=1"]
        run_serial_and_two_ranks(str(CASES / "face_on_stop.yaml"), tmp_path / blocks, overrides)
    fast, single = read_history(tmp_path / "true" / "mpi"), read_history(tmp_path / "false" / "mpi")
    assert_same_history(single, fast, 1e-10)
    assert_same_history(read_history(tmp_path / "true" / "serial"), fast, 1e-6)
    assert fast["stop_force"].max() > 0.0
    for run in ("serial", "mpi"):
        summary = json.loads((tmp_path / "true" / run / "summary.json").read_text())
        assert summary["steps_in_blocks"] >= 0.5 * summary["steps"], run


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
def test_the_explicit_plate_with_441_face_rows_agrees_on_two_ranks(tmp_path):
    """The explicit many-row scene of benchmarks/scaling.py on a coarse size: cases/plate_drop.yaml with
    central difference and a lumped mass, 4 cells through the thickness, every face node a row (441
    rows, a projection each); the face lies across both ranks."""
    overrides = ["--set", "mesh.cells=4", "--set", "solver.dt=0.125", "--set", "solver.method=central_difference",
                 "--set", "solver.mass=lumped", "--set", "output.every=1"]
    run_serial_and_two_ranks(str(CASES / "plate_drop.yaml"), tmp_path, overrides)
    a, b = read_history(tmp_path / "serial"), read_history(tmp_path / "mpi")
    assert a.dtype.names == b.dtype.names and a.shape == b.shape
    for name in ("left_ux", "right_ux", "left_vx", "right_vx", "kinetic", "strain"):   # (the momentum is round-off)
        assert np.abs(a[name] - b[name]).max() <= 1e-10 * np.abs(a[name]).max(), name
    assert a["floor_impulse"].sum() > 0.9 * 2 * 25.0      # the face hit the floor (2 rho c A v0 = 50)


@pytest.mark.slow   # (10 s: the default tier's budget)
@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
def test_axisymmetric_binary_fields_and_impacts_agree_on_two_ranks(tmp_path):
    """The axisymmetric horn (cases/vibroconverter_axi.yaml, 3.9 periods: its first four impacts), written as XDMF:
    on 2 ranks the same history, the same impacts.csv and the same fields node by node (matched by their
    coordinates: the ranks number the nodes their own way)."""
    import fem_impact as fi

    overrides = ["--set", "solver.t_end=1.5e-4", "--set", "output.format=xdmf", "--set", "output.every=200"]
    case = str(CASES / "vibroconverter_axi.yaml")
    run_serial_and_two_ranks(case, tmp_path, overrides)
    a, b = fi.Result.load(tmp_path / "serial"), fi.Result.load(tmp_path / "mpi")
    # (the same impacts; their numbers to round-off: 2 ranks sum in another order)
    ia, ib = (np.genfromtxt(tmp_path / k / "impacts.csv", delimiter=",", names=True, dtype=None, encoding=None)
              for k in ("serial", "mpi"))
    assert list(ia["contact"]) == list(ib["contact"]) and list(ia["rows"]) == list(ib["rows"])
    for name in ("t", "impulse", "speed"):
        assert np.allclose(ia[name], ib[name], rtol=1e-9, atol=0), name
    assert a.summary["impacts"] == {"stop": 4}
    energy = a.history["kinetic"][0] + a.history["strain"][0]
    for name, column in a.history.items():
        scale = energy if name in ("energy_error", "contact_loss", "impact_loss", "damping_loss", "external_work") \
            else max(np.abs(column).max(), 1e-300)
        assert np.abs(column - b.history[name]).max() <= 1e-8 * scale, name
    fa, fb = a.fields(), b.fields()
    ia, ib = np.lexsort(fa.points.T[::-1]), np.lexsort(fb.points.T[::-1])
    assert np.array_equal(fa.points[ia], fb.points[ib]) and np.array_equal(fa.t, fb.t)
    for name in ("u", "v", "contact_force"):
        assert np.abs(fa.values[name][:, ia] - fb.values[name][:, ib]).max() <= 1e-10 * np.abs(fa.values[name]).max()


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
@pytest.mark.slow   # (16 s: the moving supports' probe class runs them on 2 ranks too; the default tier keeps
                   # the other full-model paths on 2 ranks)
@pytest.mark.parametrize("method", ["moreau_jean", "modal"])
def test_a_moving_support_agrees_on_two_ranks(tmp_path, method):
    """The base-excited cantilever (cases/base_excited_beam.yaml at 30 cells, 2 periods: its first impacts),
    the clamp on one rank only: the same history, the clamp's reactions and the fields (u includes the
    clamp's motion) on 2 ranks."""
    import fem_impact as fi

    overrides = ["--set", "solver.t_end=0.74", "--set", "mesh.cells=30", "--set", f"solver.method={method}",
                 "--set", "output.format=xdmf",
                 "--set", "output.every=500", *(["--set", "solver.modes=10"] if method == "modal" else [])]
    run_serial_and_two_ranks(str(CASES / "base_excited_beam.yaml"), tmp_path, overrides)
    a, b = fi.Result.load(tmp_path / "serial"), fi.Result.load(tmp_path / "mpi")
    assert a.history["stop.impulse"].sum() > 10.0            # N s: the tip hit the stop
    energy = (a.history["kinetic"] + a.history["strain"]).max()
    for name, column in a.history.items():
        scale = energy if name in ("energy_error", "contact_loss", "external_work") else max(np.abs(column).max(), 1e-300)
        assert np.abs(column - b.history[name]).max() <= 1e-8 * scale, name
    fa, fb = a.fields(), b.fields()
    ia, ib = np.lexsort(fa.points.T[::-1]), np.lexsort(fb.points.T[::-1])
    clamp = np.isclose(fa.points[ia, 0], 0.0)
    expected = 2e-5 * np.sin(2 * np.pi * 2.7 * fa.t)
    assert np.allclose(fa.values["u"][:, ia][:, clamp, 1], expected[:, None], rtol=0, atol=1e-12 * 2e-5)
    for name in ("u", "v"):   # (as the history: 1e-8; the impacts magnify round-off, measured up to 1.05e-10)
        assert np.abs(fa.values[name][:, ia] - fb.values[name][:, ib]).max() <= 1e-8 * np.abs(fa.values[name]).max()


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
@pytest.mark.parametrize("case, overrides", [
    # a wall given a motion strikes the bar at rest (Carnot's rows, the wall's work)
    ("impacting_bar.yaml", ["mesh.cells=60", "initial.velocity=[0.0]", "contacts.0.motion=[t]", "solver.dt=0.005",
                            "solver.t_end=1.0", "solver.method=moreau_jean"]),
    # a 2D bar at rest struck by a wall that also slides along itself (friction on the relative motion)
    pytest.param("impacting_bar.yaml", ["mesh.dim=2", "mesh.cells=60", "initial.velocity=[0.0, 0.0]",
                                        "contacts.0.friction=0.3",
                            "contacts.0.motion=[t, '0.5*t']", "solver.dt=0.005", "solver.t_end=1.0",
                            "solver.method=moreau_jean"], marks=pytest.mark.slow),
    # a rigid block launched along a floor (friction), the rigid scene's state replicated, its nodes distributed
    ("sliding_block.yaml", ["bodies={bar: {model: rigid}}", "solver.t_end=0.8", "output.probes={}"]),
    # a rigid 3D block spun in the air, struck by a wall closing in (large rotation, an impact)
    pytest.param("sliding_block.yaml", ["bodies={bar: {model: rigid}}", "mesh.dim=3", "mesh.width=0.05",
                                        "material.area=null",
                            "loads=[]", "initial.velocity=['-1 + 20*(z - 0.025)', '30*(z - 0.025)', "
                            "'-20*(x - 0.1) - 30*(y - 0.025)']", "contacts.0.normal=[-1.0, 0.0, 0.0]",
                            "contacts.0.gap=0.01", "contacts.0.motion=['0.5*t', 0, 0]", "contacts.0.nodes=left",
                            "solver.t_end=0.2", "solver.dt=0.0005", "output.probes={}"], marks=pytest.mark.slow),
    # a rigid hammer strikes an elastic rod (a mixed scene: the rigid part replicated, the rod distributed)
    ("hammer_rod.yaml", ["solver.t_end=1e-4"]),
], ids=["wall", "sliding wall", "rigid block", "rigid 3D block", "rigid hammer on an elastic rod"])
def test_a_moving_obstacle_agrees_on_two_ranks(tmp_path, case, overrides):
    """An obstacle given a motion (docs/theory.md s. 2.6), rigid bodies (s. 12): the same history on 2 ranks,
    the obstacle's work in the external work included."""
    sets = [arg for change in overrides + ["output.vtk=false", "output.every=1"] for arg in ("--set", change)]
    run_serial_and_two_ranks(str(CASES / case), tmp_path, sets)
    a, b = read_history(tmp_path / "serial"), read_history(tmp_path / "mpi")
    if "contacts.0.motion" in " ".join(overrides):   # (the obstacle did the work)
        assert a["external_work"][-1] > 0.1 * a["kinetic"].max()
    if "friction_loss" in a.dtype.names:
        assert a["friction_loss"][-1] > 0.0
    # (a rigid block resting on its floor: its gap, angle and spin are round-off, 1e-10 m, 4e-10 rad, 1e-9 rad/s;
    # compared on the scenes' size, 1 cm, and on 0.01 rad and 0.01 rad/s; the hammer struck head on spins by
    # round-off too, 1e-12 rad/s: on 1 rad/s, its speed over its size being 100)
    spin = 1.0 if case == "hammer_rod.yaml" else 1e-2
    floors = {name: spin if name.endswith(("_wx", "_wy", "_wz")) else 1e-2 for name in a.dtype.names if name.endswith(("_gap", "_angle", "_omega", "_wx", "_wy", "_wz"))}
    for name, floor in floors.items():
        assert np.abs(a[name] - b[name]).max() <= 1e-10 * max(np.abs(a[name]).max(), floor), name
    keep = [name for name in a.dtype.names if name not in floors]
    assert_same_history(a[keep], b[keep], 1e-10)


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
@pytest.mark.parametrize("method", ["moreau_jean", "newmark"])
def test_a_run_without_contacts_agrees_on_two_ranks(tmp_path, method):
    """No contact row: the implicit schemes' Delassus solve has no right-hand side, which MUMPS refused on
    2 ranks (a traceback) where the serial run went through."""
    overrides = ["--set", f"solver.method={method}", "--set", "solver.t_end=0.2", "--set", "output.vtk=false",
                 "--set", "output.every=5"]
    run_serial_and_two_ranks(str(CASES / "free_vibration.yaml"), tmp_path, overrides)
    a, b = read_history(tmp_path / "serial"), read_history(tmp_path / "mpi")
    assert a.dtype.names == b.dtype.names and a.shape == b.shape
    for name in ("left_ux", "right_ux", "left_vx", "right_vx", "kinetic", "strain"):   # (the momentum is round-off)
        assert np.abs(a[name] - b[name]).max() <= 1e-10 * np.abs(a[name]).max(), name


def mpirun(*args, repeatable: bool = False) -> subprocess.CompletedProcess:
    """``fem-impact ARGS`` on 2 ranks; ``repeatable``: with SuperLU_dist, whose arithmetic repeats from run
    to run (MUMPS' order of operations on 2 ranks can follow the timing of its messages: with the tests in
    two workers, the 2D bar's Moreau-Jean restart parted from the uninterrupted run by more than 1e-12 of
    left.uy, at both levels, where an idle machine had given identical runs)."""
    env = mpirun_environment()
    if repeatable:
        env["PETSC_OPTIONS"] = (env.get("PETSC_OPTIONS", "") + " -fem_impact_pc_factor_mat_solver_type superlu_dist")
    return subprocess.run(mpirun_command(*args), capture_output=True, text=True, env=env)


def mpirun_command(*args) -> list[str]:
    return ["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2", sys.executable, "-m", "fem_impact", *args]


def mpirun_environment() -> dict:
    """This process's environment without MPI's own variables (this pytest process initialized MPI: a child
    mpirun would think it is nested)."""
    return {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "OPAL_"))}


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
@pytest.mark.parametrize("method", ["moreau_jean", *(pytest.param(m, marks=pytest.mark.slow) for m in (
    "moreau_jean_velocity", "newmark", "central_difference", "modal"))])   # (slow: the same restart path)
def test_a_run_restarted_on_two_ranks_is_the_uninterrupted_run(tmp_path, method):
    """The 2D bar on 2 ranks: run to 1.25, continue from its checkpoint (one file per rank) to 2.5, and
    compare with the run to 2.5 at once; a checkpoint of 2 ranks is refused by a serial run."""
    from test_restart import assert_same_from

    import fem_impact as fi

    case = str(CASES / "impacting_bar.yaml")
    common = ["--set", "mesh.dim=2", "--set", "mesh.cells=60", "--set", "solver.dt=0.008333333333333333",
              "--set", "output.vtk=false", "--set", f"solver.method={method.replace('_velocity', '')}",
              *(["--set", "solver.modes=10"] if method == "modal" else []),
              *(["--set", "solver.level=velocity"] if method.endswith("_velocity") else []),
              *(["--set", "solver.mass=lumped"] if method == "central_difference" else []), "-q"]
    for name, t_end, extra in (("whole", 2.5, []), ("half", 1.25, []), ("continued", 2.5, ["--restart", "half"])):
        extra = [str(tmp_path / e) if e == "half" else e for e in extra]
        done = mpirun("run", case, "-o", str(tmp_path / name), *common, "--set", f"solver.t_end={t_end}", *extra,
                      repeatable=True)
        assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in (tmp_path / "half" / "checkpoint").iterdir()) == ["rank-0.h5", "rank-1.h5",
                                                                                     "state.json"]
    whole, continued = fi.Result.load(tmp_path / "whole"), fi.Result.load(tmp_path / "continued")
    assert continued.summary["restarted_from"]["t"] == pytest.approx(1.25)
    # (the cells are distributed the same way every run, fem_impact/fem/partition.py, and SuperLU_dist
    # repeats its arithmetic: the same operations)
    assert_same_from(whole.history, continued.history, tol=1e-12, digits=12)
    serial = run_cli("run", case, "-o", str(tmp_path / "serial"), *common, "--restart", str(tmp_path / "half"))
    assert serial.returncode == 2 and "written on 2 MPI rank(s), this run has 1" in serial.stderr


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
@pytest.mark.parametrize("every", [pytest.param(False, id="rank-1.h5 missing, --restart"),
                                   pytest.param(True, id="every damage", marks=pytest.mark.slow)])
def test_a_damaged_checkpoint_of_two_ranks_is_refused_by_every_rank_at_once(tmp_path, every):
    """A file missing, cut short or of another time on one rank: every rank checks its files and the ranks
    agree before any goes on, so the run ends at once with one line naming the file and status 2 (a rank
    that stopped alone would leave the others waiting in the first collective call), for a restart and
    for a run from the checkpoint. The default tier: the file missing on rank 1 (which hung until killed);
    tools/probes/checkpoint_damaged.py tries thirty damages on 2 ranks."""
    case = str(CASES / "impacting_bar.yaml")
    common = ["--set", "mesh.cells=20", "--set", "solver.dt=0.01", "--set", "output.vtk=false", "-q"]
    done = mpirun("run", case, "-o", str(tmp_path / "saved"), *common, "--set", "solver.t_end=0.05")
    assert done.returncode == 0, done.stderr
    damages = [("rank-1.h5", lambda c: (c / "rank-1.h5").unlink()),   # (rank 1 alone finds it)
               ("rank-0.h5", lambda c: (c / "rank-0.h5").write_bytes((c / "rank-0.h5").read_bytes()[:1000])),
               ("rank-0.h5", lambda c: (c / "state.json").write_text((c / "state.json").read_text().replace(
                   '"t": 0.05', '"t": 0.03')))]   # (an edited t: not the rank files' time)
    for name, damage in damages if every else damages[:1]:
        folder = tmp_path / f"damaged-{len(list(tmp_path.iterdir()))}"
        shutil.copytree(tmp_path / "saved", folder)
        damage(folder / "checkpoint")
        options = (["--restart", str(folder)], ["--set", f"initial={{from: {folder}}}"])
        for args in options if every else options[:1]:
            start = time.monotonic()
            refused = subprocess.run(["timeout", "120", *mpirun_command("run", case, "-o", str(tmp_path / "out"),
                                                                        *common, "--set", "solver.t_end=0.1", *args)],
                                     capture_output=True, text=True, env=mpirun_environment())
            ours = [line for line in refused.stderr.splitlines() if line.startswith("fem-impact:")]
            assert refused.returncode == 2 and time.monotonic() - start < 100, refused.stderr
            assert len(ours) == 1 and str(folder / "checkpoint" / name) in ours[0], refused.stderr
            assert not (tmp_path / "out").exists()


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
def test_two_runs_on_two_ranks_write_the_same_history(tmp_path):
    """The cells go to the same rank in every run (fem_impact/fem/partition.py; PT-Scotch's partition
    changed from run to run): the explicit method on the 3D bar, which factorizes nothing, writes the
    same history.csv byte for byte."""
    overrides = ["--set", "mesh.dim=3", "--set", "mesh.cells=60", "--set", "solver.method=central_difference",
                 "--set", "solver.mass=lumped", "--set", "solver.dt=0.004", "--set", "output.vtk=false", "-q"]
    for name in ("a", "b"):
        done = mpirun("run", str(CASES / "impacting_bar.yaml"), "-o", str(tmp_path / name), *overrides)
        assert done.returncode == 0, done.stderr
    assert (tmp_path / "a" / "history.csv").read_bytes() == (tmp_path / "b" / "history.csv").read_bytes()


CUT_ACROSS = """
import json, numpy as np
from mpi4py import MPI
from fem_impact.fem.dolfinx_api import box, gmsh_cells_to_mesh
comm = MPI.COMM_WORLD
out = {}
for name in ("box", "gmsh"):
    if name == "box":
        msh = box(comm, (200, 10, 10), (1.0, 0.05, 0.05))
    else:   # the same bar's hexahedra handed over as a read mesh is (Gmsh element type 5), on rank 0
        i, j, k = np.meshgrid(np.arange(201), np.arange(11), np.arange(11), indexing="ij")
        x = np.column_stack([i.ravel() / 200, j.ravel() / 200, k.ravel() / 200])
        node = lambda a, b, c: (a * 11 + b) * 11 + c
        a, b, c = (g.ravel() for g in np.meshgrid(np.arange(200), np.arange(10), np.arange(10), indexing="ij"))
        cells = np.column_stack([node(a, b, c), node(a + 1, b, c), node(a + 1, b + 1, c), node(a, b + 1, c),
                                 node(a, b, c + 1), node(a + 1, b, c + 1), node(a + 1, b + 1, c + 1), node(a, b + 1, c + 1)])
        if comm.rank:
            cells, x = cells[:0], x[:0]
        msh = gmsh_cells_to_mesh(comm, 5, cells, x, np.ones(cells.shape[0]), 3)[0]
    owned = msh.topology.index_map(3).size_local
    nodes = msh.geometry.dofmap.array.reshape(-1, 8 if name == "gmsh" else 4)[:owned]
    cx = msh.geometry.x[nodes, 0].mean(axis=1)
    out[name] = comm.gather([owned, float(cx.min()), float(cx.max())])
if comm.rank == 0:
    print("JSON" + json.dumps(out))
"""


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
def test_a_bar_built_or_read_on_two_ranks_is_cut_straight_across_its_middle():
    """The cells of a 200 x 10 x 10 bar (benchmarks/scaling.py's 73k unknowns) go to the ranks by coordinate bisection of their centres: each rank
    owns the cells on one side of x = 1/2, half of them, whether the mesh is built (tetrahedra) or read.
    (The partition without centres, runs of a breadth-first order, gave one rank cells all along it.)"""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "OPAL_"))}
    out = subprocess.run(["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2", sys.executable, "-c",
                          CUT_ACROSS], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    result = json.loads(out.stdout.split("JSON", 1)[1].splitlines()[0])
    for name, per_layer in (("box", 6 * 100), ("gmsh", 100)):
        (n0, lo0, hi0), (n1, lo1, hi1) = sorted(result[name], key=lambda r: r[1])
        assert n0 == n1 == 100 * per_layer, name
        assert hi0 < 0.5 < lo1, name


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
def test_a_command_started_alone_starts_mpi_for_one_process_and_mpirun_ranks_keep_their_own():
    """The command line started alone sets Open MPI's start for one process (no daemon, shared memory and self
    only), unless the user set those keys; the ranks of mpirun get none of it (they may span machines)."""
    from fem_impact.app.cli import SERIAL_MPI

    show = "import os, fem_impact.app.cli; print({k: os.environ.get(k) for k in fem_impact.app.cli.SERIAL_MPI})"
    env = {k: v for k, v in mpirun_environment().items() if k not in SERIAL_MPI}
    alone = subprocess.run([sys.executable, "-c", show], capture_output=True, text=True, env=env, check=True)
    assert eval(alone.stdout) == SERIAL_MPI
    own = subprocess.run([sys.executable, "-c", show], capture_output=True, text=True, check=True,
                         env={**env, "OMPI_MCA_btl": "self,tcp"})
    assert eval(own.stdout)["OMPI_MCA_btl"] == "self,tcp"
    ranks = subprocess.run(["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2", sys.executable, "-c", show],
                           capture_output=True, text=True, env=env, check=True)
    # (mpirun forwards both ranks' lines, which may arrive joined: one dict each)
    assert [eval(seen) for seen in re.findall(r"\{[^{}]*\}", ranks.stdout)] == [dict.fromkeys(SERIAL_MPI)] * 2


def test_mpirun_started_from_a_process_started_alone_has_ranks_that_reach_each_other():
    """mpirun passes its environment, the settings for one process included, to its ranks: with self alone
    among the transports the two ranks could not reach each other ("unreachable proc")."""
    from fem_impact.mpi_start import SERIAL_MPI

    env = {**mpirun_environment(), **SERIAL_MPI}
    ranks = subprocess.run(["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2", sys.executable, "-c",
                            "from mpi4py import MPI; n = MPI.COMM_WORLD.allreduce(1)\n"
                            "if MPI.COMM_WORLD.rank == 0: print(n)"],
                           capture_output=True, text=True, env=env, timeout=120)
    # (rank 0 alone prints: mpirun forwards two ranks' lines as they come, possibly joined)
    assert ranks.returncode == 0 and ranks.stdout.split() == ["2"], ranks.stderr[-2000:]


def test_commands_started_alone_have_session_folders_of_their_own_removed_at_exit(tmp_path):
    """Isolated processes share Open MPI's job family 0: in one session folder, one process's MPI_Finalize
    removed the folder another's MPI_Init was creating ("Local abort before MPI_INIT completed"). Each
    process started alone has its own, inherited or not, and removes it; a user's own base is kept."""
    show = ("import os, fem_impact.app.cli; from mpi4py import MPI; MPI.COMM_WORLD.barrier(); "
            "base = os.environ['OMPI_MCA_orte_tmpdir_base']; print(base, os.path.isdir(base))")
    env = {k: v for k, v in mpirun_environment().items() if not k.startswith("OMPI_MCA_orte_tmpdir")}
    children = [subprocess.Popen([sys.executable, "-c", show], stdout=subprocess.PIPE, text=True,
                                 env={**env, **inherited}) for inherited in
                ({}, {}, {"OMPI_MCA_orte_tmpdir_base": os.environ.get("OMPI_MCA_orte_tmpdir_base", "/tmp"),
                      "FEM_IMPACT_MPI_SESSION_BASE": os.environ.get("OMPI_MCA_orte_tmpdir_base", "/tmp")})]
    seen = [child.communicate(timeout=120)[0].split() for child in children]
    assert [child.returncode for child in children] == [0, 0, 0]
    bases = [base for base, existed in seen]
    assert all(existed == "True" for _, existed in seen) and len(set(bases)) == 3
    assert os.environ.get("OMPI_MCA_orte_tmpdir_base") not in bases
    assert not any(Path(base).exists() for base in bases)
    user = tmp_path / "mine"
    user.mkdir()
    own = subprocess.run([sys.executable, "-c", show], capture_output=True, text=True, check=True,
                         env={**env, "OMPI_MCA_orte_tmpdir_base": str(user)})
    assert own.stdout.split() == [str(user), "True"] and user.is_dir()


ONE_RANK_FAILS = """
import sys
from mpi4py import MPI
import fem_impact.app.cli as cli
import fem_impact.build as build
built = build.build_system
def failing(*args, **kwargs):   # (a defect that strikes rank 0 alone; the pipeline takes the builder's when it runs)
    if MPI.COMM_WORLD.rank == 0:
        raise ValueError("a defect on rank 0 alone")
    return built(*args, **kwargs)
build.build_system = failing
sys.exit(cli.main(sys.argv[1:]))
"""


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
def test_an_unexpected_error_on_one_rank_stops_every_rank_instead_of_hanging(tmp_path):
    """A defect raised on one rank alone used to leave the other waiting in its next collective call: the
    run hung. Now the rank prints its traceback and aborts the job: a nonzero status within seconds."""
    script = tmp_path / "one_rank_fails.py"
    script.write_text(ONE_RANK_FAILS)
    runs = tmp_path / "runs"
    earlier = run_cli("run", str(CASES / "free_vibration.yaml"), "-q", "-o", str(runs / "out"), "--set", "solver.t_end=0.01")
    assert earlier.returncode == 0, earlier.stderr
    before = {f.relative_to(runs): f.read_bytes() for f in runs.rglob("*") if f.is_file()}
    proc = subprocess.run(["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2", sys.executable, str(script),
                           "run", str(CASES / "free_vibration.yaml"), "-q", "-o", str(runs / "out"),
                           "--set", "solver.t_end=0.01"],
                          capture_output=True, text=True, env=mpirun_environment(), timeout=120)
    assert proc.returncode != 0
    assert "a defect on rank 0 alone" in proc.stderr and "stopped on the error above" in proc.stderr
    assert {f.relative_to(runs): f.read_bytes() for f in runs.rglob("*") if f.is_file()} == before   # (the earlier result)


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
@pytest.mark.parametrize("overrides", [
    ["solver.dt=1e-6", "solver.t_end=2e-4", "initial.velocity=[{body: upper, value: [0.5, -1.0]}]"],
    # sliding 12 mm without friction (a stiff block on 8 rows with friction has impulses that are not unique
    # beyond the solver's tolerance: round-off chooses): its rows found again three times on every rank
    ["solver.dt=2e-5", "solver.t_end=0.012", "initial.velocity=[{body: upper, value: [1.0, 0.0]}]",
     "loads=[{body: upper, acceleration: [0.0, -9.81]}]", "contacts.0.friction=0.0"],
], ids=["dropped while sliding", "slid over three searches"])
def test_a_surface_contact_agrees_on_two_ranks(tmp_path, overrides):
    """Rows found by a search on the facets of every rank (docs/theory.md s. 2.7), mortar rows whose
    surface nodes another rank owns, found again as the block slides: the patch test's upper block
    with friction has the same history."""
    overrides = ["solver.theta=0.5", "contacts.0.friction=0.3", "loads=[]", "supports=[{nodes: base, fix: all}]"] + overrides
    sets = [arg for change in overrides + ["output.vtk=false"] for arg in ("--set", change)]
    run_serial_and_two_ranks(str(CASES / "contact_patch.yaml"), tmp_path, sets)
    a, b = read_history(tmp_path / "serial"), read_history(tmp_path / "mpi")
    assert a["face_force"].max() > 0.0
    # (the pressed face's gap is round-off, 2e-15 m: compared to 1e-8 of the blocks' displacement, 1e-6 m)
    assert np.abs(a["face_gap"] - b["face_gap"]).max() <= 1e-8 * 1e-6
    # A block translated by 12 mm on a steel model carries K U's round-off of its translation, about 1e-7 of
    # its forces (summary energy_roundoff): measured 5e-8 of a momentum, 9e-9 of the force, between the runs.
    # Its strain energy (2e-9 J, the block resting on the strip) is of that round-off: compared on the energy's.
    slid = "contacts.0.friction=0.0" in overrides
    keep = [n for n in a.dtype.names if n != "face_gap"]
    assert_same_history(a[keep], b[keep], 1e-6 if slid else 1e-10, on_energy=("strain",) if slid else ())
    if slid:
        searches = [json.loads((tmp_path / run / "summary.json").read_text())["surface_searches"]
                    for run in ("serial", "mpi")]
        assert searches[0] == searches[1] == 3
