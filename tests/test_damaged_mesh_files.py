"""Damaged Gmsh files: each one runs as the intact file does, or stops with one line naming the file.

The variants of a valid MSH 4.1 file (two touching strips, tests/test_touching_bodies.py) garble
each section's end marker (and two start markers), delete lines, put text where numbers go,
truncate it, add binary noise and give section headers wrong counts (some of which make Gmsh
4.8's own reader overrun its buffers and abort: fem-impact reads in a child process). Through
the API every variant either gives the intact file's history or raises CaseError on
``mesh.file`` naming the file; through the command line a few of them give exit status 2, one
line on stderr naming the file, no traceback and no output folder.
"""

from __future__ import annotations

import random
import re

import gmsh
import numpy as np
import pytest
from test_touching_bodies import write_touching_bars

from conftest import run_cli

MARKERS = ("MeshFormat", "PhysicalNames", "Entities", "Nodes", "Elements")

# bar_b flies at 1 against a wall 0.01 beyond its right end; bar_a stays at rest (a few steps).
CASE = """name: damaged
mesh:
  file: bars.msh
material: {E: 1.0, rho: 1.0, nu: 0.0, area: 1.0}
initial:
  velocity:
    - {body: bar_a, value: [0.0, 0.0]}
    - {body: bar_b, value: [1.0, 0.0]}
contacts:
  - {name: wall, type: obstacle, nodes: [b_right], normal: [1.0, 0.0], gap: 0.01}
solver:
  dt: 0.02
  t_end: 0.1
output:
  vtk: false
"""


