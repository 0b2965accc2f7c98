"""Case files: YAML loading, validation into dataclasses, --set overrides and the resolved dump."""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import keyword
import logging
import math
import numbers
import operator
import os
import re
import sys
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from pydantic import ValidationError

from ..errors import CaseError, ModelInputError, OutputFolderError, type_name, wrong_type
from ..expressions import RESERVED, Expression, ExpressionError, parse_expression
from ..fem.specs import BodyValue, Damping, Initial, Load, Material, MeshSpec, Support  # noqa: F401  (re-exported)
from ..nonsmooth.specs import Contact
from ..integrators.parameters import (DEFAULT_METHOD, METHODS, MODAL_SCHEMES, REDUCED, SCHEMAS, KeyProblem,
                                     SolverParameters, solver_schema, valid_keys)
from ..integrators.parameters import tag as _schema_tag

SHAPES = ("bar",)
BAR_ELEMENTS = ("simplex", "hex")   # triangles/tetrahedra, or quadrilaterals/hexahedra (2D/3D bar)
HYPOTHESES = ("plane_stress", "plane_strain", "axisymmetric")   # 2D: the third direction (mesh.hypothesis)
CONTACT_TYPES = ("obstacle", "pair")
CONTACT_COUPLINGS = ("each", "mean")
COMPONENTS = ("x", "y", "z")
SPACE = ("x", "y", "z")  # variables of initial fields
TIME = ("t",)  # variables of loads
_CSV_NAME = re.compile(r"[A-Za-z0-9_-]+")
log = logging.getLogger(__name__)


@dataclass
class Output:
    every: int = 10
    probes: dict[str, list[float]] = field(default_factory=dict)
    vtk: bool = True
    format: str = "vtu"   # the fields' files: vtu (results.pvd, ASCII) | xdmf (results.xdmf + .h5, binary)
    checkpoint_every: int = 0   # steps between checkpoints (0: at the end only; app/checkpoint.py)


@dataclass
class Case:
    """A validated case; `lines` maps key paths to 1-based lines of the case file.

    `overrides` maps the key paths set with ``--set`` to the option text, so that
    errors about them point to the command line instead of the file.
    """

    name: str
    path: Path | None   # the case file; None for a case built in Python (Case.from_dict)
    mesh: MeshSpec
    material: Material | None
    materials: dict[str, Material] | None
    damping: Damping
    initial: Initial
    supports: list[Support]
    loads: list[Load]
    contacts: list[Contact]
    solver: SolverParameters   # the schema of its method (fem_impact.integrators.parameters)
    output: Output
    parameters: dict[str, float] = field(default_factory=dict)
    lines: dict[tuple, int] = field(default_factory=dict)
    overrides: dict[tuple, str] = field(default_factory=dict)
    reference: str | None = None   # name of a known exact solution (fem_impact.config.references)
    source: dict = field(default_factory=dict, repr=False)   # the data as given (with the changes), unvalidated
    base_dir: Path = field(default_factory=Path.cwd, repr=False)   # where relative paths in `source` start

    @classmethod
    def from_dict(cls, data, base_dir=None) -> Case:
        """Validate a case given as a mapping, exactly as a case file with the same content.

        Parameters
        ----------
        data : mapping
            The case as a case file's YAML would give it (numbers as numbers, expressions as
            strings); it is not modified.
        base_dir : path-like, optional
            The folder that relative paths in `data` (``mesh.file``) start from; default the
            current folder.

        Raises
        ------
        CaseError
            On bad input; its ``key`` is the dotted key path (``material.E``), its ``file`` None.
        TypeError
            When `data` is not a mapping, or `base_dir` not a path.

        numpy numbers and arrays, tuples, paths and other mappings are taken as the numbers, lists,
        strings and mappings a case file would give.
        """
        if not isinstance(data, Mapping):
            raise wrong_type("Case.from_dict()", "a mapping of the case's keys", data)
        if base_dir is not None:
            base_dir = _path_argument("Case.from_dict()", "base_dir as a folder (str or os.PathLike) or None", base_dir)
        folder = Path(os.path.abspath(base_dir if base_dir is not None else Path.cwd()))
        try:
            data = _plain(data, ())
        except _Invalid as exc:
            raise _error(None, {}, {}, exc.path, exc.message) from None
        return _validated(data, None, folder, None, {}, {})

    def with_changes(self, changes) -> Case:
        """A copy of the case with keys changed, validated again (this case is not modified).

        Parameters
        ----------
        changes : mapping or iterable of str
            ``{"solver.dt": 1e-3, "contacts.0.restitution": 0.5}`` (dotted key paths to values;
            list items by their index), or ``--set`` options ``["solver.dt=1e-3"]`` (values
            read as YAML). Changing ``solver.method`` drops the keys of the previous method
            that the new one does not take (its valid keys are then checked as usual).

        Raises
        ------
        CaseError
            When a change does not fit the case; the message names the change.
        TypeError
            When `changes` is neither a mapping with string keys nor a list of strings.
        """
        takes = "a mapping {'key.path': value} or a list of 'KEY.PATH=VALUE' strings"
        if isinstance(changes, Mapping):
            key = next((key for key in changes if not isinstance(key, str)), None)
            if key is not None:
                raise TypeError(f"Case.with_changes() takes {takes}, got a mapping with a {type_name(key)} key")
        else:
            changes = _strings("Case.with_changes()", takes, changes)
        data = _plain(self.source, ())
        before = _solver_tag(data)
        if isinstance(changes, Mapping):
            origins = {}
            for key, value in changes.items():
                origin = f"the change {key}={_brief(value)}"
                try:
                    value = _plain(value, ())
                except _Invalid as exc:
                    raise CaseError(origin, _dotted(exc.path) or None, None, exc.message) from None
                origins[_set_key(data, key, value, origin)] = origin
        else:
            origins = {_apply_override(data, option): f"--set {option}" for option in changes}
        _follow_kind_changes(data, before, origins)
        return _validated(data, self.path, self.base_dir, self.lines, {**self.overrides, **origins}, origins)

    @property
    def file(self) -> str | None:
        """The case file as shown in messages (None for a case built in Python)."""
        return None if self.path is None else _display(self.path)

    @contextlib.contextmanager
    def errors_at_keys(self):
        """Within: a ModelInputError of a model builder becomes a CaseError with the file, line and key.

        The one place where the builders' domain errors meet the case file (or dict, or --set).
        """
        try:
            yield self
        except ModelInputError as err:
            raise self.error(err.key, err.message) from None

    def error(self, key_path, message) -> CaseError:
        """Build a CaseError for `key_path` (e.g. ``("contacts", 0, "nodes")``) with its line."""
        if isinstance(key_path, (str, bytes)) or not isinstance(key_path, (tuple, list)) \
                or not all(isinstance(part, (str, int)) for part in key_path) or not isinstance(message, str):
            raise TypeError(f"Case.error() takes a key path (a tuple of str and int) and a message (str), got "
                            f"{type_name(key_path)} and {type_name(message)}")
        return _error(self.file, self.lines, self.overrides, tuple(key_path), message)

    def resolved(self) -> dict:
        """Return the whole case as plain data with every default filled in.

        Expressions appear as written; the mesh file path is absolute, so the dump reads
        back the same from any folder.
        """
        mesh = dataclasses.asdict(self.mesh)
        mesh["file"] = None if self.mesh.file is None else str(self.mesh.file)
        data = {"name": self.name, "parameters": dict(self.parameters), "reference": self.reference, "mesh": mesh}
        if self.material is not None:
            data["material"] = dataclasses.asdict(self.material)
        else:
            data["materials"] = {body: dataclasses.asdict(m) for body, m in self.materials.items()}
        data["damping"] = dataclasses.asdict(self.damping)
        data["initial"] = ({"from": str(self.initial.source)} if self.initial.source is not None else
                           {"displacement": _body_values_data(self.initial.displacement),
                            "velocity": _body_values_data(self.initial.velocity)})
        data["supports"] = [{"nodes": s.nodes, "fix": "all" if s.all_components else [COMPONENTS[i] for i in s.fix],
                             **({} if s.displacement is None else {"displacement": _sources(s.displacement)})}
                            for s in self.supports]
        data["loads"] = [{key: _sources(value) if key in ("force", "acceleration") else value
                          for key, value in vars(load).items() if value is not None}
                         for load in self.loads]
        data["contacts"] = [_contact_data(c) for c in self.contacts]
        data["solver"] = self.solver.as_case()
        data["output"] = dataclasses.asdict(self.output)
        return data

    def expressions(self):
        """Every expression of the case as (key path, Expression): initial fields, supports' motions and loads."""
        for which in ("displacement", "velocity"):
            items = getattr(self.initial, which)
            for i, item in enumerate(items):
                key = ("initial", which) if item.body is None else ("initial", which, i, "value")
                for comp, expr in enumerate(item.value):
                    yield key + (comp,), expr
        for i, support in enumerate(self.supports):
            for comp, expr in enumerate(support.displacement or ()):
                yield ("supports", i, "displacement", comp), expr
        for i, load in enumerate(self.loads):
            for name in ("force", "acceleration"):
                for comp, expr in enumerate(getattr(load, name) or ()):
                    yield ("loads", i, name, comp), expr

    def write_resolved(self, path) -> Path:
        """Write the resolved case as YAML to `path` (a folder gets ``case.resolved.yaml``)."""
        path = Path(_path_argument("Case.write_resolved()", "a path (str or os.PathLike)", path))
        if path.is_dir():
            path = path / "case.resolved.yaml"
        text = yaml.safe_dump(self.resolved(), sort_keys=False)
        try:
            path.write_text(text, encoding="utf-8")
        except (OSError, ValueError) as err:   # (ValueError: a NUL character in the path)
            reason = getattr(err, "strerror", None) or err
            raise OutputFolderError(str(path), f"cannot write the resolved case: {reason}") from None
        return path


