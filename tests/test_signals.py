"""Interrupted runs leave the earlier result intact and no staging folder (issue 11; fem_impact/outdir.py).

A long run into a folder that holds an earlier result is killed in its time loop with SIGTERM,
SIGHUP, SIGQUIT or SIGINT (serial: 128 + the signal number, one line; under ``mpirun -n 2`` the
signal goes to mpirun, which passes SIGTERM to the ranks and exits with status 1 itself; every rank
removes the staging folder, since rank 0 may be inside an MPI call that does not return). SIGKILL
cannot be caught: its staging folder is left, and the next run into the folder removes it.
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


def start_and_kill(cmd, parent: Path, sig, target=None):
    """Start ``cmd``, wait until its time loop runs (its staging folder exists), send ``sig``; the result."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env())
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
    assert status != 0
    # Rank 0 says it, unless the signal found it inside an MPI call (then rank 1 cleans up, silently).
    assert "Traceback" not in stderr and stderr.count("interrupted") <= 1, stderr
    assert snapshot(out) == before
    time.sleep(0.5)
    assert debris(out.parent) == []


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
    assert snapshot(out) == before
    time.sleep(0.5)
    assert not [n for n in debris(out.parent) if ".partial-" in n]
