"""Two bodies meshed apart that touch (coincident nodes on their shared face): node groups by physical
group, and a pair contact at zero gap that moves the momentum across as the 1D wave problem does.

Two equal bars [0, L] and [L, 2L] along x, section H (2D: thickness 1; 3D: H x H), E = rho = 1,
nu = 0 (c = 1), each meshed on its own (structured quadrilaterals / hexahedra) so that the face
x = L carries a node of each bar at every place. bar_a moves at V0 toward bar_b at rest, touching
from the start (gap 0). A structured mesh with nu = 0 moving along x is the discrete 1D bar; the
continuum answer is exact: the interface carries rho c A V0 / 2 for 2L/c, then bar_a is at rest
and bar_b leaves at V0 (the compression waves run to the free ends and back).
"""

from __future__ import annotations

import json
import os
import runpy
import shutil
import subprocess
import sys

import gmsh
import numpy as np
import pytest

from conftest import read_history, run_cli

L, H, V0 = 1.0, 0.1, 1.0


def write_touching_bars(path, dim: int, cells: int, across: int = 1, apart: bool = True) -> None:
    """The two bars, each its own OCC shape (no fragment: the face x = L is two faces, one node of each
    bar at every place), structured: ``cells`` elements along, ``across`` across. Bodies ``bar_a``,
    ``bar_b``; node groups ``a_left``, ``a_right``, ``b_left``, ``b_right`` (each end face its own bar's).
    ``apart=False``: fragmented, one conforming mesh (a_right and b_left are the same face)."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("touching_bars")
        occ, tol = gmsh.model.occ, 1e-6 * L
        shapes = {bar: occ.addRectangle(x0, 0, 0, L, H) if dim == 2 else occ.addBox(x0, 0, 0, L, H, H)
                  for bar, x0 in (("a", 0.0), ("b", L))}
        if not apart:
            occ.fragment([(dim, shapes["a"])], [(dim, shapes["b"])])
        occ.synchronize()
        for bar, shape in shapes.items():
            gmsh.model.setPhysicalName(dim, gmsh.model.addPhysicalGroup(dim, [shape]), f"bar_{bar}")
            x0 = 0.0 if bar == "a" else L
            faces = [t for _, t in gmsh.model.getBoundary([(dim, shape)], oriented=False)]
            for side, x in (("left", x0), ("right", x0 + L)):
                boxes = {t: np.array(gmsh.model.getBoundingBox(dim - 1, t)) for t in faces}
                end = [t for t in faces if np.allclose(boxes[t][[0, 3]], x, atol=tol)]   # xmin = xmax = x
                gmsh.model.setPhysicalName(dim - 1, gmsh.model.addPhysicalGroup(dim - 1, end), f"{bar}_{side}")
        for _, curve in gmsh.model.getEntities(1):
            box = gmsh.model.getBoundingBox(1, curve)
            gmsh.model.mesh.setTransfiniteCurve(curve, (cells if box[3] - box[0] > 2 * tol else across) + 1)
        for d in range(2, dim + 1):
            for _, entity in gmsh.model.getEntities(d):
                (gmsh.model.mesh.setTransfiniteSurface if d == 2 else gmsh.model.mesh.setTransfiniteVolume)(entity)
                gmsh.model.mesh.setRecombine(d, entity)   # quadrilaterals, hexahedra
        gmsh.model.mesh.generate(dim)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


def case_text(dim: int, dt: float, t_end: float, method: str = "moreau_jean") -> str:
    vector = lambda x: "[" + ", ".join([str(x)] + ["0.0"] * (dim - 1)) + "]"  # noqa: E731
    return f"""name: touching_bars
mesh:
  file: bars.msh
material: {{E: 1.0, rho: 1.0, nu: 0.0, area: 1.0}}
initial:
  velocity:
    - {{body: bar_a, value: {vector(V0)}}}
    - {{body: bar_b, value: {vector(0.0)}}}
contacts:
  - name: joint
    type: pair
    nodes: [a_right, b_left]
    normal: {vector(1.0)}
    restitution: 0.0
solver:
  method: {method}
  dt: {dt}
  t_end: {t_end}
output:
  vtk: false
