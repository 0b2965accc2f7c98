"""The probe harness (tools/probes/): every class of fault probes, none ending in a traceback, a hang,
a lost file, a silent wrong answer or a defect of the probe itself. Slow: the probes run the real
command line, hundreds of times."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tools.probes import PROBES, load, run_probes  # noqa: E402

load()
CLASSES = sorted({p.cls for p in PROBES})


@pytest.mark.slow
@pytest.mark.parametrize("cls", CLASSES)
def test_probe_class(cls, tmp_path):
    probes = [p for p in PROBES if p.cls == cls]
    report = run_probes(probes, workers=2, folder=tmp_path)
    failures = [f"[{v.kind}] {p.name}: {v.detail}" for p, v, _ in report.failures()]
    assert not failures, f"{len(failures)} of {len(probes)} probes of {cls} failed:\n" + "\n".join(failures)


def test_every_class_has_probes():
    """The harness finds its classes (a module that fails to import would drop its class silently)."""
    assert CLASSES, "no probe classes found in tools/probes/"
    assert all(sum(p.cls == c for p in PROBES) >= 3 for c in CLASSES), \
        {c: sum(p.cls == c for p in PROBES) for c in CLASSES}
