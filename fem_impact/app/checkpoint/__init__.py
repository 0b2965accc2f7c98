"""Checkpoints: a run's whole state on disk, to continue it later (``fem-impact run CASE --restart DIR``).

A checkpoint is a folder ``checkpoint/`` in the run's output folder (docs/running.md, "Checkpoint and
restart"):

- ``state.json``: where the state stands (``format``, ``t``, ``step``, ``ranks``) and what it
  depends on: ``model``, the case's keys that define the model, its constraints, the method and
  its keys, the initial state and the parameters these use (flat, dotted keys: what a restart
  compares), ``loads``, the loads and the parameters they use (what a restart may change), and
  ``dofs`` and ``modes`` (the reduced model's count, which ``modes: auto`` chose);
- ``rank-R.h5`` (HDF5, one per MPI rank: the distributed vectors are each rank's owned entries):
  its rank, the checkpoint's ``t``, ``step`` and a digest of ``state.json`` (a file of another
  checkpoint, or an edited ``state.json``, is refused), and one group per stateful part of the run
  (``integrator``, ``motion``, ``fields``, ``watch``, ``impacts``) with that part's state: arrays
  as datasets, numbers and strings as HDF5 attributes, nested values (the step's state, its energy
  budget, a pair) as subgroups.

What a part's state is, it declares: ``__checkpoint__``, the names of its attributes that carry the
run from step to step (the state vectors and the products the next step reads, the step's
StepState and EnergyBudget, a solver's warm start, an impact under way). Everything else (matrices,
factors, the load's vectors, the method's constants) the restarted run builds from its case, which
``state.json``'s ``model`` must match key by key: a restart applies the case's loads (from the
checkpoint's time on: the step from it starts from the load the saved run had there), its
``solver.t_end``, ``solver.blocks`` and ``output``, and refuses a change of anything else, naming
every key that differs. Two attributes holding one array (the integrator's state vectors and its
StepState's) are stored once and linked again on restore.

A checkpoint that cannot be read (a file missing, truncated, not what it should hold) is refused in
one line naming the file; under MPI every rank checks its own files and the ranks agree before any
of them goes on.

A checkpoint is written into ``checkpoint.new/`` and renamed over ``checkpoint/`` when every rank
has written its file: an interruption mid-write leaves the previous one whole.
"""


# The modules, by concern: ``layout`` (the files, the format, HDF5 trees), ``keys`` (what a run's state
# depends on, compared on restart), ``state`` (an object's declared state: capture, check, restore),
# ``writing`` (the run's checkpoints), ``reading`` (a checkpoint read, checked, the ranks agreeing).
# What the run uses (fem_impact/app/pipeline.py):
from .keys import ChangedLoad, differences, differing, load_keys, model_keys, unknowns_keys
from .reading import Damaged, Saved, initial_state, open_checkpoint, read_parts, reduced_of, restore_parts
from .writing import Checkpoints

__all__ = ["ChangedLoad", "Checkpoints", "Damaged", "Saved", "differences", "differing", "initial_state", "load_keys",
           "model_keys", "open_checkpoint", "read_parts", "reduced_of", "restore_parts", "unknowns_keys"]
