"""The case file's schema: one pydantic model per section, whose fields carry the keys' defaults, units,
ranges and meaning. ``SECTIONS`` maps each section to its model (the items' models for the lists of
supports, loads and contacts); the documentation's case reference is generated from them.

Validating gives the plain data the model builders take (fem_impact.fem.specs, nonsmooth.specs):
each model's ``spec()``. A case is validated before anything heavy (PETSc, dolfinx) is imported.
"""

from __future__ import annotations

import keyword
import math
import os
from pathlib import Path
from typing import Annotated, Any

from pydantic import (AfterValidator, Field, PlainValidator, PrivateAttr, ValidationInfo, WithJsonSchema, create_model,
                      model_validator)

from ..expressions import RESERVED
from ..fem.specs import BodyValue, Damping, Initial, Load, Material, MeshSpec, Support
from ..integrators.parameters import SolverParameters, _flag_or_auto
from ..nonsmooth.specs import Contact
from .fields import (SPACE, TIME, CsvName, Integer, Name, Real, Section, _mapping, _number, bounds_of, choice,
                     default_of, expression, key, key_rows, list_of, mapping_of, problem, validate, vector)
from .loader import _brief, _Invalid, _show
from .solver import solver_section

__all__ = ["SECTIONS", "CaseFile", "key_rows", "validate_case"]

SHAPES = ("bar",)
BAR_ELEMENTS = ("simplex", "hex")   # triangles/tetrahedra, or quadrilaterals/hexahedra (2D/3D bar)
HYPOTHESES = ("plane_stress", "plane_strain", "axisymmetric")   # 2D: the third direction (mesh.hypothesis)
CONTACT_TYPES = ("obstacle", "pair", "surface")
CONTACT_COUPLINGS = ("each", "mean")
COMPONENTS = ("x", "y", "z")
BUILT_IN_LAWS = ("newton", "elastic_stop")   # (their keys are the contact's own)


def _spec(model: Section, cls):
    return cls(**{name: getattr(model, name) for name in type(model).model_fields})


class MeshSection(Section):
    """``mesh``: the built-in bar (``shape: bar``) or a Gmsh mesh file (``file``)."""

    shape: choice(*SHAPES) = Field(None, description="a built-in shape: bar (a rod in 1D, a strip in 2D, a box in 3D)")
    file: Name = Field(None, description="a Gmsh mesh file (.msh), relative to the case file's folder")
    dim: Integer = key("-", "the built-in bar's dimension: 1 rod, 2 strip, 3 box (default 1)", None, ge=1, le=3)
    length: Real = key("m", "the built-in bar's length", default_of(MeshSpec, "length"), gt=0)
    cells: Integer = key("-", "the built-in bar's cells along its length; across in proportion (at "
                         "least 1)",
                         default_of(MeshSpec, "cells"), ge=1, le=2**31 - 1)
    height: Real = key("m", "the built-in bar's height in 2D and 3D (default length/20)", None, gt=0)
    width: Real = key("m", "the built-in bar's width in 3D (default its height)", None, gt=0)
    elements: choice(*BAR_ELEMENTS) = Field(default_of(MeshSpec, "elements"), description="the built-in bar's cells: "
                                            "simplex (triangles, tetrahedra) or hex (quadrilaterals, hexahedra)")
    hypothesis: choice(*HYPOTHESES) = Field(default_of(MeshSpec, "hypothesis"), description="2D models: the third "
                                            "direction (plane_stress, plane_strain, axisymmetric)")
    axis: choice("x", "y") = Field(None, description="axisymmetric: the symmetry axis (default y, the radius x)")

    @model_validator(mode="after")
    def _consistent(self, info: ValidationInfo):
        if self.shape is None and self.file is None:
            raise _Invalid((), f"give 'shape' (a built-in shape: {', '.join(SHAPES)}) or 'file' (a Gmsh file)")
        if self.shape is not None and self.file is not None:
            raise _Invalid((), f"give either 'shape' ({', '.join(SHAPES)}) or 'file', not both")
        for name, dims in (("height", (2, 3)), ("width", (3,))):
            if getattr(self, name) is not None and (self.file is not None or (self.dim or 1) not in dims):
                where = "a mesh file" if self.file is not None else f"{self.dim or 1}D"
                raise _Invalid((name,), f"applies to the built-in bar in {' and '.join(f'{d}D' for d in dims)} "
                                        f"only; it has no effect in {where}: remove it")
        if self.hypothesis != "plane_stress" and self.file is None and (self.dim or 1) != 2:
            raise _Invalid(("hypothesis",), f"applies to 2D models only (this bar is {self.dim or 1}D): remove it")
        if self.axis is not None and self.hypothesis != "axisymmetric":
            raise _Invalid(("axis",), "applies to hypothesis: axisymmetric only (the symmetry axis): remove it")
        if self.hypothesis == "axisymmetric" and self.axis is None:
            self.axis = "y"
        if self.file is not None:
            self.file = Path(os.path.abspath(Path((info.context or {}).get("folder", ".")) / self.file))
            if not self.file.is_file():
                raise _Invalid(("file",), f"mesh file not found: {self.file}")
        elif self.dim is None:
            self.dim = 1
        return self

    def spec(self) -> MeshSpec:
        return _spec(self, MeshSpec)


