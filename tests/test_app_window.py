"""Smoke test of the interactive window under Xvfb, driven by xdotool.

Starts a virtual X server, runs the app in a subprocess with ``DISPLAY`` set, waits for
its window, takes a screenshot through the app's ``p`` key (written to
``MRSPH_WINDOW_SCREENSHOT``), drags the mouse across the fluid, reads the per-frame
JSON lines the app appends to ``MRSPH_WINDOW_STATS``, then presses Escape and expects
exit code 0.

Skips, with the reason, without Xvfb or xdotool or a working GGUI/Vulkan. Slow (the
real solver compiles its kernels on first use): marked ``slow``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from mrsph.app import palette

REPO = Path(__file__).resolve().parent.parent
pytestmark = [pytest.mark.slow, pytest.mark.wallclock]

WIDTH, HEIGHT = 1024, 600
#: First frame of the real solver includes compiling its kernels (tens of seconds on CPU).
FIRST_FRAMES_TIMEOUT_S = 300
#: The real-scene stir: the least hand speed of its drag (m/s), and the least fraction
#: of the KE of the mouse's disc of water at that speed that the fluid gains. Measured:
#: 4.4 % at a peak hand speed of 0.24 m/s, 1.2 % at 0.63 m/s (faster frames: the moves
#: land unevenly between frames and the peak overstates the push), 0.04-0.15 % with the
#: push's strength at 0.
MIN_HAND_SPEED = 0.05
STIR_EFFICIENCY = 0.003
#: ... and the least KE after the stir over the KE before: with the push at 0 the KE stays
#: under 5x (and the efficiency at 0.04-0.15 %); a working push at a slow hand (0.071 m/s,
#: a loaded machine's frames) read 4.3x at an efficiency of 8.6 %.
STIR_KE_RATIO = 3.0
EXIT_TIMEOUT_S = 60
# Parts of the window covered by panels (legend top-left, HUD on the right), whose
# coloured text must not be taken for fluid.
LEGEND_PX = (175, 275)  # rows, columns
HUD_PX_FROM_RIGHT = 350


@pytest.fixture(scope="module")
def xdisplay():
    for tool in ("Xvfb", "xdotool"):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} is not installed (apt-get install xvfb xdotool)")
    from mrsph.app.record import vulkan_available

    ok, why = vulkan_available()
    if not ok:
        pytest.skip(f"no Vulkan for GGUI: {why}")
    n = next(
        (
            n
            for n in range(90, 200)
            if not Path(f"/tmp/.X{n}-lock").exists() and not Path(f"/tmp/.X11-unix/X{n}").exists()
        ),
        None,
    )
    if n is None:
        pytest.skip("no free X display number in :90-:199")
    proc = subprocess.Popen(
        ["Xvfb", f":{n}", "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 30

    def ready() -> bool:
        # the socket can exist before the server answers: a loaded machine once failed
        # the first window with "cannot initialize GLFW"; ask the server itself
        if not Path(f"/tmp/.X11-unix/X{n}").exists():
            return False
        if shutil.which("xdpyinfo") is None:
            return True
        return (
            subprocess.run(
                ["xdpyinfo", "-display", f":{n}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
            ).returncode
            == 0
        )

    while not ready():
        if proc.poll() is not None or time.time() > deadline:
            proc.kill()
            pytest.skip(f"Xvfb :{n} did not start")
        time.sleep(0.1)
    yield f":{n}"
    proc.terminate()
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        proc.kill()


class App:
    """The app in a subprocess, plus the xdotool moves that drive it."""

    def __init__(self, args, display, tmp: Path, ahead: int = 0):
        """``ahead``: simulations the window builds ahead of a switch (mrsph.app.ahead);
        none unless a test asks, so that a switch opens what it names while it is timed."""
        self.display, self.tmp = display, tmp
        self.stats_path = tmp / "stats.jsonl"
        self.shot_path = tmp / "shot.png"
        env = dict(
            os.environ,
            MRSPH_AHEAD=str(ahead),
            DISPLAY=display,
            MRSPH_WINDOW_STATS=str(self.stats_path),
            MRSPH_WINDOW_SCREENSHOT=str(self.shot_path),
            PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
        )
        self.log = open(tmp / "app.log", "w")
        # cwd = tmp: whatever the app or ImGui writes next to it stays out of the repo
        self.proc = subprocess.Popen(
            [sys.executable, *map(str, args)], cwd=tmp, env=env, stdout=self.log, stderr=subprocess.STDOUT
        )
        self.wid = None

    def xdo(self, *args, check=True) -> str:
        r = subprocess.run(
            ["xdotool", *map(str, args)],
            capture_output=True,
            text=True,
            env=dict(os.environ, DISPLAY=self.display),
            timeout=30,
        )
        if check and r.returncode != 0:
            raise AssertionError(f"xdotool {args}: {r.stderr.strip()}")
        return r.stdout

    def output(self) -> str:
        self.log.flush()
        return (self.tmp / "app.log").read_text(errors="replace")[-3000:]

    def alive(self):
        assert self.proc.poll() is None, f"app exited early ({self.proc.returncode}):\n{self.output()}"

    def wait_window(self, timeout: float):
        deadline = time.time() + timeout
        while time.time() < deadline:
            self.alive()
            ids = self.xdo("search", "--name", "^mrsph - ", check=False).split()
            if ids:
                self.wid = ids[0]
                geo = dict(line.split("=") for line in self.xdo("getwindowgeometry", "--shell", self.wid).split())
                self.x, self.y = int(geo["X"]), int(geo["Y"])
                self.w, self.h = int(geo["WIDTH"]), int(geo["HEIGHT"])
                self.xdo("windowfocus", "--sync", self.wid, check=False)
                return
            time.sleep(0.5)
        raise AssertionError(f"no window within {timeout} s:\n{self.output()}")

    def stats(self) -> list[dict]:
        if not self.stats_path.exists():
            return []
        lines = self.stats_path.read_text().splitlines()
        return [json.loads(line) for line in lines if line.strip().endswith("}")]

    def wait_frames(self, n: int, timeout: float) -> list[dict]:
        deadline = time.time() + timeout
        while time.time() < deadline:
            self.alive()
            rows = self.stats()
            if rows and rows[-1]["frame"] >= n:
                return rows
            time.sleep(0.5)
        raise AssertionError(f"fewer than {n} frames within {timeout} s:\n{self.output()}")

    def screenshot(self, timeout: float = 60) -> np.ndarray:
        before = self.shot_path.stat().st_mtime_ns if self.shot_path.exists() else 0
        self.xdo("key", "p")
        deadline = time.time() + timeout
        while time.time() < deadline:
            if self.shot_path.exists() and self.shot_path.stat().st_mtime_ns != before:
                time.sleep(0.3)  # let the writer finish
                return iio.imread(self.shot_path)
            self.alive()
            time.sleep(0.2)
        raise AssertionError(f"no screenshot within {timeout} s:\n{self.output()}")

    def next_frame(self, timeout: float = 60):
        """Wait until the app has drawn another frame (paces the drag to the app's speed,
        which on a CPU can be a few frames per second)."""
        n = len(self.stats())
        deadline = time.time() + timeout
        while len(self.stats()) <= n:
            self.alive()
            if time.time() > deadline:
                raise AssertionError(f"no new frame within {timeout} s:\n{self.output()}")
            time.sleep(0.02)

    def drag(self, points, button=1):
        """Press, move one point per app frame, release."""
        self.xdo("mousemove", self.x + points[0][0], self.y + points[0][1])
        self.next_frame()
        self.xdo("mousedown", button)
        for px, py in points[1:]:
            self.next_frame()
            self.xdo("mousemove", self.x + px, self.y + py)
        self.next_frame()
        self.next_frame()
        self.xdo("mouseup", button)

    def quit(self) -> int:
        self.xdo("key", "Escape")
        try:
            return self.proc.wait(EXIT_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise AssertionError(f"no exit within {EXIT_TIMEOUT_S} s after Escape:\n{self.output()}") from None

    def close(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
        self.log.close()


def fluid_box(img: np.ndarray, levels: int):
    """Bounding box (row0, row1, col0, col1) of pixels in a level colour, outside the
    panels; None when no fluid is visible."""
    mask = np.zeros(img.shape[:2], dtype=bool)
    for lvl in range(levels):
        mask |= palette.level_mask(img[..., :3], lvl, 0.15)
    mask[: LEGEND_PX[0], : LEGEND_PX[1]] = False
    mask[:, img.shape[1] - HUD_PX_FROM_RIGHT :] = False
    rows, cols = np.nonzero(mask)
    if len(rows) < 50:
        return None
    return (np.percentile(rows, 5), np.percentile(rows, 95), np.percentile(cols, 5), np.percentile(cols, 95))


def loading_text_pixels(img: np.ndarray) -> int:
    """Pixels of the loading panel's title colour (mrsph.app.loading) outside the HUD."""
    from mrsph.app import loading

    patch = img[:, : img.shape[1] - HUD_PX_FROM_RIGHT, :3] / 255.0
    return int((np.abs(patch - np.asarray(loading.TITLE_COLOUR)).max(axis=-1) < 0.1).sum())


