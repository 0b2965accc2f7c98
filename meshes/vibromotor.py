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
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gmsh

W, H, L, T = 10e-3, 10e-3, 30e-3, 10e-3


def build(path: Path, h: float) -> None:
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("vibromotor")
        occ = gmsh.model.occ
        driver = occ.addRectangle(0.0, 0.0, 0.0, W, H)
        slider = occ.addRectangle(W / 2 - L / 2, H, 0.0, L, T)
        occ.synchronize()
        tol = 1e-6   # (OCC bounding boxes carry a slack of about 1e-7)
        for name, surface in (("driver", driver), ("slider", slider)):
            gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, [surface]), name)
        def edge(surface, y):
            found = []
            for _, c in gmsh.model.getBoundary([(2, surface)], oriented=False):
                box = gmsh.model.getBoundingBox(1, c)
                if abs(box[1] - y) < tol and abs(box[4] - y) < tol:
                    found.append(c)
            return found
        for name, surface, y in (("base", driver, 0.0), ("tip", driver, H), ("face", slider, H)):
            gmsh.model.setPhysicalName(1, gmsh.model.addPhysicalGroup(1, edge(surface, y)), name)
        for _, c in gmsh.model.getEntities(1):
            box = gmsh.model.getBoundingBox(1, c)
            length = max(box[3] - box[0], box[4] - box[1])
            gmsh.model.mesh.setTransfiniteCurve(c, max(1, round(length / h)) + 1)
        for surface in (driver, slider):
            gmsh.model.mesh.setTransfiniteSurface(surface)
            gmsh.model.mesh.setRecombine(2, surface)
        gmsh.model.mesh.generate(2)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], add_help=False)
    parser.add_argument("-h", type=float, default=1e-3, help="element size (m)")
    parser.add_argument("-o", type=Path, default=Path(__file__).with_name("vibromotor.msh"))
    parser.add_argument("--help", action="help")
    args = parser.parse_args(argv)
    build(args.o, args.h)


if __name__ == "__main__":
    main()
