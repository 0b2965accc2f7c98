"""The case-file reference, generated from the schemas that validate a case (a Sphinx extension).

When the site is built, ``docs/_generated/case_reference.md`` is written from the pydantic models
themselves: the ``solver`` section from the registry of methods
(``fem_impact.integrators.parameters.SCHEMAS``), the contact laws from
``fem_impact.nonsmooth.laws.LAWS[name].keys``, and every other section from
``fem_impact.config.schema.SECTIONS`` (name -> model) where that module exists; where it does not,
the page points to the hand-written description of those sections (docs/case_files.md).
docs/case_reference.md includes the generated file. Per key: its name, type, default, range (from
the field's constraints), unit (``json_schema_extra["unit"]``) and meaning (its description).

Run as a script, it prints the generated Markdown: ``python docs/_ext/case_reference.py``.
"""

from __future__ import annotations

import importlib
import inspect
import sys
import types
import typing
from pathlib import Path

from pydantic import BaseModel

GENERATED = Path(__file__).resolve().parents[1] / "_generated" / "case_reference.md"
NONE = type(None)


def type_text(annotation) -> str:
    """A field's type in words: ``float``, ``one of: a, b``, ``list of float``, a model's name."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if annotation is NONE or annotation is None:
        return "null"
    if origin is typing.Literal:
        return "one of: " + ", ".join(f"`{a}`" if isinstance(a, str) else repr(a) for a in args) \
            if len(args) > 1 else (f"`{args[0]}`" if isinstance(args[0], str) else repr(args[0]))
    if origin is typing.Annotated:
        return type_text(args[0])
    if origin in (typing.Union, types.UnionType):
        kinds = [type_text(a) for a in args if a is not NONE]
        return " or ".join(kinds) + (" or null" if NONE in args else "")
    if origin in (list, tuple, set, frozenset) or (origin is not None and getattr(origin, "__name__", "") == "Sequence"):
        inner = [a for a in args if a is not Ellipsis]
        return "list" + (f" of {type_text(inner[0])}" if inner else "")
    if origin is dict or (origin is not None and getattr(origin, "__name__", "") == "Mapping"):
        return f"mapping of {type_text(args[0])} to {type_text(args[1])}" if args else "mapping"
    if inspect.isclass(annotation) and issubclass(annotation, BaseModel):
        return f"{model_title(annotation)} (below)"
    if inspect.isclass(annotation):
        return annotation.__name__
    return str(annotation).replace("typing.", "")


def range_text(info) -> str:
    """The bounds a field declares (``> 0``, ``>= 0.5, <= 1``, ``at least 1 item``), from its metadata."""
    out = []
    for item in info.metadata:
        for attr, sign in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="), ("multiple_of", "multiple of")):
            value = getattr(item, attr, None)
            if value is not None:
                out.append(f"{sign} {value:g}" if isinstance(value, (int, float)) else f"{sign} {value}")
        for attr, word in (("min_length", "at least"), ("max_length", "at most")):
            value = getattr(item, attr, None)
            if value is not None:
                out.append(f"{word} {value} item{'s' if value != 1 else ''}")
    return ", ".join(dict.fromkeys(out))


def unit_text(info) -> str:
    extra = info.json_schema_extra
    return str(extra.get("unit", "")) if isinstance(extra, dict) else ""


def default_text(info) -> str:
    if info.is_required():
        return "required"
    if info.default_factory is not None:
        try:
            value = info.default_factory()
        except TypeError:
            return "computed"
    else:
        value = info.default
    if isinstance(value, BaseModel):
        return "its defaults"
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    return f"`{value}`" if isinstance(value, str) else f"{value!r}"


def cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def model_title(model: type[BaseModel]) -> str:
    return getattr(model, "__name__", str(model))


def ordered_fields(model: type[BaseModel]) -> list[str]:
    """The model's keys in declaration order, tags first (keys whose type is a single literal value,
    such as ``method`` and ``scheme``: they say which schema applies)."""
    names = list(model.model_fields)

    def is_tag(name):
        annotation = model.model_fields[name].annotation
        return typing.get_origin(annotation) is typing.Literal and len(typing.get_args(annotation)) == 1
    return [n for n in names if is_tag(n)] + [n for n in names if not is_tag(n)]


def nested_models(model: type[BaseModel]) -> list[type[BaseModel]]:
    """The models a model's fields hold (directly, in lists or mappings), in order, each once."""
    found: list[type[BaseModel]] = []

    def walk(annotation):
        if inspect.isclass(annotation) and issubclass(annotation, BaseModel):
            if annotation not in found and annotation is not model:
                found.append(annotation)
            return
        for arg in typing.get_args(annotation):
            walk(arg)
    for info in model.model_fields.values():
        walk(info.annotation)
    return found


