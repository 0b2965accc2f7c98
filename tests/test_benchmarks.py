"""The benchmark scripts still run (at their smallest size): no figures asserted, those are theirs."""

from __future__ import annotations

import subprocess
import sys

from conftest import ROOT


def test_contact_scale_runs_at_its_smallest_size():
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "contact_scale.py"), "--quick"],
                          capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    rows = [line.split() for line in proc.stdout.splitlines() if line.strip()[:1].isdigit()]
    assert [r[:2] for r in rows] == [["1", "mean"], ["121", "each"]]


def test_scaling_runs_at_a_small_size_with_equal_histories():
    """benchmarks/scaling.py at 20 cells (252 unknowns), 12 steps, every method: serial and 2 ranks run and
    give the same history (to 1e-9 of each column's scale; the figures of time are the benchmark's)."""
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "scaling.py"), "--sizes", "20", "--steps", "12"],
                          capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stderr
    rows = [line.split() for line in proc.stdout.splitlines()
            if line.split()[:1] and line.split()[0] in ("moreau_jean", "newmark", "central_difference", "modal")]
    assert [r[0] for r in rows] == ["moreau_jean", "newmark", "central_difference", "modal"]
    assert all(r[1] == "252" and float(r[-1]) <= 1e-9 for r in rows)
