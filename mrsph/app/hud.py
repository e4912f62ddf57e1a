"""The window's panels: the HUD on the right (stats, buttons, sliders) and the help,
plus the rate counters it shows. GGUI/ImGui calls only; the state is the window's."""

from __future__ import annotations

import collections
import math
import textwrap

from . import palette
from .switch import next_solver

#: HUD panel on the right: width in pixels (fits the slider labels of ImGui's default
#: 13 px font) and height in pixels (cut to the window, less the margins).
HUD_WIDTH_PX = 330
HUD_TEXT_CHARS = 40  # characters a line of the panel holds (ImGui's 7 px wide glyphs)
HUD_HEIGHT_PX = 600
HUD_MARGIN_PX = 8
#: The colour of the HUD's message lines (what an action did, or why it could not).
MESSAGE_COLOUR = (1.0, 0.75, 0.3)
#: Window over which splits/s and merges/s are counted (simulated seconds).
RATE_WINDOW_S = 1.0
_HELP = """\
space     pause / run          n   step one frame
r         reset                tab next scene (list below)
c         colour mode          v   show virtual particles
s         pressure solver: wcsph <-> dfsph (rebuilds)
h         this help            p   screenshot (out/screenshots)
left drag push the fluid       right drag / shift+left: pull
q / e     mouse radius - / +   u   hide / show the HUD
w         water view (surface)
Esc       quit
3D: right drag or arrows orbit, middle drag pan,
    z / x zoom in / out, f frame the domain"""


