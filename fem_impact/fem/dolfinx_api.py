"""The only module that calls version-bound dolfinx 0.5 API (meshes, spaces, assembly, VTK)."""

from __future__ import annotations

import errno
import logging
import os
from pathlib import Path

import numpy as np
import ufl
from dolfinx import cpp as _cpp
from dolfinx import fem, io, mesh
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI
from petsc4py import PETSc

from .partition import cell_centres, distributed_partition


# FFCx logs every JIT compilation at INFO level on the root logger: keep it quiet.
for _name in ("ffcx", "UFL", "FFC", "dijitso"):
    logging.getLogger(_name).setLevel(logging.WARNING)


def _not_a_build_line(record: logging.LogRecord) -> bool:
    return record.levelno >= logging.WARNING or record.name != "root"


# While the JIT compiles a form, setuptools lowers the root logger to INFO (distutils' threshold):
# its "running build_ext" and compiler lines would reach a script's stderr through the root
# handler ffcx installs (logging.basicConfig at its import).
for _handler in logging.root.handlers:
    _handler.addFilter(_not_a_build_line)

Mesh = mesh.Mesh


def _reproducible_graph_partitioner(comm, nparts, graph, ghosting):
    offsets, ranks = distributed_partition(comm, nparts, np.asarray(graph.offsets), np.asarray(graph.array), ghosting)
    return _cpp.graph.AdjacencyList_int32(np.ascontiguousarray(ranks, dtype=np.int32),
                                          np.ascontiguousarray(offsets, dtype=np.int32))


# Every mesh is distributed by fem_impact.fem.partition (PT-Scotch's partition changes from run to run).
_PARTITIONER = mesh.create_cell_partitioner(_reproducible_graph_partitioner)


def interval(comm: MPI.Comm, cells: int, length: float) -> Mesh:
    """A 1D mesh of ``cells`` equal cells on [0, length]."""
    with cell_centres(_grid_centres((cells,), (length,), fastest=0)):
        return mesh.create_interval(comm, cells, [0.0, length], partitioner=_PARTITIONER)


def rectangle(comm: MPI.Comm, nx: int, ny: int, length: float, height: float, hex: bool = False) -> Mesh:
    """A triangle (``hex``: quadrilateral) mesh of [0, length] x [0, height]."""
    cell = mesh.CellType.quadrilateral if hex else mesh.CellType.triangle
    centres = _grid_centres((nx, ny), (length, height), fastest=1 if hex else 0, per_square=1 if hex else 2)
    with cell_centres(centres):
        return mesh.create_rectangle(comm, [np.array([0.0, 0.0]), np.array([length, height])], [nx, ny],
                                     cell_type=cell, partitioner=_PARTITIONER)


def box(comm: MPI.Comm, n: tuple[int, int, int], size: tuple[float, float, float], hex: bool = False) -> Mesh:
    """A tetrahedron (``hex``: hexahedron) mesh of [0, Lx] x [0, Ly] x [0, Lz]."""
    cell = mesh.CellType.hexahedron if hex else mesh.CellType.tetrahedron
    with cell_centres(_grid_centres(n, size, fastest=0, per_square=1 if hex else 6)):
        return mesh.create_box(comm, [np.zeros(3), np.array(size, dtype=float)], list(n), cell_type=cell,
                               partitioner=_PARTITIONER)


def _grid_centres(n: tuple[int, ...], size: tuple[float, ...], fastest: int, per_square: int = 1) -> np.ndarray:
    """The centres of the squares (cubes) of a grid of ``n`` cells on [0, size], one row per cell in
    the order dolfinx 0.5's ``create_interval/rectangle/box`` hand them to the partitioner: squares
    with the index along axis ``fastest`` running fastest (the others in axis order), each split
    into ``per_square`` consecutive cells. (tests/test_partition.py checks this order against the
    meshes' ``original_cell_index``.)"""
    n = tuple(int(k) for k in n)
    axes = [fastest] + [a for a in range(len(n)) if a != fastest]
    index = np.arange(int(np.prod(n)))
    centre = np.empty((index.size, len(n)))
    for a in axes:
        centre[:, a] = (index % n[a] + 0.5) * (float(size[a]) / n[a])
        index //= n[a]
    return np.repeat(centre, per_square, axis=0)


