"""Checkpoint and restart (fem_impact/app/checkpoint/): a run continued from its checkpoint gives the
uninterrupted run's history from that time on, to round-off, for every method; an interrupted run
keeps its last checkpoint beside its output folder and continues from it to the same end."""

from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import fem_impact as fi
from fem_impact.config.case import CaseError

from conftest import CASES

RUNS = {
    "moreau_jean": ("impacting_bar.yaml", ["solver.method=moreau_jean"]),
    "moreau_jean_velocity": ("impacting_bar.yaml", ["solver.method=moreau_jean", "solver.level=velocity"]),
    "newmark": ("impacting_bar.yaml", ["solver.method=newmark"]),
    "central_difference": ("impacting_bar.yaml", ["solver.method=central_difference", "solver.mass=lumped"]),
    "modal": ("impacting_bar.yaml", ["solver.method=modal", "solver.modes=20"]),
    "modal_static_correction_elastic_stop": ("beam_stop.yaml", ["solver.method=modal", "solver.modes=10",
                                                                "solver.t_end=0.06"]),
    "friction": ("sliding_block.yaml", ["solver.t_end=0.3"]),
    # the static correction's forces on the tangent rows, and the probes' static part under them
    "friction_static_correction": ("sliding_block.yaml", ["solver.method=modal", "solver.modes=6",
                                                          "solver.t_end=0.3"]),
    # the steps between impacts in blocks (integrators/blocks.py), checkpoints within the run stopping them
    "modal_blocks": ("impact_oscillator.yaml", ["solver.blocks=true", "solver.t_end=40",
                                                "output.checkpoint_every=1234"]),
    # the steps with impulses in compiled blocks too (the static correction's compliant rows)
    "modal_contact_blocks": ("face_on_stop.yaml", ["solver.method=modal", "solver.modes=10", "solver.blocks=true",
                                                   "solver.t_end=0.6", "output.checkpoint_every=77"]),
    "moving_support_reduced": ("base_excited_beam.yaml", ["solver.method=modal", "solver.modes=10",
                                                          "solver.t_end=0.8", "damping.alpha=0.5"]),
}


ENERGY_TERMS = ("energy_error", "contact_loss", "impact_loss", "damping_loss", "external_work", "friction_loss")


def assert_same_from(full: dict, continued: dict, tol: float = 1e-12, digits: int | None = None) -> None:
    """``continued`` equals ``full`` from its first time on, column by column, to ``tol`` of each column's
    scale (an energy term, round-off itself where it is zero, on the energy's). ``digits``: histories read
    from history.csv, whose numbers have that many significant digits: a value may also differ by one unit
    of its last digit (a round-off difference of 1e-17 can round the 12th digit the other way: 1e-14 on
    0.0042, which is 2.4e-12 of it)."""
    start = np.searchsorted(full["t"], continued["t"][0] - 1e-9 * (full["t"][1] - full["t"][0]))
    assert full["t"][start] == pytest.approx(continued["t"][0], rel=1e-12)   # (history.csv: 12 digits)
    assert len(full["t"]) - start == len(continued["t"])
    energy = (full["kinetic"] + full["strain"]).max()
    for name, column in full.items():
        scale = max(np.abs(column).max(), energy if name in ENERGY_TERMS else 1e-300)
        if name.endswith((".px", ".py", ".pz", ".ux", ".uy", ".uz", ".vx", ".vy", ".vz")):
            # a body's momentum, a probe's displacement or velocity: on the scale of its largest component
            scale = max(np.abs(full[c]).max() for c in full if c.startswith(name[:-1]))
        allowed = tol * scale
        if digits is not None:
            larger = np.maximum(np.abs(column[start:]), np.abs(continued[name]))
            last_digit = 10.0 ** (np.floor(np.log10(np.where(larger > 0, larger, 1e-300))) - (digits - 1))
            allowed = np.maximum(allowed, 1.0001 * last_digit)
        assert np.all(np.abs(column[start:] - continued[name]) <= allowed), name


