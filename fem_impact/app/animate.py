"""``fem-impact animate``: render a run's stored time series off screen into a GIF or MP4.

The frames come from ``results.pvd`` and its pieces (read with VTK through pyvista; the
.pvd and .pvtu indexes are parsed here, so that a piece listed more than once, as dolfinx
0.5 writes them, is read once, and ghost cells of a parallel run are dropped), or from
``results.xdmf`` and its ``results.h5`` (``output.format: xdmf``, read with meshio). Each frame
shows the deformed shape ``x + scale * u`` coloured by ``|u|``, ``|v|``, ``|a|``, the contact-force
magnitude or the contact state (open, stick, slip), the contact forces as arrows (tip at the node,
length in proportion to the force), the undeformed outline in grey and the time. Camera, colour range
and arrow scale are fixed over the whole series.

1D bars are drawn as a tube along x at ``x + scale * u_x`` (the bar moves and shortens with the
magnified displacement, coloured by the field), the undeformed bar as a thin grey line just below it.

Nothing here imports dolfinx or MPI: the command works on any run's folder."""

from __future__ import annotations

import math
import os
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import OutputFolderError, SimulationError
from .progress import Progress

# --field NAME -> (point array, label)
FIELDS = {
    "u": ("u", "displacement magnitude"),
    "v": ("v", "speed"),
    "a": ("a", "acceleration magnitude"),
    "contact": ("contact_force", "contact force magnitude"),
    "state": ("contact_state", "contact state: 0 open, 1 stick, 2 slip"),
}
DEFAULT_SIZE = (800, 448)    # multiples of 16: what MP4 encoders want
AUTO_FRACTION = 0.10         # automatic scale: largest displacement = 10 % of the model size
ARROW_FRACTION = 0.15        # the largest contact force is an arrow of 15 % of the model size

# VTK cell types -> topological dimension; dolfinx's order-1 Lagrange cells -> the linear cell of their corner order.
_CELL_DIM = {1: 0, 3: 1, 4: 1, 21: 1, 68: 1, 5: 2, 7: 2, 8: 2, 9: 2, 22: 2, 23: 2, 28: 2, 69: 2, 70: 2,
             10: 3, 11: 3, 12: 3, 13: 3, 14: 3, 24: 3, 25: 3, 29: 3, 71: 3, 72: 3, 73: 3, 74: 3}
_LINEAR = {68: (2, 3), 69: (3, 5), 70: (4, 9), 71: (4, 10), 72: (8, 12)}


class AnimateError(Exception):
    """Bad input for ``fem-impact animate`` (one line for the user)."""


# --------------------------------------------------------------------------------------
# Reading the time series (index files parsed here, pieces read by VTK)
# --------------------------------------------------------------------------------------

