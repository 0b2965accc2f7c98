"""Interrupted runs leave the earlier result intact and no staging folder (fem_impact/app/outdir/).

A long run into a folder that holds an earlier result is killed in its time loop with SIGTERM,
SIGHUP, SIGQUIT or SIGINT (serial: 128 + the signal number, one line; under ``mpirun -n 2`` the
signal goes to mpirun, which passes SIGTERM to the ranks, kills them a second later and exits with
status 1 itself; one rank says it in one line, rank 0 or another when rank 0 is inside an MPI call
that does not return, and every rank removes the staging folder). SIGKILL cannot be caught: its
staging folder is left, and the next run into the folder removes it. A signal ignored when the run
starts (nohup's SIGHUP) stays ignored.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import CASES, ROOT

CASE = CASES / "impacting_bar.yaml"
QUICK = ["--set", "mesh.cells=10", "--set", "solver.dt=0.01", "--set", "solver.t_end=0.05", "--set", "output.every=1"]
# About a minute of time loop: killed long before it ends.
LONG = ["--set", "mesh.cells=50", "--set", "solver.dt=0.0005", "--set", "solver.t_end=200", "--set",
        "output.every=100000"]


def command(*args):
    return [sys.executable, "-m", "fem_impact", *map(str, args)]


def env():
    # (this pytest process may have initialized MPI itself: its variables would confuse a child mpirun)
    return {**{k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "OPAL_"))},
            "PYTHONPATH": str(ROOT)}


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def debris(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p.name != "out")


@pytest.fixture
def earlier(tmp_path):
    """tmp_path/out holding an earlier result; returns (folder, its files)."""
    out = tmp_path / "out"
    done = subprocess.run(command("run", CASE, "-o", out, "-q", *QUICK), capture_output=True, text=True, env=env())
    assert done.returncode == 0, done.stderr
    return out, snapshot(out)


def default_signals() -> None:
    """The run starts with the default dispositions, also when the suite was started with SIGHUP, SIGINT or
    SIGQUIT ignored (nohup; a shell's background job ignores SIGINT and SIGQUIT), which the run would rightly keep."""
    for sig in (signal.SIGHUP, signal.SIGINT, signal.SIGQUIT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)


def start_and_kill(cmd, parent: Path, sig, target=None):
    """Start ``cmd``, wait until its time loop runs (its staging folder exists), send ``sig``; the result."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env(),
                            preexec_fn=default_signals)
    deadline = time.monotonic() + 120
    while not list(parent.glob(".out.partial-*")):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the run did not start its time loop"
        time.sleep(0.1)
    time.sleep(0.3)   # inside the loop
    os.kill(target(proc) if target else proc.pid, sig)
    stdout, stderr = proc.communicate(timeout=120)
    return proc.returncode, stderr


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, pytest.param(signal.SIGQUIT, marks=pytest.mark.slow),
                                 signal.SIGINT])
def test_serial_run_interrupted(earlier, sig):
    out, before = earlier
    status, stderr = start_and_kill(command("run", CASE, "-o", out, "-q", *LONG), out.parent, sig)
    assert status == 128 + sig, stderr
    assert stderr.strip() == f"fem-impact: interrupted by {signal.Signals(sig).name} (the output folder was left " \
                             "as it was)"
    assert snapshot(out) == before
    assert debris(out.parent) == []


def test_sigkill_leaves_a_staging_folder_that_the_next_run_removes(earlier):
    out, before = earlier
    status, _ = start_and_kill(command("run", CASE, "-o", out, "-q", *LONG), out.parent, signal.SIGKILL)
    assert status == -signal.SIGKILL
    assert snapshot(out) == before
    stale = [p for p in out.parent.iterdir() if p.name.startswith(".out.partial-")]
    assert len(stale) == 1 and any(stale[0].iterdir())   # the killed run's files
    again = subprocess.run(command("run", CASE, "-o", out, "-q", *QUICK), capture_output=True, text=True, env=env())
    assert again.returncode == 0, again.stderr
    assert debris(out.parent) == []


LOST = """
import gc, os, signal, sys, weakref
import fem_impact.integrators as integrators
from fem_impact.app.cli import main

plain = integrators.integrate

def integrate(*args, **kwargs):   # a signal whose handler runs inside a weakref callback, then the whole run
    class Thing:
        pass
    thing = Thing()
    keep = weakref.ref(thing, lambda ref: (os.kill(os.getpid(), signal.SIGTERM), [0 for _ in range(1000)]))
    del thing
    gc.collect()
    return plain(*args, **kwargs)

integrators.integrate = integrate
sys.exit(main(sys.argv[1:]))
"""


def test_a_signal_whose_interrupt_python_lost_still_interrupts_the_run(earlier):
    """SIGTERM handled inside a weakref callback: Python prints the KeyboardInterrupt raised there as
    "Exception ignored" and goes on, and the run used to finish and put its result in place (status 0; seen
    once in test_sweep_interrupted). The claim asks before it installs: interrupted, the earlier result kept,
    and the one line alone on stderr (the default tier once saw the traceback of the lost interrupt there)."""
    out, before = earlier
    proc = subprocess.run([sys.executable, "-c", LOST, "run", str(CASE), "-o", str(out), "-q", *QUICK],
                          capture_output=True, text=True, env=env(), preexec_fn=default_signals)
    assert proc.returncode == 143 and "interrupted by SIGTERM" in proc.stderr, proc.stderr
    # (the lost KeyboardInterrupt, which Python printed as "Exception ignored" with its traceback, is not shown)
    assert "Exception ignored" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert snapshot(out) == before
    # (the run's last checkpoint is kept beside the folder, as on every interruption, and the line says so)
    assert debris(out.parent) in ([], ["out.checkpoint"])
    assert not debris(out.parent) or "out.checkpoint" in proc.stderr


@pytest.mark.slow
def test_sweep_interrupted(earlier):
    """Another command that stages its folder: the same cleanup."""
    out, _ = earlier
    sweep_out = out.parent / "out"
    shutil.rmtree(sweep_out)
    status, stderr = start_and_kill(command("sweep", CASE, "--vary", "solver.dt=0.0005,0.001", "-o", sweep_out,
                                            "-q", *LONG[:2], *LONG[4:]), out.parent, signal.SIGTERM)
    assert status == 143 and "interrupted by SIGTERM" in stderr, stderr
    assert debris(out.parent) == []


@pytest.mark.mpi
@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, pytest.param(signal.SIGHUP, marks=pytest.mark.slow)])
def test_mpi_run_interrupted(earlier, sig):
    """The user's Ctrl-C (or a SIGTERM, a closed terminal) reaches mpirun; it passes SIGTERM to every rank."""
    out, before = earlier
    cmd = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2",
           *command("run", CASE, "-o", out, "-q", *LONG)]
    status, stderr = start_and_kill(cmd, out.parent, sig)
    assert status == 1   # (mpirun's own, when it received the signal)
    # (the ranks receive SIGTERM from mpirun, whatever it received)
    assert stderr == "fem-impact: interrupted by SIGTERM (the output folder was left as it was)\n"
    assert snapshot(out) == before
    time.sleep(1.5)
    assert debris(out.parent) == []


