"""The ``fem-impact`` command line."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys

from .. import mpi_start

# The dense products of the time loop (N x p, p small) are memory bound: BLAS threads gain
# nothing there and would compete with MPI ranks for the cores.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# A command started alone starts Open MPI for one process (mpi_start.py), before MPI loads in this process
# and in the study workers it starts.
SERIAL_MPI = mpi_start.SERIAL_MPI
mpi_start.serial_start()

DESCRIPTION = """\
fem-impact: dynamics of elastic structures with unilateral constraints.

A case file (YAML) describes the mesh, material, supports, loads, contacts, solver and
output; `fem-impact run` integrates it in time and writes into OUTDIR:
  results.pvd         ParaView time series (point data u, v, a, contact_force, contact_state)
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
    from .._version import __version__
    from ..integrators.parameters import help_text as solver_help

    parser.add_argument("--version", action="version", version=f"fem-impact {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    run = sub.add_parser(
        "run", help="run a case file", description="Integrate a case file in time and write its results.",
        epilog=EXAMPLES + "\n" + solver_help(), formatter_class=argparse.RawDescriptionHelpFormatter,
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
    run.add_argument("--stop-on-energy-gain", action="store_true",
                     help="stop with status 3 as soon as the contacts create energy (E above E0 + W_ext by more "
                          "than 1e-6 of the energy scale); without it the run goes on, warns at the end and "
                          "records energy_created in summary.json")
    run.add_argument("--restart", metavar="DIR", default=None,
                     help="continue the run saved in DIR (an output folder, or the checkpoint folder an interrupted "
                          "run kept) from its last checkpoint to the case's t_end")
    run.add_argument("--force", action="store_true",
                     help="run even when the estimated steps, memory or output size are beyond the limits")

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
                    "                      (% of the free mass), residual, what moves; with --at GROUP its\n"
                    "                      modal mass and stiffness there and its participation factor\n"
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
    modes.add_argument("--at", metavar="GROUP", help="a node group: add each mode's modal mass and stiffness there "
                       "(along --direction) and its participation factor")
    modes.add_argument("--direction", choices=("x", "y", "z"), default="x", help="the direction for --at (default x)")
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
    parser.study_parser = _add_study_parser(sub)

    from .animate import add_parser as add_animate_parser

    add_animate_parser(sub)
    return parser


STUDY_DESCRIPTION = """\
Run a case many times and compare. Each study writes into OUTDIR (default
results/<case name>-<study>/): levels/ (one run per level, kept: a rerun resumes and skips the
finished ones), a CSV, a PNG and study.json. Errors are measured against the case's exact
solution when it declares one (`reference: b1 | b2 | bar_mode`), else against the finest level
(convergence) or a finer reference run (pareto, stability). A level that blows up
(SimulationError) stops the study with status 3, or is recorded as failed with its message
(--allow-failure; the stability study always records them).

methods (--method, --methods):
"""

STUDY_EXAMPLES = """\
examples:
  fem-impact study convergence cases/impacting_bar.yaml --vary mesh.cells=50,100,200,400
  fem-impact study convergence cases/signorini_bar.yaml --vary mesh.cells=20,40,80,160 --courant 0.5
  fem-impact study convergence cases/impacting_bar.yaml --vary solver.dt=0.004,0.002,0.001 --against finest
  fem-impact study pareto cases/impacting_bar.yaml
  fem-impact study pareto cases/vibroconverter_free.yaml --methods trapezoidal,modal-static
  fem-impact study stability cases/signorini_bar.yaml -j 2
"""


def _add_study_parser(sub) -> argparse.ArgumentParser:
    from .studies.methods import describe_methods

    study = sub.add_parser(
        "study", help="convergence orders, the speed-accuracy chart, the stability map, the forced response",
        description=STUDY_DESCRIPTION + describe_methods(), epilog=STUDY_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    kinds = study.add_subparsers(dest="study", metavar="STUDY")

    def common(p, jobs_default: str, failures: bool = True):
        p.add_argument("case", metavar="CASE.yaml", help="the case file")
        p.add_argument("-o", "--output", metavar="OUTDIR", help="default: results/<case name>-<study>/")
        p.add_argument("-j", "--jobs", default=jobs_default, metavar="N",
                       help=f"levels run at once, in separate processes (default {jobs_default}; with N > 1 the "
                            "timings include each process's imports and the runs share the cores)")
        p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                       help="override a case-file key for every level (repeatable)")
        p.add_argument("--allow-failure", action="store_true",
                       help="record a level that blows up as failed and go on (default: stop, status 3)"
                       if failures else "(always on here: the stability study records failures)")
        p.add_argument("-q", "--quiet", action="store_true", help="no progress lines and no table")

    conv = kinds.add_parser(
        "convergence", help="errors and fitted orders under refinement (convergence.csv, convergence.png)",
        description="Run the case at the levels of --vary, measure the errors against the case's exact solution "
                    "(reference:) or the finest level, fit the orders (log-log slopes). When the mesh varies the "
                    "time step follows it at a fixed Courant number c dt / h: the case's own, or --courant.",
        epilog=STUDY_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    common(conv, "1")
    conv.add_argument("--vary", action="append", default=[], metavar="KEY=V1,V2,...",
                      help="the levels, e.g. mesh.cells=50,100,200,400 or solver.dt=0.004,0.002,0.001; two --vary "
                           "options are taken level by level together")
    conv.add_argument("--courant", metavar="C", help="Courant number c dt / h of every level (dt follows h)")
    conv.add_argument("--dt", metavar="DT", help="the same time step for every level")
    conv.add_argument("--method", metavar="NAME", help="the method (default trapezoidal; see fem-impact study -h)")
    conv.add_argument("--against", choices=("exact", "finest"),
                      help="the reference: the case's exact solution (default when it declares one) or the finest "
                           "level")

    pareto = kinds.add_parser(
        "pareto", help="error against wall time for every method (pareto.csv, pareto.png)",
        description="For every method a ladder of resolutions (mesh cells at a fixed Courant number on the "
                    "built-in bar, the time step on a mesh file, kept modes for the modal methods); errors against "
                    "the exact solution or a finer trapezoidal run; times measured in this run, on this machine.",
        epilog=STUDY_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    common(pareto, "1")
    pareto.add_argument("--methods", metavar="A,B,...", help="methods to compare (default: all available)")
    pareto.add_argument("--courant", metavar="C", help="Courant number of the full-model ladders (default: the "
                                                       "case's)")
    pareto.add_argument("--levels", metavar="N", help="rungs per ladder (default 5)")
    pareto.add_argument("--time", choices=("wall", "loop"), default="wall",
                        help="x axis: the whole run (setup + loop, default) or the time loop alone")

    stab = kinds.add_parser(
        "stability", help="outcome map over time step, restitution and run length (stability.csv, stability.png)",
        description="For every method sweep the Courant number (at the case's restitution and length), the "
                    "restitution (at the case's Courant number) and the run length (multiples of t_end); classify "
                    "each run: accurate, inaccurate (an error above --tolerance, an oscillating contact force) or "
                    "failed (blow-up or NaN, energy growth, penetration, chattering to the end), with the reason.",
        epilog=STUDY_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    common(stab, "1", failures=False)
    stab.add_argument("--methods", metavar="A,B,...", help="methods to sweep (default: all available)")
    stab.add_argument("--courant", metavar="C1,C2,...", help="Courant numbers (default 0.1,0.25,0.5,1,2,4)")
    stab.add_argument("--restitution", metavar="E1,E2,...", help="restitution coefficients (default 0,0.5,1)")
    stab.add_argument("--length", metavar="K1,K2,...", help="run lengths in multiples of t_end (default 1,4)")
    stab.add_argument("--tolerance", metavar="TOL", help="largest relative error of an accurate run (default 0.05)")
    resp = kinds.add_parser(
        "response", help="the settled forced response over a sweep of any key: Poincare sections, periods, "
                         "impulses (response.csv, response.png)",
        description="Sweep a key of the case (--vary: the forcing frequency's parameter, an amplitude, a gap, a "
                    "restitution ...) at the forcing frequency --frequency (in Hz: an expression of the case's "
                    "parameters, by default its parameter f): each level starts from the previous one's last "
                    "state, runs --settle forcing periods, then --periods periods sampled at forcing phase 0 (the "
                    "stroboscopic Poincare section), at --steps-per-period steps a period. The period of the "
                    "settled response (the smallest k whose section repeats; 0 with a period_note when none, or "
                    "when the time step's timing error cannot tell it), the Poincare points of the probes and "
                    "each contact's impulse and impacts per period go to response.csv; response.png is the "
                    "bifurcation diagram. A sweep --down into the same folder with the same settings keeps the "
                    "sweep up: the chart shows both.",
        epilog="examples:\n"
               "  fem-impact study response cases/impact_oscillator.yaml --vary parameters.f=0.45,0.5,...,0.65\n"
               "  fem-impact study response cases/impact_oscillator.yaml --vary parameters.F0=0.5,0.6,0.7 "
               "--frequency f\n"
               "  fem-impact study response cases/impact_oscillator.yaml --vary contacts.0.gap=0,0.1,0.2",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    common(resp, "1")
    resp.add_argument("--vary", required=True, metavar="KEY=V1,V2,...",
                      help="the varied key and its values: V1,V2,... or START,NEXT,...,END (evenly spaced, END "
                           "included), e.g. parameters.f=40,45,...,60 or contacts.0.gap=0,1e-4,2e-4")
    resp.add_argument("--frequency", metavar="EXPR",
                      help="the forcing frequency in Hz: an expression of the case's parameters (default: its "
                           "parameter f) or a number; it sets the time step and the section")
    resp.add_argument("--down", action="store_true", help="sweep the values from the highest down")
    resp.add_argument("--settle", default="50", metavar="M", help="forcing periods to settle (default 50)")
    resp.add_argument("--periods", default="16", metavar="N", help="forcing periods sampled (default 16)")
    resp.add_argument("--steps-per-period", default="500", metavar="K", help="time steps a forcing period "
                                                                              "(default 500)")
    resp.add_argument("--flight", choices=("scheme", "events"), default="scheme",
                      help="scheme: each level a run of the case's time stepping (default); events: the reduced "
                           "model without static correction flown from impact to impact (exact impact instants)")
    resp.add_argument("--no-shooting", action="store_true",
                      help="skip the periodic orbits by shooting (done for the reduced model without static "
                           "correction: the period-1 orbit along the sweep, its Floquet multipliers, bifurcations)")
    resp.add_argument("--shooting-time", default="300", metavar="SECONDS",
                      help="time limit of one orbit's shooting (default 300); beyond it the orbit's note says so")
    resp.add_argument("--tolerance", default="1e-4", metavar="TOL",
                      help="relative tolerance of a repeated section point (default 1e-4)")
    return study


def main(argv=None) -> int:
    from .outdir.interruption import install_signal_handlers

    install_signal_handlers()   # SIGTERM, SIGHUP, SIGQUIT end every command as Ctrl-C does
    try:
        return _main(argv)
    except KeyboardInterrupt as err:   # (while the command line or the libraries load)
        return _interrupted(err)
    except Exception:
        from .outdir.interruption import Interrupted, received

        if received() is None:
            _abort_other_ranks()
            raise
        return _interrupted(Interrupted(received()))   # (a library's import failed, interrupted)


def _abort_other_ranks() -> None:
    """An unexpected error (a defect) on one rank of several: its traceback, then MPI_Abort. Raised on one rank
    alone it would leave the others waiting in their next collective call, and the run would hang instead of
    stopping."""
    mpi = sys.modules.get("mpi4py.MPI")
    if mpi is None or not mpi.Is_initialized() or mpi.Is_finalized() or mpi.COMM_WORLD.size < 2:
        return
    import traceback

    traceback.print_exc()
    print(f"fem-impact: rank {mpi.COMM_WORLD.rank} stopped on the error above (a defect: please report it); "
          "the other ranks are stopped with it", file=sys.stderr)
    sys.stderr.flush()
    mpi.COMM_WORLD.Abort(1)


def _main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    _configure_logging(getattr(args, "verbose", False))
    if not getattr(args, "verbose", False):
        # Overflow on the way to a blow-up: the run detects it and says so in one line (status 3);
        # numpy's warnings (with source lines, once per rank) would only add noise. Shown with -v.
        import warnings

        warnings.filterwarnings("ignore", category=RuntimeWarning)
    if args.command == "plot":
        return _plot(args.outdir, args.output)
    if args.command == "reduction":
        return _reduction(args)
    if args.command == "study":
        return _study(args, parser)
    if args.command == "modes":
        return _modes(args)
    if args.command == "sweep":
        return _sweep(args)
    if args.command == "animate":
        from .animate import main as animate_main

        return animate_main(args)

    case = args.case
    if _rank_and_size()[1] == 1:
        # Outside mpirun the case is read before MPI starts (a third of a second): bad input is told at once.
        from ..config.case import load_case

        loaded = []
        status = _guarded(lambda: loaded.append(load_case(args.case, args.overrides)), "the run failed")
        if status:
            return status
        case = loaded[0]
    # Heavy imports (dolfinx, PETSc) only once the arguments are known to be sound.
    from .pipeline import describe, energy_warning, run_case

    def run():
        summary = run_case(case, args.output, args.overrides, comm=_comm(), progress=not args.quiet,
                           stop_on_energy_gain=args.stop_on_energy_gain, force=args.force, restart=args.restart)
        if _comm().rank == 0 and not args.quiet:
            print(describe(summary))
        warning = energy_warning(summary)
        if _comm().rank == 0 and warning:
            print(warning, file=sys.stderr)
        if _comm().rank == 0 and args.plot:
            _plot(summary["outdir"], None)

    return _guarded(run, "the run failed")


class _UsageError(Exception):
    """A command-line option that does not fit the case (reported like bad input)."""


def _comm():
    from mpi4py import MPI

    return MPI.COMM_WORLD


class _Rank:
    def __init__(self, rank: int, size: int):
        self.rank, self.size = rank, size


def _started_comm():
    """MPI's world where MPI has started; else this process's rank and size from the launcher, without
    starting MPI for a message (bad input found before the run began)."""
    return _comm() if "mpi4py.MPI" in sys.modules else _Rank(*_rank_and_size())


def _guarded(action, failure: str) -> int:
    """Run ``action``; bad input -> one line and status 2, a failed computation -> status 3."""
    from ..config.case import CaseError
    from ..errors import SimulationError
    from .outdir.writes import OutputWriteError

    try:
        action()
    except (CaseError, _UsageError) as err:
        return _fail(_started_comm(), f"error: {err}", 2)
    except SimulationError as err:
        status = _fail(_comm(), f"{failure}: {err} ({_left(err)})", 3)
        if _comm().size > 1 and isinstance(err, OutputWriteError):
            sys.stderr.flush()   # (written by rank 0 alone: the other ranks wait in the time loop)
            os._exit(status)
        return status
    except KeyboardInterrupt as err:
        return _interrupted(err)
    except MemoryError:
        return _fail(_comm(), "error: not enough memory for this case (reduce mesh.cells, or run under mpirun on "
                              "more machines); nothing was written", 2)
    return 0


def _interrupted(err: KeyboardInterrupt) -> int:
    """One line for Ctrl-C, SIGTERM, SIGHUP or SIGQUIT (on its own line after a progress bar); 128 + signal."""
    from .outdir.claim import wait_for_cleanup
    from .outdir.interruption import exit_status, ignore_signals, rank_zero_stuck, signal_name

    ignore_signals()
    if "fem_impact.app.progress" in sys.modules:
        sys.modules["fem_impact.app.progress"].Progress.end_line()
    status = exit_status(err)
    rank, size = _rank_and_size()
    # Under MPI the rank that cleaned up says it (rank 0, or another when rank 0 was stuck in an MPI call).
    speaker = getattr(err, "speaker", None)
    if speaker is None:
        speaker = rank == 0 or (size > 1 and rank_zero_stuck())
    try:
        if speaker:
            print(f"fem-impact: interrupted by {signal_name(err)} ({_left(err)})", file=sys.stderr)
        sys.stderr.flush()
    except OSError:   # (SIGHUP: the terminal may be gone)
        pass
    if size > 1:
        # The other ranks may wait in a collective call that never completes: no MPI_Finalize (it
        # would wait for them too); mpirun ends the job when a rank exits with a non-zero status.
        wait_for_cleanup()
        os._exit(status)
    return status


def _rank_and_size() -> tuple[int, int]:
    """This process's MPI rank and the job's size: from MPI when mpi4py is loaded, else (interrupted while the
    libraries load) from the launcher's environment, without starting MPI now."""
    mpi = sys.modules.get("mpi4py.MPI")
    if mpi is not None and hasattr(mpi, "COMM_WORLD"):
        with contextlib.suppress(Exception):
            return mpi.COMM_WORLD.rank, mpi.COMM_WORLD.size
    env = os.environ
    rank = env.get("OMPI_COMM_WORLD_RANK", env.get("PMI_RANK", "0"))
    size = env.get("OMPI_COMM_WORLD_SIZE", env.get("PMI_SIZE", "1"))
    return (int(rank), int(size)) if rank.isdigit() and size.isdigit() else (0, 1)


def _left(err: BaseException) -> str:
    """What the output folder holds after a failure: as it was (staged commands), or what a study kept."""
    return getattr(err, "left", None) or "the output folder was left as it was"


def _modes(args) -> int:
    if args.count is not None and args.count < 1:
        return _fail(_comm(), f"error: -n {args.count}: ask for at least 1 mode", 2)
    from ..fem.modes import ModeCountError
    from .modes import format_table, run_modes

    def modes():
        try:
            summary = run_modes(args.case, args.output, args.overrides, args.count, comm=_comm(), at=args.at,
                                direction=args.direction)
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
        from ..config.case import load_case

        case = load_case(args.case, args.overrides)
        try:
            rows = reduction_table(case, modes, args.output, args.probe, _comm())
        except ValueError as err:
            raise _UsageError(str(err)) from None
        if _comm().rank == 0:
            print(format_reduction(rows))

    return _guarded(study, "the study failed")


def _sweep(args) -> int:
    from .sweep import SweepError, Target, format_sweep, run_sweep

    target = Target("probe", args.probe) if args.probe else Target("body", args.body) if args.body else None

    def sweep():
        from ..config.case import load_case

        case = load_case(args.case, args.overrides)
        try:
            outdir, rows = run_sweep(case, args.vary, target, args.output, comm=_comm(), progress=not args.quiet,
                                     report=None if args.quiet else print)
        except SweepError as err:
            raise _UsageError(str(err)) from None
        if _comm().rank == 0 and not args.quiet:
            print(format_sweep(rows))
            print(f"Results in {outdir} (sweep.csv, sweep.png, one folder per run).")

    return _guarded(sweep, "the sweep failed")


def _study(args, parser) -> int:
    if args.study is None:
        parser.study_parser.print_help()
        return 2
    from .studies import common
    from .studies.levels import StudyStopped
    from .studies.methods import UnknownMethod

    def study():
        try:
            _run_study(args)
        except (common.StudyInputError, UnknownMethod) as err:
            raise _UsageError(str(err)) from None

    try:
        return _guarded(study, "the study failed")
    except StudyStopped as err:
        outdir = err.outcome.folder.parent.parent
        return _fail(_comm(), f"the study stopped: {err} (completed levels are kept in {outdir / 'levels'}: a rerun "
                              "resumes; --allow-failure records failed levels and goes on)", 3)


def _numbers(option: str, text, kind=float, single=False):
    """A number or a comma-separated list from an option (None when not given); bad text -> usage error."""
    from .studies.common import StudyInputError

    if text is None:
        return None
    try:
        values = [kind(v) for v in str(text).split(",")]
    except ValueError:
        what = "a whole number" if kind is int else "a number"
        raise StudyInputError(f"{option} {text}: expected {what}{'' if single else ' or a comma-separated list'}") \
            from None
    if single and len(values) != 1:
        raise StudyInputError(f"{option} {text}: expected one value")
    return values[0] if single else values


def _run_study(args) -> None:
    from pathlib import Path

    from ..config.case import load_case
    from .outdir.in_place import written_in_place
    from .outdir.policy import case_inputs
    from .studies.common import default_outdir

    # Every level is a copy of the case with changes: its method's, then the --set options (so that they win
    # and may set the method's own keys, e.g. solver.modes), then the level's own.
    case = load_case(args.case)
    args.output = Path(args.output) if args.output else default_outdir(case, args.study)
    with written_in_place(args.output, _comm(), f"study {args.study}", protect=case_inputs(case), source=args.case):
        _study_in(args, case)


def _study_in(args, case) -> None:
    from .studies.common import StudyInputError

    jobs = _numbers("-j", args.jobs, int, single=True)
    if jobs < 1:
        raise StudyInputError(f"-j {jobs}: give at least 1")
    quiet = args.quiet
    if args.study == "convergence":
        from .studies.convergence import convergence_study, format_convergence

        result = convergence_study(
            case, args.vary, courant=_numbers("--courant", args.courant, single=True),
            dt=_numbers("--dt", args.dt, single=True), method=args.method, changes=args.overrides,
            against=args.against, outdir=args.output, jobs=jobs, allow_failure=args.allow_failure, quiet=quiet)
        if not quiet:
            print(format_convergence(result))
    elif args.study == "pareto":
        from .studies.pareto import format_pareto, pareto_study

        levels = _numbers("--levels", args.levels, int, single=True)
        result = pareto_study(
            case, methods=args.methods, courant=_numbers("--courant", args.courant, single=True),
            rungs=levels, time_axis=args.time, changes=args.overrides, outdir=args.output, jobs=jobs,
            allow_failure=args.allow_failure, quiet=quiet)
        if not quiet:
            print(format_pareto(result))
    elif args.study == "response":
        from .studies.response import response_study
        from .studies.response_output import format_response

        if jobs != 1:
            raise StudyInputError(f"-j {jobs}: the response study runs its levels one after the other (each starts "
                                  "from the previous one's state)")
        result = response_study(
            case, args.vary, args.output, down=args.down, settle=_numbers("--settle", args.settle, int, single=True),
            periods=_numbers("--periods", args.periods, int, single=True),
            steps_per_period=_numbers("--steps-per-period", args.steps_per_period, int, single=True),
            tolerance=_numbers("--tolerance", args.tolerance, single=True), changes=args.overrides, quiet=quiet,
            allow_failure=args.allow_failure, flight=args.flight, shooting=not args.no_shooting,
            frequency=args.frequency, shooting_seconds=_numbers("--shooting-time", args.shooting_time, single=True))
        if not quiet:
            print(format_response(result))
    else:
        from .studies.stability import format_stability, stability_study

        result = stability_study(
            case, methods=args.methods, courants=_numbers("--courant", args.courant),
            restitutions=_numbers("--restitution", args.restitution), lengths=_numbers("--length", args.length),
            tolerance=_numbers("--tolerance", args.tolerance, single=True), changes=args.overrides,
            outdir=args.output, jobs=jobs, quiet=quiet)
        if not quiet:
            print(format_stability(result))


def _plot(outdir: str, png) -> int:
    from pathlib import Path

    from ..errors import OutputFolderError
    from .outdir.writes import OutputWriteError
    from .plots import PlotError, plot_history

    if not (Path(outdir) / "history.csv").is_file():
        print(f"fem-impact: error: {outdir}: no history.csv (is it a run's output folder?)", file=sys.stderr)
        return 2
    try:
        print(f"wrote {plot_history(outdir, png)}")
    except (PlotError, OutputFolderError) as err:
        print(f"fem-impact: error: {err}", file=sys.stderr)
        return 2
    except OutputWriteError as err:
        print(f"fem-impact: the plot failed: {err}", file=sys.stderr)
        return 3
    except KeyboardInterrupt as err:
        return _interrupted(err)
    return 0


def _configure_logging(verbose: bool) -> None:
    """Our stages at INFO with -v; other libraries (the JIT compiler's build logs) only warnings."""
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(name)s: %(message)s"))
    handler.addFilter(lambda r: r.levelno >= logging.WARNING or (verbose and r.name.startswith("fem_impact")))
    logging.basicConfig(level=logging.INFO, handlers=[handler], force=True)


def _fail(comm, message: str, status: int) -> int:
    from .progress import Progress

    Progress.end_line()   # a run that failed mid-loop: the message on a line of its own
    if comm.rank == 0:
        print(f"fem-impact: {message}", file=sys.stderr)
    return status