def read_pvd(path: Path) -> list[tuple[float, Path]]:
    """(time, file) of every frame of a .pvd collection, in time order."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as err:
        raise AnimateError(f"{path}: cannot read the time series index ({err})") from None
    frames = []
    for ds in root.iter("DataSet"):
        try:
            frames.append((float(ds.get("timestep", "0")), path.parent / ds.get("file")))
        except (TypeError, ValueError):
            raise AnimateError(f"{path}: a DataSet without a valid timestep or file") from None
    if not frames:
        raise AnimateError(f"{path}: no frames")
    frames.sort(key=lambda f: f[0])
    return frames


def piece_files(path: Path) -> list[Path]:
    """The .vtu files of one frame: the file itself, or the unique pieces of a .pvtu."""
    if path.suffix != ".pvtu":
        return [path]
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as err:
        raise AnimateError(f"{path}: cannot read ({err})") from None
    seen: dict[str, None] = {}
    for piece in root.iter("Piece"):
        src = piece.get("Source")
        if src:
            seen.setdefault(src)
    if not seen:
        raise AnimateError(f"{path}: no pieces")
    return [path.parent / s for s in seen]


def _read_vtu(path: Path):
    import pyvista as pv

    if not path.is_file():
        raise AnimateError(f"{path}: missing (an incomplete output folder?)")
    try:
        return pv.read(path)
    except Exception as err:  # VTK's reader errors vary by version
        raise AnimateError(f"{path}: cannot read ({err})") from None


def read_frame(path: Path):
    """One frame as a single UnstructuredGrid: pieces joined, ghost cells dropped, shared nodes once."""
    pieces = [_read_vtu(f) for f in piece_files(path)]
    ghosted = any(np.any(g.cell_data.get("vtkGhostType", 0)) for g in pieces)
    if len(pieces) == 1 and not ghosted:
        return pieces[0]
    if not all("vtkOriginalPointIds" in g.point_data for g in pieces):
        import pyvista as pv

        return pv.merge(pieces, merge_points=False)
    return _join_pieces(pieces)


def _join_pieces(pieces):
    """Join the pieces of a parallel run by the global node numbers dolfinx writes
    (``vtkOriginalPointIds``), keeping the cells each rank owns (``vtkGhostType`` 0)."""
    import pyvista as pv

    gids, points, data, conn, counts, types = [], [], {}, [], [], []
    names = [n for n in pieces[0].point_data.keys() if n not in ("vtkOriginalPointIds", "vtkGhostType")]
    for g in pieces:
        gid = np.asarray(g.point_data["vtkOriginalPointIds"], dtype=np.int64)
        ghost = np.asarray(g.cell_data.get("vtkGhostType", np.zeros(g.n_cells)))
        keep = ghost == 0
        n = np.diff(np.asarray(_offsets(g)))
        conn.append(gid[np.asarray(g.cell_connectivity)[np.repeat(keep, n)]])
        counts.append(n[keep])
        types.append(np.asarray(g.celltypes)[keep])
        gids.append(gid)
        points.append(np.asarray(g.points))
        for name in names:
            data.setdefault(name, []).append(np.asarray(g.point_data[name]))
    gid = np.concatenate(gids)
    unique, first = np.unique(gid, return_index=True)
    conn = np.searchsorted(unique, np.concatenate(conn))
    counts = np.concatenate(counts)
    starts = np.concatenate(([0], np.cumsum(counts[:-1] + 1)))
    cells = np.empty(counts.sum() + len(counts), dtype=np.int64)
    cells[starts] = counts
    body = np.ones(len(cells), dtype=bool)
    body[starts] = False
    cells[body] = conn
    grid = pv.UnstructuredGrid(cells, np.concatenate(types).astype(np.uint8), np.concatenate(points)[first])
    for name, arrays in data.items():
        grid.point_data[name] = np.concatenate(arrays)[first]
    return grid


def _linear_grid(grid):
    """Geometry only, order-1 Lagrange cells turned into the equivalent linear cells."""
    import pyvista as pv

    types = np.asarray(grid.celltypes).copy()
    cells = np.asarray(grid.cells)
    counts = np.diff(np.asarray(_offsets(grid)))
    for lag, (npts, lin) in _LINEAR.items():
        types[(types == lag) & (counts == npts)] = lin
    return pv.UnstructuredGrid(cells, types, np.asarray(grid.points, dtype=float))


def _offsets(grid):
    """Cell offsets (pyvista renamed ``offset`` to ``cell_offsets`` in 0.47)."""
    return grid.cell_offsets if hasattr(type(grid), "cell_offsets") else grid.offset


def topological_dim(grid) -> int:
    present = set(np.unique(np.asarray(grid.celltypes)).tolist())
    return max((_CELL_DIM.get(int(c), 3) for c in present), default=1)


@dataclass
class Series:
    """The stored run, compact: geometry once, per frame u and the needed fields."""

    times: np.ndarray          # (frames,)
    grid: object               # pyvista UnstructuredGrid, undeformed, geometry only
    dim: int                   # topological dimension of the cells
    u: np.ndarray              # (frames, nodes, 3) float32
    scalar: np.ndarray         # (frames, nodes) float32: magnitude of the coloured field
    force: list                # per frame (node indices, (k, 3) force vectors)

    @property
    def size(self) -> float:
        b = np.asarray(self.grid.bounds, dtype=float).reshape(3, 2)
        extent = float(np.max(b[:, 1] - b[:, 0]))
        return extent if extent > 0 else 1.0

    def auto_scale(self) -> float:
        return auto_scale(float(np.sqrt((self.u.astype(float) ** 2).sum(axis=2)).max()), self.size)


def auto_scale(max_displacement: float, size: float) -> float:
    """Magnification that makes the largest displacement AUTO_FRACTION of the model size."""
    if not (max_displacement > 0 and math.isfinite(max_displacement)):
        return 1.0
    return float(f"{AUTO_FRACTION * size / max_displacement:.3g}")


def _series_file(outdir: Path) -> Path:
    """The run's time series: results.pvd (VTK, the default) or results.xdmf (``output.format: xdmf``)."""
    for name in ("results.pvd", "results.xdmf"):
        if (outdir / name).is_file():
            return outdir / name
    raise AnimateError(f"{outdir}: no results.pvd or results.xdmf (is it a run's output folder, with output.vtk "
                       "on?)")


