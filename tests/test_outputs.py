"""What a run writes (docs/running.md, "What a run writes"): results.pvd, history.csv, summary.json, case.resolved.yaml."""

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


def test_binary_fields_are_read_by_meshio_pyvista_and_the_api(tmp_path):
    """output.format: xdmf writes results.xdmf + results.h5 (one temporal collection, every field per
    frame): Debian's meshio and pyvista read it; fem_impact.Result.load(folder).fields() gives the
    frames, the nodes and u, v, a, contact_force, equal to the initial field at t = 0 and to the
    history's probe at every frame."""
    import meshio
    import pyvista

    import fem_impact as fi

    case = fi.load_case(CASES / "impacting_bar.yaml").with_changes({
        "mesh.dim": 2, "mesh.cells": 20, "output.format": "xdmf", "solver.dt": 0.02, "solver.t_end": 0.4,
        "output.every": 2, "initial.displacement": ["0.01*(1 - x)", "0.002*y"]})
    result = fi.run(case, outdir=tmp_path / "run")
    assert (tmp_path / "run" / "results.h5").is_file() and not (tmp_path / "run" / "results.pvd").exists()
    fields = fi.Result.load(tmp_path / "run").fields()
    assert len(fields.t) == result.summary["vtk_frames"] == 11
    x, y = fields.points[:, 0], fields.points[:, 1]
    assert np.abs(fields.values["u"][0][:, 0] - 0.01 * (1 - x)).max() < 1e-15
    assert np.abs(fields.values["u"][0][:, 1] - 0.002 * y).max() < 1e-15
    h = result.history
    right = np.flatnonzero((np.abs(x - 1.0) < 1e-12) & (np.abs(y) < 1e-12))[0]
    for t, u in zip(fields.t, fields.values["u"]):
        row = int(np.argmin(abs(h["t"] - t)))
        assert u[right, 0] == pytest.approx(h["right.ux"][row], rel=1e-11, abs=1e-15)   # (history: 12 digits)
    with meshio.xdmf.TimeSeriesReader(str(tmp_path / "run" / "results.xdmf")) as reader:
        points, _ = reader.read_points_cells()
        assert reader.num_steps == 11
        t, data, _ = reader.read_data(3)
    assert t == pytest.approx(fields.t[3]) and set(data) == {"u", "v", "a", "contact_force", "contact_state"}
    assert np.array_equal(data["v"], fields.values["v"][3]) and np.array_equal(points, fields.points)
    reader = pyvista.get_reader(str(tmp_path / "run" / "results.xdmf"))
    assert np.allclose(reader.time_values, fields.t)
    reader.set_active_time_value(reader.time_values[5])
    mesh = reader.read()
    block = next(b for b in mesh if b is not None and "u" in b.point_data)
    assert np.array_equal(np.asarray(block.point_data["u"]), fields.values["u"][5])


def test_fields_of_a_run_without_the_binary_series_say_why(tmp_path):
    import fem_impact as fi

    case = fi.load_case(CASES / "impacting_bar.yaml").with_changes({"solver.t_end": 0.1, "mesh.cells": 20,
                                                                     "solver.dt": 0.02})
    fi.run(case, outdir=tmp_path / "vtu")
    with pytest.raises(fi.SimulationError, match="ASCII VTU .* output.format: xdmf"):
        fi.Result.load(tmp_path / "vtu").fields()
    with pytest.raises(fi.SimulationError, match="not a run's output folder"):
        fi.Result.load(tmp_path / "nothing")


def test_fields_of_a_damaged_binary_series_are_one_error_naming_the_file(tmp_path):
    """A truncated results.h5, a cut results.xdmf, a frame whose data set is gone: Result.fields() raises a
    SimulationError naming the file (they escaped as h5py's OSError, ElementTree's ParseError, a KeyError)."""
    import shutil

    import fem_impact as fi

    case = fi.load_case(CASES / "impacting_bar.yaml").with_changes({
        "solver.t_end": 0.1, "mesh.cells": 20, "solver.dt": 0.02, "output.format": "xdmf", "output.every": 1})
    fi.run(case, outdir=tmp_path / "run")
    assert len(fi.Result.load(tmp_path / "run").fields().t) == 6

    def damaged(name, damage):
        folder = tmp_path / name
        shutil.copytree(tmp_path / "run", folder)
        damage(folder)
        with pytest.raises(fi.SimulationError) as info:
            fi.Result.load(folder).fields()
        message = str(info.value)
        assert str(folder / "results.xdmf") in message and "cannot read" in message and "\n" not in message
        return message

    def truncate(path):
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])

    assert "OSError" in damaged("h5", lambda f: truncate(f / "results.h5"))
    assert "ParseError" in damaged("xml", lambda f: truncate(f / "results.xdmf"))

    def renamed(folder):   # the last frame's data set named wrongly in the index
        text = (folder / "results.xdmf").read_text()
        last = text.rindex("results.h5:/Function/u/")
        (folder / "results.xdmf").write_text(text[:last] + text[last:].replace("/Function/u/", "/Function/w/", 1))

    assert "frame 5" in damaged("frame", renamed)
