"""Checkpoints: a run's whole state on disk, to continue it later (``fem-impact run CASE --restart DIR``).

A checkpoint is a folder ``checkpoint/`` in the run's output folder (README.md, "Checkpoint and
restart"):

- ``state.json``: where the state stands (``format``, ``t``, ``step``, ``ranks``) and what it
  depends on: ``model``, the case's keys that define the model, its constraints, the method and
  its keys, the initial state and the parameters these use (flat, dotted keys: what a restart
  compares), ``loads``, the loads and the parameters they use (what a restart may change), and
  ``dofs`` and ``modes`` (the reduced model's count, which ``modes: auto`` chose);
- ``rank-R.h5`` (HDF5, one per MPI rank: the distributed vectors are each rank's owned entries):
  its rank, the checkpoint's ``t``, ``step`` and a digest of ``state.json`` (a file of another
  checkpoint, or an edited ``state.json``, is refused), and one group per stateful part of the run
  (``integrator``, ``motion``, ``fields``, ``watch``, ``impacts``) with that part's state: arrays
  as datasets, numbers and strings as HDF5 attributes, nested values (the step's state, its energy
  budget, a pair) as subgroups.

What a part's state is, it declares: ``__checkpoint__``, the names of its attributes that carry the
run from step to step (the state vectors and the products the next step reads, the step's
StepState and EnergyBudget, a solver's warm start, an impact under way). Everything else (matrices,
factors, the load's vectors, the method's constants) the restarted run builds from its case, which
``state.json``'s ``model`` must match key by key: a restart applies the case's loads (from the
checkpoint's time on: the step from it starts from the load the saved run had there), its
``solver.t_end``, ``solver.blocks`` and ``output``, and refuses a change of anything else, naming
every key that differs. Two attributes holding one array (the integrator's state vectors and its
StepState's) are stored once and linked again on restore.

A checkpoint that cannot be read (a file missing, truncated, not what it should hold) is refused in
one line naming the file; under MPI every rank checks its own files and the ranks agree before any
of them goes on.

A checkpoint is written into ``checkpoint.new/`` and renamed over ``checkpoint/`` when every rank
has written its file: an interruption mid-write leaves the previous one whole.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import math
import os
import shutil
from pathlib import Path

import numpy as np

from .._version import __version__
from ..errors import CaseError
from ..integrators.state import StepState
from ..mechanics.energy import EnergyBudget
from ..integrators.parameters import REDUCED

FORMAT = 2
FOLDER = "checkpoint"
STATE = "state.json"
PARTS = ("integrator", "fields", "watch", "impacts")   # (and "motion" with moving supports)
_DATACLASSES = {"StepState": StepState, "EnergyBudget": EnergyBudget}
_SCALARS = (bool, int, float, str, np.bool_, np.integer, np.floating)


class Damaged(Exception):
    """A checkpoint's file that does not hold what it should: ``file`` and what is wrong with it."""

    def __init__(self, file, message: str):
        super().__init__(f"{file}: {message}")
        self.file, self.message = str(file), message


# -- what a run's state depends on ------------------------------------------------------------
# Solver keys a restart applies: the end, and whether steps are taken in blocks (the same results).
APPLIED_SOLVER_KEYS = ("t_end", "blocks")
# The reduced model's choice of modes: compared as the count it made (``modes`` of state.json).
MODE_KEYS = ("modes", "tolerance")
MODEL_SECTIONS = ("mesh", "material", "materials", "damping", "initial", "supports", "contacts", "solver")


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
    if case.mesh.file is not None:
        out["mesh.file"] = "sha256:" + _file_digest(case.mesh.file)
    expressions = [e for item in case.initial.displacement + case.initial.velocity for e in item.value]
    expressions += [e for s in case.supports for e in (s.displacement or ())]
    for name in _parameters_of(case, expressions):
        out[f"parameters.{name}"] = case.parameters[name]
    return out


def load_keys(case) -> dict:
    """The loads and the parameters they use, as flat dotted keys: time inputs, which a restart applies
    from the checkpoint's time on (a parameter the model uses too is also in ``model_keys``)."""
    out: dict = {}
    _flatten(case.resolved()["loads"], "loads", out)
    expressions = [e for load in case.loads for e in [*(load.force or ()), *(load.acceleration or ())]]
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