def frame_count(outdir: Path) -> int:
    """How many frames the run stored."""
    path = _series_file(outdir)
    if path.suffix == ".pvd":
        return len(read_pvd(path))
    from .xdmf import XdmfError, open_xdmf

    try:
        with open_xdmf(path) as series:
            return len(series.times)
    except XdmfError as err:
        raise AnimateError(str(err)) from None


def load_series(outdir: Path, field: str, progress=None) -> Series:
    path = _series_file(outdir)
    array = FIELDS[field][0]
    times, us, scalars, forces = [], [], [], []
    grid = None

    def add(t, where, g):
        nonlocal grid
        for name in ("u", array, "contact_force"):
            if name not in g.point_data:
                raise AnimateError(f"{where}: no point array '{name}'")
        if grid is None:
            grid = _linear_grid(g)
        elif g.n_points != grid.n_points:
            raise AnimateError(f"{where}: {g.n_points} points, the first frame has {grid.n_points}")
        u = _as3(g.point_data["u"])
        f = _as3(g.point_data["contact_force"])
        times.append(t)
        us.append(u.astype(np.float32))
        scalars.append(np.linalg.norm(_as3(g.point_data[array]), axis=1).astype(np.float32))
        fmag = np.linalg.norm(f, axis=1)
        idx = np.flatnonzero(fmag > 0)
        forces.append((idx, f[idx]))

    if path.suffix == ".pvd":
        frames = read_pvd(path)
        for k, (t, piece) in enumerate(frames):
            add(t, piece, read_frame(piece))
            if progress:
                progress(k + 1, len(frames))
    else:
        _xdmf_frames(path, add, progress)
    return Series(np.array(times), grid, topological_dim(grid), np.stack(us), np.stack(scalars), forces)


def _xdmf_frames(path: Path, add, progress) -> None:
    """Each frame of results.xdmf to ``add(t, where, grid)``, as a pyvista grid of the run's mesh."""
    import meshio
    import pyvista as pv

    from .xdmf import XdmfError, open_xdmf

    try:
        with open_xdmf(path) as series:
            points = np.zeros((len(series.points), 3))
            points[:, : series.points.shape[1]] = series.points[:, :3]
            mesh = pv.from_meshio(meshio.Mesh(points, series.cells))
            for k, (t, data) in enumerate(series.frames()):
                g = mesh.copy(deep=False)
                for name, values in data.items():
                    if len(values) != g.n_points:
                        raise AnimateError(f"{path} (frame {k}): '{name}' has {len(values)} values for "
                                           f"{g.n_points} points")
                    g.point_data[name] = values
                add(t, f"{path} (frame {k})", g)
                if progress:
                    progress(k + 1, len(series.times))
    except XdmfError as err:
        raise AnimateError(str(err)) from None


def _as3(a) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.shape[1] < 3:
        a = np.hstack([a, np.zeros((a.shape[0], 3 - a.shape[1]))])
    return a[:, :3]


# --------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------

def _prepare_offscreen() -> None:
    """Without a display, go straight to EGL (VTK would try X first and print a warning)."""
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def _import_pyvista():
    _prepare_offscreen()
    try:
        import pyvista as pv
    except ImportError as err:
        raise AnimateError(f"pyvista is not installed ({err}); run `make setup` or pip install pyvista") from None
    pv.OFF_SCREEN = True
    return pv


def _to_palette(img: np.ndarray):
    from PIL import Image

    return Image.fromarray(img).quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)