@pytest.fixture(scope="module")
def intact(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("intact") / "bars.msh"
    write_touching_bars(path, 2, 4, 1)
    return path.read_text()


def _lines(text):
    lines = text.splitlines(keepends=True)
    return lines, {line.strip(): i for i, line in enumerate(lines) if line.startswith("$")}


def edit(line_of, change):
    """The damage ``change(words)`` to the words of one line (``line_of(markers)``: its index)."""
    def damage(text: str) -> bytes:
        lines, at = _lines(text)
        k = line_of(at)
        words = lines[k].split()
        change(words)
        lines[k] = " ".join(words) + "\n"
        return "".join(lines).encode()
    return damage


def delete(line_of):
    def damage(text: str) -> bytes:
        lines, at = _lines(text)
        del lines[line_of(at)]
        return "".join(lines).encode()
    return damage


def put(i, value):
    def change(words):
        words[i] = value
    return change


def add(i, n):
    def change(words):
        words[i] = str(int(words[i]) + n)
    return change


def noise(n: int, seed: int) -> bytes:
    rng = random.Random(seed)
    return bytes(rng.randrange(256) for _ in range(n))


def after(marker: str, n: int = 1):
    return lambda at: at[marker] + n


NODES, ELEMENTS = after("$Nodes"), after("$Elements")
DAMAGES = {"empty": lambda text: b""}
for _marker in ("MeshFormat", "Nodes"):
    DAMAGES[f"garbled ${_marker}"] = lambda text, m=_marker: text.replace(f"${m}\n", "$Nodez\n", 1).encode()
for _marker in MARKERS:
    DAMAGES[f"garbled $End{_marker}"] = lambda text, m=_marker: text.replace(f"$End{m}\n", "x7#garbage\n", 1).encode()
for _name, _line in (("format line", after("$MeshFormat")), ("nodes header", NODES),
                     ("node coordinates", after("$Nodes", 4)), ("element", after("$Elements", 3))):
    DAMAGES[f"deleted {_name}"] = delete(_line)
    DAMAGES[f"text in {_name}"] = edit(_line, put(0, "abc"))
DAMAGES["deleted last element"] = delete(after("$EndElements", -1))
for _percent in (1, 10, 50, 90, 99):
    DAMAGES[f"truncated at {_percent} %"] = lambda text, p=_percent: text.encode()[: len(text) * p // 100]
DAMAGES.update({
    "binary noise": lambda text: noise(3000, 1),
    "noise inside": lambda text: text.encode()[: len(text) // 2] + noise(200, 2) + text.encode()[len(text) // 2:],
    "noise after the header": lambda text: text[: text.index("$EndMeshFormat\n") + 15].encode() + noise(500, 3),
    "5 nodes more than counted": edit(NODES, add(1, -5)),       # Gmsh 4.8's reader aborts (double free)
    "5 nodes fewer than counted": edit(NODES, add(1, 5)),
    "3 elements more than counted": edit(ELEMENTS, add(1, -3)),  # Gmsh 4.8's reader aborts
    "more node blocks counted": edit(NODES, add(0, 2)),
    "a node block counts 2 more": edit(after("$Nodes", 2), add(3, 2)),
    "huge element count": edit(ELEMENTS, put(1, "99999999999")),
    "wrong max node tag": edit(NODES, add(3, -3)),
    "element on an unknown node": edit(after("$Elements", 3), put(1, "99999")),
    "nan coordinate": edit(after("$Nodes", 4), put(0, "nan")),
    "version 5": lambda text: re.sub(r"^4\.1 ", "5.0 ", text, count=1, flags=re.M).encode(),
    "version 2.2 header": lambda text: re.sub(r"^4\.1 ", "2.2 ", text, count=1, flags=re.M).encode(),
})


@pytest.fixture(scope="module")
def intact_history(intact, tmp_path_factory):
    import fem_impact

    folder = tmp_path_factory.mktemp("intact_run")
    (folder / "bars.msh").write_text(intact)
    (folder / "case.yaml").write_text(CASE)
    history = fem_impact.run(fem_impact.load_case(folder / "case.yaml")).history
    assert history["wall.impulse"].sum() > 0.0   # the comparison below is of runs that did something
    return history


@pytest.mark.parametrize("variant", list(DAMAGES))
def test_damaged_file_through_the_api(tmp_path, intact, intact_history, variant):
    import fem_impact

    mesh = tmp_path / "bars.msh"
    mesh.write_bytes(DAMAGES[variant](intact))
    (tmp_path / "case.yaml").write_text(CASE)
    try:
        history = fem_impact.run(fem_impact.load_case(tmp_path / "case.yaml")).history
    except fem_impact.CaseError as error:
        message = str(error)
        assert error.key == "mesh.file", message
        assert str(mesh) in message and "\n" not in message, message
    else:   # Gmsh reads past this damage: then it is the intact mesh
        assert list(history) == list(intact_history)
        for name, column in history.items():
            assert np.array_equal(column, intact_history[name]), (variant, name)


@pytest.mark.parametrize("variant", ["garbled $EndNodes", "5 nodes more than counted", "binary noise"])
def test_damaged_file_on_the_command_line(tmp_path, intact, variant):
    mesh = tmp_path / "bars.msh"
    mesh.write_bytes(DAMAGES[variant](intact))
    (tmp_path / "case.yaml").write_text(CASE)
    result = run_cli("run", str(tmp_path / "case.yaml"), "-o", str(tmp_path / "out"), "-q")
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("fem-impact: error:"), result.stderr
    assert f"mesh.file: cannot read Gmsh file {mesh}: " in result.stderr
    assert not (tmp_path / "out").exists()


def write_unusable(path, kind: str) -> None:
    """A valid Gmsh file that fem-impact cannot take as it is."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        geo = gmsh.model.geo
        if kind == "1D along y":
            line = geo.addLine(geo.addPoint(0, 0, 0, 0.25), geo.addPoint(0, 1, 0, 0.25))
            geo.synchronize()
            gmsh.model.setPhysicalName(1, gmsh.model.addPhysicalGroup(1, [line]), "bar_a")
        else:
            surfaces = []
            for x0 in (0.0, 1.0):
                p = [geo.addPoint(x0 + dx, dy, 0, 0.25) for dx, dy in ((0, 0), (1, 0), (1, 0.5), (0, 0.5))]
                loop = geo.addCurveLoop([geo.addLine(p[i], p[(i + 1) % 4]) for i in range(4)])
                surfaces.append(geo.addPlaneSurface([loop]))
            if kind == "triangles and quadrilaterals":
                geo.mesh.setRecombine(2, surfaces[0])
            geo.synchronize()
            for name, surface in zip(("bar_a", "bar_b"), surfaces, strict=True):
                gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, [surface]), name)
        gmsh.model.mesh.generate(gmsh.model.getDimension())
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


@pytest.mark.parametrize("kind, said", [
    ("triangles and quadrilaterals", "its bodies mix element types (Quadrilateral 4, Triangle 3): one type is needed"),
    ("1D along y", "a 1D mesh must lie along x (its nodes' yz coordinates vary)"),
])
def test_meshes_fem_impact_cannot_take(tmp_path, kind, said):
    """Valid files, but not meshes the model can use as they are: one line saying why (the mixed
    mesh crashed dolfinx 0.5 or lost the cells of one type, the 1D one lost its y)."""
    import fem_impact

    write_unusable(tmp_path / "bars.msh", kind)
    (tmp_path / "case.yaml").write_text("name: unusable\nmesh: {file: bars.msh}\n"
                                        "material: {E: 1.0, rho: 1.0, area: 1.0}\nsolver: {dt: 0.1, t_end: 0.2}\n")
    with pytest.raises(fem_impact.CaseError) as error:
        fem_impact.run(fem_impact.load_case(tmp_path / "case.yaml"))
    assert error.value.key == "mesh.file"
    assert f"cannot read Gmsh file {tmp_path / 'bars.msh'}: {said}" in str(error.value)


def _renamed(text: str, renames: dict[str, str]) -> str:
    """``text`` with the $PhysicalNames entries ``"old"`` given the names ``"new"`` (the rest unchanged)."""
    head, _, rest = text.partition("$PhysicalNames")
    names, _, tail = rest.partition("$EndPhysicalNames")
    for old, new in renames.items():
        names = names.replace(f'"{old}"', f'"{new}"')
    return f"{head}$PhysicalNames{names}$EndPhysicalNames{tail}"


@pytest.mark.parametrize("renames, name, kind", [
    ({"bar_b": "bar_a"}, "bar_a", "bodies"),
    ({"right": "left"}, "left", "node groups"),
    ({"corner": "left"}, "left", "node groups"),
])
def test_two_physical_groups_of_one_name_are_refused_naming_the_file_and_the_name(tmp_path, renames, name, kind):
    """Two bodies, or two node groups (of one dimension or two), named alike in the file: one of them was
    taken silently (a body's cells then had no material: no mass, no stiffness). Refused, naming the file and
    the name; a body and a node group of one name are told apart (bodies and node groups are looked up apart)."""
    import fem_impact

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        a, b = gmsh.model.occ.addRectangle(0, 0, 0, 1, 0.5), gmsh.model.occ.addRectangle(1, 0, 0, 1, 0.5)
        gmsh.model.occ.fragment([(2, a)], [(2, b)])
        gmsh.model.occ.synchronize()
        for dim, tags, group in ((2, [a], "bar_a"), (2, [b], "bar_b"), (0, [1], "corner")):
            gmsh.model.setPhysicalName(dim, gmsh.model.addPhysicalGroup(dim, tags), group)
        for group, x in (("left", 0.0), ("right", 2.0)):
            ends = gmsh.model.getEntitiesInBoundingBox(x - 1e-6, -1e-6, -1e-6, x + 1e-6, 0.5 + 1e-6, 1e-6, 1)
            gmsh.model.setPhysicalName(1, gmsh.model.addPhysicalGroup(1, [t for _, t in ends]), group)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.25)
        gmsh.model.mesh.generate(2)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.write(str(tmp_path / "good.msh"))
    finally:
        gmsh.finalize()
    good = (tmp_path / "good.msh").read_text()
    (tmp_path / "bars.msh").write_text(_renamed(good, renames))
    case = ("mesh: {file: MESH}\nmaterial: {E: 1.0, rho: 1.0, area: 1.0}\nsupports: [{nodes: left, fix: all}]\n"
            "solver: {dt: 0.1, t_end: 0.2}\noutput: {vtk: false}\n")
    (tmp_path / "case.yaml").write_text("name: twins\n" + case.replace("MESH", "bars.msh"))
    with pytest.raises(fem_impact.CaseError) as error:
        fem_impact.run(fem_impact.load_case(tmp_path / "case.yaml"))
    assert error.value.key == "mesh.file"
    message = str(error.value)
    assert f"cannot read Gmsh file {tmp_path / 'bars.msh'}: two physical groups are named '{name}'" in message
    assert f"finds {kind} by name" in message
    # a node group named as a body is no clash
    (tmp_path / "shared.msh").write_text(_renamed(good, {"corner": "bar_a"}))
    (tmp_path / "shared.yaml").write_text("name: shared\n" + case.replace("MESH", "shared.msh"))
    fem_impact.run(fem_impact.load_case(tmp_path / "shared.yaml"))
