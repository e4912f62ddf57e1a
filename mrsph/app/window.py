"""The interactive window: watch the fluid, stir it with the mouse, tune it live.

One window frame = one ``sim.advance_frame(frame_budget)`` (unless paused): a frame of
simulated time, or as much of it as fits in the wall-clock budget (slow motion on a
machine too slow for the scene, with the window still responsive), then one snapshot,
drawn by the shared :class:`~mrsph.app.render.Renderer`, plus a HUD of GGUI widgets.
The physics never sees the window: the window only calls the Simulation API
(``advance_frame``, ``snapshot``, ``set_param``, ``set_disturbance``, ``reset``).

Controls (Taichi 1.7.4's GGUI reports only letters, arrows, space, Tab, Escape, Shift
and the mouse buttons: no digits, no punctuation, no wheel, so every action has a letter
or a HUD button)

=====================  =================================================
space / n / r          pause-run / step one frame / reset
tab / help buttons     next scene / any scene
c / v / h / u          colour mode / show virtual particles / help / HUD panel
s / HUD solver button  pressure solver wcsph <-> dfsph (rebuilds the scene)
left drag              push the fluid along the drag
right drag (2D),       pull the fluid toward the cursor
shift + left drag
q / e                  smaller / larger mouse radius (drawn as a white circle)
w                      water view (surface) on / off
3D: right drag,        orbit the camera
arrows
3D: middle drag        pan
3D: z / x              zoom in / out;  f: frame the domain again
p                      screenshot (PNG, into out/screenshots/)
Esc                    quit
=====================  =================================================

The mouse acts in wall-clock time, capped (``mrsph.app.mouse.safe_speed``). Key taps
are latched: a press seen between two frames acts once even when the key is up again
when the next frame reads the keys (z / x / arrows at a few frames per second).
A scene that loads or compiles shows "loading SCENE (compiling ...)"; Taichi compiles
on the main thread only, so an Esc pressed during one compile is answered when it ends.
The refinement checkbox and the solver switch rebuild the running scene with an override
(``adaptivity.enabled``, ``fluid.solver``), each on top of the other, and carry the
live-tuned sliders over; a scene that cannot take the other solver says why in the HUD.

Test hooks: ``MRSPH_WINDOW_STATS`` and ``MRSPH_WINDOW_SCREENSHOT`` (mrsph.app.hooks).
"""

from __future__ import annotations

import inspect
import json
import os
import sys
import time

from . import palette
from .hooks import AUTO_SCREENSHOT_FRAME, SCREENSHOT_ENV, STATS_ENV, loading_shot_path, stats_row, write_screenshot
from .hud import Rates, Speed, draw_hud, hud_rect_px
from .loading import loading_panel, show_loading_frame
from .marks import frame_marks
from .mouse import MouseDisturbance, safe_speed
from .pointer import Pointer
from .probe import display_available  # noqa: F401  (mrsph.cli.commands imports it from here)
from .switch import next_solver, running_solver, why_not
from .view import scene_setting

#: Keys that change the mouse radius: one press = this many wheel notches.
RADIUS_KEY_NOTCHES = 1.0
#: A tapped camera key (seen pressed and released between two frames) acts as if held
#: this long: one tap of z zooms by e^(-view.ZOOM_KEY_RATE * TAP_S), 17 %.
TAP_S = 0.15
#: Frames that say "loading SCENE (compiling the step ...)" before the first advance
#: compiles it: ImGui lays out a new window on its first frame and draws it from the
#: second, so with one frame the app's first message was never seen (a test's
#: screenshot of it had no text).
LOADING_FRAMES = 2
#: Keys whose action lasts while they are held (3D camera, with the arrows): taps of them
#: are latched.
CAMERA_KEYS = ("z", "x")
#: Keys that flip a flag of the window: the attribute flipped.
TOGGLE_KEYS = {" ": "paused", "h": "show_help", "u": "show_hud", "v": "show_virtual", "w": "surface"}


