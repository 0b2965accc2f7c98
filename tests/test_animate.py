"""``fem-impact animate``: off-screen GIF/MP4 of a run's stored time series (pyvista)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from conftest import CASES, run_case_file, run_cli

pytest.importorskip("pyvista", reason="pyvista is not installed (make setup installs it)")
Image = pytest.importorskip("PIL.Image", reason="Pillow is not installed")

SHORT = ("solver.dt=0.02", "solver.t_end=0.4", "output.every=2")   # 20 steps, a frame every 2nd: 11 frames


def pvd_times(outdir):
    return [float(d.get("timestep")) for d in ET.parse(outdir / "results.pvd").getroot().iter("DataSet")]


def gif_frames(path):
    """All frames of a GIF as RGB arrays."""
    im = Image.open(path)
    assert im.format == "GIF"
    frames = []
    for k in range(im.n_frames):
        im.seek(k)
        frames.append(np.asarray(im.convert("RGB")).astype(int))
    return frames


@pytest.fixture(scope="module")
def strip(tmp_path_factory):
    out = tmp_path_factory.mktemp("animate") / "strip"
    summary, _ = run_case_file(CASES / "impacting_bar.yaml", out, "mesh.dim=2", "mesh.cells=20", *SHORT)
    assert summary["vtk_frames"] == 11
    return out


@pytest.fixture(scope="module")
def rod(tmp_path_factory):
    out = tmp_path_factory.mktemp("animate") / "rod"
    run_case_file(CASES / "impacting_bar.yaml", out, "mesh.cells=40", *SHORT)
    return out


def test_gif_of_a_2d_run_has_one_frame_per_time_step_and_the_bar_moves(strip, tmp_path):
    gif = tmp_path / "strip.gif"
    proc = run_cli("animate", str(strip), "-o", str(gif), "--size", "320x192", "--fps", "5")
    assert proc.returncode == 0, proc.stderr
    assert f"wrote {gif} (11 frames" in proc.stdout
    assert "Traceback" not in proc.stderr
    frames = gif_frames(gif)
    assert len(frames) == len(pvd_times(strip)) == 11
    assert frames[0].shape == (192, 320, 3)
    # below the labels (time, caption) and above the colour bar: the bar itself
    body = [f[40:140] for f in frames]
    assert all(np.any(body[k] != body[k + 1]) for k in range(len(body) - 1)), "two frames show the same picture"
    assert np.abs(body[0] - body[-1]).sum() > 255 * 100, "the bar did not move"
    # red contact-force arrows appear once the bar touches the wall (gap 0.1 at speed 1: t = 0.1)
    red = [np.sum((f[..., 0] > 150) & (f[..., 1] < 80) & (f[..., 2] < 80)) for f in frames]
    assert red[0] == 0 and max(red) > 20


def test_default_output_and_scale(strip):
    from fem_impact.app.animate import animate

    out, scale, frames = animate(strip, field="contact", size=(160, 96), progress=False)
    assert out == strip / "animation.gif" and out.is_file() and frames == 11
    # the largest displacement (the free end's, about v0 t_end = 0.4) becomes 10 % of L = 1;
    # max |u| read back from the .vtu pieces by an independent (numpy) parser
    from fem_impact.app.paraview_view import series_extremes

    ext = series_extremes(strip)
    assert ext["size"] == pytest.approx(1.0) and ext["max_u"] == pytest.approx(0.4, rel=0.05)
    assert scale == pytest.approx(0.1 / ext["max_u"], rel=2e-3)
    out, scale, _ = animate(strip, field="u", scale=2.5, output=strip / "u.gif", size=(160, 96), progress=False)
    assert scale == 2.5 and len(gif_frames(out)) == 11


def test_a_1d_run_renders(rod, tmp_path):
    from fem_impact.app.animate import animate

    gif = tmp_path / "rod.gif"
    out, scale, frames = animate(rod, field="v", output=gif, size=(320, 96), progress=False)
    assert frames == 11 and scale > 0
    f = gif_frames(gif)
    assert len(f) == 11
    assert np.abs(f[0][20:80] - f[-1][20:80]).sum() > 0


@pytest.mark.parametrize("dim", [1, 2])
def test_a_run_written_as_xdmf_animates_as_its_vtk_twin(strip, rod, tmp_path, dim):
    """``output.format: xdmf`` (results.xdmf + results.h5): animate reads it, where it asked for output.vtk,
    and gets the frames of the same run written as VTK; a truncated results.h5 is one line, status 2."""
    from fem_impact.app.animate import load_series

    twin, cells = (strip, 20) if dim == 2 else (rod, 40)
    out = tmp_path / "xdmf"
    run_case_file(CASES / "impacting_bar.yaml", out, f"mesh.dim={dim}", f"mesh.cells={cells}", *SHORT,
                  "output.format=xdmf")
    assert not (out / "results.pvd").exists()
    a, b = load_series(out, "v"), load_series(twin, "v")
    assert np.array_equal(a.times, b.times) and a.dim == b.dim == dim
    assert (a.grid.n_points, a.grid.n_cells) == (b.grid.n_points, b.grid.n_cells)
    order = lambda g: np.lexsort(np.round(np.asarray(g.points), 9).T)   # noqa: E731 (VTU's points carry round-off)
    ka, kb = order(a.grid), order(b.grid)
    assert np.allclose(np.asarray(a.grid.points)[ka], np.asarray(b.grid.points)[kb], atol=1e-14)
    scale = np.abs(b.u).max()
    assert np.allclose(a.u[:, ka], b.u[:, kb], rtol=0, atol=1e-6 * scale)   # (VTU: ASCII, XDMF: binary)
    assert np.allclose(a.scalar[:, ka], b.scalar[:, kb], rtol=0, atol=1e-6 * np.abs(b.scalar).max())
    gif = tmp_path / "x.gif"
    proc = run_cli("animate", str(out), "-o", str(gif), "--size", "320x192")
    assert proc.returncode == 0 and f"wrote {gif} (11 frames" in proc.stdout, proc.stderr
    h5 = out / "results.h5"
    h5.write_bytes(h5.read_bytes()[: h5.stat().st_size // 2])
    proc = run_cli("animate", str(out), "-o", str(tmp_path / "y.gif"))
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "results.xdmf" in lines[0] and "cannot read" in lines[0]
    assert not (tmp_path / "y.gif").exists()


@pytest.mark.mpi
@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun (openmpi-bin) is not installed")
def test_the_pieces_of_a_two_rank_run_join_into_the_serial_mesh(strip, tmp_path):
    from fem_impact.app.animate import load_series

    # as in test_mpi.py: this process's own MPI variables would make mpirun think it is nested
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "OPAL_"))}
    proc = subprocess.run(
        ["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2", sys.executable, "-m", "fem_impact", "run",
         str(CASES / "impacting_bar.yaml"), "-o", str(tmp_path / "mpi"), "-q", "--set", "mesh.dim=2",
         "--set", "mesh.cells=20", *(x for o in SHORT for x in ("--set", o))],
        capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr
    assert "results_p1_000000.vtu" in {p.name for p in (tmp_path / "mpi").iterdir()}
    a, b = load_series(tmp_path / "mpi", "v"), load_series(strip, "v")
    assert (a.grid.n_points, a.grid.n_cells) == (b.grid.n_points, b.grid.n_cells)   # no ghosts, no doubles
    ka = np.lexsort(np.asarray(a.grid.points).T)
    kb = np.lexsort(np.asarray(b.grid.points).T)
    assert np.allclose(np.asarray(a.grid.points)[ka], np.asarray(b.grid.points)[kb], atol=1e-14)
    assert np.allclose(a.u[:, ka], b.u[:, kb], atol=1e-6) and np.allclose(a.scalar[:, ka], b.scalar[:, kb], atol=1e-6)


def test_png_of_one_frame(strip, tmp_path):
    """-o FILE.png writes one frame (the last by default), --frame N and --time T pick another; the
    picture is the animation's frame (same camera, colours and arrows)."""
    gif, last, third, near = (tmp_path / name for name in ("all.gif", "last.png", "third.png", "near.png"))
    common = ("--size", "320x192")
    for args in (("-o", gif), ("-o", last), ("--frame", "2", "-o", third), ("--time", "0.19", "-o", near)):
        proc = run_cli("animate", str(strip), *map(str, args), *common)
        assert proc.returncode == 0, proc.stderr
        assert f"wrote {args[-1]} ({11 if args[-1] == gif else 1} frame" in proc.stdout
    frames = gif_frames(gif)
    pictures = {p: np.asarray(Image.open(p).convert("RGB")).astype(int) for p in (last, third, near)}
    assert all(Image.open(p).format == "PNG" and img.shape == (192, 320, 3) for p, img in pictures.items())
    # The GIF's palette (256 colours) differs slightly from the PNG's full colour: compare loosely.
    closest = lambda img: int(np.argmin([np.abs(f - img).mean() for f in frames]))  # noqa: E731
    assert closest(pictures[last]) == 10 and closest(pictures[third]) == 2
    assert closest(pictures[near]) == 5          # frames every 2 steps of 0.02: t = 0.2 is frame 5
    proc = run_cli("animate", str(strip), "--frame", "-1", *common)
    assert proc.returncode == 0 and (strip / "frame.png").is_file(), proc.stderr


