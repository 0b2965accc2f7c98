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