def _accepts_overrides(make_sim) -> bool:
    """Whether make_sim takes a second argument (the scene overrides)."""
    try:
        params = list(inspect.signature(make_sim).parameters.values())
    except (TypeError, ValueError):
        return False
    positional = [p for p in params if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    return (
        len(positional) >= 2
        or any(p.kind == p.VAR_POSITIONAL for p in params)
        or any(p.name == "overrides" for p in params)
    )


class _App:
    """State of the running window; :func:`run_window` is its only user."""

    def __init__(self, make_sim, scene_name, scene_names, width, height, frame_budget=None):
        import taichi as ti

        from .render import ImguiIniGuard, Renderer

        self.ti = ti
        self.ini = ImguiIniGuard()
        self.make_sim = make_sim
        self.can_override = _accepts_overrides(make_sim)
        self.scene_names = list(scene_names) or [scene_name]
        self.scene_name = scene_name
        # The simulation first: it initialises Taichi, which the window needs.
        self.sim = self._build(scene_name)
        # no scene name in the title: GGUI 1.7.4 cannot change it when the scene changes
        # (the panel's first line names the scene)
        self.window = ti.ui.Window("mrsph - adaptive SPH", (int(width), int(height)), vsync=True)
        self.renderer = Renderer(self.window, palette.Style.from_scene(self.sim.scene), self.sim.scene)
        self.paused = False
        self.step_once = False
        self.show_virtual = False
        self.color_mode = "level"
        self.show_help = False
        self.show_hud = True
        self.message = ""
        self.snap = None
        self.dirty = True
        self.rates = Rates()
        self.fps = 0.0
        self.frame_budget = frame_budget
        self.speed = Speed()
        self.start = time.perf_counter()
        self.last = self.start
        self.pointer = Pointer()  # who owns a drag (fluid, camera, HUD)
        self.stats_file = None
        path = os.environ.get(STATS_ENV)
        if path:
            self.stats_file = open(path, "a", encoding="utf-8")
        self.screenshot_path = os.environ.get(SCREENSHOT_ENV)
        self.frames_drawn = 0
        self.loading_shots = 0  # loading frames saved by the test hook
        self.want_screenshot = False
        self.taps: set = set()  # camera keys pressed since the last frame
        self.loading = None  # the loading message while a scene loads or compiles
        self.surface = False
        self.pending = None  # an action of the HUD (scene switch) for the next frame
        self.overrides: dict = {}  # the window's overrides of the running scene (rebuilds)
        self.label = scene_name  # what the loading message names: the scene, its solver
        self._on_new_sim()

    # -- simulation lifecycle ----------------------------------------------------------
    def _build(self, name, overrides=None):
        if overrides and self.can_override:
            return self.make_sim(name, overrides)
        return self.make_sim(name)

    def _on_new_sim(self):
        """Sliders, mouse and view follow the (new) simulation's scene."""
        scene = self.sim.scene
        snap = self.sim.snapshot()
        self.snap, self.dirty = snap, False
        stiffness = float(scene_setting(scene, "fluid.stiffness", 1000.0))
        self.mouse = MouseDisturbance.for_domain(snap.domain_min, snap.domain_max, stiffness)
        g = scene_setting(scene, "physics.gravity", None)
        self.params = {
            "fluid.viscosity": float(scene_setting(scene, "fluid.viscosity", 0.05)),
            "fluid.stiffness": float(scene_setting(scene, "fluid.stiffness", 1000.0)),
            "gravity_y": float(g[1]) if g is not None else -9.81,
        }
        self.gravity = list(map(float, g)) if g is not None else [0.0, -9.81, 0.0][: snap.dim]
        self.slider_max = {
            "fluid.viscosity": max(1.0, 5.0 * self.params["fluid.viscosity"]),
            "fluid.stiffness": 4.0 * self.params["fluid.stiffness"],
        }
        self.refinement = bool(scene_setting(scene, "adaptivity.enabled", self.sim.levels > 1))
        self.solver = running_solver(scene)  # None: the stand-in, no solver to switch
        self.tolerance = scene_setting(scene, "dfsph.density_tolerance", None) if self.solver == "dfsph" else None
        # the keys this simulation tunes live (None: the stand-in, which takes them all)
        self.live = getattr(self.sim, "LIVE_KEYS", None)
        self.frame_dt = 1.0 / float(scene_setting(scene, "run.fps", 30.0))
        self.frame_sim = self.frame_dt  # simulated time the last frame advanced
        self.renderer.reset_view(scene, palette.Style.from_scene(scene))
        self.surface = bool(scene_setting(scene, "render.surface", False))
        self.rates, self.speed = Rates(), Speed()
        # The first frames show the particles and say the step is compiling; the next
        # frame's first advance compiles it (tens of seconds for a 3D scene on a CPU).
        self.fresh = LOADING_FRAMES
        self.pointer.reset()

    def switch_scene(self, name: str, overrides=None, label: str | None = None) -> bool:
        """Build ``name`` (optionally with overrides) and make it current; on failure
        keep the running scene and say why in the HUD. ``label``: what the loading
        message calls it (default: ``name``)."""
        label = label or name
        if not self._same_precision(name):
            return False
        if not self._show_loading(name, f"loading {label} (compiling the particles' setup ...)"):
            return False  # Esc: quitting
        try:
            sim = self._build(name, overrides)
        except Exception as e:  # a bad scene file must not close the window
            first = (str(e).splitlines() or [""])[0][:160]
            self.message = f"cannot load {label}: {type(e).__name__}: {first}"
            return False
        self.sim.set_disturbance(None)
        self.sim, self.scene_name, self.label = sim, name, label
        self.overrides = dict(overrides or {})
        self._on_new_sim()
        self.message = f"scene {name}" + (f" with {overrides}" if overrides else "")
        return True

    def takes(self, key: str) -> bool:
        """Whether the running simulation tunes ``key`` live (dfsph: no stiffness)."""
        return self.live is None or key in self.live

    def _rebuild(self, override: dict, label: str) -> bool:
        """Rebuild the running scene with ``override`` on top of the window's earlier
        overrides (a solver switch keeps the refinement toggle's choice, and the reverse),
        then carry the live-tuned values over where the new simulation takes them; one it
        does not take (dfsph has no stiffness) stays remembered for a switch back."""
        if not self.can_override:
            self.message = f"{', '.join(override)}: rebuilding needs make_sim(scene_name, overrides)"
            return False
        kept = dict(self.params)
        if not self.switch_scene(self.scene_name, {**self.overrides, **override}, label):
            return False
        for key in ("fluid.viscosity", "fluid.stiffness"):
            if self.takes(key):
                self._set_param(key, kept[key])
            else:
                self.params[key] = kept[key]
        if self.takes("physics.gravity"):
            self._set_gravity_y(kept["gravity_y"])
        return True

    def switch_solver(self) -> None:
        """The other pressure solver (``fluid.solver``) for the running scene, rebuilt with
        it; a scene that cannot take it (a SceneError, e.g. symmetric coupling with dfsph)
        keeps running and the HUD says why, in one line."""
        if not self.solver:
            self.message = "this simulation has no pressure solver to switch"
            return
        want = next_solver(self.solver)
        why = why_not(self.sim.scene, want)
        if why:
            self.message = why
            return
        if self._rebuild({"fluid.solver": want}, f"{self.scene_name} with {want}"):
            self.message = f"solver {want}"

    def _same_precision(self, name: str) -> bool:
        """A scene with another float precision would re-initialise Taichi, which
        destroys this window's fields: refuse it with the reason instead."""
        try:
            from mrsph.scene.config import load_scene

            want = scene_setting(load_scene(name), "particles.precision", None)
        except Exception:
            return True  # let make_sim report the problem
        have = scene_setting(self.sim.scene, "particles.precision", None)
        if want is not None and have is not None and want != have:
            self.message = f"{name} needs precision {want} (running {have}): start the window with that scene instead"
            return False
        return True

    def set_refinement(self, enabled: bool) -> None:
        """Refinement on / off: live where the simulation lists ``adaptivity.enabled`` in
        its ``LIVE_KEYS``, else by rebuilding the scene with the override (the solver's
        levels are fixed when it is built)."""
        if "adaptivity.enabled" in getattr(self.sim, "LIVE_KEYS", ()):
            self._set_param("adaptivity.enabled", bool(enabled))
            self.refinement = bool(enabled)
            return
        if self._rebuild(
            {"adaptivity.enabled": bool(enabled)}, f"{self.scene_name} with refinement {'on' if enabled else 'off'}"
        ):
            self.refinement = bool(enabled)

    def _set_param(self, key, value) -> None:
        try:
            self.sim.set_param(key, value)
            self.params[key] = value
        except Exception as e:
            self.message = f"{key}: {str(e).splitlines()[0][:160]}"
            return
        if key == "fluid.stiffness":  # the sound speed, and so the mouse's cap, follow it
            self.mouse.max_speed = safe_speed(float(value), self.snap.domain_min, self.snap.domain_max)

    def _set_gravity_y(self, gy: float) -> None:
        g = list(self.gravity)
        g[1] = float(gy)
        try:
            self.sim.set_param("physics.gravity", tuple(g))
            self.gravity, self.params["gravity_y"] = g, float(gy)
        except Exception as e:
            self.message = f"physics.gravity: {str(e).splitlines()[0][:160]}"

    # -- per frame ---------------------------------------------------------------------
    def run(self) -> None:
        while self.window.running:
            now = time.perf_counter()
            dt_wall = max(now - self.last, 1e-4)
            self.last = now
            self.fps = 1.0 / dt_wall if self.fps == 0 else 0.9 * self.fps + 0.1 / dt_wall
            if not self._keys():
                break
            if self.pending is not None:  # before anything of this frame is drawn
                action, self.pending = self.pending, None
                action()
                if not self.window.running:
                    break
            # fit the domain into the area left of the HUD panel, so nothing hides (3D:
            # when the camera is framed, at the start or on f); before any camera use
            w, _ = self.renderer.size
            free = self._hud_rect_px()[0] / w if self.show_hud else 1.0
            self.renderer.viewport = (0.0, 0.0, max(free, 0.3), 1.0)
            self._held_keys(min(dt_wall, 0.1))  # no camera jump after a slow frame
            # The drag velocity is the hand's, in metres per wall second, capped to the
            # safe speed (mrsph.app.mouse): per simulated second, a swipe in slow motion
            # became a blow as many times faster as the slow-down.
            d = self._mouse(dt_wall)
            self.sim.set_disturbance(d)
            if self.paused or self.step_once:
                self.speed.clear()
            self._advance()
            if self.dirty:
                self.snap = self.sim.snapshot()
                self.dirty = False
            snap = self.snap
            st = snap.stats or {}
            self.rates.add(float(snap.time), float(st.get("splits", 0)), float(st.get("merges", 0)))
            self.renderer.draw(
                snap,
                self.color_mode,
                self.show_virtual,
                rest_density=getattr(self.sim, "rest_density", None),
                marks=self._marks(snap),
                surface=self.surface,
            )
            draw_hud(self, snap)
            loading_panel(self.window, self.renderer.size, self.loading)
            self._write_stats(snap, d)
            if self.loading:
                self._loading_shot(self.scene_name)
            self.frames_drawn += 1
            if self.want_screenshot or (self.screenshot_path and self.frames_drawn == AUTO_SCREENSHOT_FRAME):
                # Between drawing and show(): the image buffer holds this frame.
                self._screenshot()
                self.want_screenshot = False
            self.window.show()
        if self.stats_file:
            self.stats_file.close()
        self.window.destroy()
        self.ini.cleanup()

    def _advance(self) -> None:
        """This frame's simulation: none on a scene's first LOADING_FRAMES frames (they
        say the step is compiling; the next frame's advance compiles it), or while
        paused."""
        compiling = self.fresh > 0 and not self.paused
        if compiling:
            self.loading = f"loading {self.label} (compiling the step ...)"
        elif self.loading and not self.fresh:
            self.loading = None
        if (not self.paused or self.step_once) and not compiling:
            t0 = float(self.sim.time)
            try:
                # a frame cut to the budget keeps the window responsive where the
                # machine is too slow for the scene (slow motion); a single step
                # (n) is a whole frame
                self.sim.advance_frame(None if self.step_once else self.frame_budget)
            except Exception as e:  # blow-up: stop and say so, keep the window
                self.paused = True
                line = (str(e).splitlines() or [type(e).__name__])[0]
                print(f"error: {line}", file=sys.stderr, flush=True)  # as headless runs say it
                self.message = f"simulation stopped: {line[:240]} (r: reset)"
            advanced = float(self.sim.time) - t0
            if advanced > 0.0:
                self.frame_sim = advanced
            if not (self.paused or self.step_once):
                self.speed.add(time.perf_counter(), float(self.sim.time))
            self.step_once = False
            self.dirty = True
        if compiling:
            self.fresh -= 1  # then a frame advances (and compiles)
        elif self.fresh and self.paused:
            self.fresh = 0

    def _keys(self) -> bool:
        """Pressed-key events; False when the app should quit."""
        ui = self.ti.ui
        actions = {
            "n": self._step_once,
            "r": self._reset,
            ui.TAB: self._next_scene,
            "c": lambda: setattr(self, "color_mode", palette.next_mode(self.color_mode)),
            "q": lambda: self.mouse.scroll(-RADIUS_KEY_NOTCHES),
            "e": lambda: self.mouse.scroll(RADIUS_KEY_NOTCHES),
            "f": self.renderer.reset_view,
            "s": lambda: self.later(self.switch_solver),  # draws loading frames of its own
            "p": lambda: setattr(self, "want_screenshot", True),
        }  # after this frame is drawn
        for e in self.window.get_events(ui.PRESS):
            k = e.key
            if k == ui.ESCAPE:
                self.window.running = False
                return False
            if k in TOGGLE_KEYS:
                setattr(self, TOGGLE_KEYS[k], not getattr(self, TOGGLE_KEYS[k]))
            elif k in CAMERA_KEYS or k in (ui.LEFT, ui.RIGHT, ui.UP, ui.DOWN):
                self.taps.add(k)  # latched: acts this frame even if already released
            elif k in actions:
                actions[k]()
        return True

    def _step_once(self) -> None:
        self.paused, self.step_once = True, True

    def _held_keys(self, dt: float) -> None:
        """Camera keys act while held (3D only); a key pressed since the last frame acts
        for at least TAP_S, so a tap zooms the same whether or not this frame still sees
        it down."""
        taps, self.taps = self.taps, set()
        if self.snap is None or self.snap.dim != 3:
            return
        w, ui = self.window, self.ti.ui
        held = [
            max(dt if w.is_pressed(k) else 0.0, TAP_S if k in taps else 0.0)
            for k in (ui.LEFT, ui.RIGHT, ui.UP, ui.DOWN, "z", "x")
        ]
        self.renderer.ensure_camera(self.snap).keys(*held)

    def _reset(self) -> None:
        try:
            self.sim.reset()
            self.message = "reset"
        except Exception as e:
            self.message = f"reset failed: {str(e).splitlines()[0][:160]}"
        self.mouse.reset()
        self.dirty = True

    def later(self, action) -> None:
        """Run ``action`` at the start of the next frame: a HUD button is read in the
        middle of a frame, and a scene switch draws loading frames of its own."""
        self.pending = action

    def _show_loading(self, name: str, text: str) -> bool:
        """Draw one frame that says ``text``; False when Esc was pressed (quitting)."""
        self.loading = text
        if show_loading_frame(self.window, self.renderer, text, self.ti.ui.ESCAPE, lambda: self._loading_shot(name)):
            return True
        self.window.running = False
        return False

    def _marks(self, snap) -> list:
        """What acts on the water, to draw (mrsph.app.marks)."""
        u, v = self.window.get_cursor_pos()
        hovering = self.pointer.owner is None and not self._over_hud(u, v)
        return frame_marks(self.sim.scene, snap, self.mouse, (u, v), self.renderer, hovering)

    def _next_scene(self) -> None:
        if self.scene_name in self.scene_names:
            i = (self.scene_names.index(self.scene_name) + 1) % len(self.scene_names)
        else:
            i = 0
        self.switch_scene(self.scene_names[i])

    # -- mouse -------------------------------------------------------------------------
    def _hud_rect_px(self):
        return hud_rect_px(self.renderer.size)

    def _over_hud(self, u: float, v: float) -> bool:
        """Whether the cursor (canvas coords, y up) is over a HUD panel, where clicks
        belong to ImGui and must not stir the fluid."""
        from .render import legend_rect

        w, h = self.renderer.size
        x, y = u * w, (1.0 - v) * h  # ImGui: y down from the top
        x0, y0, x1, y1 = self._hud_rect_px()
        if self.show_hud and x0 <= x <= x1 and y0 <= y <= y1:
            return True
        lx, ly, lw, lh = legend_rect(self.snap, self.color_mode, (w, h))
        return lx * w <= x <= (lx + lw) * w and ly * h <= y <= (ly + lh) * h

    def _mouse(self, dt: float):
        """Cursor and buttons -> camera motion (3D) or a disturbance (mrsph.app.pointer)."""
        ti, w = self.ti, self.window
        u, v = w.get_cursor_pos()
        return self.pointer.update(
            (u, v),
            w.is_pressed(ti.ui.LMB),
            w.is_pressed(ti.ui.RMB),
            w.is_pressed(ti.ui.MMB),
            w.is_pressed(ti.ui.SHIFT),
            self.snap,
            self.renderer,
            self.mouse,
            self._over_hud(u, v),
            dt,
        )

    # -- hooks -------------------------------------------------------------------------
    def _write_stats(self, snap, d) -> None:
        if self.stats_file:
            self.stats_file.write(json.dumps(stats_row(self, snap, d)) + "\n")
            self.stats_file.flush()

    def _loading_shot(self, scene: str) -> None:
        """Test hook: every loading frame's screenshot beside MRSPH_WINDOW_SCREENSHOT's
        (``scene``: the scene it loads)."""
        path = loading_shot_path(self.screenshot_path, scene, self.loading_shots)
        if path is not None:
            write_screenshot(self.window, str(path))
            self.loading_shots += 1

    def _screenshot(self) -> None:
        self.message = write_screenshot(self.window, self.screenshot_path)


def run_window(
    make_sim,
    scene_name: str,
    scene_names: list[str],
    width: int = 1280,
    height: int = 720,
    frame_budget: float | None = None,
) -> None:
    """Open the interactive window on ``scene_name`` and run until closed (Esc).

    ``make_sim(scene_name)`` builds a Simulation (and so initialises Taichi). If it also
    accepts overrides, ``make_sim(scene_name, overrides: dict)``, the refinement
    checkbox and the solver switch can rebuild the scene with
    ``{"adaptivity.enabled": bool, "fluid.solver": name}``.
    ``scene_names`` are the scenes offered by Tab and the help panel's buttons.
    ``frame_budget``: wall seconds of simulation per drawn frame (None: whole frames).
    """
    ok, why = display_available()
    if not ok:
        raise RuntimeError(f"cannot open a window: {why}")
    app = _App(make_sim, scene_name, scene_names, width, height, frame_budget)
    app.run()