def key_table(model: type[BaseModel]) -> str:
    """A Markdown table of the model's keys: key, type, default, range, unit, meaning."""
    lines = ["| key | type | default | range | unit | meaning |", "|---|---|---|---|---|---|"]
    for name in ordered_fields(model):
        info = model.model_fields[name]
        key = info.alias or name
        lines.append("| " + " | ".join(cell(x) for x in (
            f"`{key}`", type_text(info.annotation), default_text(info), range_text(info), unit_text(info),
            info.description or "")) + " |")
    if len(lines) == 2:
        return "No keys of its own."
    return "\n".join(lines)


def summary_of(model: type[BaseModel]) -> str:
    doc = inspect.cleandoc(model.__doc__ or "")
    if doc.startswith(("A base class for creating Pydantic models", "Usage docs:")):   # pydantic's own
        return ""
    return " ".join(doc.split("\n\n")[0].split())


def model_markdown(title: str, model: type[BaseModel], level: int = 3, intro: str = "") -> str:
    """A section for one model: its title, what it is (its docstring's first paragraph), its key table,
    then a section for each model its keys hold."""
    parts = [f"{'#' * level} {title}", ""]
    text = intro or summary_of(model)
    if text:
        parts += [text, ""]
    parts += [key_table(model), ""]
    for inner in nested_models(model):
        parts.append(model_markdown(model_title(inner), inner, min(level + 1, 6)))
    return "\n".join(parts)


def solver_markdown() -> str:
    from fem_impact.integrators import parameters

    parts = ["## `solver`: the time integration", "",
             f"`solver.method` chooses the method (default `{parameters.DEFAULT_METHOD}`); each method takes "
             "the keys of its own schema and no others (a key another method takes is refused, naming the "
             "method's keys). `method: modal` is the reduced model, stepped by its `scheme`.", ""]
    for name, schema in parameters.SCHEMAS.items():
        method, _, scheme = name.partition("/")
        title = f"`method: {method}`" + (f", `scheme: {scheme}`" if scheme else "")
        parts.append(model_markdown(title, schema))
    return "\n".join(parts)


def laws_markdown() -> str:
    from fem_impact.nonsmooth import laws

    parts = ["## `contacts[].law`: the contact laws", "",
             "A contact's `law` names one of these (a rigid contact takes `newton`, a contact with a `stiffness` "
             "`elastic_stop`, when `law` is not given); the contact then takes the law's keys.", ""]
    for name, law in laws.LAWS.items():
        intro = " ".join(filter(None, [law.summary and law.summary[0].upper() + law.summary[1:] + ".",
                                       " ".join(inspect.cleandoc(law.__doc__ or "").split("\n\n")[0].split())]))
        parts.append(model_markdown(f"`law: {name}`", law.keys, intro=intro))
    return "\n".join(parts)


def sections_markdown() -> str:
    """Every other section: from ``fem_impact.config.schema.SECTIONS`` where it exists."""
    try:
        schema = importlib.import_module("fem_impact.config.schema")
        sections = schema.SECTIONS
    except (ImportError, AttributeError):
        return ("## The other sections\n\nThe other sections of a case file (`mesh`, `material`, `initial`, "
                "`supports`, `loads`, `contacts`, `output`, ...) are described in {doc}`/case_files`.\n")
    parts = ["## The sections of a case file", ""]
    for name, model in sections.items():
        if name == "solver":
            continue   # (above, per method)
        parts.append(model_markdown(f"`{name}`", model))
    return "\n".join(parts)


def reference_markdown() -> str:
    """The whole generated reference, as Markdown (MyST)."""
    return "\n".join([
        "<!-- Generated by docs/_ext/case_reference.py when the site is built: do not edit. -->", "",
        solver_markdown(), laws_markdown(), sections_markdown()])


def write(path: Path = GENERATED) -> bool:
    """Write the reference into ``path`` when it changed (so that Sphinx rebuilds only then)."""
    text = reference_markdown()
    if path.is_file() and path.read_text() == text:
        return False
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return True


def _generate(app) -> None:
    write()


def setup(app):
    app.connect("builder-inited", _generate)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    print(reference_markdown())