class _Writer:
    """Frames to a GIF (Pillow, adaptive palette per frame), an MP4 (imageio-ffmpeg) or, for a single
    frame, a PNG (Pillow, full colour).

    GIF frames are reduced to 256 colours in worker threads (Pillow releases the GIL), so that this
    overlaps with the rendering of the next frames."""

    def __init__(self, path: Path, fps: float):
        self.path, self.fps = path, fps
        self.tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
        self.kind = path.suffix.lower()
        self.frames: list = []
        self.mp4 = self.pool = None
        if self.kind == ".png":
            return
        if self.kind == ".mp4":
            try:
                import imageio.v2 as iio
                import imageio_ffmpeg  # noqa: F401
            except ImportError:
                raise AnimateError("MP4 needs imageio and imageio-ffmpeg (pip install imageio imageio-ffmpeg); "
                                   "or write a .gif") from None
            self.mp4 = iio.get_writer(self.tmp, format="FFMPEG", mode="I", fps=fps, codec="libx264",
                                      quality=7, pixelformat="yuv420p", macro_block_size=16)
        else:
            from concurrent.futures import ThreadPoolExecutor

            self.workers = max(1, min(4, os.cpu_count() or 1))
            self.pool = ThreadPoolExecutor(self.workers)

    def add(self, img: np.ndarray) -> None:
        if self.kind == ".png":
            self.frames = [img]
            return
        if self.mp4 is not None:
            self.mp4.append_data(img)
            return
        self.frames.append(self.pool.submit(_to_palette, img))
        busy = [f for f in self.frames[-4 * self.workers:] if not f.done()]
        if len(busy) > 2 * self.workers:   # bound the backlog of full-colour frames
            busy[0].result()

    def close(self) -> None:
        if self.kind == ".png":
            from PIL import Image

            Image.fromarray(self.frames[0]).save(self.tmp, format="PNG")
        elif self.mp4 is not None:
            self.mp4.close()
        else:
            frames = [f.result() for f in self.frames]
            self.pool.shutdown()
            duration = max(20, int(round(1000 / self.fps)))
            frames[0].save(self.tmp, format="GIF", save_all=True, append_images=frames[1:],
                           duration=duration, loop=0)
        os.replace(self.tmp, self.path)

    def abort(self) -> None:
        if self.mp4 is not None:
            try:
                self.mp4.close()
            except Exception:
                pass
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)
        self.tmp.unlink(missing_ok=True)


