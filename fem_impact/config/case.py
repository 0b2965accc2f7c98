"""A case: loaded from its file (fem_impact.config.loader), validated by the schema of every section
(fem_impact.config.schema) and the checks across them (fem_impact.config.checks), changed by ``--set``
or :meth:`Case.with_changes`, and dumped back with every default filled in."""

from __future__ import annotations

import contextlib
import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ..errors import CaseError, ModelInputError, OutputFolderError, type_name, wrong_type
from ..fem.specs import BodyValue, Damping, Initial, Load, Material, MeshSpec, Support  # noqa: F401  (re-exported)
from ..integrators.parameters import SolverParameters
from ..nonsmooth.specs import Contact
from .checks import check_case
from .loader import (_apply_override, _brief, _display, _dotted, _error, _Invalid, _parse_yaml, _path_argument,
                     _plain, _set_key, _strings, yaml_value)
from .schema import COMPONENTS, OutputSection, validate_case
from .solver import follow_kind_changes, solver_tag

__all__ = ["Case", "CaseError", "Output", "load_case", "yaml_value"]


Output = OutputSection   # the output section as validated (its keys: fem_impact.config.schema)


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
    reference: str | None = None   # name of a known exact solution (fem_impact.references)
    bodies: dict[str, str] = field(default_factory=dict)   # per body named in the case: elastic, rigid or modal
    body_modes: dict[str, int] = field(default_factory=dict)   # per modal body: its kept modes
    body_blocks: dict[str, bool | str] = field(default_factory=dict)   # per modal body that sets it: blocks
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
        before = solver_tag(data)
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
        follow_kind_changes(data, before, origins)
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
            data["material"] = _material_data(self.material, self.mesh.hypothesis)
        else:
            data["materials"] = {body: _material_data(m, self.mesh.hypothesis) for body, m in self.materials.items()}
        data["damping"] = dataclasses.asdict(self.damping)
        data["initial"] = ({"from": str(self.initial.source)} if self.initial.source is not None else
                           {"displacement": _body_values_data(self.initial.displacement),
                            "velocity": _body_values_data(self.initial.velocity)})
        data["supports"] = [{"nodes": s.nodes, "fix": "all" if s.all_components else [COMPONENTS[i] for i in s.fix],
                             **({} if s.displacement is None else {"displacement": _sources(s.displacement)})}
                            for s in self.supports]
        data["loads"] = [{key: _sources(value) if key in ("force", "acceleration", "traction") else value
                          for key, value in vars(load).items() if value is not None}
                         for load in self.loads]
        data["contacts"] = [_contact_data(c) for c in self.contacts]
        if self.bodies:
            data["bodies"] = {name: {"model": model, **({"modes": self.body_modes[name]} if model == "modal" else {}),
                                     **({"blocks": self.body_blocks[name]} if name in self.body_blocks else {})}
                              for name, model in self.bodies.items()}
        data["solver"] = self.solver.as_case()
        data["output"] = self.output.model_dump()
        return data

    def expressions(self):
        """Every expression of the case as (key path, Expression): initial fields, supports' motions, loads
        and obstacles' motions."""
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
            for name in ("force", "traction", "acceleration"):
                for comp, expr in enumerate(getattr(load, name) or ()):
                    yield ("loads", i, name, comp), expr
        for i, contact in enumerate(self.contacts):
            for comp, expr in enumerate(contact.motion or ()):
                yield ("contacts", i, "motion", comp), expr

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


def _material_data(material, hypothesis: str) -> dict:
    """A material as the case file gives it: an axisymmetric model takes no area (its section is the circle)."""
    data = dataclasses.asdict(material)
    if hypothesis == "axisymmetric":
        del data["area"]
    return data


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
    if contact.motion is None:
        data.pop("motion", None)
    else:
        data["motion"] = _sources(contact.motion)
    for name in ("surface",) + (("normal", "gap") if contact.type == "surface" else ()):
        if data.get(name, 0) is None:   # (a surface contact has no normal or gap, the others no surface)
            del data[name]
    return data | {"nodes": contact.nodes[0] if contact.type in ("obstacle", "surface") else list(contact.nodes)}


def _sources(expressions):
    return [e.source for e in expressions]


def _body_values_data(items):
    """Initial field as plain data: the all-nodes list, or the per-body list of mappings."""
    if len(items) == 1 and items[0].body is None:
        return _sources(items[0].value)
    return [{"body": item.body, "value": _sources(item.value)} for item in items]


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
    before = solver_tag(data)
    options = {_apply_override(data, option): f"--set {option}" for option in overrides}
    follow_kind_changes(data, before, options)
    return _validated(data, case_path, case_path.parent, lines, options, options)


def _validated(data: dict, case_path: Path | None, folder: Path, lines, overrides: dict, changed: dict) -> Case:
    """Validate `data` into a Case; `overrides` maps changed key paths to their origin (for messages),
    `changed` those of this very call (a parameter they set must be used)."""
    file = None if case_path is None else _display(case_path)
    try:
        source = _plain(data, ())
        sections = validate_case(data, folder)
    except _Invalid as exc:
        raise _error(file, lines or {}, overrides, exc.path, exc.message) from None
    name = sections.pop("name") or (case_path.stem if case_path is not None else "case")
    output = sections.pop("output") or Output()
    case = Case(name=name, path=case_path, **sections, output=output)
    case.base_dir, case.source = folder, source
    case.lines, case.overrides = dict(lines or {}), dict(overrides)
    check_case(case, changed)
    return case
