"""Gmsh files in 2D and 3D: bodies and node groups by physical name, and the bar answer on them."""

from __future__ import annotations

import os
import subprocess
import sys

import gmsh
import numpy as np
import pytest

from conftest import CASES, ROOT, run_case_file, run_cli

L, H = 1.0, 0.05


def write_bar_mesh(path, dim: int, h: float) -> None:
    """A strip [0, L] x [0, H] (2D) or a box [0, L] x [0, H] x [0, H] (3D), body 'bar', ends 'left', 'right'."""
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("bar")
    if dim == 2:
        gmsh.model.occ.addRectangle(0, 0, 0, L, H)
    else:
        gmsh.model.occ.addBox(0, 0, 0, L, H, H)
    gmsh.model.occ.synchronize()
    body = gmsh.model.getEntities(dim)[0][1]
    gmsh.model.setPhysicalName(dim, gmsh.model.addPhysicalGroup(dim, [body]), "bar")
    for name, x in (("left", 0.0), ("right", L)):
        ends = gmsh.model.getEntitiesInBoundingBox(x - 1e-6, -1e-6, -1e-6, x + 1e-6, H + 1e-6, H + 1e-6, dim - 1)
        gmsh.model.setPhysicalName(dim - 1, gmsh.model.addPhysicalGroup(dim - 1, [t for _, t in ends]), name)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.model.mesh.generate(dim)
    gmsh.write(str(path))
    gmsh.finalize()


def contact_duration(h):
    closed = h["wall_gap"] <= 1e-12
    return closed.sum() * (h["t"][1] - h["t"][0])


@pytest.mark.parametrize("dim, h", [(2, 0.0125), (3, 0.025)])
def test_bar_from_a_gmsh_file_reproduces_the_rod(tmp_path, dim, h):
    """B2a on an unstructured Gmsh strip/box: contact duration, impulse and force per area as the rod."""
    msh = tmp_path / f"bar{dim}d.msh"
    write_bar_mesh(msh, dim, h)
    cells = int(round(L / h))
    common = ["solver.t_end=2.4", f"solver.dt={0.5 * h}", "output.vtk=false"]
    _, rod = run_case_file(CASES / "impacting_bar.yaml", tmp_path / "rod", f"mesh.cells={cells}", *common)
    summary, hd = run_case_file(CASES / "impacting_bar.yaml", tmp_path / "gmsh",
                                "mesh={file: " + str(msh) + "}", *common)
    assert summary["mesh"].startswith(f"Gmsh file bar{dim}d.msh, {dim}D")
    area = H * 1.0 if dim == 2 else H * H   # 2D: thickness (material.area) 1
    assert contact_duration(hd) == pytest.approx(contact_duration(rod), rel=0.05)
    assert hd["wall_impulse"].sum() / area == pytest.approx(rod["wall_impulse"].sum(), rel=0.05)
    busy = (rod["t"] > 0.2) & (rod["t"] < 2.0)
    assert np.mean(hd["wall_force"][busy]) / area == pytest.approx(np.mean(rod["wall_force"][busy]), rel=0.05)
    assert summary["max_energy_error_relative"] < 1e-6


# --- the mesh scripts of meshes/: their dimensions as options ------------------------------------

def mesh_script(name: str, *args: str, cwd=None) -> subprocess.CompletedProcess:
    """``python meshes/NAME ARGS`` as a user runs it (the scripts import fem_impact)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, str(ROOT / "meshes" / name), *args], capture_output=True, text=True,
                          cwd=cwd, env=env)


def test_a_horn_of_other_dimensions_from_the_script_is_one_fem_impact_runs(tmp_path):
    """meshes/vibroconverter_axi.py --length --r-large --r-small --h (no import of build()): a shorter,
    thicker horn whose node groups the case file finds; its first longitudinal mode is the half-wave
    stepped horn's c / (2 L) (1D theory; lateral inertia lowers it by 0.1 %), and the case runs on it."""
    horn = tmp_path / "horn.msh"
    made = mesh_script("vibroconverter_axi.py", "--length", "0.08", "--r-large", "0.012", "--r-small", "0.004",
                       "--h", "2e-3", "-o", str(horn))
    assert made.returncode == 0, made.stderr
    assert "L = 0.08 m" in made.stdout and "radii 0.012 and 0.004 m" in made.stdout and horn.is_file()
    case = str(CASES / "vibroconverter_axi.yaml")
    mesh = ["--set", f"mesh.file={horn}", "--set", "output.probes={tip: [0.08, 0.0]}"]
    modes = run_cli("modes", case, *mesh, "-n", "1", "-o", str(tmp_path / "modes"), "-q")
    assert modes.returncode == 0, modes.stderr
    f1 = float((tmp_path / "modes" / "modes.csv").read_text().splitlines()[1].split(",")[1])
    assert f1 == pytest.approx((210e9 / 7800.0) ** 0.5 / (2 * 0.08), rel=0.005)
    run = run_cli("run", case, *mesh, "--set", "solver.t_end=1e-6", "-o", str(tmp_path / "run"), "-q")
    assert run.returncode == 0, run.stderr


def test_a_vibromotor_of_other_dimensions_from_the_script_is_one_fem_impact_runs(tmp_path):
    mesh = tmp_path / "motor.msh"
    made = mesh_script("vibromotor.py", "--slider-length", "0.04", "--driver-height", "0.015", "--h", "2.5e-3",
                       "-o", str(mesh))
    assert made.returncode == 0, made.stderr
    assert "driver 0.01 x 0.015 m, slider 0.04 x 0.01 m" in made.stdout
    run = run_cli("run", str(CASES / "vibromotor.yaml"), "--set", f"mesh.file={mesh}", "--set", "solver.t_end=5e-5",
                  "--set", "output.vtk=false", "-o", str(tmp_path / "run"), "-q")
    assert run.returncode == 0, run.stderr


@pytest.mark.parametrize("script, args, said", [
    ("vibroconverter_axi.py", ["--length", "-0.1"], "argument --length: must be a number > 0, got -0.1"),
    ("vibroconverter_axi.py", ["--r-small", "0.02"], "the small radius (0.02 m) must be > 0 and below the large one"),
    ("vibroconverter_axi.py", ["--split", "1.2"], "split (the step's position, a fraction of the length) must lie"),
    ("vibroconverter_axi.py", ["--h", "nan"], "argument --h: must be a number > 0, got nan"),
    ("vibroconverter_axi.py", ["-o", "horn.vtk"], "argument -o/--output: write a .msh file"),
    ("vibromotor.py", ["--slider-length", "0.005"], "the slider (0.005 m) must be longer than the driver is wide"),
    ("vibromotor.py", ["-h", "0.05"], "h = 0.05 m is above the smallest dimension"),
    ("two_bars.py", ["--cells", "0"], "cells >= 1"),
    ("vibrodrive.py", ["--alpha", "70"], "need 0 < alpha < 60 degrees"),
    ("vibroconverter.py", ["--split", "abc"], "argument --split: expected a number, got 'abc'"),
])
def test_a_mesh_script_refuses_dimensions_that_do_not_fit_in_one_line(tmp_path, script, args, said):
    """Status 2 and one line naming the option (never a traceback, nor argparse's usage block); no file."""
    made = mesh_script(script, *args, *([] if "-o" in args else ["-o", str(tmp_path / "m.msh")]), cwd=tmp_path)
    assert made.returncode == 2
    lines = made.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{script}: error: ") and said in lines[0], made.stderr
    assert list(tmp_path.iterdir()) == []