def render(series: Series, out: Path, field: str, scale: float, fps: float, size=DEFAULT_SIZE,
           progress=None, frames=None) -> Path:
    """Render the frames of ``series`` (all, or the indices in ``frames``) into ``out``; the camera,
    colour range and arrow scale are those of the whole series either way."""
    pv = _import_pyvista()
    label = FIELDS[field][1]
    X = np.asarray(series.grid.points, dtype=float)
    L = series.size
    nframes = len(series.times)

    vmax = float(series.scalar.max()) if series.scalar.size else 0.0
    clim = [0.0, vmax if vmax > 0 else 1.0]
    fmax = max((float(np.linalg.norm(f, axis=1).max()) for _, f in series.force if len(f)), default=0.0)
    arrow_per_force = ARROW_FRACTION * L / fmax if fmax > 0 else 0.0
    radius = 0.015 * L   # 1D tube

    def deformed(k):
        return X + scale * series.u[k].astype(float)

    def arrows(k):
        idx, f = series.force[k]
        keep = np.linalg.norm(f, axis=1) > 1e-9 * fmax if fmax > 0 else np.zeros(len(idx), bool)
        idx, f = idx[keep], f[keep]
        if not len(idx):
            return None
        vec = f * arrow_per_force
        tails = deformed(k)[idx] - vec
        pts = pv.PolyData(tails)
        pts["vec"] = vec
        pts["len"] = np.linalg.norm(vec, axis=1)
        return pts.glyph(orient="vec", scale="len", factor=1.0,
                         geom=pv.Arrow(tip_length=0.3, tip_radius=0.12, shaft_radius=0.045))

    # bounds over the whole series (deformed shapes and arrow tails): a fixed camera
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for k in range(nframes):
        P = deformed(k)
        lo, hi = np.minimum(lo, P.min(axis=0)), np.maximum(hi, P.max(axis=0))
        idx, f = series.force[k]
        if len(idx) and fmax > 0:
            T = P[idx] - f * arrow_per_force
            lo, hi = np.minimum(lo, T.min(axis=0)), np.maximum(hi, T.max(axis=0))
    lo, hi = np.minimum(lo, X.min(axis=0)), np.maximum(hi, X.max(axis=0))
    if series.dim == 1:
        lo[1], hi[1] = lo[1] - 4 * radius, hi[1] + 2 * radius

    # Software OpenGL (llvmpipe) without a GPU: multisampling (8x by default) triples the
    # cost of a frame and FXAA is worse still, so no anti-aliasing.
    theme = pv.themes.DocumentTheme()
    theme.multi_samples = 0
    theme.anti_aliasing = None
    try:
        p = pv.Plotter(off_screen=True, window_size=list(size), theme=theme)
    except Exception as err:
        raise AnimateError(f"cannot open an off-screen render window ({err})") from None
    p.set_background("white")
    sbar = {"title": label, "vertical": False, "color": "black", "position_x": 0.3, "position_y": 0.02,
            "width": 0.4, "height": 0.14, "fmt": "%.3g", "title_font_size": 14, "label_font_size": 12}
    common = {"scalars": "field", "clim": clim, "cmap": "viridis", "scalar_bar_args": sbar, "reset_camera": False}
    if field == "state":   # (open, stick, slip: three colours, not mixed across a cell into a false stick)
        sbar.update(fmt="%.0f", n_labels=3)
        common.update(clim=[0, 2], cmap=["whitesmoke", "tab:blue", "tab:red"], n_colors=3, interpolate_before_map=False)

    if series.dim == 1:
        line = pv.PolyData(X.copy(), lines=_line_cells(series.grid))

        def body_at(k):
            m = line.copy()
            m.points = deformed(k)
            m["field"] = series.scalar[k]
            return m.tube(radius=radius, n_sides=16)

        body = body_at(0)
        ref = pv.PolyData(X + np.array([0.0, -3 * radius, 0.0]), lines=_line_cells(series.grid))
        p.add_mesh(ref, color="grey", line_width=2, reset_camera=False)
    else:
        body = series.grid.copy()
        body.points = deformed(0)
        body["field"] = series.scalar[0]
        outline = _surface(series.grid).extract_feature_edges(boundary_edges=True, feature_edges=series.dim == 3,
                                                manifold_edges=False, non_manifold_edges=False)
        p.add_mesh(outline, color="grey", line_width=1, opacity=0.6, reset_camera=False)
    p.add_mesh(body, **common)
    p.scalar_bars[label].SetTitle("")   # VTK draws it over the tick labels; the caption names the field

    # camera: fixed, fitted to the bounds of the whole series
    center = (lo + hi) / 2
    span = np.maximum(hi - lo, 1e-12 * L)
    if series.dim < 3:
        aspect = size[0] / size[1]
        cam = p.camera
        cam.focal_point = tuple(center)
        cam.position = tuple(center + np.array([0.0, 0.0, 4 * L]))
        cam.up = (0.0, 1.0, 0.0)
        cam.parallel_projection = True
        # room at the bottom for the colour bar and at the top for the labels
        cam.parallel_scale = 0.5 * max(span[1] / 0.6, span[0] / (0.92 * aspect))
        cam.clipping_range = (0.01 * L, 10 * L)
    else:
        # y up (the bar's height), seen from the front (+z), a little from above and from +x:
        # x runs from left to right as in the 1D and 2D pictures
        direction = np.array([0.3, 0.45, 1.0]) / np.linalg.norm([0.3, 0.45, 1.0])
        p.camera.focal_point = tuple(center)
        p.camera.position = tuple(center + 4 * L * direction)
        p.camera.up = (0.0, 1.0, 0.0)
        p.reset_camera(bounds=tuple(np.column_stack([lo, hi]).ravel()))
        p.camera.zoom(1.3)
    p.camera_set = True

    p.add_text(f"colour: {label}\ndisplacement x {scale:.3g}", position="upper_right", font_size=10, color="black")
    clock = p.add_text(f"t = {series.times[0]:.6g}", position="upper_left", font_size=10, color="black")
    glyphs = pv.PolyData()   # the arrows of the frame, updated in place (may be empty: a bare VTK actor)
    from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper

    mapper = vtkPolyDataMapper()
    mapper.SetInputData(glyphs)
    mapper.ScalarVisibilityOff()
    arrow_actor = vtkActor()
    arrow_actor.SetMapper(mapper)
    arrow_actor.GetProperty().SetColor(0.85, 0.1, 0.1)
    p.add_actor(arrow_actor, reset_camera=False)
    writer = _Writer(out, fps)
    selected = list(range(nframes)) if frames is None else list(frames)
    try:
        for i, k in enumerate(selected):
            if k or i:
                if series.dim == 1:
                    body.copy_from(body_at(k))
                else:
                    body.points = deformed(k)
                    body["field"] = series.scalar[k]
            arr = arrows(k)
            glyphs.copy_from(arr if arr is not None else pv.PolyData())
            clock.SetText(2, f"t = {series.times[k]:.6g}")   # a vtkCornerAnnotation; 2 = upper left
            p.render()
            writer.add(p.screenshot(return_img=True))
            if progress:
                progress(i + 1, len(selected))
        writer.close()
    except BaseException:
        writer.abort()
        raise
    finally:
        p.close()
    return out


