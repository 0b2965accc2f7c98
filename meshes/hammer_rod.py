"""A 3D hammer and rod for cases/hammer_rod.yaml: a block (the hammer, rigid in the case) strikes the
free end of a rod held at its far end.

Builds, with the Gmsh Python API (lengths in m; the rod along x), structured hexahedra:

- body ``rod``: a square bar ``L`` x ``b`` x ``b`` (200 mm x 10 mm x 10 mm) on x in [0, L], ``cells``
  hexahedra along x (default 80) and ``across`` (default 1) along y and z; node groups ``rod_end``
  (x = 0, the struck face) and ``rod_fixed`` (x = L);
- body ``hammer``: a block ``l`` x ``b`` x ``b`` (20 mm long) on x in [-gap - l, -gap] (gap 0.01 mm),
  with the same cells across; node group ``hammer_face`` (x = -gap), whose nodes face ``rod_end``'s
  one to one (a node-to-node pair contact).

    .venv/bin/python meshes/hammer_rod.py              # the committed meshes/hammer_rod.msh
    .venv/bin/python meshes/hammer_rod.py --cells 160 -o /tmp/fine.msh
"""

from __future__ import annotations

from pathlib import Path

import gmsh

from fem_impact.fem.gmsh_utils import ScriptParser, add_named_groups, length_option, output_option, run_script, \
    write_msh

DEFAULT_OUTPUT = Path(__file__).with_name("hammer_rod.msh")


def build(path: Path = DEFAULT_OUTPUT, length: float = 0.2, side: float = 0.01, hammer: float = 0.02,
          gap: float = 1e-5, cells: int = 80, across: int = 1) -> Path:
    """Mesh the rod and the hammer (lengths in m) and write them to ``path``; returns ``path``.
    ValueError for dimensions that do not fit (before anything is written)."""
    for name, value in (("length", length), ("side", side), ("hammer", hammer), ("gap", gap)):
        if not value > 0:
            raise ValueError(f"{name} must be > 0 m, got {value:g}")
    for name, value in (("cells", cells), ("across", across)):
        if not (isinstance(value, int) and value >= 1):
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    path = Path(path)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("hammer_rod")
        occ = gmsh.model.occ
        rod = occ.addBox(0.0, 0.0, 0.0, length, side, side)
        block = occ.addBox(-gap - hammer, 0.0, 0.0, hammer, side, side)
        occ.synchronize()
        along_hammer = max(1, round(cells * hammer / length))
        for volume, along in ((rod, cells), (block, along_hammer)):
            surfaces = gmsh.model.getBoundary([(3, volume)], combined=False, oriented=False)
            for curve in {tag for _, tag in gmsh.model.getBoundary(surfaces, combined=False, oriented=False)}:
                x0, _y0, _z0, x1, _y1, _z1 = gmsh.model.getBoundingBox(1, curve)
                gmsh.model.mesh.setTransfiniteCurve(curve, (along if abs(x1 - x0) > 0.5 * gap else across) + 1)
            for _, surface in gmsh.model.getBoundary([(3, volume)], combined=False, oriented=False):
                gmsh.model.mesh.setTransfiniteSurface(surface)
                gmsh.model.mesh.setRecombine(2, surface)
            gmsh.model.mesh.setTransfiniteVolume(volume)
        tol = 0.25 * min(gap, side)   # (OCC bounding boxes carry a slack of about 1e-7 m)

        def face(x):
            return [tag for _, tag in gmsh.model.getEntitiesInBoundingBox(x - tol, -tol, -tol, x + tol, side + tol,
                                                                          side + tol, 2)]

        add_named_groups(3, {"rod": [rod], "hammer": [block]})
        add_named_groups(2, {"rod_end": face(0.0), "rod_fixed": face(length), "hammer_face": face(-gap)})
        gmsh.model.mesh.generate(3)
        write_msh(path)
    finally:
        gmsh.finalize()
    return path


def main(argv=None) -> None:
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--length", type=length_option(), default=0.2, help="the rod's length (default 0.2 m)")
    parser.add_argument("--side", type=length_option(), default=0.01, help="the square section's side (default 0.01 m)")
    parser.add_argument("--hammer", type=length_option(), default=0.02, help="the hammer's length (default 0.02 m)")
    parser.add_argument("--gap", type=length_option(), default=1e-5, help="between hammer and rod (default 1e-5 m)")
    parser.add_argument("--cells", type=int, default=80, help="hexahedra along the rod (default 80)")
    parser.add_argument("--across", type=int, default=1, help="hexahedra across the section (default 1)")
    parser.add_argument("-o", "--output", type=output_option, default=DEFAULT_OUTPUT,
                        help=f"output .msh file (default {DEFAULT_OUTPUT.name} next to this script)")
    args, path = run_script(parser, lambda a: build(a.output, a.length, a.side, a.hammer, a.gap, a.cells, a.across),
                            argv)
    print(f"wrote {path}: a rod {args.length:g} m x {args.side:g} m, {args.cells} x {args.across} x {args.across} "
          f"hexahedra, and a hammer {args.hammer:g} m long {args.gap:g} m from its end")


if __name__ == "__main__":
    main()