"""


def write_case(folder, dim: int, cells: int, across: int, dt: float, t_end: float, method: str = "moreau_jean",
               apart: bool = True):
    folder.mkdir(parents=True, exist_ok=True)
    write_touching_bars(folder / "bars.msh", dim, cells, across, apart)
    path = folder / "case.yaml"
    path.write_text(case_text(dim, dt, t_end, method))
    return path


# --- node groups ----------------------------------------------------------------------------


@pytest.mark.parametrize("dim, across", [(2, 3), (3, 2)])
def test_each_node_group_holds_its_own_bodys_nodes(tmp_path, dim, across):
    """A face group is the nodes of its own physical group, not every node at its place: the nodes
    of a_right and b_left sit at the same places, yet are distinct, each group's in its own body."""
    from fem_impact.fem import dolfinx_api as dx
    from fem_impact.config.case import load_case
    from fem_impact.fem.mesh import build_mesh
    from fem_impact.fem.model import node_set

    case = load_case(write_case(tmp_path, dim, 6, across, 0.05, 0.1))
    meshdata = build_mesh(case.mesh)
    V = dx.vector_space(meshdata.mesh)
    groups = {name: node_set(meshdata, V, name, ()) for name in ("a_left", "a_right", "b_left", "b_right")}
    tags = meshdata.cell_tags
    cell_nodes = dx.cell_nodes(V)
    body_nodes = {name: np.unique(cell_nodes[tags.indices[tags.values == tag]])
                  for name, tag in meshdata.bodies.items()}
    assert not np.intersect1d(body_nodes["bar_a"], body_nodes["bar_b"]).size   # meshed apart: no shared node
    face_nodes = (across + 1) ** (dim - 1)
    for name, group in groups.items():
        own, other = ("bar_a", "bar_b") if name.startswith("a") else ("bar_b", "bar_a")
        assert len(group) == face_nodes, name
        assert np.isin(group.global_node, body_nodes[own]).all(), name
        assert not np.isin(group.global_node, body_nodes[other]).any(), name
    a, b = groups["a_right"], groups["b_left"]
    assert np.abs(a.coords - b.coords).max() <= 1e-12 * L   # the same places (both sorted by position) ...
    assert not np.intersect1d(a.global_node, b.global_node).size   # ... and different nodes


# --- a pair at zero gap: the 1D wave answer ---------------------------------------------------

CELLS, ACROSS = 40, 2
DT = 0.5 / CELLS                  # Courant number 0.5
T_END = 2.5                       # contact on [0, 2L/c], then the bars part
AREA = H                          # 2D: section H x thickness 1
MASS = 1.0 * L * AREA             # rho A L of each bar


@pytest.fixture(scope="module", params=["moreau_jean", "newmark"])
def touching(request, tmp_path_factory):
    """bar_a at V0 against bar_b at rest, touching at t = 0, through the command line."""
    folder = tmp_path_factory.mktemp(f"touching_{request.param}")
    case = write_case(folder, 2, CELLS, ACROSS, DT, T_END, request.param)
    result = run_cli("run", str(case), "-o", str(folder / "out"), "-q")
    assert result.returncode == 0, result.stderr
    return result, read_history(folder / "out")


def test_zero_gap_pair_starts_quietly(touching):
    """Touching at t = 0 is a valid state: no error, no warning, no penetration, no energy created."""
    result, h = touching
    assert result.stderr == ""
    assert h["joint_gap"][0] == 0.0                     # coincident nodes: gap 0, not round-off
    assert h["joint_gap"].min() >= -1e-12 * L
    E = h["kinetic"] + h["strain"]
    E0 = 0.5 * MASS * V0**2
    assert E.max() <= E0 * (1.0 + 1e-9)
    # What is missing went to the impact at the node (restitution 0), O(1/n).
    assert E + h["impact_loss"] + h["contact_loss"] == pytest.approx(np.full(len(h), E0), rel=1e-9)
    assert 0.0 < h["impact_loss"][-1] < 0.02 * E0


def test_zero_gap_pair_balances_momentum_exactly(touching):
    """What bar_b gains is the sum of the contact impulses, what bar_a loses too (history: 12 digits)."""
    _, h = touching
    assert h["bar_b_px"] == pytest.approx(np.cumsum(h["joint_impulse"]), abs=1e-9 * MASS * V0)
    assert h["bar_a_px"] + h["bar_b_px"] == pytest.approx(np.full(len(h), MASS * V0), abs=1e-9 * MASS * V0)