@pytest.mark.mpi
@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
@pytest.mark.parametrize("sig", [signal.SIGTERM, pytest.param(signal.SIGINT, marks=pytest.mark.slow)])
def test_mpi_run_interrupted_keeps_its_checkpoint_and_says_so(earlier, sig):
    """With output.checkpoint_every under mpirun: the last checkpoint is kept in NAME.checkpoint (not left in
    the hidden .NAME.checkpoint-PID), and the one line says where, before mpirun kills the ranks."""
    out, before = earlier
    cmd = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2",
           *command("run", CASE, "-o", out, "-q", *LONG, "--set", "output.checkpoint_every=200")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env(),
                            preexec_fn=default_signals)
    deadline = time.monotonic() + 120
    while not list(out.parent.glob(".out.checkpoint-*/checkpoint/state.json")):
        assert proc.poll() is None and time.monotonic() < deadline, "no checkpoint was written"
        time.sleep(0.05)
    proc.send_signal(sig)
    _, stderr = proc.communicate(timeout=120)
    kept = out.parent / "out.checkpoint"
    assert proc.returncode == 1
    assert stderr.startswith("fem-impact: interrupted by SIGTERM (the output folder was left as it was; the run's "
                             "last checkpoint (t = ") and stderr.count("\n") == 1, stderr
    assert stderr.endswith(f"is kept in {kept}: continue it with --restart {kept})\n"), stderr
    assert (kept / "state.json").is_file() and sorted(p.name for p in kept.iterdir()) == \
        ["rank-0.h5", "rank-1.h5", "state.json"]
    assert snapshot(out) == before
    time.sleep(1.5)
    assert debris(out.parent) == ["out.checkpoint"]


@pytest.mark.mpi
@pytest.mark.slow
@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
def test_mpi_one_rank_signalled(earlier):
    """A signal to one rank only (here rank 1, which does not own the files): it still removes the staging
    folder, exits with 128 + signal, and mpirun ends the job with that status."""
    out, before = earlier
    cmd = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2",
           *command("run", CASE, "-o", out, "-q", *LONG)]

    def last_rank(proc):
        ranks = subprocess.run(["ps", "-o", "pid=", "--ppid", str(proc.pid)], capture_output=True, text=True)
        return int(ranks.stdout.split()[-1])

    status, stderr = start_and_kill(cmd, out.parent, signal.SIGTERM, target=last_rank)
    assert status == 143, stderr
    # rank 1 says it (rank 0 waits for it in an MPI call), then mpirun its own lines
    assert stderr.startswith("fem-impact: interrupted by SIGTERM (the output folder was left as it was)\n"), stderr
    assert stderr.count("fem-impact:") == 1, stderr
    assert snapshot(out) == before
    time.sleep(0.5)
    assert not [n for n in debris(out.parent) if ".partial-" in n]