class MaterialSection(Section):
    """``material`` (every body), or each body's entry of ``materials``: linear elastic, isotropic."""

    E: Real = key("Pa", "Young's modulus", ..., gt=0)
    rho: Real = key("kg/m^3", "density", ..., gt=0)
    nu: Real = key("-", "Poisson's ratio (0 in 1D)", default_of(Material, "nu"), ge=0, lt=0.5)
    area: Real = key("m^2", "1D: the section; 2D: the thickness (refused in an axisymmetric model)",
                     default_of(Material, "area"), gt=0)

    def spec(self) -> Material:
        return _spec(self, Material)


class DampingSection(Section):
    """``damping``: Rayleigh damping, C = alpha M + beta K."""

    alpha: Real = key("1/s", "mass-proportional coefficient", default_of(Damping, "alpha"), ge=0)
    beta: Real = key("s", "stiffness-proportional coefficient", default_of(Damping, "beta"), ge=0)

    def spec(self) -> Damping:
        return _spec(self, Damping)


_SpaceVector = vector(expression(SPACE))


class BodyValueSection(Section):
    """An entry of a per-body initial field."""

    body: Name = Field(description="the body (cell group of the mesh file)")
    value: _SpaceVector = Field(description="the field's components on the body, in x, y, z")


def _body_values(value, info: ValidationInfo):
    """An initial field: a list of component expressions, or a list of {body, value} mappings."""
    if isinstance(value, list) and all(isinstance(entry, dict) for entry in value):
        values = []
        for index, entry in enumerate(value):
            try:
                values.append(BodyValue(**dict(validate(BodyValueSection, entry, info.context))))
            except _Invalid as exc:
                raise _Invalid((index,) + exc.path, exc.message) from None
        return values
    return [BodyValue(None, validate(_SpaceVector, value, info.context))]


_Field = Annotated[Any, PlainValidator(_body_values), WithJsonSchema({"type": "array", "description": (
    "components (numbers or expressions in x, y, z), or a list of {body, value}")})]


class InitialSection(Section):
    """``initial``: the fields at t = 0 (zero by default), or a saved run's last state."""

    displacement: _Field = key("m", "initial displacement", [])
    velocity: _Field = key("m/s", "initial velocity", [])
    source: Name = Field(None, alias="from", description="a saved run's folder or checkpoint, relative to the case "
                                                         "file's folder: start from its last state")

    @model_validator(mode="after")
    def _one_start(self, info: ValidationInfo):
        if self.source is not None:
            if self.displacement or self.velocity:
                raise _Invalid(("from",), "starts from a saved state: give either 'from' or the initial fields, "
                                          "not both")
            # (read when the run starts: fem_impact/app/checkpoint/)
            self.source = Path(os.path.abspath(Path((info.context or {}).get("folder", ".")) / self.source))
        return self

    def spec(self) -> Initial:
        return Initial(self.displacement, self.velocity, self.source)


def _fix(value):
    """Fixed components: 'all' or a list of x, y, z (as given)."""
    if value == "all":
        return value
    names = [value] if isinstance(value, str) else value
    if not isinstance(names, list) or not names:
        raise _Invalid((), f"expected 'all' or a list of x, y, z; got {_show(value)}")
    for index, name in enumerate(names):
        if name not in COMPONENTS:
            raise _Invalid((index,) if isinstance(value, list) else (),
                           f"unknown component {_show(name)}; expected 'all' or a list of x, y, z")
    return names


