"""impacts.csv: one row per impact (a contact's rows carrying impulses from one step to the last
before none does): t, contact, impulse, speed, rows (docs/running.md, "What a run writes")."""

from __future__ import annotations

import csv

import numpy as np
import pytest

import fem_impact as fi
from conftest import CASES


def impacts(folder):
    with open(folder / "impacts.csv", newline="") as f:
        return [{**row, "t": float(row["t"]), "impulse": float(row["impulse"]), "speed": float(row["speed"]),
                 "rows": int(row["rows"])} for row in csv.DictReader(f)]


def test_the_free_bar_hits_the_wall_once_with_its_momentum(tmp_path):
    """B2a: one impact at t = gap / v0 = 0.1, approached at v0 = 1, impulse 2 rho A L v0 = 2 within
    the scheme's 0.28 % (docs/verification.md); the bar's momentum changes by exactly the impulse."""
    result = fi.run(fi.load_case(CASES / "impacting_bar.yaml").with_changes({"output.vtk": False}),
                    outdir=tmp_path / "b2a")
    rows = impacts(tmp_path / "b2a")
    assert len(rows) == 1 and result.summary["impacts"] == {"wall": 1}
    (row,) = rows
    assert (row["contact"], row["rows"]) == ("wall", 1)
    assert row["t"] == pytest.approx(0.1, abs=1e-12) and row["speed"] == pytest.approx(1.0, rel=1e-12)
    assert row["impulse"] == pytest.approx(2.0, rel=0.003)
    h = result.history
    assert row["impulse"] == pytest.approx(h["wall.impulse"].sum(), rel=1e-11)
    assert h["bar.px"][-1] - h["bar.px"][0] == pytest.approx(row["impulse"], rel=1e-9)


def test_the_vibroconverter_gives_its_five_impacts(tmp_path):
    """The free vibroconverter's five impacts: 21.657, 14.989, 8.266, 3.550, 0.921 mN s (docs/verification.md), each
    approached at a speed that falls with the mode's energy."""
    fi.run(fi.load_case(CASES / "vibroconverter_free.yaml").with_changes({"output.vtk": False}),
           outdir=tmp_path / "v")
    rows = impacts(tmp_path / "v")
    assert [r["contact"] for r in rows] == ["stop"] * 5
    assert [r["impulse"] * 1e3 for r in rows] == pytest.approx([21.657, 14.989, 8.266, 3.550, 0.921], abs=6e-4)
    assert np.all(np.diff([r["speed"] for r in rows[1:]]) < 0) and rows[0]["speed"] > 1.0


def test_a_face_of_many_rows_lands_as_one_impact(tmp_path):
    """The plate of 121 face rows lands flat once (restitution 0, nu = 0: exactly the 1D bar of area 25
    and the same 2 cells through its thickness, cases/plate_drop.yaml): one impact of all its rows with
    the 1D bar's impulse (to 1e-9; 45.7 = 2 rho A L v0 less the coarse mesh's 9 %), momentum to 1e-9."""
    case = fi.load_case(CASES / "plate_drop.yaml").with_changes({"output.vtk": False})
    result = fi.run(case, outdir=tmp_path / "plate")
    (row,) = impacts(tmp_path / "plate")
    assert row["rows"] == 121 and row["speed"] == pytest.approx(1.0, rel=1e-12)
    rod = case.with_changes({"mesh.dim": 1, "mesh.height": None, "mesh.width": None, "mesh.elements": "simplex",
                             "initial.velocity": [-1.0], "contacts.0.normal": [-1.0],
                             "output.probes": {"left": [0.0], "right": [1.0]}})
    fi.run(rod, outdir=tmp_path / "rod")
    (bar,) = impacts(tmp_path / "rod")
    assert row["impulse"] == pytest.approx(bar["impulse"], rel=1e-9) and (bar["t"], bar["rows"]) == (row["t"], 1)
    h = result.history
    assert h["bar.px"][-1] - h["bar.px"][0] == pytest.approx(row["impulse"], rel=1e-9)
