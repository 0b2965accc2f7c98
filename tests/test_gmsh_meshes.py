"""Gmsh files in 2D and 3D: bodies and node groups by physical name, and the bar answer on them."""

from __future__ import annotations

import gmsh
import numpy as np
import pytest

from conftest import CASES, run_case_file

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