class SupportSection(Section):
    """An item of ``supports``: components of a node group held fixed, or moved as prescribed."""

    nodes: Name = Field(description="the node group (a named group of the mesh: left, right, or a physical group)")
    fix: Annotated[Any, PlainValidator(_fix), WithJsonSchema({"type": ["string", "array"]})] = Field(
        None, description="the fixed components: all, or a list of x, y, z (default all)")
    displacement: vector(expression(TIME)) = key("m", "prescribed motion of the fixed components, in the order of "
                                                       "fix (expressions in t; default held at zero)")

    @model_validator(mode="after")
    def _one_motion_per_component(self):
        if self.displacement is not None and self.fix not in ("all", None):
            if len(self.displacement) != len(self.fix):
                raise _Invalid(("displacement",), f"gives {len(self.displacement)} expressions for the {len(self.fix)} "
                                                  f"fixed component(s) {', '.join(self.fix)}: give one per component, "
                                                  "in the order of 'fix'")
        return self

    def spec(self) -> Support:
        if self.fix in ("all", None):
            return Support(self.nodes, "all" if self.fix is None else [0, 1, 2], True, self.displacement)
        fixed = sorted({COMPONENTS.index(name) for name in self.fix})
        motion = self.displacement
        if motion is not None:   # (fix is stored sorted: x, y, z) the expressions follow it
            order = {COMPONENTS.index(name): expr for name, expr in zip(self.fix, motion)}
            motion = [order[c] for c in sorted(order)]
        return Support(self.nodes, fixed, False, motion)


class LoadSection(Section):
    """An item of ``loads``: a force or a traction on a node group, or an acceleration of a body (gravity)."""

    nodes: Name = Field(None, description="the node group the force or the traction acts on")
    body: Name = Field(None, description="the body accelerated: all, or a cell group of the mesh file")
    force: vector(expression(TIME)) = key("N", "total force on the node group, shared equally by its nodes "
                                               "(expressions in t)")
    traction: vector(expression(TIME)) = key("Pa", "force per unit area on the boundary faces (2D: edges, times "
                                                   "the thickness) whose nodes are all in the group, integrated "
                                                   "into consistent nodal forces (expressions in t)")
    acceleration: vector(expression(TIME)) = key("m/s^2", "body acceleration (expressions in t)")

    @model_validator(mode="after")
    def _one_kind(self):
        if (self.nodes is None) == (self.body is None):
            raise _Invalid((), "give either 'nodes' (with 'force' or 'traction') or 'body' (with 'acceleration')")
        if self.nodes is not None:
            if self.acceleration is not None:
                raise _Invalid(("acceleration",), "not allowed with 'nodes' (use 'force' or 'traction')")
            if self.force is not None and self.traction is not None:
                raise _Invalid(("traction",), "give 'force' (a total) or 'traction' (per unit area), not both")
            if self.force is None and self.traction is None:
                raise _Invalid(("force",), "missing required key (a load on 'nodes' needs 'force' or 'traction')")
            return self
        for other in ("force", "traction"):
            if getattr(self, other) is not None:
                raise _Invalid((other,), "not allowed with 'body' (use 'acceleration')")
        if self.acceleration is None:
            raise _Invalid(("acceleration",), "missing required key (a load on 'body' needs 'acceleration')")
        return self

    def spec(self) -> Load:
        return _spec(self, Load)


# --- contacts ------------------------------------------------------------------------------------


def _law_key(law: str, name: str, default=...):
    """A key of a built-in law as a contact's own: declared once, by the law (fem_impact.nonsmooth.laws)."""
    from ..nonsmooth.laws import LAWS

    info = LAWS[law].keys.model_fields[name]
    extra = {"unit": "-", **(info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {})}
    return (Real, Field(info.default if default is ... else default, description=info.description,
                        json_schema_extra=extra, **bounds_of(info)))


