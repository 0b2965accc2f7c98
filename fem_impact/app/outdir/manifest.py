"""What a result folder holds: the marker ``.fem-impact.json`` and its manifest (the files a command
wrote), which entries are the program's and which are foreign, and removing a result's own entries."""

from __future__ import annotations

import contextlib
import fnmatch
import json
import os
import re
import shutil
from pathlib import Path

from .writes import replacing

MARKER = ".fem-impact.json"


def is_result(folder: Path) -> bool:
    """True when ``folder`` holds a fem-impact result (marker, or the files of an earlier version)."""
    folder = Path(folder)
    if (folder / MARKER).is_file():
        return True
    try:
        if "fem_impact_version" in json.loads((folder / "summary.json").read_text()):
            return True
    except (OSError, ValueError, TypeError):
        pass
    legacy = [("case.resolved.yaml",), ("study.json",), ("level.json",), ("sweep.csv", "run01"),
              ("reduction.csv", "full")]
    return any(all((folder / name).exists() for name in names) for names in legacy)


# The marker records the relative paths a command wrote (``files``: folders with a trailing "/"). A rerun
# may replace or remove those, never anything else: a folder that holds other entries is refused, and
# removing a result removes its own entries only (:func:`remove_result`). Two kinds of entries are the
# program's without being listed: a study's levels (``levels/NAME``, each a result of its own, with its
# ``level.json``: a study killed before it completes lists none of them) and the debris of a killed
# command (:func:`_debris`). A result of an earlier version (no manifest) owns the names its commands
# write (:data:`_KNOWN_FILES`, :data:`_KNOWN_FOLDERS`); anything else in it is foreign.

_KNOWN_FILES = ("results.pvd", "results*.pvtu", "results*.vtu", "results.xdmf", "results.h5", "history.csv",
                "history.png", "summary.json", "case.resolved.yaml", "impacts.csv", "view.py", "state.json",
                "rank-*.h5", "modes.csv", "modes.pvd", "modes*.pvtu", "modes*.vtu", "sweep.csv", "sweep.png",
                "reduction.csv", "reduction.png", "study.json", "level.json", "convergence.csv", "convergence.png",
                "pareto.csv", "pareto.png", "stability.csv", "stability.png", "response.csv", "response.png",
                "response-up.json", "response-down.json", "animation.gif", "animation.mp4", "frame.png", MARKER)
_KNOWN_FOLDERS = ("checkpoint", "checkpoint.new", "checkpoint.old", "run[0-9][0-9]*", "full", "modal-*-static",
                  "modal-*-plain")
LEVELS = "levels"
_STAGING = re.compile(r"\..+\.(partial|old|checkpoint)-\d+")
_TEMPORARY = re.compile(r"\..+\.(partial)-\d+(\.[A-Za-z0-9]+)?")   # replacing()'s files
_STUDY_CACHE = re.compile(r"\.cache-[a-z0-9_]{8}")                # levels.run_levels's private cache


def _debris(name: str, is_dir: bool, in_levels: bool, owned: _Owned, sub: str) -> bool:
    """An entry a command makes while it works and removes when it ends (a killed one leaves it): a
    temporary file of :func:`replacing` beside one of the result's files, a study's cache; in ``levels/``, a
    level run's staging, moved-aside, checkpoint folders and lock. Names no user gives a file (a dot, the
    name, the kind, a process id)."""
    temporary = None if is_dir else _TEMPORARY.fullmatch(name)
    if temporary:
        target = name[1:temporary.start(1) - 1] + (temporary.group(2) or "")   # (.history.partial-7.csv)
        return owned.owns(sub + target, False)
    if is_dir and _STUDY_CACHE.fullmatch(name):
        return True
    return in_levels and ((is_dir and _STAGING.fullmatch(name) is not None) or
                          (not is_dir and name.startswith(".") and name.endswith(".lock")))


def _read_manifest(folder: Path) -> set[str] | None:
    """The ``files`` the marker of ``folder`` lists; None without a marker or without a manifest (an earlier
    version's result, or a marker cut short)."""
    try:
        data = json.loads((folder / MARKER).read_text())
    except (OSError, ValueError):
        return None
    files = data.get("files") if isinstance(data, dict) else None
    if isinstance(files, list) and all(isinstance(f, str) for f in files):
        return set(files)
    return None


class _Owned:
    """Which entries of one result folder (relative paths) fem-impact wrote: its manifest, or the known names."""

    def __init__(self, folder: Path, level: bool = False):
        self.files = _read_manifest(folder)
        self.level = level   # a study's level: its level.json too

    def owns(self, rel: str, is_dir: bool) -> bool:
        if self.level and rel == "level.json" and not is_dir:
            return True
        if self.files is not None:
            return (rel + "/" if is_dir else rel) in self.files or rel == MARKER
        patterns = _KNOWN_FOLDERS if is_dir else _KNOWN_FILES
        name = rel.rsplit("/", 1)[-1]
        return any(fnmatch.fnmatchcase(name, p) for p in patterns)


