"""The ``fem-impact`` command line."""

from __future__ import annotations

import argparse
import logging
import os
import sys

# The dense products of the time loop (N x p, p small) are memory bound: BLAS threads gain
# nothing there and would compete with MPI ranks for the cores.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

DESCRIPTION = """\
fem-impact: dynamics of elastic structures with unilateral constraints.

A case file (YAML) describes the mesh, material, supports, loads, contacts, solver and
output; `fem-impact run` integrates it in time and writes into OUTDIR:
  results.pvd         ParaView time series (point data u, v, a, contact_force)
  history.csv         per step: gaps, forces, impulses per contact, probes, energies,
                      momentum of every body
  summary.json        run figures (times, unknowns, steps, max penetration, energy error)
  case.resolved.yaml  the case with every default filled in
"""

EXAMPLES = """\
examples:
  fem-impact run cases/impacting_bar.yaml
  fem-impact run cases/impacting_bar.yaml -o results/fine --set mesh.cells=400 --set solver.dt=1.25e-3
  mpirun -n 2 fem-impact run cases/impacting_bar.yaml --set mesh.dim=2
"""

MODES_EXAMPLES = """\
examples:
  fem-impact modes cases/signorini_bar.yaml -n 5
  fem-impact modes cases/impacting_bar.yaml --set mesh.dim=3 --set mesh.cells=80 -n 12 -o results/bar3d-modes
"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fem-impact", description=DESCRIPTION, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    from . import __version__

    parser.add_argument("--version", action="version", version=f"fem-impact {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    run = sub.add_parser(
        "run", help="run a case file", description="Integrate a case file in time and write its results.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    run.add_argument("case", metavar="CASE.yaml", help="the case file")
    run.add_argument("-o", "--output", metavar="OUTDIR",
                     help="output folder (default: results/<case name>/ under the current folder); "
                          "replaced only when the run completes")
    run.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                     help="override a case-file key, value typed as in YAML (repeatable), "
                          "e.g. --set solver.dt=1e-3 --set contacts.0.restitution=0.5")
    run.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary paragraph")
    run.add_argument("-v", "--verbose", action="store_true", help="log the stages of the run")
    run.add_argument("--plot", action="store_true", help="also write history.png (contact force and energies)")

    reduction = sub.add_parser(
        "reduction", help="table of the reduced model's errors and times against the full model",
        description="Run a case with the full model and with the modal model (n1 modes, with and without "
                    "the static correction); print and write reduction.csv with the errors of a probe's "
                    "displacement and velocity and of the contact impulse, and the time of each run.")
    reduction.add_argument("case", metavar="CASE.yaml")
    reduction.add_argument("--modes", default="2,5,10,20", help="kept mode counts, comma-separated (default 2,5,10,20)")
    reduction.add_argument("--probe", help="probe to compare (default: the case's first probe)")
    reduction.add_argument("-o", "--output", metavar="OUTDIR", help="default: results/<case>-reduction/")
    reduction.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE")

    plot = sub.add_parser("plot", help="plot a run's contact forces and energy budget to a PNG",
                          description="Plot history.csv of a finished run: contact forces and the energy budget.")
    plot.add_argument("outdir", metavar="OUTDIR", help="a run's output folder")
    plot.add_argument("-o", "--output", metavar="PNG", help="image path (default: OUTDIR/history.png)")

    modes = sub.add_parser(
        "modes", help="natural frequencies and mode shapes of a case's structure",
        description="Compute the lowest natural modes (K y = w^2 M y; supports held, contacts ignored) and\n"
                    "write into OUTDIR:\n"
                    "  modes.csv           per mode: frequency, rigid/elastic, effective mass per direction\n"
                    "                      (% of the free mass), residual\n"
                    "  modes.pvd           the mass-normalized shapes, one frame per mode (t = mode number)\n"
                    "  case.resolved.yaml  the case with every default filled in",
        epilog=MODES_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    modes.add_argument("case", metavar="CASE.yaml", help="the case file")
    modes.add_argument("-n", "--modes", dest="count", type=int, metavar="N",
                       help="number of modes (default: solver.modes of the case if it is a number, else 10)")
    modes.add_argument("-o", "--output", metavar="OUTDIR",
                       help="output folder (default: results/<case name>-modes/ under the current folder); "
                            "replaced only when the computation completes")
    modes.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                       help="override a case-file key, value typed as in YAML (repeatable)")
    modes.add_argument("-q", "--quiet", action="store_true", help="do not print the table")
    modes.add_argument("-v", "--verbose", action="store_true", help="log the stages of the computation")

    sweep = sub.add_parser(
        "sweep", help="run a case once per value of one key; mean speed of a probe or body against the value",
        description="Run CASE.yaml once per value of KEY (as with --set KEY=VALUE) and write into OUTDIR:\n"
                    "  sweep.csv   per value: mean velocity of the probe or body over the second half of the\n"
                    "              run (per axis), its final displacement, the total impulse of every\n"
                    "              contact, the wall time\n"
                    "  sweep.png   the mean velocity against the value\n"
                    "  runNN/      each run's history.csv, summary.json, case.resolved.yaml (VTK off\n"
                    "              unless --set output.vtk=true)",
        epilog="examples:\n  fem-impact sweep cases/vibrodrive.yaml --vary parameters.f=16e3,17e3,18e3 --body slider\n"
               "  fem-impact sweep cases/impacting_bar.yaml --vary initial.velocity.0=-0.5,-1,-2 --probe right",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    sweep.add_argument("case", metavar="CASE.yaml", help="the case file")
    sweep.add_argument("--vary", required=True, metavar="KEY=v1,v2,...",
                       help="the key to vary and its values, typed as in YAML, e.g. parameters.f=20e3,21e3")
    target = sweep.add_mutually_exclusive_group()
    target.add_argument("--probe", metavar="NAME", help="measure this probe (default: the case's first probe)")
    target.add_argument("--body", metavar="NAME", help="measure this body's centre of mass (history BODY.px ...)")
    sweep.add_argument("-o", "--output", metavar="OUTDIR",
                       help="output folder (default: results/<case name>-sweep/); replaced only when the sweep "
                            "completes")
    sweep.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                       help="override a case-file key for every run (repeatable)")
    sweep.add_argument("-q", "--quiet", action="store_true", help="no progress and no table")

    from .animate import add_parser as add_animate_parser

    add_animate_parser(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    _configure_logging(getattr(args, "verbose", False))
    if args.command == "plot":
        return _plot(args.outdir, args.output)
    if args.command == "reduction":
        return _reduction(args)
    if args.command == "modes":
        return _modes(args)
    if args.command == "sweep":
        return _sweep(args)
    if args.command == "animate":
        from .animate import main as animate_main

        return animate_main(args)

    # Heavy imports (dolfinx, PETSc) only once the arguments are known to be sound.
    from .run import describe, run_case

    def run():
        summary = run_case(args.case, args.output, args.overrides, comm=_comm(), progress=not args.quiet)
        if _comm().rank == 0 and not args.quiet:
            print(describe(summary))
        if _comm().rank == 0 and args.plot:
            _plot(summary["outdir"], None)

    return _guarded(run, "the run failed")


class _UsageError(Exception):
    """A command-line option that does not fit the case (reported like bad input)."""


def _comm():
    from mpi4py import MPI

    return MPI.COMM_WORLD


def _guarded(action, failure: str) -> int:
    """Run ``action``; bad input -> one line and status 2, a failed computation -> status 3."""
    from .case import CaseError
    from .errors import SimulationError

    try:
        action()
    except (CaseError, _UsageError) as err:
        return _fail(_comm(), f"error: {err}", 2)
    except SimulationError as err:
        return _fail(_comm(), f"{failure}: {err} (the output folder was left as it was)", 3)
    except KeyboardInterrupt:
        return _fail(_comm(), "interrupted (the output folder was left as it was)", 130)
    return 0


def _modes(args) -> int:
    if args.count is not None and args.count < 1:
        return _fail(_comm(), f"error: -n {args.count}: ask for at least 1 mode", 2)
    from .modes import ModeCountError, format_table, run_modes

    def modes():
        try:
            summary = run_modes(args.case, args.output, args.overrides, args.count, comm=_comm())
        except ModeCountError as err:
            raise _UsageError(f"-n {args.count}: {err}") from None
        if _comm().rank == 0 and not args.quiet:
            print(format_table(summary))

    return _guarded(modes, "the modal analysis failed")


def _reduction(args) -> int:
    from .studies import format_reduction, reduction_table

    try:
        modes = [int(m) for m in args.modes.split(",")]
    except ValueError:
        return _fail(_comm(), f"error: --modes {args.modes}: give whole numbers separated by commas, e.g. 2,5,10", 2)

    def study():
        try:
            rows = reduction_table(args.case, modes, args.output, args.overrides, args.probe, _comm())
        except ValueError as err:
            raise _UsageError(str(err)) from None
        if _comm().rank == 0:
            print(format_reduction(rows))

    return _guarded(study, "the study failed")


def _sweep(args) -> int:
    from .sweep import SweepError, Target, format_sweep, run_sweep

    target = Target("probe", args.probe) if args.probe else Target("body", args.body) if args.body else None

    def sweep():
        try:
            outdir, rows = run_sweep(args.case, args.vary, target, args.output, args.overrides, comm=_comm(),
                                     progress=not args.quiet, report=None if args.quiet else print)
        except SweepError as err:
            raise _UsageError(str(err)) from None
        if _comm().rank == 0 and not args.quiet:
            print(format_sweep(rows))
            print(f"Results in {outdir} (sweep.csv, sweep.png, one folder per run).")

    return _guarded(sweep, "the sweep failed")


def _plot(outdir: str, png) -> int:
    from pathlib import Path

    from .plots import plot_history

    if not (Path(outdir) / "history.csv").is_file():
        print(f"fem-impact: error: {outdir}: no history.csv (is it a run's output folder?)", file=sys.stderr)
        return 2
    print(f"wrote {plot_history(outdir, png)}")
    return 0


def _configure_logging(verbose: bool) -> None:
    """Our stages at INFO with -v; other libraries (the JIT compiler's build logs) only warnings."""
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(name)s: %(message)s"))
    handler.addFilter(lambda r: r.levelno >= logging.WARNING or (verbose and r.name.startswith("fem_impact")))
    logging.basicConfig(level=logging.INFO, handlers=[handler], force=True)


def _fail(comm, message: str, status: int) -> int:
    if comm.rank == 0:
        print(f"fem-impact: {message}", file=sys.stderr)
    return status
