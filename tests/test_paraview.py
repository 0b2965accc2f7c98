"""A run's results in ParaView itself (``pvpython`` from Debian's ``paraview``), and ``view.py``.

ParaView runs as a subprocess with small scripts written to tmp_path that print JSON; reading
data needs no display. Rendering ``view.py`` does: Debian's ParaView renders through X, so
that part runs on a private Xvfb (skipped without it).
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import shutil
import subprocess
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from conftest import CASES, read_history, run_case_file

PVPYTHON = shutil.which("pvpython")
XVFB = shutil.which("Xvfb")
needs_pvpython = pytest.mark.skipif(
    PVPYTHON is None, reason="pvpython not found (Debian package `paraview`; `make setup` installs it)")

SHORT = ("solver.dt=0.02", "solver.t_end=0.4", "output.every=2")   # 20 steps, 11 frames

# Reads each run's results.pvd and prints, per run: the time steps, the point arrays, and at
# every time step the u of the point nearest the probe.
PROBE = r'''
import json, sys
from paraview import servermanager
from paraview.simple import PVDReader
from vtkmodules.util.numpy_support import vtk_to_numpy
import numpy as np

out = {}
for folder, x, y in json.loads(sys.argv[1]):
    reader = PVDReader(FileName=folder + "/results.pvd")
    reader.UpdatePipelineInformation()
    times = list(reader.TimestepValues)
    info = {"times": times, "arrays": sorted(reader.PointData.keys()), "u": []}
    for t in times:
        reader.UpdatePipeline(t)
        data = servermanager.Fetch(reader)
        pts = vtk_to_numpy(data.GetPoints().GetData())
        k = int(np.argmin(np.hypot(pts[:, 0] - x, pts[:, 1] - y)))
        info["point"] = pts[k].tolist()
        info["u"].append(vtk_to_numpy(data.GetPointData().GetArray("u"))[k].tolist())
    out[folder] = info
print("JSON" + json.dumps(out))
'''


def pvpython(*args, timeout=120):
    return subprocess.run([PVPYTHON, *args], capture_output=True, text=True, timeout=timeout)


@contextlib.contextmanager
def private_display():
    """A virtual X display of this test's own: ``DISPLAY`` for the body.

    ``-noreset``: an X server resets when its last client disconnects, and refuses connections while it
    does; ParaView connects, disconnects and connects again while it starts, so on a busy machine its
    second connection fell into the reset ("bad X server connection", an abort in CreateAWindow).
    ``-displayfd``: the server picks a free display itself and reports it once it accepts connections
    (``xvfb-run -a`` guesses a number, and two started at once may take the same one)."""
    read, write = os.pipe()
    server = subprocess.Popen([XVFB, "-displayfd", str(write), "-screen", "0", "1280x1024x24", "-nolisten", "tcp",
                               "-noreset"], pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    os.close(write)
    try:
        number = b""
        while not number.endswith(b"\n"):
            ready, _, _ = select.select([read], [], [], 60)
            chunk = os.read(read, 16) if ready else b""
            if not chunk:
                server.kill()
                raise RuntimeError(f"Xvfb did not start: {server.communicate()[1].decode()[-500:]}")
            number += chunk
        yield f":{number.decode().strip()}"
    finally:
        os.close(read)
        if server.poll() is None:
            server.terminate()
            server.wait(timeout=30)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A 1D rod and a 2D strip of the impacting bar, each with its view.py."""
    from fem_impact.app.paraview_view import write_view_script

    base = tmp_path_factory.mktemp("paraview")
    out = {}
    for dim, cells in ((1, 40), (2, 20)):
        folder = base / f"bar{dim}d"
        run_case_file(CASES / "impacting_bar.yaml", folder, f"mesh.dim={dim}", f"mesh.cells={cells}", *SHORT)
        write_view_script(folder, dim)
        out[dim] = folder
    return out


def pvd_times(folder):
    return [float(d.get("timestep")) for d in ET.parse(folder / "results.pvd").getroot().iter("DataSet")]


def test_view_script_is_written_with_the_runs_scale(runs):
    from fem_impact.app.paraview_view import displacement_scale

    for dim, folder in runs.items():
        text = (folder / "view.py").read_text()
        compile(text, str(folder / "view.py"), "exec")
        scale = displacement_scale(folder)
        assert 0.1 < scale < 1 and f"SCALE = {scale!r}" in text and f"DIM = {dim}" in text
        assert "COLOR = 'v'" in text and f"RUN_FOLDER = {str(folder.resolve())!r}" in text


