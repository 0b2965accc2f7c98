"""A 1D stepped ultrasonic horn (vibroconverter) for cases/vibroconverter_free.yaml and _forced.yaml.

Builds, with the Gmsh Python API, a rod along x in two segments that share the node at the
step:

- curve ``horn_large`` on [0, L1] (the input, thick segment) and curve ``horn_small`` on
  [L1, L] (the output, thin segment); with ``L1 = L/2`` (the default) each segment is a
  quarter wavelength at the first free-free longitudinal mode, the classic half-wave stepped
  horn: its first frequency is ``f1 = c / (2 L)`` whatever the area ratio, the step sits on
  the nodal plane, and the output end moves ``A_large / A_small`` times as far as the input
  end (the gain). The sections are not in the mesh: the case file gives each body its own
  ``area`` (``materials: {horn_large: {..., area: A1}, horn_small: {..., area: A2}}``); equal
  areas make the same mesh a uniform rod;
- physical groups of dimension 1 (bodies): ``horn_large``, ``horn_small``;
- physical groups of dimension 0 (node groups): ``drive`` (x = 0, where the transducer
  pushes), ``step`` (x = L1, the nodal plane of mode 1) and ``tip`` (x = L, facing the stop).

The mesh size follows the physics: ``h = c / (f_max * n)``, ``n`` elements per shortest
wavelength (``--elements-per-wavelength``, default 10) of the highest frequency the scene
needs (``--f-max``). An impact of duration tau sends waves up to about 1/tau along the rod;
the impacts of the cases last 0.05 to 0.2 T1 (T1 = 1/f1), so the default is
``f_max = 20 f1 = 20 c / (2 L)``, the 20th longitudinal mode, wavelength ``c / f_max = L / 10``.
Linear elements with a consistent mass give the frequency of a mode resolved with ``n``
elements per wavelength about ``(2 pi / n)^2 / 24`` too high: 1.6 % at n = 10, 0.4 % at
n = 20; the first mode of the default mesh (100 elements per half wavelength) is 0.004 % too
high. Measured on the free case (impulses of its five impacts against 400 + 400 elements and
T1/1600): 10 elements per wavelength at 20 f1 with dt = T1/400 are within 1.3 % on the
fourth impact and 6 % on the fifth, the weakest. ``--h`` sets the element size directly
instead. Each segment gets ``ceil(length / h)`` equal elements.

The file is written in MSH 4.1 format. Regenerate the committed mesh (L = 0.1 m, step at L/2,
steel c = 5188.75 m/s, 10 elements per wavelength at 20 f1: 50 + 50 elements) with

    .venv/bin/python meshes/vibroconverter.py

or a finer or coarser one, e.g.

    .venv/bin/python meshes/vibroconverter.py --elements-per-wavelength 20 -o /tmp/fine.msh
    .venv/bin/python meshes/vibroconverter.py --h 0.004 -o /tmp/coarse.msh   # 13 + 13 elements

and point a case to it with ``--set mesh.file=/tmp/fine.msh``.
"""

from __future__ import annotations

import math
from pathlib import Path

import gmsh

from fem_impact.fem.gmsh_utils import (ScriptParser, add_named_groups, length_option, output_option, run_script,
                                       write_msh)

HERE = Path(__file__).resolve().parent
DEFAULT_OUTPUT = HERE / "vibroconverter.msh"
STEEL_WAVE_SPEED = math.sqrt(210e9 / 7800.0)   # m/s, sqrt(E / rho) of the cases' steel
DEFAULT_MODE = 20                               # f_max = DEFAULT_MODE * c / (2 L) by default


def element_size(length: float, wave_speed: float = STEEL_WAVE_SPEED, elements_per_wavelength: float = 10.0,
                 f_max: float | None = None) -> float:
    """h = c / (f_max n): ``n`` elements per wavelength at ``f_max`` (default 20 c / (2 L))."""
    if f_max is None:
        f_max = DEFAULT_MODE * wave_speed / (2.0 * length)
    if wave_speed <= 0 or elements_per_wavelength <= 0 or f_max <= 0:
        raise ValueError("need wave_speed, elements_per_wavelength and f_max > 0")
    return wave_speed / (f_max * elements_per_wavelength)


