"""The window's panels: the HUD on the right (figures, buttons, sliders) and the help,
plus the rate counters the HUD shows. GGUI/ImGui calls only; the state is the window's.

Each panel is first planned as rows (text or a widget), so that its height is known
before ImGui draws it: a panel fits its rows, and its window (at 1280x720 the HUD
needs 660 px at most). ImGui sizes a panel only when it first appears, so a panel's
name carries its size; the rows whose number would change from frame to frame (the
last message, the solver's counts) keep their place, blank when there is nothing to
say, so the HUD changes size only when the scene or solver does.
"""

from __future__ import annotations

import collections
import math
import textwrap
import time

from . import keys
from .loading import CHAR_PX, LINE_PX, PAD_PX, TITLE_PX
from .mouse import STRENGTH_MAX
from .switch import next_solver

#: HUD panel on the right: width in pixels (a line of HUD_TEXT_CHARS characters of ImGui's
#: 7 px glyphs, and the slider labels) and its margin from the window's edges.
HUD_WIDTH_PX = 330
HUD_TEXT_CHARS = 44
HUD_MARGIN_PX = 8
#: Height of a widget row (button, slider, checkbox): ImGui's 19 px frame and 4 px spacing.
WIDGET_PX = 23
#: The colour of the HUD's message lines (what an action did, or why it could not).
MESSAGE_COLOUR = (1.0, 0.75, 0.3)
DIM_COLOUR = (0.65, 0.68, 0.72)
#: Lines kept for the message and for the solver's figures.
MESSAGE_LINES = 2
SOLVER_LINES = 4
#: How long a message stays (one that says something went wrong stays until the next).
MESSAGE_S = 8.0
#: Window over which splits/s and merges/s are counted (simulated seconds).
RATE_WINDOW_S = 1.0
#: The help panel: characters a line, at most.
HELP_CHARS = 96


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


class Message:
    """The HUD's last message: what an action did (it goes after MESSAGE_S) or what went
    wrong (``sticky``: it stays until the next message)."""

    def __init__(self):
        self.text, self.until = "", None

    def set(self, text: str, sticky: bool = False, now: float | None = None) -> None:
        now = time.perf_counter() if now is None else now
        self.text, self.until = str(text), None if sticky else now + MESSAGE_S

    def shown(self, now: float | None = None) -> str:
        now = time.perf_counter() if now is None else now
        if self.until is not None and now > self.until:
            return ""
        return self.text


def _number(st: dict, key: str) -> float | None:
    """A figure of the stats row, or None where the row has none."""
    value = st.get(key)
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        return None


def solver_lines(
    st: dict, solver: str | None, tolerance: float | None = None, seen: set | None = None, next_ready: bool = False
) -> list[str]:
    """The HUD's lines on the pressure solver, from a stats row ``st`` of
    ``Simulation.stats()``: ``solver`` (else the running scene's ``solver``), the mean
    iterations a step since the last row of its solves (``density_iterations``,
    ``divergence_iterations``: shown once one has been above 0, which ``seen`` remembers
    across rows), ``density_error`` (an iterating solver's last solve's, else the mean
    compression), ``unconverged``, ``shortened`` (steps halved so that a solve converged) and ``clamped``
    (shown when above 0); ``tolerance``:
    ``dfsph.density_tolerance``, shown beside the error; ``clamped`` counts the particles
    a velocity clamp slowed (pbf); ``next_ready``: what ``s`` opens is ready (built
    ahead or kept), so the first line says so. Any key may be missing. No
    lines for a simulation without a pressure solver (the app's stand-in)."""
    name = st.get("solver") or solver
    if not name:
        return []
    seen = set() if seen is None else seen
    nxt = next_solver(name)
    ready = ", ready" if next_ready else ""
    lines = [f"solver {name}" + (f"   (s: next {nxt}{ready})" if nxt != name else "")]
    its = {}
    for key, label in (("density_iterations", "density"), ("divergence_iterations", "divergence")):
        value = _number(st, key)
        if value is not None and (value > 0 or key in seen):
            seen.add(key)
            its[label] = value
    if its:
        lines.append("iterations/step: " + ", ".join(f"{k} {v:.1f}" for k, v in its.items()))
    err = _number(st, "density_error")
    if err is not None:
        if "density_iterations" in seen:
            tol = f" (tolerance {100.0 * tolerance:.3g} %)" if tolerance else ""
            lines.append(f"density error {100.0 * err:.3g} %{tol}")
        else:
            lines.append(f"mean compression {100.0 * err:.3g} %")
    unconverged, clamped = _number(st, "unconverged"), _number(st, "clamped")
    if unconverged:
        lines.append(f"{int(unconverged)} solves stopped at max. iterations")
    shortened = _number(st, "shortened")
    if shortened:
        lines.append(f"{int(shortened)} steps halved for the solve")
    if clamped:
        lines.append(f"{int(clamped)} particles slowed by the velocity clamp")
    return lines