def hud_rect_px(size) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of the HUD panel in pixels, y down from the top."""
    w, h = size
    x0 = w - HUD_WIDTH_PX - HUD_MARGIN_PX
    return x0, HUD_MARGIN_PX, w - HUD_MARGIN_PX, min(HUD_MARGIN_PX + HUD_HEIGHT_PX, h - HUD_MARGIN_PX)


class Rates:
    """Splits and merges per simulated second. The stats row counts events since the
    previous snapshot, so the rate is the sum over the last RATE_WINDOW_S divided by
    the time covered."""

    def __init__(self):
        self.samples = collections.deque()

    def add(self, t: float, splits: float, merges: float) -> None:
        if self.samples and t < self.samples[-1][0]:
            self.samples.clear()  # reset or new scene: time went back
        if self.samples and t == self.samples[-1][0]:
            return  # paused: the same frame again
        self.samples.append((t, splits, merges))
        while self.samples and self.samples[0][0] < t - RATE_WINDOW_S:
            self.samples.popleft()

    def rates(self) -> tuple[float, float]:
        if len(self.samples) < 2:
            return 0.0, 0.0
        span = self.samples[-1][0] - self.samples[0][0]
        if span <= 0:
            return 0.0, 0.0
        s = sum(x[1] for x in list(self.samples)[1:])
        m = sum(x[2] for x in list(self.samples)[1:])
        return s / span, m / span


class Speed:
    """Simulated seconds per wall second over the frames of the last RATE_WINDOW_S of
    wall time while the simulation runs (cleared on pause, single steps and resets)."""

    def __init__(self):
        self.samples = collections.deque()

    def add(self, wall: float, sim_time: float) -> None:
        if self.samples and sim_time < self.samples[-1][1]:
            self.samples.clear()  # reset or new scene: time went back
        self.samples.append((wall, sim_time))
        while len(self.samples) > 2 and self.samples[0][0] < wall - RATE_WINDOW_S:
            self.samples.popleft()

    def clear(self) -> None:
        self.samples.clear()

    def value(self) -> float | None:
        if len(self.samples) < 2:
            return None
        (w0, t0), (w1, t1) = self.samples[0], self.samples[-1]
        return (t1 - t0) / (w1 - w0) if w1 > w0 else None


def solver_lines(st: dict, solver: str | None, tolerance: float | None = None) -> list[str]:
    """The HUD's lines on the pressure solver, from a stats row ``st`` of
    ``Simulation.stats()`` (``solver``, ``density_iterations``, ``divergence_iterations``,
    ``density_error``, ``unconverged``); ``solver``: the running scene's, for a row
    without it; ``tolerance``: ``dfsph.density_tolerance``, shown beside the error. The
    iterations are the mean velocity updates a step since the last row, the error the
    average density error (DFSPH: its last density solve's; WCSPH: the mean compression).
    No lines for a simulation without a pressure solver (the app's stand-in)."""
    name = st.get("solver") or solver
    if not name:
        return []
    lines = [f"solver {name}   (s: switch to {next_solver(name)})"]
    err = st.get("density_error")
    if name == "dfsph":
        lines.append(
            f"iterations/step: density {float(st.get('density_iterations') or 0.0):.1f}, "
            f"div {float(st.get('divergence_iterations') or 0.0):.1f}"
        )
        tol = f" (tol {100.0 * tolerance:.3g} %)" if tolerance else ""
        lines.append(f"density error {100.0 * float(err or 0.0):.3g} %{tol}")
        if st.get("unconverged"):
            lines.append(f"{int(st['unconverged'])} solves stopped at max iterations")
    elif err is not None:
        lines.append(f"mean compression {100.0 * float(err):.3g} %")
    return lines


def draw_hud(self, snap) -> None:
    """The HUD panel (right) and the help panel of the window ``self`` (an ``_App``)."""
    gui = self.window.get_gui()
    w, h = self.renderer.size
    x0, y0, x1, y1 = hud_rect_px(self.renderer.size)
    st = snap.stats or {}
    if self.show_help:
        rows = len(_HELP.splitlines()) + 2 + len(self.scene_names)
        with gui.sub_window("Help", 0.2, 0.15, min(440 / w, 0.9), min((40 + 23 * rows) / h, 0.9)):
            for line in _HELP.splitlines():
                gui.text(line)
            gui.text("scenes:")
            for name in self.scene_names:
                if name != self.scene_name and gui.button(name):
                    self.later(lambda name=name: self.switch_scene(name))
    if not self.show_hud:
        return
    with gui.sub_window("mrsph", x0 / w, y0 / h, (x1 - x0) / w, (y1 - y0) / h):
        gui.text(f"scene {self.scene_name} ({snap.dim}D)")
        gui.text("h: help   u: hide this panel")
        gui.text(f"{self.fps:5.1f} fps   frame {snap.frame}" + ("   PAUSED" if self.paused else ""))
        gui.text(f"t = {float(snap.time):.3f} s   dt = {float(st.get('dt', 0.0)):.2e} s")
        speed = self.speed.value()
        if speed is None:
            gui.text("speed: paused" if self.paused else "speed: measuring")
        else:
            slow = "   (slow motion)" if self.frame_sim < 0.999 * self.frame_dt else ""
            gui.text(f"speed {speed:.3g}x real time{slow}")
        for line in solver_lines(st, self.solver, self.tolerance):
            gui.text(line)
        # the last message under the figures, where it is seen at any window height (at
        # the panel's foot it fell below the fold of a 600-pixel window)
        for line in textwrap.wrap(self.message, HUD_TEXT_CHARS):
            gui.text(line, color=MESSAGE_COLOUR)
        gui.text(
            f"real {st.get('n_real', '?')}   virtual {st.get('n_virtual', '?')}"
            f"   transient {st.get('n_transient', '?')}"
        )
        for lvl in range(int(snap.levels)):
            gui.text(
                f"  level {lvl}: {st.get(f'n_level_{lvl}', '?')} real, {st.get(f'n_virtual_level_{lvl}', '?')} virtual",
                color=tuple(float(c) for c in palette.level_colour(lvl)),
            )
        splits, merges = self.rates.rates()
        gui.text(f"splits {splits:.0f}/s   merges {merges:.0f}/s")
        unit = "kg" if snap.dim == 3 else "kg/m"
        gui.text(
            f"mass {float(st.get('total_mass', 0.0)):.4g} {unit}   "
            f"max rho/rho0 {float(st.get('max_density_ratio', 0.0)):.3f}"
        )
        if gui.button("Run" if self.paused else "Pause"):
            self.paused = not self.paused
        if gui.button("Step"):
            self.paused, self.step_once = True, True
        if gui.button("Reset"):
            self._reset()
        if self.solver and gui.button(f"Solver: {self.solver} -> {next_solver(self.solver)} (s)"):
            self.later(self.switch_solver)
        if gui.button("Next scene (tab)"):
            self.later(self._next_scene)
        if gui.button("Scenes and keys (h)"):
            self.show_help = not self.show_help
        gui.text("fluid")
        for key, label in (("fluid.viscosity", "viscosity"), ("fluid.stiffness", "stiffness")):
            if not self.takes(key):  # dfsph has no stiffness
                continue
            lo = 0.0 if key == "fluid.viscosity" else 0.1 * self.slider_max[key] / 4.0
            new = gui.slider_float(label, self.params[key], lo, self.slider_max[key])
            if not math.isclose(new, self.params[key], rel_tol=1e-6, abs_tol=1e-12):
                self._set_param(key, float(new))
        new = gui.slider_float("gravity y", self.params["gravity_y"], -20.0, 5.0)
        if not math.isclose(new, self.params["gravity_y"], abs_tol=1e-9):
            self._set_gravity_y(new)
        gui.text(f"mouse (q / e: radius), cap {self.mouse.max_speed:.2g} m/s")
        self.mouse.radius = gui.slider_float("radius", self.mouse.radius, self.mouse.radius_min, self.mouse.radius_max)
        self.mouse.strength = gui.slider_float("strength", self.mouse.strength, 0.0, 100.0)
        new = gui.checkbox("refinement", self.refinement)
        if new != self.refinement:
            self.later(lambda new=new: self.set_refinement(new))
        self.show_virtual = gui.checkbox("show virtual (v)", self.show_virtual)
        self.surface = gui.checkbox("water view (w)", self.surface)
        if gui.button(f"colour: {self.color_mode} (c)"):
            self.color_mode = palette.next_mode(self.color_mode)