@pytest.mark.parametrize("run", list(RUNS))
def test_a_run_continued_from_its_checkpoint_is_the_uninterrupted_run(tmp_path, run):
    name, changes = RUNS[run]
    case = fi.load_case(CASES / name, ["output.vtk=false", *changes])
    t_end = case.solver.t_end
    full = fi.run(case, tmp_path / "full")
    half = fi.run(case.with_changes({"solver.t_end": 0.5 * t_end}), tmp_path / "half")
    continued = fi.run(case, tmp_path / "continued", restart=tmp_path / "half")
    assert continued.summary["restarted_from"]["t"] == pytest.approx(0.5 * t_end, rel=1e-9)
    assert continued.history["t"][0] == half.history["t"][-1]
    assert_same_from(full.history, continued.history)
    # the summary's extremes and totals are the whole run's, as the uninterrupted run's are
    for key in ("max_penetration", "max_stop_compression", "max_energy", "max_energy_error"):
        assert continued.summary[key] == pytest.approx(full.summary[key], rel=1e-9, abs=1e-12 * full.summary[
            "initial_energy"]), key
    for name, impulse in full.summary["total_impulse"].items():
        assert continued.summary["total_impulse"][name] == pytest.approx(impulse, rel=1e-9, abs=1e-12), name
    if run.endswith("_blocks"):
        assert full.summary["steps_in_blocks"] > 0 and continued.summary["steps_in_blocks"] > 0
    state = json.loads((tmp_path / "half" / "checkpoint" / "state.json").read_text())
    assert state["step"] == half.summary["steps"] and state["ranks"] == 1
    # the continued run saved its own end: it continues again (to a later t_end)
    again = fi.run(case.with_changes({"solver.t_end": 1.25 * t_end}), tmp_path / "again",
                   restart=tmp_path / "continued")
    assert again.history["t"][0] == full.history["t"][-1]


def test_a_restart_that_does_not_fit_is_refused(tmp_path):
    case = fi.load_case(CASES / "impacting_bar.yaml", ["output.vtk=false", "solver.t_end=0.5"])
    fi.run(case, tmp_path / "done")
    with pytest.raises(CaseError, match=r"the checkpoint does not fit this case: .*solver.dt \(checkpoint 0.002, "
                                        r"case 0.001\)"):
        fi.run(case.with_changes({"solver.dt": 0.001, "solver.t_end": 1.0}), restart=tmp_path / "done")
    with pytest.raises(CaseError, match=r"solver.method \(checkpoint 'newmark', case 'moreau_jean'\)"):
        fi.run(case.with_changes({"solver.method": "moreau_jean", "solver.t_end": 1.0}), restart=tmp_path / "done")
    with pytest.raises(CaseError, match="the checkpoint is at t = 0.5, not before the case's t_end = 0.5"):
        fi.run(case, restart=tmp_path / "done")
    with pytest.raises(CaseError, match="no checkpoint there"):
        fi.run(case, restart=tmp_path)
    with pytest.raises(TypeError, match="restart as a folder"):
        fi.run(case, restart=3)


