"""The benchmark scripts still run (at their smallest size): no figures asserted, those are theirs."""

from __future__ import annotations

import subprocess
import sys

import pytest

from conftest import ROOT


def test_contact_scale_runs_at_its_smallest_size():
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "contact_scale.py"), "--quick"],
                          capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    rows = [line.split() for line in proc.stdout.splitlines() if line.strip()[:1].isdigit()]
    assert [r[:2] for r in rows] == [["1", "mean"], ["121", "each"]]


def test_contact_scale_with_friction_at_the_velocity_level_runs_at_its_smallest_size():
    """--friction with --method velocity: the frictional and the frictionless step at that level, the cone
    problems within the tolerance; newmark has no frictional step and is refused in one line."""
    script = str(ROOT / "benchmarks" / "contact_scale.py")
    proc = subprocess.run([sys.executable, script, "--friction", "0.3", "--quick", "--method", "velocity"],
                          capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("method: velocity, mu = 0.3")
    rows = [line.split() for line in proc.stdout.splitlines() if line.strip()[:1].isdigit()]
    assert [r[:2] for r in rows] == [["121", "1089"]] and float(rows[0][8]) <= 1e-10
    refused = subprocess.run([sys.executable, script, "--friction", "0.3", "--quick", "--method", "newmark"],
                             capture_output=True, text=True, cwd=ROOT)
    assert refused.returncode != 0 and "--friction takes moreau_jean" in refused.stderr
    assert "Traceback" not in refused.stderr


@pytest.mark.slow   # (16 runs; tests/test_mpi.py checks every method's serial and 2-rank histories in the default tier)
def test_scaling_runs_at_a_small_size_with_equal_histories():
    """benchmarks/scaling.py at 20 cells (252 unknowns), 12 steps, every method: serial and 2 ranks run and
    give the same history (to 1e-9 of each column's scale; the figures of time are the benchmark's); and the
    explicit plate at 2 cells (121 face rows): the same history, E <= E0, the momentum equal to the impulses."""
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "scaling.py"), "--sizes", "20", "--steps", "12",
                           "--plate", "2"], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stderr
    rows = [line.split() for line in proc.stdout.splitlines()
            if line.split()[:1] and line.split()[0] in ("moreau_jean", "newmark", "central_difference", "modal")]
    assert [r[0] for r in rows] == ["moreau_jean", "newmark", "central_difference", "modal"]
    assert all(r[1] == "252" and float(r[-1]) <= 1e-9 for r in rows)
    plate = [line.split() for line in proc.stdout.splitlines() if line.split()[:2] == ["121", "1089"]]
    assert len(plate) == 1
    diff, e1, _, e2, gap1, _, gap2 = plate[0][10:]
    assert float(diff) <= 1e-9 and float(e1) <= 1.0 + 1e-12 and float(e2) <= 1.0 + 1e-12
    assert float(gap1) <= 1e-9 and float(gap2) <= 1e-9


@pytest.mark.slow
def test_small_friction_runs_quickly():
    """benchmarks/small_friction.py --quick: both scenes, with and without friction, a line each."""
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "small_friction.py"), "--quick"],
                          capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert [line.split(":")[0] for line in proc.stdout.splitlines()] == ["block", "conveyor"]
