"""A 2D (plane stress) friction drive for cases/vibromotor.yaml: a driver whose top face vibrates on an
ellipse carries a slider pressed onto it; friction moves the slider along x against a load.

Builds, with the Gmsh Python API (lengths in m; y up, the travel along x), structured quadrilaterals
of size ``h`` (``-h``, default 1 mm):

- body ``driver``: a block ``w`` x ``H`` (10 mm x 10 mm) held at its bottom face (node group
  ``base``, y = 0); its top face (node group ``tip``, y = H) is where the case applies the drive
  and where the slider rests;
- body ``slider``: a bar ``L`` x ``t`` (30 mm x 10 mm) lying on the tip from y = H, from x = -L/2 + w/2
  (centred over the tip); its bottom face is node group ``face``.

The contact ``tip``-``face`` is a pair with ``coupling: mean``: one row between the two faces' mean
motions, so it follows the slider as it travels along the tip (up to (L - w)/2 = 10 mm either way,
while the tip stays under the face).

    .venv/bin/python meshes/vibromotor.py              # the committed meshes/vibromotor.msh
    .venv/bin/python meshes/vibromotor.py -h 2e-3 -o /tmp/coarse.msh
    .venv/bin/python meshes/vibromotor.py --slider-length 0.05 --driver-height 0.02 -o /tmp/long.msh

(lengths in m; ``--help`` lists the options and their defaults.) The case's loads and drive are the
case file's: a changed geometry may need them changed too.
"""

from __future__ import annotations

from pathlib import Path

import gmsh

from fem_impact.fem.gmsh_utils import ScriptParser, length_option, output_option, run_script

W, H, L, T = 10e-3, 10e-3, 30e-3, 10e-3
DEFAULT_OUTPUT = Path(__file__).with_name("vibromotor.msh")


def build(path: Path, h: float, driver_width: float = W, driver_height: float = H, slider_length: float = L,
          slider_thickness: float = T) -> dict:
    """Mesh the driver and the slider (lengths in m) and write them to ``path``; returns ``path`` and
    ``cells`` (quadrilaterals). ValueError for dimensions that do not fit (before anything is written)."""
    for name, value in (("h", h), ("driver_width", driver_width), ("driver_height", driver_height),
                        ("slider_length", slider_length), ("slider_thickness", slider_thickness)):
        if not value > 0:
            raise ValueError(f"{name} must be > 0 m, got {value:g}")
    if slider_length <= driver_width:
        raise ValueError(f"the slider ({slider_length:g} m) must be longer than the driver is wide "
                         f"({driver_width:g} m): the tip stays under the face as the slider travels")
    if h > min(driver_width, driver_height, slider_thickness):
        raise ValueError(f"h = {h:g} m is above the smallest dimension: give h <= "
                         f"{min(driver_width, driver_height, slider_thickness):g}")
    w, height, length, thickness = driver_width, driver_height, slider_length, slider_thickness
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("vibromotor")
        occ = gmsh.model.occ
        driver = occ.addRectangle(0.0, 0.0, 0.0, w, height)
        slider = occ.addRectangle(w / 2 - length / 2, height, 0.0, length, thickness)
        occ.synchronize()
        tol = 1e-4 * min(w, height, thickness)   # (OCC bounding boxes carry a slack of about 1e-7 m)
        for name, surface in (("driver", driver), ("slider", slider)):
            gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, [surface]), name)

        def edge(surface, y):
            found = []
            for _, c in gmsh.model.getBoundary([(2, surface)], oriented=False):
                box = gmsh.model.getBoundingBox(1, c)
                if abs(box[1] - y) < tol and abs(box[4] - y) < tol:
                    found.append(c)
            return found
        for name, surface, y in (("base", driver, 0.0), ("tip", driver, height), ("face", slider, height)):
            gmsh.model.setPhysicalName(1, gmsh.model.addPhysicalGroup(1, edge(surface, y)), name)
        for _, c in gmsh.model.getEntities(1):
            box = gmsh.model.getBoundingBox(1, c)
            size = max(box[3] - box[0], box[4] - box[1])
            gmsh.model.mesh.setTransfiniteCurve(c, max(1, round(size / h)) + 1)
        for surface in (driver, slider):
            gmsh.model.mesh.setTransfiniteSurface(surface)
            gmsh.model.mesh.setRecombine(2, surface)
        gmsh.model.mesh.generate(2)
        cells = sum(len(tags[0]) for tags in (gmsh.model.mesh.getElements(2, s)[1] for s in (driver, slider)))
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    return {"path": Path(path), "cells": cells}


def main(argv=None) -> None:
    parser = ScriptParser(description=__doc__.splitlines()[0], add_help=False)
    parser.add_argument("-h", "--h", type=length_option(), default=1e-3, metavar="M",
                        help="element size in m (default 1 mm)")
    parser.add_argument("--driver-width", type=length_option(), default=W, metavar="M",
                        help=f"width w of the driver block in m (default {W:g})")
    parser.add_argument("--driver-height", type=length_option(), default=H, metavar="M",
                        help=f"height H of the driver block in m (default {H:g})")
    parser.add_argument("--slider-length", type=length_option(), default=L, metavar="M",
                        help=f"length L of the slider in m, above the driver's width (default {L:g})")
    parser.add_argument("--slider-thickness", type=length_option(), default=T, metavar="M",
                        help=f"thickness t of the slider in m (default {T:g})")
    parser.add_argument("-o", "--output", type=output_option, default=DEFAULT_OUTPUT,
                        help=f"output .msh file (default {DEFAULT_OUTPUT.name} next to this script)")
    parser.add_argument("--help", action="help", help="show this help and stop")
    args, info = run_script(parser, lambda a: build(a.output, a.h, a.driver_width, a.driver_height, a.slider_length,
                                                    a.slider_thickness), argv)
    print(f"wrote {info['path']}: driver {args.driver_width:g} x {args.driver_height:g} m, slider "
          f"{args.slider_length:g} x {args.slider_thickness:g} m, {info['cells']} quadrilaterals (h = {args.h:g} m)")


if __name__ == "__main__":
    main()
