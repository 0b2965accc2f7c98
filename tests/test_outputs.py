"""What a run writes (README.md, "What a run writes"): results.pvd, history.csv, summary.json, case.resolved.yaml."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from conftest import CASES, read_history, run_cli
from fem_impact.config.case import load_case

SUMMARY_KEYS = {"wall_time_s", "loop_time_s", "steps", "dofs", "modes", "max_penetration", "max_energy_error",
                "fem_impact_version"}
HISTORY_COLUMNS = ["t", "wall.gap", "wall.force", "wall.impulse", "left.ux", "left.vx", "right.ux", "right.vx",
                   "kinetic", "strain", "external_work", "damping_loss", "impact_loss", "contact_loss", "energy_error",
                   "bar.px"]


def read_vtu(path):
    """Points and point data of a dolfinx ASCII .vtu piece (VTK XML 2.2, which meshio does not read)."""
    piece = ET.parse(path).getroot().find("UnstructuredGrid/Piece")

    def values(array):
        ncomp = int(array.get("NumberOfComponents", 1))
        return np.array(array.text.split(), dtype=float).reshape(-1, ncomp)

    points = values(piece.find("Points/DataArray"))
    data = {a.get("Name"): values(a) for a in piece.find("PointData").findall("DataArray")}
    return points, data


@pytest.fixture(scope="module")
def bar_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "bar"
    proc = run_cli("run", str(CASES / "impacting_bar.yaml"), "-o", str(out), "--set", "mesh.cells=20",
                   "--set", "solver.dt=0.025", "--set", "solver.t_end=2.6", "--set", "output.every=8", "--plot")
    assert proc.returncode == 0, proc.stderr
    return out, proc


def test_files_and_the_summary_paragraph(bar_run):
    out, proc = bar_run
    names = {p.name for p in out.iterdir()}
    assert {"results.pvd", "history.csv", "summary.json", "case.resolved.yaml", "history.png"} <= names
    assert "104 steps" in proc.stdout and "21 unknowns" in proc.stdout and str(out) in proc.stdout
    assert not list(out.parent.glob(".bar.*")), "a staging folder was left behind"


def test_history_columns_and_rows(bar_run):
    out, _ = bar_run
    assert (out / "history.csv").read_text().splitlines()[0].split(",") == HISTORY_COLUMNS
    h = read_history(out)
    assert len(h) == 105 and h["t"][0] == 0.0 and h["t"][-1] == pytest.approx(2.6)
    # Probes read the end nodes: the left end is pinned at -gap while in contact.
    assert h["left_ux"][(h["t"] > 0.3) & (h["t"] < 2.0)] == pytest.approx(-0.1, abs=1e-12)


def test_summary(bar_run):
    out, _ = bar_run
    summary = json.loads((out / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(summary)
    assert summary["steps"] == 104 and summary["dofs"] == 21 and summary["modes"] is None
    assert summary["total_impulse"]["wall"] == pytest.approx(read_history(out)["wall_impulse"].sum(), rel=1e-9)


def test_paraview_time_series(bar_run):
    """results.pvd lists every 8th step (and the last); each piece has u, v, a, contact_force as point data."""
    out, _ = bar_run
    datasets = ET.parse(out / "results.pvd").getroot().find("Collection").findall("DataSet")
    times = [float(d.get("timestep")) for d in datasets]
    assert times == pytest.approx(np.arange(0, 105, 8) * 0.025)   # 104 = 13 x 8 is the last step
    last = out / datasets[-1].get("file").replace(".pvtu", ".vtu").replace("results", "results_p0_")
    points, data = read_vtu(last)
    for name in ("u", "v", "a", "contact_force"):
        assert data[name].shape == (21, 3)
    h = read_history(out)
    right = np.argmax(points[:, 0])
    assert data["u"][right, 0] == pytest.approx(h["right_ux"][-1], rel=1e-9)
    # During contact the contact force on the structure pushes the left end away from the wall (+x).
    frame = out / datasets[5].get("file").replace(".pvtu", ".vtu").replace("results", "results_p0_")
    points, data = read_vtu(frame)
    assert data["contact_force"][np.argmin(points[:, 0]), 0] > 0.5


def test_resolved_case_runs_again_the_same(bar_run, tmp_path):
    out, _ = bar_run
    resolved = load_case(out / "case.resolved.yaml")
    assert resolved.mesh.cells == 20 and resolved.solver.dt == 0.025 and resolved.solver.beta == 0.25
    assert resolved.resolved() == load_case(out / "case.resolved.yaml").resolved()