_RELATION = {   # the relation's keys of a contact, whatever its law
    "name": (CsvName, Field(description="the contact's name: its columns' prefix in history.csv")),
    "type": (choice(*CONTACT_TYPES), Field(description="obstacle: a node group against a fixed plane; pair: two "
                                                        "node groups against each other; surface: a node group "
                                                        "against the boundary of another, rows found by a search")),
    "nodes": (Any, Field(description="obstacle, surface: a node group; pair: a list of two node groups")),
    "normal": (vector(Real), key("-", "obstacle: the direction in which the nodes approach the plane; pair: from "
                                      "the first group to the second (made unit); surface: none (the surface's "
                                      "own)")),
    "gap": (Real, key("m", "the gap of every row (obstacle: default 0; pair: default each pair's distance "
                             "along the normal in the mesh)")),
    "coupling": (choice(*CONTACT_COUPLINGS), Field(default_of(Contact, "coupling"), description=(
        "pair: each (a row per node pair) or mean (one row between the groups' mean motions)"))),
    "law": (choice(*BUILT_IN_LAWS), Field(default_of(Contact, "law"), description=(
        "the contact law: newton (rigid, restitution) or elastic_stop (stiffness), or a registered one"))),
    "friction": (Real, key("-", "Coulomb's coefficient mu on every row (default 0: frictionless)", None, ge=0)),
    "point": (vector(Real), key("m", "obstacle: a point of its plane, instead of gap: each node's gap is its own "
                                   "distance to the plane")),
    "motion": (vector(expression(TIME)), key("m", "obstacle: the plane's displacement from where gap or point put it "
                                                  "at t = 0, one expression in t per axis (default: fixed); the laws "
                                                  "act on the motion relative to it, its work is external work")),
    "surface": (Name, Field(None, description="surface: the node group whose boundary edges (2D) or faces (3D) "
                                              "the nodes meet; the gaps are the geometry's")),
}


def _relation(contact: Section) -> dict:
    """The relation's keys of a contact: node groups per type, the gap of an obstacle, a unit normal."""
    f = {name: getattr(contact, name) for name in _RELATION if name != "law"}
    nodes = [f["nodes"]] if isinstance(f["nodes"], str) else f["nodes"]
    if f["type"] == "surface":   # (its own words for what it does not take: point, motion, normal, gap)
        _surface_keys(f, nodes)
    if f["point"] is not None:
        if f["type"] != "obstacle":
            raise _Invalid(("point",), "a point of the obstacle's plane is for an obstacle contact "
                                       "(a pair's gaps are its nodes' distances)")
        if f["gap"] is not None:
            raise _Invalid(("point",), "give either gap (one for every node) or point (each node's gap "
                                       "its own distance to the plane through it), not both")
    if f["motion"] is not None and f["type"] != "obstacle":
        raise _Invalid(("motion",), "a motion is for an obstacle contact's plane (a pair moves with its bodies)")
    if f["type"] != "surface" and f["surface"] is not None:
        raise _Invalid(("surface",), "a surface is for a surface contact (type: surface)")
    elif f["type"] != "surface" and f["normal"] is None:
        raise _Invalid(("normal",), f"required for {_article(f['type'])} {f['type']} contact")
    if f["type"] in ("obstacle", "surface"):
        if not (isinstance(nodes, list) and len(nodes) == 1):
            raise _Invalid(("nodes",), f"{_article(f['type'])} {f['type']} contact takes one node group, "
                                       f"got {_show(f['nodes'])}")
        if f["point"] is None and f["type"] == "obstacle":
            f["gap"] = 0.0 if f["gap"] is None else f["gap"]
    elif not (isinstance(nodes, list) and len(nodes) == 2):
        raise _Invalid(("nodes",), f"a pair contact takes a list of two node groups, got {_show(f['nodes'])}")
    f["nodes"] = [group if isinstance(group, str) and group else _bad_group(i, group) for i, group in enumerate(nodes)]
    if len(set(f["nodes"])) != len(f["nodes"]):
        raise _Invalid(("nodes",), "the two node groups must differ")
    if f["normal"] is not None:
        length = math.hypot(*f["normal"])
        if length == 0.0:
            raise _Invalid(("normal",), "must have a nonzero length")
        f["normal"] = [component / length for component in f["normal"]]
    return f


def _article(word: str) -> str:
    return "an" if word[0] in "aeiou" else "a"


