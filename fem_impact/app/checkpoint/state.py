"""An object's declared state (``__checkpoint__``): captured as a tree of plain values, checked against
the object built again from the case, and restored into it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ...integrators.state import StepState
from ...mechanics.energy import EnergyBudget
from .keys import _shown

_DATACLASSES = {"StepState": StepState, "EnergyBudget": EnergyBudget}
_SCALARS = (bool, int, float, str, np.bool_, np.integer, np.floating)


def capture(obj) -> dict:
    """The state of ``obj``, the attributes its ``__checkpoint__`` names, as a tree of plain values."""
    seen: dict[int, str] = {}
    out = {}
    for name in obj.__checkpoint__:
        value = _capture(getattr(obj, name), name, seen)
        if value is _SKIP:
            raise TypeError(f"{type(obj).__name__}.{name} is declared as state but cannot be saved "
                            f"({type(getattr(obj, name)).__name__})")
        out[name] = value
    return out


_SKIP = object()


def _capture(value, path: str, seen: dict):
    if value is None or isinstance(value, _SCALARS):
        return value.item() if isinstance(value, np.generic) else value
    if isinstance(value, np.ndarray):
        if value.ndim > 1 or value.dtype.kind not in "biuf":
            return _SKIP
        if id(value) in seen:
            return ("alias", seen[id(value)])
        seen[id(value)] = path
        return value.copy()
    if type(value).__name__ in _DATACLASSES and dataclasses.is_dataclass(value):
        fields = {}
        for f in dataclasses.fields(value):
            item = _capture(getattr(value, f.name), f"{path}.{f.name}", seen)
            fields[f.name] = None if item is _SKIP else item
        return ("dataclass", type(value).__name__, fields)
    if isinstance(value, (list, tuple)):
        items = [_capture(v, f"{path}.{i}", seen) for i, v in enumerate(value)]
        return _SKIP if any(i is _SKIP for i in items) else ("list" if isinstance(value, list) else "tuple", items)
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            return _SKIP
        items = {k: _capture(v, f"{path}.{k}", seen) for k, v in value.items()}
        return _SKIP if any(i is _SKIP for i in items.values()) else ("dict", items)
    if hasattr(value, "__checkpoint__"):
        return ("object", {n: _capture(getattr(value, n), f"{path}.{n}", seen) for n in value.__checkpoint__})
    return _SKIP


def check(obj, state: dict) -> None:
    """Raise ValueError, naming the attribute, when ``state`` (``capture``'s tree, as read back) does not
    fit ``obj`` (built from the case, started): a declared attribute missing, an array of another length,
    a value of another kind. ``restore`` then sets every attribute."""
    links = []

    def fits(template, value, path):
        if isinstance(value, tuple) and value and value[0] == "alias":
            if len(value) != 2 or not isinstance(value[1], str):
                raise ValueError(f"{path}: a link to nothing")
            links.append((path, value[1]))
            return
        if template is None:
            if isinstance(value, tuple) and value and value[0] == "object":
                raise ValueError(f"{path}: saved with state, this case has none")
            return
        if isinstance(template, np.ndarray):
            if not isinstance(value, np.ndarray) or value.ndim != 1 or value.dtype.kind not in "biuf":
                raise ValueError(f"{path}: {_kind(value)}, not an array")
            if value.shape != template.shape:
                raise ValueError(f"{path}: {value.size} values, this case's has {template.size}")
            if value.dtype != template.dtype:
                raise ValueError(f"{path}: values of type {value.dtype}, not {template.dtype}")
            return
        if isinstance(template, (bool, np.bool_)):
            if not isinstance(value, (bool, np.bool_)):
                raise ValueError(f"{path}: {_kind(value)}, not true or false")
            return
        if isinstance(template, (int, float, np.integer, np.floating)):
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise ValueError(f"{path}: {_kind(value)}, not a number")
            if isinstance(template, (int, np.integer)) and not isinstance(value, (int, np.integer)):
                raise ValueError(f"{path}: {_kind(value)}, not an integer")
            if not math.isfinite(value) and math.isfinite(template):
                raise ValueError(f"{path}: {value}, not a finite number")
            return
        if isinstance(template, str):
            if not isinstance(value, str):
                raise ValueError(f"{path}: {_kind(value)}, not a string")
            return
        if dataclasses.is_dataclass(template):
            if not (isinstance(value, tuple) and len(value) == 3 and value[0] == "dataclass"
                    and value[1] == type(template).__name__ and isinstance(value[2], dict)):
                raise ValueError(f"{path}: {_kind(value)}, not a {type(template).__name__}")
            names = {f.name for f in dataclasses.fields(template)}
            if set(value[2]) - names:
                raise ValueError(f"{path}: holds {', '.join(sorted(set(value[2]) - names))}, which it has not")
            for f in dataclasses.fields(template):
                if f.name not in value[2]:
                    if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING:
                        continue   # a field added since the checkpoint was written: its default
                    raise ValueError(f"{path}.{f.name}: missing")
                fits(getattr(template, f.name), value[2][f.name], f"{path}.{f.name}")
            return
        if isinstance(template, (list, tuple, dict)):
            kind = "dict" if isinstance(template, dict) else "list" if isinstance(template, list) else "tuple"
            if not (isinstance(value, tuple) and len(value) == 2 and value[0] == kind):
                raise ValueError(f"{path}: {_kind(value)}, not a {kind}")
            return
        if hasattr(template, "__checkpoint__"):
            if not (isinstance(value, tuple) and len(value) == 2 and value[0] == "object"
                    and isinstance(value[1], dict)):
                raise ValueError(f"{path}: {_kind(value)}, not a saved object")
            if set(value[1]) - set(template.__checkpoint__):
                raise ValueError(f"{path}: holds {', '.join(sorted(set(value[1]) - set(template.__checkpoint__)))}, "
                                 "which it has not")
            for name in template.__checkpoint__:
                if name not in value[1]:
                    raise ValueError(f"{path}.{name}: missing")
                fits(getattr(template, name), value[1][name], f"{path}.{name}")

    for name in obj.__checkpoint__:
        if name not in state:
            if name in getattr(obj, "__checkpoint_added__", ()):
                continue   # declared since the checkpoint was written: it keeps the value the case built
            raise ValueError(f"{name}: missing")
        fits(getattr(obj, name), state[name], name)
    arrays = set(_array_paths(state))
    for path, source in links:
        if source not in arrays:
            raise ValueError(f"{path}: a link to {source}, which the state does not hold as an array")


def _array_paths(tree, prefix: str = ""):
    """The dotted paths of the arrays in ``capture``'s tree (what a link may name)."""
    items = tree.items() if isinstance(tree, dict) else ()
    for name, value in items:
        path = f"{prefix}{name}"
        if isinstance(value, np.ndarray):
            yield path
        elif isinstance(value, tuple) and value and value[0] in ("dataclass", "dict", "object") \
                and isinstance(value[-1], dict):
            yield from _array_paths(value[-1], path + ".")
        elif isinstance(value, tuple) and len(value) == 2 and value[0] in ("list", "tuple") \
                and isinstance(value[1], list):
            yield from _array_paths(dict(zip(map(str, range(len(value[1]))), value[1])), path + ".")


def _kind(value) -> str:
    if isinstance(value, tuple) and value and isinstance(value[0], str):
        return f"a {value[0]}"
    if isinstance(value, np.ndarray):
        return f"an array of {value.shape} {value.dtype}"
    return "nothing" if value is None else f"{type(value).__name__} {_shown(value)}"


def restore(obj, state: dict) -> None:
    """Set the declared attributes of ``obj`` (built again from the case) from ``capture``'s tree
    (``check``ed first)."""
    arrays: dict[str, np.ndarray] = {}
    pending: list = []
    written: set[int] = set()

    def build(value, path):
        if isinstance(value, np.ndarray):
            # Into the object's own array where it has one (its own or a part's: an attribute of objects
            # with state all the way): an integrator's vectors are known to its algebra by identity
            # (PETSc vectors over them), and swapped in pairs by reference.
            existing = _own_array(obj, path)
            if isinstance(existing, np.ndarray) and existing.shape == value.shape and \
                    existing.dtype == value.dtype and id(existing) not in written:
                np.copyto(existing, value)
                written.add(id(existing))
                arrays[path] = existing
            else:
                arrays[path] = value.copy()
            return arrays[path]
        if not isinstance(value, tuple):
            return value
        kind = value[0]
        if kind == "alias":
            pending.append((path, value[1]))
            return None
        if kind == "dataclass":
            _, cls, fields = value
            return _DATACLASSES[cls](**{k: build(v, f"{path}.{k}") for k, v in fields.items()})
        if kind in ("list", "tuple"):
            items = [build(v, f"{path}.{i}") for i, v in enumerate(value[1])]
            return items if kind == "list" else tuple(items)
        if kind == "dict":
            return {k: build(v, f"{path}.{k}") for k, v in value[1].items()}
        if kind == "object":
            return _Part({k: build(v, f"{path}.{k}") for k, v in value[1].items()})
        raise ValueError(f"unknown entry {kind!r}")

    def put(target, name, value):
        if isinstance(value, _Part):   # a part's state: into the part the case built, attribute by attribute
            part = getattr(target, name)
            for k, v in value.items():
                put(part, k, v)
        else:
            setattr(target, name, value)

    built = {name: build(state[name], name) for name in obj.__checkpoint__ if name in state}
    for name, value in built.items():
        put(obj, name, value)
    # Links: a path "a.b.c" names an attribute, a dataclass field or a sequence's item.
    for path, source in pending:
        try:
            target = arrays[source] if source in arrays else _get_path(obj, source)
        except (AttributeError, KeyError, IndexError, TypeError, ValueError):
            raise ValueError(f"{path}: a link to {source}, which the state does not hold") from None
        if not isinstance(target, np.ndarray):
            raise ValueError(f"{path}: a link to {source}, which is not an array")
        _set_path(obj, path, target)


class _Part(dict):
    """A part's restored attributes (restore: set into the part itself, not in its place)."""


def _own_array(obj, path: str):
    """The array at ``path`` ("U", "part.U") where every step before it is an object with state, else None."""
    *parts, last = path.split(".")
    for part in parts:
        obj = getattr(obj, part, None)
        if not hasattr(obj, "__checkpoint__"):
            return None
    return getattr(obj, last, None)


def _get_path(obj, path: str):
    for part in path.split("."):
        obj = obj[int(part)] if isinstance(obj, (list, tuple)) else obj[part] if isinstance(obj, dict) \
            else getattr(obj, part)
    return obj


def _set_path(obj, path: str, value) -> None:
    head, _, last = path.rpartition(".")
    parent = _get_path(obj, head) if head else obj
    if isinstance(parent, list):
        parent[int(last)] = value
    elif isinstance(parent, dict):
        parent[last] = value
    elif isinstance(parent, tuple):
        raise ValueError(f"cannot link {path}: inside a tuple")
    else:
        setattr(parent, last, value)