def gmsh_cells_to_mesh(comm: MPI.Comm, gmsh_type: int, cells: np.ndarray, x: np.ndarray, cell_values: np.ndarray,
                       gdim: int):
    """Mesh and cell tags from Gmsh elements of one type, given on rank 0 (empty arrays elsewhere).

    ``cells`` holds node numbers (rows of ``x``) in Gmsh's local order; a node's number is its input
    index (``input_nodes_to_vertices``). As ``gmshio.model_to_mesh``, without a gmsh model in this process.
    """
    from dolfinx.io import gmshio   # (it loads the gmsh library: a fifth of a run's start, for Gmsh files only)

    try:
        domain = gmshio.ufl_mesh(gmsh_type, gdim)
    except KeyError:
        raise ValueError(f"dolfinx has no cell for Gmsh element type {gmsh_type}") from None
    cells = np.asarray(cells, dtype=np.int64)
    cells = cells[:, gmshio.cell_perm_array(_cpp.mesh.to_type(str(domain.ufl_cell())), cells.shape[1])]
    x = np.asarray(x, dtype=float)[:, :gdim]
    with cell_centres(x[cells].mean(axis=1) if cells.size else None):
        msh = mesh.create_mesh(comm, cells, x, domain, partitioner=_PARTITIONER)
    tdim = msh.topology.dim
    entities, values = _cpp.io.distribute_entity_data(msh._mesh, tdim, cells, np.asarray(cell_values, dtype=np.int32))
    msh.topology.create_connectivity(tdim, 0)
    cell_tags = mesh.meshtags_from_entities(msh, tdim, _cpp.graph.AdjacencyList_int32(entities),
                                            values.astype(np.int32))
    return msh, cell_tags


def vertex_input_indices(msh: Mesh) -> np.ndarray:
    """The input index (row of the coordinates given to ``create_mesh``) of each local vertex, owned and ghost."""
    tdim = msh.topology.dim
    msh.topology.create_connectivity(0, tdim)
    msh.topology.create_connectivity(tdim, 0)
    index_map = msh.topology.index_map(0)
    vertices = np.arange(index_map.size_local + index_map.num_ghosts, dtype=np.int32)
    geometry_nodes = _cpp.mesh.entities_to_geometry(msh._mesh, 0, vertices, False)[:, 0]
    return np.asarray(msh.geometry.input_global_indices)[geometry_nodes]


def input_nodes_to_vertices(msh: Mesh, nodes: np.ndarray) -> np.ndarray:
    """Local indices (owned and ghost) of the vertices whose input index is in ``nodes``: identity, not
    position, so coincident nodes stay apart."""
    return np.flatnonzero(np.isin(vertex_input_indices(msh), nodes)).astype(np.int32)


def locate_vertices(msh: Mesh, marker) -> np.ndarray:
    """Local indices of the vertices whose coordinates (3 x n array) satisfy ``marker``."""
    return mesh.locate_entities(msh, 0, marker)


def vector_space(msh: Mesh):
    """Continuous P1 displacement space with one component per geometric dimension."""
    return fem.VectorFunctionSpace(msh, ("CG", 1))


def scalar_space(msh: Mesh):
    return fem.FunctionSpace(msh, ("CG", 1))


def node_coordinates(V) -> np.ndarray:
    """Coordinates (n_blocks x 3) of the nodes of P1 space ``V``, local numbering (owned, then ghosts)."""
    Q = scalar_space(V.mesh)
    if not np.array_equal(Q.dofmap.list.array, V.dofmap.list.array):
        raise RuntimeError("scalar and vector P1 dof maps differ; cannot tabulate node coordinates")
    return Q.tabulate_dof_coordinates()


def node_keys(V) -> np.ndarray:
    """A partition-independent number per node of P1 space ``V`` (local numbering, owned then ghosts): its
    index in the mesh as read or built (the geometry's input index). Two runs on as many ranks may number
    and distribute the nodes differently; these numbers are the same."""
    msh = V.mesh
    geometry = msh.geometry.dofmap.array
    nodes = V.dofmap.list.array
    if geometry.size != nodes.size:
        raise RuntimeError("the P1 space's cells and the geometry's differ; cannot key the nodes")
    keys = np.full(V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts, -1, dtype=np.int64)
    keys[nodes] = np.asarray(msh.geometry.input_global_indices, dtype=np.int64)[geometry]
    return keys