def _surface(grid):
    """The outer surface of a grid as PolyData (VTK's filter: pyvista's wrapper changes between versions)."""
    import pyvista as pv
    from vtkmodules.vtkFiltersGeometry import vtkDataSetSurfaceFilter

    f = vtkDataSetSurfaceFilter()
    f.SetInputData(grid)
    f.Update()
    return pv.wrap(f.GetOutput())


def _line_cells(grid) -> np.ndarray:
    """Legacy line cells [2, i, j, ...] of a 1D mesh (each cell's two end nodes)."""
    conn = np.asarray(grid.cell_connectivity)
    start = np.asarray(_offsets(grid))[:-1]
    return np.column_stack([np.full(len(start), 2), conn[start], conn[start + 1]]).ravel().astype(np.int64)


# --------------------------------------------------------------------------------------
# Command
# --------------------------------------------------------------------------------------

def add_parser(sub) -> None:
    """The ``animate`` subcommand (added to the ``fem-impact`` parser in cli.py)."""
    a = sub.add_parser(
        "animate", help="render a run's time series into an animated GIF or MP4 (off screen)",
        description="Render OUTDIR/results.pvd off screen: the deformed shape (displacement magnified by "
                    "--scale) coloured by a field, contact forces as red arrows, the undeformed outline in "
                    "grey, the time. 1D bars are drawn as a tube moved along x by the magnified displacement.")
    a.add_argument("outdir", metavar="OUTDIR", help="a run's output folder")
    a.add_argument("--field", default="v", metavar="FIELD", help="colour by |u|, |v|, |a|, |contact force| or "
                   "the contact state (0 open, 1 stick, 2 slip): u, v, a, contact or state (default v)")
    a.add_argument("--scale", metavar="S",
                   help="displacement magnification (default: the largest displacement is 10%% of the model size)")
    a.add_argument("-o", "--output", metavar="FILE",
                   help="animation.gif or .mp4 (default: OUTDIR/animation.gif), or a .png picture of one frame "
                        "(the last one, or the one --frame or --time picks)")
    pick = a.add_mutually_exclusive_group()
    pick.add_argument("--frame", metavar="N", help="a PNG of stored frame N (0 the first, -1 the last; default "
                      "-o: OUTDIR/frame.png)")
    pick.add_argument("--time", metavar="T", help="a PNG of the stored frame nearest to time T")
    a.add_argument("--fps", default="10", help="frames per second (default 10)")
    a.add_argument("--size", default=f"{DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]}", metavar="WxH",
                   help=f"image size in pixels (default {DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]})")


