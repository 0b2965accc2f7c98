"""The output folder's policy, shared by every command that writes: which folders may be written or
replaced, the staging folder, the lock against a concurrent run, stale debris, and interruption.

- A folder is replaced only when it holds an earlier fem-impact result and nothing else: the marker
  file ``.fem-impact.json`` that every command writes lists what the command wrote (its manifest);
  a result written before the manifest existed owns the names its commands write. A result that
  holds anything else (a notebook, a folder of figures, a link, a note inside ``checkpoint/``) is
  refused naming those entries, and any other folder that is not empty is refused; both are left
  as they were. Removing a result removes its own entries only (:func:`remove_result`).
- The home folder, the current folder and its parents, the case file's folder and its parents
  (and the mesh file's) are never output folders.
- Results are written into a hidden sibling ``.NAME.partial-PID`` and moved into place when
  complete, under the policy checked again at that moment: a folder that appeared or changed
  meanwhile and holds files that are not the result's is left as it was, and the result is kept
  beside it (``NAME.result-TIMESTAMP``, :class:`OutputFolderChanged`). A lock (``.NAME.lock``
  beside the folder, ``flock``: released by the kernel when the process dies) makes a second run
  into the same folder refuse; whoever holds the lock removes staging folders that a killed
  process left behind, puts back an earlier result it finds moved aside, and keeps a killed run's
  checkpoint in ``NAME.checkpoint`` (a restart from it follows it there: :meth:`OutputFolder.follow`).
- A study writes into its folder directly (:func:`written_in_place`): its completed levels stay
  when it fails or is interrupted, for a rerun to resume.
- SIGTERM, SIGHUP and SIGQUIT end a run as Ctrl-C does (:class:`Interrupted`, a KeyboardInterrupt):
  the staging folder is removed and the command exits with 128 + the signal number; a signal the
  process was started with ignored (nohup) stays ignored. Under mpirun one rank says it
  (:meth:`OutputFolder._stop_ranks`).
- A write that fails (a full disk, a quota, an I/O error) is :class:`OutputWriteError`, a
  SimulationError (status 3) naming the file and the reason; the staging folder is removed.

Refusals are :class:`OutputFolderError`, a CaseError: one line and status 2, like other bad input.
Under MPI, rank 0 decides and does the file work; every rank raises the same error.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import fnmatch
import json
import logging
import os
import re
import shutil
import signal
import threading
import time
from pathlib import Path

from .._version import __version__
from ..errors import CaseError, OutputFolderError, SimulationError  # noqa: F401  (OutputFolderError: re-exported)

log = logging.getLogger(__name__)

MARKER = ".fem-impact.json"
# Leave room for ".partial-PID" and ".lock" around the folder's name (NAME_MAX is 255 bytes).
MAX_NAME_BYTES = 255 - len("..partial-4194304")


class OutputFolderChanged(OutputFolderError):
    """At the final move the output folder (or file) held what is not a fem-impact result: it was left as
    it was and the complete result was kept beside it, at ``kept``."""

    def __init__(self, where, message, kept):
        super().__init__(where, message)
        self.kept = Path(kept)


class OutputWriteError(SimulationError):
    """Results that could not be written (a full disk, a quota, an I/O error): the run fails (status 3)."""


def write_error(err: OSError, stage: Path | None = None, final: Path | None = None,
                checkpoints: Path | None = None) -> OutputWriteError:
    """The one line for an OSError while writing results: the file (as it would be named in ``final``
    when it lies in the staging folder ``stage``, or in the run's ``checkpoints`` folder beside it) and
    the system's reason."""
    name = err.filename
    if name is not None and stage is not None and final is not None:
        with contextlib.suppress(ValueError):
            name = final / Path(os.fsdecode(name)).relative_to(stage)
    if name is not None and checkpoints is not None and final is not None:
        with contextlib.suppress(ValueError):
            inside = Path(os.fsdecode(name)).relative_to(checkpoints).parts   # (checkpoint.new/rank-0.h5)
            name = final.joinpath(CHECKPOINT, *inside[1:])
    if err.filename2 is not None:   # a rename: the move into place
        what = f"cannot move the results into {final if final is not None else os.fsdecode(err.filename2)}"
    elif name is not None:
        what = f"cannot write {os.fsdecode(name)}"
    else:
        what = f"cannot write the results{f' into {final}' if final is not None else ''}"
    return OutputWriteError(f"{what}: {err.strerror or err}")


@contextlib.contextmanager
def writing(path):
    """An OSError of the body names ``path`` (a failed ``write`` or ``close`` of a file object names none)."""
    try:
        yield
    except OSError as err:
        if err.filename is None:
            raise OSError(err.errno, err.strerror or str(err), os.fspath(path)) from None
        raise


@contextlib.contextmanager
def replacing(path):
    """Yields a temporary name beside ``path``; it replaces ``path`` when the body completes and is removed
    when it fails (errors name ``path``): a file is either the old one or the new one, whole."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    try:
        with writing(path):
            yield tmp
            os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    _WRITTEN.add(os.path.realpath(path))


# The files this process wrote in place (replacing): a study's marker lists those of its folder.
_WRITTEN: set[str] = set()


# --- which folders ---------------------------------------------------------------------------


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


# --- what a result folder holds: its manifest ---------------------------------------------------
#
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


# --- the claim: lock, stale debris, staging ---------------------------------------------------


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_while_written(stage: Path, linger: float) -> None:
    """Remove a staging folder that another rank may still be writing into, and keep it removed for
    ``linger`` seconds. Interrupted under MPI, the signal reaches one rank; another may be inside a
    write that creates the folder again (dolfinx's VTK writer makes its directories) before it waits
    in a collective until mpirun kills it: an empty ``.NAME.partial-PID`` left behind (measured on 1
    in 5 interrupted 2-rank runs before this)."""
    deadline = time.monotonic() + linger
    while True:
        shutil.rmtree(stage, ignore_errors=True)
        if time.monotonic() >= deadline:
            return
        time.sleep(0.05)


# Under MPI, how long a rank other than 0 waits for rank 0 to clean up after an interruption before it does.
TAKE_OVER = 0.3
_CLEANUP: list[threading.Thread] = []


def wait_for_cleanup(timeout: float = 1.5) -> None:
    """Before an interrupted process ends: let the background removal of its staging folder finish."""
    end = time.monotonic() + timeout
    while _CLEANUP:
        _CLEANUP.pop().join(max(0.0, end - time.monotonic()))


CHECKPOINT = "checkpoint"   # (fem_impact/app/checkpoint.py writes it)


def _is_checkpoint(folder: Path) -> bool:
    """A checkpoint folder fem-impact wrote: state.json naming its version, rank-R.h5 files, nothing else."""
    try:
        names = {p.name for p in folder.iterdir()}
        state = json.loads((folder / "state.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(state, dict) and "fem_impact_version" in state and \
        all(n == "state.json" or (n.startswith("rank-") and n.endswith(".h5")) for n in names)


def _keep_checkpoint(folder: Path, path: Path, inputs=()) -> tuple[Path, str] | None:
    """Move the last complete checkpoint written in ``folder`` to ``NAME.checkpoint`` beside the output
    folder ``path`` (an earlier checkpoint of that name is replaced, anything else is kept: the
    checkpoint then goes to ``NAME.checkpoint-TIMESTAMP``; so does it when ``NAME.checkpoint`` is one of
    ``inputs``, what the command reads: a restart's checkpoint); returns (where, its time) or None."""
    try:
        for source in (folder / CHECKPOINT, folder / f"{CHECKPOINT}.old"):   # (.old: interrupted mid-rename)
            if (source / "state.json").is_file():
                break
        else:
            return None
        when = json.loads((source / "state.json").read_text()).get("t")
        target = path.parent / f"{path.name}.checkpoint"
        read = any(_real(target) == _real(p) or _real(target) in _real(p).parents for p in inputs)
        if _is_checkpoint(target) and not read:   # an earlier one, kept the same way: replaced; anything else is left
            shutil.rmtree(target)
        if target.exists():
            target = path.parent / f"{path.name}.checkpoint-{time.strftime('%Y%m%d-%H%M%S')}"
        os.rename(source, target)
        return target, f"t = {when:.6g}"
    except (OSError, ValueError):
        return None
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _remove_stale(parent: Path, name: str, inputs=(), moved=None) -> list[Path]:
    """Staging and replaced folders of ``name`` left by processes that no longer exist; the last checkpoint of
    a killed run is kept in ``NAME.checkpoint`` (and said in a warning), its old and new places in ``moved``."""
    removed = []
    for p in parent.glob(f".{_glob_escape(name)}.checkpoint-*"):   # a killed run's checkpoints: kept
        pid = p.name.rsplit("-", 1)[1]
        if pid.isdigit() and not _alive(int(pid)):
            kept = _keep_checkpoint(p, parent / name, inputs)
            if kept is not None:
                log.warning("the last checkpoint (%s) of a run into %s that was killed is kept in %s: continue it "
                            "with --restart %s", kept[1], parent / name, kept[0], kept[0])
                if moved is not None:
                    moved[str(_real(p))] = str(kept[0])
    for kind in ("partial", "old"):
        for p in parent.glob(f".{_glob_escape(name)}.{kind}-*"):
            pid = p.name.rsplit("-", 1)[1]
            if not (pid.isdigit() and (int(pid) == 0 or not _alive(int(pid)))):
                continue
            if kind == "partial":   # (only ever what a command was writing)
                shutil.rmtree(p, ignore_errors=True)
            elif not os.path.lexists(parent / name):   # killed between its two moves: the earlier result goes back
                with contextlib.suppress(OSError):
                    os.rename(p, parent / name)
                continue
            elif is_result(p):   # (only ever a result moved aside: what fem-impact wrote in it)
                _discard(p, parent / name)
            else:
                continue
            removed.append(p)
    return removed


def _glob_escape(name: str) -> str:
    return "".join(f"[{c}]" if c in "*?[" else c for c in name)


class OutputFolder:
    """A claimed output folder: checked, locked; ``staged()`` writes it atomically."""

    def __init__(self, path: Path, comm, command: str, source=None, inputs=()):
        self.path, self.comm, self.command, self.source = path, comm, command, source
        self.inputs = tuple(p for p in inputs if p is not None)
        self.moved: dict[str, str] = {}   # a killed run's checkpoint folder -> where the claim kept it
        self._lock_fd = None
        self._lock_path = path.parent / f".{path.name}.lock"
        self._created: list[Path] = []
        self.stale: list[Path] = []

    # rank 0 only
    def _acquire(self) -> None:
        missing = []
        p = self.path.parent
        while not p.exists():
            missing.append(p)
            p = p.parent
        try:
            for folder in reversed(missing):
                folder.mkdir()
                self._created.append(folder)
            while True:
                fd = os.open(self._lock_path, os.O_RDWR | os.O_CREAT, 0o644)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError as err:
                    holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                    os.close(fd)
                    if err.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                        raise OutputFolderError(str(self.path), f"another fem-impact process (pid {holder}) is "
                                                                "writing this folder; wait for it to finish or "
                                                                "choose another folder") from None
                    raise
                # The holder before us may have removed the file after we opened it: lock the file in place.
                try:
                    same = os.fstat(fd).st_ino == os.stat(self._lock_path).st_ino
                except FileNotFoundError:
                    same = False
                if same:
                    break
                os.close(fd)
            self._lock_fd = fd
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            self.stale = _remove_stale(self.path.parent, self.path.name, self.inputs, self.moved)
        except OSError as err:
            self._release()
            raise OutputFolderError(str(self.path), f"cannot create the output folder: "
                                                    f"{err.strerror or err}") from None
        except BaseException:
            self._release()
            raise

    def _release(self, failed: bool = True) -> None:
        if self._lock_fd is not None:
            with contextlib.suppress(OSError):
                os.unlink(self._lock_path)
            os.close(self._lock_fd)
            self._lock_fd = None
        if failed:   # folders made for the output that stayed empty
            for folder in reversed(self._created):
                with contextlib.suppress(OSError):
                    folder.rmdir()
        self._created = []

    def follow(self, path):
        """Where ``path`` is now: a killed run's checkpoint that this claim moved to ``NAME.checkpoint`` (a
        restart from it reads it there); any other path as it is."""
        if path is None or not self.moved:
            return path
        real = _real(path)
        for old, new in self.moved.items():
            if real == Path(old) or real == Path(old) / CHECKPOINT:
                return Path(new)
        return path

    def write_marker(self, folder: Path, files=()) -> None:
        """The marker of ``folder``, with its manifest ``files`` (relative paths, folders with "/"): written
        whole or not at all."""
        data = {"written_by": f"fem-impact {self.command}", "fem_impact_version": __version__,
                "source": None if self.source is None else str(self.source), "files": sorted(set(files))}
        write_marker_data(Path(folder), data)

    @contextlib.contextmanager
    def staged(self):
        """Write into ``.NAME.partial-PID`` beside the folder; move it over the folder when complete.

        A failed or interrupted body removes the staging folder and leaves the folder as it was; so
        does a failed write (:class:`OutputWriteError`). At the move the policy is checked again
        (:meth:`install`).
        """
        comm = self.comm
        install_signal_handlers()   # again: PETSc, imported meanwhile, installs its own
        stage = self.path.parent / f".{self.path.name}.partial-{os.getpid()}"
        error = None
        if comm.rank == 0:
            try:
                stage.mkdir()
            except OSError as err:
                error = f"cannot create the staging folder {stage}: {err.strerror}"
        error = comm.bcast(error, root=0)
        if error:
            raise OutputFolderError(str(self.path), error)
        stage = Path(comm.bcast(str(stage), root=0))
        # Checkpoints are written beside the staging folder, not in it: an interrupted run keeps the last
        # one (:func:`_keep_checkpoint`) while every rank removes the staging folder.
        self.checkpoints = stage.parent / stage.name.replace(".partial-", ".checkpoint-", 1)
        try:
            yield stage
            comm.barrier()
            failure = None
            if comm.rank == 0:
                try:
                    saved = self.checkpoints / CHECKPOINT
                    if saved.is_dir():
                        os.rename(saved, stage / CHECKPOINT)
                    shutil.rmtree(self.checkpoints, ignore_errors=True)
                    self.write_marker(stage, tree(stage))
                    self.install(stage)
                    self._created = []   # they hold the result now
                except OutputFolderChanged as err:
                    failure = ("changed", err.file, err.message, str(err.kept))
                except OSError as err:
                    failure = ("write", str(write_error(err, stage, self.path)))
            failure = comm.bcast(failure, root=0)
            if failure is not None:
                raise OutputFolderChanged(*failure[1:]) if failure[0] == "changed" else OutputWriteError(failure[1])
        except BaseException as err:
            interrupted = isinstance(err, KeyboardInterrupt)
            if interrupted:
                ignore_signals()   # a second signal (mpirun sends one) must not cut the cleanup short
            if interrupted and comm.size > 1:
                self._stop_ranks(err, stage)
            elif comm.rank == 0:
                self._keep_last_checkpoint(err)
                shutil.rmtree(stage, ignore_errors=True)
            if isinstance(err, OSError):
                converted = write_error(err, stage, self.path, self.checkpoints)
                converted.left = getattr(err, "left", None)
                raise converted from None
            raise
        comm.barrier()

    def _keep_last_checkpoint(self, err: BaseException) -> None:
        """Keep the run's last checkpoint beside the output folder and say so in ``err.left``."""
        kept = _keep_checkpoint(self.checkpoints, self.path)
        if kept is not None:
            err.left = (f"the output folder was left as it was; the run's last checkpoint ({kept[1]}) is "
                        f"kept in {kept[0]}: continue it with --restart {kept[0]}")

    def _stop_ranks(self, err: KeyboardInterrupt, stage: Path) -> None:
        """An interruption under MPI: one rank keeps the last checkpoint and speaks (``err.speaker``), every rank
        removes the staging folder.

        mpirun passes the signal to every rank and kills them a second later (odls_base_sigkill_timeout); a
        rank inside an MPI call that waits for another never sees it. Rank 0 does it when it can; another rank
        that finds the staging folder still there after :data:`TAKE_OVER` seconds takes over (rank 0 is stuck).
        Who does it is decided by renaming the staging folder away: that succeeds for one rank only. The folder
        is then kept removed for a second in the background (:func:`_remove_while_written`): the line is said
        first (:func:`wait_for_cleanup` before the process ends).
        """
        comm = self.comm
        if comm.rank != 0:
            deadline = time.monotonic() + TAKE_OVER
            while stage.exists() and time.monotonic() < deadline:
                time.sleep(0.02)
        mine = stage.with_name(f"{stage.name}.removing-{os.getpid()}")
        try:
            os.rename(stage, mine)
        except OSError:
            err.speaker = False
        else:
            err.speaker = True
            self._keep_last_checkpoint(err)
        if comm.rank != 0:   # (rank 0, if stuck, is killed with the lock file left)
            with contextlib.suppress(OSError):
                os.unlink(self._lock_path)
        else:
            self._release()   # (before lingering: mpirun may kill this rank meanwhile)
        def remove():
            shutil.rmtree(mine, ignore_errors=True)
            _remove_while_written(stage, linger=1.0)

        thread = threading.Thread(target=remove, daemon=True)
        thread.start()
        _CLEANUP.append(thread)

    def install(self, stage: Path) -> None:
        """Move the complete ``stage`` into place (rank 0, holding the lock), under the policy checked again:
        between the check at the start and now the folder may have appeared or changed.

        The move itself never replaces files: rename(2) puts a folder over an empty folder only, and
        fails on one with files (which may appear between this check and the move). An earlier result
        is first moved aside (``.NAME.old-PID``) and removed once the new one is in place; it is put
        back when the move fails. When the folder holds what is not a result, it is left as it was and
        the result is kept beside it: :class:`OutputFolderChanged`.
        """
        path = self.path
        refusal = _refusal(path)
        old = None
        if refusal is None and path.is_dir() and any(path.iterdir()):
            old = path.parent / f".{path.name}.old-{os.getpid()}"
            try:
                os.rename(path, old)
            except FileNotFoundError:   # (gone meanwhile: nothing to move aside)
                old = None
            else:   # an entry made between the check and the move aside: the folder goes back (below)
                try:
                    late = foreign_entries(old)
                except OSError as err:
                    late = [f"{err.filename}: {err.strerror}"]
                if late:
                    refusal = foreign_refusal(late)
        try:
            if refusal is None:
                try:
                    os.rename(stage, path)
                except OSError as err:
                    if err.errno not in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
                        raise
                    refusal = _refusal(path) or "the output path was taken during the run"
        except BaseException:
            if old is not None:
                os.rename(old, path)
            raise
        if refusal is not None:
            earlier = ""
            if old is not None:   # (the folder appeared again between the two renames)
                try:
                    os.rename(old, path)
                except OSError:
                    earlier = f"; the earlier result is in {_keep_beside(old, path)}"
            kept = _keep_beside(stage, path)
            raise OutputFolderChanged(str(path), f"{refusal} (checked again at the end of the {self.command}, "
                                                 f"before the results were moved into place); the results are "
                                                 f"in {kept}{earlier}", kept)
        if old is not None:
            _discard(old, path)


def _discard(old: Path, path: Path) -> None:
    """Remove the earlier result ``old`` (moved aside from ``path``): what fem-impact wrote in it. An entry of
    the user's that is still there (made in it after the last check, through a process's open folder) goes
    to the same place in ``path`` when that is free, else stays in ``old``: never removed."""
    left = remove_result(old)
    if not left:
        return
    for name in left:
        source, target = old / name.rstrip("/"), path / name.rstrip("/")
        if target.parent.is_dir() and not os.path.lexists(target):
            with contextlib.suppress(OSError):
                os.rename(source, target)
    remove_result(old)


@contextlib.contextmanager
def claim(outdir, comm, command: str, protect=(), source=None):
    """Check and lock ``outdir`` for the body; yields an :class:`OutputFolder`.

    Raises OutputFolderError (on every rank) when the policy refuses the folder or another
    process holds it. On leaving, the lock is released; on failure, parent folders this claim
    created are removed again if empty.
    """
    install_signal_handlers()
    out = None
    error = None
    if comm.rank == 0:
        try:
            path = check(outdir, protect)
            out = OutputFolder(path, comm, command, source, protect)
            out._acquire()
        except OutputFolderError as err:
            error = (err.file, err.message)
    error = comm.bcast(error, root=0)
    if error:
        raise OutputFolderError(*error)
    moved = comm.bcast(out.moved if comm.rank == 0 else None, root=0)
    if comm.rank != 0:
        out = OutputFolder(Path(os.path.abspath(outdir)), comm, command, source, protect)
        out.moved = moved
    ok = False
    try:
        yield out
        ok = True
    finally:
        if comm.rank == 0:
            out._release(failed=not ok)


_IN_PLACE: set[str] = set()   # the folders this process's written_in_place claims hold now


@contextlib.contextmanager
def in_place(outdir, command: str, protect=(), source=None):
    """:func:`written_in_place` for a study called from Python; nothing more when this process holds that claim
    already (the command line claims the folder before it calls the study)."""
    if os.path.realpath(outdir) in _IN_PLACE:
        yield None
        return
    from mpi4py import MPI

    with written_in_place(outdir, MPI.COMM_WORLD, command, protect, source) as out:
        yield out


@contextlib.contextmanager
def written_in_place(outdir, comm, command: str, protect=(), source=None):
    """Claim ``outdir`` for a command that writes into it directly, not through a staging folder: a study,
    whose completed levels (``OUTDIR/levels/NAME``) are kept for a rerun to resume.

    The folder is made at once (mkdir, which does not take over a folder that appeared since the
    check: that one is checked again). The marker is written at once only into a new or empty folder
    (so that it is recognized with its first level); into an earlier result, at completion.

    Leaving with an error, the exception gets ``left``, one sentence on what the folder keeps: the
    levels this run completed, or "the output folder was left as it was" (then what this claim made
    is removed again). An OSError becomes :class:`OutputWriteError`.
    """
    with claim(outdir, comm, command, protect, source) as out:
        made, before, before_files, error = set(), {}, [], None
        if comm.rank == 0:
            try:
                made = _open_in_place(out)
                before = _levels(out.path)
                before_files = owned_entries(out.path)
            except OutputFolderError as err:
                error = (err.file, err.message)
            except OSError as err:
                error = (str(out.path), f"cannot create the output folder: {err.strerror or err}")
        error = comm.bcast(error, root=0)
        if error:
            raise OutputFolderError(*error)
        held = os.path.realpath(out.path)
        _IN_PLACE.add(held)
        try:
            yield out
            if comm.rank == 0:
                with writing(out.path / MARKER):
                    out.write_marker(out.path, _in_place_manifest(out.path, before_files))
        except BaseException as err:
            if comm.rank == 0:
                err.left = _left_in_place(out.path, before, made)
            if isinstance(err, OSError):
                converted = write_error(err, final=out.path)
                converted.left = getattr(err, "left", None)
                raise converted from None
            raise
        finally:
            _IN_PLACE.discard(held)


def _in_place_manifest(folder: Path, before: list[str]) -> list[str]:
    """What a study's folder holds of the program's at its end: the earlier result's entries that are still
    there and the files this study wrote (its levels are known as such: not listed)."""
    real = os.path.realpath(folder) + os.sep
    mine = {p for p in _WRITTEN if p.startswith(real)}
    _WRITTEN.difference_update(mine)
    files = set()
    for rel in [*before, *(p[len(real):].replace(os.sep, "/") for p in mine)]:
        if rel == MARKER or rel.startswith(LEVELS + "/") or not os.path.lexists(folder / rel.rstrip("/")):
            continue
        files.add(rel)
        parts = rel.rstrip("/").split("/")
        files.update("/".join(parts[:k]) + "/" for k in range(1, len(parts)))
    return sorted(files)


def _open_in_place(out: OutputFolder) -> set:
    """Make the folder (or check it again) for writing in place; returns what was made: "folder", "marker"."""
    made = set()
    try:
        out.path.mkdir()
        made.add("folder")
    except FileExistsError:
        refusal = _refusal(out.path)
        if refusal is not None:
            raise OutputFolderError(str(out.path), refusal) from None
    if "folder" in made or not any(out.path.iterdir()):
        out.write_marker(out.path)
        made.add("marker")
    for cache in out.path.glob(".cache-*"):   # a killed study's private cache (we hold the lock)
        if _STUDY_CACHE.fullmatch(cache.name) and cache.is_dir() and not cache.is_symlink():
            shutil.rmtree(cache, ignore_errors=True)
    if not (out.path / "levels").exists():
        made.add("levels")
    return made


def _levels(folder: Path) -> dict:
    """The recorded levels of a study folder: name -> identity of its ``level.json`` (rewritten by replace)."""
    found = {}
    for record in (folder / "levels").glob("*/level.json"):
        with contextlib.suppress(OSError):
            st = record.stat()
            found[record.parent.name] = (st.st_ino, st.st_mtime_ns)
    return found


def _left_in_place(folder: Path, before: dict, made: set) -> str:
    """What a study that ends early leaves in its folder, in words; when it recorded no level, what it
    made is removed (the folder, the marker, an empty ``levels/``), so that the folder is as it was."""
    now = _levels(folder)
    new = [name for name, ident in now.items() if before.get(name) != ident]
    if new:
        others = len(now) - len(new)
        return (f"{len(new)} completed level{'s' if len(new) > 1 else ''} of this run "
                f"{'are' if len(new) > 1 else 'is'} kept in {folder / 'levels'}"
                + (f", with {others} of an earlier run" if others else "")
                + "; run the same command again to resume")
    try:
        if "levels" in made and (folder / "levels").exists():
            (folder / "levels").rmdir()
        if "marker" in made:
            (folder / MARKER).unlink()
        if "folder" in made:
            folder.rmdir()
    except OSError:   # (something else was left in it: a killed level's staging folder)
        return "no level was completed"
    return "the output folder was left as it was"


# --- single files (plot, animate) ------------------------------------------------------------

_MAGIC = {".png": (b"\x89PNG",), ".gif": (b"GIF8",), ".jpg": (b"\xff\xd8",), ".jpeg": (b"\xff\xd8",),
          ".pdf": (b"%PDF",), ".svg": (b"<?xml", b"<svg"), ".mp4": (b"ftyp",)}


def check_file(output, protect=(), option: str = "-o") -> Path:
    """An output file (a picture, an animation): its folder must exist; an existing file is replaced
    only when it is a picture of the same kind, never a folder or another file."""
    text = os.fspath(output)
    if not text.strip():
        raise OutputFolderError(f"{option} {text!r}", "give a file name")
    if "\0" in text:
        raise OutputFolderError(f"{option} {text!r}", "a file name cannot hold a NUL character")
    path = Path(os.path.abspath(text))
    if len(os.fsencode(path.name)) > MAX_NAME_BYTES:
        raise OutputFolderError(f"{option} {text[:60]}...", "the file name is too long")
    if not path.parent.is_dir():
        raise OutputFolderError(f"{option} {text}", f"no folder {path.parent}" if not path.parent.exists()
                                else f"{path.parent} is not a folder")
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise OutputFolderError(f"{option} {text}", f"cannot write into {path.parent} (permission denied)")
    if any(_real(path) == _real(p) for p in protect if p is not None):
        raise OutputFolderError(f"{option} {text}", "is an input of this command; choose another file")
    refusal = _file_refusal(path)
    if refusal is not None:
        raise OutputFolderError(f"{option} {text}", refusal)
    return path


def _file_refusal(path: Path) -> str | None:
    """Why a picture must not replace what ``path`` is now; None for nothing there or a picture of its kind."""
    if path.is_dir():
        return "is a folder; give a file name"
    if not path.exists():
        return None
    magic = _MAGIC.get(path.suffix.lower(), ())
    try:
        with open(path, "rb") as f:
            head = f.read(12)
    except OSError as err:
        return f"cannot read the existing file: {err.strerror}"
    if not any(head.startswith(m) or m in head[:12] for m in magic):
        return (f"the file exists and is not a {path.suffix or 'picture'} picture; it is left as it was (choose "
                "another name)")
    return None


@contextlib.contextmanager
def atomic_file(path: Path):
    """Yields a temporary name beside ``path`` (same suffix); it replaces ``path`` when the body completes.

    The temporary file is made first: a place where no file can be made is refused
    (:class:`OutputFolderError`); a write that fails later is :class:`OutputWriteError`. At the end
    :func:`check_file`'s policy is checked again: a file that appeared meanwhile and is not a picture of
    the kind is left as it was, and the picture kept beside it (:class:`OutputFolderChanged`).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    try:
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644))
    except OSError as err:
        raise OutputFolderError(str(path), f"cannot write the file: {err.strerror or err}") from None
    try:
        with writing(path):
            yield tmp
            _install_file(tmp, path)
    except OSError as err:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if err.filename is not None and os.fsdecode(err.filename) == str(tmp):
            err.filename = str(path)
        raise write_error(err) from None
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def _install_file(tmp: Path, path: Path) -> None:
    """Put the finished ``tmp`` at ``path`` under the policy checked again; never over another file: a new
    name is taken with link(2), which fails on whatever exists (rename would replace it)."""
    refusal = _file_refusal(path)
    if refusal is None and not path.exists():
        try:
            os.link(tmp, path)
        except FileExistsError:
            refusal = _file_refusal(path) or "a file of that name was made during the rendering"
        except OSError as err:
            if err.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EMLINK):
                raise
            os.replace(tmp, path)   # (no hard links on this file system: the check just made must do)
            adopt(path)
            return
        else:
            os.unlink(tmp)
            adopt(path)
            return
    if refusal is None:
        os.replace(tmp, path)   # a picture of the kind, replaced
        adopt(path)
        return
    kept = _keep_beside(tmp, path)
    raise OutputFolderChanged(str(path), f"{refusal} (checked again before the picture was written); the picture "
                                         f"is in {kept}", kept)


# --- interruption ----------------------------------------------------------------------------


class Interrupted(KeyboardInterrupt):
    """A run ended by a signal (SIGTERM, SIGHUP, SIGQUIT, SIGINT): a KeyboardInterrupt with ``signum``."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


HANDLED = (signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


_RECEIVED: list[int] = []


def _raise(signum, frame):
    # The process is ending: a second signal (mpirun follows one with another, a user presses Ctrl-C
    # twice) must not interrupt the cleanup. The next claim() installs the handlers again.
    ignore_signals()
    _RECEIVED.append(signum)
    raise Interrupted(signum)


def received() -> int | None:
    """The signal that interrupted this process (a library may have turned the KeyboardInterrupt raised in
    its code into an error of its own: an extension's import fails), or None."""
    return _RECEIVED[-1] if _RECEIVED else None


def rank_zero_stuck(wait: float = TAKE_OVER) -> bool:
    """Under mpirun, interrupted on a rank other than 0: whether rank 0 is still running ``wait`` seconds
    later (stuck in an MPI call that waits for this rank; it exits at once when it can say so itself). Rank 0
    is found among this process's siblings (the ranks mpirun starts on this machine); False when it is not."""
    pid = _rank_zero_pid()
    if pid is None:
        return False
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline:
        if not _running(pid):
            return False
        time.sleep(0.02)
    return _running(pid)


def _rank_zero_pid() -> int | None:
    parent, me = os.getppid(), os.getpid()
    try:
        entries = [e.name for e in os.scandir("/proc") if e.name.isdigit() and int(e.name) != me]
    except OSError:
        return None
    for pid in entries:
        try:
            with open(f"/proc/{pid}/stat") as f:
                if int(f.read().rsplit(")", 1)[1].split()[1]) != parent:
                    continue
            with open(f"/proc/{pid}/environ", "rb") as f:
                env = f.read().split(b"\0")
        except (OSError, ValueError, IndexError):
            continue
        if b"OMPI_COMM_WORLD_RANK=0" in env or b"PMI_RANK=0" in env:
            return int(pid)
    return None


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except (OSError, IndexError):
        return False


_IGNORED_AT_START: frozenset | None = None


def install_signal_handlers() -> None:
    """SIGTERM, SIGHUP, SIGQUIT and SIGINT raise :class:`Interrupted` (in the main thread; else nothing).

    A signal the process was started with ignored stays ignored (``nohup`` ignores SIGHUP, a shell script's
    background command SIGINT): the run goes on, as the one who started it asked. (Noted at the first call;
    PETSc, imported later, installs handlers of its own, which the next call replaces.)"""
    global _IGNORED_AT_START
    if _IGNORED_AT_START is None:
        _IGNORED_AT_START = frozenset(sig for sig in (*HANDLED, signal.SIGINT)
                                      if signal.getsignal(sig) == signal.SIG_IGN)
    try:
        for sig in (*HANDLED, signal.SIGINT):
            signal.signal(sig, signal.SIG_IGN if sig in _IGNORED_AT_START else _raise)
    except ValueError:   # not the main thread (a study's worker): the process's owner handles signals
        pass


def ignore_signals() -> None:
    """After an interruption: the process is ending, further signals wait for nothing."""
    try:
        for sig in (*HANDLED, signal.SIGINT):
            signal.signal(sig, signal.SIG_IGN)
    except ValueError:
        pass


def exit_status(err: KeyboardInterrupt) -> int:
    """128 + the signal number: 130 for Ctrl-C, 143 for SIGTERM, 129 for SIGHUP, 131 for SIGQUIT."""
    return 128 + getattr(err, "signum", signal.SIGINT)


def signal_name(err: KeyboardInterrupt) -> str:
    return signal.Signals(getattr(err, "signum", signal.SIGINT)).name
