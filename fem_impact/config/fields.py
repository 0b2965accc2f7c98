"""The building blocks of the case file's schemas (pydantic): numbers, integers, names, choices, vectors,
expressions and mappings checked in the case file's own words, and pydantic's errors turned into the
``key: problem`` of a message. Ranges are declared on the fields (``Field(gt=0)``) and read back here."""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import sys
import typing
from typing import Annotated, Any, Literal

from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, PlainValidator, TypeAdapter, ValidationError,
                      ValidationInfo, WithJsonSchema, model_validator)

from ..expressions import ExpressionError, parse_expression
from .loader import _brief, _Invalid, _show

SPACE = ("x", "y", "z")  # variables of initial fields
TIME = ("t",)  # variables of loads and motions
_CSV_NAME = re.compile(r"[A-Za-z0-9_-]+")


def key(unit: str, doc: str, default: Any = None, **bounds):
    """A key of the case file: its default, unit, range (gt, ge, lt, le) and meaning."""
    return Field(default, description=doc, json_schema_extra={"unit": unit}, **bounds)


def default_of(spec, name: str):
    """The default of a field of the dataclass `spec` (the one place it is written)."""
    field = {f.name: f for f in dataclasses.fields(spec)}[name]
    return field.default if field.default is not dataclasses.MISSING else field.default_factory()


# --- value types ---------------------------------------------------------------------------


def _mapping(value):
    """A mapping with string keys (null counts as empty)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise _Invalid((), f"expected a mapping, got {_show(value)}")
    for name in value:
        if not isinstance(name, str):
            raise _Invalid((), f"keys must be names (strings), got {_brief(name)}")
    return value


def _number(value):
    """A finite number (an integer too, within the floats); as given, so that a message quotes it as written."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _Invalid((), f"expected a number, got {_show(value)}")
    try:
        number = float(value)
    except OverflowError:
        raise _Invalid((), f"expected a finite number, got {_brief(value)}, beyond the largest float "
                           f"({sys.float_info.max:.3g})") from None
    if not math.isfinite(number):
        raise _Invalid((), f"expected a finite number, got {value}")
    return value


def _integral(value):
    """An integer; integral floats such as ``1e3`` are accepted."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise _Invalid((), f"expected an integer, got {_show(value)}")
    return value


def _name(value):
    if not isinstance(value, str) or not value:
        raise _Invalid((), f"expected a non-empty string, got {_show(value)}")
    return value


def _csv_name(value):
    """A name used as a column prefix in history.csv."""
    if not isinstance(value, str) or not _CSV_NAME.fullmatch(value):
        raise _Invalid((), f"expected a name of letters, digits, '_' and '-', got {_show(value)}")
    return value


def _list(value):
    if not isinstance(value, list):
        raise _Invalid((), f"expected a list, got {_show(value)}")
    return value


def _components(value):
    if not isinstance(value, list):
        raise _Invalid((), f"expected a list of 1 to 3 components, got {_show(value)}")
    if not 1 <= len(value) <= 3:
        raise _Invalid((), f"must have 1 to 3 components, got {len(value)}")
    return value


Real = Annotated[float, BeforeValidator(_number)]
Integer = Annotated[int, BeforeValidator(_integral)]
Name = Annotated[str, BeforeValidator(_name)]
CsvName = Annotated[str, BeforeValidator(_csv_name)]


def choice(*options: str):
    """One of `options` (a string)."""
    def check(value):
        if not isinstance(value, str) or value not in options:
            raise _Invalid((), f"must be one of {', '.join(options)}; got {_show(value)}")
        return value
    return Annotated[Literal[options], BeforeValidator(check)]


def vector(item):
    """A list of 1 to 3 components."""
    return Annotated[list[item], BeforeValidator(_components)]


def list_of(item):
    return Annotated[list[item], BeforeValidator(_list)]


def mapping_of(item, names=Name):
    """A mapping of names (checked as `names`) to items."""
    return Annotated[dict[names, item], BeforeValidator(_mapping)]


def expression(variables: tuple[str, ...]):
    """An arithmetic expression in `variables` and the case's parameters (the validation's context)."""
    def convert(value, info: ValidationInfo):
        if not isinstance(value, str):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise _Invalid((), f"expected a number or an arithmetic expression, got {_show(value)}")
            _number(value)   # (an integer beyond the floats: refused here, with its key)
        try:
            return parse_expression(value, variables, (info.context or {}).get("parameters", {}))
        except ExpressionError as exc:
            raise _Invalid((), str(exc)) from None
    what = f"an expression in {', '.join(variables)}" if variables else "an expression of the parameters"
    return Annotated[Any, PlainValidator(convert), WithJsonSchema(
        {"type": ["number", "string"], "description": f"a number or {what}"})]


# --- sections --------------------------------------------------------------------------------


class Section(BaseModel):
    """A mapping of the case file: unknown keys refused (with the closest valid one), null meaning the default."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, value):
        data = _mapping(value)
        keys = {info.alias or name: info for name, info in cls.model_fields.items()}
        for name in data:
            if name not in keys:
                close = difflib.get_close_matches(name, list(keys), n=1)
                hint = f"did you mean '{close[0]}'?" if close else f"valid keys: {', '.join(keys)}"
                raise _Invalid((name,), f"unknown key '{name}'; {hint}")
        # (an explicit null on an optional key means its default, so that a resolved dump reads back)
        return {name: item for name, item in data.items() if item is not None or keys[name].is_required()}


