"""Gmsh files: the parametric scripts' helpers (named groups, the format written) and the reader fem-impact uses."""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import gmsh
import numpy as np


def add_named_groups(dim: int, groups: dict[str, list[int]]) -> None:
    """One physical group per name over entities of dimension ``dim`` (top dimension: bodies;
    lower: node groups, as fem-impact reads them)."""
    for name, tags in groups.items():
        gmsh.model.setPhysicalName(dim, gmsh.model.addPhysicalGroup(dim, list(tags)), name)


def structured_quads(surfaces, size: float) -> None:
    """Structured quadrilaterals on the (synchronized) OCC surfaces: each boundary curve divided into elements of
    about ``size``, each surface transfinite and recombined."""
    for surface in surfaces:
        for _, curve in gmsh.model.getBoundary([(2, surface)], oriented=False):
            x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(1, curve)
            gmsh.model.mesh.setTransfiniteCurve(curve, max(1, round(max(x1 - x0, y1 - y0) / size)) + 1)
        gmsh.model.mesh.setTransfiniteSurface(surface)
        gmsh.model.mesh.setRecombine(2, surface)


def write_msh(path) -> Path:
    """Write the current model as MSH 4.1 text (what ``fem_impact.fem.mesh`` reads)."""
    path = Path(path)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.Binary", 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    gmsh.write(str(path))
    return path


def length_option(minimum: float = 0.0, inclusive: bool = False):
    """An argparse ``type`` for a length in m (or another real): finite and above ``minimum`` (or at
    least it, ``inclusive``); what is not is refused naming the option (status 2), never a traceback."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value) or value < minimum or (value == minimum and not inclusive):
            raise argparse.ArgumentTypeError(f"must be a number {'>=' if inclusive else '>'} {minimum:g}, "
                                             f"got {text}")
        return value
    return parse


def output_option(text: str) -> Path:
    """An argparse ``type`` for a mesh script's output: a .msh file (Gmsh picks the format by the
    extension), not a folder."""
    path = Path(text)
    if path.suffix.lower() != ".msh":
        raise argparse.ArgumentTypeError(f"write a .msh file, got {text!r}")
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a folder: give the .msh file to write")
    return path


class ScriptParser(argparse.ArgumentParser):
    """A mesh script's options: a bad one is a single line (``SCRIPT: error: ...; see --help``, status 2),
    not argparse's usage block."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def run_script(parser: argparse.ArgumentParser, build, argv=None):
    """Parse a mesh script's options and ``build(args)``: a ValueError of ``build`` (options that do not
    fit together) is the parser's error, one line naming them (status 2), and no file is written."""
    args = parser.parse_args(argv)
    try:
        return args, build(args)
    except ValueError as err:
        parser.error(str(err))


class MshError(Exception):
    """A mesh file that cannot be read, or holds no mesh fem-impact can use (the message says why)."""