def segment_cells(length: float, split: float, h: float) -> tuple[int, int]:
    """Elements of the two segments for an element size of at most ``h``."""
    l1 = split * length
    # (a tiny relative slack so that a length that is a whole multiple of h is not rounded up)
    return (max(1, math.ceil(l1 / h * (1 - 1e-12))), max(1, math.ceil((length - l1) / h * (1 - 1e-12))))


def build(length: float = 0.1, split: float = 0.5, h: float | None = None, elements_per_wavelength: float = 10.0,
          f_max: float | None = None, wave_speed: float = STEEL_WAVE_SPEED, output: Path = DEFAULT_OUTPUT) -> dict:
    """Mesh the stepped horn and write it to ``output``.

    Returns a dict with ``path``, ``h`` (the element size asked for), ``cells`` (per segment)
    and ``f1_hz`` (``c / (2 L)``, exact for split = 0.5 or equal areas).
    """
    if not (length > 0 and 0 < split < 1):
        raise ValueError(f"need length > 0 and 0 < split < 1 (the step's position, a fraction of the length); got "
                         f"length {length:g}, split {split:g}")
    if h is None:
        h = element_size(length, wave_speed, elements_per_wavelength, f_max)
    elif h <= 0:
        raise ValueError("need h > 0")
    n1, n2 = segment_cells(length, split, h)
    output = Path(output)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("vibroconverter")
        geo = gmsh.model.geo
        points = [geo.addPoint(x, 0.0, 0.0) for x in (0.0, split * length, length)]
        large = geo.addLine(points[0], points[1])
        small = geo.addLine(points[1], points[2])   # shares the step node with `large`
        geo.mesh.setTransfiniteCurve(large, n1 + 1)
        geo.mesh.setTransfiniteCurve(small, n2 + 1)
        geo.synchronize()
        add_named_groups(1, {"horn_large": [large], "horn_small": [small]})
        add_named_groups(0, {name: [p] for name, p in zip(("drive", "step", "tip"), points, strict=True)})
        gmsh.model.mesh.generate(1)
        write_msh(output)
    finally:
        gmsh.finalize()
    f1 = wave_speed / (2.0 * length)
    return {"path": output, "h": h, "cells": (n1, n2), "f1_hz": f1}


def main(argv=None) -> None:
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--length", type=length_option(),
                        default=0.1, help="total length L in m (default 0.1: f1 = 25.9 kHz "
                        "in steel)")
    parser.add_argument("--split", type=length_option(),
                        default=0.5, help="position of the step as a fraction of L "
                        "(default 0.5: the nodal plane of mode 1)")
    parser.add_argument("--elements-per-wavelength", "-n", type=length_option(),
                        default=10.0,
                        help="elements per wavelength at f_max (default 10)")
    parser.add_argument("--f-max", type=length_option(),
                        default=None,
                        help=f"highest frequency the scene needs, Hz (default the {DEFAULT_MODE}th mode, "
                             f"{DEFAULT_MODE} c / (2 L))")
    parser.add_argument("--h", type=length_option(),
                        default=None, help="element size in m (overrides the two above)")
    parser.add_argument("--wave-speed", type=length_option(),
                        default=STEEL_WAVE_SPEED,
                        help=f"sqrt(E / rho) in m/s (default steel, {STEEL_WAVE_SPEED:.2f})")
    parser.add_argument("-o", "--output", type=output_option, default=DEFAULT_OUTPUT,
                        help=f"output .msh file (default {DEFAULT_OUTPUT.name} next to this script)")
    args, info = run_script(parser, lambda a: build(a.length, a.split, a.h, a.elements_per_wavelength, a.f_max,
                                                    a.wave_speed, a.output), argv)
    n1, n2 = info["cells"]
    print(f"wrote {info['path']}: stepped horn L = {args.length:g} m, step at {args.split * args.length:g} m, "
          f"{n1} + {n2} elements (h <= {info['h']:.4g} m); f1 = c/(2L) = {info['f1_hz']:.5g} Hz")


if __name__ == "__main__":
    main()
