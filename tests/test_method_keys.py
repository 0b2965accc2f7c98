"""One typed schema per method: a key that a method (or a contact kind) does not use is
refused with the method's valid keys, from a case file (file, line, key), from a dict (key) and from
``--set`` (the option); a change of method drops the previous method's keys."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

import fem_impact
from conftest import CASES, run_cli
from fem_impact import Case, CaseError
from fem_impact.integrators.parameters import SCHEMAS, describe, solver_schema, tag, valid_keys

BAR = """\
mesh: {shape: bar, cells: 20}
material: {E: 1.0, rho: 1.0}
contacts:
  - name: wall
    type: obstacle
    nodes: left
    normal: [-1.0]
    gap: 0.1
solver:
  method: {method}
  dt: 0.01
  t_end: 1.0
"""

CENTRAL = ", ".join(["method", "dt", "t_end", "mass"])
NEWMARK = ", ".join(["method", "dt", "t_end", "mass", "beta", "gamma", "impact_correction"])
STOP = "name, type, nodes, normal, gap, coupling, stiffness, law, friction, point, motion, surface"

# (method of the file, section, ignored key, value, the key's owner as named in the message, valid keys)
IGNORED = [
    ("central_difference", "solver", "beta", 0.9, "newmark, modal (scheme newmark)", CENTRAL),
    ("central_difference", "solver", "gamma", 0.9, "newmark, modal (scheme newmark)", CENTRAL),
    ("newmark", "solver", "modes", 10, "modal", NEWMARK),
    ("newmark", "solver", "tolerance", 0.5, "modal", NEWMARK),
]


def expected(method, key, owners, valid):
    return f"method {method} does not use '{key}' (a key of {owners}); its keys: {valid}"


STOP_MESSAGE = (f"an elastic stop (stiffness given) does not use 'restitution': its spring gives back what it "
                f"stores; keys of an elastic stop: {STOP} (or remove stiffness for a rigid contact)")


def elastic_stop(text: str) -> str:
    return text.replace("    gap: 0.1\n", "    gap: 0.1\n    stiffness: 1000.0\n")


@pytest.mark.parametrize("method, section, key, value, owners, valid", IGNORED)
def test_ignored_solver_key_refused_from_a_file(tmp_path, method, section, key, value, owners, valid):
    text = BAR.replace("{method}", method) + f"  {key}: {value}\n"
    path = tmp_path / "case.yaml"
    path.write_text(text)
    with pytest.raises(CaseError) as info:
        fem_impact.load_case(path)
    err = info.value
    line = text.splitlines().index(f"  {key}: {value}") + 1
    assert (err.file, err.line, err.key) == (str(path), line, f"solver.{key}")
    assert err.message == expected(method, key, owners, valid)
    assert str(err) == f"{path}:{line}: solver.{key}: {expected(method, key, owners, valid)}"


@pytest.mark.parametrize("method, section, key, value, owners, valid", IGNORED)
def test_ignored_solver_key_refused_from_a_dict(method, section, key, value, owners, valid):
    data = yaml.safe_load(BAR.replace("{method}", method))
    data["solver"][key] = value
    with pytest.raises(CaseError) as info:
        Case.from_dict(data)
    assert (info.value.file, info.value.key) == (None, f"solver.{key}")
    assert info.value.message == expected(method, key, owners, valid)


@pytest.mark.parametrize("method, section, key, value, owners, valid", IGNORED)
def test_ignored_solver_key_refused_from_set(tmp_path, method, section, key, value, owners, valid):
    path = tmp_path / "case.yaml"
    path.write_text(BAR.replace("{method}", method))
    result = run_cli("run", str(path), "-o", str(tmp_path / "out"), "--set", f"solver.{key}={value}")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.strip() == (f"fem-impact: error: {path}: solver.{key}: {expected(method, key, owners, valid)}"
                                     f" (from --set solver.{key}={value})")
    assert not (tmp_path / "out").exists()


def test_elastic_stop_refuses_a_restitution_from_a_file_a_dict_and_set(tmp_path):
    text = elastic_stop(BAR.replace("{method}", "moreau_jean"))
    path = tmp_path / "stop.yaml"
    path.write_text(text.replace("stiffness: 1000.0\n", "stiffness: 1000.0\n    restitution: 0.8\n"))
    with pytest.raises(CaseError) as info:
        fem_impact.load_case(path)
    line = path.read_text().splitlines().index("    restitution: 0.8") + 1
    assert (info.value.key, info.value.line, info.value.message) == ("contacts[0].restitution", line, STOP_MESSAGE)

    data = yaml.safe_load(text)
    data["contacts"][0]["restitution"] = 0.8
    with pytest.raises(CaseError) as info:
        Case.from_dict(data)
    assert (info.value.key, info.value.message) == ("contacts[0].restitution", STOP_MESSAGE)

    path.write_text(text)
    fem_impact.load_case(path)   # the stop without a restitution is fine
    result = run_cli("run", str(path), "-o", str(tmp_path / "out"), "--set", "contacts.0.restitution=0.8")
    assert result.returncode == 2
    assert result.stderr.strip().endswith(f"contacts[0].restitution: {STOP_MESSAGE} (from --set "
                                          "contacts.0.restitution=0.8)")
    # a rigid contact takes it, and the resolved dump of a stop reads back
    assert fem_impact.load_case(path, ["contacts.0.stiffness=null", "contacts.0.restitution=0.8"]) \
        .contacts[0].restitution == 0.8
    case = fem_impact.load_case(path)
    assert Case.from_dict(case.resolved()).resolved() == case.resolved()


def test_unknown_solver_key_suggests_the_closest_of_the_method():
    data = yaml.safe_load(BAR.replace("{method}", "moreau_jean"))
    data["solver"]["thetaa"] = 0.6
    with pytest.raises(CaseError) as info:
        Case.from_dict(data)
    assert info.value.message == ("unknown key 'thetaa'; did you mean 'theta'? (keys of method moreau_jean: "
                                  "method, dt, t_end, mass, theta, level)")


def test_changing_the_method_drops_the_previous_methods_keys():
    """impacting_bar.yaml is newmark with beta and gamma: --set solver.method=moreau_jean takes it over."""
    case = fem_impact.load_case(CASES / "impacting_bar.yaml", ["solver.method=moreau_jean"])
    assert case.solver.model_dump() == {"method": "moreau_jean", "dt": 0.002, "t_end": 4.0, "mass": "consistent",
                                        "theta": 0.5, "level": "position"}
    modal = fem_impact.load_case(CASES / "impacting_bar.yaml").with_changes(
        {"solver.method": "modal", "solver.scheme": "newmark", "solver.modes": 12})
    assert (modal.solver.beta, modal.solver.modes) == (0.25, 12)   # newmark's keys kept: the scheme takes them
    with pytest.raises(CaseError) as info:   # a key the change itself gives is checked as usual
        fem_impact.load_case(CASES / "impacting_bar.yaml", ["solver.method=moreau_jean", "solver.beta=0.3"])
    assert info.value.key == "solver.beta" and "(from --set solver.beta=0.3)" in info.value.message


def test_resolved_dump_of_every_method_reads_back():
    base = yaml.safe_load(BAR.replace("{method}", "moreau_jean"))
    for tag in SCHEMAS:
        method, _, scheme = tag.partition("/")
        solver = {"method": method, "dt": 0.01, "t_end": 1.0, **({"scheme": scheme} if scheme else {})}
        case = Case.from_dict({**base, "solver": solver})
        assert list(case.resolved()["solver"]) == valid_keys(SCHEMAS[tag])
        assert Case.from_dict(case.resolved()).resolved() == case.resolved()
        if method == "modal":   # a count of modes: no tolerance in the dump, which reads back
            counted = case.with_changes({"solver.modes": 5})
            assert "tolerance" not in counted.resolved()["solver"]
            assert Case.from_dict(counted.resolved()).resolved() == counted.resolved()


def test_every_method_documents_its_keys_with_units():
    for schema in SCHEMAS.values():
        assert schema.__doc__ and schema.__doc__.strip()
        text = describe(schema)
        for key in valid_keys(schema):
            assert re.search(rf"^{key} \(", text, re.M), f"{schema.__name__}.{key} undocumented"
        assert "dt (s, required): time step" in text


def test_tolerance_needs_modes_auto(tmp_path):
    data = yaml.safe_load(BAR.replace("{method}", "modal"))
    data["solver"].update(modes=5, tolerance=0.1)
    with pytest.raises(CaseError) as info:
        Case.from_dict(data)
    assert info.value.key == "solver.tolerance" and "applies to modes: auto only" in info.value.message


def test_every_shipped_case_sets_its_methods_keys_and_its_solver_section_reads_back():
    """The solver section of each case in cases/ against its method's schema: the file sets only that
    method's keys, the resolved dump lists all of them (a count of modes: no tolerance), and the dump
    read back through the schema gives the same parameters."""
    for path in sorted(Path(CASES).glob("*.yaml")):
        given = yaml.safe_load(path.read_text()).get("solver") or {}
        case = fem_impact.load_case(path)
        dumped = case.resolved()["solver"]
        keys = valid_keys(SCHEMAS[tag(dumped)])
        assert set(given) <= set(keys), path.name
        counted = tag(dumped).startswith("modal") and dumped["modes"] != "auto"
        assert list(dumped) == [k for k in keys if not (counted and k == "tolerance")], path.name
        again = solver_schema().validate_python(dumped)
        assert again.model_dump() == case.solver.model_dump(), path.name


def test_run_help_lists_each_methods_keys():
    result = run_cli("run", "--help")
    assert result.returncode == 0
    for title in ("method: moreau_jean", "method: newmark", "method: central_difference",
                  "method: modal, scheme: moreau_jean", "method: modal, scheme: newmark"):
        assert title in result.stdout
    assert "tolerance (-, default 0.01)" in result.stdout and "dt (s, required): time step" in result.stdout


def test_a_misspelt_key_is_named_before_the_key_it_leaves_missing():
    """``dtt`` for ``dt``: the typo is the cause, the missing dt its consequence."""
    data = yaml.safe_load(BAR.replace("{method}", "newmark"))
    data["solver"] = {"method": "newmark", "dtt": 0.01, "t_end": 1.0}
    with pytest.raises(CaseError) as info:
        Case.from_dict(data)
    assert info.value.key == "solver.dtt"
    assert info.value.message.startswith("unknown key 'dtt'; did you mean 'dt'? (keys of method newmark: ")
