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
from fem_impact.references import column  # noqa: E402

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


# --- the benchmark checks of the test suite (docs/benchmarks.md B1, B2) ------------------------------


def contact_window(h, name):
    """(start, end) of the first contact: first step with a closed gap, first step open again."""
    gap = column(h, f"{name}.gap")
    closed = gap <= 1e-9 * np.abs(gap).max()
    i0 = int(np.argmax(closed))
    i1 = i0 + int(np.argmax(~closed[i0:]))
    t = column(h, "t")
    return t[i0], t[i1]


def b2_checks(h, L, E, rho, A, v0, g0, name="wall"):
    """B2 figures against the exact solution: returns relative errors by name.

    ``start``, ``duration`` of the first contact and ``mean_force`` over the exact contact
    phase relative to ``2L/c`` and ``rho c A v0``; total ``impulse`` relative to ``2 rho A L v0``;
    ``rebound``: mean velocity of the probe ``right`` after separation against ``+v0``;
    ``contact_end_u``: max over time of the error of the probe ``left`` relative to ``v0 L/c``.
    """
    c = np.sqrt(E / rho)
    t0, duration, force = g0 / v0, 2 * L / c, rho * c * A * v0
    t = column(h, "t")
    start, end = contact_window(h, name)
    in_contact = (t > t0) & (t <= t0 + duration)
    after = t > t0 + duration + 0.05 * L / c
    # After separation the bar moves rigidly at +v0; its ends oscillate about that (dispersion).
    rebound = column(h, "right.vx")[after].mean()
    exact_u0 = np.where(t < t0, -v0 * t, np.where(t < t0 + duration, -g0, -g0 + v0 * (t - t0 - duration)))
    return {
        "start": abs(start - t0) / duration,
        "duration": abs((end - start) - duration) / duration,
        "mean_force": abs(column(h, f"{name}.force")[in_contact].mean() - force) / force,
        "impulse": abs(column(h, f"{name}.impulse").sum() - 2 * rho * A * L * v0) / (2 * rho * A * L * v0),
        "rebound": abs(rebound - v0) / v0,
        "contact_end_u": np.abs(column(h, "left.ux") - exact_u0).max() / (v0 * L / c),
    }


def b1_exact_u0(t):
    """u(0, t) of B1 as in docs/benchmarks.md B1 (L = E = rho = 1, u0 = (1 - x)/2): period 3."""
    tau = np.mod(t, 3.0)
    return np.where(tau < 1, (1 - tau) / 2, np.where(tau < 2, 0.0, (tau - 2) / 2))
