"""The window's scene and solver switches: which solver comes next, whether the running
scene can take it, and opening a scene (or the running one rebuilt with an override)
while the window goes on drawing.

A switch opens the new simulation through :class:`mrsph.app.host.Sims` (a process of its
own, or one kept from before) and keeps the running one on screen, paused and dimmed,
with a panel that says what the new one is doing, until it is ready; then the window
takes it in one frame. The solver check runs before anything is opened, so that a scene
that cannot take the next solver (``adaptivity.coupling = "symmetric"`` with "dfsph",
say) costs nothing: the HUD says why in one line and the running simulation goes on.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from .ahead import AFTER_S
from .host import key_of
from .view import scene_setting

#: Longest reason the HUD shows (it wraps it into the panel's width).
MAX_REASON_CHARS = 200
#: The scene keys the window overrides (the solver switch, the refinement checkbox).
WINDOW_KEYS = ("fluid.solver", "adaptivity.enabled")


def solver_names() -> tuple[str, ...]:
    """The solvers a scene may name, in the order the switch cycles through them (the
    scene schema's choices of ``fluid.solver``)."""
    from mrsph.scene.config import SCHEMA

    return tuple(SCHEMA.keys["fluid"].keys["solver"].choices)


def running_solver(scene) -> str | None:
    """The scene's ``fluid.solver``; None for a simulation without one (the app's
    stand-in, whose scene is a plain dict without the key)."""
    name = scene_setting(scene, "fluid.solver", None)
    return None if name is None else str(name)


def next_solver(current: str) -> str:
    """The solver after ``current`` in the schema's list (wraps around)."""
    names = solver_names()
    return names[(names.index(current) + 1) % len(names)] if current in names else names[0]


def why_not(scene, solver: str) -> str | None:
    """Why ``scene`` cannot run with ``fluid.solver = solver`` (one line), or None when
    it can. The scene is validated with the override, as the rebuild will be."""
    with_overrides = getattr(scene, "with_overrides", None)
    if with_overrides is None or running_solver(scene) is None:
        return "this simulation has no pressure solver to switch"
    try:
        with_overrides({"fluid.solver": solver})
    except Exception as e:  # SceneError: the scene's own words, first line
        first = (str(e).splitlines() or [type(e).__name__])[0]
        # less the scene's path: "FILE with override fluid.solver: KEY: what (got; expected)"
        _, found, rest = first.partition(" with override fluid.solver: ")
        return f"cannot switch to {solver}: {(rest if found else first)[:MAX_REASON_CHARS]}"
    return None


def first_line(e: BaseException, limit: int = 160) -> str:
    return (str(e).splitlines() or [type(e).__name__])[0][:limit]


@dataclass
class Opening:
    """A simulation the window is opening: what, as which label, since when, and what to
    do once it runs (the live-tuned sliders carried over)."""

    name: str
    overrides: dict
    label: str
    handle: object
    then: object = None
    started: float = field(default_factory=time.perf_counter)

    @property
    def solver(self) -> str | None:
        return self.overrides.get("fluid.solver")


class Switching:
    """The window's half that opens scenes (mixed into ``mrsph.app.window._App``, whose
    state it reads: ``sims``, ``sim``, ``opening``, ``scene_name``, ``overrides``...)."""

    # -- opening -------------------------------------------------------------------------
    def open_scene(self, name: str, overrides=None, label: str | None = None, then=None) -> bool:
        """Start opening ``name`` with ``overrides``; the running scene stays on screen
        until it is ready (``poll_opening``). A newer choice replaces one still opening."""
        label = label or name
        overrides = self._own(name, overrides)
        if not self.sims.separate and not self._same_precision(name):
            return False
        if self.opening is not None:
            self.opening.handle.close()
            self.opening = None
        try:
            handle = self.sims.open(name, overrides)
        except Exception as e:
            self.note(f"cannot open {label}: {type(e).__name__}: {first_line(e)}")
            return False
        self.opening = Opening(name, dict(overrides or {}), label, handle, then)
        self.pointer.reset()
        return True

    def poll_opening(self) -> None:
        """Take the opening simulation once it is ready; say why where it failed (at the
        start, with nothing to show, its error ends the window)."""
        op = self.opening
        if op is None:
            return
        state = op.handle.poll()
        if state == "busy":
            return
        self.opening = None
        if state != "ready":
            op.handle.close()
            error = op.handle.error or RuntimeError(f"{op.label} did not open")
            if self.sim is None:
                raise error
            self.note(f"cannot open {op.label}: {type(error).__name__}: {first_line(error)}")
            return
        took = time.perf_counter() - op.started
        if self.sim is not None:
            self.sim.set_disturbance(None)
        self.sims.put_back(self.sim)
        self.sim = op.handle
        self.scene_name, self.label, self.overrides = op.name, op.label, op.overrides
        if not op.overrides:  # the scene as make_sim gives it: what its overrides change
            self.base_of[op.name] = {k: scene_setting(op.handle.scene, k, None) for k in WINDOW_KEYS}
        self.opened_at = time.perf_counter()
        self._on_new_sim()
        self.note(f"opened {op.label} in {took:.1f} s")
        if op.then is not None:
            op.then()

    def _own(self, name: str, overrides) -> dict:
        """``overrides`` less those ``name`` has anyway: a switch back finds the kept one."""
        base = self.base_of.get(name, {})
        return {k: v for k, v in (overrides or {}).items() if k not in base or base[k] != v}

    # -- building ahead (mrsph.app.ahead) -------------------------------------------------
    def build_ahead(self) -> None:
        """Once the running scene has run a moment, build what s, Tab and shift+Tab would
        open; nothing new starts while a scene opens."""
        ahead = self.sims.ahead
        running = self.sim is not None and self.opening is None and self.sims.separate
        if running and self.ahead_n and time.perf_counter() - self.opened_at > AFTER_S:
            now = self._running_key()
            if now != self.ahead_for:
                self.ahead_for = now
                solver, scenes = self.likely_next()
                self.s_key = None if solver is None else key_of(*solver)
                items = ([solver] if solver is not None else []) + scenes
                ahead.want(items[: self.ahead_n])
        ahead.tick(start=running)

    def likely_next(self) -> tuple:
        """What s, Tab and shift+Tab would open now: (the scene with the next solver, or
        None where it cannot take it; [the next scene, the previous one]), each as
        (name, overrides)."""
        solver = None
        if self.solver and self.can_override:
            want = next_solver(self.solver)
            if why_not(self.sim.scene, want) is None:
                solver = (self.scene_name, self._own(self.scene_name, {**self.overrides, "fluid.solver": want}))
        names, scenes = self.scene_names, []
        if self.scene_name in names and len(names) > 1:
            i = names.index(self.scene_name)
            scenes = [(names[j], {}) for j in dict.fromkeys(((i + 1) % len(names), (i - 1) % len(names)))]
        return solver, scenes

    def next_ready(self) -> bool:
        """Whether what ``s`` opens is ready now (built ahead, or kept from before)."""
        key = self.s_key if self.ahead_for == self._running_key() else None
        if key is None or self.opening is not None:
            return False
        handle = self.sims.ahead.handles.get(key) or self.sims.kept.get(key)
        return handle is not None and handle.state == "ready"

    def _running_key(self) -> tuple:
        return (self.scene_name, tuple(sorted(self.overrides.items())))

    # -- what the keys and buttons ask ----------------------------------------------------
    def step_scene(self, step: int = 1) -> None:
        """The next (``step`` 1) or previous (-1) scene of the list, with its own solver."""
        base = self.opening.name if self.opening is not None else self.scene_name
        names = self.scene_names
        i = (names.index(base) + step) % len(names) if base in names else 0
        self.open_scene(names[i])

    def switch_solver(self) -> None:
        """The next pressure solver (``fluid.solver``) for the running scene, rebuilt with
        it; a scene that cannot take it (a SceneError, e.g. symmetric coupling with
        dfsph) keeps running and the HUD says why, in one line."""
        if not self.solver:
            self.note("this simulation has no pressure solver to switch")
            return
        op = self.opening
        current = op.solver if op is not None and op.name == self.scene_name and op.solver else self.solver
        want = next_solver(current)
        why = why_not(self.sim.scene, want)
        if why:
            self.note(why)
            return
        self._rebuild({"fluid.solver": want}, f"{self.scene_name} with {want}")

    def set_refinement(self, enabled: bool) -> None:
        """Refinement on / off: live where the simulation lists ``adaptivity.enabled`` in
        its ``LIVE_KEYS``, else by rebuilding the scene with the override (the solver's
        levels are fixed when it is built)."""
        if "adaptivity.enabled" in (getattr(self.sim, "LIVE_KEYS", None) or ()):
            self._set_param("adaptivity.enabled", bool(enabled))
            self.refinement = bool(enabled)
            return
        label = f"{self.scene_name} with refinement {'on' if enabled else 'off'}"
        self._rebuild({"adaptivity.enabled": bool(enabled)}, label)

    def _rebuild(self, override: dict, label: str) -> bool:
        """Open the running scene with ``override`` on top of the window's earlier
        overrides (a solver switch keeps the refinement toggle's choice, and the reverse),
        then carry the live-tuned values over where the new simulation takes them; one it
        does not take (dfsph has no stiffness) stays remembered for a switch back."""
        if not self.can_override:
            self.note(f"{', '.join(override)}: rebuilding needs make_sim(scene_name, overrides)")
            return False
        kept = dict(self.params)

        def carry_over():
            for key in ("fluid.viscosity", "fluid.stiffness", "pbf.xsph"):
                if self.takes(key):
                    self._set_param(key, kept[key])
                else:
                    self.params[key] = kept[key]
            if self.takes("physics.gravity"):
                self._set_gravity_y(kept["gravity_y"])

        return self.open_scene(self.scene_name, {**self.overrides, **override}, label, carry_over)

    def reset_sim(self) -> None:
        """Back to t = 0 (r); a simulation whose process stopped is opened again."""
        if self.sim is None or self.opening is not None:
            return
        if not self.sim.alive():
            self.open_scene(self.scene_name, self.overrides, self.label)
            return
        try:
            self.sim.reset()
            self.note("reset to t = 0")
        except Exception as e:
            self.note(f"reset failed: {first_line(e)}", sticky=True)
        self.mouse.reset()
        self.dirty = True

    def _same_precision(self, name: str) -> bool:
        """In-process simulations only: a scene with another float precision would
        re-initialise Taichi, which destroys this window's fields: refuse it with the
        reason instead."""
        if self.sim is None:
            return True
        try:
            from mrsph.scene.config import load_scene

            want = scene_setting(load_scene(name), "particles.precision", None)
        except Exception:
            return True  # let make_sim report the problem
        have = scene_setting(self.sim.scene, "particles.precision", None)
        if want is not None and have is not None and want != have:
            self.note(f"{name} needs precision {want} (running {have}): start the window with that scene instead")
            return False
        return True
