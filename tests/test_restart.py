"""Checkpoint and restart (fem_impact/app/checkpoint.py): a run continued from its checkpoint gives the
uninterrupted run's history from that time on, to round-off, for every method; an interrupted run
keeps its last checkpoint beside its output folder and continues from it to the same end."""

from __future__ import annotations

import json
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
    # the steps between impacts in blocks (integrators/blocks.py), checkpoints within the run stopping them
    "modal_blocks": ("impact_oscillator.yaml", ["solver.blocks=true", "solver.t_end=40",
                                                "output.checkpoint_every=1234"]),
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
        if name.endswith((".px", ".py", ".pz")):   # a body's momentum: on the scale of its largest component
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
    with pytest.raises(CaseError, match="the checkpoint does not fit this case: its dt is 0.002, the case's 0.001"):
        fi.run(case.with_changes({"solver.dt": 0.001, "solver.t_end": 1.0}), restart=tmp_path / "done")
    with pytest.raises(CaseError, match="its method is 'newmark', the case's 'moreau_jean'"):
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
    from fem_impact.app.outdir import _keep_checkpoint

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

    from fem_impact.app.checkpoint import load

    case = fi.load_case(CASES / "impacting_bar.yaml", ["output.vtk=false", "solver.t_end=0.5", "mesh.dim=2",
                                                       "mesh.cells=20"])
    fi.run(case, tmp_path / "run")
    meta = {"method": "newmark"}
    _, same = load(tmp_path / "run", MPI.COMM_WORLD, meta, keys=("method",))
    import h5py

    with h5py.File(tmp_path / "run" / "checkpoint" / "rank-0.h5") as f:
        keys = f["dof_keys"][()]
    order = np.random.default_rng(3).permutation(keys.size)
    _, moved = load(tmp_path / "run", MPI.COMM_WORLD, meta, keys=("method",), dof_keys=keys[order])
    assert np.array_equal(moved["integrator"]["U"], same["integrator"]["U"][order])
    assert np.array_equal(moved["integrator"]["V"], same["integrator"]["V"][order])
    assert np.array_equal(moved["integrator"]["state"][2]["gap"], same["integrator"]["state"][2]["gap"])  # (p rows)
    assert moved["integrator"]["state"][2]["U"] == ("alias", "U")
    with pytest.raises(CaseError, match="its dofs are not this case's"):
        load(tmp_path / "run", MPI.COMM_WORLD, meta, keys=("method",), dof_keys=keys + 10**9)


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
