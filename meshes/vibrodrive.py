"""A 2D (plane stress) vibrodrive for cases/vibrodrive.yaml: a resonant driver rod whose bevelled tip
strikes the inclined face of a slider that runs on a guide.

Builds, with the Gmsh Python API (lengths in m; y up, the guide along x):

- body ``piezo``: a piezo stack of length ``Lp`` and width ``w``, clamped at its top (node group
  ``base``, y = top), the driver hanging from it. The stack's drive is the force pair it exerts on
  its two end faces: the clamp takes one, the other acts on the rod's top face (node group
  ``drive``, the line the stack and the rod share), where the case file applies it;
- body ``driver``: a steel rod of length ``L`` (along its centre line) and width ``w``, axis along
  y. Stack and rod are a clamped-free two-segment resonator: its first longitudinal mode has the
  frequency of ``rho_p c_p cot(w Lp / c_p) = rho c tan(w L / c)`` (``first_frequency``; 17.05 kHz
  for the defaults, against c / (4 (L + Lp)) = 25.9 kHz for an all-steel rod of that length);
- the rod's bottom end (node group ``tip``) is cut at the angle ``alpha`` to the guide;
- body ``slider``: a wedge on the guide (node group ``guide``, its bottom edge, y = 0) whose top
  face rises toward +x at the angle ``alpha``; the part of that face under the rod's tip (node
  group ``face``) is the tip face moved by ``gap`` along the contact normal
  ``n = (sin alpha, -cos alpha)`` (from the tip toward the face). ``tip`` and ``face`` are
  transfinite curves with the same number of nodes, so that every tip node faces one face node
  along ``n`` (pair contacts are matched that way). A push of the tip along ``n`` drives the
  slider toward +x with ``sin alpha`` of the impulse; the guide takes the rest.

Mesh size (the one number to turn is ``--elements-per-wavelength``, n, default 10): the strikes
last about a tenth of the drive period (measured: 0.09 to 0.13 T1), so the scene needs the modes up
to ``f_max = 10 f1`` (``--f-max``); the shortest wavelength there is the shear wave's,
``c_s / f_max`` with ``c_s = sqrt(E / (2 (1 + nu) rho))``, so each body gets ``h = c_s / (f_max n)``
with its own material (steel: 1.9 mm, 5 to 6 elements across the rod; the softer stack: 0.9 mm).
Near the contact the size is ``h / refine`` (``--refine``, default 4: 25 elements per face) within
``w / 4`` of the faces, growing to ``h`` at ``w``: the contact force spreads over the face's nodes,
and a strike's pressure varies over the face. Measured on the case's launch speed (the slider's
final speed, mm/s): n = 5, 7, 10 (committed), 14, 20 give 40.61, 38.92, 37.99, 38.18, 38.39 (within
1 % from n = 10 on); refine = 1, 2, 4 give 37.63, 37.81, 37.99; dt = T1/50, T1/100 (the case's),
T1/200, T1/400 give 39.06, 37.99, 37.88, 37.86.

Regenerate the committed mesh (L = 40 mm steel rod, 10 mm stack, w = 10 mm, alpha = 30 deg, gap
2 um, slider 30 mm long) with

    .venv/bin/python meshes/vibrodrive.py

or another one, e.g. ``meshes/vibrodrive.py -n 5 -o /tmp/coarse.msh`` (the tests' coarse mesh),
and point the case to it with ``--set mesh.file=/tmp/coarse.msh``. The materials are the case
file's: change them in both places.
"""

from __future__ import annotations

import math
from pathlib import Path

import gmsh

from fem_impact.fem.gmsh_utils import (ScriptParser, add_named_groups, length_option, output_option, run_script,
                                       write_msh)

HERE = Path(__file__).resolve().parent
DEFAULT_OUTPUT = HERE / "vibrodrive.msh"
STEEL = {"E": 210.0e9, "rho": 7800.0, "nu": 0.3}      # rod and slider (Pa, kg/m^3, -)
PIEZO = {"E": 50.0e9, "rho": 7800.0, "nu": 0.3}       # the stack, axially (a PZT multilayer stack)
DEFAULT_MODE = 10                                     # f_max = DEFAULT_MODE * f1 by default


