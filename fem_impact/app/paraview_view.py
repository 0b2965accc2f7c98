"""``view.py`` beside a run's results: a ParaView script that shows the time series.

``write_view_script(outdir, dim, scale)`` writes OUTDIR/view.py; then

    paraview --script=view.py                  # the ParaView GUI, ready to play
    pvpython view.py                           # an interactive window (needs a display)
    pvpython view.py --screenshot view.png     # an image, no window (headless: see below)
        [--time T] [--size 1200x500]
    pvpython view.py --animation frames.png    # every frame (frames.0000.png, ...) or .avi

The script loads ``results.pvd`` from its own folder, applies *Warp By Vector* on ``u``
with the run's magnification, colours by the magnitude of ``v`` (or another field) with
one colour range over all time steps, draws the contact forces as arrows whose tips sit
on the nodes, the undeformed outline in grey and the time. Debian's ParaView renders
through X: headless, run ``xvfb-run -a -s -noreset pvpython --force-offscreen-rendering view.py
--screenshot view.png``.

The default magnification is the one of ``fem-impact animate``: the largest displacement
of the series becomes 10 % of the model size. It is read here from the ASCII .vtu pieces
with numpy (no VTK needed, so run.py can call this cheaply).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from .._version import __version__
from .animate import AUTO_FRACTION, AnimateError, auto_scale, piece_files, read_pvd

COLORS = {"u": "u", "v": "v", "a": "a", "contact": "contact_force", "contact_force": "contact_force",
          "state": "contact_state", "contact_state": "contact_state"}

def _find_array(text: bytes, name: bytes | None) -> np.ndarray | None:
    """The values of the (first) ASCII DataArray called ``name`` (None: the Points array)."""
    if name is None:
        start = text.find(b"<Points>")
        start = text.find(b"<DataArray", start) if start >= 0 else -1
    else:
        key = text.find(b'Name="' + name + b'"')
        start = text.rfind(b"<DataArray", 0, key) if key >= 0 else -1
    if start < 0:
        return None
    head_end = text.find(b">", start)
    end = text.find(b"</DataArray>", head_end)
    if head_end < 0 or end < 0:
        return None
    attrs = text[start:head_end]
    if b'format="ascii"' not in attrs:
        return None
    m = re.search(rb'NumberOfComponents="(\d+)"', attrs)
    ncomp = int(m.group(1)) if m else 1
    values = np.fromstring(text[head_end + 1:end], sep=" ")  # text mode: fast and not deprecated
    if ncomp > 1 and values.size % ncomp == 0:
        return values.reshape(-1, ncomp)
    return values.reshape(-1, 1)


def series_extremes(outdir) -> dict | None:
    """Model size (largest extent), largest |u| and largest nodal |contact_force| of a run's series.

    Read from the ASCII .vtu pieces with numpy; None when they cannot be read this way (not
    ASCII VTK XML, missing files).
    """
    outdir = Path(outdir)
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    peak = {"u": 0.0, "contact_force": 0.0}
    try:
        frames = read_pvd(outdir / "results.pvd")
        for k, (_, path) in enumerate(frames):
            for piece in piece_files(path):
                text = piece.read_bytes()
                if k == 0:
                    pts = _find_array(text, None)
                    if pts is None:
                        return None
                    pts = np.pad(pts, ((0, 0), (0, max(0, 3 - pts.shape[1]))))[:, :3]
                    lo, hi = np.minimum(lo, pts.min(axis=0)), np.maximum(hi, pts.max(axis=0))
                for name in peak:
                    a = _find_array(text, name.encode())
                    if a is None:
                        if name == "u":
                            return None
                        continue
                    if a.size:
                        peak[name] = max(peak[name], float(np.sqrt((a ** 2).sum(axis=1)).max()))
    except (AnimateError, OSError, ValueError):
        return None
    extent = float(np.max(hi - lo)) if np.all(np.isfinite(hi - lo)) else 0.0
    return {"size": extent if extent > 0 else 1.0, "max_u": peak["u"], "max_contact_force": peak["contact_force"]}


def displacement_scale(outdir) -> float | None:
    """Magnification so that the largest |u| of the series is 10 % of the model size (None: unreadable)."""
    ext = series_extremes(outdir)
    return auto_scale(ext["max_u"], ext["size"]) if ext else None


def write_view_script(outdir, dim: int | None = None, scale: float | None = None, color: str = "v",
                      final_dir=None) -> Path:
    """Write OUTDIR/view.py (ParaView: Warp By Vector on u x ``scale``, colour by |``color``|).

    ``scale`` None: the magnification of ``displacement_scale`` (read from the results),
    or 1 when that cannot be read. ``dim`` (1, 2, 3; None: 3) chooses the 1D/2D or 3D view.
    ``final_dir``: where OUTDIR will end up when it is a staging folder moved into place
    afterwards. The script finds ``results.pvd`` beside itself under ``pvpython``; the
    ParaView GUI runs ``--script`` without ``__file__``, so there it looks in the current
    folder and then in this recorded folder (default: OUTDIR).
    """
    outdir = Path(outdir)
    if color not in COLORS:
        raise ValueError(f"color {color!r}: choose one of u, v, a, contact, state")
    ext = series_extremes(outdir)
    if scale is None:
        scale = auto_scale(ext["max_u"], ext["size"]) if ext else 1.0
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale {scale!r}: must be > 0")
    text = (_TEMPLATE.replace("@VERSION@", str(__version__))
            .replace("@DIM@", repr(int(dim) if dim else 3))
            .replace("@FOLDER@", repr(str(Path(final_dir or outdir).resolve())))
            .replace("@SCALE@", repr(float(f"{scale:.4g}")))
            .replace("@COLOR@", repr(COLORS[color]))
            .replace("@FMAX@", repr(float(f"{ext['max_contact_force']:.6g}")) if ext else "None")
            .replace("@FRACTION@", f"{AUTO_FRACTION:g}"))
    path = outdir / "view.py"
    tmp = outdir / ".view.py.partial"
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


_TEMPLATE = r'''"""ParaView view of this fem-impact run (written by fem-impact @VERSION@).

    paraview --script=view.py                  the ParaView GUI, ready to play (Play button)
    pvpython view.py                           an interactive window (needs a display)
    pvpython view.py --screenshot view.png [--time T] [--size 1200x500]
    pvpython view.py --animation frames.png    every frame (frames.0000.png, ...) or .avi