def _digest(meta: dict) -> str:
    """A digest of state.json's content (not its layout): each rank file carries it."""
    return hashlib.sha256(json.dumps(meta, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


# -- capture and restore of an object's state -----------------------------------------------
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
            # Into the object's own array where it has one: an integrator's vectors are known to its
            # algebra by identity (PETSc vectors over them), and swapped in pairs by reference.
            existing = getattr(obj, path, None) if "." not in path else None
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
            return ("object", {k: build(v, f"{path}.{k}") for k, v in value[1].items()})
        raise ValueError(f"unknown entry {kind!r}")

    built = {name: build(state[name], name) for name in obj.__checkpoint__}
    for name, value in built.items():
        if isinstance(value, tuple) and value and value[0] == "object":
            target = getattr(obj, name)
            for k, v in value[1].items():
                setattr(target, k, v)
        else:
            setattr(obj, name, value)
    # Links: a path "a.b.c" names an attribute, a dataclass field or a sequence's item.
    for path, source in pending:
        try:
            target = arrays[source] if source in arrays else _get_path(obj, source)
        except (AttributeError, KeyError, IndexError, TypeError, ValueError):
            raise ValueError(f"{path}: a link to {source}, which the state does not hold") from None
        if not isinstance(target, np.ndarray):
            raise ValueError(f"{path}: a link to {source}, which is not an array")
        _set_path(obj, path, target)


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


# -- HDF5 -----------------------------------------------------------------------------------
def _write(group, tree: dict) -> None:
    for name, value in tree.items():
        _write_value(group, name, value)


def _write_value(group, name: str, value) -> None:
    if value is None:
        group.attrs[name] = "__none__"
    elif isinstance(value, np.ndarray):   # (with a checksum: a damaged block of data is found on reading)
        group.create_dataset(name, data=value, fletcher32=bool(value.size))
    elif isinstance(value, tuple):
        kind = value[0]
        sub = group.create_group(name)
        sub.attrs["__kind__"] = kind
        if kind == "alias":
            sub.attrs["source"] = value[1]
        elif kind == "dataclass":
            sub.attrs["__class__"] = value[1]
            _write(sub, value[2])
        elif kind in ("list", "tuple"):
            sub.attrs["__length__"] = len(value[1])
            _write(sub, {str(i): v for i, v in enumerate(value[1])})
        else:   # dict, object
            _write(sub, value[1])
    else:
        group.attrs[name] = value


def _read(group) -> dict:
    out = {}
    for name, value in group.attrs.items():
        if name.startswith("__") and name.endswith("__"):
            continue
        out[name] = None if isinstance(value, str) and value == "__none__" else _plain(value)
    for name, item in group.items():
        if not hasattr(item, "attrs") or "__kind__" not in item.attrs:
            out[name] = np.asarray(item[()])
            continue
        kind = str(item.attrs["__kind__"])
        if kind == "alias":
            out[name] = ("alias", str(item.attrs["source"]))
        elif kind == "dataclass":
            out[name] = ("dataclass", str(item.attrs["__class__"]), _read(item))
        elif kind in ("list", "tuple"):
            items = _read(item)
            out[name] = (kind, [items[str(i)] for i in range(int(item.attrs["__length__"]))])
        else:
            out[name] = (kind, _read(item))
    return out


def _plain(value):
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.generic):
        return value.item()
    return value


# -- the run's checkpoints ------------------------------------------------------------------
class Checkpoints:
    """An observer that saves the run's parts every ``every`` steps (0: at the end only) and at the end."""

    def __init__(self, folder: Path, comm, parts: dict, meta: dict, every: int, last_step: int,
                 dof_keys: np.ndarray | None = None):
        self.folder, self.comm, self.parts, self.meta = Path(folder), comm, parts, meta
        self.dof_keys = dof_keys   # the owned dofs' partition-independent numbers (the full model's vectors)
        self.every, self.last_step = every, last_step
        self.saved_at: float | None = None

    def _due(self, step: int) -> bool:
        return step == self.last_step or bool(self.every and step % self.every == 0 and step)

    def write(self, state: StepState) -> None:
        if self._due(state.step):
            self.save(state)

    def next_stop(self, step: int) -> int:
        """The next step after ``step`` at which a checkpoint is saved: no block of steps runs past it."""
        if not self.every:
            return self.last_step
        return min(self.last_step, (step // self.every + 1) * self.every)

    def write_block(self, block) -> None:
        """After a block (integrators/blocks.py), the integrator holds its last step: saved when due."""
        if self._due(int(block.step[-1])):
            self.save(block.state(len(block) - 1))

    def save(self, state: StepState) -> None:
        """Write the state into ``checkpoint.new/`` and rename it over ``checkpoint/`` once every rank's file is
        there. A write that fails (a full disk) raises the same OSError, naming the file, on every rank: each
        rank's HDF5 file is made in memory and written as plain bytes, so that HDF5 never holds a file it
        cannot write (its failed close leaves the process to crash at exit)."""
        import h5py

        comm = self.comm
        new, final = self.folder / f"{FOLDER}.new", self.folder / FOLDER
        meta = json.loads(json.dumps(dict(self.meta, format=FORMAT, t=float(state.t), step=int(state.step),
                                          ranks=comm.size, fem_impact_version=__version__)))
        error = None
        if comm.rank == 0:
            try:
                shutil.rmtree(new, ignore_errors=True)
                new.mkdir(parents=True)
            except OSError as err:
                error = _error_of(err, new)
        _raise_any(comm.bcast(error, root=0))
        path = new / f"rank-{comm.rank}.h5"
        try:
            # Made in memory, written as plain bytes: on a full disk h5py's own write fails midway and its
            # close fails again at exit.
            image = io.BytesIO()
            with h5py.File(image, "w") as f:
                f.attrs.update(format=FORMAT, rank=comm.rank, ranks=comm.size, t=meta["t"], step=meta["step"],
                               state_digest=_digest(meta))
                if self.dof_keys is not None:
                    f.create_dataset("dof_keys", data=self.dof_keys, fletcher32=bool(self.dof_keys.size))
                for name, part in self.parts.items():
                    _write(f.create_group(name), capture(part))
            with open(path, "wb") as out:
                out.write(image.getbuffer())
        except OSError as err:
            error = _error_of(err, path)
        _raise_any(next((e for e in comm.allgather(error) if e is not None), None))
        if comm.rank == 0:
            try:
                try:
                    (new / STATE).write_text(json.dumps(meta, indent=2) + "\n")
                except OSError as err:
                    raise OSError(err.errno, err.strerror, str(new / STATE)) from None
                old = self.folder / f"{FOLDER}.old"
                if final.exists():
                    os.rename(final, old)
                os.rename(new, final)
                shutil.rmtree(old, ignore_errors=True)
            except OSError as err:
                error = _error_of(err, new)
        _raise_any(comm.bcast(error, root=0))
        self.saved_at = state.t


def _error_of(err: OSError, path: Path) -> tuple:
    """An OSError as plain data (to send to every rank), naming ``path`` when it names no file."""
    return (err.errno, err.strerror or str(err), os.fsdecode(err.filename) if err.filename is not None else str(path))


def _raise_any(error) -> None:
    if error is not None:
        raise OSError(*error)


def find(path, option: str = "--restart") -> Path:
    """The checkpoint folder of ``path``: a run's output folder, or the checkpoint folder itself."""
    path = Path(path)
    for folder in (path / FOLDER, path):
        if (folder / STATE).is_file():
            return folder
    raise Damaged(path, f"no checkpoint there (neither {path / FOLDER / STATE} nor {path / STATE}"
                        f"{'' if path.is_dir() else ': no such folder'}); a run saves one at its end and every "
                        f"output.checkpoint_every steps")


# -- reading a checkpoint: every file checked, the ranks agreeing --------------------------
class Saved:
    """A checkpoint whose ``state.json`` was read and checked: its ``folder`` and ``state`` (the dict)."""

    def __init__(self, folder: Path, state: dict):
        self.folder, self.state = folder, state

    @property
    def t(self) -> float:
        return self.state["t"]

    @property
    def step(self) -> int:
        return self.state["step"]


def agree(comm, problem: Damaged | None) -> None:
    """Raise the first problem any rank found (in rank order), on every rank: one collective call, which every
    rank makes, so that no rank goes on (or waits) while another stops."""
    found = comm.allgather(None if problem is None else (problem.file, problem.message)) if comm.size > 1 \
        else [None if problem is None else (problem.file, problem.message)]
    first = next((p for p in found if p is not None), None)
    if first is not None:
        raise Damaged(*first)


def open_checkpoint(path, comm) -> Saved:
    """The checkpoint at ``path`` with its state.json read and checked on every rank (Damaged: the
    file and what is wrong, the same on every rank)."""
    problem, saved = None, None
    try:
        folder = find(path)
        saved = Saved(folder, _read_state(folder / STATE, comm))
    except Damaged as err:
        problem = err
    agree(comm, problem)
    return saved


# state.json's keys: (what they must be, a check)
_STATE_KEYS = {
    "t": ("a time >= 0", lambda v: _is_real(v) and math.isfinite(v) and v >= 0.0),
    "step": ("a step count >= 0", lambda v: _is_int(v) and v >= 0),
    "ranks": ("a count of ranks >= 1", lambda v: _is_int(v) and v >= 1),
    "model": ("a mapping of keys", lambda v: isinstance(v, dict)),
    "loads": ("a mapping of keys", lambda v: isinstance(v, dict)),
    "dofs": ("a count of dofs >= 1", lambda v: _is_int(v) and v >= 1),
    "modes": ("a count of modes or null", lambda v: v is None or (_is_int(v) and v >= 1)),
}


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _read_state(file: Path, comm) -> dict:
    try:
        text = file.read_bytes().decode("utf-8")
        state = json.loads(text)
    except OSError as err:
        raise Damaged(file, f"cannot be read ({err.strerror or err})") from None
    except UnicodeDecodeError:
        raise Damaged(file, "is not text: a checkpoint's state.json is JSON (the checkpoint is damaged)") from None
    except (ValueError, RecursionError) as err:   # (RecursionError: nested beyond what Python reads)
        what = "empty" if not text.strip() else f"not valid JSON ({getattr(err, 'msg', err)} at line " \
                                                 f"{getattr(err, 'lineno', '?')}): truncated or damaged"
        raise Damaged(file, f"is {what}; the checkpoint cannot be read") from None
    if not isinstance(state, dict):
        raise Damaged(file, f"holds {_kind(state)}, not a checkpoint's mapping of keys (the checkpoint is damaged)")
    version = state.get("format")
    if version != FORMAT:
        if version == 1:
            raise Damaged(file, "was written by an earlier fem-impact (checkpoint format 1), which did not record "
                                f"what its state depends on; this version reads format {FORMAT}: run the case again")
        raise Damaged(file, f"has format {_shown(version) if 'format' in state else 'none'}: not a checkpoint this "
                            f"version reads (format {FORMAT})")
    for key, (what, ok) in _STATE_KEYS.items():
        if key not in state:
            raise Damaged(file, f"has no '{key}' (the checkpoint is damaged)")
        if not ok(state[key]):
            raise Damaged(file, f"'{key}' is {_shown(state[key])}, not {what} (the checkpoint is damaged or was "
                                "edited)")
    if state["ranks"] != comm.size:
        raise Damaged(file, f"the checkpoint was written on {state['ranks']} MPI rank(s), this run has {comm.size}: "
                            "run with as many")
    return state


def read_parts(saved: Saved, comm, now: dict, dof_keys: np.ndarray | None = None) -> dict:
    """This rank's parts of the checkpoint (``capture``'s trees by part), its files checked against
    state.json and the run's ``now`` (``dofs``, ``modes``: the model it built), every rank agreeing."""
    problem, parts = None, None
    try:
        state, folder = saved.state, saved.folder
        for key, what in (("dofs", "dofs"), ("modes", "modes kept by the reduced model")):
            if state.get(key) != now.get(key):
                hint = (" (modes: auto chooses the count from solver.dt, solver.t_end, output.every and the loads: "
                        f"give solver.modes: {state[key]})" if key == "modes" and state[key] and now.get(key) else "")
                raise Damaged(folder / STATE, f"the checkpoint's model has {state.get(key)} {what}, this case's "
                                              f"{now.get(key)}{hint}")
        parts, keys = _read_rank(folder, comm.rank, state, full=dof_keys is not None)
        if dof_keys is not None and not np.array_equal(keys, dof_keys):
            parts = _redistributed(folder, state, parts, dof_keys)
    except Damaged as err:
        problem = err
    agree(comm, problem)
    return parts


def _read_rank(folder: Path, rank: int, state: dict, full: bool) -> tuple[dict, np.ndarray | None]:
    """(parts, dof keys) of ``rank-R.h5``, checked: it belongs to this checkpoint (its t, step, rank and
    state.json's digest), holds every part, and (``full``) the dofs' numbers."""
    import h5py

    file = folder / f"rank-{rank}.h5"
    if not file.is_file():
        raise Damaged(file, "missing: the checkpoint is incomplete (each MPI rank writes its own file)")
    try:
        with h5py.File(file, "r") as f:
            stamp = {key: _plain(f.attrs[key]) if key in f.attrs else None
                     for key in ("format", "rank", "t", "step", "state_digest")}
            expected = {"format": FORMAT, "rank": rank, "t": state["t"], "step": state["step"],
                        "state_digest": _digest(state)}
            wrong = [key for key in expected if stamp[key] != expected[key]]
            if wrong:
                raise Damaged(file, _mismatch(wrong, stamp, expected))
            missing = [name for name in PARTS if name not in f]
            if missing:
                raise Damaged(file, f"has no {', '.join(missing)} (the checkpoint is damaged)")
            parts = {name: _read(f[name]) for name in f if name != "dof_keys"}
            keys = np.asarray(f["dof_keys"][()]) if "dof_keys" in f else None
    except Damaged:
        raise
    except (OSError, KeyError, ValueError, TypeError, IndexError, AttributeError, RuntimeError) as err:
        raise Damaged(file, f"cannot be read ({type(err).__name__}: {_reason(err)}): the checkpoint is damaged"
                            " (truncated, or not a checkpoint's file)") from None
    if full and (keys is None or keys.ndim != 1 or keys.dtype.kind not in "iu"):
        raise Damaged(file, "has no numbers of its dofs (dof_keys): the checkpoint is damaged")
    step_state = parts["integrator"].get("state")
    if not (isinstance(step_state, tuple) and len(step_state) == 3 and isinstance(step_state[2], dict)
            and step_state[2].get("t") == state["t"] and step_state[2].get("step") == state["step"]):
        raise Damaged(file, "its integrator's state is not at the checkpoint's t and step (the checkpoint is "
                            "damaged)")
    return parts, keys


def _mismatch(wrong: list, stamp: dict, expected: dict) -> str:
    if "format" in wrong or "rank" in wrong:
        return (f"is not this checkpoint's file for rank {expected['rank']} (its format {_shown(stamp['format'])}, "
                f"rank {_shown(stamp['rank'])})")
    if "t" in wrong or "step" in wrong:
        return (f"holds the state at t = {_shown(stamp['t'])} (step {_shown(stamp['step'])}), state.json says "
                f"t = {expected['t']!r} (step {expected['step']}): the files are of different checkpoints, or "
                "state.json was edited")
    return "does not belong to this state.json (another checkpoint's file, or state.json was edited)"


def _reason(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 120 else text[:100] + "..."


def restore_parts(parts: dict, trees: dict, saved: Saved, comm) -> None:
    """Restore each part from its tree, after checking every one fits (Damaged naming the rank's file
    and the attribute), every rank agreeing first."""
    problem = None
    file = saved.folder / f"rank-{comm.rank}.h5"
    for name, part in parts.items():
        try:
            if name not in trees:
                raise ValueError("missing")
            check(part, trees[name])
        except ValueError as err:
            problem = Damaged(file, f"its {name} does not fit this case: {err} (the checkpoint is damaged)")
            break
    agree(comm, problem)
    for name, part in parts.items():
        restore(part, trees[name])


def initial_state(path, comm, model: dict, reduced: bool, now: dict, U0, dof_keys=None):
    """(U, V) of the saved run at ``path``: its integrator's state vectors (nodal values, or the reduced
    model's modal coordinates), for a run that starts where it ended (``initial: {from: DIR}``). The time
    step, the loads, the method and the model's other keys may differ; what the unknowns are (the mesh;
    for the reduced model its modes) and the ranks must not (Damaged: which file, what differs)."""
    saved = open_checkpoint(path, comm)
    differ = differences(unknowns_keys(saved.state["model"], reduced_of(saved.state)),
                         unknowns_keys(model, reduced))
    if differ:
        raise Damaged(saved.folder / STATE, f"its unknowns are not this case's: {', '.join(differ)}")
    parts = read_parts(saved, comm, now, dof_keys)
    size = np.asarray(U0.array_r if hasattr(U0, "array_r") else U0).size
    problem = None
    state = parts.get("integrator", {})
    U, V = state.get("U"), state.get("V")
    if not all(isinstance(x, np.ndarray) and x.ndim == 1 and x.dtype.kind == "f" for x in (U, V)):
        problem = Damaged(saved.folder / f"rank-{comm.rank}.h5", "holds no state vectors U and V (damaged)")
    elif U.size != size or V.size != size:
        problem = Damaged(saved.folder / f"rank-{comm.rank}.h5", f"its state has {U.size} unknowns on this rank, "
                                                                 f"the case {size} (another mesh or count of modes)")
    agree(comm, problem)
    return U.copy(), V.copy()


def reduced_of(state: dict) -> bool:
    """Whether a checkpoint's run was of the reduced model."""
    return state.get("model", {}).get("solver.method") == REDUCED


def _redistributed(folder: Path, state: dict, mine: dict, dof_keys: np.ndarray) -> dict:
    """This rank's parts when the mesh was distributed otherwise than in the saved run (the partitioner
    numbers nodes its own way each time): every vector of owned dofs is gathered from all ranks' files
    by the dofs' partition-independent numbers. (Each rank reads every file: N values a rank, once.)"""
    trees, keys = [], []
    for r in range(state["ranks"]):
        tree, k = _read_rank(folder, r, state, full=True)
        trees.append(tree)
        keys.append(k)
    all_keys = np.concatenate(keys)
    order = np.argsort(all_keys, kind="stable")
    where = order[np.minimum(np.searchsorted(all_keys[order], dof_keys), all_keys.size - 1)]
    if not all_keys.size or not np.array_equal(all_keys[where], dof_keys):
        raise Damaged(folder, "its dofs are not this case's (another mesh?)")

    def remap(values, path):
        first = values[0]
        if isinstance(first, dict):   # a part: its attributes
            return {k: remap([v[k] for v in values], path + (k,)) for k in first}
        if isinstance(first, np.ndarray):
            local = all(v.ndim == 1 and v.size == k.size for v, k in zip(values, keys))
            # (a p-vector the ranks share may have the length of every rank's owned dofs, by chance)
            replicated = len(values) > 1 and all(v.shape == first.shape and np.array_equal(v, first) for v in values)
            if local and not (replicated and first.size):
                return np.concatenate(values)[where]
            return mine_at(path)
        if isinstance(first, tuple) and first and first[0] in ("dataclass", "list", "tuple", "dict", "object"):
            if first[0] == "dataclass":
                return ("dataclass", first[1], {k: remap([v[2][k] for v in values], path + (k,)) for k in first[2]})
            if first[0] in ("list", "tuple"):
                return (first[0], [remap([v[1][i] for v in values], path + (i,)) for i in range(len(first[1]))])
            return (first[0], {k: remap([v[1][k] for v in values], path + (k,)) for k in first[1]})
        return mine_at(path)

    def mine_at(path):
        node = mine
        for part in path:
            node = node[part] if isinstance(node, dict) else (node[2][part] if node[0] == "dataclass" else node[1][part])
        return node

    try:
        return {name: remap([t[name] for t in trees], (name,)) for name in mine}
    except (KeyError, IndexError, TypeError, ValueError):
        raise Damaged(folder, "its rank files do not hold the same parts (the checkpoint is damaged)") from None