def _is_level(folder: Path) -> bool:
    return (folder / "level.json").is_file() or (folder / MARKER).is_file()


def _scan(root: Path, owned: _Owned, shown: str = "", sub: str = ""):
    """Every entry under ``root`` as (path, what): "file" and "folder" for the program's own (a folder after
    its entries), "debris" for a killed command's, "foreign" for the rest (its contents not listed).
    Symbolic links are entries, never followed."""
    folder = root / sub if sub else root
    with os.scandir(folder) as it:
        entries = sorted(it, key=lambda e: e.name)
    for entry in entries:
        rel = sub + entry.name
        is_dir = entry.is_dir(follow_symlinks=False)
        path = Path(entry.path)
        if _debris(entry.name, is_dir, sub == f"{LEVELS}/", owned, sub):
            yield path, "debris", shown + rel
        elif owned.owns(rel, is_dir):
            if is_dir:
                yield from _scan(root, owned, shown, rel + "/")
            yield path, "folder" if is_dir else "file", shown + rel
        elif is_dir and rel == LEVELS:   # a study's levels, listed or not: each must be a level
            yield from _scan(root, owned, shown, rel + "/")
            yield path, "folder", shown + rel
        elif is_dir and sub == f"{LEVELS}/" and _is_level(path):
            yield from _scan(path, _Owned(path, level=True), shown + rel + "/")
            yield path, "folder", shown + rel
        else:
            yield path, "foreign", shown + rel + ("/" if is_dir else "")


def tree(folder) -> list[str]:
    """Every entry under ``folder`` (relative paths, folders with "/"; symbolic links not followed), the
    marker left out: the manifest of a folder a command wrote whole."""
    folder = Path(folder)
    out = []

    def walk(directory: Path, prefix: str):
        with os.scandir(directory) as it:
            for entry in it:
                if entry.is_dir(follow_symlinks=False):
                    out.append(prefix + entry.name + "/")
                    walk(Path(entry.path), prefix + entry.name + "/")
                elif not (prefix == "" and entry.name == MARKER):
                    out.append(prefix + entry.name)

    walk(folder, "")
    return sorted(out)


def write_marker_data(folder: Path, data: dict) -> None:
    with replacing(folder / MARKER) as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n")


def foreign_entries(folder) -> list[str]:
    """The entries of the result ``folder`` that fem-impact did not write (relative, folders with "/"),
    the outermost of each: what a rerun must not remove."""
    folder = Path(folder)
    return [shown for _, what, shown in _scan(folder, _Owned(folder)) if what == "foreign"]


def owned_entries(folder) -> list[str]:
    """The manifest of ``folder`` as it stands: the entries fem-impact wrote (relative, folders with "/")."""
    folder = Path(folder)
    return sorted(shown + ("/" if what == "folder" else "") for _, what, shown in _scan(folder, _Owned(folder))
                  if what in ("file", "folder") and shown != MARKER)


def remove_result(folder, level: bool = False) -> list[str]:
    """Remove what fem-impact wrote in ``folder`` (its own entries and debris; the marker last, so that a
    removal cut short leaves a folder still known as a result), and ``folder`` itself when nothing else is
    left; returns the foreign entries it left. ``level``: a study's level (its level.json is the program's)."""
    folder = Path(folder)
    left = []
    for path, what, shown in list(_scan(folder, _Owned(folder, level))):
        if what == "foreign":
            left.append(shown)
        elif what == "debris":
            _remove_tree(path)
        elif path.name == MARKER and path.parent == folder:
            continue
        elif what == "file":
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
        else:
            with contextlib.suppress(OSError):   # (not empty: it holds foreign entries)
                path.rmdir()
    if not left:
        with contextlib.suppress(FileNotFoundError):
            (folder / MARKER).unlink()
        with contextlib.suppress(OSError):
            folder.rmdir()
    return left


def _remove_tree(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def adopt(path) -> None:
    """A file another command wrote into a result folder (a picture of ``plot``, ``animate``) becomes part of
    that result: its manifest lists it (a rerun replaces it). Nothing when the folder is not a result with a
    marker; a marker that cannot be rewritten leaves the file foreign (a rerun then names it)."""
    path = Path(path)
    folder = path.parent
    try:
        data = json.loads((folder / MARKER).read_text())
        if not isinstance(data, dict):
            return
        files = data.get("files")
        if not (isinstance(files, list) and all(isinstance(f, str) for f in files)):
            files = owned_entries(folder)   # (an earlier version's result: its known names, listed from now on)
        if path.name not in files:
            data["files"] = sorted({*files, path.name})
            write_marker_data(folder, data)
    except (OSError, ValueError):
        pass


def _listing(names: list[str], most: int = 4) -> str:
    shown = ", ".join(names[:most])
    return shown + (f" and {len(names) - most} more" if len(names) > most else "")


def foreign_refusal(names: list[str]) -> str:
    return (f"the folder holds files fem-impact did not write ({_listing(names)}): move them, or choose another "
            "folder")