def animate(outdir, field: str = "v", scale: float | None = None, output=None, fps: float = 10.0,
            size=DEFAULT_SIZE, progress: bool | None = None, frame: int | None = None,
            when: float | None = None) -> tuple[Path, float, int]:
    """Render a run's results; returns (file, scale used, frames written). Raises AnimateError.

    A ``.png`` output (or ``frame``/``time`` given) is one picture: stored frame ``frame`` (negative
    counts from the end), the frame nearest to time ``when``, or the last frame."""
    outdir = Path(outdir)
    if field not in FIELDS:
        raise AnimateError(f"--field {field}: unknown, choose one of {', '.join(FIELDS)}")
    if scale is not None and not (math.isfinite(scale) and scale > 0):
        raise AnimateError(f"--scale {scale}: must be a number > 0")
    if not (math.isfinite(fps) and fps > 0):
        raise AnimateError(f"--fps {fps}: must be > 0")
    if not outdir.is_dir():
        raise AnimateError(f"{outdir}: no such folder")
    _series_file(outdir)
    picture = frame is not None or when is not None
    out = Path(output) if output else outdir / ("frame.png" if picture else "animation.gif")
    if out.suffix.lower() not in (".gif", ".mp4", ".png"):
        raise AnimateError(f"-o {out}: write a .gif or an .mp4 (an animation) or a .png (one frame)")
    if picture and out.suffix.lower() != ".png":
        raise AnimateError(f"-o {out}: --frame and --time pick one frame for a picture: write a .png")
    if when is not None and not math.isfinite(when):
        raise AnimateError(f"--time {when}: must be a number")
    if not out.parent.is_dir():
        raise AnimateError(f"-o {out}: no folder {out.parent}")
    from .outdir.single_file import atomic_file, check_file

    try:
        out = check_file(out)
    except OutputFolderError as err:
        raise AnimateError(str(err)) from None
    if frame is not None:
        n = frame_count(outdir)
        if not -n <= frame < n:
            raise AnimateError(f"--frame {frame}: the run stored {n} frames (0 to {n - 1}, or -1 to -{n})")
    _import_pyvista()
    series = load_series(outdir, field, Progress(label="reading", unit="frame", enabled=progress))
    s = scale if scale is not None else series.auto_scale()
    selected = None
    if out.suffix.lower() == ".png":
        if when is not None:
            selected = [int(np.argmin(np.abs(series.times - when)))]
        else:
            selected = [(frame if frame is not None else -1) % len(series.times)]
    try:
        with atomic_file(out) as tmp:   # an interrupted rendering leaves no half-written file
            bar = Progress(label="rendering", unit="frame", enabled=progress)
            render(series, tmp, field, s, fps, size, bar, frames=selected)
    except OutputFolderError as err:
        raise AnimateError(str(err)) from None
    return out, s, len(selected) if selected is not None else len(series.times)


def _positive(option: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise AnimateError(f"{option} {text}: must be a number > 0")
    return value


def _integer(option: str, text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise AnimateError(f"{option} {text}: must be a whole number") from None


def _number(option: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise AnimateError(f"{option} {text}: must be a number")
    return value


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise AnimateError(f"--size {text}: give WIDTHxHEIGHT in pixels, e.g. 1024x576") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise AnimateError(f"--size {text}: each side between 16 and 8192 pixels")
    return w, h


def main(args) -> int:
    """Run the ``animate`` subcommand from parsed arguments; exit status."""
    try:
        scale = None if args.scale is None else _positive("--scale", args.scale)
        fps = _positive("--fps", args.fps)
        size = parse_size(args.size)
        if args.output and Path(args.output).suffix.lower() == ".mp4":
            size = (size[0] // 16 * 16 or 16, size[1] // 16 * 16 or 16)
        frame = None if args.frame is None else _integer("--frame", args.frame)
        when = None if args.time is None else _number("--time", args.time)
        out, scale, frames = animate(args.outdir, args.field, scale, args.output, fps, size, frame=frame, when=when)
    except AnimateError as err:
        print(f"fem-impact: error: {err}", file=sys.stderr)
        return 2
    except SimulationError as err:   # (OutputWriteError: a full disk)
        print(f"fem-impact: the rendering failed: {err}", file=sys.stderr)
        return 3
    except KeyboardInterrupt as err:
        from .outdir.interruption import exit_status, signal_name

        Progress.end_line()
        print(f"fem-impact: interrupted by {signal_name(err)}", file=sys.stderr)
        return exit_status(err)
    print(f"wrote {out} ({frames} frame{'s' if frames != 1 else ''}, displacement x {scale:.3g})")
    return 0
