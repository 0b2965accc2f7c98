"""A checkpoint on disk: its folder and files, the format version, the digest that ties each rank's file
to ``state.json``, and a state tree written to and read from an HDF5 group."""

from __future__ import annotations

import hashlib
import json

import numpy as np

FORMAT = 2
FOLDER = "checkpoint"
STATE = "state.json"
PARTS = ("integrator", "fields", "watch", "impacts")   # (and "motion" with moving supports)


def _digest(meta: dict) -> str:
    """A digest of state.json's content (not its layout): each rank file carries it."""
    return hashlib.sha256(json.dumps(meta, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


# A state tree (``state.capture``'s) in an HDF5 group: arrays as datasets, numbers and strings as
# attributes, nested values as subgroups that name their kind.
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