def _surface_keys(f: dict, nodes) -> None:
    """A surface contact: a node group and a surface; its normals and gaps are the geometry's."""
    if f["surface"] is None:
        raise _Invalid(("surface",), "required for a surface contact: the node group whose boundary the nodes meet")
    for name, why in (("normal", "its rows use the surface's own normals"), ("gap", "its rows use the geometry's "
                                                                                   "distances"),
                      ("point", "its rows use the geometry's distances"),
                      ("motion", "its rows move with the bodies")):
        if f[name] is not None:
            raise _Invalid((name,), f"a surface contact takes no {name}: {why}")
    if f["coupling"] != "each":
        raise _Invalid(("coupling",), "a surface contact has a row per node (coupling: each)")
    if isinstance(nodes, list) and len(nodes) == 1 and nodes[0] == f["surface"]:
        raise _Invalid(("surface",), f"is the contact's own node group '{nodes[0]}': give the surface as another "
                                     "group")


def _bad_group(index, group):
    raise _Invalid(("nodes", index), f"expected a non-empty string, got {_show(group)}")


class _ContactChecks(Section):
    _relation: dict = PrivateAttr(default_factory=dict)

    @model_validator(mode="after")
    def _relation_keys(self):
        self._relation = _relation(self)
        return self

    def spec(self) -> Contact:
        law = "elastic_stop" if self.stiffness is not None else "newton"
        law_keys = {"stiffness": self.stiffness} if self.stiffness is not None else {"restitution": self.restitution}
        friction = 0.0 if self.friction is None else self.friction
        return Contact(**{**self._relation, "friction": friction}, restitution=self.restitution,
                       stiffness=self.stiffness, law=law, law_keys=law_keys)


def _built_in_law(contact: Section, value: dict) -> None:
    """A built-in law follows from the keys (elastic_stop: a stiffness given); ``law`` may only confirm it."""
    inferred = "elastic_stop" if contact.stiffness is not None else "newton"
    if value.get("law") is not None and contact.law != inferred:
        needs = "a stiffness" if contact.law == "elastic_stop" else "no stiffness"
        raise _Invalid(("law",), f"law {contact.law} takes {needs}; got law {contact.law} with keys "
                                 f"{', '.join(str(k) for k in value)}")
    if contact.stiffness is not None and value.get("restitution") is not None:
        # Its spring stores the approach and gives it back: no impact law, so no restitution.
        keys = ", ".join(name for name in type(contact).model_fields if name != "restitution")
        raise _Invalid(("restitution",), f"an elastic stop (stiffness given) does not use 'restitution': its "
                                         f"spring gives back what it stores; keys of an elastic stop: {keys} "
                                         "(or remove stiffness for a rigid contact)")


_CONTACT_ORDER = ("name", "type", "nodes", "normal", "gap", "restitution", "coupling", "stiffness", "law", "friction",
                  "point", "motion", "surface")
_contact_keys = {**_RELATION, "restitution": _law_key("newton", "restitution"),
           "stiffness": _law_key("elastic_stop", "stiffness", None)}
ContactSection = create_model("ContactSection", __base__=_ContactChecks, __module__=__name__,
                              __doc__="An item of ``contacts``: a unilateral contact, with the built-in laws' keys "
                                      "(restitution: newton; stiffness: elastic_stop) as its own.",
                              **{name: _contact_keys[name] for name in _CONTACT_ORDER})
_RelationSection = create_model("RelationSection", __base__=Section, __module__=__name__,
                                **{**_RELATION, "law": (Name, Field(description="a registered contact law"))})


def _registered_law_contact(value, context):
    """A contact whose ``law`` is one registered beyond the built-in ones: its keys are the law's."""
    from pydantic import ValidationError

    from ..nonsmooth.laws import LAWS

    name = value["law"]
    if not isinstance(name, str) or name not in LAWS:
        raise _Invalid(("law",), f"must be one of {', '.join(LAWS)}; got {_show(name)}")
    law = LAWS[name]
    relation = validate(_RelationSection, {k: v for k, v in value.items() if k in _RELATION}, context)
    f = _relation(relation)
    given = {k: v for k, v in value.items() if k not in _RELATION}
    try:
        law_keys = law.keys.model_validate(given).model_dump()
    except ValidationError as exc:
        error = exc.errors()[0]
        where = error["loc"][0] if error["loc"] else None
        if error["type"] == "extra_forbidden":
            keys = ", ".join([*_RELATION, *law.keys.model_fields])
            raise _Invalid((where,), f"contact law {name} does not use '{where}'; keys of a contact with "
                                     f"law {name}: {keys}") from None
        raise problem(error, law.keys) from None   # (in the case file's words, as the built-in laws' keys)
    if f["friction"] is None:
        del f["friction"]
    return Contact(**f, law=name, law_keys=law_keys)


