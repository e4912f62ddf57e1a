"""The window's switch between pressure solvers (scene key ``fluid.solver``): which one
comes next, and whether the running scene can take it.

The check runs before anything is rebuilt, so that a scene that cannot take the other
solver (``adaptivity.coupling = "symmetric"`` with "dfsph", say) costs no loading frame
and no compile: the HUD says why in one line and the running simulation goes on.
Taichi-free, like the rest of the app's logic, so it is tested without a window.
"""

from __future__ import annotations

from .view import scene_setting

#: Longest reason the HUD shows (it wraps it into the panel's width).
MAX_REASON_CHARS = 200


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
    """The solver after ``current`` (wcsph -> dfsph -> wcsph)."""
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