def test_a_run_started_with_sighup_ignored_goes_on(earlier):
    """nohup starts a run with SIGHUP ignored, so that it outlives the terminal: it must go on (it ended,
    status 129); SIGTERM still ends it in one line."""
    out, before = earlier
    proc = subprocess.Popen(command("run", CASE, "-o", out, "-q", *LONG), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env(),
                            preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN))
    deadline = time.monotonic() + 120
    while not list(out.parent.glob(".out.partial-*")):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.1)
    proc.send_signal(signal.SIGHUP)
    time.sleep(1.0)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 143 and stderr == "fem-impact: interrupted by SIGTERM (the output folder was left as " \
                                                "it was)\n", stderr
    assert snapshot(out) == before and debris(out.parent) == []


LOADING_HOOK = """
import os, signal, sys, time

class Interrupting:   # Ctrl-C while dolfinx initializes: its extension's import fails ("initialization failed")
    def find_spec(self, name, path=None, target=None):
        if name == "dolfinx":
            try:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(1)
            except KeyboardInterrupt:   # (as the extension's initialization turns it into its own error)
                raise ImportError("initialization failed") from None
        return None

sys.meta_path.insert(0, Interrupting())
from fem_impact.app.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_an_interrupt_while_the_libraries_load_is_one_line(tmp_path):
    result = subprocess.run([sys.executable, "-c", LOADING_HOOK, "run", CASE, "-o", tmp_path / "out", "-q", *QUICK],
                            capture_output=True, text=True, env=env(), timeout=300)
    assert result.returncode == 130, result.stderr
    assert result.stderr == "fem-impact: interrupted by SIGINT (the output folder was left as it was)\n"
    assert list(tmp_path.iterdir()) == []


# --- studies: they write in place and keep their completed levels (issue 16) ---------------------

STUDY = ["study", "convergence", CASE, "--vary", "mesh.cells=10,20,40", "--set", "solver.t_end=0.2", "-q"]

INTERRUPT_HOOK = """
import signal, sys
from fem_impact.app.outdir.interruption import Interrupted
from fem_impact.app.studies import levels, worker

after = int(sys.argv[1])   # SIGTERM once this many levels are recorded (0: when the first level starts)
finish, run_data = levels._finish, worker.run_data
done = []

def hooked_finish(*args, **kwargs):
    finish(*args, **kwargs)
    done.append(1)
    if len(done) == after:
        raise Interrupted(signal.SIGTERM)

def hooked_run_data(*args, **kwargs):
    if after == 0:
        raise Interrupted(signal.SIGTERM)
    return run_data(*args, **kwargs)

