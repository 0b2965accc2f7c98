"""Checkpoints: a run's whole state on disk, to continue it later (``fem-impact run CASE --restart DIR``).

A checkpoint is a folder ``checkpoint/`` in the run's output folder (README.md, "Checkpoint and
restart"):

- ``state.json``: what the state belongs to and where it stands: ``format``, ``t``, ``step``,
  ``ranks``, ``case``, ``method``, ``scheme``, ``dt``, ``dofs``, ``fem_impact_version``;
- ``rank-R.h5`` (HDF5, one per MPI rank: the distributed vectors are each rank's owned entries):
  one group per stateful part of the run (``integrator``, ``motion``, ``fields``, ``watch``,
  ``impacts``); in each, the part's state attributes: arrays as datasets, numbers and strings as
  HDF5 attributes, nested values (the step's state, its energy budget, a pair) as subgroups.

What a part's state is: its attributes that are numbers, strings, None, one-dimensional arrays,
the step's StepState and EnergyBudget, and lists, tuples and string-keyed dicts of these; an
object may name more with ``__checkpoint__`` (a tuple of attribute names: the friction solver's
warm start). Matrices, factors and operators are left out: the restarted run builds them again
from the case, and the checks of ``state.json`` make sure it is the same case. Two attributes
holding one array (the integrator's state vectors and its StepState's) are stored once and
linked again on restore.

A checkpoint is written into ``checkpoint.new/`` and renamed over ``checkpoint/`` when every rank
has written its file: an interruption mid-write leaves the previous one whole.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import shutil
from pathlib import Path

import numpy as np

from .._version import __version__
from ..errors import CaseError
from ..integrators.base import EnergyBudget, StepState

FORMAT = 1
FOLDER = "checkpoint"
_DATACLASSES = {"StepState": StepState, "EnergyBudget": EnergyBudget}
_SCALARS = (bool, int, float, str, np.bool_, np.integer, np.floating)


# -- capture and restore of an object's state -----------------------------------------------
def capture(obj) -> dict:
    """The state of ``obj`` as a tree of plain values (module docstring)."""
    seen: dict[int, str] = {}
    names = list(vars(obj)) + [n for n in getattr(obj, "__checkpoint__", ()) if n not in vars(obj)]
    out = {}
    for name in names:
        value = _capture(getattr(obj, name), name, seen)
        if value is not _SKIP:
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


def restore(obj, state: dict) -> None:
    """Set the attributes of ``obj`` (built again from the same case) from ``capture``'s tree."""
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

    built = {name: build(value, name) for name, value in state.items()}
    for name, value in built.items():
        if isinstance(value, tuple) and value and value[0] == "object":
            target = getattr(obj, name)
            for k, v in value[1].items():
                setattr(target, k, v)
        else:
            setattr(obj, name, value)
    # Links: a path "a.b.c" names an attribute, a dataclass field or a sequence's item.
    for path, source in pending:
        _set_path(obj, path, arrays[source] if source in arrays else _get_path(obj, source))


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
    elif isinstance(value, np.ndarray):
        group.create_dataset(name, data=value)
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
            image = io.BytesIO()
            with h5py.File(image, "w") as f:
                f.attrs["format"] = FORMAT
                if self.dof_keys is not None:
                    f.create_dataset("dof_keys", data=self.dof_keys)
                for name, part in self.parts.items():
                    _write(f.create_group(name), capture(part))
            with open(path, "wb") as out:
                out.write(image.getbuffer())
        except OSError as err:
            error = _error_of(err, path)
        _raise_any(next((e for e in comm.allgather(error) if e is not None), None))
        if comm.rank == 0:
            try:
                meta = dict(self.meta, format=FORMAT, t=state.t, step=state.step, ranks=comm.size,
                            fem_impact_version=__version__)
                try:
                    (new / "state.json").write_text(json.dumps(meta, indent=2) + "\n")
                except OSError as err:
                    raise OSError(err.errno, err.strerror, str(new / "state.json")) from None
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
        if (folder / "state.json").is_file():
            return folder
    raise CaseError(f"{option} {path}", None, None, f"no checkpoint there (neither {path / FOLDER / 'state.json'} "
                    f"nor {path / 'state.json'}); a run saves one at its end and every output.checkpoint_every steps")


def initial_state(path, comm, meta: dict, U0, V0, dof_keys=None):
    """(U, V) of the saved run at ``path``: its integrator's state vectors (nodal values, or the reduced
    model's modal coordinates), for a run that starts where it ended (``initial: {from: DIR}``). The time
    step and the loads may differ; the unknowns (method family, mesh, modes) and the ranks must not."""
    saved, parts = load(path, comm, meta, keys=("dofs",), option="initial.from", dof_keys=dof_keys)
    state = parts["integrator"]
    U, V = state["U"], state["V"]
    size = np.asarray(U0.array_r if hasattr(U0, "array_r") else U0).size
    if U.size != size:
        raise CaseError(f"initial.from {find(path)}", None, None,
                        f"its state has {U.size} unknowns on this rank, the case {size} (another mesh, method or "
                        "count of modes)")
    return U.copy(), V.copy()


def load(path, comm, meta: dict, keys=("method", "scheme", "dt", "dofs"), option="--restart",
         dof_keys: np.ndarray | None = None) -> tuple[dict, dict]:
    """(state.json, this rank's parts) of the checkpoint at ``path``, checked against the run's ``meta``."""
    import h5py

    folder = find(path, option)
    saved = json.loads((folder / "state.json").read_text())
    problems = []
    if saved.get("format") != FORMAT:
        problems.append(f"format {saved.get('format')} (this version reads {FORMAT})")
    if saved.get("ranks") != comm.size:
        problems.append(f"it was written on {saved.get('ranks')} MPI rank(s), this run has {comm.size}: restart "
                        f"with the same count")
    for key in keys:
        if saved.get(key) != meta.get(key):
            problems.append(f"its {key} is {saved.get(key)!r}, the case's {meta.get(key)!r}")
    if problems:
        raise CaseError(f"{option} {folder}", None, None, "the checkpoint does not fit this case: " + "; ".join(problems))
    with h5py.File(folder / f"rank-{comm.rank}.h5", "r") as f:
        parts = {name: _read(f[name]) for name in f if name != "dof_keys"}
        keys = f["dof_keys"][()] if "dof_keys" in f else None
    if dof_keys is not None and keys is not None and not np.array_equal(keys, dof_keys):
        parts = _redistributed(folder, saved["ranks"], parts, dof_keys)
    return saved, parts


def _redistributed(folder: Path, ranks: int, mine: dict, dof_keys: np.ndarray) -> dict:
    """This rank's parts when the mesh was distributed otherwise than in the saved run (the partitioner
    numbers nodes its own way each time): every vector of owned dofs is gathered from all ranks' files
    by the dofs' partition-independent numbers. (Each rank reads every file: N values a rank, once.)"""
    import h5py

    trees, keys = [], []
    for r in range(ranks):
        with h5py.File(folder / f"rank-{r}.h5", "r") as f:
            trees.append({name: _read(f[name]) for name in f if name != "dof_keys"})
            keys.append(f["dof_keys"][()])
    all_keys = np.concatenate(keys)
    order = np.argsort(all_keys, kind="stable")
    where = order[np.minimum(np.searchsorted(all_keys[order], dof_keys), all_keys.size - 1)]
    if not np.array_equal(all_keys[where], dof_keys):
        raise CaseError(f"checkpoint {folder}", None, None, "its dofs are not this case's (another mesh?)")

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

    return {name: remap([t[name] for t in trees], (name,)) for name in mine}
