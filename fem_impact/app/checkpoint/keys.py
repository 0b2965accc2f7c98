"""What a run's state depends on, as flat dotted keys (the model's, the loads'), and the differences a
restart names; the load of a run restarted under other loads."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from ...integrators.parameters import REDUCED


# Solver keys a restart applies: the end, and whether steps are taken in blocks (the same results).
APPLIED_SOLVER_KEYS = ("t_end", "blocks")
# The reduced model's choice of modes: compared as the count it made (``modes`` of state.json).
MODE_KEYS = ("modes", "tolerance")
MODEL_SECTIONS = ("mesh", "material", "materials", "damping", "initial", "supports", "contacts", "bodies", "solver")


def model_keys(case) -> dict:
    """What a run's state depends on, as flat dotted keys: the case's mesh (a mesh file by its
    content), material(s), damping, initial state, supports, contacts, the method and its keys,
    and the parameters their expressions use. A restart must find every one of them unchanged."""
    data = case.resolved()
    out: dict = {}
    for section in MODEL_SECTIONS:
        if section in data:
            _flatten(data[section], section, out)
    for key in APPLIED_SOLVER_KEYS + MODE_KEYS:
        out.pop(f"solver.{key}", None)
    for name in case.body_blocks:   # (a modal body's blocks: how its scene is stepped, the same results)
        out.pop(f"bodies.{name}.blocks", None)
    if case.mesh.file is not None:
        out["mesh.file"] = "sha256:" + _file_digest(case.mesh.file)
    expressions = [e for item in case.initial.displacement + case.initial.velocity for e in item.value]
    expressions += [e for s in case.supports for e in (s.displacement or ())]
    expressions += [e for c in case.contacts for e in (c.motion or ())]
    for name in _parameters_of(case, expressions):
        out[f"parameters.{name}"] = case.parameters[name]
    return out


def load_keys(case) -> dict:
    """The loads and the parameters they use, as flat dotted keys: time inputs, which a restart applies
    from the checkpoint's time on (a parameter the model uses too is also in ``model_keys``)."""
    out: dict = {}
    _flatten(case.resolved()["loads"], "loads", out)
    expressions = [e for load in case.loads
                   for e in [*(load.force or ()), *(load.acceleration or ()), *(load.traction or ())]]
    for name in _parameters_of(case, expressions):
        out[f"parameters.{name}"] = case.parameters[name]
    return out


def unknowns_keys(model: dict, reduced: bool) -> dict:
    """The part of ``model_keys`` that decides what the unknowns are (``initial: {from: ...}`` needs
    them alike): the method family, the mesh; for the reduced model also what its modes depend on."""
    scene = ("mesh.",) + (("material.", "materials.", "solver.mass", "supports.") if reduced else ())
    out = {key: value for key, value in model.items() if key.startswith(scene)}
    out["solver.method"] = REDUCED if reduced else "a full model's"
    return out


def _parameters_of(case, expressions) -> list[str]:
    used = set()
    for expr in expressions:
        used |= getattr(expr, "constants", frozenset())
    return sorted(name for name in used if name in case.parameters)


def _flatten(value, key: str, out: dict) -> None:
    if isinstance(value, dict) and value:
        for name, item in value.items():
            _flatten(item, f"{key}.{name}", out)
    elif isinstance(value, (list, tuple)) and value:
        for i, item in enumerate(value):
            _flatten(item, f"{key}.{i}", out)
    else:
        out[key] = list(value) if isinstance(value, tuple) else value


def _file_digest(path) -> str:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return "unreadable"


def differing(saved: dict, now: dict) -> list[str]:
    """The keys whose values differ between two of ``model_keys``' (or ``load_keys``') dicts."""
    keys = list(now) + [k for k in saved if k not in now]
    # (an empty list on one side, its items on the other: the items name the change)
    expanded = lambda key, other: any(k.startswith(key + ".") for k in other)   # noqa: E731
    return [key for key in keys if not _same(saved.get(key, _MISSING), now.get(key, _MISSING))
            and not (key not in now and expanded(key, now)) and not (key not in saved and expanded(key, saved))]


def differences(saved: dict, now: dict) -> list[str]:
    """The keys whose values differ, each with both values: ``key (checkpoint SAVED, case NOW)``."""
    out = []
    for key in differing(saved, now):
        a, b = saved.get(key, _MISSING), now.get(key, _MISSING)
        if key == "mesh.file" and a is not _MISSING and b is not _MISSING:
            out.append(f"{key} (the mesh file's content)")
        else:
            out.append(f"{key} (checkpoint {_shown(a)}, case {_shown(b)})")
    return out


class ChangedLoad:
    """The load of a run restarted under other loads: evaluated at every step's end, so that the step from
    the checkpoint's time starts from the load the saved run had there (its state) and ends with the case's.
    (Any other attribute is the case's load's.)"""

    time_dependent = True

    def __init__(self, load):
        self.load = load

    def evaluate(self, t: float, out: np.ndarray) -> np.ndarray:
        return self.load.evaluate(t, out)

    def __getattr__(self, name):
        return getattr(self.load, name)


_MISSING = object()


def _same(a, b) -> bool:
    if isinstance(a, bool) or isinstance(b, bool) or a is None or b is None or a is _MISSING or b is _MISSING:
        return a is b or (type(a) is type(b) and a == b)
    return a == b


def _shown(value) -> str:
    if value is _MISSING:
        return "none"
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= 40 else f"{text[:30]}...{text[-6:]}"