def read_msh(path) -> dict:
    """The mesh of a Gmsh file as arrays (what ``_extract`` returns), read in a child process.

    Gmsh 4.8's reader writes past its buffers when a section's counts disagree with its content
    (a damaged file: double free, abort): in a child process such a crash is a clean error.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise MshError(f"cannot open it ({exc.strerror})") from None
    if size == 0:
        raise MshError("the file is empty")
    # A corrupted heap may also deadlock the reader: minutes for what Gmsh reads in seconds.
    timeout = 120.0 + size / 1e6
    with tempfile.TemporaryDirectory(prefix="fem-impact-msh-") as tmp:
        out = Path(tmp) / "mesh.npz"
        # -P: this file's folder (the package's modules) does not shadow others on sys.path.
        try:
            child = subprocess.run([sys.executable, "-P", __file__, str(path), str(out)], stdin=subprocess.DEVNULL,
                                   capture_output=True, text=True, errors="replace", timeout=timeout)
        except subprocess.TimeoutExpired:
            raise MshError(f"the Gmsh reader did not finish in {timeout:.0f} s: the file is damaged") from None
        if child.returncode < 0:
            raise MshError(f"the Gmsh reader crashed on it (signal {-child.returncode}): the file is damaged")
        if child.returncode != 0 or not out.exists():
            last = (child.stderr.strip().splitlines() or ["no message"])[-1]
            raise MshError(f"the Gmsh reader failed on it (status {child.returncode}: {last})")
        with np.load(out, allow_pickle=False) as arrays:
            data = {key: arrays[key] for key in arrays.files}
    meta = json.loads(str(data.pop("meta")))
    if "error" in meta:
        raise MshError(meta["error"])
    data.update(meta)
    data["node_groups"] = {name: data.pop(f"group{i}") for i, name in enumerate(meta["node_group_names"])}
    return data


def _extract(path: str) -> tuple[dict, dict]:
    """(arrays, meta) of the mesh in ``path``; gmsh must be initialized. Nodes are numbered by
    their position in ``x`` (the file's nodes sorted by tag), the input index of each dolfinx node.

    - ``x`` (n x 3): node coordinates;
    - ``cells`` (n_cells x nodes per cell): the body elements, node numbers in gmsh's local order;
      ``cell_body``: the body tag (physical group) of each;
    - ``group<i>``: the node numbers of the i-th node group (the nodes of the elements of its
      physical group's entities: coincident nodes of another body are not its own);
    - meta: ``dim``, ``element_type`` (gmsh's code), ``bodies`` (name -> tag), ``node_group_names``.
    """
    try:
        gmsh.merge(path)
    except UnicodeDecodeError:   # gmsh's message about bytes it could not read, not text itself
        raise MshError("it holds bytes that are neither MSH text nor MSH binary data") from None
    except Exception as exc:   # gmsh raises plain Exceptions with its own message
        said = str(exc).replace(path, Path(path).name)
        raise MshError(f"gmsh says: {said}" if said else "gmsh stops reading it, without a message") from None
    model = gmsh.model
    tags, coords, _ = model.mesh.getNodes()
    if tags.size == 0:
        raise MshError("it holds no mesh nodes (an empty, truncated or damaged file)")
    by_tag = np.argsort(tags)
    tags, x = tags[by_tag], coords.reshape(-1, 3)[by_tag]
    if np.any(np.diff(tags) == 0):
        raise MshError("two nodes have the same tag")
    if not np.all(np.isfinite(x)):
        raise MshError("a node coordinate is not a finite number")

    def numbers(node_tags: np.ndarray, what: str) -> np.ndarray:
        at = np.minimum(np.searchsorted(tags, node_tags), tags.size - 1)
        if np.any(tags[at] != node_tags):
            raise MshError(f"{what} refers to a node the file does not define")
        return at

    groups = model.getPhysicalGroups()
    if not groups:
        raise MshError("no physical groups (name the bodies and node groups in the .geo/.py script)")
    dim = max(d for d, _ in groups)
    names = {(d, t): model.getPhysicalName(d, t) or f"group_{d}_{t}" for d, t in groups}
    _check_unique_names(names, dim)
    meta = {"dim": dim, "bodies": {}, "node_group_names": []}
    if dim < 1:
        return {"x": x}, meta
    # dolfinx keeps the first dim coordinates: the others must be the same for every node.
    spread = np.ptp(x, axis=0)
    if np.any(spread[dim:] > 1e-12 * max(spread.max(), 1e-300)):
        along = "along x" if dim == 1 else "parallel to the x-y plane"
        raise MshError(f"a {dim}D mesh must lie {along} (its nodes' {'yz'[dim - 1:]} coordinates vary)")
    cells, cell_body, types = [], [], set()
    for d, t in groups:
        if d != dim:
            continue
        name = names[d, t]
        meta["bodies"][name] = t
        count = 0
        for entity in model.getEntitiesForPhysicalGroup(d, t):
            for etype, _, enodes in zip(*model.mesh.getElements(d, entity), strict=True):
                type_name, _, _, per = model.mesh.getElementProperties(etype)[:4]
                types.add((int(etype), type_name))
                cells.append(numbers(enodes, f"an element of body '{name}'").reshape(-1, per))
                cell_body.append(np.full(len(cells[-1]), t, dtype=np.int32))
                count += len(cells[-1])
        if count == 0:
            raise MshError(f"body '{name}' (physical group of dimension {dim}) has no elements (not meshed, "
                           "or the file is damaged)")
    if len(types) > 1:
        raise MshError("its bodies mix element types (" + ", ".join(sorted(n for _, n in types))
                       + "): one type is needed")
    meta["element_type"] = next(iter(types))[0]
    arrays = {"x": x, "cells": np.concatenate(cells), "cell_body": np.concatenate(cell_body)}
    in_bodies = np.zeros(len(tags), dtype=bool)
    in_bodies[arrays["cells"]] = True
    for d, t in groups:
        if d == dim:
            continue
        name = names[d, t]
        group = np.unique(numbers(model.mesh.getNodesForPhysicalGroup(d, t)[0], f"node group '{name}'"))
        if not np.all(in_bodies[group]):
            raise MshError(f"node group '{name}' has nodes that no body's element holds")
        arrays[f"group{len(meta['node_group_names'])}"] = group
        meta["node_group_names"].append(name)
    return arrays, meta


def _check_unique_names(names: dict, dim: int) -> None:
    """Bodies (groups of the top dimension) and node groups (the lower ones) are looked up by name:
    two groups of one kind with the same name would be one of them silently (MshError)."""
    for kind, same_kind in (("bodies", lambda d: d == dim), ("node groups", lambda d: d < dim)):
        seen: dict[str, tuple[int, int]] = {}
        for (d, t), name in sorted(names.items()):
            if not same_kind(d):
                continue
            if name in seen:
                (d0, t0) = seen[name]
                raise MshError(f"two physical groups are named '{name}' (dimension {d0} tag {t0}, dimension {d} tag "
                               f"{t}): fem-impact finds {kind} by name, so each needs its own (or make them one "
                               "physical group)")
            seen[name] = (d, t)


def _child(path: str, out: str) -> None:
    """Read ``path`` and write what ``_extract`` finds (or the error) to ``out`` (.npz)."""
    gmsh.initialize(["fem-impact"], readConfigFiles=False)
    gmsh.option.setNumber("General.Terminal", 0)
    try:
        arrays, meta = _extract(path)
    except MshError as exc:
        arrays, meta = {}, {"error": str(exc)}
    finally:
        gmsh.finalize()
    np.savez(out, meta=np.array(json.dumps(meta)), **arrays)


if __name__ == "__main__":
    _child(*sys.argv[1:3])
