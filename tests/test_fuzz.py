"""Fuzzing the loader (issue 11): mutated case files and --set values end in a valid case or a clean error.

Hypothesis mutates the project's own case files: a value anywhere replaced by another type or an
extreme number, a key dropped or added, the structure nested, the text's bytes and encoding
changed, random ``--set`` options. For each: ``load_case`` and the size guard either accept the case
or raise CaseError (the command line's status 2: one line naming file and key, no traceback), and
nothing is written. The default tier runs a few hundred examples; ``-m slow`` a few thousand.
"""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

import pytest
import yaml

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from conftest import CASES  # noqa: E402

BASES = {p.name: yaml.safe_load(p.read_text()) for p in sorted(CASES.glob("*.yaml"))
         if "file" not in (yaml.safe_load(p.read_text()).get("mesh") or {})}   # (mesh files: see below)
KEYS = ["name", "mesh.dim", "mesh.cells", "mesh.length", "mesh.height", "mesh.width", "mesh.shape", "mesh.file",
        "material.E", "material.rho", "material.nu", "material.area", "initial.velocity", "initial.velocity.0",
        "initial.displacement", "supports", "loads", "contacts", "contacts.0.normal", "contacts.0.gap",
        "contacts.0.restitution", "contacts.0.nodes", "solver.dt", "solver.t_end", "solver.method", "solver.modes",
        "solver.beta", "solver.gamma", "output.every", "output.probes", "output.probes.left", "parameters.f",
        "damping.alpha", "reference", "nothing.here", "contacts.7.gap", ".", "a..b"]

numbers = st.one_of(st.integers(), st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from([0, -1, 1e-300, 1e300, 2**63, -(2**63), 1e-12, 1e12, 1e9, 0.5, 3]))
scalars = st.one_of(st.none(), st.booleans(), numbers, st.text(max_size=20),
                    st.sampled_from(["all", "x", "w", "bar", "left", "newmark", "modal", "auto", "sin(t)", "1/0",
                                     "x**x**x**x", "__import__('os')", "\0", "\ud800", "1e400", "9" * 400]))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                        st.dictionaries(st.text(max_size=8), inner, max_size=4)),
                      max_leaves=12)


def paths(data, prefix=()):
    """Every key path of a nested structure (mappings and lists)."""
    yield prefix
    if isinstance(data, dict):
        for k, v in data.items():
            yield from paths(v, prefix + (k,))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            yield from paths(v, prefix + (i,))


def mutate(data, path, how, value):
    if not path:
        return value if how == "replace" else data
    parent = data
    for part in path[:-1]:
        parent = parent[part]
    last = path[-1]
    if how == "replace":
        parent[last] = value
    elif how == "delete":
        del parent[last]
    elif how == "nest":
        parent[last] = [parent[last]] if isinstance(parent, dict) else {"x": parent[last]}
    elif how == "add" and isinstance(parent, dict):
        parent[f"extra_{value!s:.8}"] = value
    return data


@st.composite
def case_texts(draw):
    """(file bytes, --set options) of a mutated case file."""
    import copy

    base = copy.deepcopy(BASES[draw(st.sampled_from(sorted(BASES)))])
    for _ in range(draw(st.integers(0, 3))):
        path = draw(st.sampled_from(list(paths(base))))
        base = mutate(base, path, draw(st.sampled_from(["replace", "delete", "nest", "add"])), draw(values))
    try:
        text = yaml.safe_dump(base, sort_keys=False, allow_unicode=True)
    except Exception:   # (a value PyYAML cannot dump: skip, not the loader's concern)
        text = "name: x\n"
    raw = text.encode("utf-8", "surrogatepass")
    edit = draw(st.sampled_from(["none", "none", "bytes", "encoding", "truncate", "text"]))
    if edit == "bytes":
        at = draw(st.integers(0, len(raw)))
        raw = raw[:at] + draw(st.binary(max_size=8)) + raw[at:]
    elif edit == "encoding":
        raw = text.encode(draw(st.sampled_from(["utf-16", "utf-32", "latin-1", "cp1252"])), "replace")
    elif edit == "truncate":
        raw = raw[:draw(st.integers(0, len(raw)))]
    elif edit == "text":
        at = draw(st.integers(0, len(text)))
        raw = (text[:at] + draw(st.text(alphabet=":-[]{}&*!|>'\"#%@` \n\t,?", max_size=6)) + text[at:]).encode()
    options = draw(st.lists(st.tuples(st.sampled_from(KEYS), st.one_of(
        st.text(max_size=20), values.map(lambda v: yaml.safe_dump(v, default_flow_style=True).strip()
                                        if _dumpable(v) else "x"))).map(lambda kv: f"{kv[0]}={kv[1]}"),
        max_size=2))
    return raw, options


def _dumpable(v) -> bool:
    try:
        yaml.safe_dump(v)
        return True
    except Exception:
        return False


def check_one(raw: bytes, options) -> None:
    from mpi4py import MPI

    from fem_impact.config.case import CaseError, load_case
    from fem_impact.app.limits import check_limits

    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        path = folder / "case.yaml"
        path.write_bytes(raw)
        try:
            case = load_case(path, options)
            check_limits(case, folder / "out", MPI.COMM_SELF)
        except CaseError as err:
            message = str(err)
            assert message and "\n" not in message and "Traceback" not in message, message
            assert len(message) < 2000, message[:300]
        assert sorted(os.listdir(folder)) == ["case.yaml"]   # nothing written
        assert path.read_bytes() == raw


FAST = settings(max_examples=300, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
LONG = settings(max_examples=5000, deadline=None, suppress_health_check=list(HealthCheck))


@FAST
@given(case_texts())
def test_mutated_cases_load_or_fail_cleanly(sample):
    check_one(*sample)


@pytest.mark.slow
@LONG
@given(case_texts())
def test_mutated_cases_load_or_fail_cleanly_long(sample):
    check_one(*sample)


@FAST
@given(st.sampled_from(sorted(BASES)), st.lists(st.tuples(st.sampled_from(KEYS), st.text(max_size=30)), max_size=3))
def test_set_values_load_or_fail_cleanly(name, options):
    """Any text after ``--set KEY=``: a value typed as in YAML, or a clean error."""
    check_one((CASES / name).read_bytes(), [f"{k}={v}" for k, v in options])


def test_the_fuzzer_reaches_both_outcomes():
    """The mutations are not all rejected (or all accepted): the property tests see both outcomes."""
    from fem_impact.config.case import CaseError, load_case

    good = (CASES / "impacting_bar.yaml").read_bytes()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "case.yaml"
        path.write_bytes(good)
        assert load_case(path, ["solver.dt=0.001"]).solver.dt == 0.001
        with pytest.raises(CaseError):
            load_case(path, ["solver.dt=-1"])
    assert math.isfinite(len(BASES)) and len(BASES) >= 5