def bar_speed(material: dict) -> float:
    """sqrt(E / rho): longitudinal waves in a thin strip (plane stress), m/s."""
    return math.sqrt(material["E"] / material["rho"])


def shear_speed(material: dict) -> float:
    """sqrt(G / rho), G = E / (2 (1 + nu)), m/s."""
    return bar_speed(material) / math.sqrt(2.0 * (1.0 + material["nu"]))


def first_frequency(length: float = 0.04, piezo_length: float = 0.01, rod: dict = STEEL,
                    piezo: dict = PIEZO) -> float:
    """First longitudinal frequency (Hz) of the clamped stack carrying the free rod (1D, equal sections).

    The stack (clamped at x = 0) moves as ``sin(k_p x)``, the rod (free at its tip) as
    ``cos(k (L + Lp - x))``; equal displacement and force at the joint give
    ``rho_p c_p cot(w Lp / c_p) = rho c tan(w L / c)``, whose root lies below both segments' own
    quarter-wave frequencies.
    """
    from scipy.optimize import brentq

    cp, c = bar_speed(piezo), bar_speed(rod)
    zp, z = piezo["rho"] * cp, rod["rho"] * c
    upper = min(0.5 * math.pi * cp / piezo_length, 0.5 * math.pi * c / length) * (1 - 1e-12)
    w = brentq(lambda w: zp / math.tan(w * piezo_length / cp) - z * math.tan(w * length / c), 1e-6 * upper, upper)
    return w / (2.0 * math.pi)


def element_size(material: dict, f_max: float, elements_per_wavelength: float = 10.0) -> float:
    """h = c_s / (f_max n): ``n`` elements per shear wavelength at ``f_max``."""
    if elements_per_wavelength <= 0 or f_max <= 0:
        raise ValueError("need elements_per_wavelength and f_max > 0")
    return shear_speed(material) / (f_max * elements_per_wavelength)


def face_nodes(width: float, alpha_deg: float, h_contact: float) -> int:
    """Nodes on the tip face (and on the slider's face): elements of at most ``h_contact``."""
    return max(2, math.ceil(width / math.cos(math.radians(alpha_deg)) / h_contact * (1 - 1e-12))) + 1


