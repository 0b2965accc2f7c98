"""The pipeline of one run: case -> mesh -> model -> constraints -> integrator -> outputs, written atomically."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from .._version import __version__
from ..config.case import Case, load_case
from ..build import System, make_integrator  # noqa: F401  (re-exported: tests, benchmarks)
from ..errors import CaseError, SimulationError, wrong_type
from .limits import check_limits
from .outdir.claim import claim
from .outdir.policy import case_inputs
from .outdir.writes import writing

log = logging.getLogger(__name__)


def block_stepper(case: Case, integrator, n_steps: int, rank: int = 0):
    """The stepper of many steps at a time, or None (one step at a time): the reduced model's between
    contacts (``solver.blocks``, integrators/blocks.py), a modal body's scene (``bodies.NAME.blocks``,
    rigid/blocks.py)."""
    from ..integrators import is_reduced
    from ..integrators.blocks import AUTO_FROM, BlockStepper

    modal = [name for name, model in case.bodies.items() if model == "modal"]
    setting = case.solver.blocks if is_reduced(case.solver) else case.body_blocks.get(modal[0], "auto") if modal \
        else False
    if setting is False or (setting == "auto" and n_steps < AUTO_FROM):
        return None
    if is_reduced(case.solver):
        return BlockStepper.of(integrator)
    from ..rigid.blocks import MixedBlocks

    reason = MixedBlocks.refusal(integrator)
    if reason is None:
        return MixedBlocks.of(integrator)
    if setting is True and rank == 0:   # (said once: by rank 0)
        log.warning("bodies.%s.blocks: true, but this scene's steps are taken one at a time: %s", modal[0], reason)
    return None


def default_outdir(case: Case) -> Path:
    return Path.cwd() / "results" / case.name


@contextlib.contextmanager
def staged_directory(outdir: Path, comm: MPI.Comm, command: str = "run", protect=()):
    """Claim ``outdir`` (fem_impact.app.outdir: policy, lock) and write it atomically: yields the staging folder.

    A failed or interrupted run removes its staging folder and leaves ``outdir`` as it was.
    """
    with claim(outdir, comm, command, protect) as out, out.staged() as stage:
        yield stage


@dataclass
class Result:
    """What a run gives back (:func:`run`).

    Attributes
    ----------
    summary : dict
        The run's summary, as ``summary.json`` holds it (plus ``outdir``).
    outdir : Path or None
        The output folder; None when nothing was written.
    history : dict of str to numpy.ndarray
        ``history.csv``'s columns by name (``t``, ``wall.force``, ``kinetic``, ...): one value
        for t = 0 and one per step.
    """

    summary: dict
    outdir: Path | None
    _history: dict | None = None

    @property
    def history(self) -> dict[str, np.ndarray]:
        """history.csv's columns by name (read from the folder on first use when the run wrote one)."""
        if self._history is None:
            from .plots import history_columns

            self._history = history_columns(self.outdir)
        return self._history

    @classmethod
    def load(cls, outdir) -> Result:
        """The result a run wrote into ``outdir`` (its summary.json; history and fields read on use)."""
        path = Path(outdir)
        try:
            summary = json.loads((path / "summary.json").read_text())
        except (OSError, ValueError) as exc:
            raise SimulationError(f"{outdir}: not a run's output folder (summary.json: {exc})") from None
        return cls(summary, path.resolve())

    def fields(self) -> Fields:
        """The fields the run wrote with ``output.format: xdmf`` (:func:`read_fields`)."""
        if self.outdir is None:
            raise SimulationError("this run wrote no files (fem_impact.run without outdir): nothing to read")
        return read_fields(self.outdir)


@dataclass
class Fields:
    """A run's nodal fields: ``t`` (frames,), ``points`` (nodes, the coordinates as written: 2 columns in 1D
    and 2D, 3 in 3D) and ``values[name]`` (frames, nodes, 3) for u, v, a and contact_force (1D and 2D fields
    padded to 3 components, zeros), (frames, nodes, 1) for contact_state (0 open, 1 stick, 2 slip)."""

    t: np.ndarray
    points: np.ndarray
    values: dict


