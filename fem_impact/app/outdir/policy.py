"""Which folders may be output folders: never the home folder, the current folder, the inputs' folders or
their parents; a folder is replaced only when it holds a fem-impact result and nothing else. A result
that finds the place changed at the end is kept beside it (:class:`OutputFolderChanged`)."""

from __future__ import annotations

import errno
import os
import time
from pathlib import Path

from ...errors import OutputFolderError
from .manifest import foreign_entries, foreign_refusal, is_result

# Leave room for ".partial-PID" and ".lock" around the folder's name (NAME_MAX is 255 bytes).
MAX_NAME_BYTES = 255 - len("..partial-4194304")


class OutputFolderChanged(OutputFolderError):
    """At the final move the output folder (or file) held what is not a fem-impact result: it was left as
    it was and the complete result was kept beside it, at ``kept``."""

    def __init__(self, where, message, kept):
        super().__init__(where, message)
        self.kept = Path(kept)


def _real(path) -> Path:
    return Path(os.path.realpath(path))


def _protected(protect=()) -> dict[Path, str]:
    """Folders that are never output folders, with what they are (for the message)."""
    places: dict[Path, str] = {}

    def add_with_parents(folder: Path, label: str, parent_label: str):
        places.setdefault(folder, label)
        for parent in folder.parents:
            places.setdefault(parent, parent_label)

    for item in protect:
        if item is not None:
            add_with_parents(_real(item).parent, "the folder of " + Path(item).name,
                             "a folder that holds " + Path(item).name)
    add_with_parents(_real(os.getcwd()), "the current folder", "a parent of the current folder")
    home = os.path.expanduser("~")
    if home not in ("~", "/"):
        places[_real(home)] = "the home folder"
    return places


def case_inputs(case) -> tuple:
    """The files a case reads (the case file, a mesh file): their folders are never output folders."""
    return tuple(p for p in (case.path, case.mesh.file) if p is not None)


def check(outdir, protect=(), option: str = "-o") -> Path:
    """The absolute output folder if the policy allows writing it; raises OutputFolderError.

    ``protect``: files (the case, the mesh) whose folders and their parents must not be replaced.
    """
    text = os.fspath(outdir)
    shown = text
    if not text.strip():
        raise OutputFolderError(f"{option} {text!r}", "give a folder name")
    if "\0" in text:
        raise OutputFolderError(f"{option} {text!r}", "a folder name cannot hold a NUL character")
    path = Path(os.path.abspath(text))
    real = _real(path)
    what = _protected(protect).get(real)
    if what is not None:
        raise OutputFolderError(shown, f"is {what}: it cannot be an output folder (the results replace the "
                                       "folder's contents); choose a folder of its own, e.g. results/NAME")
    if len(os.fsencode(path.name)) > MAX_NAME_BYTES:
        raise OutputFolderError(shown[:60] + "...", f"the folder name is too long ({len(os.fsencode(path.name))} "
                                                    f"bytes; at most {MAX_NAME_BYTES})")
    ancestor = path.parent
    while not ancestor.exists():
        if ancestor.is_symlink():
            raise OutputFolderError(shown, f"{ancestor} is a broken symbolic link")
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputFolderError(shown, f"{ancestor} is a file, not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise OutputFolderError(shown, f"cannot write into {ancestor} (permission denied)")
    refusal = _refusal(path)
    if refusal is not None:
        raise OutputFolderError(shown, refusal + ". Choose a new or empty folder (an earlier result of "
                                                 "fem-impact is replaced)" if refusal.startswith(_NOT_A_RESULT)
                                else refusal)
    return path


def _refusal(path: Path) -> str | None:
    """Why the policy does not let results replace what ``path`` holds now; None for nothing there, an empty
    folder or an earlier result."""
    if path.is_symlink():
        return "is a symbolic link; give the folder itself"
    if not path.exists():
        return None
    if not path.is_dir():
        return "the output path exists and is not a folder"
    try:
        entries = sorted(p.name for p in path.iterdir())
    except OSError as err:
        return f"cannot read the folder: {err.strerror}"
    if entries and not is_result(path):
        example = ", ".join(repr(e) for e in entries[:3]) + (", ..." if len(entries) > 3 else "")
        return (f"{_NOT_A_RESULT} ({len(entries)} entries: {example}); it is left as it was")
    if entries:
        try:
            foreign = foreign_entries(path)
        except OSError as err:
            return f"cannot read the folder: {err.strerror} ({err.filename})"
        if foreign:
            return foreign_refusal(foreign)
    return None


_NOT_A_RESULT = "the folder holds files that are not a fem-impact result"


def _keep_beside(result: Path, target: Path) -> Path:
    """Move the complete ``result`` (a folder or a file) to a new name beside ``target``,
    ``NAME.result-TIMESTAMP`` (a file keeps its suffix), never over anything: the name is taken
    first (mkdir, or an exclusive create), which fails on whatever exists."""
    is_file = result.is_file()
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for n in range(1, 1000):
        tag = f".result-{stamp}" + (f"-{n}" if n > 1 else "")
        kept = target.with_name(target.stem + tag + target.suffix) if is_file else target.with_name(target.name + tag)
        try:
            if is_file:
                os.close(os.open(kept, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
            else:
                kept.mkdir()
        except FileExistsError:
            continue
        os.rename(result, kept)   # over the empty folder (or file) just taken
        return kept
    raise OSError(errno.EEXIST, "no free name beside it for the result", str(target))