levels._finish, worker.run_data = hooked_finish, hooked_run_data
from fem_impact.app.cli import main
sys.exit(main(sys.argv[2:]))
"""


def interrupted_study(out: Path, after: int, *extra):
    return subprocess.run([sys.executable, "-c", INTERRUPT_HOOK, str(after), *map(str, STUDY), "-o", out, *extra],
                          capture_output=True, text=True, env=env(), timeout=300)


def outside_levels(folder: Path) -> dict[str, bytes]:
    return {k: v for k, v in snapshot(folder).items() if not k.startswith("levels/")}


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_study_interrupted_on_an_earlier_result_says_what_it_kept(earlier, jobs):
    """The issue's case: a study into an earlier result S, interrupted by SIGTERM after one level. The
    line says what was kept and that a rerun resumes; nothing of S but S/levels changed (not even its
    marker); the rerun resumes."""
    out, before = earlier
    result = interrupted_study(out, 1, "-j", jobs)
    assert result.returncode == 143, result.stderr
    assert result.stderr == (f"fem-impact: interrupted by SIGTERM (1 completed level of this run is kept in "
                             f"{out / 'levels'}; run the same command again to resume)\n")
    assert outside_levels(out) == before
    assert len(list((out / "levels").glob("*/level.json"))) == 1
    assert debris(out.parent) == []
    again = subprocess.run(command(*[a for a in STUDY if a != "-q"], "-o", out, "-j", jobs), capture_output=True,
                           text=True, env=env(), timeout=300)
    assert again.returncode == 0, again.stderr
    assert again.stderr.count("kept from an earlier run") == 1, again.stderr
    assert (out / "convergence.csv").is_file() and (out / "history.csv").read_bytes() == before["history.csv"]


def test_study_interrupted_before_a_level_completes_leaves_the_folder_as_it_was(earlier):
    out, before = earlier
    result = interrupted_study(out, 0)
    assert result.returncode == 143, result.stderr
    assert result.stderr == "fem-impact: interrupted by SIGTERM (the output folder was left as it was)\n"
    assert snapshot(out) == before
    assert sorted(p.name for p in out.iterdir()) == sorted({k.split("/")[0] for k in before})   # (checkpoint/)
    assert debris(out.parent) == []


def test_a_new_study_folder_interrupted_stays_a_result(tmp_path):
    """Interrupted after a level in a folder it made: the folder keeps its marker with the level (a
    rerun takes it, as a result); interrupted before any level: no folder is left."""
    from fem_impact.app.outdir.manifest import is_result

    out = tmp_path / "S"
    assert interrupted_study(out, 0).returncode == 143
    assert not out.exists() and list(tmp_path.iterdir()) == []
    result = interrupted_study(out, 2)
    assert result.returncode == 143 and "2 completed levels of this run are kept" in result.stderr, result.stderr
    assert is_result(out) and sorted(p.name for p in out.iterdir()) == [".fem-impact.json", "levels"]
    again = subprocess.run(command(*[a for a in STUDY if a != "-q"], "-o", out), capture_output=True, text=True,
                           env=env(), timeout=300)
    assert again.returncode == 0 and again.stderr.count("kept from an earlier run") == 2, again.stderr


FULL_DISK_HOOK = """
import errno, os, sys
import fem_impact.app.output as output

init, calls = output.HistoryWriter.__init__, []

def hooked(self, *args, **kwargs):   # the warm-up run, the first level, then the disk is full
    calls.append(1)
    if len(calls) == 3:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(args[0]))
    init(self, *args, **kwargs)

output.HistoryWriter.__init__ = hooked
from fem_impact.app.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_study_on_a_full_disk_stops_with_one_line(tmp_path):
    """A level that cannot be written is not a failed level: the study stops, status 3, and says what
    it kept."""
    out = tmp_path / "S"
    result = subprocess.run([sys.executable, "-c", FULL_DISK_HOOK, *map(str, STUDY), "-o", out], capture_output=True,
                            text=True, env=env(), timeout=300)
    assert result.returncode == 3, result.stderr
    level = sorted((out / "levels").iterdir())
    assert [p.name for p in level] == ["00-mesh.cells_10"]
    assert result.stderr == (f"fem-impact: the study failed: cannot write {out}/levels/01-mesh.cells_20/history.csv: "
                             f"No space left on device (1 completed level of this run is kept in {out / 'levels'}; "
                             "run the same command again to resume)\n")


def test_study_with_children_interrupted_by_sigterm(earlier):
    """The issue's command for real: ``study ... -j 2 -o S`` on an earlier result S, SIGTERM to the
    study once a level is recorded (the children, stopped, remove their staging folders)."""
    out, before = earlier
    cmd = command("study", "convergence", CASE, "--vary", "mesh.cells=10,20,1000", "--set", "solver.t_end=20",
                  "-j", "2", "-q", "-o", out)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env(),
                            preexec_fn=default_signals)
    deadline = time.monotonic() + 120
    while not list(out.glob("levels/*/level.json")):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no level completed"
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    kept = len(list(out.glob("levels/*/level.json")))
    assert proc.returncode == 143, stderr
    levels = "1 completed level of this run is" if kept == 1 else f"{kept} completed levels of this run are"
    assert stderr == (f"fem-impact: interrupted by SIGTERM ({levels} kept in {out / 'levels'}; run the same "
                      "command again to resume)\n")
    assert outside_levels(out) == before
    assert not [p for p in (out / "levels").iterdir() if p.name.startswith(".")]   # no staging folder, no lock
    assert debris(out.parent) == []


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT])
def test_a_signal_once_petsc_has_started_is_the_runs_to_answer(sig):
    """PETSc's own handler would abort (status 59, the staging folder and lock left); the run's answers."""
    script = f"""
import os, signal, sys
import fem_impact.app.cli
from fem_impact.app.outdir.interruption import Interrupted, install_signal_handlers
install_signal_handlers()
from petsc4py import PETSc   # starts PETSc, which installs its handlers unless told not to
PETSc.COMM_WORLD.barrier()
try:
    os.kill(os.getpid(), {int(sig)})
except Interrupted as err:
    sys.exit(100 + err.signum)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env(), timeout=120,
                          preexec_fn=default_signals)
    assert done.returncode == 100 + sig, done.stderr
    assert "PETSC ERROR" not in done.stderr
