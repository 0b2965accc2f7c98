"""The examples in examples/ run on a coarse setting (as scikit-fem runs its examples), and what
each one claims holds: exact contact times, the momentum balance, the static correction's gain, the
paper's scheme failing where Moreau-Jean holds. They write nothing into the folder they run from."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run_example(name: str, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("FEM_IMPACT_CACHE", str(tmp_path.parent / f"{tmp_path.name}-cache"))
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.__doc__ and "--coarse" in module.__doc__
    result = module.main(coarse=True)
    assert list(tmp_path.iterdir()) == [], "the example wrote into the current folder"
    return result


def test_every_example_is_tested():
    tested = {"parameter_study", "gmsh_scene", "reduced_vs_full", "large_steps", "vibromotor_curves", "vibromotor_zone"}
    assert {p.stem for p in EXAMPLES.glob("*.py")} == tested


def test_parameter_study_finds_the_exact_contact_times(tmp_path, monkeypatch):
    rows = run_example("parameter_study", tmp_path, monkeypatch)
    assert [r["length"] for r in rows] == [0.5, 1.0, 2.0]
    for r in rows:   # 2 L / c to a step (dt = 0.01), rho c A v0 to 2 % (50 cells)
        assert abs(r["duration"] - r["exact"]) <= 0.0101
        assert r["force"] == pytest.approx(1.0, rel=0.02)


def test_gmsh_scene_closes_the_momentum_balance(tmp_path, monkeypatch):
    r = run_example("gmsh_scene", tmp_path, monkeypatch)
    assert r["rows"] > 1 and r["impulse"] > 0
    assert r["impulse"] == pytest.approx(r["momentum_change"] - r["weight_impulse"], rel=1e-9)
    assert r["max_energy_ratio"] <= 1 + 1e-6


def test_reduced_model_converges_and_the_static_correction_pays(tmp_path, monkeypatch):
    rows = run_example("reduced_vs_full", tmp_path, monkeypatch)
    full = rows["full"]["impulse"]
    assert rows["10 modes + static"]["impulse"] == pytest.approx(full, rel=0.005)
    for n1 in (2, 5, 10):
        with_static = abs(rows[f"{n1} modes + static"]["impulse"] - full)
        truncated = abs(rows[f"{n1} modes"]["impulse"] - full)
        assert with_static < truncated, n1
    errors = [abs(rows[f"{n1} modes + static"]["deflection"] / rows["full"]["deflection"] - 1) for n1 in (2, 5, 10)]
    assert errors[0] > 5 * max(errors[1:]) and max(errors[1:]) < 1e-3   # (from 5 modes: the time step's error)


def test_large_steps_show_the_paper_scheme_failing(tmp_path, monkeypatch):
    ratios = run_example("large_steps", tmp_path, monkeypatch)
    assert ratios["newmark"] > 1.1   # (1.9 measured; chaotic: a margin, not the figure)
    assert ratios["moreau_jean"] <= 1 + 1e-6


def test_a_script_sees_no_compiler_log(tmp_path):
    """A script's first run compiles its forms: setuptools' build lines must not reach its stderr."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache"), "FEM_IMPACT_CACHE": str(tmp_path / "fem")}
    result = subprocess.run([sys.executable, str(EXAMPLES / "parameter_study.py"), "--coarse"], cwd=tmp_path,
                            capture_output=True, text=True, env=env)
    assert result.returncode == 0, result.stderr
    assert "build_ext" not in result.stderr and "INFO" not in result.stderr, result.stderr[:500]
    assert (tmp_path / "cache").is_dir()   # (the forms were compiled in this run)


def test_the_vibromotor_characteristic_falls_with_the_load_to_a_stall(tmp_path, monkeypatch):
    out = run_example("vibromotor_curves", tmp_path, monkeypatch)
    speeds = out["speeds"]
    assert out["loads"] == [0.0, 2.0, 4.0]
    assert speeds[0] > speeds[1] > 0.0 > speeds[2]   # forward, slower under load, pushed back past stall
    assert 2.0 < out["stall"] < 4.0


@pytest.mark.slow   # (11 s: the default tier's budget)
def test_vibromotor_zone_shows_the_zone_open_at_its_ends_and_sticking_at_the_reversals(tmp_path, monkeypatch):
    """examples/vibromotor_zone.py (cases/vibromotor_surface.yaml, 1 mm, 0.004 s): in the last two periods
    the tip's open nodes are always a run from one end of the tip (it rocks, lifting off at its ends),
    some frames have every node in contact, some nodes stick, and a stick frame is one where the friction
    on the slider changes sign within a step of it (the reversals)."""
    z = run_example("vibromotor_zone", tmp_path, monkeypatch)
    state = z["state"]
    assert state.shape[1] == 11
    for frame in state:
        open_ = np.flatnonzero(frame == 0)
        if open_.size:   # (a run of nodes from an end)
            assert np.all(np.diff(open_) == 1) and (open_[0] == 0 or open_[-1] == frame.size - 1)
    assert (state > 0).all(axis=1).any()
    sticking = np.flatnonzero((state == 1).any(axis=1))
    assert sticking.size
    friction = -z["tangential"]
    reversal = np.flatnonzero(np.sign(friction[1:]) != np.sign(friction[:-1]))
    assert all(np.abs(reversal - k).min() <= 1 or np.abs(reversal + 1 - k).min() <= 1 for k in sticking)
