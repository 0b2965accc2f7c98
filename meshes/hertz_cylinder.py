"""A cylinder on a block in plane strain, meshed apart, half of each by symmetry: Hertz's contact
(tests/test_surface.py).

Builds, with the Gmsh Python API (lengths in m), triangles refined where the two touch:

- body ``cylinder``: the quarter disk of radius ``R`` = 0.05 centred at (0, R), x >= 0, y <= R: node
  groups ``rim`` (its arc, touching the block at the origin), ``lid`` (its flat top, y = R) and
  ``axis`` (x = 0, both bodies);
- body ``block``: the rectangle [0, 0.1] x [-0.1, 0] under it: node groups ``top`` (y = 0) and
  ``base`` (y = -0.1).

Cells of size ``h`` (default R / 200) within ``zone`` (default R / 5) of the origin, growing to R / 5
away from it.

    .venv/bin/python meshes/hertz_cylinder.py -o /tmp/hertz.msh [--cell 2.5e-4]
"""

from __future__ import annotations

import math
from pathlib import Path

import gmsh

from fem_impact.fem.gmsh_utils import ScriptParser, add_named_groups, length_option, output_option, run_script, write_msh

R = 0.05


def build(path: Path, h: float = R / 200, zone: float = R / 5, whole: bool = False) -> Path:
    """Mesh the quarter cylinder and the block with cells of size ``h`` (m) near the contact and write
    them to ``path``; returns ``path``. ``whole``: the half cylinder (x in [-R, R]) on the block [-2R,
    2R] x [-2R, 0], no symmetry (a tangential load), its ``rim`` the arc within 30 degrees of the
    bottom, ``side`` the rest of it, and no ``axis``."""
    if not 0.0 < h <= R / 10:
        raise ValueError(f"h must be in (0, {R / 10:g}] m, got {h:g}")
    path = Path(path)
    gmsh.initialize(["", "-v", "0"])
    try:
        gmsh.model.add("hertz_cylinder")
        geo = gmsh.model.geo
        centre = geo.addPoint(0.0, R, 0.0)
        bottom = geo.addPoint(0.0, 0.0, 0.0)
        side = geo.addPoint(R, R, 0.0)
        if whole:
            c, s_ = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
            left, rim_l, rim_r = (geo.addPoint(x, y, 0.0) for x, y in ((-R, R), (-R * s_, R - R * c),
                                                                         (R * s_, R - R * c)))
            arcs = [geo.addCircleArc(p, centre, q) for p, q in ((left, rim_l), (rim_l, bottom), (bottom, rim_r),
                                                                 (rim_r, side))]
            lid = geo.addLine(side, left)
            cylinder = geo.addPlaneSurface([geo.addCurveLoop([*arcs, lid])])
            x0 = -2 * R
        else:
            arc = geo.addCircleArc(bottom, centre, side)
            lid = geo.addLine(side, centre)
            axis_c = geo.addLine(centre, bottom)
            cylinder = geo.addPlaneSurface([geo.addCurveLoop([arc, lid, axis_c])])
            x0 = 0.0
        b0, b1, b2, b3 = (geo.addPoint(x, y, 0.0) for x, y in ((x0, 0.0), (2 * R, 0.0), (2 * R, -2 * R),
                                                                  (x0, -2 * R)))
        top, right, base, axis_b = (geo.addLine(p, q) for p, q in ((b0, b1), (b1, b2), (b2, b3), (b3, b0)))
        block = geo.addPlaneSurface([geo.addCurveLoop([top, right, base, axis_b])])
        geo.synchronize()
        field = gmsh.model.mesh.field
        distance = field.add("Distance")
        field.setNumbers(distance, "PointsList", [bottom] + ([] if whole else [b0]))
        threshold = field.add("Threshold")
        field.setNumber(threshold, "InField", distance)
        field.setNumber(threshold, "SizeMin", h)
        field.setNumber(threshold, "SizeMax", R / 5)
        field.setNumber(threshold, "DistMin", zone)
        field.setNumber(threshold, "DistMax", 4 * zone)
        field.setAsBackgroundMesh(threshold)
        for option in ("Mesh.MeshSizeExtendFromBoundary", "Mesh.MeshSizeFromPoints", "Mesh.MeshSizeFromCurvature"):
            gmsh.option.setNumber(option, 0)
        if whole:
            edges = {"rim": arcs[1:3], "side": [arcs[0], arcs[3]]}
        else:
            edges = {"rim": [arc], "axis": [axis_c, axis_b]}
        add_named_groups(2, {"cylinder": [cylinder], "block": [block]})
        add_named_groups(1, {**edges, "lid": [lid], "top": [top], "base": [base]})
        gmsh.model.mesh.generate(2)
        write_msh(path)
    finally:
        gmsh.finalize()
    return path


def main(argv=None) -> None:
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-H", "--cell", type=length_option(), default=R / 200,
                        help=f"the cells' size near the contact (default {R / 200:g} m)")
    parser.add_argument("-o", "--output", type=output_option, required=True, help="the .msh file to write")
    _, path = run_script(parser, lambda a: build(a.output, a.cell), argv)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