def read_fields(outdir) -> Fields:
    """Read ``results.xdmf`` of a run's folder with meshio (Debian's python3-meshio), frame by frame; a
    file that cannot be read (a truncated results.h5) is a SimulationError naming it."""
    from .xdmf import XdmfError, open_xdmf

    path = Path(outdir) / "results.xdmf"
    if not path.is_file():
        pvd = Path(outdir) / "results.pvd"
        why = ("its fields are ASCII VTU (results.pvd), which meshio cannot read: run it with output.format: xdmf"
               if pvd.is_file() else "it holds no fields (output.vtk: false?)")
        raise SimulationError(f"{outdir}: no results.xdmf: {why}")
    times, values = [], {}
    try:
        with open_xdmf(path) as series:
            for t, point_data in series.frames():
                times.append(t)
                for name, array in point_data.items():
                    values.setdefault(name, []).append(array)
            points = series.points
    except XdmfError as err:
        raise SimulationError(str(err)) from None
    try:
        stacked = {name: np.stack(a) for name, a in values.items()}
    except ValueError:   # (frames of different sizes: not one run's fields)
        raise SimulationError(f"{path}: its frames differ in size: a damaged file?") from None
    return Fields(np.array(times), np.asarray(points), stacked)


def run(case: Case, outdir=None, progress=False, comm: MPI.Comm | None = None,
        stop_on_energy_gain: bool = False, force: bool = False, restart=None) -> Result:
    """Run a case: the public entry point (``fem-impact run`` is a thin layer over it).

    Parameters
    ----------
    case : Case
        From :func:`fem_impact.load_case` or :meth:`fem_impact.Case.from_dict`.
    outdir : path-like, optional
        None (the default): nothing is written to disk, the history is kept in memory. A
        folder: exactly what ``fem-impact run -o OUTDIR`` writes (results.pvd, history.csv,
        summary.json, case.resolved.yaml), atomically, under the output-folder policy of
        :mod:`fem_impact.app.outdir` (a folder that is not an earlier result is never replaced).
    progress : bool or callable
        True for the time loop's progress bar (on a terminal, rank 0), or a callable
        ``(step, total)`` of the caller's own.
    comm : mpi4py communicator, optional
        Default ``MPI.COMM_WORLD``.
    stop_on_energy_gain : bool
        Raise :class:`~fem_impact.integrators.EnergyCreated` (a SimulationError) as soon as the
        scheme creates energy; by default the summary records it (``energy_created_at``).
    force : bool
        Run even when the size estimate is beyond the limits (:mod:`fem_impact.app.limits`).
    restart : path-like, optional
        Continue the run saved in this folder (a run's output folder, or a checkpoint folder) from
        its last checkpoint to the case's ``t_end`` (:mod:`fem_impact.app.checkpoint`), on as many
        MPI ranks: the same model, method and initial state (a change of any is refused, naming the
        keys); the case's loads (and the parameters they use) apply from the checkpoint's time on,
        its output settings to the new folder. The history then starts at the checkpoint's time.

    Raises
    ------
    CaseError
        The case does not fit the mesh or the limits (before anything is written), or the output
        folder is refused: at the start, or at the end when it appeared or changed during the run
        (:class:`~fem_impact.app.outdir.OutputFolderChanged`: the result is kept beside it, at ``kept``).
    SimulationError
        The run could not go on, or its files could not be written (a full disk:
        :class:`~fem_impact.app.outdir.OutputWriteError`); an output folder is then left as it was.
    TypeError
        An argument of a wrong Python type (the message says what it takes).
    """
    t_start = time.perf_counter()
    _check_arguments(case, outdir, progress, comm, stop_on_energy_gain, force)
    if restart is not None and not isinstance(restart, (str, os.PathLike)):
        raise wrong_type("run()", "restart as a folder (str or os.PathLike) or None", restart)
    comm = MPI.COMM_WORLD if comm is None else comm
    if outdir is None:
        with case.errors_at_keys():
            return _run(case, None, comm, progress, force, t_start, stop_on_energy_gain, restart)
    protect = case_inputs(case) + ((Path(restart),) if restart is not None else ())
    with claim(Path(outdir), comm, "run", protect=protect, source=case.path) as out, \
            case.errors_at_keys():
        # (a killed run's checkpoint that the claim kept in NAME.checkpoint: read there)
        return _run(case, out, comm, progress, force, t_start, stop_on_energy_gain, out.follow(restart))


