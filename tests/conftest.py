"""Shared fixtures: run a case file through the real pipeline and read its history."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

# Modes and static solves are cached on disk: tests keep their own cache, away from the user's.
os.environ["FEM_IMPACT_CACHE"] = tempfile.mkdtemp(prefix="fem-impact-cache-")

# Open MPI started for one process, as the command line starts it (fem_impact/app/cli.py, SERIAL_MPI): in
# this process and the interpreters the tests start (mpirun's ranks are told otherwise by mpirun).
import fem_impact.app.cli  # noqa: E402, F401

ROOT = Path(__file__).resolve().parents[1]
CASES = ROOT / "cases"


class ConstantLoad:
    """A load vector constant in time, for integrators on tiny systems (``Operators.load``)."""

    time_dependent = False

    def __init__(self, value):
        self.value = value

    def evaluate(self, t, out):
        out[:] = self.value
        return out


def read_history(outdir: Path) -> np.ndarray:
    """history.csv as a structured array; dots in column names become underscores."""
    with open(outdir / "history.csv") as f:
        names = [n.replace(".", "_") for n in f.readline().strip().split(",")]
    return np.genfromtxt(outdir / "history.csv", delimiter=",", skip_header=1, names=names)


def run_case_file(case, outdir: Path, *overrides: str):
    """Run a case in-process; returns (summary dict, history array)."""
    from fem_impact.app.pipeline import run_case

    summary = run_case(Path(case), outdir, list(overrides), progress=False)
    return summary, read_history(outdir)


def run_cli(*args: str, cwd=None) -> subprocess.CompletedProcess:
    """``fem-impact ARGS`` in a fresh interpreter, as a user would call it."""
    return subprocess.run([sys.executable, "-m", "fem_impact", *args], capture_output=True, text=True, cwd=cwd)


@pytest.fixture
def run(tmp_path):
    """``run("impacting_bar", "mesh.cells=100", ...)`` -> (summary, history)."""
    counter = iter(range(1000))

    def _run(name: str, *overrides: str):
        case = CASES / f"{name}.yaml" if not str(name).endswith(".yaml") else Path(name)
        return run_case_file(case, tmp_path / f"run{next(counter)}", *overrides)

    return _run


def load_summary(outdir: Path) -> dict:
    return json.loads((outdir / "summary.json").read_text())
