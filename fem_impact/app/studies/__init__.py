"""Studies that run a case many times: convergence orders, the speed-accuracy (Pareto) chart, the
stability map, and the reduction table (reduced against the full model).

Every study works on a :class:`~fem_impact.config.case.Case`: each run is a copy of it with changes
(``Case.with_changes``): its method's, then the changes given to the study (the command line's
``--set`` options), then the run's own (mesh, time step, ...).

- ``methods``: the registry of integration methods compared (name -> case changes; ``apply``);
- ``levels``: running levels (one run each, in its own folder) in-process or in parallel
  processes, with progress, resume and failure handling;
- ``worker``: one level's run (``fem_impact.run``) and the status it reports, in this process or
  in a child (``python -m fem_impact.app.studies.worker SPEC.json``);
- ``convergence``, ``pareto``, ``stability``: the three ``fem-impact study`` commands;
- ``common``, ``resolution``: what they share (files, error rows, order fits; c, h, Courant number);
- ``reduction``: ``fem-impact reduction``.
- ``response`` (the sweep and its options), ``response_period`` (the Poincare section's period),
  ``response_orbits`` (event-driven levels, shooting), ``response_output`` (response.csv, the chart, the
  table): ``fem-impact study response``.
"""

__all__ = ["REDUCTION_COLUMNS", "format_reduction", "reduction_table"]


def __getattr__(name):
    # The reduction table needs MPI and the pipeline: imported when asked for, so that building
    # the command line (which lists the methods) stays light.
    if name in __all__:
        from . import reduction

        return getattr(reduction, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
