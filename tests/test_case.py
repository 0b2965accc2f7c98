"""Unit tests for fem_impact.config.case: loading, validation, --set overrides and the resolved dump."""

import textwrap

import numpy as np
import pytest
import yaml

from conftest import CASES
from fem_impact.config.case import Case, CaseError, load_case

BASE = """\
mesh:
  shape: bar
material:
  E: 1.0
  rho: 1.0
solver:
  dt: 0.01
  t_end: 1.0
"""

FULL = """\
name: impacting-bar
mesh:
  shape: bar
  dim: 1
  length: 1.0
  cells: 100
material:
  E: 70e9
  rho: 2.7e3
  nu: 0.0
  area: 1.0
damping: {alpha: 0.0, beta: 1e-6}
initial:
  velocity: [-1.0]
  displacement: ["(1 - x)/2"]
supports: [{nodes: clamp, fix: [x, y]}]
loads:
  - {nodes: drive, force: ["50*sin(2*pi*400*t)", 0]}
  - {body: all, acceleration: [0, -9.81]}
contacts:
  - name: wall
    type: obstacle
    nodes: left
    normal: [-2.0]
    gap: 0.1
    restitution: 0.0
  - name: joint
    type: pair
    nodes: [a_right, b_left]
    normal: [1.0]
    restitution: 0.5
solver:
  method: newmark
  beta: 0.25
  gamma: 0.5
  dt: 0.005
  t_end: 4.0
output:
  every: 10
  probes:
    left: [0.0]
    right: [1.0]
"""


