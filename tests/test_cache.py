"""The on-disk cache (fem_impact.cache): its key holds the code (version and fingerprint of the
sources) and the solvers' settings, so a fix or a changed tolerance never reuses an old entry."""

from __future__ import annotations

import numpy as np
from mpi4py import MPI

from conftest import CASES, run_case_file
from fem_impact import cache
from fem_impact.fem import modes
from fem_impact.fem.modes import solver_settings
from fem_impact.fem.reduced import static_settings

COMM = MPI.COMM_SELF
MODAL = ["solver.method=modal", "solver.modes=6", "mesh.cells=30", "output.vtk=false"]


def test_the_key_changes_with_the_code_and_the_settings(monkeypatch):
    arrays = (np.arange(5.0), "scene", 8)
    settings = solver_settings()
    first = cache.key(COMM, *arrays, settings)
    assert cache.key(COMM, *arrays, solver_settings()) == first          # the same inputs: the same entry
    assert cache.key(COMM, *arrays, solver_settings(tol=1e-9)) != first  # another tolerance
    assert cache.key(COMM, *arrays, static_settings()) != first
    monkeypatch.setattr(cache, "code_fingerprint", lambda: "a fixed bug")
    assert cache.key(COMM, *arrays, settings) != first                   # other code
    monkeypatch.setattr(cache, "__version__", "99.0")
    assert cache.key(COMM, *arrays, settings) != first


def test_the_fingerprint_covers_what_computes_and_skips_what_presents(tmp_path, monkeypatch):
    for name in ("modes.py", "reduce.py", "cli.py"):
        (tmp_path / name).write_text("x = 1\n")
    (tmp_path / "studies").mkdir()
    (tmp_path / "studies" / "levels.py").write_text("x = 1\n")
    monkeypatch.setattr(cache, "PACKAGE", tmp_path)
    before = cache.code_fingerprint()
    (tmp_path / "cli.py").write_text("x = 2\n")
    (tmp_path / "studies" / "levels.py").write_text("x = 2\n")
    assert cache.code_fingerprint() == before
    (tmp_path / "modes.py").write_text("x = 2   # a fix\n")
    assert cache.code_fingerprint() != before


def test_an_entry_is_reused_under_its_key_only(tmp_path, monkeypatch):
    monkeypatch.setenv("FEM_IMPACT_CACHE", str(tmp_path))
    name = f"test-{cache.key(COMM, 'scene', solver_settings())}"
    cache.save(name, COMM, values=np.arange(3.0))
    np.testing.assert_array_equal(cache.load(name, COMM)["values"], np.arange(3.0))
    other = f"test-{cache.key(COMM, 'scene', solver_settings(tol=1e-9))}"
    assert cache.load(other, COMM) is None


def test_a_run_reuses_modes_unless_the_code_or_the_tolerance_changed(tmp_path, monkeypatch):
    monkeypatch.setenv("FEM_IMPACT_CACHE", str(tmp_path / "cache"))
    bar = CASES / "impacting_bar.yaml"
    first, h1 = run_case_file(bar, tmp_path / "a", *MODAL)
    second, h2 = run_case_file(bar, tmp_path / "b", *MODAL)
    assert first["reused_from_cache"] == [] and second["reused_from_cache"] == ["modes", "static solves"]
    np.testing.assert_array_equal(h1["t"], h2["t"])
    monkeypatch.setattr(modes, "TOLERANCE", 1e-9)
    looser, _ = run_case_file(bar, tmp_path / "c", *MODAL)
    assert "modes" not in looser["reused_from_cache"]
    monkeypatch.setattr(cache, "code_fingerprint", lambda: "a fixed bug")
    fixed, _ = run_case_file(bar, tmp_path / "d", *MODAL)
    assert fixed["reused_from_cache"] == []