def _contact_data(contact: Contact) -> dict:
    """A contact as the case file gives it: the law's keys as the contact's own; ``law`` where it does
    not follow from them."""
    if contact.law_is_inferred:   # (an elastic stop has no restitution)
        skip = ("law", "law_keys") + (("restitution",) if contact.stiffness is not None else ())
        data = {key: value for key, value in dataclasses.asdict(contact).items() if key not in skip}
    else:
        data = {key: value for key, value in dataclasses.asdict(contact).items()
                if key not in ("law", "law_keys", "restitution", "stiffness")} | {"law": contact.law, **contact.law_keys}
    if not contact.friction:   # (frictionless: the key left out, as files without friction write it)
        data.pop("friction", None)
    data.pop("point" if contact.point is None else "gap", None)
    return data | {"nodes": contact.nodes[0] if contact.type == "obstacle" else list(contact.nodes)}


def _sources(expressions):
    return [e.source for e in expressions]


def _body_values_data(items):
    """Initial field as plain data: the all-nodes list, or the per-body list of mappings."""
    if len(items) == 1 and items[0].body is None:
        return _sources(items[0].value)
    return [{"body": item.body, "value": _sources(item.value)} for item in items]


# --- YAML -------------------------------------------------------------------------------


class _Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 core-schema booleans, integers and floats (``70e9`` is a number)."""


_TAG = "tag:yaml.org,2002:"
# Copy the resolver table without the YAML 1.1 bool/int/float/timestamp rules so the global
# SafeLoader is untouched and `010` is ten, `on` a string and `1e-3` a float.
_Loader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers
            if tag not in (_TAG + "bool", _TAG + "int", _TAG + "float", _TAG + "timestamp")]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Loader.add_implicit_resolver(_TAG + "bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
                              list("tTfF"))
_Loader.add_implicit_resolver(_TAG + "int", re.compile(r"^[-+]?[0-9]+$"), list("-+0123456789"))
_Loader.add_implicit_resolver(
    _TAG + "float",
    re.compile(r"""^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?
                   |[-+]?\.?(?:inf|Inf|INF)|\.?(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789.iInN"))


def _construct_int(loader, node):
    text = loader.construct_scalar(node)
    try:
        return int(text)
    except ValueError:   # (Python reads integers of at most sys.get_int_max_str_digits() digits)
        raise yaml.constructor.ConstructorError(
            None, None, f"an integer of {len(text.lstrip('+-'))} digits, more than Python reads "
                        f"({sys.get_int_max_str_digits()})", node.start_mark) from None


_Loader.add_constructor(_TAG + "int", _construct_int)


def yaml_value(text: str):
    """One value typed as in a case file (YAML 1.2: ``2.5e3`` is a number); raises yaml.YAMLError.

    The same guards as a case file: no duplicate keys, no deep nesting, no alias bombs.
    """
    try:
        return _parse_yaml(text, "--set")[0]
    except CaseError as exc:
        raise yaml.YAMLError(f"{exc.key}: {exc.message}" if exc.key else exc.message) from None


# A case file is a few hundred values a few levels deep: far beyond these, it is a mistake or an attack.
MAX_DEPTH = 64
MAX_VALUES = 100_000


def _expanded_size(node, memo) -> int:
    """Values a node stands for once its aliases are expanded (an alias counts as often as it is used)."""
    key = id(node)
    if key not in memo:
        memo[key] = 0   # (a recursive alias counts nothing the second time)
        if isinstance(node, yaml.MappingNode):
            memo[key] = 1 + sum(_expanded_size(k, memo) + _expanded_size(v, memo) for k, v in node.value)
        elif isinstance(node, yaml.SequenceNode):
            memo[key] = 1 + sum(_expanded_size(item, memo) for item in node.value)
        else:
            memo[key] = 1
    return memo[key]


def _parse_yaml(text, file):
    """Return (node tree, data) of a YAML document; syntax errors become CaseError with the line."""
    loader = None
    try:
        loader = _Loader(text)
        node = loader.get_single_node()
        lines = {}
        if node is not None:
            _record_lines(node, (), lines, set(), file)  # before construction flattens merge keys
            size = _expanded_size(node, {})
            if size > MAX_VALUES:
                raise CaseError(file, None, None, f"the document stands for {size:.3g} values once its aliases "
                                                  f"(*name) are expanded, more than {MAX_VALUES}")
        return loader.construct_document(node) if node is not None else None, lines
    except RecursionError:
        raise CaseError(file, None, None, f"the YAML is nested too deeply (at most {MAX_DEPTH} levels)") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = " ".join(str(exc.problem or exc.context).split())
        raise CaseError(file, None, mark.line + 1 if mark else None,
                        f"invalid YAML: {problem}") from None
    except yaml.YAMLError as exc:
        raise CaseError(file, None, None, f"invalid YAML: {' '.join(str(exc).split())}") from None
    finally:
        if loader is not None:
            loader.dispose()


def _record_lines(node, path, lines, seen, file, ancestors=frozenset()):
    """Record the line of every mapping key and sequence item under `path`; reject duplicate keys and
    an alias inside its own anchor (a value that would contain itself)."""
    if id(node) in ancestors:
        raise CaseError(file, _dotted(path) or None, node.start_mark.line + 1 if file != "--set" else None,
                        "an alias (*name) inside its own anchor (&name): the value would contain itself")
    if id(node) in seen:  # an alias: its lines were recorded where the anchor is
        return
    seen.add(id(node))
    ancestors = ancestors | {id(node)}
    if len(path) > MAX_DEPTH:
        raise CaseError(file, _dotted(path[:3]) + ".(...)", node.start_mark.line + 1,
                        f"nested more than {MAX_DEPTH} levels deep")
    if isinstance(node, yaml.MappingNode):
        keys = set()
        for key_node, value_node in node.value:
            key = key_node.value if isinstance(key_node, yaml.ScalarNode) else id(key_node)
            line = key_node.start_mark.line + 1
            if key in keys:
                raise CaseError(file, _dotted(path + (key,)), line, "duplicate key")
            keys.add(key)
            lines[path + (key,)] = line
            _record_lines(value_node, path + (key,), lines, seen, file, ancestors)
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            lines[path + (index,)] = item.start_mark.line + 1
            _record_lines(item, path + (index,), lines, seen, file, ancestors)


# --- errors -----------------------------------------------------------------------------


class _Invalid(Exception):
    """A validation failure at a key path, turned into a CaseError once file and lines are known."""

    def __init__(self, path, message):
        super().__init__(path, message)
        self.path, self.message = path, message


def _dotted(path):
    """Key path as text: ``("contacts", 0, "normal")`` -> ``"contacts[0].normal"``."""
    text = ""
    for part in path:
        text += f"[{part}]" if isinstance(part, int) else f".{part}" if text else str(part)
    return text


def _display(path):
    """The case file as shown in messages: relative to the current folder when inside it."""
    relative = os.path.relpath(path)
    return str(path) if relative.startswith("..") else relative


def _error(file, lines, overrides, path, message):
    """CaseError for `path`: its line (or the nearest ancestor's), or the --set option that gave it."""
    for prefix, origin in overrides.items():
        if path[:len(prefix)] == prefix:
            shown = origin if origin.isprintable() else repr(origin)   # (one line: no raw newline)
            shown = shown if len(shown) <= 100 else f"{shown[:80]}... ({len(shown)} characters)"
            return CaseError(file, _dotted(path) or None, None, f"{message} (from {shown})")
    line = next((lines[path[:n]] for n in range(len(path), 0, -1) if path[:n] in lines), None)
    return CaseError(file, _dotted(path) or None, line, message)


# --- overrides --------------------------------------------------------------------------


def _apply_override(data, option):
    """Apply one ``KEY.PATH=VALUE`` option to `data` in place and return the key path."""
    key, equals, text = option.partition("=")
    segments = key.strip().split(".")
    if not equals or not all(segments):
        raise CaseError("--set", None, None, f"expected KEY.PATH=VALUE, got {option!r}")
    try:
        value = yaml_value(text)
    except yaml.YAMLError as exc:
        raise CaseError("--set", key, None, f"cannot read the value {_brief(text)}: "
                        f"{' '.join(str(getattr(exc, 'problem', exc)).split())}") from None
    return _set_key(data, key.strip(), value, "--set")


def _set_key(data, key: str, value, origin: str):
    """Set the dotted ``key`` of `data` (in place) to `value`; returns the key path.

    Missing mappings on the way are created; a list item is named by its index. `origin`
    names the change in errors (``"--set"``, or the change of ``Case.with_changes``).
    """
    segments = key.split(".")
    if not all(segments):
        raise CaseError(origin, None, None, f"expected a dotted key path, got {key!r}")
    target, path = data, ()
    for depth, segment in enumerate(segments, 1):
        if isinstance(target, list):
            if not segment.isdigit() or int(segment) >= len(target):
                raise CaseError(origin, _dotted(path + (segment,)), None,
                                f"no item {segment}: {_dotted(path)} has {len(target)} items")
            segment = int(segment)
        elif not isinstance(target, dict):
            raise CaseError(origin, _dotted(path), None, f"is not a mapping or a list; cannot set {key}")
        path += (segment,)
        if depth == len(segments):
            try:
                target[segment] = _plain(value, path)
            except _Invalid as exc:
                raise CaseError(origin, _dotted(exc.path), None, exc.message) from None
        else:
            if isinstance(target, dict) and target.get(segment) is None:
                target[segment] = {}
            target = target[segment]
    return path


# --- generic validation -----------------------------------------------------------------

_REQUIRED = object()


def _show(value):
    """A value as quoted in a message."""
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return "null" if value is None else _brief(value)


def _brief(value) -> str:
    """A value's repr for a message, shortened; an integer too long to print (or to read) by its magnitude."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 10**30:
        return f"an integer of about {'-' if value < 0 else ''}1e+{round(math.log10(abs(value)))}"
    try:
        text = repr(value)
    except Exception:   # (an object of a script whose repr fails)
        text = f"<{type_name(value)}>"
    return text if len(text) <= 80 else f"{text[:60]}...{text[-10:]} ({len(text)} characters)"


def _plain(value, path):
    """A script's value as the YAML of a case file gives it (a copy): numpy numbers and arrays, tuples, paths
    and other mappings become Python numbers, lists, strings and dicts; anything else is left for the
    validation to refuse. Nested deeper than a case file may be: _Invalid."""
    if len(path) > MAX_DEPTH:
        raise _Invalid(path[:3] + ("(...)",), f"nested more than {MAX_DEPTH} levels deep")
    if value is None or type(value) in (str, bool, int, float):
        return value
    if isinstance(value, Mapping):
        return {str(key) if isinstance(key, str) else key: _plain(item, path + (key,)) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item, path + (index,)) for index, item in enumerate(value)]
    if isinstance(value, (str, os.PathLike)):
        return os.fspath(str(value) if isinstance(value, str) else value)
    if hasattr(value, "dtype") and hasattr(value, "tolist"):   # numpy scalars and arrays
        return _plain(value.tolist(), path)
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(value)
    return value


def _path_argument(call: str, takes: str, value) -> str:
    """A path argument of the API as text; TypeError naming what `call` takes otherwise."""
    try:
        text = os.fspath(value)
    except TypeError:
        text = None
    if not isinstance(text, str):
        raise wrong_type(call, takes, value)
    return text


def _strings(call: str, takes: str, values) -> list[str]:
    """An iterable of strings (not a string itself) as a list; TypeError naming what `call` takes otherwise."""
    if isinstance(values, (str, bytes, Mapping)) or not isinstance(values, typing.Iterable):
        raise wrong_type(call, takes, values)
    values = list(values)
    wrong = next((value for value in values if not isinstance(value, str)), None)
    if wrong is not None:
        raise TypeError(f"{call} takes {takes}, got a {type_name(values if isinstance(values, list) else values)} "
                        f"holding {type_name(wrong)}")
    return values


def _mapping(value, path):
    """A mapping with string keys (null counts as empty)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise _Invalid(path, f"expected a mapping, got {_show(value)}")
    for key in value:
        if not isinstance(key, str):
            raise _Invalid(path, f"keys must be names (strings), got {_brief(key)}")
    return value


def _fields(value, path, spec, section=None):
    """Validate a mapping against `spec` and return the converted values.

    Parameters
    ----------
    value : object
        The mapping from the case file.
    path : tuple
        Its key path.
    spec : dict
        ``key -> (converter, default)``, or ``key -> converter`` when the default is the
        `section` dataclass's own (the one place it is written); a converter is
        ``(value, path) -> result`` raising _Invalid; default ``_REQUIRED`` makes the key
        mandatory. An explicit null on an optional key means its default (so a resolved
        dump reads back).
    section : dataclass, optional
        The section the values are for: the defaults of the keys given without one.
    """
    if section is not None:
        own = {f.name: f.default if f.default is not dataclasses.MISSING else f.default_factory()
               for f in dataclasses.fields(section)
               if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING}
        spec = {key: entry if isinstance(entry, tuple) else (entry, own[key]) for key, entry in spec.items()}
    data = _mapping(value, path)
    for key in data:
        if key not in spec:
            close = difflib.get_close_matches(key, list(spec), n=1)
            hint = f"did you mean '{close[0]}'?" if close else f"valid keys: {', '.join(spec)}"
            raise _Invalid(path + (key,), f"unknown key '{key}'; {hint}")
    result = {}
    for key, (convert, default) in spec.items():
        if key in data and (data[key] is not None or default is _REQUIRED):
            result[key] = convert(data[key], path + (key,))
        elif default is _REQUIRED:
            raise _Invalid(path + (key,), "missing required key")
        else:
            result[key] = default
    return result


def _number(value, path):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _Invalid(path, f"expected a number, got {_show(value)}")
    try:
        number = float(value)
    except OverflowError:
        raise _Invalid(path, f"expected a finite number, got {_brief(value)}, beyond the largest float "
                             f"({sys.float_info.max:.3g})") from None
    if not math.isfinite(number):
        raise _Invalid(path, f"expected a finite number, got {value}")
    return number


_BOUNDS = {"gt": (operator.gt, ">", "("), "ge": (operator.ge, ">=", "["),
           "lt": (operator.lt, "<", ")"), "le": (operator.le, "<=", "]")}


def _range_text(bounds) -> str:
    """``{"gt": 0, "lt": 1}`` -> ``"in (0, 1)"``; ``{"ge": 0}`` -> ``">= 0"``."""
    if len(bounds) == 2:
        (low, a), (high, b) = bounds.items()
        return f"in {_BOUNDS[low][2]}{a:g}, {b:g}{_BOUNDS[high][2]}"
    return " ".join(f"{_BOUNDS[name][1]} {bound:g}" for name, bound in bounds.items())


def _real(**bounds):
    """Converter for a finite number within `bounds` (keywords gt, ge, lt, le)."""
    text = _range_text(bounds)

    def convert(value, path):
        number = _number(value, path)
        if not all(_BOUNDS[name][0](number, bound) for name, bound in bounds.items()):
            raise _Invalid(path, f"must be {text}, got {_brief(value)}")
        return number
    return convert


def _integer(low, high=None):
    """Converter for an integer in [low, high]; integral floats such as ``1e3`` are accepted."""
    def convert(value, path):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            raise _Invalid(path, f"expected an integer, got {_show(value)}")
        if value < low or (high is not None and value > high):
            wanted = f">= {low}" if high is None else f"in [{low}, {high}]"
            raise _Invalid(path, f"must be {wanted}, got {_brief(value)}")
        return value
    return convert


def _string(value, path):
    if not isinstance(value, str) or not value:
        raise _Invalid(path, f"expected a non-empty string, got {_show(value)}")
    return value


def _csv_name(value, path):
    """A name used as a column prefix in history.csv."""
    if not isinstance(value, str) or not _CSV_NAME.fullmatch(value):
        raise _Invalid(path, f"expected a name of letters, digits, '_' and '-', got {_show(value)}")
    return value


def _boolean(value, path):
    if not isinstance(value, bool):
        raise _Invalid(path, f"expected true or false, got {_show(value)}")
    return value


def _choice(*options):
    def convert(value, path):
        if not isinstance(value, str) or value not in options:
            raise _Invalid(path, f"must be one of {', '.join(options)}; got {_show(value)}")
        return value
    return convert


def _list(item):
    """Converter for a list of items converted with `item`."""
    def convert(value, path):
        if not isinstance(value, list):
            raise _Invalid(path, f"expected a list, got {_show(value)}")
        return [item(entry, path + (index,)) for index, entry in enumerate(value)]
    return convert


def _vector(item):
    """Converter for a list of 1 to 3 components."""
    def convert(value, path):
        if not isinstance(value, list):
            raise _Invalid(path, f"expected a list of 1 to 3 components, got {_show(value)}")
        if not 1 <= len(value) <= 3:
            raise _Invalid(path, f"must have 1 to 3 components, got {len(value)}")
        return [item(entry, path + (index,)) for index, entry in enumerate(value)]
    return convert


def _mapping_of(item, key=_string):
    """Converter for a mapping of names (checked with `key`) to items."""
    def convert(value, path):
        return {key(name, path + (name,)): item(entry, path + (name,))
                for name, entry in _mapping(value, path).items()}
    return convert


def _expression(allowed, parameters):
    """Converter for an expression in the variables `allowed` and the case's `parameters`."""
    def convert(value, path):
        if not isinstance(value, str):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise _Invalid(path, f"expected a number or an arithmetic expression, got {_show(value)}")
            _number(value, path)   # (an integer beyond the floats: refused here, with its key)
        try:
            return parse_expression(value, allowed, parameters)
        except ExpressionError as exc:
            raise _Invalid(path, str(exc)) from None
    return convert


# --- sections ---------------------------------------------------------------------------


def _case_name(value, path):
    name = _string(value, path)
    if name in (".", "..") or any(c in name for c in "/\\\0"):
        raise _Invalid(path, f"must be usable as a folder name, got {_brief(name)}")
    return name


def _mesh(value, path, folder):
    f = _fields(value, path, {
        "shape": _choice(*SHAPES), "file": _string, "dim": _integer(1, 3),
        "length": _real(gt=0), "cells": _integer(1, 2**31 - 1),   # (PETSc's 32-bit indices)
        "height": _real(gt=0), "width": _real(gt=0), "elements": _choice(*BAR_ELEMENTS),
        "hypothesis": _choice(*HYPOTHESES), "axis": _choice("x", "y")}, MeshSpec)
    if f["shape"] is None and f["file"] is None:
        raise _Invalid(path, f"give 'shape' (a built-in shape: {', '.join(SHAPES)}) or 'file' (a Gmsh file)")
    if f["shape"] is not None and f["file"] is not None:
        raise _Invalid(path, f"give either 'shape' ({', '.join(SHAPES)}) or 'file', not both")
    for key, dims in (("height", (2, 3)), ("width", (3,))):
        if f[key] is not None and (f["file"] is not None or (f["dim"] or 1) not in dims):
            where = "a mesh file" if f["file"] is not None else f"{f['dim'] or 1}D"
            raise _Invalid(path + (key,), f"applies to the built-in bar in {' and '.join(f'{d}D' for d in dims)} "
                                          f"only; it has no effect in {where}: remove it")
    if f["hypothesis"] != "plane_stress" and f["file"] is None and (f["dim"] or 1) != 2:
        raise _Invalid(path + ("hypothesis",), f"applies to 2D models only (this bar is {f['dim'] or 1}D): remove it")
    if f["axis"] is not None and f["hypothesis"] != "axisymmetric":
        raise _Invalid(path + ("axis",), "applies to hypothesis: axisymmetric only (the symmetry axis): remove it")
    if f["hypothesis"] == "axisymmetric" and f["axis"] is None:
        f["axis"] = "y"
    if f["file"] is not None:
        f["file"] = Path(os.path.abspath(folder / f["file"]))
        if not f["file"].is_file():
            raise _Invalid(path + ("file",), f"mesh file not found: {f['file']}")
    elif f["dim"] is None:
        f["dim"] = 1
    return MeshSpec(**f)


def _material(value, path):
    return Material(**_fields(value, path, {
        "E": (_real(gt=0), _REQUIRED), "rho": (_real(gt=0), _REQUIRED),
        "nu": _real(ge=0, lt=0.5), "area": _real(gt=0)}, Material))


def _damping(value, path):
    return Damping(**_fields(value, path, {"alpha": _real(ge=0), "beta": _real(ge=0)}, Damping))


def _body_values(value, path, parameters):
    """An initial field: a list of component expressions, or a list of {body, value} mappings."""
    expressions = _vector(_expression(SPACE, parameters))
    if isinstance(value, list) and all(isinstance(entry, dict) for entry in value):
        spec = {"body": (_string, _REQUIRED), "value": (expressions, _REQUIRED)}
        return [BodyValue(**_fields(entry, path + (index,), spec)) for index, entry in enumerate(value)]
    return [BodyValue(None, expressions(value, path))]


def _initial(value, path, parameters, folder):
    field_ = lambda v, p: _body_values(v, p, parameters)  # noqa: E731
    f = _fields(value, path, {"displacement": (field_, []), "velocity": (field_, []), "from": (_string, None)})
    source = f.pop("from")
    if source is not None:
        if f["displacement"] or f["velocity"]:
            raise _Invalid(path + ("from",), "starts from a saved state: give either 'from' or the initial fields, "
                                             "not both")
        source = Path(os.path.abspath(folder / source))   # (read when the run starts: fem_impact/app/checkpoint.py)
    return Initial(**f, source=source)


def _fix(value, path):
    """Fixed components: 'all' or a list of x, y, z -> sorted component indices."""
    if value == "all":
        return [0, 1, 2]
    names = [value] if isinstance(value, str) else value
    if not isinstance(names, list) or not names:
        raise _Invalid(path, f"expected 'all' or a list of x, y, z; got {_show(value)}")
    for index, name in enumerate(names):
        if name not in COMPONENTS:
            raise _Invalid(path + (index,) if isinstance(value, list) else path,
                           f"unknown component {_show(name)}; expected 'all' or a list of x, y, z")
    return sorted({COMPONENTS.index(n) for n in names})


def _support(value, path, parameters):
    f = _fields(value, path, {"nodes": (_string, _REQUIRED), "fix": (_fix, "all"),
                              "displacement": (_vector(_expression(TIME, parameters)), None)})
    fixed = value.get("fix", "all") if isinstance(value, dict) else "all"
    motion = f["displacement"]
    if motion is not None and fixed not in ("all", None):
        names = [fixed] if isinstance(fixed, str) else fixed
        if len(motion) != len(names):
            raise _Invalid(path + ("displacement",), f"gives {len(motion)} expressions for the {len(names)} fixed "
                                                     f"component(s) {', '.join(names)}: give one per component, "
                                                     "in the order of 'fix'")
        # (fix is stored sorted: x, y, z) the expressions follow it
        order = {COMPONENTS.index(n): expr for n, expr in zip(names, motion)}
        f["displacement"] = [order[c] for c in sorted(order)]
    return Support(**f, all_components=fixed in ("all", None))


def _load(value, path, parameters):
    f = _fields(value, path, {
        "nodes": (_string, None), "body": (_string, None),
        "force": (_vector(_expression(TIME, parameters)), None),
        "acceleration": (_vector(_expression(TIME, parameters)), None)})
    if (f["nodes"] is None) == (f["body"] is None):
        raise _Invalid(path, "give either 'nodes' (with 'force') or 'body' (with 'acceleration')")
    on, wanted, other = (("nodes", "force", "acceleration") if f["nodes"] is not None
                         else ("body", "acceleration", "force"))
    if f[other] is not None:
        raise _Invalid(path + (other,), f"not allowed with '{on}' (use '{wanted}')")
    if f[wanted] is None:
        raise _Invalid(path + (wanted,), f"missing required key (a load on '{on}' needs '{wanted}')")
    return Load(**f)


def _contact(value, path):
    law = _mapping(value, path).get("law")
    if law is not None and law not in BUILT_IN_LAWS:
        return _registered_law_contact(value, path)
    f = _fields(value, path, {
        "name": (_csv_name, _REQUIRED), "type": (_choice(*CONTACT_TYPES), _REQUIRED),
        "nodes": (lambda nodes, _: nodes, _REQUIRED), "normal": (_vector(_number), _REQUIRED),
        "gap": _real(), "restitution": _real(ge=0, le=1),
        "coupling": _choice(*CONTACT_COUPLINGS), "stiffness": _real(gt=0),
        "law": _choice(*BUILT_IN_LAWS), "friction": _real(ge=0), "point": _vector(_number)}, Contact)
    f = _contact_relation(f, value, path)
    inferred = "elastic_stop" if f["stiffness"] is not None else "newton"
    if value.get("law") is not None and f["law"] != inferred:
        needs = "a stiffness" if f["law"] == "elastic_stop" else "no stiffness"
        raise _Invalid(path + ("law",), f"law {f['law']} takes {needs}; got law {f['law']} with keys "
                                        f"{', '.join(str(k) for k in value)}")
    f["law"] = inferred
    f["law_keys"] = {"stiffness": f["stiffness"]} if f["stiffness"] is not None else {"restitution": f["restitution"]}
    if f["stiffness"] is not None and value.get("restitution") is not None:
        # Its spring stores the approach and gives it back: no impact law, so no restitution.
        keys = ", ".join(key for key in CONTACT_KEYS if key != "restitution")
        raise _Invalid(path + ("restitution",), f"an elastic stop (stiffness given) does not use 'restitution': "
                                                f"its spring gives back what it stores; keys of an elastic stop: "
                                                f"{keys} (or remove stiffness for a rigid contact)")
    if f["friction"] is None:
        f["friction"] = 0.0
    return Contact(**f)


def _registered_law_contact(value, path):
    """A contact whose ``law`` is one registered beyond the built-in ones: its keys are the law's."""
    from pydantic import ValidationError

    from ..nonsmooth.laws import LAWS

    name = value["law"]
    if not isinstance(name, str) or name not in LAWS:
        raise _Invalid(path + ("law",), f"must be one of {', '.join(LAWS)}; got {_show(name)}")
    law = LAWS[name]
    relation = ("name", "type", "nodes", "normal", "gap", "coupling", "law", "friction", "point")
    f = _fields({k: v for k, v in value.items() if k in relation}, path, {
        "name": (_csv_name, _REQUIRED), "type": (_choice(*CONTACT_TYPES), _REQUIRED),
        "nodes": (lambda nodes, _: nodes, _REQUIRED), "normal": (_vector(_number), _REQUIRED),
        "gap": _real(), "coupling": _choice(*CONTACT_COUPLINGS), "law": _string,
        "friction": _real(ge=0), "point": _vector(_number)}, Contact)
    f = _contact_relation(f, value, path)
    given = {k: v for k, v in value.items() if k not in relation}
    try:
        f["law_keys"] = law.keys.model_validate(given).model_dump()
    except ValidationError as exc:
        error = exc.errors()[0]
        key = error["loc"][0] if error["loc"] else None
        if error["type"] == "extra_forbidden":
            keys = ", ".join([*relation, *law.keys.model_fields])
            raise _Invalid(path + (key,), f"contact law {name} does not use '{key}'; keys of a contact with "
                                          f"law {name}: {keys}") from None
        raise _Invalid(path + ((key,) if key else ()), error["msg"]) from None
    return Contact(**{k: v for k, v in f.items() if k in ("name", "type", "nodes", "normal", "gap", "coupling",
                                                          "law", "law_keys", "point")
                      or (k == "friction" and v is not None)})


def _contact_relation(f: dict, value, path) -> dict:
    """The relation's keys of a contact: node groups per type, the gap of an obstacle, a unit normal."""
    nodes = [f["nodes"]] if isinstance(f["nodes"], str) else f["nodes"]
    if f.get("point") is not None:
        if f["type"] != "obstacle":
            raise _Invalid(path + ("point",), "a point of the obstacle's plane is for an obstacle contact "
                                              "(a pair's gaps are its nodes' distances)")
        if f["gap"] is not None:
            raise _Invalid(path + ("point",), "give either gap (one for every node) or point (each node's gap "
                                              "its own distance to the plane through it), not both")
    if f["type"] == "obstacle":
        if not (isinstance(nodes, list) and len(nodes) == 1):
            raise _Invalid(path + ("nodes",), f"an obstacle contact takes one node group, "
                                              f"got {_show(f['nodes'])}")
        if f.get("point") is None:
            f["gap"] = 0.0 if f["gap"] is None else f["gap"]
    elif not (isinstance(nodes, list) and len(nodes) == 2):
        raise _Invalid(path + ("nodes",), f"a pair contact takes a list of two node groups, "
                                          f"got {_show(f['nodes'])}")
    f["nodes"] = [_string(group, path + ("nodes", i)) for i, group in enumerate(nodes)]
    if len(set(f["nodes"])) != len(f["nodes"]):
        raise _Invalid(path + ("nodes",), "the two node groups must differ")
    length = math.hypot(*f["normal"])
    if length == 0.0:
        raise _Invalid(path + ("normal",), "must have a nonzero length")
    f["normal"] = [component / length for component in f["normal"]]
    return f


CONTACT_KEYS = ("name", "type", "nodes", "normal", "gap", "restitution", "coupling", "stiffness", "law", "friction",
                "point")
BUILT_IN_LAWS = ("newton", "elastic_stop")   # (their keys are the contact's own, as before laws were named)


def _contacts(value, path):
    contacts = _list(_contact)(value, path)
    names = [contact.name for contact in contacts]
    for index, name in enumerate(names):
        if name in names[:index]:
            raise _Invalid(path + (index, "name"), f"duplicate contact name '{name}'")
    return contacts


def _solver(value, path):
    """The solver section, validated by the schema of its method (fem_impact.integrators.parameters)."""
    # (an explicit null means the default, as everywhere in a case file)
    data = {key: entry for key, entry in _mapping(value, path).items() if entry is not None}
    method, scheme = data.get("method", DEFAULT_METHOD), data.get("scheme", MODAL_SCHEMES[0])
    if not isinstance(method, str) or method not in METHODS:
        raise _Invalid(path + ("method",), f"must be one of {', '.join(METHODS)}; got {_show(data['method'])}")
    if method == REDUCED and (not isinstance(scheme, str) or scheme not in MODAL_SCHEMES):
        raise _Invalid(path + ("scheme",), f"must be one of {', '.join(MODAL_SCHEMES)}; got {_show(data['scheme'])}")
    schema = SCHEMAS[_schema_tag(data)]
    try:
        return solver_schema().validate_python(data)
    except ValidationError as exc:
        # A misspelt key first: the required key it leaves missing is its consequence, not the cause.
        errors = exc.errors()
        raise _from_pydantic(next((e for e in errors if e["type"] == "extra_forbidden"), errors[0]), path,
                             schema) from None


def _method_name(schema) -> str:
    """How messages name a schema's method: ``newmark``, or ``modal (scheme newmark)``."""
    name = next(tag for tag, s in SCHEMAS.items() if s is schema)
    method, _, scheme = name.partition("/")
    return f"{method} (scheme {scheme})" if scheme else method


def _owners(takes) -> list[str]:
    """The methods whose schema `takes`: ``modal`` when all its schemes do, else ``modal (scheme X)``."""
    owners = []
    for method in METHODS:
        schemas = [schema for tag, schema in SCHEMAS.items() if tag.partition("/")[0] == method]
        taking = [schema for schema in schemas if takes(schema)]
        if taking == schemas:
            owners.append(method)
        else:
            owners += [_method_name(schema) for schema in taking]
    return owners


def _from_pydantic(error: dict, path: tuple, schema) -> _Invalid:
    """A pydantic error as the case file reports it: the key path, and the project's own words."""
    loc = tuple(part for part in error["loc"] if part not in SCHEMAS)   # (the union's tag is not a key)
    kind, given, ctx = error["type"], error.get("input"), error.get("ctx") or {}
    if isinstance(ctx.get("error"), KeyProblem):
        return _Invalid(path + loc + (ctx["error"].key,), str(ctx["error"]))
    key = loc[-1] if loc else None
    field_info = schema.model_fields.get(key) if isinstance(key, str) else None
    if kind == "extra_forbidden":
        valid = valid_keys(schema)
        owners = _owners(lambda other: key in other.model_fields)
        if owners:
            return _Invalid(path + loc, f"method {_method_name(schema)} does not use '{key}' (a key of "
                                        f"{', '.join(owners)}); its keys: {', '.join(valid)}")
        close = difflib.get_close_matches(str(key), valid, n=1)
        hint = f"did you mean '{close[0]}'? (" if close else "("
        return _Invalid(path + loc, f"unknown key '{key}'; {hint}keys of method {_method_name(schema)}: "
                                    f"{', '.join(valid)})")
    if kind == "missing":
        return _Invalid(path + loc, "missing required key")
    if kind in ("float_type", "float_parsing", "int_type", "int_parsing"):
        return _Invalid(path + loc, f"expected a number, got {_show(given)}")
    if kind == "bool_type":
        return _Invalid(path + loc, f"expected true or false, got {_show(given)}")
    if kind == "finite_number":
        return _Invalid(path + loc, f"expected a finite number, got {_brief(given)}")
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal") and field_info:
        bounds = {name: getattr(item, name) for item in field_info.metadata for name in _BOUNDS
                  if getattr(item, name, None) is not None}
        return _Invalid(path + loc, f"must be {_range_text(bounds)}, got {_brief(given)}")
    if kind == "literal_error" and field_info:
        options = typing.get_args(field_info.annotation)
        owners = _owners(lambda other: key in other.model_fields
                         and given in typing.get_args(other.model_fields[key].annotation))
        where = f" (a value for method {', '.join(owners)})" if owners else ""
        return _Invalid(path + loc, f"must be one of {', '.join(options)} with method {_method_name(schema)}; "
                                    f"got {_show(given)}{where}")
    if kind == "value_error":
        return _Invalid(path + loc, str(ctx.get("error", error["msg"])))
    return _Invalid(path + loc, error["msg"])


def _solver_tag(data):
    solver = data.get("solver") if isinstance(data, dict) else None
    return _schema_tag(solver) if isinstance(solver, dict) else None


def _follow_kind_changes(data, before: str | None, changed) -> None:
    """A change of kind drops the file's keys that the new kind does not take.

    A change of solver.method (or scheme) drops the previous method's keys; a change that makes a
    contact an elastic stop (its stiffness) drops its restitution. They belonged to what the file
    chose; keys the changes themselves give are kept (and checked as usual).
    """
    for path in changed:
        if len(path) == 3 and path[0] == "contacts" and path[2] == "stiffness" \
                and ("contacts", path[1], "restitution") not in changed:
            contact = data["contacts"][path[1]]
            if isinstance(contact, dict) and contact.get("stiffness") is not None:
                contact.pop("restitution", None)
    solver = data.get("solver") if isinstance(data, dict) else None
    if not isinstance(solver, dict) or _schema_tag(solver) == before or _schema_tag(solver) not in SCHEMAS:
        return
    schema = SCHEMAS[_schema_tag(solver)]
    dropped = [key for key in list(solver) if key not in schema.model_fields and ("solver", key) not in changed]
    for key in dropped:
        del solver[key]
    if dropped:
        log.info("solver.method %s: dropped %s (keys of the previous method)", _method_name(schema),
                 ", ".join(dropped))


def _output(value, path):
    return Output(**_fields(value, path, {
        "every": _integer(1), "probes": _mapping_of(_vector(_number), _csv_name), "vtk": _boolean,
        "format": _choice("vtu", "xdmf"), "checkpoint_every": _integer(0)}, Output))


def _parameters(value, path):
    """Named numbers for the expressions: identifiers that shadow no variable, constant or function."""
    parameters = {}
    for name, number in _mapping(value, path).items():
        if not name.isidentifier() or keyword.iskeyword(name):
            raise _Invalid(path + (name,), f"a parameter name must be an identifier (letters, digits and '_', "
                                           f"not starting with a digit), got {_brief(name)}")
        if name in RESERVED:
            raise _Invalid(path + (name,), f"'{name}' is reserved (the names {', '.join(RESERVED)} have a meaning "
                                           "in expressions); choose another name")
        parameters[name] = _number(number, path + (name,))
    return parameters


def _reference(value, path):
    """The name of a known exact solution; the solutions live in fem_impact.config.references."""
    from .references import REFERENCES  # (numpy: loaded only when a case names a reference)

    if not isinstance(value, str) or value not in REFERENCES:
        raise _Invalid(path, f"unknown reference {_show(value)}; known references: "
                             + ", ".join(f"{name} ({REFERENCES[name].title})" for name in REFERENCES))
    return value


def _case(data, folder: Path, default_name: str):
    """Validate the whole case mapping (lines and overrides are added by the caller)."""
    # The parameters first: every expression of the other sections may use them.
    parameters = _parameters(data.get("parameters"), ("parameters",)) if isinstance(data, dict) else {}
    f = _fields(data, (), {
        "name": (_case_name, default_name),
        "mesh": (lambda value, path: _mesh(value, path, folder), _REQUIRED),
        "material": (_material, None), "materials": (_mapping_of(_material), None),
        "damping": (_damping, Damping()),
        "initial": (lambda value, path: _initial(value, path, parameters, folder), Initial()),
        "supports": (_list(lambda value, path: _support(value, path, parameters)), []),
        "loads": (_list(lambda value, path: _load(value, path, parameters)), []),
        "contacts": (_contacts, []), "solver": (_solver, _REQUIRED), "output": (_output, Output()),
        "parameters": (lambda value, path: parameters, {}), "reference": (_reference, None)})
    if f["material"] is None and f["materials"] is None:
        raise _Invalid(("material",), "missing required key: give 'material' (for every body) or 'materials' "
                                      "(per body)")
    if f["material"] is not None and f["materials"] is not None:
        raise _Invalid(("material",), "give either 'material' (for every body) or 'materials' (per body), not both")
    if f["materials"] == {}:
        raise _Invalid(("materials",), "must give at least one body")
    return Case(path=None, **f)


def load_case(path, overrides=()) -> Case:
    """Load, override and validate a case file.

    Parameters
    ----------
    path : path-like
        The case file (YAML).
    overrides : iterable of str
        ``KEY.PATH=VALUE`` options from ``--set``; VALUE is read as YAML.

    Returns
    -------
    Case

    Raises
    ------
    CaseError
        On any bad input, naming the file, key and line.
    TypeError
        When `path` is not a path or `overrides` not a list of strings.
    """
    path = _path_argument("load_case()", "a path (str or os.PathLike)", path)
    overrides = _strings("load_case()", "overrides as a list of 'KEY.PATH=VALUE' strings", overrides)
    case_path = Path(os.path.abspath(path))
    file = _display(case_path)
    try:
        text = case_path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CaseError(file, None, None, "case file not found") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:   # (ValueError: a NUL character in the path)
        raise CaseError(file, None, None, f"cannot read the case file: {exc}") from None
    data, lines = _parse_yaml(text, file)
    if not isinstance(data, dict):
        raise CaseError(file, None, None, "the file is empty" if data is None
                        else "expected a mapping of keys at the top level")
    if overrides and isinstance(data.get("reference"), str):
        # The file's reference must fit the file's case: the overrides may take the case out of it, not excuse it.
        try:
            _validated(_plain(data, ()), case_path, case_path.parent, lines, {}, {})
        except CaseError as err:
            if err.key == "reference":
                raise
    before = _solver_tag(data)
    options = {_apply_override(data, option): f"--set {option}" for option in overrides}
    _follow_kind_changes(data, before, options)
    return _validated(data, case_path, case_path.parent, lines, options, options)


def _validated(data: dict, case_path: Path | None, folder: Path, lines, overrides: dict, changed: dict) -> Case:
    """Validate `data` into a Case; `overrides` maps changed key paths to their origin (for messages),
    `changed` those of this very call (a parameter they set must be used)."""
    file = None if case_path is None else _display(case_path)
    try:
        source = _plain(data, ())
        case = _case(data, folder, case_path.stem if case_path is not None else "case")
    except _Invalid as exc:
        raise _error(file, lines or {}, overrides, exc.path, exc.message) from None
    case.path, case.base_dir, case.source = case_path, folder, source
    case.lines, case.overrides = dict(lines or {}), dict(overrides)
    from .numbers import check_numbers   # (it reads the case's sections: imported once they exist)

    check_numbers(case)
    _check_section(case)
    _check_friction(case)
    _check_moving_supports(case)
    _check_set_parameters(case, changed)
    _check_reference(case, changed)
    return case


def _check_reference(case: Case, changed) -> None:
    """A declared exact solution must fit the case (fem_impact.references: what the studies measure against).

    Where the case is written (a file, a dict, or a change of ``reference`` itself) a reference that does not
    fit is bad input. Changes of other keys may take the case out of its reference (a benchmark used as a
    template: ``--set loads=...``): the reference is then left behind, as a change of method leaves the
    previous method's keys: the run and its resolved dump have none, and ``references.from_case`` still says
    why the case does not fit it (the studies refuse to measure against it).
    """
    if case.reference is None:
        return
    from .references import from_case

    try:
        from_case(case)
    except CaseError as misfit:
        if not changed or ("reference",) in changed:
            raise
        log.info("%s: the changes took the case out of its reference, which is left behind", misfit)
        case.reference = None


def _check_section(case: Case) -> None:
    """An axisymmetric model's section is the circle, 2 pi r: a given ``area`` would be ignored (a null
    one is not given, as everywhere in a case file: ``--set material.area=null`` takes it out)."""
    if case.mesh.hypothesis != "axisymmetric":
        return
    source = case.source if isinstance(case.source, dict) else {}
    material = source.get("material")
    where = [("material", "area")] if isinstance(material, dict) and material.get("area") is not None else []
    materials = source.get("materials")
    for body, values in (materials.items() if isinstance(materials, dict) else ()):
        if isinstance(values, dict) and values.get("area") is not None:
            where.append(("materials", body, "area"))
    if where:
        raise case.error(where[0], "an axisymmetric model's section is the whole circle, 2 pi r (forces are totals "
                                   f"over it): remove area (or give it null: --set {_dotted(where[0])}=null)")


def _check_friction(case: Case) -> None:
    """Friction needs a method that solves the cone problem (Moreau-Jean on the full model)."""
    from ..integrators import integrator_class, is_reduced, scheme_of

    for i, contact in enumerate(case.contacts):
        if not contact.friction:
            continue
        if is_reduced(case.solver) and case.solver.static_correction:
            raise case.error(("contacts", i, "friction"), "friction is not available with the reduced model's static "
                                                          "correction yet: use solver.static_correction: false (modes "
                                                          "alone) or solver.method: moreau_jean")
        if not getattr(integrator_class(scheme_of(case.solver)), "takes_friction", False):
            # (the reduced model's time scheme is the cause: the model itself takes friction)
            key, use = (("solver.scheme", "solver.scheme: moreau_jean") if is_reduced(case.solver) else
                        ("solver.method", "solver.method: moreau_jean"))
            raise case.error(("contacts", i, "friction"),
                             f"{key} {scheme_of(case.solver)} cannot take friction (its contact step is an "
                             f"LCP on normal forces only): use {use}")


def _check_moving_supports(case: Case) -> None:
    """The reduced model holds a support's quasi-static motion in its static correction: the
    fixed-base modes alone carry only the share their mass takes part in (docs/theory.md s. 2.4)."""
    from ..integrators import is_reduced

    if not is_reduced(case.solver) or case.solver.static_correction:
        return
    for i, support in enumerate(case.supports):
        if any(not (f.is_constant and f.at_time(0.0) == 0.0) for f in support.displacement or ()):
            raise case.error(("solver", "static_correction"),
                             f"supports[{i}] moves (displacement), and the reduced model holds a support's motion "
                             "in its static correction (the fixed-base modes alone leave most of it out): set "
                             "solver.static_correction: true, or use the full model (solver.method: moreau_jean)")


def _check_set_parameters(case: Case, changed) -> None:
    """A parameter set with --set (or a change) that no expression uses is a typo, not a silent no-op."""
    used = set()
    for _, expr in case.expressions():
        used |= expr.constants
    for path in changed:
        names = [path[1]] if len(path) == 2 and path[0] == "parameters" else (
            sorted(case.parameters) if path == ("parameters",) else [])
        for name in names:
            if name in case.parameters and name not in used:
                known = ", ".join(sorted(used)) or "none"
                raise case.error(("parameters", name), f"no expression of the case uses parameter '{name}' "
                                                       f"(used: {known})")