def vertex_dofs(V, vertices: np.ndarray) -> np.ndarray:
    """Local node (block) indices of the given local vertices."""
    return fem.locate_dofs_topological(V, 0, vertices)


def owned_nodes(V) -> tuple[int, int]:
    """(number of owned nodes on this rank, global index of the first one)."""
    index_map = V.dofmap.index_map
    return index_map.size_local, index_map.local_range[0]


def cell_nodes(V) -> np.ndarray:
    """Node (block) indices of every local cell (owned and ghost), one row per cell."""
    return V.dofmap.list.array.reshape(-1, V.dofmap.cell_dofs(0).size)


def assemble_matrix(form) -> PETSc.Mat:
    A = fem_petsc.assemble_matrix(fem.form(form))
    A.assemble()
    return A


def assemble_vector(form) -> PETSc.Vec:
    b = fem_petsc.assemble_vector(fem.form(form))
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    return b


def assemble_scalar(form) -> float:
    """This rank's part of a scalar form's value (the caller sums over the ranks)."""
    return float(fem.assemble_scalar(fem.form(form)))


def body_measure(msh: Mesh, cell_tags):
    """Cell measure that can be restricted to a body with ``dx(tag)``."""
    return ufl.Measure("dx", domain=msh, subdomain_data=cell_tags)


def boundary_facet_measure(msh: Mesh, vertices: np.ndarray, cell_tags, bodies: dict[str, int]):
    """The boundary facets (edges in 2D, faces in 3D, end points in 1D) whose vertices are all in
    ``vertices`` (local indices), tagged by the body of the cell they bound (its cell tag; 1 where the mesh
    has one body): ``(ds, {body: tag})``, ``ds(tag)`` integrating over that body's facets."""
    tdim = msh.topology.dim
    fdim = tdim - 1
    facets = _boundary_facets_within(msh, vertices)
    f2c = msh.topology.connectivity(fdim, tdim)
    if cell_tags is None:
        tags = {name: 1 for name in bodies}
        values = np.ones(facets.size, dtype=np.int32)
    else:
        tag_of_cell = np.zeros(msh.topology.index_map(tdim).size_local + msh.topology.index_map(tdim).num_ghosts,
                               dtype=np.int32)
        tag_of_cell[cell_tags.indices] = cell_tags.values
        tags = dict(bodies)
        values = tag_of_cell[f2c.array[f2c.offsets[facets]]]   # (a boundary facet bounds one cell)
    marked = mesh.meshtags(msh, fdim, facets, values.astype(np.int32))
    return ufl.Measure("ds", domain=msh, subdomain_data=marked), tags


def _boundary_facets_within(msh: Mesh, vertices: np.ndarray) -> np.ndarray:
    """This rank's boundary facets (sorted local indices) whose vertices are all in ``vertices``."""
    tdim = msh.topology.dim
    fdim = tdim - 1
    msh.topology.create_connectivity(fdim, 0)
    msh.topology.create_connectivity(fdim, tdim)
    outside = mesh.exterior_facet_indices(msh.topology)
    f2v = msh.topology.connectivity(fdim, 0)
    inside = np.zeros(msh.topology.index_map(0).size_local + msh.topology.index_map(0).num_ghosts, dtype=bool)
    inside[vertices] = True
    # (a facet's vertices are f2v.array[offsets[f]:offsets[f + 1]]: all inside where none is outside)
    outside = np.asarray(outside, dtype=np.int32)
    count = np.diff(f2v.offsets)[outside]
    where = np.repeat(f2v.offsets[outside], count) + np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    missing = np.add.reduceat(~inside[f2v.array[where]], np.cumsum(count) - count) if outside.size else count
    return np.sort(outside[missing == 0])


