"""A run's ``results.xdmf`` (``output.format: xdmf``) read back with meshio: the mesh and the nodal
fields frame by frame, for ``Result.fields`` and ``fem-impact animate``.

Nothing here imports dolfinx or MPI. A file that cannot be read (a truncated ``results.h5``, a
damaged index) is one :class:`XdmfError` line naming it, never a reader's traceback.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np


class XdmfError(Exception):
    """``results.xdmf`` or its ``results.h5`` cannot be read (one line, naming the file)."""


@dataclass
class XdmfSeries:
    """The mesh of a run's XDMF output and a reader of its frames."""

    path: Path
    points: np.ndarray     # (nodes, gdim)
    cells: list            # meshio CellBlocks
    times: np.ndarray      # (frames,)
    _reader: object

    def frames(self) -> Iterator[tuple[float, dict[str, np.ndarray]]]:
        """(t, point arrays by name) of each frame, in the file's order."""
        for k in range(len(self.times)):
            try:
                t, point_data, _ = self._reader.read_data(k)
            except Exception as err:   # (meshio and h5py raise what the damage makes them: OSError, KeyError, ...)
                raise XdmfError(_cannot(self.path, err, f"frame {k}")) from None
            yield float(t), {name: np.asarray(a) for name, a in point_data.items()}


def _cannot(path: Path, err: Exception, where: str = "") -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    h5 = path.with_suffix(".h5")
    return (f"{path}{' (' + where + ')' if where else ''}: cannot read the fields ({type(err).__name__}: {text}); "
            f"a damaged or incomplete {path.name} or {h5.name}?")


class open_xdmf:
    """``with open_xdmf(path) as series``: the mesh and times of ``path``, its frames on demand."""

    def __init__(self, path):
        self.path = Path(path)
        self._reader = None

    def __enter__(self) -> XdmfSeries:
        import meshio
        import meshio.xdmf.common

        # dolfinx writes a 1D mesh's intervals as XDMF "PolyLine", meshio 1.x knows "Polyline" only
        meshio.xdmf.common.xdmf_to_meshio_type.setdefault("PolyLine", "line")
        try:
            self._reader = meshio.xdmf.TimeSeriesReader(str(self.path))
            self._reader.__enter__()
            points, cells = self._reader.read_points_cells()
            if points is None or not cells:
                raise ValueError("no mesh (Geometry and Topology) in it")
            times = np.array([_time(self._reader, k) for k in range(self._reader.num_steps)])
        except Exception as err:
            self.__exit__(None, None, None)
            raise XdmfError(_cannot(self.path, err)) from None
        if not len(times):
            self.__exit__(None, None, None)
            raise XdmfError(f"{self.path}: no frames")
        return XdmfSeries(self.path, np.asarray(points, dtype=float), cells, times, self._reader)

    def __exit__(self, *exc):
        if self._reader is not None:
            try:
                self._reader.__exit__(None, None, None)
            except Exception:   # (closing a reader of a damaged file: nothing left to say)
                pass
            self._reader = None
        return False


def _time(reader, k: int) -> float:
    """The time of step k from the XDMF index alone (no read of the heavy data)."""
    grid = reader.collection[k]
    for child in grid:
        if child.tag == "Time":
            return float(child.attrib["Value"])
    raise ValueError(f"step {k} has no Time")
