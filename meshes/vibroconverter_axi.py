"""The stepped ultrasonic horn of cases/vibroconverter_free.yaml as a solid of revolution (2D, axisymmetric).

The meridian half-plane of the horn about the x axis (``mesh.hypothesis: axisymmetric``,
``mesh.axis: x``; the radius is y >= 0), for cases/vibroconverter_axi.yaml:

- surface ``horn_large``: x in [0, L1], y in [0, R1] (D = 20 mm by default);
- surface ``horn_small``: x in [L1, L], y in [0, R2] (D = 10 mm); the two share the segment
  x = L1, y in [0, R2], so the mesh is conforming across the step;
- node groups (curves): ``drive`` (the face x = 0), ``step`` (the whole section x = L1, the
  shared segment and the shoulder up to R1: the plane the 1D model's mount holds), ``tip``
  (the face x = L, facing the stop), ``axis`` (y = 0).

Quadrilaterals of side ``h`` (the 1D mesh's element size: ``--h``, default 1 mm = the committed
1D mesh's 50 + 50 elements), transfinite on each rectangle. Regenerate the committed mesh with

    .venv/bin/python meshes/vibroconverter_axi.py

or another horn, e.g. ``meshes/vibroconverter_axi.py --length 0.12 --r-large 0.015 --r-small 0.006
-o /tmp/horn.msh`` (lengths in m; ``--help`` lists the options and their defaults), and point the
case to it with ``--set mesh.file=/tmp/horn.msh``.
"""

from __future__ import annotations

import math
from pathlib import Path

import gmsh

from fem_impact.fem.gmsh_utils import (ScriptParser, add_named_groups, length_option, output_option, run_script,
                                       write_msh)

HERE = Path(__file__).resolve().parent
DEFAULT_OUTPUT = HERE / "vibroconverter_axi.msh"


def build(length: float = 0.1, split: float = 0.5, r_large: float = 0.01, r_small: float = 0.005, h: float = 1e-3,
          output: Path = DEFAULT_OUTPUT) -> dict:
    """Mesh the horn's meridian section; returns ``path`` and the quadrilateral count ``cells``."""
    if not length > 0:
        raise ValueError(f"the length must be > 0 m, got {length:g}")
    if not 0 < split < 1:
        raise ValueError(f"split (the step's position, a fraction of the length) must lie between 0 and 1, "
                         f"got {split:g}")
    if not r_large > r_small > 0:
        raise ValueError(f"the small radius ({r_small:g} m) must be > 0 and below the large one ({r_large:g} m)")
    if not h > 0:
        raise ValueError(f"the element size h must be > 0 m, got {h:g}")
    if h > min(split * length, (1 - split) * length, r_small):
        raise ValueError(f"h = {h:g} m is longer than a segment or the small radius: give h <= "
                         f"{min(split * length, (1 - split) * length, r_small):g}")
    l1 = split * length

    def count(size: float) -> int:
        return max(1, math.ceil(size / h * (1 - 1e-12)))

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("vibroconverter_axi")
        geo = gmsh.model.geo
        p = {name: geo.addPoint(x, y, 0.0) for name, (x, y) in {
            "o": (0, 0), "s0": (l1, 0), "t0": (length, 0), "t1": (length, r_small), "s1": (l1, r_small),
            "s2": (l1, r_large), "d1": (0, r_large)}.items()}
        line = {name: geo.addLine(p[a], p[b]) for name, (a, b) in {
            "axis_large": ("o", "s0"), "axis_small": ("s0", "t0"), "tip": ("t0", "t1"), "top_small": ("t1", "s1"),
            "step_inner": ("s0", "s1"), "shoulder": ("s1", "s2"), "top_large": ("s2", "d1"), "drive": ("d1", "o")}.items()}
        large = geo.addPlaneSurface([geo.addCurveLoop([line["axis_large"], line["step_inner"], line["shoulder"],
                                                       line["top_large"], line["drive"]])])
        small = geo.addPlaneSurface([geo.addCurveLoop([line["axis_small"], line["tip"], line["top_small"],
                                                       -line["step_inner"]])])
        n_large, n_small = count(l1), count(length - l1)
        n_r_small, n_r_shoulder = count(r_small), count(r_large - r_small)
        for name, n in (("axis_large", n_large), ("top_large", n_large), ("axis_small", n_small),
                        ("top_small", n_small), ("tip", n_r_small), ("step_inner", n_r_small),
                        ("shoulder", n_r_shoulder), ("drive", n_r_small + n_r_shoulder)):
            geo.mesh.setTransfiniteCurve(line[name], n + 1)
        geo.mesh.setTransfiniteSurface(large, cornerTags=[p["o"], p["s0"], p["s2"], p["d1"]])
        geo.mesh.setTransfiniteSurface(small)
        for surface in (large, small):
            geo.mesh.setRecombine(2, surface)
        geo.synchronize()
        add_named_groups(2, {"horn_large": [large], "horn_small": [small]})
        add_named_groups(1, {"drive": [line["drive"]], "step": [line["step_inner"], line["shoulder"]],
                             "tip": [line["tip"]], "axis": [line["axis_large"], line["axis_small"]]})
        gmsh.model.mesh.generate(2)
        cells = sum(len(tags[0]) for tags in (gmsh.model.mesh.getElements(2, s)[1] for s in (large, small)))
        write_msh(output)
    finally:
        gmsh.finalize()
    return {"path": Path(output), "cells": cells}


def main(argv=None) -> None:
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--length", type=length_option(), default=0.1, metavar="M",
                        help="total length L in m (default 0.1: f1 = c/(2L) = 25.9 kHz in steel)")
    parser.add_argument("--split", type=length_option(), default=0.5, metavar="FRACTION",
                        help="the step's position as a fraction of L, between 0 and 1 (default 0.5)")
    parser.add_argument("--r-large", type=length_option(), default=0.01, metavar="M",
                        help="radius of the large segment (the drive end) in m (default 0.01: D = 20 mm)")
    parser.add_argument("--r-small", type=length_option(), default=0.005, metavar="M",
                        help="radius of the small segment (the tip) in m, below --r-large (default 0.005: D = 10 mm)")
    parser.add_argument("--h", type=length_option(), default=1e-3, metavar="M", help="element size in m (default 1 mm)")
    parser.add_argument("-o", "--output", type=output_option, default=DEFAULT_OUTPUT,
                        help=f"output .msh file (default {DEFAULT_OUTPUT.name} next to this script)")
    args, info = run_script(parser, lambda a: build(a.length, a.split, a.r_large, a.r_small, a.h, a.output), argv)
    print(f"wrote {info['path']}: the stepped horn's meridian section, L = {args.length:g} m, step at "
          f"{args.split * args.length:g} m, radii {args.r_large:g} and {args.r_small:g} m, {info['cells']} "
          f"quadrilaterals (h = {args.h:g} m)")


if __name__ == "__main__":
    main()
