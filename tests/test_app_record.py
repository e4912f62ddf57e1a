"""Headless recording to mp4 / gif / PNG sequence, read back with imageio.

The raster backend always runs; the GGUI backend runs where ``vulkan_available()``
says yes and skips with its reason elsewhere.
"""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest
from fake_app import FakeSimulation

from mrsph.app import palette
from mrsph.app import record as rec

FRAMES = 10
W, H = 320, 180


@pytest.fixture(scope="module")
def taichi_cpu(taichi_f32):
    """Taichi on the CPU (f32) for this module, reset afterwards: conftest's
    ``taichi_f32`` does ti.init / ti.reset through mrsph.runtime."""
    import taichi as ti

    return ti


def backend_or_skip(backend):
    if backend == "ggui":
        ok, why = rec.vulkan_available()
        if not ok:
            pytest.skip(f"GGUI offscreen rendering unavailable: {why}")


def read_frames(path) -> np.ndarray:
    return iio.imread(path, index=None)


@pytest.mark.parametrize("backend", ["raster", "ggui"])
@pytest.mark.parametrize("fmt", ["mp4", "gif"])
@pytest.mark.parametrize("dim", [2, 3])
def test_record_reads_back_with_requested_size(dim, fmt, backend, tmp_path, taichi_cpu):
    backend_or_skip(backend)
    sim = FakeSimulation(dim=dim)
    out = rec.record(sim, tmp_path / f"clip.{fmt}", FRAMES, W, H, fps=20, backend=backend, progress=False)
    assert out.exists()
    frames = read_frames(out)
    assert frames.shape[:3] == (FRAMES, H, W), frames.shape
    assert sim.frame == FRAMES - 1, "frame 0 is the initial state, then one advance per frame"
    last = frames[-1][..., :3]
    assert sum(c > 20 for c in palette.count_level_pixels(last, sim.levels, 0.2)) >= 1


def test_gif_loops_forever(tmp_path):
    out = rec.record(FakeSimulation(dim=2), tmp_path / "clip.gif", 3, W, H, backend="raster", progress=False)
    assert iio.immeta(out, index=None).get("loop") == 0


def test_png_sequence(tmp_path):
    out = rec.record(FakeSimulation(dim=2), tmp_path / "frames", 4, W, H, backend="raster", progress=False)
    names = sorted(p.name for p in out.iterdir())
    assert names == [f"frame_{i:05d}.png" for i in range(4)]
    assert iio.imread(out / names[0]).shape == (H, W, 3)


def test_png_sequence_replaces_a_longer_one(tmp_path):
    """Two frames recorded where four were: the folder holds two, and a warning says
    how many were removed."""
    rec.record(FakeSimulation(dim=2), tmp_path / "frames", 4, W, H, backend="raster", progress=False)
    with pytest.warns(RuntimeWarning, match="removed 4 frame file"):
        out = rec.record(FakeSimulation(dim=2), tmp_path / "frames", 2, W, H, backend="raster", progress=False)
    assert sorted(p.name for p in out.iterdir()) == [f"frame_{i:05d}.png" for i in range(2)]


def test_mp4_odd_size_becomes_even(tmp_path, capsys):
    out = rec.record(FakeSimulation(dim=2), tmp_path / "odd.mp4", 2, 321, 181, backend="raster", progress=False)
    assert read_frames(out).shape[1:3] == (182, 322)
    assert "even" in capsys.readouterr().err


def test_size_and_fps_default_to_the_scene(tmp_path):
    sim = FakeSimulation(dim=2)
    sim.scene = {"render": {"width": 200, "height": 100}, "run": {"fps": 12.5}}
    out = rec.record(sim, tmp_path / "d.mp4", 3, backend="raster", progress=False)
    assert read_frames(out).shape[1:3] == (100, 200)
    assert iio.immeta(out)["fps"] == pytest.approx(12.5)


def test_refuses_bad_requests(tmp_path):
    sim = FakeSimulation(dim=2)
    with pytest.raises(ValueError, match="frames"):
        rec.record(sim, tmp_path / "a.mp4", 0, backend="raster")
    with pytest.raises(ValueError, match=".mp4 or .gif"):
        rec.record(sim, tmp_path / "a.avi", 2, backend="raster")
    with pytest.raises(ValueError, match="backend"):
        rec.record(sim, tmp_path / "a.mp4", 2, backend="opengl")


def test_auto_falls_back_to_raster_with_a_notice(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(rec.NO_VULKAN_ENV, "1")
    assert rec.vulkan_available() == (False, f"{rec.NO_VULKAN_ENV} is set")
    out = rec.record(FakeSimulation(dim=2), tmp_path / "f.gif", 2, W, H, progress=False)
    assert read_frames(out).shape[0] == 2
    err = capsys.readouterr().err
    assert "software rasteriser" in err and rec.NO_VULKAN_ENV in err
    with pytest.raises(RuntimeError, match="not available"):
        rec.record(FakeSimulation(dim=2), tmp_path / "g.gif", 2, W, H, backend="ggui", progress=False)


def test_progress_bar_goes_to_stderr(tmp_path, capsys):
    rec.record(FakeSimulation(dim=2), tmp_path / "p.gif", 3, W, H, backend="raster", progress=True)
    captured = capsys.readouterr()
    assert "3/3" in captured.err and captured.out == ""


def test_vulkan_probe_is_cached(monkeypatch):
    """The probe (a subprocess, seconds) runs once per process, whatever it found."""
    calls = []

    def probe(*args, **kwargs):
        calls.append(args)
        return False, "no Vulkan in this test"

    monkeypatch.delenv(rec.NO_VULKAN_ENV, raising=False)
    monkeypatch.setattr(rec, "_probe_cache", {})
    monkeypatch.setattr(rec, "run_probe", probe)
    first = rec.vulkan_available()
    assert first == (False, "no Vulkan in this test"), first
    assert rec.vulkan_available() == first and len(calls) == 1, f"the probe ran {len(calls)} times for two calls"