def hud_rect_px(size) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of the HUD's column in pixels, y down from the top."""
    w, h = size
    x0 = w - HUD_WIDTH_PX - HUD_MARGIN_PX
    return x0, HUD_MARGIN_PX, w - HUD_MARGIN_PX, h - HUD_MARGIN_PX


def panel_height(rows) -> int:
    """Pixels a panel of ``rows`` needs: text rows LINE_PX, widgets WIDGET_PX."""
    body = sum(LINE_PX if r[0] == "text" else WIDGET_PX for r in rows)
    return TITLE_PX + 2 * PAD_PX + body


def draw_rows(gui, rows) -> None:
    """Draw planned rows: ("text", str, colour), ("button", label, act),
    ("slider", label, value, lo, hi, act(new)), ("checkbox", label, value, act(new))."""
    for row in rows:
        kind = row[0]
        if kind == "text":
            if row[2] is None:
                gui.text(row[1])
            else:
                gui.text(row[1], color=row[2])
        elif kind == "button":
            if gui.button(row[1]):
                row[2]()
        elif kind == "slider":
            _, label, value, lo, hi, act = row
            new = gui.slider_float(label, value, lo, hi)
            if not math.isclose(new, value, rel_tol=1e-6, abs_tol=1e-12):
                act(float(new))
        elif kind == "checkbox":
            _, label, value, act = row
            new = gui.checkbox(label, value)
            if new != value:
                act(new)


def _text(s, colour=None):
    return ("text", s, colour)