def _check_arguments(case, outdir, progress, comm, stop_on_energy_gain, force) -> None:
    """TypeError, saying what run() takes, for an argument of a wrong Python type."""
    if not isinstance(case, Case):
        raise wrong_type("run()", "a Case: fem_impact.load_case(path) or Case.from_dict(data)", case)
    if outdir is not None and not isinstance(outdir, (str, os.PathLike)):
        raise wrong_type("run()", "outdir as a folder (str or os.PathLike) or None", outdir)
    if comm is not None and not isinstance(comm, MPI.Comm):
        raise wrong_type("run()", "comm as an mpi4py communicator (e.g. MPI.COMM_WORLD) or None", comm)
    if not (isinstance(progress, bool) or callable(progress)):
        raise wrong_type("run()", "progress as true, false or a callable (step, total)", progress)
    for name, value in (("stop_on_energy_gain", stop_on_energy_gain), ("force", force)):
        if not isinstance(value, bool):
            raise wrong_type("run()", f"{name} as true or false", value)


def run_case(path, outdir=None, overrides=(), comm: MPI.Comm = MPI.COMM_WORLD, progress=True,
             stop_on_energy_gain: bool = False, force: bool = False, restart=None) -> dict:
    """Run a case file into ``outdir`` (default ``results/<name>``); returns the summary.

    The command's path: :func:`load_case` with the ``--set`` overrides (or ``path`` is the Case they gave
    already), then :func:`run`.
    """
    case = path if isinstance(path, Case) else load_case(path, overrides)
    return run(case, outdir if outdir is not None else default_outdir(case), progress, comm,
               stop_on_energy_gain, force, restart).summary