def write(tmp_path, text, name="case.yaml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def error_of(tmp_path, text, overrides=()):
    with pytest.raises(CaseError) as info:
        load_case(write(tmp_path, text), overrides)
    return info.value


def test_full_case(tmp_path):
    case = load_case(write(tmp_path, FULL))
    assert case.name == "impacting-bar" and case.path == tmp_path / "case.yaml"
    assert (case.mesh.shape, case.mesh.file, case.mesh.dim, case.mesh.cells) == ("bar", None, 1, 100)
    assert case.material.E == 70e9 and case.material.rho == 2700.0 and case.materials is None
    assert case.damping.beta == 1e-6
    (velocity,) = case.initial.velocity
    assert velocity.body is None and velocity.value[0].evaluate() == -1.0
    x = np.array([0.0, 1.0])
    np.testing.assert_allclose(case.initial.displacement[0].value[0].evaluate(x=x), [0.5, 0.0])
    assert case.supports[0].nodes == "clamp" and case.supports[0].fix == [0, 1]
    drive, gravity = case.loads
    assert drive.nodes == "drive" and drive.body is None and drive.acceleration is None
    assert drive.force[0].variables == {"t"} and drive.force[1].evaluate() == 0.0
    assert gravity.body == "all" and gravity.acceleration[1].evaluate() == -9.81
    wall, joint = case.contacts
    assert (wall.type, wall.nodes, wall.normal, wall.gap) == ("obstacle", ["left"], [-1.0], 0.1)
    assert (joint.nodes, joint.gap, joint.restitution) == (["a_right", "b_left"], None, 0.5)
    assert (case.solver.dt, case.solver.t_end, case.solver.mass) == (0.005, 4.0, "consistent")
    assert case.output.probes == {"left": [0.0], "right": [1.0]} and case.output.vtk
    assert case.lines[("contacts", 0, "normal")] == 24


def test_defaults(tmp_path):
    case = load_case(write(tmp_path, BASE, "my-case.yaml"))
    assert case.name == "my-case"
    assert (case.mesh.dim, case.mesh.length, case.mesh.cells, case.mesh.height) == (1, 1.0, 100, None)
    assert (case.material.nu, case.material.area) == (0.0, 1.0)
    assert (case.damping.alpha, case.damping.beta) == (0.0, 0.0)
    assert case.initial.velocity == [] and case.initial.displacement == []
    assert case.supports == [] and case.loads == [] and case.contacts == []
    solver = case.solver   # the default method, the one that holds at any step, and only its keys
    assert solver.model_dump() == {"method": "moreau_jean", "dt": 0.01, "t_end": 1.0, "mass": "consistent",
                                   "theta": 0.5, "level": "position"}
    newmark = case.with_changes({"solver.method": "newmark"}).solver
    assert (newmark.beta, newmark.gamma, newmark.impact_correction) == (0.25, 0.5, True)
    modal = case.with_changes({"solver.method": "modal"}).solver
    assert (modal.scheme, modal.modes, modal.static_correction, modal.tolerance) == ("moreau_jean", "auto", True, 0.01)
    central = case.with_changes({"solver.method": "central_difference"}).solver
    assert central.mass == "lumped"   # (explicit: no solve per step)
    assert (case.output.every, case.output.probes, case.output.vtk) == (10, {}, True)


def test_yaml_1_2_numbers(tmp_path):
    case = load_case(write(tmp_path, BASE.replace("E: 1.0", "E: 2.1e+11").replace("dt: 0.01", "dt: 1e-3")
                           .replace("rho: 1.0", "rho: 70.0e9") + "output: {every: 010}\n"))
    assert (case.material.E, case.material.rho, case.solver.dt) == (2.1e11, 70e9, 1e-3)
    assert case.output.every == 10  # decimal, not YAML 1.1 octal
    assert yaml.safe_load("a: 1e-3")["a"] == "1e-3"  # the global SafeLoader is left alone


def test_per_body_materials_and_initial_values(tmp_path):
    mesh = tmp_path / "meshes" / "two_bars.msh"
    mesh.parent.mkdir()
    mesh.write_text("")
    case = load_case(write(tmp_path, """\
        mesh: {file: meshes/two_bars.msh}
        materials: {bar_a: {E: 1, rho: 1}, bar_b: {E: 2, rho: 3, nu: 0.3}}
        initial:
          velocity: [{body: bar_a, value: [1.0, "y"]}, {body: bar_b, value: [0]}]
        solver: {dt: 0.1, t_end: 1, method: modal, modes: auto}
        """))
    assert case.mesh.file == mesh and case.mesh.shape is None and case.mesh.dim is None
    assert case.material is None and case.materials["bar_b"].nu == 0.3
    assert [v.body for v in case.initial.velocity] == ["bar_a", "bar_b"]
    assert case.solver.modes == "auto"


def test_resolved_round_trip(tmp_path):
    (tmp_path / "m.msh").write_text("")
    text = FULL.replace("shape: bar", "file: m.msh").replace("""\
  velocity: [-1.0]""", """\
  velocity: [{body: bar, value: ["x", 0]}]""")
    case = load_case(write(tmp_path, text))
    resolved = case.resolved()
    assert resolved["mesh"]["file"] == str(tmp_path / "m.msh") and resolved["solver"]["mass"] == "consistent"
    out = tmp_path / "out"
    out.mkdir()
    written = case.write_resolved(out)
    assert written == out / "case.resolved.yaml"
    again = load_case(written)
    assert again.mesh.file == case.mesh.file
    assert again.resolved() == resolved
    assert yaml.safe_load(yaml.safe_dump(resolved)) == resolved


def test_error_format(tmp_path):
    err = error_of(tmp_path, BASE.replace("E: 1.0", "E: -1"))
    assert (err.key, err.line) == ("material.E", 4)
    assert err.file.endswith("case.yaml")
    assert str(err) == f"{err.file}:4: material.E: must be > 0, got -1"
    assert str(CaseError("x.yaml", None, 3, "bad")) == "x.yaml:3: bad"
    assert str(CaseError("x.yaml", "a.b", None, "bad")) == "x.yaml: a.b: bad"


def test_case_error_method_for_later_stages(tmp_path):
    case = load_case(write(tmp_path, FULL))
    err = case.error(("contacts", 1, "nodes"), "unknown node group 'a_right'")
    assert (err.key, err.line) == ("contacts[1].nodes", 29)
    assert case.error(("contacts", 1, "nodes", 5), "x").line == 29  # nearest known ancestor


def test_yaml_syntax_error(tmp_path):
    err = error_of(tmp_path, BASE + "output: {every: [1}\n")
    assert err.line == 9 and "invalid YAML" in str(err) and "\n" not in str(err)


@pytest.mark.parametrize("text, message", [("", "empty"), ("- 1\n", "mapping")])
def test_top_level_must_be_a_mapping(tmp_path, text, message):
    assert message in str(error_of(tmp_path, text))


def test_unknown_keys(tmp_path):
    err = error_of(tmp_path, BASE.replace("shape: bar", "shape: bar\n  cels: 4"))
    assert ":3: mesh.cels: unknown key 'cels'; did you mean 'cells'?" in str(err)
    err = error_of(tmp_path, BASE + "zzz: 1\n")
    assert err.line == 9 and "valid keys: name, mesh" in str(err)


def test_duplicate_key(tmp_path):
    err = error_of(tmp_path, BASE + "  dt: 0.02\n")
    assert (err.key, err.line, err.message) == ("solver.dt", 9, "duplicate key")


@pytest.mark.parametrize("old, new, key, message", [
    ("dt: 0.01", "dt: abc", "solver.dt", "expected a number, got 'abc'"),
    ("dt: 0.01", "dt: true", "solver.dt", "expected a number, got True"),
    ("dt: 0.01", "dt: .inf", "solver.dt", "finite"),
    ("shape: bar", "shape: bar\n  cells: 2.5", "mesh.cells", "expected an integer, got 2.5"),
    ("shape: bar", "shape: bar\n  dim: 4", "mesh.dim", "must be in [1, 3], got 4"),
    ("shape: bar", "shape: ball", "mesh.shape", "must be one of bar"),
    ("material:\n  E: 1.0\n  rho: 1.0\n", "material: 3\n", "material", "expected a mapping"),
])
def test_wrong_types(tmp_path, old, new, key, message):
    err = error_of(tmp_path, BASE.replace(old, new))
    assert err.key == key and message in err.message


def test_integral_float_accepted_for_int(tmp_path):
    assert load_case(write(tmp_path, BASE.replace("shape: bar", "shape: bar\n  cells: 1e3"))).mesh.cells == 1000


@pytest.mark.parametrize("old, new, key, message", [
    ("E: 1.0", "E: 0", "material.E", "must be > 0, got 0"),
    ("rho: 1.0", "rho: -2", "material.rho", "must be > 0"),
    ("rho: 1.0", "rho: 1\n  area: 0", "material.area", "must be > 0"),
    ("rho: 1.0", "rho: 1\n  nu: 0.5", "material.nu", "must be in [0, 0.5), got 0.5"),
    ("rho: 1.0", "rho: 1\n  nu: -0.1", "material.nu", "must be in [0, 0.5)"),
    ("dt: 0.01", "dt: 0", "solver.dt", "must be > 0"),
    ("t_end: 1.0", "t_end: -1", "solver.t_end", "must be > 0"),
    ("dt: 0.01", "dt: 2", "solver.dt", "must be <= t_end"),
    ("shape: bar", "shape: bar\n  length: 0", "mesh.length", "must be > 0"),
    ("dt: 0.01", "dt: 0.01\n  method: modal\n  tolerance: 1", "solver.tolerance", "must be in (0, 1)"),
    ("dt: 0.01", "dt: 0.01\n  method: modal\n  modes: 0", "solver.modes", "'auto' or an integer >= 1"),
    ("dt: 0.01", "dt: 0.01\n  method: explicit", "solver.method",
     "one of moreau_jean, newmark, central_difference, modal"),
    ("dt: 0.01", "dt: 0.01\n  method: newmark\n  gamma: 0.4", "solver.gamma", "must be >= 0.5"),
    ("dt: 0.01", "dt: 0.01\n  method: modal\n  mass: redistributed", "solver.mass",
     "must be one of consistent, lumped with method modal (scheme moreau_jean); got 'redistributed' "
     "(a value for method moreau_jean, newmark)"),
])
def test_out_of_range(tmp_path, old, new, key, message):
    err = error_of(tmp_path, BASE.replace(old, new))
    assert err.key == key and message in err.message and err.line


def test_missing_required_keys(tmp_path):
    assert error_of(tmp_path, BASE.replace("  t_end: 1.0\n", "")).key == "solver.t_end"
    assert "give 'material'" in str(error_of(tmp_path, BASE.replace("material:\n  E: 1.0\n  rho: 1.0\n", "")))
    both = BASE + "materials: {a: {E: 1, rho: 1}}\n"
    assert "not both" in str(error_of(tmp_path, both))
    assert "give 'shape'" in str(error_of(tmp_path, BASE.replace("  shape: bar\n", "  dim: 1\n")))


def test_missing_mesh_file(tmp_path):
    err = error_of(tmp_path, BASE.replace("shape: bar", "file: nowhere.msh"))
    assert err.key == "mesh.file" and err.line == 2
    assert f"mesh file not found: {tmp_path / 'nowhere.msh'}" in str(err)


CONTACT = BASE + """\
contacts:
  - name: c
    type: obstacle
    nodes: left
    normal: [1.0]
"""


@pytest.mark.parametrize("old, new, key, message", [
    ("normal: [1.0]", "normal: [0, 0.0]", "contacts[0].normal", "nonzero length"),
    ("normal: [1.0]", "normal: [1, 0, 0, 0]", "contacts[0].normal", "1 to 3 components"),
    ("nodes: left", "nodes: [left, right]", "contacts[0].nodes", "one node group"),
    ("type: obstacle\n    nodes: left", "type: pair\n    nodes: [a, b, c]", "contacts[0].nodes", "two node groups"),
    ("type: obstacle\n    nodes: left", "type: pair\n    nodes: left", "contacts[0].nodes", "two node groups"),
    ("type: obstacle\n    nodes: left", "type: pair\n    nodes: [a, a]", "contacts[0].nodes", "must differ"),
    ("normal: [1.0]", "normal: [1.0]\n    restitution: 1.5", "contacts[0].restitution", "in [0, 1]"),
    ("normal: [1.0]", "normal: [1.0]\n    restitution: -0.1", "contacts[0].restitution", "in [0, 1]"),
    ("name: c", "name: 'a,b'", "contacts[0].name", "letters, digits"),
    ("type: obstacle", "type: glue", "contacts[0].type", "one of obstacle, pair"),
])
def test_bad_contacts(tmp_path, old, new, key, message):
    err = error_of(tmp_path, CONTACT.replace(old, new))
    assert err.key == key and message in err.message and err.line


def test_contact_and_probe_names_unique(tmp_path):
    twice = CONTACT + "  - {name: c, type: obstacle, nodes: right, normal: [-1]}\n"
    err = error_of(tmp_path, twice)
    assert (err.key, err.line) == ("contacts[1].name", 14) and "duplicate" in err.message
    err = error_of(tmp_path, BASE + "output:\n  probes: {p: [0], p: [1]}\n")
    assert err.key == "output.probes.p" and "duplicate" in err.message


def test_obstacle_gap_defaults_to_zero(tmp_path):
    assert load_case(write(tmp_path, CONTACT)).contacts[0].gap == 0.0


@pytest.mark.parametrize("section, key", [
    ("initial:\n  velocity: [\"__import__('os').system('touch {marker}')\"]\n", "initial.velocity[0]"),
    ("initial:\n  velocity: [{body: b, value: [\"open('{marker}', 'w')\"]}]\n", "initial.velocity[0].value[0]"),
    ("loads: [{nodes: n, force: [\"x\"]}]\n", "loads[0].force[0]"),
])
def test_expressions_are_not_executed(tmp_path, section, key):
    marker = tmp_path / "X"
    err = error_of(tmp_path, BASE + section.replace("{marker}", str(marker)))
    assert err.key == key and err.line
    assert not marker.exists()


def test_loads_need_matching_keys(tmp_path):
    assert "either 'nodes'" in str(error_of(tmp_path, BASE + "loads: [{force: [1]}]\n"))
    err = error_of(tmp_path, BASE + "loads: [{body: all, force: [1]}]\n")
    assert err.key == "loads[0].force" and "not allowed with 'body'" in err.message


def test_overrides(tmp_path):
    path = write(tmp_path, CONTACT)
    case = load_case(path, ["solver.dt=1e-3", "mesh.cells=400", "contacts.0.gap=0.2",
                            "contacts.0.normal=[-1]", "damping.alpha=0.5"])
    assert (case.solver.dt, case.mesh.cells, case.damping.alpha) == (1e-3, 400, 0.5)
    assert (case.contacts[0].gap, case.contacts[0].normal) == (0.2, [-1.0])


@pytest.mark.parametrize("option, text", [
    ("mesh.cels=400", "mesh.cels: unknown key 'cels'; did you mean 'cells'? (from --set mesh.cels=400)"),
    ("solver.dt=abc", "solver.dt: expected a number, got 'abc' (from --set solver.dt=abc)"),
    ("contacts.3.gap=1", "--set: contacts.3: no item 3"),
    ("solver.dt.x=1", "--set: solver.dt: is not a mapping"),
    ("solver.dt", "--set: expected KEY.PATH=VALUE"),
    ("solver.dt=[1", "--set: solver.dt: cannot read the value"),
])
def test_bad_overrides(tmp_path, option, text):
    err = error_of(tmp_path, CONTACT, [option])
    assert text in str(err) and err.line is None


def test_error_from_later_stage_names_override(tmp_path):
    case = load_case(write(tmp_path, CONTACT), ["contacts.0.nodes=right"])
    err = case.error(("contacts", 0, "nodes"), "unknown node group 'right'")
    assert err.line is None and "(from --set contacts.0.nodes=right)" in str(err)


# --- parameters ---------------------------------------------------------------------------

PARAMETERS = BASE + """\
parameters: {f: 2000.0, F0: 5.0, v0: -1}
initial:
  velocity: ["v0*x"]
loads:
  - {nodes: right, force: ["F0*sin(2*pi*f*t)", 0]}
"""


def test_parameters_in_expressions(tmp_path):
    case = load_case(write(tmp_path, PARAMETERS))
    assert case.parameters == {"f": 2000.0, "F0": 5.0, "v0": -1.0}
    force = case.loads[0].force[0]
    assert force.at_time(1.0 / 8000.0) == pytest.approx(5.0) and force.constants == {"F0", "f"}
    assert case.initial.velocity[0].value[0](x=np.array([0.5])) == pytest.approx([-0.5])


def test_parameters_overridden_with_set_and_written_resolved(tmp_path):
    path = write(tmp_path, PARAMETERS)
    case = load_case(path, ["parameters.f=2500", "parameters.F0=1e1"])
    assert case.loads[0].force[0].at_time(1.0 / 10000.0) == pytest.approx(10.0)   # sin(2 pi 2500 / 10000)
    resolved = yaml.safe_load(case.write_resolved(tmp_path / "resolved.yaml").read_text())
    assert resolved["parameters"] == {"f": 2500.0, "F0": 10.0, "v0": -1.0}
    assert resolved["loads"][0]["force"][0] == "F0*sin(2*pi*f*t)"    # as written, with the values beside
    again = load_case(tmp_path / "resolved.yaml")
    assert again.loads[0].force[0].at_time(1.0 / 10000.0) == pytest.approx(10.0)
    # a case without a parameters section takes one from --set
    plain = load_case(write(tmp_path, BASE + 'loads: [{nodes: right, force: ["F0"]}]\n', "plain.yaml"),
                      ["parameters.F0=3"])
    assert plain.loads[0].force[0]() == 3.0


@pytest.mark.parametrize("parameters, key, message", [
    ("{t: 1.0}", "parameters.t", "'t' is reserved"),
    ("{x: 1.0}", "parameters.x", "'x' is reserved"),
    ("{pi: 3.0}", "parameters.pi", "'pi' is reserved"),
    ("{e: 2.7}", "parameters.e", "'e' is reserved"),
    ("{sin: 1.0}", "parameters.sin", "'sin' is reserved"),
    ("{2f: 1.0}", "parameters.2f", "must be an identifier"),
    ("{f-0: 1.0}", "parameters.f-0", "must be an identifier"),
    ("{lambda: 1.0}", "parameters.lambda", "must be an identifier"),
    ("{f: fast}", "parameters.f", "expected a number, got 'fast'"),
    ("{f: [1, 2]}", "parameters.f", "expected a number, got a list"),
    ("{f: .inf}", "parameters.f", "expected a finite number"),
    ("{f: true}", "parameters.f", "expected a number, got True"),
    ("[1, 2]", "parameters", "expected a mapping"),
])
def test_bad_parameters(tmp_path, parameters, key, message):
    err = error_of(tmp_path, BASE + f"parameters: {parameters}\n")
    assert err.key == key and err.line == 9 and message in err.message, str(err)


def test_unknown_name_in_an_expression_names_file_key_and_line(tmp_path):
    err = error_of(tmp_path, PARAMETERS.replace("F0*sin", "G0*sin"))
    assert (err.key, err.line) == ("loads[0].force[0]", 13)
    assert "'G0' is not an allowed name (allowed: t, pi, f, F0, v0)" in err.message


def test_a_parameter_set_on_the_command_line_must_be_used(tmp_path):
    path = write(tmp_path, PARAMETERS)
    err = error_of(tmp_path, PARAMETERS, ["parameters.freq=2500"])
    assert err.key == "parameters.freq" and "no expression of the case uses parameter 'freq'" in str(err)
    assert "(used: F0, f, v0)" in str(err) and "--set parameters.freq=2500" in str(err)
    # defined in the file and unused is allowed (documentation), and so is a new one that is used
    load_case(write(tmp_path, PARAMETERS.replace("{f: 2000.0,", "{f: 2000.0, spare: 1,")))
    load_case(path, ["parameters.g=9.81", "loads.0.force=[\"F0\", \"-g\"]"])


def test_a_parameter_of_a_supports_motion_is_used():
    """base_excited_beam's amplitude A appears only in its clamp's prescribed motion: --set takes it (it was
    refused as used by no expression), and the motion follows it."""
    case = load_case(CASES / "base_excited_beam.yaml", ["parameters.A=4e-5"])
    assert case.parameters["A"] == 4e-5
    motion = case.supports[0].displacement[1]
    assert motion.at_time(0.25 / case.parameters["f"]) == pytest.approx(4e-5, rel=1e-12)


# --- numeric limits (issue 16): values and the scales the model forms from them ----------------


@pytest.mark.parametrize("key, value", [
    ("material.E", "1e308"), ("material.area", "1e308"), ("material.area", "1e-320"), ("material.rho", "1e-320"),
    ("damping.beta", "1e308"), ("mesh.length", "1e-320"), ("mesh.length", "1e200"), ("solver.t_end", "1e300"),
    ("material.E", "1e101"), ("contacts.0.gap", "-1e-101"),
])
def test_a_value_whose_square_leaves_the_floats_is_refused_on_its_key(tmp_path, key, value):
    err = error_of(tmp_path, CONTACT, [f"{key}={value}"])
    assert err.key == key.replace(".0.", "[0]."), str(err)
    assert err.message.startswith(f"must be within 1e-100 and 1e+100 in magnitude, got {float(value)!r} ("), str(err)
    assert "explicit" not in err.message and "\n" not in str(err)


def test_values_at_the_ends_of_the_range_load(tmp_path):
    """1e-100 and 1e+100 themselves are accepted, and so are the scales they form within the range."""
    case = load_case(write(tmp_path, BASE), ["material.E=1e100", "material.rho=1e100", "material.area=1e-5",
                                             "damping.alpha=1e-100"])
    assert (case.material.E, case.material.rho, case.damping.alpha) == (1e100, 1e100, 1e-100)


@pytest.mark.parametrize("changes, key, scale, direction", [
    # every value in range, but the element stiffness E A / h = 1e99 * 1e10 * 100 leaves it
    (["material.E=1e99", "material.area=1e10", "mesh.cells=100"], "material.E", "element stiffness", "above"),
    # the element mass rho A h = 1e-90 * 1e-10 / 100: below the range; the smallest factor is rho
    (["material.rho=1e-90", "material.area=1e-10", "mesh.cells=100"], "material.rho", "element mass", "below"),
    # the stiffness term of the step matrix dt^2 E A / h = 1e10 * 1e90 * 100: its largest factor is E
    (["material.E=1e90", "solver.t_end=1e5", "solver.dt=1e5"], "material.E", "dt^2 k", "above"),
    # the contact problem's scale dt^2 / (rho A h) = 1e80 / 1e-62 with a large step on a light bar: dt is named
    (["solver.t_end=1e40", "solver.dt=1e40", "material.rho=1e-60"], "solver.dt", "dt^2 / m", "above"),
    # a light 3D bar of a thin section (h x 1e-15 x 1e-15): rho pushes the element mass furthest
    (["mesh.dim=3", "mesh.height=1e-15", "mesh.width=1e-15", "mesh.cells=10", "material.rho=1e-70"], "material.rho",
     "element mass", "below"),
])
def test_a_scale_the_model_forms_beyond_the_range_names_its_largest_factor(tmp_path, changes, key, scale, direction):
    err = error_of(tmp_path, BASE, changes)
    assert err.key == key, str(err)
    assert scale in err.message and f"{direction} 1e" in err.message and "use other units" in err.message, str(err)
    assert "\n" not in str(err)


def test_a_side_of_the_built_in_bar_below_the_machine_epsilon_is_refused(tmp_path):
    """dolfinx's generator takes a side shorter than 2.2e-16 for zero ('Length of interval is zero')."""
    err = error_of(tmp_path, BASE, ["mesh.length=1e-20"])
    assert err.key == "mesh.length" and "below 2.22e-16 (the mesh generator takes it for zero)" in err.message
    err = error_of(tmp_path, BASE, ["mesh.dim=2", "mesh.length=1e-15"])   # its default height, length / 20
    assert err.key == "mesh.length" and "height would be 5.0000000000000005e-17" in err.message
    err = error_of(tmp_path, BASE, ["mesh.dim=3", "mesh.width=1e-17"])
    assert err.key == "mesh.width"


def test_huge_integers_in_a_file_and_in_messages_are_one_clear_line(tmp_path):
    """Python refuses to print an integer of more than 4300 digits: the loader and the messages must not try."""
    err = error_of(tmp_path, BASE.replace("shape: bar", f"shape: bar\n  cells: {'9' * 5000}"))
    assert (err.key, err.line) == (None, 3) and "5000 digits" in err.message, str(err)
    from fem_impact import Case

    case = load_case(write(tmp_path, BASE))
    for changes, key in [({"mesh.cells": 10**5000}, "mesh.cells"), ({"material.E": 10**400}, "material.E"),
                         ({"name": -10**5000}, "name"), ({"parameters": {"p": 10**5000}}, "parameters.p")]:
        with pytest.raises(CaseError) as info:
            case.with_changes(changes)
        assert info.value.key == key and "\n" not in str(info.value) and len(str(info.value)) < 300, str(info.value)
    with pytest.raises(CaseError) as info:
        Case.from_dict({**case.source, "material": {"E": 10**400, "rho": 1.0}})
    assert info.value.key == "material.E" and "1e+400" in info.value.message, str(info.value)


def test_a_case_with_neither_material_nor_materials_is_told_what_is_missing(tmp_path):
    err = error_of(tmp_path, BASE.replace("material:\n  E: 1.0\n  rho: 1.0\n", ""))
    assert err.key == "material" and err.message == ("missing required key: give 'material' (for every body) or "
                                                     "'materials' (per body)")
    both = error_of(tmp_path, BASE + "materials: {a: {E: 1, rho: 1}}\n")
    assert both.key == "material" and "not both" in both.message


@pytest.mark.parametrize("text", [
    BASE.replace("shape: bar", 'shape: bar\n  "ce\\nlls": 4'),          # an unknown key holding a newline
    BASE.replace("material:\n  E: 1.0\n  rho: 1.0\n", 'materials: {"ba\\nr": {E: 1, rho: 1, nu: 2}}\n'),  # a body
    BASE + '"a\\u2028b": 1\n',                                            # a unicode line separator
])
def test_a_key_holding_a_newline_keeps_the_message_on_one_line(tmp_path, text):
    message = str(error_of(tmp_path, text))
    assert message.splitlines() == [message], message
    assert "\\n" in message or "\\u2028" in message, message



def test_validating_loads_no_petsc():
    """A case with friction is validated from its method's schema alone: neither PETSc nor dolfinx loads."""
    import subprocess
    import sys

    code = ("import sys; from fem_impact.config.case import load_case; case = load_case(sys.argv[1]); "
            "assert case.contacts[0].friction > 0; "
            "print(sorted(m for m in ('petsc4py', 'dolfinx', 'mpi4py') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code, str(CASES / "vibromotor.yaml")], capture_output=True,
                         text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_sections_declare_their_keys():
    """Every key of every section carries its meaning, and every number its unit (the case reference reads them)."""
    from fem_impact.config.schema import SECTIONS
    from fem_impact.integrators.parameters import SCHEMAS

    for section, model in [*SECTIONS.items(), *((f"solver ({tag})", schema) for tag, schema in SCHEMAS.items())]:
        for name, info in model.model_fields.items():
            if name in ("method", "scheme"):   # (the method's name: its schema's docstring says what it is)
                continue
            assert info.description, f"{section}.{name} has no description"
            if info.annotation in (float, int):
                unit = (info.json_schema_extra or {}).get("unit")
                assert unit, f"{section}.{name} has no unit"
    from fem_impact.config.schema import key_rows

    assert key_rows(SECTIONS["material"])[:2] == [
        {"key": "E", "unit": "Pa", "default": "required", "range": "> 0", "description": "Young's modulus"},
        {"key": "rho", "unit": "kg/m^3", "default": "required", "range": "> 0", "description": "density"}]
    assert key_rows(SECTIONS["contacts"])[5]["range"] == "in [0, 1]"   # (restitution: declared by the law)


@pytest.mark.parametrize("path", sorted(CASES.glob("*.yaml")), ids=lambda p: p.stem)
def test_every_shipped_cases_resolved_dump_reads_back_as_itself(path):
    """case.resolved.yaml is a case file: read again it gives the same case (an axisymmetric one had an area)."""
    case = load_case(path)
    assert Case.from_dict(case.resolved()).resolved() == case.resolved()
