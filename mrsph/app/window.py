"""The interactive window: watch the fluid, stir it with the mouse, tune it live.

One window frame = one ``sim.advance_frame(frame_budget, seconds)`` (unless paused): the
wall time the last frame took (at most ``REAL_TIME_CAP_S``), so that the water keeps the
wall clock's pace when drawing is slow and the simulation fast, or as much of it as fits
in the wall-clock budget (slow motion on a machine too slow for the scene, with the
window still responsive), then one snapshot,
drawn by the shared :class:`~mrsph.app.render.Renderer`, plus a HUD of GGUI widgets.
The physics never sees the window: the window only calls the Simulation API
(``advance_frame``, ``snapshot``, ``set_param``, ``set_disturbance``, ``reset``), on a
simulation that runs in a process of its own where it can (:mod:`mrsph.app.host`).

The keys and the mouse: :mod:`mrsph.app.keys` (the README's table, the help panel and
``python3 main.py keys`` come from it). The mouse acts in wall-clock time, capped
(``mrsph.app.mouse.safe_speed``). Key taps are latched: a press seen between two frames
acts once even when the key is up again when the next frame reads the keys (z / x /
arrows at a few frames per second).

A scene switch (Tab, the help panel's buttons, ``s``, the refinement checkbox) opens the
new simulation while the window goes on drawing the running one, paused and dimmed,
under a panel that says what the new one is doing (mrsph.app.switch, mrsph.app.loading);
Esc quits at once. The refinement checkbox and the solver switch rebuild the running
scene with an override (``adaptivity.enabled``, ``fluid.solver``), each on top of the
other, and carry the live-tuned sliders over; a scene that cannot take the next solver
says why in the HUD.

Test hooks: ``MRSPH_WINDOW_STATS`` and ``MRSPH_WINDOW_SCREENSHOT`` (mrsph.app.hooks).
"""

from __future__ import annotations

import inspect
import json
import os
import sys
import time

from . import palette
from .ahead import count as ahead_count
from .hooks import AUTO_SCREENSHOT_FRAME, SCREENSHOT_ENV, STATS_ENV, loading_shot_path, stats_row, write_screenshot
from .host import Sims
from .hud import HUD_MARGIN_PX, Message, Rates, Speed, draw_hud, hud_rect_px
from .loading import loading_lines, loading_panel
from .marks import frame_marks
from .mouse import MouseDisturbance, safe_speed
from .pointer import Pointer
from .probe import display_available
from .switch import Switching, first_line, running_solver
from .view import scene_setting

#: Keys that change the mouse radius: one press = this many wheel notches.
RADIUS_KEY_NOTCHES = 1.0
#: A tapped camera key (seen pressed and released between two frames) acts as if held
#: this long: one tap of z zooms by e^(-view.ZOOM_KEY_RATE * TAP_S), 17 %.
TAP_S = 0.15
#: Keys whose action lasts while they are held (3D camera, with the arrows): taps of them
#: are latched.
CAMERA_KEYS = ("z", "x")
#: Keys that flip a flag of the window: the attribute flipped.
TOGGLE_KEYS = {" ": "paused", "h": "show_help", "u": "show_hud", "v": "show_virtual", "w": "surface", "t": "tint"}
#: The scene a switch leaves, drawn at this brightness while the next one opens.
DIM_WHILE_OPENING = 0.45
#: Shortest frame, seconds: while nothing advances (a scene opening, paused) the window
#: draws at 30 frames a second, and never faster than 120 (without vsync, as under Xvfb,
#: it spun through hundreds a second and took a core from the simulation it waited for).
IDLE_FRAME_S = 1.0 / 30.0
MIN_FRAME_S = 1.0 / 120.0
#: The most simulated time one frame advances: a frame after a stall (a scene opening, a
#: slow snapshot) does not jump the water by the stall's length.
REAL_TIME_CAP_S = 0.1


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