def build(length: float = 0.04, piezo_length: float = 0.01, width: float = 0.01, alpha_deg: float = 30.0,
          gap: float = 2e-6, slider_length: float = 0.03, slider_height: float = 0.004,
          elements_per_wavelength: float = 10.0, f_max: float | None = None, h: float | None = None,
          refine: float = 4.0, output: Path = DEFAULT_OUTPUT) -> dict:
    """Mesh the stack, the rod and the slider and write them to ``output``.

    ``slider_height`` is the slider's height at its left end (its face rises from there); ``h``
    (if given) is the steel element size, overriding ``elements_per_wavelength`` and ``f_max``
    (the stack's size then scales with its shear speed). Returns a dict with ``path``, ``h``
    (steel), ``h_piezo``, ``h_contact``, ``face_nodes``, ``nodes``, ``f1_hz``
    (``first_frequency``), ``normal`` (tip toward face), ``tip_centre`` and ``drive_y``.
    """
    if not (length > 0 and piezo_length > 0 and width > 0 and gap > 0 and slider_height > 0):
        raise ValueError("need length, piezo_length, width, gap and slider_height > 0")
    if slider_length <= 1.5 * width:
        raise ValueError("need slider_length > 1.5 width (the face must carry the whole tip)")
    if not 0.0 < alpha_deg < 60.0:
        raise ValueError("need 0 < alpha < 60 degrees")
    if refine < 1:
        raise ValueError("need refine >= 1")
    f1 = first_frequency(length, piezo_length)
    if h is None:
        h = element_size(STEEL, f_max if f_max is not None else DEFAULT_MODE * f1, elements_per_wavelength)
    elif h <= 0:
        raise ValueError("need h > 0")
    h_piezo = h * shear_speed(PIEZO) / shear_speed(STEEL)
    h_contact = h / refine
    n_face = face_nodes(width, alpha_deg, h_contact)
    a = math.radians(alpha_deg)
    normal = (math.sin(a), -math.cos(a))
    # The slider spans x in [0, slider_length] with its top face at y = slider_height + x tan(alpha);
    # the tip face's centre sits above the slider's middle, `gap` from the face along the normal.
    face_y = lambda x: slider_height + x * math.tan(a)  # noqa: E731
    xc, half = 0.5 * slider_length, 0.5 * width
    face_l, face_r = (xc - half, face_y(xc - half)), (xc + half, face_y(xc + half))
    tip_l = (face_l[0] - gap * normal[0], face_l[1] - gap * normal[1])
    tip_r = (face_r[0] - gap * normal[0], face_r[1] - gap * normal[1])
    tip_c = (0.5 * (tip_l[0] + tip_r[0]), 0.5 * (tip_l[1] + tip_r[1]))
    y_drive, y_base = tip_c[1] + length, tip_c[1] + length + piezo_length

    output = Path(output)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("vibrodrive")
        geo = gmsh.model.geo
        pt = lambda xy: geo.addPoint(xy[0], xy[1], 0.0)  # noqa: E731
        # rod (tip to the stack) and stack (to the clamped base), sharing the `drive` line
        p_tl, p_tr = pt(tip_l), pt(tip_r)
        p_dl, p_dr = pt((tip_l[0], y_drive)), pt((tip_r[0], y_drive))
        p_bl, p_br = pt((tip_l[0], y_base)), pt((tip_r[0], y_base))
        tip, rod_right = geo.addLine(p_tl, p_tr), geo.addLine(p_tr, p_dr)
        drive, rod_left = geo.addLine(p_dr, p_dl), geo.addLine(p_dl, p_tl)
        stack_right, base, stack_left = geo.addLine(p_dr, p_br), geo.addLine(p_br, p_bl), geo.addLine(p_bl, p_dl)
        rod = geo.addPlaneSurface([geo.addCurveLoop([tip, rod_right, drive, rod_left])])
        stack = geo.addPlaneSurface([geo.addCurveLoop([-drive, stack_right, base, stack_left])])
        # slider: guide, right side, top face in three collinear pieces (the contact part in the middle)
        q_bl, q_br = pt((0.0, 0.0)), pt((slider_length, 0.0))
        q_tr, q_tl = pt((slider_length, face_y(slider_length))), pt((0.0, slider_height))
        q_fl, q_fr = pt(face_l), pt(face_r)
        guide, right = geo.addLine(q_bl, q_br), geo.addLine(q_br, q_tr)
        top_right, face, top_left = geo.addLine(q_tr, q_fr), geo.addLine(q_fr, q_fl), geo.addLine(q_fl, q_tl)
        left = geo.addLine(q_tl, q_bl)
        slider = geo.addPlaneSurface([geo.addCurveLoop([guide, right, top_right, face, top_left, left])])
        for curve in (tip, face):
            geo.mesh.setTransfiniteCurve(curve, n_face)
        geo.synchronize()

        # Size: h (steel) and h_piezo (the stack), h_contact near the faces; the smallest applies.
        field = gmsh.model.mesh.field
        dist = field.add("Distance")
        field.setNumbers(dist, "CurvesList", [tip, face])
        field.setNumber(dist, "NumPointsPerCurve", 100)
        near = field.add("Threshold")
        field.setNumber(near, "InField", dist)
        field.setNumber(near, "SizeMin", h_contact)
        field.setNumber(near, "SizeMax", h)
        field.setNumber(near, "DistMin", 0.25 * width)
        field.setNumber(near, "DistMax", width)
        in_stack = field.add("Box")   # the stack is the rectangle between the drive and base lines
        for key, value in (("VIn", h_piezo), ("VOut", h), ("XMin", tip_l[0]), ("XMax", tip_r[0]),
                           ("YMin", y_drive), ("YMax", y_base)):
            field.setNumber(in_stack, key, value)
        smallest = field.add("Min")
        field.setNumbers(smallest, "FieldsList", [near, in_stack])
        field.setAsBackgroundMesh(smallest)
        for option in ("Mesh.MeshSizeExtendFromBoundary", "Mesh.MeshSizeFromPoints", "Mesh.MeshSizeFromCurvature"):
            gmsh.option.setNumber(option, 0)
        gmsh.option.setNumber("Mesh.Algorithm", 6)   # Frontal-Delaunay: well-shaped triangles

        add_named_groups(2, {"piezo": [stack], "driver": [rod], "slider": [slider]})
        add_named_groups(1, {"base": [base], "drive": [drive], "tip": [tip], "face": [face], "guide": [guide]})
        gmsh.model.mesh.generate(2)
        nodes = len(gmsh.model.mesh.getNodes()[0])
        write_msh(output)
    finally:
        gmsh.finalize()
    return {"path": output, "h": h, "h_piezo": h_piezo, "h_contact": h_contact, "face_nodes": n_face,
            "nodes": nodes, "f1_hz": f1, "normal": normal, "tip_centre": tip_c, "drive_y": y_drive}


