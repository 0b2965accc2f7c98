"""One level's run, and the status it reports: the single-run step of every study.

:func:`run_data` runs a level's case, given as data (``Case.resolved()`` and ``base_dir``), into its
folder with :func:`fem_impact.run` and returns its status as plain data (``status`` ok | failed |
skipped, ``reason``, ``error`` (the exception's type), ``summary``, and ``traceback`` for a
crash). A study with ``-j 1`` calls it in its own process; with ``-j N`` each level is a child
process (the same call, so that a level's run and its reason do not depend on ``-j``)::

    python -m fem_impact.app.studies.worker SPEC.json

where SPEC.json holds the level's case as data (``Case.resolved()``, ``base_dir``), its folder and
the file to write the status to (as JSON). The child exits 0 once the status is written; an
interrupted child (SIGINT from the study) removes its staging folder and writes none.
"""

from __future__ import annotations

import contextlib
import json
import sys
import traceback
import warnings
from pathlib import Path

from ...errors import CaseError, SimulationError

STATUSES = ("ok", "failed", "skipped")
WRITE_FAILED = 3   # the child's status when it could not write (the line on its stderr says what)


def run_data(data: dict, base_dir, folder: Path) -> dict:
    """Run the case ``data`` (``Case.resolved()``; relative paths from ``base_dir``) into ``folder``: its status.

    A case the data does not make (CaseError: it should) is ``skipped``; else :func:`run_level`.
    """
    from ...config.case import Case

    try:
        case = Case.from_dict(data, base_dir=base_dir)
    except CaseError as err:
        return status("skipped", str(err), err)
    return run_level(case, folder)


def run_level(case, folder: Path) -> dict:
    """Run ``case`` into ``folder`` (nothing written there unless it completes); its status as plain data.

    SimulationError (blow-up, NaN, energy created when asked to stop) -> ``failed`` with its message;
    CaseError (the run refuses its input when it starts) -> ``skipped``; any other error -> ``failed``
    as a crash, with its traceback. KeyboardInterrupt goes through, and so does OutputWriteError (a
    full disk is not the level's outcome: the study stops).
    """
    from mpi4py import MPI

    from ..outdir.writes import OutputWriteError
    from ..pipeline import run

    try:
        with warnings.catch_warnings():   # (overflow on the way to a blow-up: the run reports it)
            warnings.simplefilter("ignore", RuntimeWarning)
            run(case, folder, comm=MPI.COMM_SELF, progress=False)
    except OutputWriteError:
        raise
    except SimulationError as err:
        return status("failed", str(err), err)
    except CaseError as err:
        return status("skipped", str(err), err)
    except Exception as err:   # a crash of the run: recorded like a failure
        return status("failed", f"the run crashed: {type(err).__name__}: {err}", err, traceback.format_exc())
    # The summary as written, as a resumed level reads it.
    return status("ok", "", summary=json.loads((Path(folder) / "summary.json").read_text()))


def status(name: str, reason: str, err: BaseException | None = None, trace: str | None = None,
           summary: dict | None = None) -> dict:
    """A level's status as plain data (the reason on one line)."""
    return {"status": name, "reason": " ".join(reason.split()), "error": type(err).__name__ if err else None,
            "summary": summary, "traceback": trace}


def write_spec(path: Path, case, folder: Path, status_file: Path) -> Path:
    """The child's instructions: the case as data, where to run it, where to report."""
    data = {"case": case.resolved(), "base_dir": str(case.base_dir), "folder": str(folder),
            "status": str(status_file)}
    _write_json(path, data)
    return path


def read_status(path: Path) -> dict | None:
    """A child's status, or None when it wrote none (or an unreadable one)."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("status") not in STATUSES:
        return None
    return data


def _write_json(path: Path, data) -> None:
    from ..outdir.writes import replacing

    with replacing(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=str) + "\n")


def main(argv=None) -> int:
    import logging

    from ..outdir.interruption import exit_status, install_signal_handlers
    from ..outdir.writes import OutputWriteError, write_error

    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m fem_impact.app.studies.worker SPEC.json", file=sys.stderr)
        return 2
    install_signal_handlers()   # SIGINT from the study: the run removes its staging folder
    # Warnings only (on stderr, which the study keeps in a log file): no stage logs, no JIT build logs.
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    spec = json.loads(Path(argv[0]).read_text())
    try:
        result = run_data(spec["case"], spec["base_dir"], Path(spec["folder"]))
        _write_json(Path(spec["status"]), result)
    except KeyboardInterrupt as err:
        return exit_status(err)
    except OutputWriteError as err:   # the study reads the line from the log and stops
        with contextlib.suppress(OSError):
            print(err, file=sys.stderr)
        return WRITE_FAILED
    except OSError as err:
        with contextlib.suppress(OSError):
            print(write_error(err), file=sys.stderr)
        return WRITE_FAILED
    return 0


if __name__ == "__main__":
    sys.exit(main())