class _App(Switching):
    """State of the running window; :func:`run_window` is its only user."""

    def __init__(self, make_sim, scene_name, scene_names, width, height, frame_budget=None, opened=None):
        import taichi as ti

        from mrsph import runtime

        from .render import ImguiIniGuard, Renderer

        self.ti = ti
        self.ini = ImguiIniGuard()
        self.can_override = _accepts_overrides(make_sim)
        self.scene_names = list(scene_names) or [scene_name]
        self.scene_name = self.label = scene_name
        self.overrides: dict = {}  # the window's overrides of the running scene (rebuilds)
        self.base_of: dict = {}  # per scene, its own values of the keys the window overrides
        self.message = Message()
        self.sim = self.opening = None
        self.pointer = Pointer()  # who owns a drag (fluid, camera, HUD)
        self.mouse = None
        self.sims = Sims(make_sim, self.can_override)
        self.ahead_n, self.opened_at = ahead_count(), time.perf_counter()
        self.ahead_for = self.s_key = None  # what the builds ahead are for; what s opens
        self.open_scene(scene_name)
        ok, why = display_available()  # a test window in a subprocess, while the scene builds
        if not ok:
            self.opening.handle.close()
            self.sims.close()
            raise NoDisplay(why)
        if opened is not None:
            opened()
        if not self.sims.separate:
            # the simulation first: it initialises Taichi as it needs, and the window
            # then runs in that program (the stand-in leaves it to the window)
            while self.opening.handle.poll() == "busy":
                pass
            self.poll_opening()
        if ti.lang.impl.get_runtime().prog is None:
            runtime.ensure("cpu")  # the window's own Taichi: the simulations run elsewhere
        # no scene name in the title: GGUI 1.7.4 cannot change it when the scene changes
        # (the panel's first line names the scene)
        self.window = ti.ui.Window("mrsph - adaptive SPH", (int(width), int(height)), vsync=True)
        self.renderer = Renderer(self.window)
        self.renderer.legend_shown = self.renderer.legend_rows_for_all = True  # one size in every mode
        self.paused = self.step_once = self.show_virtual = self.show_help = False
        self.surface = self.tint = False
        self.show_hud = True
        self.color_mode = "level"
        self.snap, self.dirty = None, True
        self.rates, self.speed, self.solver_seen = Rates(), Speed(), set()
        self.fps = 0.0
        self.frame_budget = frame_budget
        self.start = self.last = time.perf_counter()
        self.frame_wall = 0.0  # wall seconds between the last two frames
        self.stats_file = None
        path = os.environ.get(STATS_ENV)
        if path:
            self.stats_file = open(path, "a", encoding="utf-8")
        self.screenshot_path = os.environ.get(SCREENSHOT_ENV)
        self.frames_drawn = 0
        self.frames_run = 0  # frames drawn of a running scene
        self.loading_shots = 0  # loading frames saved by the test hook
        self.want_screenshot = False
        self.taps: set = set()  # camera keys pressed since the last frame
        self.shift = False  # Shift held, as the key events tell
        self.loading = None  # the loading panel's lines while a scene opens
        self.pending: list = []  # actions of the HUD for the start of the next frame
        if self.sim is not None:
            self._on_new_sim()

    # -- simulation lifecycle ----------------------------------------------------------
    def _on_new_sim(self):
        """Sliders, mouse and view follow the (new) simulation's scene."""
        if not hasattr(self, "renderer"):
            return  # before the window: its first frame calls this again
        scene = self.sim.scene
        snap = self.sim.snapshot()
        self.snap, self.dirty = snap, False
        stiffness = float(scene_setting(scene, "fluid.stiffness"))
        self.mouse = MouseDisturbance.for_domain(snap.domain_min, snap.domain_max, stiffness)
        g = scene_setting(scene, "physics.gravity")
        self.params = {
            "fluid.viscosity": float(scene_setting(scene, "fluid.viscosity")),
            "fluid.stiffness": float(scene_setting(scene, "fluid.stiffness")),
            "pbf.xsph": float(scene_setting(scene, "pbf.xsph")),
            "gravity_y": float(g[1]),
        }
        self.gravity = list(map(float, g))
        self.slider_max = {
            "fluid.viscosity": max(1.0, 5.0 * self.params["fluid.viscosity"]),
            "fluid.stiffness": 4.0 * self.params["fluid.stiffness"],
            "pbf.xsph": 1.0,  # the key's range
        }
        self.refinement = bool(scene_setting(scene, "adaptivity.enabled", self.sim.levels > 1))
        self.solver = running_solver(scene)  # None: the stand-in, no solver to switch
        self.tolerance = scene_setting(scene, "dfsph.density_tolerance", None) if self.solver == "dfsph" else None
        # the keys this simulation tunes live (None: the stand-in, which takes them all)
        self.live = getattr(self.sim, "LIVE_KEYS", None)
        self.frame_dt = 1.0 / float(scene_setting(scene, "run.fps"))
        self.frame_sim = self.frame_dt  # simulated time the last frame advanced
        self.renderer.reset_view(scene, palette.Style.from_scene(scene))
        self.surface = bool(scene_setting(scene, "render.surface"))
        self.rates, self.speed, self.solver_seen = Rates(), Speed(), set()
        self.pointer.reset()

    def takes(self, key: str) -> bool:
        """Whether the running simulation tunes ``key`` live (dfsph: no stiffness)."""
        return self.live is None or key in self.live

    def note(self, text: str, sticky: bool = False) -> None:
        """A message for the HUD: what an action did (it goes after a while), or what
        went wrong (``sticky``: it stays until the next one)."""
        self.message.set(text, sticky)

    def _set_param(self, key, value) -> None:
        try:
            self.sim.set_param(key, value)
            self.params[key] = value
        except Exception as e:
            self.note(f"{key}: {first_line(e)}", sticky=True)
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
            self.note(f"physics.gravity: {first_line(e)}", sticky=True)

    # -- what the HUD's buttons do ------------------------------------------------------
    def toggle_pause(self) -> None:
        self.paused = not self.paused

    def step_frame(self) -> None:
        self.paused, self.step_once = True, True

    def toggle_help(self) -> None:
        self.show_help = not self.show_help

    def next_colour(self) -> None:
        self.color_mode = palette.next_mode(self.color_mode)

    def later(self, action) -> None:
        """Run ``action`` at the start of the next frame (a HUD button is read in the
        middle of a frame, and what it opens takes over from the next)."""
        self.pending.append(action)

    # -- per frame ---------------------------------------------------------------------
    def run(self) -> None:
        try:
            while self.window.running:
                if not self._frame():
                    break
        finally:
            if self.stats_file:
                self.stats_file.close()
            if self.opening is not None:
                self.opening.handle.close()
            self.sims.put_back(self.sim)
            self.window.destroy()
            from mrsph import runtime

            runtime.finish()  # the window's kernels into Taichi's cache, before its workers'
            self.sims.close()  # each ends its program, which writes Taichi's kernel cache
            self.ini.cleanup()

    def _frame(self) -> bool:
        """One frame of the window; False when it should close."""
        now = time.perf_counter()
        dt_wall = max(now - self.last, 1e-4)
        self.last = now
        self.frame_wall = dt_wall
        self.fps = 1.0 / dt_wall if self.fps == 0 else 0.9 * self.fps + 0.1 / dt_wall
        if not self._keys():
            return False
        actions, self.pending = self.pending, []
        for action in actions:  # before anything of this frame is drawn
            action()
        had = self.sim
        self.poll_opening()
        if self.sim is not had and had is None:
            self._on_new_sim()  # the first scene: the window's state follows it
        self.build_ahead()
        self.loading = loading_lines(self.opening, self.sims.separate)[0] if self.opening else None
        # fit the domain into the area left of the HUD panel, so nothing hides (3D:
        # when the camera is framed, at the start or on f); before any camera use
        w, h = self.renderer.size
        self.renderer.viewport = (0.0, 0.0, max(self.view_area()[2] / w, 0.3), 1.0)
        snap = None
        d = None
        if self.sim is not None:
            self._held_keys(min(dt_wall, 0.1))  # no camera jump after a slow frame
            # The drag velocity is the hand's, in metres per wall second, capped to the
            # safe speed (mrsph.app.mouse): per simulated second, a swipe in slow motion
            # became a blow as many times faster as the slow-down.
            d = self._mouse(dt_wall) if self.opening is None else None
            self.sim.set_disturbance(d)
            if self.paused or self.step_once or self.opening is not None:
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
                marks=self._marks(snap) if self.opening is None else (),
                surface=self.surface,
                tint=self.tint,
                dim=DIM_WHILE_OPENING if self.opening is not None else 1.0,
            )
        else:
            self.renderer.clear()
        draw_hud(self, snap)
        if self.opening is not None:
            lines, sized = loading_lines(self.opening, self.sims.separate)
            loading_panel(self.window, self.view_area(), lines, sized)
        self._write_stats(snap, d)
        if self.loading:
            self._loading_shot(self.opening.name)
        self.frames_drawn += 1
        if self.sim is not None and self.opening is None:
            self.frames_run += 1
        if self.want_screenshot or (self.screenshot_path and self.frames_run == AUTO_SCREENSHOT_FRAME):
            # Between drawing and show(): the image buffer holds this frame.
            self.note(write_screenshot(self.window, self.screenshot_path))
            self.want_screenshot = False
        self.window.show()
        idle = self.sim is None or self.opening is not None or (self.paused and not self.step_once)
        rest = (IDLE_FRAME_S if idle else MIN_FRAME_S) - (time.perf_counter() - now)
        if rest > 0:
            time.sleep(rest)
        return True

    def view_area(self) -> tuple[int, int, int, int]:
        """Pixels (x0, y0, x1, y1; y down) the scene is drawn in: left of the HUD."""
        w, h = self.renderer.size
        right = hud_rect_px((w, h))[0] - HUD_MARGIN_PX if self.show_hud else w
        return 0, 0, right, h

    def _advance(self) -> None:
        """This frame's simulation: none while paused or while the next scene opens."""
        if self.opening is not None or (self.paused and not self.step_once):
            return
        t0 = float(self.sim.time)
        try:
            # the wall time since the last frame, so that the water keeps the clock's pace;
            # a frame cut to the budget keeps the window responsive where the machine is
            # too slow for the scene (slow motion); a single step (n) is a whole frame
            if self.step_once:
                self.sim.advance_frame(None)
            else:
                self.sim.advance_frame(self.frame_budget, min(self.frame_wall, REAL_TIME_CAP_S))
        except Exception as e:  # blow-up: stop and say so, keep the window
            self.paused = True
            line = first_line(e, 10_000)
            print(f"error: {line}", file=sys.stderr, flush=True)  # as headless runs say it
            again = "r: reset" if self.sim.alive() else "r: open it again"
            self.note(f"simulation stopped: {line[:240]} ({again})", sticky=True)
        advanced = float(self.sim.time) - t0
        if advanced > 0.0:
            self.frame_sim = advanced
        if not (self.paused or self.step_once):
            self.speed.add(time.perf_counter(), float(self.sim.time))
        self.step_once = False
        self.dirty = True

    def _keys(self) -> bool:
        """Pressed-key events; False when the app should quit."""
        ui = self.ti.ui
        actions = {
            "n": self.step_frame,
            "r": self.reset_sim,
            ui.TAB: lambda: self.step_scene(-1 if self.shift else 1),
            "c": self.next_colour,
            "q": lambda: self.mouse and self.mouse.scroll(-RADIUS_KEY_NOTCHES),
            "e": lambda: self.mouse and self.mouse.scroll(RADIUS_KEY_NOTCHES),
            "f": self.renderer.reset_view,
            "s": self.switch_solver,
            "p": lambda: setattr(self, "want_screenshot", True),  # after this frame is drawn
        }
        presses = [e.key for e in self.window.get_events(ui.PRESS)]
        released = {e.key for e in self.window.get_events(ui.RELEASE)}
        for k in presses:
            if k == ui.SHIFT:  # a quick shift+Tab is over by the time the frame reads it:
                self.shift = True  # Shift is held for the presses after its own
                continue
            if k == ui.ESCAPE:
                self.window.running = False
                return False
            if self.sim is None and k != ui.ESCAPE:
                continue  # nothing to act on before the first scene runs
            if k in TOGGLE_KEYS:
                setattr(self, TOGGLE_KEYS[k], not getattr(self, TOGGLE_KEYS[k]))
            elif k in CAMERA_KEYS or k in (ui.LEFT, ui.RIGHT, ui.UP, ui.DOWN):
                self.taps.add(k)  # latched: acts this frame even if already released
            elif k in actions:
                actions[k]()
        if ui.SHIFT in released:
            self.shift = False
        return True

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

    def _marks(self, snap) -> list:
        """What acts on the water, to draw (mrsph.app.marks)."""
        u, v = self.window.get_cursor_pos()
        hovering = self.pointer.owner is None and not self._over_hud(u, v)
        return frame_marks(self.sim.scene, snap, self.mouse, (u, v), self.renderer, hovering)

    # -- mouse -------------------------------------------------------------------------
    def _over_hud(self, u: float, v: float) -> bool:
        """Whether the cursor (canvas coords, y up) is over a panel (the HUD's column,
        the legend, the help), where clicks belong to ImGui and must not stir the fluid."""
        w, h = self.renderer.size
        x, y = u * w, (1.0 - v) * h  # ImGui: y down from the top
        x0, y0, x1, y1 = hud_rect_px((w, h))
        if self.show_hud and x0 <= x <= x1 and y0 <= y <= y1:
            return True
        if self.show_help:
            return True  # the help panel covers the view's middle
        lx, ly, lw, lh = self.renderer.legend_box_px(self.snap)
        return lx <= x <= lx + lw and ly <= y <= ly + lh

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
        (``scene``: the scene it opens)."""
        path = loading_shot_path(self.screenshot_path, scene, self.loading_shots)
        if path is not None:
            write_screenshot(self.window, str(path))
            self.loading_shots += 1


class NoDisplay(RuntimeError):
    """No window can open here; the text says why (mrsph.app.probe)."""


def run_window(
    make_sim,
    scene_name: str,
    scene_names: list[str],
    width: int = 1280,
    height: int = 720,
    frame_budget: float | None = None,
    opened=None,
) -> None:
    """Open the interactive window on ``scene_name`` and run until closed (Esc).

    ``make_sim(scene_name)`` builds a Simulation (in a process of its own where one can
    be forked: mrsph.app.host). If it also accepts overrides, ``make_sim(scene_name,
    overrides: dict)``, the refinement checkbox and the solver switch can rebuild the
    scene with ``{"adaptivity.enabled": bool, "fluid.solver": name}``.
    ``scene_names`` are the scenes offered by Tab and the help panel's buttons.
    ``frame_budget``: wall seconds of simulation per drawn frame (None: whole frames).
    A first scene that cannot be built raises its error (the window closes).
    The display is tried (a test window in a subprocess) while the first scene builds:
    where no window can open, :class:`NoDisplay` says why; where one can, ``opened()``
    is called before it opens.
    """
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise NoDisplay(display_available()[1])  # at once: no display is named
    app = _App(make_sim, scene_name, scene_names, width, height, frame_budget, opened)
    app.run()