def _contact(value, info: ValidationInfo) -> Contact:
    law = _mapping(value).get("law")
    if law is not None and law not in BUILT_IN_LAWS:
        return _registered_law_contact(value, info.context)
    contact = validate(ContactSection, value, info.context)
    _built_in_law(contact, value)
    return contact.spec()


def _unique_names(contacts: list[Contact]) -> list[Contact]:
    names = [contact.name for contact in contacts]
    for index, name in enumerate(names):
        if name in names[:index]:
            raise _Invalid((index, "name"), f"duplicate contact name '{name}'")
    return contacts


_Contact = Annotated[Any, PlainValidator(_contact), WithJsonSchema({"type": "object"})]


def _positive_time(period) -> float:
    """A drive's period (a constant expression): its value in seconds, > 0 and finite."""
    value = period.evaluate()
    if not (math.isfinite(value) and value > 0.0):
        raise _Invalid((), f"must be a positive, finite time, got {value!r} (from {_show(period.source)})")
    return float(value)


class OutputSection(Section):
    """``output``: what the run writes, and how often."""

    every: Integer = key("-", "steps between the fields' frames (history.csv has a row every step)", 10, ge=1,
                         le=2**53)
    probes: mapping_of(vector(Real), CsvName) = key("m", "named points whose displacement and velocity history.csv "
                                                         "records", {})
    vtk: bool = Field(True, description="write the fields for ParaView (format)")
    format: choice("vtu", "xdmf") = Field("vtu", description="the fields' files: vtu (results.pvd, ASCII) or xdmf "
                                                             "(results.xdmf + .h5, binary)")
    checkpoint_every: Integer = key("-", "steps between checkpoints (0: at the end only)", 0, ge=0, le=2**53)
    period: Annotated[expression(()), AfterValidator(_positive_time)] = key(
        "s", "the drive's period (a number or an expression of the parameters, e.g. 1/f): impacts.csv gains the "
             "impacts' phase, and periods.csv a row per period", None)


def _parameter_names(value):
    """Named numbers for the expressions: identifiers that shadow no variable, constant or function."""
    parameters = {}
    for name, number in _mapping(value).items():
        if not name.isidentifier() or keyword.iskeyword(name):
            raise _Invalid((name,), f"a parameter name must be an identifier (letters, digits and '_', "
                                    f"not starting with a digit), got {_brief(name)}")
        if name in RESERVED:
            raise _Invalid((name,), f"'{name}' is reserved (the names {', '.join(RESERVED)} have a meaning "
                                    "in expressions); choose another name")
        try:
            parameters[name] = float(_number(number))
        except _Invalid as exc:
            raise _Invalid((name,), exc.message) from None
    return parameters


def _reference(value):
    """The name of a known exact solution (fem_impact.references)."""
    from ..references import REFERENCES  # (numpy: loaded only when a case names a reference)

    if not isinstance(value, str) or value not in REFERENCES:
        raise _Invalid((), f"unknown reference {_show(value)}; known references: "
                           + ", ".join(f"{name} ({REFERENCES[name].title})" for name in REFERENCES))
    return value


def _case_name(value):
    if not isinstance(value, str) or not value:
        raise _Invalid((), f"expected a non-empty string, got {_show(value)}")
    if value in (".", "..") or any(c in value for c in "/\\\0"):
        raise _Invalid((), f"must be usable as a folder name, got {_brief(value)}")
    return value


def _solver(value):
    return solver_section(value, ())


class BodySection(Section):
    """An entry of ``bodies``: how a body of the mesh is modelled."""

    model: choice("elastic", "rigid", "modal") = Field("elastic", description=(
        "elastic: the finite-element model (the default); rigid: its rigid motion in large rotations, mass, "
        "centre and inertia from its mesh and material (beside elastic bodies or not); modal: this body alone "
        "reduced to its lowest modes plus the static correction of the others at its contact rows, beside "
        "rigid bodies"))
    modes: Integer = key("-", "modal: the body's kept eigenmodes (required there)", None, ge=1, le=2**31 - 1)
    blocks: Annotated[bool | str, PlainValidator(_flag_or_auto)] = Field(
        None, description="modal: take the scene's steps many at a time in one compiled loop (2D, every contact "
                          "row on the modal body; the single steps' results to round-off); auto (the default): "
                          "when the run has at least 4000 steps; false: one at a time")

    @model_validator(mode="after")
    def _modes_with_modal(self):
        if self.model == "modal" and self.modes is None:
            raise _Invalid(("modes",), "a modal body needs its count of kept modes: modes: N (an integer >= 1)")
        for name in ("modes", "blocks"):
            if self.model != "modal" and getattr(self, name) is not None:
                raise _Invalid((name,), f"applies to model: modal only (this body is {self.model}): remove it")
        return self