@needs_pvpython
def test_paraview_reads_the_series(runs, tmp_path):
    script = tmp_path / "probe.py"
    script.write_text(PROBE)
    # the probe `right` of the case: x = 1 (on the axis of the rod, the lower corner of the strip)
    proc = pvpython(str(script), json.dumps([[str(runs[1]), 1.0, 0.0], [str(runs[2]), 1.0, 0.0]]))
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.split("JSON", 1)[1])
    for dim, folder in runs.items():
        info = result[str(folder)]
        summary = json.loads((folder / "summary.json").read_text())
        assert len(info["times"]) == summary["vtk_frames"] == len(pvd_times(folder)) == 11
        assert np.allclose(info["times"], pvd_times(folder), rtol=0, atol=1e-12)
        assert {"u", "v", "a", "contact_force"} <= set(info["arrays"])
        assert info["point"] == pytest.approx([1.0, 0.0, 0.0], abs=1e-12)
        h = read_history(folder)
        for t, u in zip(info["times"], info["u"], strict=True):
            row = int(np.argmin(abs(h["t"] - t)))
            assert abs(h["t"][row] - t) < 1e-9
            ux = h["right_ux"][row]
            assert u[0] == pytest.approx(ux, rel=1e-9, abs=1e-14), (dim, t)
            if dim == 1:
                assert u[1] == u[2] == 0.0
        assert info["u"][-1][0] == pytest.approx(-0.4, rel=0.05)   # the free end, still at -v0 t


@needs_pvpython
@pytest.mark.skipif(XVFB is None, reason="Xvfb not found (Debian package `xvfb`): Debian's ParaView renders "
                                         "through X, so view.py needs a (virtual) display")
@pytest.mark.parametrize("dim", [1, pytest.param(2, marks=pytest.mark.slow)])   # (2D: 12 s, the same script)
def test_view_script_renders_a_screenshot(runs, tmp_path, dim):
    from PIL import Image

    png = tmp_path / "view.png"
    cmd = [PVPYTHON, "--force-offscreen-rendering", str(runs[dim] / "view.py"),
           "--screenshot", str(png), "--time", "0.3", "--size", "600x250"]
    with private_display() as display:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=180, cwd=tmp_path,
                              env={**os.environ, "DISPLAY": display})
    assert proc.returncode == 0, proc.stderr[-3000:]
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    assert img.shape == (250, 600, 3)
    colours = {tuple(c) for c in img.reshape(-1, 3)[::7]}
    assert len(colours) > 20, "a blank picture"
    red = np.sum((img[..., 0] > 150) & (img[..., 1] < 80) & (img[..., 2] < 80))
    assert red > 20, "no contact-force arrows (the bar is on the wall at t = 0.3)"


XDMF_PROBE = """
import json, sys
from paraview.simple import OpenDataFile
from paraview import servermanager
from vtkmodules.util.numpy_support import vtk_to_numpy
reader = OpenDataFile(sys.argv[1])
reader.UpdatePipelineInformation()
times = list(reader.TimestepValues)
reader.UpdatePipeline(times[-1])
data = servermanager.Fetch(reader)
block = data.GetBlock(0) if data.IsA("vtkMultiBlockDataSet") else data
print("JSON" + json.dumps({"times": times, "arrays": sorted(reader.PointData.keys()),
                           "points": block.GetNumberOfPoints(),
                           "u": vtk_to_numpy(block.GetPointData().GetArray("u")).tolist()}))
"""


@needs_pvpython
def test_paraview_opens_the_binary_series(tmp_path):
    """output.format: xdmf (results.xdmf + results.h5): pvpython opens it with every field and frame,
    and the last frame's u is the one fem_impact's reader gives."""
    import fem_impact as fi

    folder = tmp_path / "xdmf"
    run_case_file(CASES / "impacting_bar.yaml", folder, "mesh.dim=2", "mesh.cells=20", "output.format=xdmf", *SHORT)
    script = tmp_path / "probe.py"
    script.write_text(XDMF_PROBE)
    proc = pvpython(str(script), str(folder / "results.xdmf"))
    assert proc.returncode == 0, proc.stderr[-3000:]
    info = json.loads(proc.stdout.split("JSON", 1)[1])
    fields = fi.Result.load(folder).fields()
    assert info["arrays"] == ["a", "contact_force", "contact_state", "u", "v"]
    assert np.allclose(info["times"], fields.t, rtol=0, atol=1e-12) and len(fields.t) == 11
    assert info["points"] == fields.points.shape[0]
    assert np.abs(np.asarray(info["u"]) - fields.values["u"][-1]).max() == 0.0