def loading_shots(app: App, scene: str) -> list[Path]:
    """The loading frames' screenshots of ``scene`` (the hook's), in order."""
    return sorted(app.tmp.glob(f"shot_loading_{scene}_*.png"))


def stir_and_check(app: App, levels: int, first_timeout: float, min_frames: int = 10, points: int = 16):
    app.wait_window(first_timeout)
    rows = app.wait_frames(min_frames, first_timeout)
    img = app.screenshot()
    assert img.shape[:2] == (app.h, app.w), f"screenshot {img.shape} of a {app.w}x{app.h} window"
    box = fluid_box(img, levels)
    assert box is not None, "no fluid (level colours) visible in the screenshot"
    r0, r1, c0, c1 = box
    y = int(r1 - 0.3 * (r1 - r0))  # low in the fluid: there is water there in every scene
    xs = np.linspace(c0 + 0.1 * (c1 - c0), c0 + 0.9 * (c1 - c0), points).astype(int)
    before = app.stats()
    app.drag([(x, y) for x in xs])
    for _ in range(3):
        app.next_frame()
    after = app.stats()
    new = after[len(before) :]
    active = [r for r in new if r["disturbance_active"]]
    assert active, f"dragging the mouse made no disturbance ({len(new)} frames during the drag)"
    assert after[-1]["time"] > before[-1]["time"], "the simulation did not advance"
    ke_before = float(np.median([r["kinetic_energy"] for r in before[-5:]]))
    ke_stirred = max(r["kinetic_energy"] for r in active + new[len(new) // 2 :])
    hand_speed = max(r.get("disturbance_speed", 0.0) for r in active)
    return ke_before, ke_stirred, rows, hand_speed


def test_window_fake_sim_stir_and_quit(xdisplay, tmp_path):
    """Window machinery on the stand-in simulation: fast, independent of the solver."""
    app = App(
        ["-m", "mrsph.app", "--fake", "2", "--width", WIDTH, "--height", HEIGHT, "--frame-budget", "0"],
        xdisplay,
        tmp_path,
    )  # whole frames: no timing in it
    try:
        app.wait_window(120)
        app.wait_frames(120, 120)  # the stand-in fluid has fallen and settled by then
        ke_before, ke_stirred, _, _ = stir_and_check(app, 3, 120)
        assert ke_stirred > 1.5 * ke_before + 1e-6, (
            f"stirring did not move the fluid: KE {ke_before:.3g} -> {ke_stirred:.3g} J"
        )
        assert app.quit() == 0, app.output()
    finally:
        app.close()
    assert not (tmp_path / "imgui.ini").exists(), "ImGui's layout file left behind"


def test_window_frame_budget_cuts_frames_into_slow_motion(xdisplay, tmp_path):
    """With a budget smaller than any step, each drawn frame advances the stand-in
    simulation by exactly one of its steps (a quarter of a frame): the window draws
    what is done instead of waiting for whole frames."""
    from fake_app import FakeSimulation

    fake = FakeSimulation(dim=2)
    step = 1.0 / (fake.fps * fake.steps_per_frame)
    app = App(
        ["-m", "mrsph.app", "--fake", "2", "--width", WIDTH, "--height", HEIGHT, "--frame-budget", "1e-6"],
        xdisplay,
        tmp_path,
    )
    try:
        rows = [r for r in app.wait_frames(24, 120) if not r["loading"]]  # loading: no advance
        advances = np.diff([r["time"] for r in rows[:20]])
        assert np.allclose(advances, step, rtol=1e-6), (
            f"frames advanced the stand-in by {np.unique(advances.round(6))} s; one step is "
            f"{step:.6f} s, a whole frame {1.0 / fake.fps:.6f} s"
        )
        speed = rows[19]["speed"]
        assert 0.0 < speed < 1.0, f"HUD speed {speed} x real time: expected slow motion, above 0 and below 1"
        assert app.quit() == 0, app.output()
    finally:
        app.close()


def test_window_real_scene_stir_and_quit(xdisplay, tmp_path):
    """The real app, ``python3 main.py pool_2d``: a drag across the resting pool stirs it.

    The mouse pushes toward the hand's speed in wall-clock time, so how hard a drag of
    four points (one a frame) pushes depends on how long this machine takes per frame:
    ~1 s here gave a hand speed of 0.24 m/s and a KE of 0.0018 -> 0.028 J; CI's machine
    gave 0.019 J, under the absolute bound this test used to have. The bound is therefore
    on the push the hand asked for: the KE gained is at least STIR_EFFICIENCY of that of
    the mouse's disc of water (rho0 * pi * r^2 per metre of depth) moving at the hand's
    peak speed (values measured: at STIR_EFFICIENCY; the disc jumps more than its
    diameter a frame and pushes each parcel for one frame only)."""
    from mrsph.app.mouse import RADIUS_FRACTION
    from mrsph.scene.config import load_scene

    scene = "pool_2d"
    config = load_scene(scene)
    # whole frames: on this CPU a frame cut to the default budget is ~0.01 s of simulated
    # time, and a drag of a few frames in slow motion hardly shows; the budget has its own test
    app = App(
        [str(REPO / "main.py"), scene, "--width", WIDTH, "--height", HEIGHT, "--frame-budget", "0"], xdisplay, tmp_path
    )
    try:
        ke_before, ke_stirred, rows, hand = stir_and_check(
            app, int(config.get("adaptivity.levels")), FIRST_FRAMES_TIMEOUT_S, points=4
        )
        assert all(r["n_real"] > 0 for r in rows if not r["loading"]), "no fluid particles"
        assert hand > MIN_HAND_SPEED, (
            f"the drag's hand speed was {hand:.3g} m/s (expected > {MIN_HAND_SPEED} m/s: four points across the pool)"
        )
        size = max(hi - lo for lo, hi in zip(config.get("domain.min"), config.get("domain.max")))
        disc_mass = float(config.get("fluid.rest_density")) * np.pi * (RADIUS_FRACTION * size) ** 2
        asked = 0.5 * disc_mass * hand**2
        gained = ke_stirred - ke_before
        assert gained > STIR_EFFICIENCY * asked and ke_stirred > STIR_KE_RATIO * ke_before, (
            f"stirring did not move the fluid: KE {ke_before:.3g} -> {ke_stirred:.3g} J at a hand "
            f"speed of {hand:.3g} m/s; gained {gained:.3g} J = {gained / asked:.3g} of the disc's "
            f"{asked:.3g} J (expected > {STIR_EFFICIENCY}, and KE > {STIR_KE_RATIO}x)"
        )
        assert app.quit() == 0, app.output()
    finally:
        app.close()


def test_window_switches_to_a_scene_that_auto_runs_on_more_threads(xdisplay, tmp_path):
    """Tab from pool_2d (small: ``--threads auto`` gives it one thread) to pool_3d (large:
    all cores) and back. In one process, re-initialising Taichi for another thread count
    freed the window's fields under it (a segmentation fault); each scene now runs in a
    process of its own. While pool_3d opens, the window goes on drawing pool_2d (dimmed)
    under the panel that says so; then pool_3d's first frame runs; shift+Tab opens the
    pool_2d it kept, at once."""
    from mrsph import runtime
    from mrsph.scene.config import load_scene

    assert (runtime.auto_threads(load_scene("pool_2d")), runtime.auto_threads(load_scene("pool_3d"))) == (1, None), (
        "the two scenes no longer differ in their automatic thread count"
    )
    # --frames, --fps and --dump, which the window does not honour, are said to be ignored (and
    # still are: no dump folder is made)
    no_dump = tmp_path / "no_dump"
    app = App(
        [
            str(REPO / "main.py"),
            "pool_2d",
            "--width",
            WIDTH,
            "--height",
            HEIGHT,
            "--frames",
            "2",
            "--fps",
            "24",
            "--dump",
            str(no_dump),
        ],
        xdisplay,
        tmp_path,
    )
    try:
        app.wait_window(FIRST_FRAMES_TIMEOUT_S)
        app.wait_frames(3, FIRST_FRAMES_TIMEOUT_S)
        assert "--frames applies to headless runs and recordings" in app.output(), app.output()
        assert "the window does not dump" in app.output(), app.output()
        assert "--fps applies to recordings" in app.output(), app.output()
        assert not no_dump.exists(), f"the window made the --dump folder {no_dump}, which it never fills"
        before = len(app.stats())
        app.xdo("key", "Tab")
        deadline = time.time() + FIRST_FRAMES_TIMEOUT_S
        while sum(r["scene"] == "pool_3d" and not r["loading"] for r in app.stats()) < 3:
            app.alive()
            assert time.time() < deadline, f"no 3 frames of pool_3d after Tab:\n{app.output()}"
            time.sleep(0.5)
        rows = app.stats()[before:]
        opening = [r for r in rows if r["loading"]]
        assert opening and opening[0]["opening"] == "pool_3d" and opening[0]["scene"] == "pool_2d", opening[:1]
        assert all(r["n_real"] > 0 for r in opening), "the scene left is not drawn while the next one opens"
        first = next(r for r in rows if r["scene"] == "pool_3d")
        assert not first["loading"] and first["n_real"] > 0, first
        shots = loading_shots(app, "pool_3d")
        assert shots, f"no loading frame of pool_3d saved: {sorted(p.name for p in tmp_path.iterdir())}"
        shot = iio.imread(shots[-1])
        assert loading_text_pixels(shot) > 100, "the loading frame has no message"
        assert fluid_box(shot, 3) is not None, "the scene left is not drawn under the loading panel"
        before = len(app.stats())
        app.xdo("key", "shift+Tab")
        deadline = time.time() + FIRST_FRAMES_TIMEOUT_S
        while not any(r["scene"] == "pool_2d" and not r["loading"] for r in app.stats()[before:]):
            app.alive()
            assert time.time() < deadline, f"shift+Tab did not open pool_2d again:\n{app.output()}"
            time.sleep(0.2)
        back = next(r for r in app.stats()[before:] if r["scene"] == "pool_2d" and not r["loading"])
        assert back["time"] < 0.2 and back["message"].startswith("opened pool_2d in "), back
        assert app.quit() == 0, app.output()
    finally:
        app.close()


def test_window_blow_up_pauses_and_prints_one_line(xdisplay, tmp_path):
    """A blow-up in the window (here a speed limit the falling column passes at once)
    pauses the simulation and prints the reason as one line, as a headless run does; the
    window stays open and quits normally."""
    app = App(
        [str(REPO / "main.py"), "dam_break_2d", "--set", "physics.max_speed=0.5", "--width", WIDTH, "--height", HEIGHT],
        xdisplay,
        tmp_path,
    )
    try:
        app.wait_window(FIRST_FRAMES_TIMEOUT_S)
        deadline = time.time() + FIRST_FRAMES_TIMEOUT_S
        while "error: step" not in app.output():
            app.alive()
            assert time.time() < deadline, f"no blow-up reported:\n{app.output()}"
            time.sleep(0.5)
        lines = [l for l in app.output().splitlines() if l.startswith("error: step")]
        assert len(lines) == 1 and lines[0].endswith("above physics.max_speed = 0.5 m/s"), app.output()
        app.next_frame()
        assert app.stats()[-1]["paused"], "the window did not pause after the blow-up"
        assert app.quit() == 0, app.output()
    finally:
        app.close()


def test_window_draws_the_loading_message(xdisplay, tmp_path):
    """Until the first scene runs, the window's frames say "opening SCENE" (their stats
    lines say loading, and the last one's screenshot has the panel's title colour); a
    later frame does not. The stand-in takes 3 s to build here, as a scene would."""
    app = App(
        ["-m", "mrsph.app", "--fake", "2", "--fake-build-s", "3", "--width", WIDTH, "--height", HEIGHT]
        + ["--frame-budget", "0"],
        xdisplay,
        tmp_path,
    )
    try:
        app.wait_window(120)
        rows = app.wait_frames(12, 120)
        assert rows[0]["loading"] and rows[0]["opening"] == "fake_2d" and not rows[-1]["loading"], rows[0]
        shots = sorted(tmp_path.glob("shot_loading_*.png"))
        assert shots, f"no loading frame saved: {sorted(p.name for p in tmp_path.iterdir())}"
        # the last (ImGui draws a new panel from its second frame)
        loading, later = iio.imread(shots[-1]), iio.imread(app.shot_path)  # the 10th frame run
        assert loading_text_pixels(loading) > 30, f"{loading_text_pixels(loading)} pixels of the loading title"
        assert loading_text_pixels(later) < 10, "the message is still drawn after loading"
        assert app.quit() == 0, app.output()
    finally:
        app.close()


def test_window_latches_a_tapped_key_and_toggles_the_water_view(xdisplay, tmp_path):
    """A tap of z (pressed and released between two frames: xdotool's key) zooms the 3D
    camera in once, by e^(-1.2 x 0.15) (window.TAP_S), or by up to one more frame's held
    time (at most 0.1 s) when the release lands after the next frame began; w turns the
    water view on. Without the latch, the held-key check never sees a tap's key down, or
    sees it down for one frame only (at most 0.1 s: too little zoom)."""
    app = App(
        ["-m", "mrsph.app", "--fake", "3", "--width", WIDTH, "--height", HEIGHT, "--frame-budget", "0"],
        xdisplay,
        tmp_path,
    )
    try:
        app.wait_window(120)
        rows = app.wait_frames(5, 120)
        before = rows[-1]["camera_distance"]
        app.xdo("key", "z")
        app.xdo("key", "w")
        deadline = time.time() + 60
        while True:
            app.alive()
            last = app.stats()[-1]
            if last["camera_distance"] < before and last["surface"]:
                break
            assert time.time() < deadline, f"camera {before} -> {last['camera_distance']}, water view {last['surface']}"
            time.sleep(0.3)
        held_s = np.log(before / last["camera_distance"]) / 1.2
        assert 0.15 - 2e-3 <= held_s <= 0.25 + 2e-3, (
            f"camera {before} -> {last['camera_distance']}: z acted {held_s:.4f} s, a tap acts 0.15 s"
        )
        assert app.quit() == 0, app.output()
    finally:
        app.close()


def test_window_s_switches_the_solver_and_frames_keep_coming(xdisplay, tmp_path):
    """s on pool_2d opens it with the next solver of the schema's list (dfsph): pool_2d
    goes on being drawn while that opens (the frames say loading), then the stats line's
    solver turns from wcsph to dfsph and dfsph frames keep coming with simulated time
    advancing and the density solve iterating; the HUD says what opened, how fast."""
    from mrsph.app.switch import next_solver

    app = App([str(REPO / "main.py"), "pool_2d", "--width", WIDTH, "--height", HEIGHT], xdisplay, tmp_path)
    try:
        app.wait_window(FIRST_FRAMES_TIMEOUT_S)
        rows = app.wait_frames(3, FIRST_FRAMES_TIMEOUT_S)
        assert {r["solver"] for r in rows if not r["loading"]} == {"wcsph"}, "pool_2d no longer opens with wcsph"
        want = next_solver("wcsph")
        app.xdo("key", "s")
        deadline = time.time() + FIRST_FRAMES_TIMEOUT_S
        while True:
            app.alive()
            new = app.stats()[len(rows) :]
            running = [r for r in new if r["solver"] == want and not r["loading"]]
            if len(running) >= 5:
                break
            assert time.time() < deadline, f"{len(running)} {want} frames after s:\n{app.output()}"
            time.sleep(0.5)
        opening = [r for r in new if r["loading"]]
        assert opening and opening[0]["opening"] == f"pool_2d with {want}" and opening[0]["solver"] == "wcsph", opening[
            :1
        ]
        assert running[0]["message"].startswith(f"opened pool_2d with {want} in "), running[0]["message"]
        times = [r["time"] for r in running]
        assert times[-1] > times[0] > 0.0, f"{want} frames did not advance: {times}"
        assert running[-1]["density_iterations"] > 0, running[-1]
        assert app.quit() == 0, app.output()
    finally:
        app.close()


def test_window_builds_the_next_solver_ahead_and_s_opens_it_at_once(xdisplay, tmp_path):
    """With one simulation built ahead (MRSPH_AHEAD=1: what s would open), pool_2d runs
    while pool_2d with the next solver builds in a worker of its own; once the stats say
    it is ready, s opens it without a loading frame, within a second, and it advances."""
    from mrsph.app.switch import next_solver

    app = App([str(REPO / "main.py"), "pool_2d", "--width", WIDTH, "--height", HEIGHT], xdisplay, tmp_path, ahead=1)
    try:
        app.wait_window(FIRST_FRAMES_TIMEOUT_S)
        app.wait_frames(3, FIRST_FRAMES_TIMEOUT_S)
        deadline = time.time() + FIRST_FRAMES_TIMEOUT_S
        while not app.stats()[-1]["ahead_ready"]:
            app.alive()
            assert time.time() < deadline, f"nothing built ahead within {FIRST_FRAMES_TIMEOUT_S} s:\n{app.output()}"
            time.sleep(0.5)
        rows = app.stats()
        running = next(i for i, r in enumerate(rows) if not r["loading"])  # the start's panel before
        assert not any(r["loading"] for r in rows[running:]), "building ahead showed the loading panel"
        app.next_frame()
        assert app.stats()[-1]["s_ready"], "the HUD does not say that what s opens is ready"
        assert not rows[running]["s_ready"], "the HUD said ready before anything was built ahead"
        want = next_solver("wcsph")
        pressed = time.time()
        app.xdo("key", "s")
        while True:
            app.alive()
            new = app.stats()[len(rows) :]
            running = [r for r in new if r["solver"] == want and not r["loading"]]
            if len(running) >= 3:
                break
            assert time.time() < pressed + 60, f"{len(running)} {want} frames after s:\n{app.output()}"
            time.sleep(0.1)
        first = running[0]
        assert first["unix_s"] - pressed < 1.0, f"pool_2d with {want} opened {first['unix_s'] - pressed:.2f} s after s"
        assert not any(r["loading"] for r in new), "a simulation built ahead opened through the loading panel"
        assert first["message"].startswith(f"opened pool_2d with {want} in 0."), first["message"]
        assert running[-1]["time"] > running[0]["time"], "it does not advance"
        assert app.quit() == 0, app.output()
        # two workers and the window started Taichi: it announces its start once
        log = (tmp_path / "app.log").read_text(errors="replace")
        assert log.count("Starting on arch") == 1, log[-3000:]
    finally:
        app.close()
