"""The ``solver`` section: validated by the schema of its method (fem_impact.integrators.parameters, one
pydantic model per registered method), its errors told with the methods that do take a key."""

from __future__ import annotations

import difflib
import logging
import typing

from pydantic import ValidationError

from ..integrators.parameters import (DEFAULT_METHOD, METHODS, MODAL_SCHEMES, REDUCED, SCHEMAS, KeyProblem,
                                      solver_schema, valid_keys)
from ..integrators.parameters import tag as _schema_tag
from .fields import _mapping, bounds_of, range_text
from .loader import _brief, _Invalid, _show

log = logging.getLogger(__name__)


def solver_section(value, path=()):
    """The solver section, validated by the schema of its method (fem_impact.integrators.parameters)."""
    # (an explicit null means the default, as everywhere in a case file)
    data = {key: entry for key, entry in _mapping(value).items() if entry is not None}
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
        return _Invalid(path + loc, f"must be {range_text(bounds_of(field_info))}, got {_brief(given)}")
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


def solver_tag(data):
    solver = data.get("solver") if isinstance(data, dict) else None
    return _schema_tag(solver) if isinstance(solver, dict) else None


def follow_kind_changes(data, before: str | None, changed) -> None:
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

