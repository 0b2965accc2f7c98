"""The tutorials' scripts (docs/tutorials/*.py, shown on the site by literalinclude) run, and what each
page says of its output holds: quick settings in the default tier, the scripts as shipped in the slow one."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIALS = ROOT / "docs" / "tutorials"


def tutorial(name: str, tmp_path, monkeypatch):
    """The script ``docs/tutorials/<name>.py`` as a module, run from an empty folder it must leave empty."""
    monkeypatch.chdir(tmp_path)
    spec = importlib.util.spec_from_file_location(f"tutorial_{name}", TUTORIALS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_tutorial_script_is_tested_and_shown_on_a_page():
    scripts = {p.stem for p in TUTORIALS.glob("*.py")}
    assert scripts == {"impacting_bar", "vibroconverter", "vibrodrive", "convergence_study", "response_sweep",
                       "shaken_table"}
    pages = "\n".join(p.read_text() for p in TUTORIALS.glob("*.md"))
    for name in scripts:
        assert f"literalinclude:: {name}.py" in pages.replace("{literalinclude} ", "literalinclude:: "), name


@pytest.mark.parametrize("cells", [50, pytest.param(250, marks=pytest.mark.slow)])
def test_impacting_bar(cells, tmp_path, monkeypatch):
    rows = tutorial("impacting_bar", tmp_path, monkeypatch).main(cells)
    dt = 0.5 / cells
    for method, r in rows.items():   # B2a's exact answer (docs/benchmarks.md B2) to the scheme's accuracy
        assert r["start"] == pytest.approx(0.1, abs=2.5 * dt) and r["end"] == pytest.approx(2.1, abs=2.5 * dt)
        assert r["force"] == pytest.approx(1.0, rel=0.01) and r["rebound"] == pytest.approx(1.0, rel=0.02)
        assert r["loss"] == pytest.approx(1 / (2 * math.sqrt(3) * cells), rel=1e-3)
        assert r["residual"] < 1e-10, method
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("periods, impulses", [
    (2, [21.657, 14.989]),
    pytest.param(50, [21.657, 14.989, 8.266, 3.550, 0.921], marks=pytest.mark.slow)])
def test_vibroconverter(periods, impulses, tmp_path, monkeypatch):
    out = tutorial("vibroconverter", tmp_path, monkeypatch).main(periods)
    assert [s * 1e3 for _, s in out["impacts"]] == pytest.approx(impulses, abs=6e-4)
    assert out["summary"]["max_energy_error_relative"] < 1e-10
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("t_end", [6.4e-4, pytest.param(5.0e-3, marks=pytest.mark.slow)])
def test_vibrodrive(t_end, tmp_path, monkeypatch):
    out = tutorial("vibrodrive", tmp_path, monkeypatch).main(t_end)
    assert [s * 1e3 for _, s in out["strikes"][:2]] == pytest.approx([1.190, 1.052], abs=1e-3)
    assert out["momentum"] == pytest.approx(out["pushed"], rel=1e-9)   # the slider's only push along x
    assert out["speed"] * 1e3 == pytest.approx(37.99, abs=0.01)         # launched: it coasts after 2 strikes
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("cells", [(25, 50, 100), pytest.param((50, 100, 200, 400), marks=pytest.mark.slow)])
def test_convergence_study(cells, tmp_path, monkeypatch):
    out = tutorial("convergence_study", tmp_path, monkeypatch).main(cells)
    for row in out["rows"]:
        assert row["loss"] == pytest.approx(row["exact_loss"], rel=1e-3)
    assert out["orders"]["loss"] == pytest.approx(1.0, abs=0.01)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("values, periods, shooting", [
    ((0.5, 0.667), {0.5: 1, 0.667: 2}, False),
    pytest.param((0.45, 0.5, 0.64, 0.66, 0.6645, 0.667), {0.45: 1, 0.5: 1, 0.64: 1, 0.66: 1, 0.6645: 2, 0.667: 2},
                 True, marks=pytest.mark.slow)])
def test_response_sweep(values, periods, shooting, tmp_path, monkeypatch):
    module = tutorial("response_sweep", tmp_path, monkeypatch)
    out = module.main(values, tmp_path / "sweep", shooting=shooting)
    assert out["periods"] == periods   # period 1 below the period doubling, 2 above
    assert (tmp_path / "sweep" / "response.csv").is_file()
    if shooting:   # located between the last period-1 and the first period-2 level: w = 4 f = 2.6533
        (mark,) = out["study"]["bifurcations"]
        assert mark["kind"] == "period_doubling" and mark["between"] == [0.66, 0.6645]
        assert 4 * mark["parameters.f"] == pytest.approx(2.6533477, abs=0.005)


@pytest.mark.slow   # (9 s: its pieces, the ball's phase and periods, the sweep and the rigid part, are tested in
                   # tests/test_moving_obstacles.py, test_periods.py and test_rigid.py in the default tier)
@pytest.mark.parametrize("t_end, gammas, conveyor", [(0.2, (1.3, 1.55), 5), (0.4, (1.3, 1.5, 1.55), 10)])
def test_shaken_table(t_end, gammas, conveyor, tmp_path, monkeypatch):
    out = tutorial("shaken_table", tmp_path, monkeypatch).main(tmp_path / "out", t_end, gammas, conveyor)
    assert abs(out["phase"] - 0.5) * 360 <= 0.5                       # the orbit's impact at T/2
    assert out["periods"] == {g: (2 if g > 1.527 else 1) for g in gammas}
    if len(gammas) == 3:   # (the doubling between 1.5 and 1.55: at the closed form's Gamma, 1.526824)
        (mark,) = out["marks"]
        assert mark["parameters.Gamma"] == pytest.approx(1.526824, rel=1e-3)
    assert out["speeds"][-1] == pytest.approx(0.04838, rel=0.01)       # the stick-slip theory's