def test_an_interrupted_run_keeps_its_last_checkpoint_and_continues_to_the_same_end(tmp_path):
    """SIGTERM in the middle of a run with checkpoints every 200 steps: the output folder's earlier
    result stays as it was, the last checkpoint is kept in OUTDIR.checkpoint (the one line says so),
    and the run continued from it ends as the uninterrupted one."""
    case = str(CASES / "impacting_bar.yaml")
    common = ["--set", "output.vtk=false", "--set", "solver.t_end=400", "--set", "output.checkpoint_every=200"]
    out = tmp_path / "run"
    first = subprocess.run([sys.executable, "-m", "fem_impact", "run", case, "-o", str(out), "-q",
                            "--set", "solver.t_end=1", "--set", "output.vtk=false"], capture_output=True, text=True)
    assert first.returncode == 0, first.stderr
    before = (out / "history.csv").read_bytes()
    process = subprocess.Popen([sys.executable, "-m", "fem_impact", "run", case, "-o", str(out), "-q", *common],
                               stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not list(tmp_path.glob(".run.checkpoint-*/checkpoint/state.json")):
        assert process.poll() is None and time.monotonic() < deadline, "no checkpoint was written"
        time.sleep(0.05)
    time.sleep(0.3)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 128 + signal.SIGTERM
    kept = tmp_path / "run.checkpoint"
    assert f"kept in {kept}: continue it with --restart {kept}" in err
    assert (out / "history.csv").read_bytes() == before           # the earlier result untouched
    # a folder of that name that is not a checkpoint fem-impact kept is never replaced: kept beside it
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine.checkpoint").mkdir()
    (tmp_path / "mine.checkpoint" / "state.json").write_text("{}")
    from fem_impact.app.outdir.claim import _keep_checkpoint

    import shutil

    staging = tmp_path / ".mine.checkpoint-1"
    shutil.copytree(kept, staging / "checkpoint")
    where, when = _keep_checkpoint(staging, tmp_path / "mine")
    assert where.name.startswith("mine.checkpoint-") and (where / "state.json").is_file() and when.startswith("t = ")
    assert (tmp_path / "mine.checkpoint" / "state.json").read_text() == "{}" and not staging.exists()
    assert not list(tmp_path.glob(".run.*"))                      # no debris
    saved = json.loads((kept / "state.json").read_text())
    assert 0 < saved["step"] < 200_000 and saved["step"] % 200 == 0
    # continued to a nearer end, and compared with an uninterrupted run to that end
    t_end = saved["t"] + 2.0
    finish = subprocess.run([sys.executable, "-m", "fem_impact", "run", case, "-o", str(tmp_path / "finished"), "-q",
                             *common, "--set", f"solver.t_end={t_end}", "--restart", str(kept)],
                            capture_output=True, text=True)
    assert finish.returncode == 0, finish.stderr
    whole = fi.run(fi.load_case(case, ["output.vtk=false", f"solver.t_end={t_end}"]))
    assert_same_from(whole.history, fi.Result.load(tmp_path / "finished").history, tol=1e-10)


def test_a_checkpoint_is_read_back_by_the_dofs_numbers_when_the_mesh_is_distributed_otherwise(tmp_path):
    """Two runs on as many ranks may number and distribute the nodes otherwise (dolfinx's partitioner):
    the full model's vectors are saved with their dofs' partition-independent numbers and gathered back
    by them. Here the dofs come back in another order: every vector follows it, the rest stays."""
    from mpi4py import MPI

    from fem_impact.app.checkpoint.reading import Damaged, open_checkpoint, read_parts

    case = fi.load_case(CASES / "impacting_bar.yaml", ["output.vtk=false", "solver.t_end=0.5", "mesh.dim=2",
                                                       "mesh.cells=20"])
    result = fi.run(case, tmp_path / "run")
    saved = open_checkpoint(tmp_path / "run", MPI.COMM_WORLD)
    now = {"dofs": result.summary["dofs"], "modes": None}
    import h5py

    with h5py.File(tmp_path / "run" / "checkpoint" / "rank-0.h5") as f:
        keys = f["dof_keys"][()]
    same = read_parts(saved, MPI.COMM_WORLD, now, keys)
    order = np.random.default_rng(3).permutation(keys.size)
    moved = read_parts(saved, MPI.COMM_WORLD, now, keys[order])
    assert np.array_equal(moved["integrator"]["U"], same["integrator"]["U"][order])
    assert np.array_equal(moved["integrator"]["V"], same["integrator"]["V"][order])
    assert np.array_equal(moved["integrator"]["state"][2]["gap"], same["integrator"]["state"][2]["gap"])  # (p rows)
    assert moved["integrator"]["state"][2]["U"] == ("alias", "U")
    with pytest.raises(Damaged, match="its dofs are not this case's"):
        read_parts(saved, MPI.COMM_WORLD, now, keys + 10**9)


# -- a restart under a changed case: applied consistently, or refused naming the keys ------------------
# The step of a load switched between the checkpoint's time tc and the next step's, tc + dt: 0 up to tc,
# 1 from tc + dt on, exactly (min and max of the linear ramp)
def switch(tc: float, dt: float) -> str:
    return f"max(0, min(1, (t - {tc + 0.5 * dt!r})/{0.25 * dt!r}))"


BAR = ["output.vtk=false", "mesh.cells=50", "solver.method=moreau_jean", "solver.dt=0.01", "solver.t_end=0.05"]
BLOCK = ["output.vtk=false", "solver.t_end=0.05"]
BEAM = ["output.vtk=false", "mesh.cells=10", "solver.t_end=0.05", "solver.dt=0.01"]
# the reduced model: modes: auto with a loose tolerance, so that the output's rate decides the count
MODAL = ["output.vtk=false", "mesh.cells=100", "solver.method=modal", "solver.t_end=0.05", "solver.dt=0.01",
         "solver.tolerance=0.3"]


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    """Short runs whose checkpoints (at t = 0.05) the tests below continue under changed cases."""
    folder = tmp_path_factory.mktemp("checkpoints")
    made = {}
    for name, case, changes in (("bar", "impacting_bar.yaml", BAR), ("block", "sliding_block.yaml", BLOCK),
                                ("beam", "base_excited_beam.yaml", BEAM), ("modal", "impacting_bar.yaml", MODAL)):
        made[name] = (fi.load_case(CASES / case, changes), folder / name)
        fi.run(made[name][0], folder / name)
    return made


@pytest.mark.parametrize("which, changes, reference, keys", [
    # an added force on the bar's free end: the reference switches it on after the checkpoint
    ("bar", {"loads": [{"nodes": "right", "force": [-1.0]}]},
     {"loads": [{"nodes": "right", "force": [f"-1.0*{switch(0.05, 0.01)}"]}]}, ["loads.0.nodes", "loads.0.force.0"]),
    # the block's gravity doubled through the parameter its load uses (friction: the warm start goes on)
    ("block", {"parameters.g": 20.0},
     {"loads.0.acceleration": [0.0, f"-(g*(1 - {switch(0.05, 0.002)}) + 20*{switch(0.05, 0.002)})"]},
     ["parameters.g"]),
    # gravity on a beam shaken by its support, which takes the load on its held nodes: the reactions too
    ("beam", {"loads": [{"body": "all", "acceleration": [0.0, -9.81]}]},
     {"loads": [{"body": "all", "acceleration": [0.0, f"-9.81*{switch(0.05, 0.01)}"]}]},
     ["loads.0.body", "loads.0.acceleration.0", "loads.0.acceleration.1"]),
])
def test_a_restart_under_changed_loads_is_the_run_that_switched_them_at_the_checkpoint(tmp_path, checkpoints, which,
                                                                                       changes, reference, keys):
    """Loads are the run's time inputs: a restart continues the saved state under the case's loads from
    the checkpoint's time on (the step from it starts from the load the saved run had there), which is
    the uninterrupted run whose loads switch between the checkpoint's step and the next, to round-off,
    its energy budget included (the external work goes on)."""
    case, saved = checkpoints[which]
    longer = case.with_changes({"solver.t_end": 0.2})
    continued = fi.run(longer.with_changes(changes), tmp_path / "continued", restart=saved)
    switched = fi.run(longer.with_changes(reference), tmp_path / "switched")
    assert_same_from(switched.history, continued.history)
    unchanged = fi.run(longer, tmp_path / "unchanged", restart=saved)
    assert not np.allclose(unchanged.history["external_work"], continued.history["external_work"])
    assert continued.summary["restarted_from"]["changed"] == keys
    assert unchanged.summary["restarted_from"]["changed"] == []


@pytest.mark.parametrize("which, change, named", [
    ("bar", "solver.level=velocity", "solver.level"),
    ("bar", "solver.theta=1", "solver.theta"),
    ("bar", "solver.method=newmark", "solver.method"),
    ("bar", "solver.dt=0.005", "solver.dt"),
    ("bar", "solver.mass=lumped", "solver.mass"),
    ("bar", "material.rho=2", "material.rho"),
    ("bar", "material.area=2", "material.area"),
    ("bar", "material.E=2", "material.E"),
    ("bar", "mesh.length=2", "mesh.length"),
    ("bar", "mesh.cells=60", "mesh.cells"),
    ("bar", "damping.alpha=1", "damping.alpha"),
    ("bar", "contacts.0.stiffness=1000", "contacts.0.stiffness"),
    ("bar", "contacts.0.gap=0.2", "contacts.0.gap"),
    ("bar", "supports=[{nodes: right, fix: [x]}]", "supports.0.nodes"),
    ("bar", "initial.velocity=[-2.0]", "initial.velocity.0"),
    ("block", "contacts.0.friction=0", "contacts.0.friction"),
    ("block", "mesh.elements=hex", "mesh.elements"),
    ("block", "parameters.v0=3", "parameters.v0"),    # (used by the initial velocity, not by a load)
    ("block", "contacts.0.motion=['0.5*t', 0]", "contacts.0.motion.0"),   # (the floor set moving: a new relation)
])
def test_a_restart_refuses_a_change_of_what_its_state_depends_on_naming_the_key(checkpoints, which, change, named):
    """The model, its constraints, the method and its keys and the initial state: the saved state belongs
    to them, so a restart that changes one is refused before anything runs, naming every key that differs."""
    case, saved = checkpoints[which]
    changed = case.with_changes(["solver.t_end=0.2", change])
    with pytest.raises(CaseError, match=rf"the checkpoint does not fit this case: .*{re.escape(named)} \(checkpoint "):
        fi.run(changed, restart=saved)


def test_a_restart_of_the_reduced_model_keeps_its_modes_and_its_static_correction_its_loads(checkpoints):
    """The reduced model's state is its kept modes' coordinates: a restart whose modes: auto would keep
    another count is refused (the count to give is named); its static correction holds the saved loads'
    quasi-static response at the checkpoint's time, so a changed load is refused there."""
    case, saved = checkpoints["modal"]
    with pytest.raises(CaseError, match=r"state.json: the checkpoint's model has \d+ modes kept by the reduced model, "
                                        r"this case's \d+ .*give solver.modes: \d+"):
        fi.run(case.with_changes(["solver.t_end=0.2", "output.every=1"]), restart=saved)
    with pytest.raises(CaseError, match="loads.0.nodes: the reduced model's static correction holds the response to "
                                        "the saved run's loads"):
        fi.run(case.with_changes(["solver.t_end=0.2", "loads=[{nodes: right, force: [-1.0]}]"]), restart=saved)


# -- a damaged checkpoint: one line naming the file, for --restart and for initial: {from: ...} ---------
def _state(folder):
    return folder / "checkpoint" / "state.json"


def _rank(folder):
    return folder / "checkpoint" / "rank-0.h5"


def _edit_state(change):
    def damage(folder):
        state = json.loads(_state(folder).read_text())
        change(state)
        _state(folder).write_text(json.dumps(state))
    return damage


def _edit_rank(change):
    def damage(folder):
        import h5py

        with h5py.File(_rank(folder), "r+") as f:
            change(f)
    return damage


def _longer_U(f):
    U = f["integrator/U"][()]
    del f["integrator/U"]
    f["integrator/U"] = np.zeros(U.size + 3)


def _flipped_byte(folder):
    import h5py

    with h5py.File(_rank(folder)) as f:
        U = f["integrator/U"]
        at = U.id.get_offset() if U.chunks is None else U.id.get_chunk_info(0).byte_offset
    data = bytearray(_rank(folder).read_bytes())
    data[at + 20] ^= 0xFF
    _rank(folder).write_bytes(bytes(data))


DAMAGES = {
    "state.json truncated": ("state.json", lambda d: _state(d).write_bytes(_state(d).read_bytes()[:100])),
    "state.json empty": ("state.json", lambda d: _state(d).write_bytes(b"")),
    "state.json a list": ("state.json", lambda d: _state(d).write_text("[1, 2]")),
    "state.json binary": ("state.json", lambda d: _state(d).write_bytes(bytes(range(256)) * 2)),
    "t: abc": ("state.json", _edit_state(lambda s: s.update(t="abc"))),
    "t: null": ("state.json", _edit_state(lambda s: s.update(t=None))),
    "t edited": ("rank-0.h5", _edit_state(lambda s: s.update(t=0.02))),   # (the rank file's t and digest)
    "step edited": ("rank-0.h5", _edit_state(lambda s: s.update(step=3))),
    "no t": ("state.json", _edit_state(lambda s: s.pop("t"))),
    "no model": ("state.json", _edit_state(lambda s: s.pop("model"))),
    "no format": ("state.json", _edit_state(lambda s: s.pop("format"))),
    "rank-0.h5 missing": ("rank-0.h5", lambda d: _rank(d).unlink()),
    "rank-0.h5 truncated": ("rank-0.h5", lambda d: _rank(d).write_bytes(_rank(d).read_bytes()[:2000])),
    "rank-0.h5 empty": ("rank-0.h5", lambda d: _rank(d).write_bytes(b"")),
    "rank-0.h5 random": ("rank-0.h5", lambda d: _rank(d).write_bytes(np.random.default_rng(1).bytes(5000))),
    "integrator deleted": ("rank-0.h5", _edit_rank(lambda f: f.__delitem__("integrator"))),
    "U deleted": ("rank-0.h5", _edit_rank(lambda f: f.__delitem__("integrator/U"))),
    "U of another length": ("rank-0.h5", _edit_rank(_longer_U)),
    "a byte of U flipped": ("rank-0.h5", _flipped_byte),
    "the state's t edited": ("rank-0.h5", _edit_rank(lambda f: f["integrator/state"].attrs.__setitem__("t", 0.02))),
}


@pytest.mark.parametrize("how", ["--restart", "initial.from"])
@pytest.mark.parametrize("damage", list(DAMAGES))
def test_a_damaged_checkpoint_is_refused_in_one_line_naming_its_file(tmp_path, checkpoints, damage, how):
    """Whatever is wrong with a checkpoint's files (cut short, empty, not what they should hold, edited, of
    another length), a restart and a run from it refuse it before the time loop, naming the file."""
    case, saved = checkpoints["bar"]
    folder = tmp_path / "damaged"
    shutil.copytree(saved, folder)
    file, damage = DAMAGES[damage]
    damage(folder)
    with pytest.raises(CaseError) as refused:
        if how == "--restart":
            fi.run(case.with_changes({"solver.t_end": 0.2}), tmp_path / "out", restart=folder)
        else:
            fi.run(case.with_changes({"initial": {"from": str(folder)}}), tmp_path / "out")
    message = str(refused.value)
    assert str(folder / "checkpoint" / file) in message and message.isprintable(), message
    assert message.startswith(how) if how == "--restart" else "initial.from" in message
    assert not (tmp_path / "out").exists()


def test_initial_from_a_relative_folder_without_a_checkpoint_names_the_line_and_where_it_starts(tmp_path):
    first = "/".join(("..", "runs", "first"))   # (a folder of the test's: no document of the repository)
    (tmp_path / "cases").mkdir()
    text = (CASES / "impacting_bar.yaml").read_text().replace("  velocity: [-1.0]", f"  from: {first}")
    (tmp_path / "cases" / "bar.yaml").write_text("\n".join(line for line in text.splitlines()
                                                          if not line.startswith("reference")))
    case = fi.load_case(tmp_path / "cases" / "bar.yaml", ["output.vtk=false", "mesh.cells=20"])
    line = next(i for i, text in enumerate((tmp_path / "cases" / "bar.yaml").read_text().splitlines(), 1)
                if "from:" in text)
    with pytest.raises(CaseError, match=rf"bar.yaml:{line}: initial.from: {re.escape(str(tmp_path))}/runs/first: no "
                                        rf"checkpoint there .*\(the relative path '{first}' starts at "
                                        rf"{re.escape(str(tmp_path / 'cases'))}\)"):
        fi.run(case)


def test_initial_from_takes_another_model_on_the_same_unknowns_and_refuses_other_modes(tmp_path, checkpoints):
    """initial: {from: DIR} starts a new run from a saved state: the model may differ where the unknowns
    mean the same (the full model's nodal values on the same mesh), not where they do not (the reduced
    model's modal coordinates, when its modes change with the material)."""
    case, saved = checkpoints["bar"]
    stiffer = fi.run(case.with_changes({"initial": {"from": str(saved)}, "material.E": 2.0}))
    assert stiffer.summary["steps"] == 5
    case, saved = checkpoints["modal"]
    with pytest.raises(CaseError, match=r"initial.from: .*state.json: its unknowns are not this case's: material.E "
                                        r"\(checkpoint 1.0, case 2.0\)"):
        fi.run(case.with_changes({"initial": {"from": str(saved)}, "material.E": 2.0}))


def test_initial_from_under_a_support_the_saved_run_had_not_holds_its_nodes_at_rest(checkpoints):
    """The case's supports hold their dofs from the start, as they do the case's own initial fields: a
    saved state moving there is not carried over (a held node of unit placeholder mass would drift on)."""
    case, saved = checkpoints["bar"]
    held = fi.run(case.with_changes({"initial": {"from": str(saved)}, "solver.t_end": 0.2,
                                     "supports": [{"nodes": "right", "fix": ["x"]}]}))
    assert not held.history["right.ux"].any() and not held.history["right.vx"].any()


def killed_run_checkpoint(tmp_path, name: str, t_end: float) -> tuple:
    """What a run into tmp_path/NAME killed outright (SIGKILL) after a checkpoint at t_end leaves: its hidden
    .NAME.checkpoint-PID/checkpoint (a process id that does not exist); returns (that folder, the case)."""
    import shutil

    case = fi.load_case(CASES / "impacting_bar.yaml", ["output.vtk=false", "solver.t_end=1"])
    saved = fi.run(case.with_changes({"solver.t_end": t_end}), tmp_path / f"made-{t_end}").outdir
    hidden = tmp_path / f".{name}.checkpoint-4194303"
    hidden.mkdir()
    shutil.copytree(saved / "checkpoint", hidden / "checkpoint")
    shutil.rmtree(saved)
    return hidden, case


@pytest.mark.parametrize("inner", [False, True], ids=["the hidden folder", "its checkpoint/"])
def test_a_restart_from_a_killed_runs_hidden_checkpoint_into_the_same_folder(tmp_path, inner):
    """Claiming the folder keeps the killed run's checkpoint in NAME.checkpoint (it moved it away, and the
    restart then found "no checkpoint there"): the restart follows it there."""
    hidden, case = killed_run_checkpoint(tmp_path, "run", 0.5)
    result = fi.run(case, tmp_path / "run", restart=hidden / "checkpoint" if inner else hidden)
    kept = tmp_path / "run.checkpoint"
    assert result.summary["restarted_from"]["folder"] == str(kept) and result.summary["restarted_from"]["t"] == 0.5
    assert not hidden.exists() and (kept / "state.json").is_file()


def test_a_restart_reads_the_checkpoint_it_names_not_another_killed_runs(tmp_path):
    """NAME.checkpoint is the restart's (t = 0.5); a run killed later left a hidden one (t = 0.25). Claiming
    the folder keeps that one beside, never over the one the restart reads."""
    import shutil

    first, case = killed_run_checkpoint(tmp_path, "run", 0.5)
    shutil.move(first / "checkpoint", tmp_path / "run.checkpoint")
    first.rmdir()
    hidden, _ = killed_run_checkpoint(tmp_path, "run", 0.25)
    result = fi.run(case, tmp_path / "run", restart=tmp_path / "run.checkpoint")
    assert result.summary["restarted_from"]["t"] == 0.5 and result.history["t"][0] == 0.5
    beside = sorted(tmp_path.glob("run.checkpoint-*"))
    assert len(beside) == 1 and json.loads((beside[0] / "state.json").read_text())["t"] == 0.25
    assert not hidden.exists()


def test_a_checkpoint_written_before_a_field_was_added_restores_it_at_its_default():
    """A state saved by an earlier version lacks the fields added since (EnergyBudget.losses): those take
    their defaults; a field without a default that is missing is still refused."""
    from fem_impact.app.checkpoint.state import capture, check, restore
    from fem_impact.mechanics.energy import EnergyBudget

    class Part:
        __checkpoint__ = ("budget",)

        def __init__(self, budget):
            self.budget = budget

    saved = capture(Part(EnergyBudget(kinetic=1.5, strain=0.25, losses={"stop_loss": 0.125})))
    earlier = {"budget": (*saved["budget"][:2], {k: v for k, v in saved["budget"][2].items() if k != "losses"})}
    part = Part(EnergyBudget(losses={"stop_loss": 9.0}))
    check(part, earlier)
    restore(part, earlier)
    assert part.budget.losses == {} and (part.budget.kinetic, part.budget.strain) == (1.5, 0.25)
    from fem_impact.integrators.state import StepState

    rows = np.zeros(1)
    state = StepState(step=3, t=0.5, U=np.ones(2), V=np.zeros(2), A=np.zeros(2), gap=rows, force=rows, impulse=rows,
                      energy=EnergyBudget(), normal_displacement=rows, normal_velocity=rows)
    stepped = Part(state)
    saved = capture(stepped)
    without_t = {"budget": (*saved["budget"][:2], {k: v for k, v in saved["budget"][2].items() if k != "t"})}
    with pytest.raises(ValueError, match=r"budget\.t: missing"):   # (StepState.t has no default)
        check(stepped, without_t)