class CaseFile(Section):
    """A case file: the model (mesh, materials, supports, loads, contacts), the method, the outputs."""

    name: Annotated[str, PlainValidator(_case_name)] = Field(
        None, description="the run's name: its output folder (default the case file's name)")
    mesh: MeshSection = Field(description="the mesh")
    material: MaterialSection = Field(None, description="one material for every body")
    materials: mapping_of(MaterialSection) = Field(None, description="one material per body (cell group)")
    damping: DampingSection = Field(None, description="Rayleigh damping (none by default)")
    initial: InitialSection = Field(None, description="the initial state (at rest by default)")
    supports: list_of(SupportSection) = Field([], description="fixed or moved node groups")
    loads: list_of(LoadSection) = Field([], description="forces and body accelerations")
    contacts: Annotated[list_of(_Contact), AfterValidator(_unique_names)] = Field([], description="contacts")
    bodies: mapping_of(BodySection) = Field({}, description="per body of the mesh, how it is modelled (default "
                                                           "elastic)")
    solver: Annotated[Any, PlainValidator(_solver), WithJsonSchema({"type": "object"})] = Field(
        description="the time integration: the keys of its method (fem_impact.integrators.parameters)")
    output: OutputSection = Field(None, description="what the run writes")
    parameters: Annotated[dict, PlainValidator(lambda value, info: info.context["parameters"])] = Field(
        {}, description="named numbers the expressions may use")
    reference: Annotated[str, PlainValidator(_reference)] = Field(None, description=(
        "a known exact solution the case fits (b1, b2, bar_mode): the studies measure errors against it"))

    @model_validator(mode="after")
    def _one_material(self):
        if self.material is None and self.materials is None:
            raise _Invalid(("material",), "missing required key: give 'material' (for every body) or 'materials' "
                                          "(per body)")
        if self.material is not None and self.materials is not None:
            raise _Invalid(("material",), "give either 'material' (for every body) or 'materials' (per body), "
                                          "not both")
        if self.materials == {}:
            raise _Invalid(("materials",), "must give at least one body")
        return self


_Parameters = Annotated[dict, PlainValidator(_parameter_names)]


def validate_case(data: dict, folder: Path) -> dict:
    """The sections of a case mapping as the model builders take them (Case's fields, but name, path and lines)."""
    try:
        parameters = validate(_Parameters, data.get("parameters"))
    except _Invalid as exc:
        raise _Invalid(("parameters",) + exc.path, exc.message) from None
    case = validate(CaseFile, data, {"parameters": parameters, "folder": folder})
    return {
        "name": case.name, "mesh": case.mesh.spec(),
        "material": None if case.material is None else case.material.spec(),
        "materials": None if case.materials is None else {b: m.spec() for b, m in case.materials.items()},
        "damping": Damping() if case.damping is None else case.damping.spec(),
        "initial": Initial() if case.initial is None else case.initial.spec(),
        "supports": [s.spec() for s in case.supports], "loads": [load.spec() for load in case.loads],
        "contacts": case.contacts, "bodies": {name: body.model for name, body in case.bodies.items()},
        "body_modes": {name: body.modes for name, body in case.bodies.items() if body.model == "modal"},
        "body_blocks": {name: body.blocks for name, body in case.bodies.items() if body.blocks is not None},
        "solver": case.solver, "output": case.output, "parameters": parameters,
        "reference": case.reference}


# Each section's model (a list's: its items'): the case reference of the documentation reads them, a row per
# key with key_rows(model) (the solver's keys: each method's schema, fem_impact.integrators.parameters.SCHEMAS).
SECTIONS: dict[str, type[Section]] = {
    "mesh": MeshSection, "material": MaterialSection, "materials": MaterialSection, "damping": DampingSection,
    "initial": InitialSection, "supports": SupportSection, "loads": LoadSection, "contacts": ContactSection,
    "bodies": BodySection,
    "solver": SolverParameters, "output": OutputSection}