def test_zero_gap_pair_is_the_wave_transfer(touching):
    """Force rho c A V0 / 2 from t = 0 for 2L/c, one contact phase; then bar_a at rest, bar_b at V0
    (the discrete bar, 40 elements, loses O(1/n) at the node: 2 %)."""
    _, h = touching
    t, f = h["t"], h["joint_force"]
    on = np.flatnonzero(h["joint_impulse"] > 0.0)
    assert t[on[0]] <= DT                                   # in contact from the first step
    assert np.all(np.diff(on) == 1)                         # one phase, no chatter
    assert t[on[-1]] - t[on[0]] + DT == pytest.approx(2.0 * L, abs=2 * DT)
    plateau = (t > 0.3) & (t < 2.0 * L - 0.3)               # away from the wave fronts
    assert f[plateau] == pytest.approx(np.full(plateau.sum(), 0.5 * AREA * V0), rel=0.02)
    assert h["bar_b_px"][-1] == pytest.approx(MASS * V0, rel=0.02)
    assert abs(h["bar_a_px"][-1]) < 0.02 * MASS * V0
    assert h["joint_gap"][-1] > 0.0                         # they have parted


def test_a_pair_on_a_shared_face_is_refused(tmp_path, run):
    """Bars meshed together (one conforming mesh): a_right and b_left are the same nodes, and a node
    cannot be its own partner. The error says so (not that a support holds them)."""
    from fem_impact.errors import CaseError

    case = write_case(tmp_path, 2, 4, 1, 0.1, 0.2, apart=False)
    with pytest.raises(CaseError, match=r"share the node at \[1\.0, 0\.0\]: a pair joins nodes of two bodies"):
        run(case)


# --- distributed ------------------------------------------------------------------------------

GROUPS_SCRIPT = """
import json, sys
from mpi4py import MPI
import fem_impact
from fem_impact.fem import dolfinx_api as dx
from fem_impact.fem.mesh import build_mesh
case = fem_impact.load_case(sys.argv[1])
meshdata = build_mesh(case.mesh)
inputs = dx.vertex_input_indices(meshdata.mesh)
groups = {name: sorted(set().union(*MPI.COMM_WORLD.allgather(set(inputs[v].tolist()))))
          for name, v in meshdata.node_groups.items()}
if MPI.COMM_WORLD.rank == 0:
    print(json.dumps(groups))
fem_impact.run(case, sys.argv[2])
"""


@pytest.mark.mpi
@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
def test_groups_and_contact_are_the_same_on_two_ranks(tmp_path, monkeypatch, capsys):
    """Node groups are the same input nodes (the file's, by tag) serial and on 2 ranks, and the run agrees."""
    case = write_case(tmp_path, 2, 20, 2, 0.025, 0.5)
    script = tmp_path / "groups.py"
    script.write_text(GROUPS_SCRIPT)
    monkeypatch.setattr(sys, "argv", [str(script), str(case), str(tmp_path / "serial")])
    runpy.run_path(str(script), run_name="__main__")
    groups = json.loads(capsys.readouterr().out)
    # This pytest process has initialized MPI itself: its OMPI_/PMIX_ variables would make mpirun nested.
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "OPAL_"))}
    two = subprocess.run(["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2", sys.executable, str(script),
                          str(case), str(tmp_path / "mpi")], capture_output=True, text=True, env=env)
    assert two.returncode == 0, two.stderr
    assert json.loads(two.stdout) == groups
    assert {name: len(nodes) for name, nodes in groups.items()} == dict.fromkeys(groups, 3)
    assert not set(groups["a_right"]) & set(groups["b_left"])
    a, b = read_history(tmp_path / "serial"), read_history(tmp_path / "mpi")
    assert a["joint_impulse"].sum() > 0.1 * MASS * V0
    for name in ("joint_force", "joint_impulse", "bar_a_px", "bar_b_px", "kinetic", "strain"):
        assert np.abs(a[name] - b[name]).max() <= 1e-8 * np.abs(a[name]).max(), name