def test_the_contact_state_field_animates(strip, tmp_path):
    """--field state reads contact_state: the frictionless bar's contact nodes 2 (closed without friction)
    in the frames where the contact pushes, never 1 (stick), 0 everywhere before; the picture renders."""
    from fem_impact.app.animate import animate, load_series

    series = load_series(strip, "state")
    state = np.rint(series.scalar)
    pushed = [len(idx) > 0 for idx, _ in series.force]
    assert not state[0].any() and not np.isin(1, state)
    assert all((state[k] == 2).any() == pushed[k] for k in range(len(pushed))) and any(pushed)
    out, _, frames = animate(strip, field="state", output=tmp_path / "state.png", size=(160, 96), progress=False)
    assert frames == 1 and out.is_file()


def test_mp4(strip, tmp_path):
    pytest.importorskip("imageio_ffmpeg", reason="imageio-ffmpeg is not installed: MP4 is not available")
    import imageio.v2 as iio

    mp4 = tmp_path / "strip.mp4"
    proc = run_cli("animate", str(strip), "-o", str(mp4), "--size", "320x192")
    assert proc.returncode == 0, proc.stderr
    reader = iio.get_reader(mp4)
    try:
        assert reader.count_frames() == 11
    finally:
        reader.close()


@pytest.mark.parametrize("args, message", [
    (["{tmp}"], "no results.pvd"),
    (["{tmp}/nowhere"], "no such folder"),
    (["{run}", "--field", "w"], "--field w: unknown, choose one of u, v, a, contact, state"),
    (["{run}", "-o", "{tmp}/a.jpg"], "write a .gif or an .mp4 (an animation) or a .png (one frame)"),
    (["{run}", "--frame", "2", "-o", "{tmp}/a.gif"], "--frame and --time pick one frame for a picture"),
    (["{run}", "--frame", "11"], "--frame 11: the run stored 11 frames"),
    (["{run}", "--frame", "last"], "--frame last: must be a whole number"),
    (["{run}", "--time", "soon"], "--time soon: must be a number"),
    (["{run}", "--scale", "-1"], "--scale -1: must be a number > 0"),
    (["{run}", "--scale", "big"], "--scale big: must be a number > 0"),
    (["{run}", "--size", "12"], "--size 12: give WIDTHxHEIGHT"),
])
def test_bad_input_one_line_exit_2(strip, tmp_path, args, message):
    args = [a.format(tmp=tmp_path, run=strip) for a in args]
    proc = run_cli("animate", *args)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fem-impact: error: ") and message in lines[0], proc.stderr
    assert not list(tmp_path.glob("*.gif")) and not list(tmp_path.glob(".*partial*"))
