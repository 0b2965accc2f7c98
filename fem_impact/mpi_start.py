"""How Open MPI starts in a process started alone (not by mpirun): set before mpi4py loads.

A process started alone is one MPI process: Open MPI need not start a daemon nor probe the network's
transports for it (most of a tiny run's start). Shared memory stays among its transports: an mpirun started
from such a process (a test, a script) passes these settings on to its ranks, which must reach each other. Isolated processes all take job family 0, so they would
share one session folder, and one process's MPI_Finalize could remove it while another's MPI_Init creates
its own inside: each gets a base folder of its own, removed at exit. hwloc's OpenGL component is left out:
at every start it connects to the X displays it finds (:0, :1, ...), and an X server that shuts down during
that query ends the run ("X connection to :0 broken"); fem-impact places no work on graphics cards. A user's
own settings win; mpirun's ranks keep theirs (they may span machines).
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile

SERIAL_MPI = {"OMPI_MCA_ess_singleton_isolated": "1", "OMPI_MCA_pml": "ob1", "OMPI_MCA_btl": "self,vader",
              "HWLOC_COMPONENTS": "-gl"}
SESSION_BASE = "FEM_IMPACT_MPI_SESSION_BASE"   # the session folder's base fem-impact chose (not the user)
_LAUNCHED = ("OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK", "PMI_SIZE")
_OWN: list[str] = []


def started_alone() -> bool:
    return not any(key in os.environ for key in _LAUNCHED)


def serial_start() -> None:
    """The command line's start: the settings for one process, and a session folder of its own."""
    if started_alone():
        for key, value in SERIAL_MPI.items():
            os.environ.setdefault(key, value)
    own_session()


def own_session() -> None:
    """A session base of this process's own when it starts isolated and its base is not the user's (a child
    of a fem-impact process inherits its parent's base and replaces it). Once per process."""
    if _OWN or not started_alone() or os.environ.get("OMPI_MCA_ess_singleton_isolated") != "1":
        return
    base = os.environ.get("OMPI_MCA_orte_tmpdir_base")
    if base is not None and base != os.environ.get(SESSION_BASE):
        return   # the user's
    folder = tempfile.mkdtemp(prefix="fem-impact-mpi-")
    os.environ["OMPI_MCA_orte_tmpdir_base"] = os.environ[SESSION_BASE] = folder
    _OWN.append(folder)
    atexit.register(shutil.rmtree, folder, True)   # (after MPI_Finalize when registered before mpi4py loads)