Headless (no display): xvfb-run -a -s -noreset pvpython --force-offscreen-rendering view.py --screenshot view.png

The shape is results.pvd warped by u x SCALE (Warp By Vector), coloured by the magnitude of
COLOR with one range over all time steps; contact forces are red arrows ending at the nodes
(the largest nodal contact force is an arrow of ARROW x the model size);
the undeformed shape is drawn in grey. Change the constants below to taste.
"""
import csv
import os
import sys

import paraview
from paraview.simple import (AnnotateTimeFilter, ColorBy, GetActiveView, GetActiveViewOrCreate, GetAnimationScene,
                             GetColorTransferFunction, GetScalarBar, Glyph, Interact, PVDReader, Render, ResetCamera,
                             SaveAnimation, SaveScreenshot, SetActiveSource, Show, WarpByVector)

DIM = @DIM@                # 1 rod, 2 strip (seen in the x-y plane), 3 solid
SCALE = @SCALE@            # displacement magnification (the largest |u| ~ @FRACTION@ of the model size)
COLOR = @COLOR@            # u, v, a, contact_force or contact_state: coloured by its magnitude
ARROW = 0.15               # arrow length of the largest nodal contact force, as a fraction of the model size
FORCE_MAX = @FMAX@         # the largest nodal |contact_force| of the series (None: from history.csv)


RUN_FOLDER = @FOLDER@   # where the run was written (used when this file's own folder is unknown)


def _folder():
    """The folder of results.pvd: this file's (pvpython), else the current one, else RUN_FOLDER.

    The ParaView GUI runs --script without __file__.
    """
    candidates = [os.getcwd(), RUN_FOLDER]
    try:
        candidates.insert(0, os.path.dirname(os.path.abspath(__file__)))
    except NameError:
        pass
    for folder in candidates:
        if os.path.isfile(os.path.join(folder, "results.pvd")):
            return folder
    raise SystemExit("view.py: results.pvd not found in %s" % " or ".join(candidates))


def _largest_contact_force(folder):
    """Largest |total normal force| of any contact in history.csv (0 without contacts)."""
    try:
        with open(os.path.join(folder, "history.csv"), newline="") as f:
            rows = csv.reader(f)
            head = next(rows)
            cols = [k for k, name in enumerate(head) if name.endswith(".force")]
            return max((abs(float(r[k])) for r in rows for k in cols), default=0.0)
    except (OSError, StopIteration, ValueError):
        return 0.0


# The GUI (paraview --script=view.py) already has a view and runs the script with argv ['']
# (paraview.fromGUI is not set by ParaView 5.11's GUI); pvpython starts without a view.
IN_GUI = paraview.fromGUI or (sys.argv[:1] in ([], [""]) and GetActiveView() is not None)
HERE = _folder()
reader = PVDReader(registrationName="results.pvd", FileName=os.path.join(HERE, "results.pvd"))
reader.PointArrays = ["u", "v", "a", "contact_force", "contact_state"]
reader.UpdatePipelineInformation()
times = list(reader.TimestepValues) if reader.TimestepValues else [0.0]
reader.UpdatePipeline(times[0])
b = reader.GetDataInformation().GetBounds()
size = max(b[1] - b[0], b[3] - b[2], b[5] - b[4]) or 1.0

warp = WarpByVector(registrationName="Warp u x %g" % SCALE, Input=reader)
warp.Vectors = ["POINTS", "u"]
warp.ScaleFactor = SCALE

view = GetActiveViewOrCreate("RenderView")
if not IN_GUI and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) and \
        "XOpenGL" in view.GetRenderWindow().GetClassName():
    # Debian's ParaView renders through X only: without a display the first render would crash
    sys.exit("view.py: no display, and this ParaView renders through X; run\n"
             "  xvfb-run -a -s -noreset pvpython --force-offscreen-rendering view.py --screenshot view.png")
view.OrientationAxesVisibility = 1
view.Background = [1.0, 1.0, 1.0]
try:                       # ParaView >= 5.10: the background is the palette's unless told otherwise
    view.UseColorPaletteForBackground = 0
except AttributeError:
    pass

undeformed = Show(reader, view)
# (an outline: dolfinx 0.5 lists each piece of a .pvtu once per field, so ParaView loads the
# mesh several times over and "Feature Edges" would draw every edge as non-manifold)
undeformed.Representation = "Wireframe" if DIM == 1 else "Outline"
undeformed.AmbientColor = undeformed.DiffuseColor = [0.6, 0.6, 0.6]
undeformed.Opacity = 0.5
undeformed.Visibility = 1

shape = Show(warp, view)
ColorBy(shape, ("POINTS", COLOR, "Magnitude"))
shape.RescaleTransferFunctionToDataRangeOverTime()
lut = GetColorTransferFunction(COLOR)
lut.ApplyPreset("Viridis (matplotlib)", True)
shape.RescaleTransferFunctionToDataRangeOverTime()
lut.AutomaticRescaleRangeMode = "Never"
lut.RescaleTransferFunction(0.0, max(lut.RGBPoints[-4], 1e-300))   # magnitudes: from 0
shape.SetScalarBarVisibility(view, True)
bar = GetScalarBar(lut, view)
bar.Title = COLOR
bar.ComponentTitle = "magnitude"
bar.TitleColor = bar.LabelColor = [0.0, 0.0, 0.0]
bar.Orientation = "Horizontal"
bar.WindowLocation = "Lower Center"
bar.ScalarBarLength = 0.4
bar.TitleFontSize = bar.LabelFontSize = 12
bar.RangeLabelFormat = "%-#.3g"
if DIM == 1:
    shape.LineWidth = 8.0
    shape.RenderLinesAsTubes = 1

fmax = FORCE_MAX if FORCE_MAX is not None else _largest_contact_force(HERE)
if fmax > 0:
    arrows = Glyph(registrationName="contact forces", Input=warp, GlyphType="Arrow")
    arrows.OrientationArray = ["POINTS", "contact_force"]
    arrows.ScaleArray = ["POINTS", "contact_force"]
    arrows.ScaleFactor = ARROW * size / fmax
    arrows.GlyphMode = "All Points"
    arrows.GlyphTransform.Translate = [-1.0, 0.0, 0.0]   # the arrow ends at the node
    shown = Show(arrows, view)
    ColorBy(shown, None)
    shown.AmbientColor = shown.DiffuseColor = [0.85, 0.1, 0.1]

clock = AnnotateTimeFilter(registrationName="time", Input=reader)
clock.Format = "t = {time:.6g}"
label = Show(clock, view)
label.WindowLocation = "Upper Left Corner"
label.Color = [0.0, 0.0, 0.0]
label.FontSize = 14

scene = GetAnimationScene()
scene.UpdateAnimationUsingDataTimeSteps()


def _option(name, default=None):
    args = sys.argv[1:]
    return args[args.index(name) + 1] if name in args and args.index(name) + 1 < len(args) else default


if IN_GUI:
    width, height = (list(view.ViewSize) + [0, 0])[:2]
else:
    width, height = (int(v) for v in _option("--size", "1200x500" if DIM < 3 else "1000x700").split("x"))
    view.ViewSize = [width, height]
aspect = width / height if width > 0 and height > 0 else 2.0

# fixed camera: the undeformed model, with room for the magnified motion and the arrows
cx, cy, cz = (b[0] + b[1]) / 2, (b[2] + b[3]) / 2, (b[4] + b[5]) / 2
if DIM < 3:
    view.InteractionMode = "2D"
    view.CameraPosition = [cx, cy, cz + 5 * size]
    view.CameraFocalPoint = [cx, cy, cz]
    view.CameraViewUp = [0.0, 1.0, 0.0]
    ResetCamera(view)
    margin = 1.1 + 2 * (@FRACTION@ + (ARROW if fmax > 0 else 0.0))
    view.CameraParallelScale = 0.5 * max((b[3] - b[2]) * 2.5, margin * (b[1] - b[0]) / aspect, 0.05 * size)
else:
    view.CameraFocalPoint = [cx, cy, cz]
    view.CameraPosition = [cx + 1.2 * size, cy + 1.8 * size, cz + 4.0 * size]
    view.CameraViewUp = [0.0, 1.0, 0.0]
    ResetCamera(view)
SetActiveSource(warp)

if IN_GUI:
    Render(view)
else:
    t = _option("--time")
    if t is not None:
        scene.AnimationTime = min(times, key=lambda s: abs(s - float(t)))
    else:
        scene.AnimationTime = times[len(times) // 2]
    shot, movie = _option("--screenshot"), _option("--animation")
    if shot:
        SaveScreenshot(shot, view, ImageResolution=[width, height])
        print("wrote", shot)
    elif movie:
        SaveAnimation(movie, view, ImageResolution=[width, height], FrameRate=10)
        print("wrote", movie)
    else:
        try:
            Interact(view)
        except RuntimeError as err:
            sys.exit("view.py: no interactive window here (%s); try --screenshot view.png" % err)
'''