def hud_rows(self, snap) -> list:
    """The HUD's rows for the window ``self`` (an ``_App``) and its snapshot."""
    st = snap.stats or {}
    rows = [_text(f"scene {self.scene_name} ({snap.dim}D)"[:HUD_TEXT_CHARS])]
    rows.append(_text(f"t = {float(snap.time):.3f} s   dt = {float(st.get('dt', 0.0)):.2e} s"))
    rows.append(_text(f"frame {snap.frame}   drawn at {self.fps:.1f} frames/s"))
    speed = self.speed.value()
    if self.opening is not None:
        rows.append(_text("speed: paused while the next scene opens"))
    elif speed is None:
        rows.append(_text("speed: paused" if self.paused else "speed: measuring"))
    else:
        slow = " (slow motion)" if self.frame_sim < 0.999 * self.frame_dt else ""
        rows.append(_text(f"speed {speed:.3g}x real time{slow}"))
    solver = solver_lines(st, self.solver, self.tolerance, self.solver_seen, self.next_ready()) if self.solver else []
    if solver:
        solver = (solver + [""] * SOLVER_LINES)[:SOLVER_LINES]
    rows += [_text(line) for line in solver]
    message = textwrap.wrap(self.message.shown(), HUD_TEXT_CHARS)[:MESSAGE_LINES]
    rows += [_text(line, MESSAGE_COLOUR) for line in message + [""] * (MESSAGE_LINES - len(message))]
    counts = (st.get(k, "?") for k in ("n_real", "n_virtual", "n_transient"))
    rows.append(_text("real {}   virtual {}   transient {}".format(*counts)))
    splits, merges = self.rates.rates()
    rows.append(_text(f"splits {splits:.0f}/s   merges {merges:.0f}/s   levels {int(snap.levels)}"))
    unit = "kg" if snap.dim == 3 else "kg/m"
    mass, ratio = float(st.get("total_mass", 0.0)), float(st.get("max_density_ratio", 0.0))
    rows.append(_text(f"mass {mass:.4g} {unit}   max rho/rho0 {ratio:.3f}"))
    rows.append(("button", ("Run" if self.paused else "Pause") + " (space)", self.toggle_pause))
    rows.append(("button", "Step one frame (n)", self.step_frame))
    rows.append(("button", "Reset (r)", self.reset_sim))
    if self.solver:
        rows.append(("button", f"Solver: {self.solver} -> {next_solver(self.solver)} (s)", self.switch_solver))
    rows.append(("button", "Next scene (tab)", lambda: self.later(self.step_scene)))
    rows.append(("button", "Scenes and keys (h)", self.toggle_help))
    rows.append(_text("fluid", DIM_COLOUR))
    for key, label in (("fluid.viscosity", "viscosity"), ("pbf.xsph", "smoothing"), ("fluid.stiffness", "stiffness")):
        if self.takes(key):  # dfsph has no stiffness; pbf its smoothing, the viscosity where it acts
            lo = 0.1 * self.slider_max[key] / 4.0 if key == "fluid.stiffness" else 0.0
            rows.append(("slider", label, self.params[key], lo, self.slider_max[key], _setter(self, key)))
    # symmetric, so that the handle at Earth's -9.81 stands clear of the value's minus sign
    rows.append(("slider", "gravity y", self.params["gravity_y"], -20.0, 20.0, self._set_gravity_y))
    rows.append(_text(f"mouse (q / e: radius), cap {self.mouse.max_speed:.2g} m/s", DIM_COLOUR))
    m = self.mouse
    rows.append(("slider", "radius", m.radius, m.radius_min, m.radius_max, lambda v: setattr(m, "radius", v)))
    rows.append(("slider", "strength", m.strength, 0.0, STRENGTH_MAX, lambda v: setattr(m, "strength", v)))
    rows.append(("checkbox", "refinement", self.refinement, lambda new: self.later(lambda: self.set_refinement(new))))
    rows.append(("checkbox", "show virtual (v)", self.show_virtual, lambda new: setattr(self, "show_virtual", new)))
    rows.append(("checkbox", "water view (w)", self.surface, lambda new: setattr(self, "surface", new)))
    rows.append(("checkbox", "water tinted by colour (t)", self.tint, lambda new: setattr(self, "tint", new)))
    rows.append(("button", f"colour: {self.color_mode} (c)", self.next_colour))
    return rows


def _setter(self, key):
    return lambda value: self._set_param(key, value)


def help_rows(self) -> list:
    """The help panel's rows: the keys (mrsph.app.keys), then a button per scene."""
    table = keys.text_table(HELP_CHARS, indent=0, ascii_only=True)  # ImGui's font: Latin-1 only
    rows = [_text(line) for line in table.splitlines()]
    rows.append(_text(""))
    rows.append(_text("scenes (a button opens one):", DIM_COLOUR))
    for name in self.scene_names:
        label = f"{name} (running)" if name == self.scene_name else name
        rows.append(("button", label, lambda name=name: self.later(lambda: self.open_scene(name))))
    return rows


def draw_hud(self, snap) -> None:
    """The HUD panel (right) and the help panel of the window ``self`` (an ``_App``)."""
    gui = self.window.get_gui()
    w, h = self.renderer.size
    if self.show_help:
        rows = help_rows(self)
        pw = min(CHAR_PX * HELP_CHARS + 2 * PAD_PX + 8, w - 2 * HUD_MARGIN_PX)
        ph = min(panel_height(rows), h - 2 * HUD_MARGIN_PX)
        x0, _, x1, _ = self.view_area()
        x = int(max(HUD_MARGIN_PX, (x0 + x1 - pw) / 2))
        y = int(max(HUD_MARGIN_PX, (h - ph) / 2))
        with gui.sub_window(f"Help: keys and scenes (h closes)##{x},{y},{pw}x{ph}", x / w, y / h, pw / w, ph / h):
            draw_rows(gui, rows)
    if not self.show_hud or snap is None:
        return
    rows = hud_rows(self, snap)
    x0, y0, x1, y1 = hud_rect_px(self.renderer.size)
    ph = min(panel_height(rows), y1 - y0)
    with gui.sub_window(f"mrsph##{x0},{y0},{ph},{len(rows)}", x0 / w, y0 / h, (x1 - x0) / w, ph / h):
        draw_rows(gui, rows)