def main(argv=None) -> None:
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--length", type=length_option(),
                        default=0.04, help="rod length L in m (default 0.04)")
    parser.add_argument("--piezo-length", type=length_option(),
                        default=0.01, help="stack length Lp in m (default 0.01)")
    parser.add_argument("--width", type=length_option(),
                        default=0.01, help="width w of rod and stack in m (default 0.01)")
    parser.add_argument("--alpha", type=length_option(),
                        default=30.0, help="inclination of the faces to the guide, degrees "
                        "(default 30)")
    parser.add_argument("--gap", type=length_option(),
                        default=2e-6, help="initial gap between tip and face along the "
                        "normal, m (default 2e-6)")
    parser.add_argument("--slider-length", type=length_option(),
                        default=0.03, help="m (default 0.03)")
    parser.add_argument("--slider-height", type=length_option(),
                        default=0.004, help="slider height at its left end, m "
                        "(default 0.004)")
    parser.add_argument("--elements-per-wavelength", "-n", type=length_option(),
                        default=10.0,
                        help="elements per shear wavelength at f_max (default 10)")
    parser.add_argument("--f-max", type=length_option(),
                        default=None,
                        help=f"highest frequency the scene needs, Hz (default {DEFAULT_MODE} f1)")
    parser.add_argument("--h", type=length_option(),
                        default=None, help="steel element size in m (overrides -n and --f-max)")
    parser.add_argument("--refine", type=length_option(),
                        default=4.0, help="element size ratio away from / at the contact "
                        "(default 4)")
    parser.add_argument("-o", "--output", type=output_option, default=DEFAULT_OUTPUT,
                        help=f"output .msh file (default {DEFAULT_OUTPUT.name} next to this script)")
    args, info = run_script(parser, lambda a: build(a.length, a.piezo_length, a.width, a.alpha, a.gap, a.slider_length,
                                                    a.slider_height, a.elements_per_wavelength, a.f_max, a.h,
                                                    a.refine, a.output), argv)
    print(f"wrote {info['path']}: rod {args.length:g} m + stack {args.piezo_length:g} m, width {args.width:g} m, "
          f"faces at {args.alpha:g} deg, gap {args.gap:g} m; h = {info['h']:.3g} m (stack {info['h_piezo']:.3g} m, "
          f"contact {info['h_contact']:.3g} m, {info['face_nodes']} nodes per face), {info['nodes']} nodes; "
          f"f1 = {info['f1_hz']:.5g} Hz")


if __name__ == "__main__":
    main()