def boundary_facet_nodes(V, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The boundary facets of this rank whose vertices are all in ``vertices`` (local), as
    ``(nodes, x, inside)``: their nodes' global numbers in the P1 space ``V`` (f x k, the reference
    facet's vertex order: a quadrilateral's in tensor order 0 1 / 2 3), the nodes' coordinates
    (f x k x 3) and the centre of the cell each bounds (f x 3, on the body's side of the facet)."""
    msh = V.mesh
    tdim = msh.topology.dim
    fdim = tdim - 1
    facets = _boundary_facets_within(msh, vertices)
    msh.topology.create_connectivity(tdim, 0)
    f2v, f2c = msh.topology.connectivity(fdim, 0), msh.topology.connectivity(fdim, tdim)
    c2v = msh.topology.connectivity(tdim, 0)
    cells = cell_nodes(V)
    if c2v.array.size != cells.size:
        raise RuntimeError("the P1 space's cells and the mesh's vertices differ; cannot find facet nodes")
    # (P1: a cell's nodes are its vertices, in the same order)
    node_of_vertex = np.full(msh.topology.index_map(0).size_local + msh.topology.index_map(0).num_ghosts, -1,
                             dtype=np.int64)
    node_of_vertex[c2v.array] = cells.reshape(-1)
    per_facet = int(np.diff(f2v.offsets)[0]) if f2v.offsets.size > 1 else tdim
    local = node_of_vertex[f2v.array.reshape(-1, per_facet)[facets]] if facets.size else np.zeros((0, per_facet),
                                                                                                    dtype=np.int64)
    nodes = V.dofmap.index_map.local_to_global(local.reshape(-1).astype(np.int32)).reshape(local.shape)
    x = node_coordinates(V)
    cell = f2c.array[f2c.offsets[facets]]   # (a boundary facet bounds one cell)
    inside = x[cells[cell]].mean(axis=1) if facets.size else np.zeros((0, 3))
    return np.asarray(nodes, dtype=np.int64), x[local], inside


def function(V, name: str):
    f = fem.Function(V)
    f.name = name
    return f


class _NodalScalars:
    """Scalar fields on V's nodes (a P1 space of one component on V's mesh): their values given per
    owned node of V, in V's order."""

    def __init__(self, V, names):
        bs = V.dofmap.index_map_bs
        if bs > 1:
            Q, dofs = V.sub(0).collapse()
            self.node = np.asarray(dofs, dtype=np.int64) // bs   # (V's node of each of Q's dofs)
        else:
            Q = V
            self.node = np.arange(V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts)
        self.owned = Q.dofmap.index_map.size_local
        self.functions = {name: function(Q, name) for name in names}

    def set(self, name: str, values: np.ndarray) -> None:
        f = self.functions[name]
        f.x.array[:self.owned] = values[self.node[:self.owned]]
        f.x.scatter_forward()


class VTKSeries:
    """A ParaView time series (.pvd, one .vtu/.pvtu piece per frame) of nodal vector fields, and of
    nodal scalars (``scalars``: one value per owned node).

    dolfinx 0.5 cannot write a one-component vector space, so 1D fields are written as 3D
    vectors (x component filled) on the same nodes: ParaView's Warp By Vector works the same.
    """

    def __init__(self, comm: MPI.Comm, path, V, names, scalars=()):
        self.bs = V.dofmap.index_map_bs
        W = V if self.bs > 1 else fem.VectorFunctionSpace(V.mesh, ("CG", 1), dim=3)
        self.out_bs = W.dofmap.index_map_bs
        self.functions = {name: function(W, name) for name in names}
        self.scalars = _NodalScalars(V, scalars)
        self._file = io.VTKFile(comm, str(path), "w")
        self._path, self._comm = Path(path), comm
        self._frames = 0

    def write(self, t: float, owned_values: dict) -> None:
        """Write one frame; ``owned_values`` maps a field name to its owned dof values.

        dolfinx 0.5 ignores a failed write of a frame's files (a full disk leaves them empty or cut
        short): each rank reads the end of its piece back, and all raise OSError if one is incomplete.
        """
        for name, values in owned_values.items():
            if name in self.scalars.functions:
                self.scalars.set(name, values)
                continue
            f = self.functions[name]
            blocks = values.reshape(-1, self.bs)
            f.x.array.reshape(-1, self.out_bs)[: blocks.shape[0], : self.bs] = blocks
            f.x.scatter_forward()
        self._file.write_function(list(self.functions.values()) + list(self.scalars.functions.values()), t)
        stem, rank = self._path.stem, self._comm.rank
        files = [self._path.with_name(f"{stem}_p{rank}_{self._frames:06d}.vtu")]
        if rank == 0:
            files.append(self._path.with_name(f"{stem}{self._frames:06d}.pvtu"))
        self._frames += 1
        bad = next((str(f) for f in files if not _complete_xml(f)), None)
        bad = self._comm.allgather(bad)
        if any(bad):
            raise _unwritten(Path(next(b for b in bad if b)))

    def close(self) -> None:
        # dolfinx 0.5 rewrites the .pvd when the file object is destroyed: destroy it now,
        # before the output folder is moved into place (or removed, when this fails).
        file, self._file = self._file, None
        if file is None:
            return
        try:
            file.close()
        except RuntimeError:   # "Could not write VTKFile": the .pvd
            del file
            raise _unwritten(self._path) from None
        del file
        if self._comm.rank == 0:
            _drop_repeated_pieces(self._path)


class XDMFSeries:
    """A binary time series of nodal vector fields: ``NAME.xdmf`` (XML) and ``NAME.h5`` (HDF5), as
    dolfinx's XDMFFile writes them; meshio (``meshio.xdmf.TimeSeriesReader``), pyvista and
    ParaView read it. The same fields and the same 1D rule as :class:`VTKSeries`."""

    def __init__(self, comm: MPI.Comm, path, V, names, scalars=()):
        self.bs = V.dofmap.index_map_bs
        W = V if self.bs > 1 else fem.VectorFunctionSpace(V.mesh, ("CG", 1), dim=3)
        self.out_bs = W.dofmap.index_map_bs
        self.functions = {name: function(W, name) for name in names}
        self.scalars = _NodalScalars(V, scalars)
        self._path, self._comm = Path(path), comm
        silence_hdf5_errors()
        try:
            self._file = io.XDMFFile(comm, str(self._path), "w")
            self._file.write_mesh(V.mesh)
        except RuntimeError:   # (HDF5's failed write, e.g. a full disk)
            raise _unwritten(self._path.with_suffix(".h5")) from None

    def write(self, t: float, owned_values: dict) -> None:
        """Write one frame; ``owned_values`` maps a field name to its owned dof values."""
        for name, values in owned_values.items():
            if name in self.scalars.functions:
                self.scalars.set(name, values)
                f = self.scalars.functions[name]
            else:
                f = self.functions[name]
                blocks = values.reshape(-1, self.bs)
                f.x.array.reshape(-1, self.out_bs)[: blocks.shape[0], : self.bs] = blocks
                f.x.scatter_forward()
            try:
                self._file.write_function(f, t)
            except RuntimeError:   # (HDF5's failed write, e.g. a full disk)
                raise _unwritten(self._path.with_suffix(".h5")) from None

    def close(self) -> None:
        file, self._file = self._file, None
        if file is not None:
            try:
                file.close()
            except RuntimeError:
                raise _unwritten(self._path.with_suffix(".h5")) from None
            if self._comm.rank == 0:
                _one_collection(self._path)


def silence_hdf5_errors() -> None:
    """HDF5 prints its whole error stack (dozens of "HDF5-DIAG" lines) on stderr when a write fails, before
    dolfinx raises: the run says what failed in one line. Turns that printing off (``H5Eset_auto2``) in every
    HDF5 library of the process (dolfinx's is not h5py's, which keeps its own off)."""
    import ctypes

    try:
        with open("/proc/self/maps") as maps:
            libraries = {line.split()[-1] for line in maps if "/libhdf5" in line and "_hl" not in line}
    except OSError:
        return
    for library in libraries:
        try:
            set_auto = ctypes.CDLL(library).H5Eset_auto2
        except (OSError, AttributeError):
            continue
        set_auto.argtypes = [ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p]   # (hid_t, H5E_auto2_t, void *)
        set_auto(0, None, None)   # H5E_DEFAULT: the default error stack


def _one_collection(path: Path) -> None:
    """Rewrite dolfinx's XDMF (one temporal collection per field) as one collection whose grids hold
    every field of their time: meshio's TimeSeriesReader and pyvista read a single collection. Only
    the XML changes; the data stay in the .h5 where dolfinx wrote them."""
    import xml.etree.ElementTree as ET

    try:
        domain = ET.parse(path).getroot().find("Domain")
    except (ET.ParseError, OSError):   # (dolfinx wrote it cut short: a full disk)
        raise _unwritten(path) from None
    # (dolfinx leaves the floats' precision out, which XDMF reads as 4 bytes: VTK and ParaView
    # then read the float64 data as float32; say 8)
    for item in domain.iter("DataItem"):
        if item.get("NumberType") is None:
            item.set("NumberType", "Float")
            item.set("Precision", "8")
    grids = domain.findall("Grid")
    mesh = next(g for g in grids if g.get("GridType") == "Uniform")
    frames: dict[str, list[str]] = {}
    for collection in (g for g in grids if g.get("CollectionType") == "Temporal"):
        for grid in collection.findall("Grid"):
            time, attribute = grid.find("Time").get("Value"), grid.find("Attribute")
            frames.setdefault(time, []).append("        " + ET.tostring(attribute, encoding="unicode").strip())
    include = ("        <xi:include xpointer=\"xpointer(/Xdmf/Domain/Grid[@GridType='Uniform'][1]/*[self::Topology or "
               "self::Geometry])\" />")
    lines = ['<?xml version="1.0"?>', '<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd" []>',
             '<Xdmf Version="3.0" xmlns:xi="http://www.w3.org/2001/XInclude">', "  <Domain>",
             "    " + ET.tostring(mesh, encoding="unicode").strip(),
             '    <Grid Name="fields" GridType="Collection" CollectionType="Temporal">']
    for time, attributes in frames.items():
        lines += ['      <Grid Name="fields" GridType="Uniform">', include, f'        <Time Value="{time}" />',
                  *attributes, "      </Grid>"]
    lines += ["    </Grid>", "  </Domain>", "</Xdmf>", ""]
    temporary = path.with_name(path.name + ".tmp")
    try:
        temporary.write_text("\n".join(lines))
    except OSError:
        temporary.unlink(missing_ok=True)
        raise _unwritten(path) from None
    os.replace(temporary, path)


def _complete_xml(path: Path) -> bool:
    """Whether an XML file dolfinx wrote is there to its last line (``</VTKFile>``)."""
    try:
        with open(path, "rb") as f:
            f.seek(0, 2)
            f.seek(max(f.tell() - 16, 0))
            return f.read().rstrip().endswith(b"</VTKFile>")
    except OSError:
        return False


def _unwritten(path: Path) -> OSError:
    """The error of a file dolfinx could not write (it gives no reason): a full disk, or an I/O error."""
    try:
        full = os.statvfs(path.parent).f_bavail == 0
    except OSError:
        full = False
    if full:
        return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
    return OSError(errno.EIO, "the file was not written completely", str(path))


def _drop_repeated_pieces(pvd: Path) -> None:
    """dolfinx 0.5 lists every piece once per field in each .pvtu, so ParaView would load the
    mesh several times over: keep each piece once."""
    for pvtu in pvd.parent.glob(f"{pvd.stem}*.pvtu"):
        lines = pvtu.read_text().splitlines(keepends=True)
        seen, kept = set(), []
        for line in lines:
            if line.lstrip().startswith("<Piece "):
                if line in seen:
                    continue
                seen.add(line)
            kept.append(line)
        if len(kept) < len(lines):
            pvtu.write_text("".join(kept))


def distance_to_mesh(msh: Mesh, point: np.ndarray, tol: float) -> float:
    """Distance from ``point`` (3 coordinates) to this rank's cells when within ``tol``, else inf."""
    from dolfinx import geometry

    tdim = msh.topology.dim
    tree = geometry.BoundingBoxTree(msh, tdim, padding=tol)
    candidates = geometry.compute_collisions(tree, point.reshape(1, 3)).links(0)
    if len(candidates) == 0:
        return np.inf
    cells = geometry.squared_distance(msh, tdim, candidates, np.tile(point, (len(candidates), 1)))
    return float(np.sqrt(np.min(cells)))
