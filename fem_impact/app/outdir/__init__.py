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


# The modules, by concern:
# - policy: which folders and files may be written or replaced (check, and the refusals);
# - manifest: what a result folder holds (the marker and its list of files), foreign entries, removal;
# - writes: writing a file whole or not at all, and the one line for a failed write;
# - claim: the lock, a killed run's debris, the staging folder and its install;
# - in_place: a study's folder, written directly;
# - single_file: a picture or an animation (plot, animate);
# - interruption: signals, and the exit status they give.