_ADAPTERS: dict = {}


def validate(schema, value, context=None):
    """`value` validated by `schema` (a model or a type); _Invalid at the key path (relative to `value`)."""
    if schema not in _ADAPTERS:
        _ADAPTERS[schema] = TypeAdapter(schema)
    try:
        return _ADAPTERS[schema].validate_python(value, context=context)
    except ValidationError as exc:
        raise problem(exc.errors()[0], schema) from None


# --- errors ----------------------------------------------------------------------------------

_BOUNDS = {"gt": (">", "("), "ge": (">=", "["), "lt": ("<", ")"), "le": ("<=", "]")}


def _figure(bound) -> str:
    return str(bound) if isinstance(bound, int) else f"{bound:g}"


def range_text(bounds: dict) -> str:
    """``{"gt": 0, "lt": 1}`` -> ``"in (0, 1)"``; ``{"ge": 0}`` -> ``">= 0"``."""
    if len(bounds) == 2:
        (low, a), (high, b) = sorted(bounds.items(), key=lambda item: item[0][0] == "l")
        return f"in {_BOUNDS[low][1]}{_figure(a)}, {_figure(b)}{_BOUNDS[high][1]}"
    return " ".join(f"{_BOUNDS[name][0]} {_figure(bound)}" for name, bound in bounds.items())


def bounds_of(info) -> dict:
    """The range declared on a field: ``{"gt": 0}``."""
    return {name: getattr(item, name) for item in info.metadata for name in _BOUNDS
            if getattr(item, name, None) is not None}


def _unwrap(annotation):
    while typing.get_origin(annotation) is Annotated:
        annotation = typing.get_args(annotation)[0]
    return annotation


def field_at(schema, loc):
    """The pydantic field at the key path `loc` under `schema` (None where the path leaves the models)."""
    info, annotation = None, schema
    for part in loc:
        annotation = _unwrap(annotation)
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            info = next((i for n, i in annotation.model_fields.items() if (i.alias or n) == part), None)
            if info is None:
                return None
            annotation = info.annotation
        else:
            args = typing.get_args(annotation)   # list[X], dict[str, X]: the item
            annotation, info = (args[-1] if args else None), None
    return info


def problem(error: dict, schema) -> _Invalid:
    """A pydantic error as the case file reports it: the key path, and the project's own words."""
    loc = tuple(part for part in error["loc"] if part != "[key]")   # (a mapping's name: reported on its entry)
    kind, given, ctx = error["type"], error.get("input"), error.get("ctx") or {}
    if isinstance(ctx.get("error"), _Invalid):
        return _Invalid(loc + ctx["error"].path, ctx["error"].message)
    if kind == "missing":
        return _Invalid(loc, "missing required key")
    if kind == "bool_type":
        return _Invalid(loc, f"expected true or false, got {_show(given)}")
    if kind in ("float_type", "float_parsing", "int_type", "int_parsing"):
        return _Invalid(loc, f"expected a number, got {_show(given)}")
    if kind == "finite_number":
        return _Invalid(loc, f"expected a finite number, got {_brief(given)}")
    info = field_at(schema, loc)
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal") and info is not None:
        return _Invalid(loc, f"must be {range_text(bounds_of(info))}, got {_brief(given)}")
    if kind == "value_error":
        return _Invalid(loc, str(ctx.get("error", error["msg"])))
    return _Invalid(loc, error["msg"])


def key_rows(schema: type[BaseModel]) -> list[dict]:
    """The keys of a section's model as the case reference shows them: key, unit, default, range, meaning.

    ``default`` is ``"required"`` for a key that must be given, and None where the default is worked out
    (the description says how); ``range`` is text such as ``"> 0"`` or ``"in [0, 0.5)"``, or "".
    """
    rows = []
    for name, info in schema.model_fields.items():
        extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
        choices = typing.get_args(_unwrap(info.annotation)) if typing.get_origin(_unwrap(info.annotation)) is Literal \
            else ()
        bounds = bounds_of(info)
        rows.append({"key": info.alias or name, "unit": extra.get("unit", ""),
                     "default": "required" if info.is_required() else info.get_default(call_default_factory=True),
                     "range": range_text(bounds) if bounds else " | ".join(choices),
                     "description": info.description or ""})
    return rows