def _run(case: Case, out, comm: MPI.Comm, progress, force: bool, t_start: float,
         stop_on_energy_gain: bool, restart=None) -> Result:
    """The pipeline; ``out`` is the claimed output folder, or None to write nothing."""
    outdir = out.path if out is not None else None
    check_limits(case, outdir, comm, force)
    saved = changed = None
    if restart is not None:   # (its state.json checked against the case before anything is built)
        saved, changed = _open_restart(restart, case, comm)
    # dolfinx and PETSc load in about a second: only once the case file is known to be sound.
    from ..build import build_system
    from ..integrators import EnergyWatch, integrate, is_reduced, steps_for
    from . import checkpoint
    from .outdir.interruption import install_signal_handlers
    from .output import BodyMomenta, HistoryWriter, ImpactLog, Progress, RunStatistics, VTKWriter
    from .periods import PeriodLog
    from .sliding import SlidingWatch

    install_signal_handlers()   # again: PETSc, imported just now, installs its own (SIGHUP, SIGQUIT)

    solver = case.solver
    system = build_system(case, comm, check_initial=True, probes=True)
    model, cons, probes = system.model, system.constraints, system.probes
    meshdata = model.meshdata
    if changed:   # a restart under other loads: from the checkpoint's load at its time to the case's after it
        system.operators.load = checkpoint.ChangedLoad(system.operators.load)
    integrator = make_integrator(case, system.operators, system.rigid, system.elastic,
                                 system.reduced if system.rigid is not None else None)
    if not is_reduced(solver) and system.rigid is None:
        _restitution_advice(case, system.operators)
    fields = system.fields
    if model.motion is not None:   # moving supports: the run seen as the whole structure's
        integrator, fields = model.motion.view(integrator, fields, comm)
    n_steps = steps_for(solver.t_end, solver.dt)
    # What a checkpoint holds: the state of every part of the run that carries one from step to step.
    raw = integrator.integrator if model.motion is not None else integrator
    impacts = ImpactLog(cons, case.output.period)
    stats = RunStatistics(cons)
    watch = EnergyWatch(stop_on_energy_gain, scheme=raw.name, stable=getattr(raw, "unconditionally_stable", None))
    momenta = BodyMomenta(model, fields)
    periods = PeriodLog(case.output.period, cons.contacts, momenta, impacts) if case.output.period else None
    parts = {"integrator": raw, "fields": system.fields, "watch": watch, "impacts": impacts, "statistics": stats}
    if periods is not None:
        parts["periods"] = periods
    if model.motion is not None:
        parts["motion"] = integrator
    # surface contacts: rows found again as their bodies slide (Moreau-Jean, full model), else watched
    sliding = SlidingWatch(cons, fields, comm, raw, model.fixed)
    if sliding.searching:
        parts["sliding"] = sliding
    model_keys = checkpoint.model_keys(case)
    # What the model built is, beyond the case's keys: its dofs, and the count of modes the reduced model kept.
    built = {"dofs": model.dofs, "modes": system.summary["modes"]}
    meta = {"case": case.name, "method": solver.method, "scheme": raw.name, "dt": solver.dt, **built,
            "model": model_keys, "loads": checkpoint.load_keys(case)}
    t0, restarted = 0.0, None
    # The full model's vectors are saved with their dofs' partition-independent numbers: a restart on as
    # many ranks may find the mesh distributed otherwise (the reduced model's state is replicated).
    dof_keys = None if is_reduced(solver) else model.dof_keys()
    if case.initial.source is not None and restart is None:   # initial.from: the saved run's last state
        try:
            system.U0, system.V0 = checkpoint.initial_state(case.initial.source, comm, model_keys,
                                                            is_reduced(solver), built, system.U0, dof_keys)
        except checkpoint.Damaged as err:
            raise case.error(("initial", "from"), f"{err.file}: {err.message}{_relative_note(case, err)}") from None
        if dof_keys is not None:   # (the case's supports hold their dofs at rest, as its own initial fields)
            system.U0[model.fixed] = 0.0
            system.V0[model.fixed] = 0.0
    if restart is not None:
        try:
            trees = checkpoint.read_parts(saved, comm, built, dof_keys)
            # (output.period new, or another, on restart: periods from here on, not mixed with the saved ones)
            if periods is not None and (trees.get("periods") or {}).get("period") != periods.period:
                del parts["periods"]
            integrator.start(system.U0, system.V0, 0.0)   # (allocates what the state then overwrites)
            checkpoint.restore_parts(parts, trees, saved, comm)
            if "sliding" in parts:   # (the rows the run had at its checkpoint)
                sliding.restored(raw.state)
        except checkpoint.Damaged as err:
            raise CaseError(f"--restart {err.file}", None, None, err.message) from None
        t0 = saved.t
        restarted = {"folder": str(Path(restart).resolve()), "t": saved.t, "step": saved.step,
                     "changed": changed}
    blocks = block_stepper(case, integrator, n_steps, comm.rank)
    setup_time = time.perf_counter() - t_start
    log.info("setup %.3f s: %d dofs, %d constraint rows, %d steps", setup_time, model.dofs, cons.p, n_steps)
    for c, relation in zip(cons.contacts, cons.relations.relations):
        if hasattr(relation, "describe"):
            log.info("contact %s: %s", c.name, relation.describe())

    with out.staged() if out is not None else contextlib.nullcontext(None) as stage:
        history = HistoryWriter(stage / "history.csv" if stage else None, cons, probes, comm, fields, momenta=momenta,
                                scheme_energy=getattr(integrator, "scheme_energy", False), name=case.name,
                                reactions=model.motion.names if model.motion else (),
                                numerical_loss=getattr(raw, "theta", 0.5) != 0.5, rigid=system.rigid,
                                dt=getattr(integrator, "dt", None))
        # (the sliding watch first: a step whose rows it finds again is written with them, as a restart
        # from that step's checkpoint writes it again)
        observers = ([sliding] if sliding else []) + [history, stats, impacts] + ([periods] if periods is not None
                                                                                  else [])
        vtk = None
        if case.output.vtk and stage is not None:
            vtk = VTKWriter(stage, model, fields, case.output.every, n_steps, case.output.format,
                            dt=getattr(integrator, "dt", None), cons=cons)
            observers.append(vtk)
        if hasattr(fields, "write"):   # the reduced model's fields remember the previous step
            observers.append(fields)
        if stage is not None:   # last: it saves the state every other observer has updated
            from .checkpoint import Checkpoints

            observers.append(Checkpoints(out.checkpoints, comm, parts, meta, case.output.checkpoint_every, n_steps,
                                         dof_keys))
        t_loop = time.perf_counter()
        try:
            final = integrate(integrator, system.U0, system.V0, solver.t_end, observers, watch=watch, t0=t0,
                              progress=progress if callable(progress) else Progress(comm) if progress else None,
                              resume=restart is not None, blocks=blocks)
        except BaseException:
            # Both closed now (the VTK file writes again when destroyed, after the staging folder is gone),
            # without hiding the run's own error behind a write that fails too.
            for writer in (history, vtk):
                if writer is not None:
                    with contextlib.suppress(OSError):
                        writer.close()
            raise
        try:
            history.close()
        finally:
            if vtk is not None:
                vtk.close()
        loop_time = time.perf_counter() - t_loop
        summary = {
            "case": case.name,
            "method": solver.method,
            "scheme": integrator.name,
            "wall_time_s": time.perf_counter() - t_start,
            "setup_time_s": setup_time,
            "loop_time_s": loop_time,
            "steps": final.step,
            # the steps taken many at a time (the reduced model's, a modal body's scene's), and in how many blocks
            "steps_in_blocks": blocks.steps if blocks is not None else 0,
            "blocks": blocks.blocks if blocks is not None else 0,
            "dt": solver.dt,
            "t_end": final.t,
            "dofs": model.dofs,
            "constraints": cons.p,
            **system.summary,
            "mpi_ranks": comm.size,
            "mesh": meshdata.description,
            "max_penetration": stats.max_penetration,
            "max_stop_compression": stats.max_stop_compression,
            "max_energy_error": stats.max_energy_error,
            "max_energy_error_relative": stats.max_energy_error / stats.energy_scale if stats.energy_scale else 0.0,
            "initial_energy": final.energy.initial,
            "final_energy": final.energy.total,
            "max_energy": stats.max_energy,
            # Energy the scheme created (E above E0 + W_ext(t), or a loss below zero): 0 and null when none.
            "energy_created": watch.created if watch.energy_was_created else 0.0,
            "energy_created_relative": watch.created_relative if watch.energy_was_created else 0.0,
            "energy_created_at": watch.created_at,
            "max_energy_ratio": watch.max_ratio,
            "impact_loss": final.energy.impact_loss,
            "contact_loss": final.energy.contact_loss,
            # the scheme's own dissipation (Moreau-Jean, theta > 1/2; booked in the balance) and the round-off
            # that U^T K U may carry at the displacements reached (EnergyBudget.roundoff)
            "numerical_loss": final.energy.numerical_loss,
            "energy_roundoff": watch.roundoff,
            **({"gamma": solver.gamma} if getattr(solver, "gamma", 0.5) != 0.5 else {}),
            "total_impulse": stats.total_impulse,
            "impacts": {c.name: sum(e[1] == c.name for e in impacts.close()) for c in cons.contacts},
            "body_mass": momenta.mass,
            "vtk_frames": vtk.frames if vtk else 0, "fields_file": VTKWriter.FILES[case.output.format] if vtk else None,
            "fem_impact_version": __version__,
            "restarted_from": restarted,
        }
        if sliding:   # surface contacts: how often their rows were found again as the bodies slid, in what time
            summary["surface_searches"] = sliding.searches
            summary["surface_search_s"] = [round(s, 6) for s in sliding.seconds]
        if getattr(integrator, "friction", None) is not None:   # (keys added only where friction is)
            summary.update(friction_loss=final.energy.friction_loss,
                           max_friction_residual=integrator.friction_residual,
                           max_friction_sweeps=integrator.friction_sweeps,
                           friction_retries=integrator.friction_retries)
            if getattr(integrator, "friction_impact", None) is not None:   # (position level: Carnot's correction)
                summary["friction_corrections_scaled"] = integrator.friction_scaled
                # (steps whose position-level cone problem was not solved, taken at the velocity level)
                summary["friction_velocity_steps"] = integrator.friction_velocity_steps
        # the loss columns the run's contact laws declare beyond contact_loss (added only where they are)
        summary.update({name: final.energy.losses.get(name, 0.0) for name in cons.laws.extra_columns()})
        if comm.rank == 0 and stage is not None:
            with writing(stage / "summary.json"):
                (stage / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
            with writing(stage / "case.resolved.yaml"):
                case.write_resolved(stage / "case.resolved.yaml")
            with writing(stage / "impacts.csv"):
                impacts.save(stage / "impacts.csv")
            if periods is not None:
                with writing(stage / "periods.csv"):
                    periods.save(stage / "periods.csv")
            if vtk is not None and case.output.format == "vtu":   # (view.py loads results.pvd)
                from .paraview_view import write_view_script

                with writing(stage / "view.py"):
                    write_view_script(stage, meshdata.dim, final_dir=outdir)
    summary["outdir"] = str(outdir.resolve()) if outdir is not None else None
    columns = None if outdir is not None else comm.bcast(history.columns_data(), root=0)
    return Result(summary, outdir.resolve() if outdir is not None else None, columns)


def _restitution_advice(case: Case, ops) -> None:
    """Say once when a rigid contact's restitution acts on an elastic body at a step longer than the
    shortest period its mesh carries (dt above 2 / omega_max): e then acts on the contact's nodes alone
    within a step, and the body's rebound comes from its waves and depends on the step, not on e
    (docs/case_files.md, "Restitution on an elastic body")."""
    from ..integrators.central_difference import critical_time_step

    bouncing = [(i, c) for i, c in enumerate(case.contacts)
                if c.law == "newton" and c.restitution > 0.0 and c.stiffness is None]
    if not bouncing:
        return
    limit = critical_time_step(ops)   # (collective: every rank calls it)
    if case.solver.dt <= limit or ops.comm.rank != 0:   # (said once: by rank 0)
        return
    named = ", ".join(f"contacts[{i}] ({c.name}, e = {c.restitution:g})" for i, c in bouncing)
    log.warning("%s: the restitution acts on the contact's nodes alone; at dt = %.3g, %.3g times the shortest "
                "period the mesh carries (2/omega_max = %.3g), the elastic body's rebound comes from its waves and "
                "depends on the step, not on e. For a body's restitution, model its rigid motion (solver.method: "
                "modal with its rigid modes, as cases/bouncing_ball.yaml); see docs/case_files.md, \"Restitution "
                "on an elastic body\"", named, case.solver.dt, case.solver.dt / limit, limit)


def _relative_note(case: Case, err) -> str:
    """Where a relative ``initial.from`` starts, when no checkpoint was found there."""
    written = (case.source.get("initial") or {}).get("from") if isinstance(case.source, dict) else None
    if not isinstance(written, str) or os.path.isabs(written) or Path(err.file) != case.initial.source:
        return ""
    return f" (the relative path {written!r} starts at {case.base_dir})"


def _open_restart(restart, case: Case, comm) -> tuple:
    """The checkpoint to continue (``checkpoint.Saved``) and the keys of the loads that changed since it:
    a case whose model, method or initial state differ from the checkpoint's, or that ends before it, is
    refused naming the keys (CaseError)."""
    from ..integrators.parameters import is_reduced
    from . import checkpoint

    try:
        saved = checkpoint.open_checkpoint(restart, comm)
    except checkpoint.Damaged as err:
        raise CaseError(f"--restart {err.file}", None, None, err.message) from None
    state, where = saved.state, f"--restart {restart}"
    differ = checkpoint.differences(state["model"], checkpoint.model_keys(case))
    if differ:
        same_unknowns = not checkpoint.differences(
            checkpoint.unknowns_keys(state["model"], checkpoint.reduced_of(state)),
            checkpoint.unknowns_keys(checkpoint.model_keys(case), is_reduced(case.solver)))
        hint = (f"; to start the changed case from the checkpoint's state, give it initial: {{from: {saved.folder}}}"
                if same_unknowns and not all(key.startswith("initial.") for key in differ)
                and not any(model == "rigid" for model in case.bodies.values()) else "")   # (rigid: no initial.from)
        raise CaseError(where, None, None, f"the checkpoint does not fit this case: its state depends on keys the "
                                           f"case changes: {', '.join(differ)}. A restart continues the saved run "
                                           f"under the case's loads, solver.t_end and output only{hint}")
    if saved.t >= case.solver.t_end * (1 - 1e-12):
        raise CaseError(where, "solver.t_end", None, f"the checkpoint is at t = {saved.t:.6g}, not before the case's "
                                                     f"t_end = {case.solver.t_end:.6g}: raise solver.t_end to continue")
    changed = checkpoint.differing(state["loads"], checkpoint.load_keys(case))
    if changed and is_reduced(case.solver) and case.solver.static_correction:
        raise CaseError(where, changed[0], None,
                        f"the reduced model's static correction holds the response to the saved run's loads, also "
                        f"at the checkpoint's time: a restart cannot change them ({', '.join(changed)} differ). "
                        f"Continue with the saved loads, or start a new run from the checkpoint's state with "
                        f"initial: {{from: {saved.folder}}}")
    return saved, changed


def energy_warning(summary: dict) -> str | None:
    """One line when the run created energy (printed on stderr at the end of a run), else None."""
    if summary.get("energy_created_at") is None:
        return None
    who = "the contacts" if summary.get("constraints", 1) else "the scheme"   # (a run without contact rows)
    return (f"warning: {who} created energy in {summary['case']} ({summary['method']}, dt = "
            f"{summary['dt']:.4g} s): {summary['energy_created']:.4g} J above E0 + W_ext ("
            f"{summary['energy_created_relative']:.3g} of the energy scale), first at t = "
            f"{summary['energy_created_at']:.6g} s; max E / (E0 + W_ext) = {summary['max_energy_ratio']:.3g}. "
            f"{energy_advice(summary)}")


def energy_advice(summary: dict) -> str:
    """What to change after energy was created, for the method that ran."""
    reduced = summary.get("modes") is not None
    if summary.get("scheme", summary["method"]) != "moreau_jean":
        switch = "solver.scheme: moreau_jean" if reduced else "solver.method: moreau_jean"
        return f"The results are not physical: use {switch} (stable at any step), or a smaller dt"
    if reduced and summary.get("static_correction"):
        return ("The reduced model's contact rows are compliant (static correction); under a load that varies "
                "over a step they gain energy of order dt^2: use a smaller dt")
    return ("Moreau-Jean's contacts cannot create energy beyond round-off: check the case (a smaller dt), and "
            "report it if it persists")


def describe(summary: dict) -> str:
    """The one-paragraph report printed at the end of a run."""
    restarted = summary.get("restarted_from")
    run_steps = summary["steps"] - (restarted["step"] if restarted else 0)
    start = f" from t = {restarted['t']:.4g} s (restarted from {restarted['folder']}" + (
        f", under changed loads: {', '.join(restarted['changed'])})" if restarted.get("changed") else ")") \
        if restarted else ""
    return (
        f"{summary['case']}: {run_steps} steps of {summary['dt']:.4g} s{start} to t = {summary['t_end']:.4g} s, "
        f"{summary['dofs']} unknowns, {summary['constraints']} contact rows, {summary['method']} "
        f"on {summary['mpi_ranks']} rank(s). Wall time {summary['wall_time_s']:.2f} s "
        f"(setup {summary['setup_time_s']:.2f} s, loop {summary['loop_time_s']:.2f} s, "
        f"{1e3 * summary['loop_time_s'] / max(run_steps, 1):.3f} ms/step). "
        f"Max penetration {summary['max_penetration']:.3g}"
        + (f", elastic stops compressed by up to {summary['max_stop_compression']:.3g}"
           if summary.get("max_stop_compression") else "")
        + "; energy-balance residual "
        f"{summary['max_energy_error']:.3g} ({summary['max_energy_error_relative']:.2g} of the energy scale"
        f"{_residual_note(summary)}); "
        f"impact loss {summary['impact_loss']:.4g}, contact loss {summary['contact_loss']:.4g}"
        + (f", numerical dissipation {summary['numerical_loss']:.4g} (the scheme's, theta > 1/2: booked in the "
           "balance)" if summary.get("numerical_loss") else "") + ". "
        f"Results in {summary['outdir']} ({', '.join(_files_written(summary))})."
        + _reduction_note(summary)
    )


def _residual_note(summary: dict) -> str:
    """What a residual above round-off of the energy scale is, where the run knows it."""
    from ..mechanics.energy import ENERGY_TOLERANCE

    if summary["max_energy_error_relative"] <= ENERGY_TOLERANCE:
        return ""
    if summary.get("gamma", 0.5) > 0.5:
        return (f"; Newmark's gamma = {summary['gamma']:.4g} > 1/2 damps the high frequencies: the residual is "
                "that numerical dissipation, which the balance does not book")
    if summary["max_energy_error"] <= summary.get("energy_roundoff", 0.0):
        return (f"; within the round-off of the strain energy U^T K U at the displacements reached, "
                f"{summary['energy_roundoff']:.3g}: a stiff body moved far from where K U = 0")
    return ""


def _files_written(summary: dict) -> list[str]:
    """The main files of a run's folder (the VTK series only when it wrote frames: output.vtk)."""
    fields = summary.get("fields_file") or "results.pvd"
    return ([fields] if summary.get("vtk_frames") else []) + ["history.csv", "summary.json",
                                                                     "case.resolved.yaml"]


def _reduction_note(summary: dict) -> str:
    if summary.get("modes") is None:
        return ""
    flex = ", ".join(f"{k} {v:.3g}" for k, v in summary["neglected_flexibility"].items())
    note = (f" Reduced model: {summary['modes']} modes ({summary['rigid_modes']} rigid; "
            f"{summary['modes_reason']}), cut-off "
            f"{summary['cutoff_hz']:.4g} Hz, static correction {'on' if summary['static_correction'] else 'off'}"
            f"{', neglected flexibility ' + flex if flex else ''}.")
    if summary.get("reused_from_cache"):
        note += f" Reused from the cache: {' and '.join(summary['reused_from_cache'])}."
    return note
