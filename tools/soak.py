"""Soak test: an adaptive 2D scene stirred as hard as the app allows, checked as it runs.

    python3 tools/soak.py                                  # 100 000 steps of demo_2d
    python3 tools/soak.py --steps 10000 --threads 1
    python3 tools/soak.py --scene region_2d --set adaptivity.levels=2

The stirrer is the window's own mouse logic (:class:`mrsph.app.mouse.MouseDisturbance`)
fed a scripted cursor, at the strongest settings the window offers: strength at the HUD
slider's maximum (:data:`STRENGTH_MAX`), radius at the mouse's clamp
(``RADIUS_MAX_FRACTION`` of the domain's largest side), the cursor sweeping back and forth
through the water at the mouse's speed clamp: by default the clamp without a sound speed,
8 domain sizes a second (12.8 m/s in demo_2d), harsher than any window; with
``--window-cap`` the window's own, a tenth of sqrt(fluid.stiffness) (2 m/s in demo_2d).
It pushes, pulls, then lets go, in turn (:data:`GESTURES`, :data:`GESTURE_S` each), so
that fluid refines under it and merges back behind it.

Every ``--check-every`` steps, and after the last one, it checks:

- no NaN or Inf in the position or velocity of any alive particle (the solver itself
  stops on a NaN acceleration, and on a time step below ``physics.dt_min``: both count
  as failures here);
- every real particle inside the domain box and outside every obstacle (signed
  distances evaluated in numpy from the scene, as ``mrsph/sph/boundary.py`` defines them),
  to within :data:`POSITION_TOLERANCE` finest spacings;
- the real mass equal to the mass at the start (``math.fsum`` over the float64 values of
  the masses): exactly where the scene merges full groups only (splits and merges of full
  groups are exact in binary), and to :data:`PARTIAL_MASS_RTOL` where partial groups may
  merge (``adaptivity.merge_min_children`` < 2^d or ``merge_remnants``; the demo does):
  a partial group's sum is rounded to float32, see ``tests/test_multires.py``. One lost
  finest-level particle of the demo is 1e-4 of its mass, 100 times that tolerance;
- capacity refusals (the pool's ``refused`` counter and ``sim.warnings``): reported, not
  failures, since a full pool is a documented state (the simulation goes on coarser);
  but refusals counted without a warning in ``sim.warnings`` fail;
- the pressure solves that stopped at their maximum iterations short of their tolerance
  (the stats rows' ``unconverged``): reported; ``--strict`` makes any a failure, as
  ``tests/test_soak.py`` holds the soak to none;
- the step: the mean step between two checks at least :data:`STALL_FRACTION` of the
  median of those before it (:func:`stalled`, once :data:`STALL_WINDOWS` have passed). A
  step that falls and stays fallen is a simulation that no longer advances, though each
  step is above ``physics.dt_min`` and every other check passes.

It stops at the first failed check, prints one summary line (steps, simulated time,
wall time, smallest dt, largest speed, splits, merges, refusals, and per level the median
real particle's mass over the level's nominal mass, :func:`mass_ratios`) and exits 0 when
every check passed, 1 otherwise.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: The upper end of the window's "strength" slider (mrsph/app/hud.py), 1/s.
from mrsph.app.mouse import STRENGTH_MAX  # noqa: E402

#: The cursor's gestures in turn; None lets go.
GESTURES = ("push", "pull", None)
#: How long each gesture lasts (simulated s): long enough for the fluid under the cursor
#: to refine and, after letting go, to merge back.
GESTURE_S = 0.5
#: The mouse buttons of each gesture (a right drag pulls, see mrsph/app/mouse.py).
BUTTONS = {"push": ("left",), "pull": ("right",), None: ()}
#: The window hands the mouse to the solver once per rendered frame; 60 frames/s.
MOUSE_RATE_HZ = 60.0
#: A real particle may sit this many finest spacings outside the domain or inside an
#: obstacle (float32 rounding of the projection onto a surface) before it counts.
POSITION_TOLERANCE = 1e-3
#: A check window whose mean step is below this share of the median window's has stalled:
#: under dfsph the stirred demo's mean step over 1000 steps read 0.46-2.8 times its median
#: until it collapsed to 0.013-0.02 of it (2026-12-05, before caged remnants were absorbed).
STALL_FRACTION = 0.05
#: Windows before the stall check starts, so that its median stands on a run's worth.
STALL_WINDOWS = 10


@dataclass
class SoakResult:
    scene: str
    steps: int = 0
    sim_time: float = 0.0
    wall_s: float = 0.0
    min_dt: float = math.inf
    max_speed: float = 0.0
    splits: int = 0
    merges: int = 0
    refused: int = 0
    unconverged: int = 0  # solves stopped at their maximum iterations (stats rows)
    shortened: int = 0  # steps halved so that a solve converged (dfsph.shorten_steps)
    checks: int = 0
    n_real_min: int = 0
    n_real_max: int = 0
    n_real_end: int = 0
    mass0: float = 0.0
    mass_ratio: list = field(default_factory=list)  # per level, at the last check
    window_dt: list = field(default_factory=list)  # the mean step between checks, s
    warnings: list = field(default_factory=list)
    failures: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.failures

    def summary(self) -> str:
        verdict = "OK" if self.ok else f"FAILED ({len(self.failures)}): {self.failures[0]}"
        return (
            f"soak {self.scene}: {self.steps} steps, {self.sim_time:.4g} s simulated in "
            f"{self.wall_s:.4g} s wall ({self.steps / max(self.wall_s, 1e-9):.0f} steps/s); "
            f"min dt {self.min_dt:.3g} s; max speed {self.max_speed:.3g} m/s; "
            f"splits {self.splits}, merges {self.merges}; refused {self.refused}"
            f"{' (warned)' if self.refused and self.warnings else ''}; solves at their maximum "
            f"{self.unconverged}, steps halved {self.shortened}; real particles "
            f"{self.n_real_min}..{self.n_real_max} (at the end {self.n_real_end}); "
            f"{self._mass_text()}{self.checks} checks: {verdict}"
        )

    def _mass_text(self) -> str:
        if not self.mass_ratio:
            return ""
        return f"median mass / nominal by level {', '.join(f'{r:.2f}' for r in self.mass_ratio)}; "


def mass_ratios(parts: dict, nominal) -> list[float]:
    """The median of the real particles' mass over their level's nominal mass, per level
    (nan for an empty level). Not a check: partial merges make lighter particles by design
    (a group of one, a quarter in 2D), but a run that drifts far below 1 has fewer
    particles than its spacing says, each with more neighbours (docs/METHOD.md §15)."""
    from mrsph.sph.particles import VIRTUAL_CHILD

    real = parts["kind"] < VIRTUAL_CHILD
    out = []
    for level, m in enumerate(nominal):
        sel = real & (parts["level"] == level)
        out.append(float(np.median(parts["m"][sel] / m)) if sel.any() else math.nan)
    return out


# ----------------------------------------------------------------------------- geometry
def obstacle_sdf(x: np.ndarray, obstacles, domain=None) -> np.ndarray:
    """Signed distance (positive outside) to the nearest obstacle, per row of x; +inf
    without obstacles. Boxes and spheres as in ``Boundary.obstacle_sdf``; with the
    scene's ``domain``, a box's faces on its walls are shut, as there: the box reaches
    past the wall, so that a particle on the floor under a post is inside it."""
    from mrsph.sph.boundary import shut_faces

    best = np.full(len(x), np.inf)
    for o in obstacles:
        if o["shape"] == "box":
            lo, hi = np.asarray(o["min"], float), np.asarray(o["max"], float)
            if domain is not None:
                dlo, dhi = np.asarray(domain["min"], float), np.asarray(domain["max"], float)
                shut_lo, shut_hi = shut_faces(lo, hi, dlo, dhi)
                lo = np.where(shut_lo == 1, dlo - (dhi - dlo), lo)
                hi = np.where(shut_hi == 1, dhi + (dhi - dlo), hi)
            q = np.abs(x - 0.5 * (lo + hi)) - 0.5 * (hi - lo)
            outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
            dist = np.where(outside > 0.0, outside, q.max(axis=1))
        else:
            dist = np.linalg.norm(x - np.asarray(o["center"], float), axis=1) - float(o["radius"])
        best = np.minimum(best, dist)
    return best


PARTIAL_MASS_RTOL = 1e-6


def mass_rtol(scene_data: dict) -> float:
    """0 (exact) where only full groups merge (:func:`mrsph.scene.config.mass_exact`), else
    :data:`PARTIAL_MASS_RTOL`."""
    from mrsph.scene.config import mass_exact

    if "adaptivity" not in scene_data or mass_exact(scene_data):
        return 0.0
    return PARTIAL_MASS_RTOL


def check_state(parts: dict, scene_data: dict, mass0: float, tolerance: float) -> list[str]:
    """The checks of one moment, as failure lines (empty when all pass)."""
    from mrsph.sph.particles import VIRTUAL_CHILD

    problems = []
    x, v = parts["x"].astype(np.float64), parts["v"].astype(np.float64)
    bad = ~(np.isfinite(x).all(axis=1) & np.isfinite(v).all(axis=1))
    if bad.any():
        i = int(np.argmax(bad))
        problems.append(
            f"{int(bad.sum())} particle(s) with NaN/Inf position or velocity "
            f"(first: level {int(parts['level'][i])}, kind {int(parts['kind'][i])})"
        )
    real = parts["kind"] < VIRTUAL_CHILD
    xr = x[real & ~bad]
    lo = np.asarray(scene_data["domain"]["min"], float)
    hi = np.asarray(scene_data["domain"]["max"], float)
    out = ((xr < lo - tolerance) | (xr > hi + tolerance)).any(axis=1)
    if out.any():
        problems.append(
            f"{int(out.sum())} real particle(s) outside the domain "
            f"(first at {np.round(xr[np.argmax(out)], 5).tolist()})"
        )
    if scene_data["obstacles"]:
        phi = obstacle_sdf(xr, scene_data["obstacles"], scene_data["domain"])
        inside = phi < -tolerance
        if inside.any():
            problems.append(f"{int(inside.sum())} real particle(s) inside an obstacle (deepest {-phi.min():.3g} m)")
    mass = math.fsum(parts["m"][real].astype(np.float64).tolist())
    if abs(mass - mass0) > mass_rtol(scene_data) * abs(mass0):
        problems.append(f"real mass {mass!r} kg differs from the start's {mass0!r} kg (by {mass - mass0:.3g} kg)")
    return problems


def stalled(window_dt: list) -> str | None:
    """Whether the last check window's mean step fell below :data:`STALL_FRACTION` of the
    median of the windows before it, as a failure line (None: it did not, or fewer than
    :data:`STALL_WINDOWS` windows came before)."""
    if len(window_dt) <= STALL_WINDOWS:
        return None
    typical = float(np.median(window_dt[:-1]))
    if window_dt[-1] >= STALL_FRACTION * typical:
        return None
    return (
        f"the step collapsed: {window_dt[-1]:.3g} s on average since the last check, "
        f"{window_dt[-1] / typical:.3g} of the run's median {typical:.3g} s (at least {STALL_FRACTION:g} expected)"
    )


# ----------------------------------------------------------------------------- stirring
class ScriptedCursor:
    """A cursor sweeping back and forth across the fluid's bounding box at ``speed``
    (m/s) along x, bobbing slowly in y, holding the buttons of :data:`GESTURES` in
    turn for ``gesture_s`` each."""

    def __init__(self, scene_data: dict, speed: float, gesture_s: float = GESTURE_S):
        blocks = scene_data["fluid"]["blocks"]
        self.lo = np.min([b["min"] for b in blocks], axis=0).astype(float)
        self.hi = np.max([b["max"] for b in blocks], axis=0).astype(float)
        self.speed = float(speed)
        self.gesture_s = float(gesture_s)

    def position(self, t: float) -> np.ndarray:
        span = self.hi - self.lo
        inner_lo, inner_span = self.lo + 0.1 * span, 0.8 * span
        phase = (t * self.speed / inner_span[0]) % 2.0  # triangle wave along x
        pos = inner_lo + 0.5 * inner_span
        pos[0] = inner_lo[0] + inner_span[0] * (phase if phase < 1.0 else 2.0 - phase)
        pos[1] = inner_lo[1] + inner_span[1] * (0.5 + 0.5 * math.sin(2.0 * math.pi * t / 1.3))
        return pos

    def gesture(self, t: float):
        return GESTURES[int(t // self.gesture_s) % len(GESTURES)]

    def buttons(self, t: float) -> set:
        return set(BUTTONS[self.gesture(t)])


# ----------------------------------------------------------------------------- the soak
def soak_mouse(
    data: dict, strength: float = STRENGTH_MAX, radius_fraction: float | None = None, window_cap: bool = False
):
    """The soak's mouse: ``strength``, the radius at ``radius_fraction`` (default the
    mouse's clamp) of the domain's largest side, and the speed cap of a mouse that knows
    no sound speed, or with ``window_cap`` the window's (``safe_speed`` of the scene's
    ``fluid.stiffness``, as ``mrsph/app/window.py`` builds it)."""
    from mrsph.app.mouse import RADIUS_MAX_FRACTION, MouseDisturbance

    lo, hi = np.asarray(data["domain"]["min"], float), np.asarray(data["domain"]["max"], float)
    size = float(np.max(hi - lo))
    stiffness = float(data["fluid"]["stiffness"]) if window_cap else None
    return MouseDisturbance.for_domain(
        lo, hi, stiffness, strength=strength, radius=(radius_fraction or RADIUS_MAX_FRACTION) * size
    )


def soak(
    steps: int = 100_000,
    check_every: int = 500,
    scene="demo_2d",
    overrides=(),
    arch: str = "cpu",
    threads: int | None = None,
    strength: float = STRENGTH_MAX,
    radius_fraction: float | None = None,
    gesture_s: float = GESTURE_S,
    progress=None,
    window_cap: bool = False,
    strict: bool = False,
) -> SoakResult:
    """Run the soak (see the module docstring); ``progress(result)`` after every check;
    ``strict``: a solve stopped at its maximum iterations is a failure."""
    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation, SimulationError
    from mrsph.sph.particles import VIRTUAL_CHILD

    sc = load_scene(scene, list(overrides))
    data = sc.data
    if int(data["dim"]) != 2 or not data["adaptivity"]["enabled"]:
        raise ValueError(
            f"{sc.name}: the soak wants a 2D adaptive scene (dim = {data['dim']}, "
            f"adaptivity.enabled = {data['adaptivity']['enabled']})"
        )
    sim = Simulation(sc, arch=arch, threads=threads)
    mouse = soak_mouse(data, strength, radius_fraction, window_cap)
    cursor = ScriptedCursor(data, mouse.max_speed, gesture_s)
    tolerance = POSITION_TOLERANCE * sim.s0
    nominal = sim.lev.m.to_numpy().astype(np.float64)

    res = SoakResult(scene=sc.name)
    parts = sim.particles()
    st = sim.stats(parts)
    res.mass0 = st["total_mass"]
    res.n_real_min = res.n_real_max = res.n_real_end = st["n_real"]
    res.failures += check_state(parts, data, res.mass0, tolerance)
    mouse_every = 1.0 / MOUSE_RATE_HZ
    last_mouse = -math.inf
    t0 = time.perf_counter()
    t_check, step_check = sim.time, 0
    try:
        while res.steps < steps and res.ok:
            if sim.time - last_mouse >= mouse_every:
                dt_mouse = sim.time - last_mouse if last_mouse > -math.inf else 0.0
                sim.set_disturbance(mouse.update(cursor.position(sim.time), cursor.buttons(sim.time), dt_mouse))
                last_mouse = sim.time
            res.min_dt = min(res.min_dt, sim.step())
            res.steps += 1
            if res.steps % check_every == 0 or res.steps == steps:
                parts = sim.particles()
                st = sim.stats(parts)
                res.checks += 1
                res.splits += st["splits"]
                res.merges += st["merges"]
                res.refused += st["refused"]
                res.unconverged += int(st["unconverged"])
                res.shortened += int(st.get("shortened", 0))
                res.n_real_min = min(res.n_real_min, st["n_real"])
                res.n_real_max = max(res.n_real_max, st["n_real"])
                res.n_real_end = st["n_real"]
                real = parts["kind"] < VIRTUAL_CHILD
                if real.any():
                    speed = np.linalg.norm(parts["v"][real].astype(np.float64), axis=1)
                    res.max_speed = max(res.max_speed, float(np.nanmax(speed)))
                res.mass_ratio = mass_ratios(parts, nominal)
                for line in check_state(parts, data, res.mass0, tolerance):
                    res.failures.append(f"step {sim.steps} (t = {sim.time:.5g} s): {line}")
                res.window_dt.append((sim.time - t_check) / (res.steps - step_check))
                t_check, step_check = sim.time, res.steps
                stall = stalled(res.window_dt)
                if stall:
                    res.failures.append(f"step {sim.steps} (t = {sim.time:.5g} s): {stall}")
                if strict and st["unconverged"]:
                    res.failures.append(
                        f"step {sim.steps} (t = {sim.time:.5g} s): {int(st['unconverged'])} pressure solve(s) "
                        f"stopped at their maximum iterations since the last check"
                    )
                res.wall_s, res.sim_time = time.perf_counter() - t0, sim.time
                if progress:
                    progress(res)
    except SimulationError as e:
        res.failures.append(f"SimulationError: {e}")
    res.wall_s, res.sim_time = time.perf_counter() - t0, sim.time
    res.refused = int(sim.pool.refused[None])
    res.warnings = list(sim.warnings)
    if res.refused and not res.warnings:
        res.failures.append(f"{res.refused} capacity refusal(s) counted but no warning in sim.warnings")
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    ap.add_argument("--steps", type=int, default=100_000, help="time steps to run")
    ap.add_argument("--check-every", type=int, default=500, metavar="N", help="steps between checks")
    ap.add_argument("--scene", default="demo_2d", help="a 2D adaptive scene (name or path)")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="overrides",
        help="override a scene key (repeatable)",
    )
    ap.add_argument("--arch", default="cpu", choices=("auto", "cpu", "gpu"))
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: all cores)")
    ap.add_argument("--strength", type=float, default=STRENGTH_MAX, help="stirring strength, 1/s")
    ap.add_argument(
        "--gesture-s", type=float, default=GESTURE_S, help="simulated seconds of each gesture (push, pull, let go)"
    )
    ap.add_argument(
        "--window-cap",
        action="store_true",
        help="cap the cursor's speed as the window does (0.1 sqrt(fluid.stiffness)), not at 8 domain sizes a second",
    )
    ap.add_argument(
        "--strict", action="store_true", help="a pressure solve stopped at its maximum iterations is a failure"
    )
    ap.add_argument("--quiet", action="store_true", help="only the summary line")
    args = ap.parse_args(argv)
    if args.steps < 1 or args.check_every < 1:
        ap.error("--steps and --check-every must be positive")
    from mrsph.scene.config import SceneError

    report_every = max(1, args.steps // args.check_every // 20)

    def progress(r: SoakResult):
        if not args.quiet and (r.checks % report_every == 0 or not r.ok):
            print(
                f"  step {r.steps}: t = {r.sim_time:.4g} s, {r.wall_s:.0f} s wall, "
                f"real {r.n_real_end} ({r.n_real_min}..{r.n_real_max}), splits {r.splits}, merges {r.merges}, "
                f"refused {r.refused}, max speed {r.max_speed:.3g} m/s, solves at their maximum {r.unconverged}, "
                f"steps halved {r.shortened}",
                file=sys.stderr,
                flush=True,
            )

    try:
        res = soak(
            args.steps,
            args.check_every,
            args.scene,
            args.overrides,
            args.arch,
            args.threads,
            args.strength,
            gesture_s=args.gesture_s,
            progress=progress,
            window_cap=args.window_cap,
            strict=args.strict,
        )
    except SceneError as e:
        for line in e.problems:
            print(line, file=sys.stderr)
        return 2
    for line in res.warnings:
        print(f"warning: {line}", file=sys.stderr)
    for line in res.failures:
        print(f"failed: {line}", file=sys.stderr)
    print(res.summary())
    return 0 if res.ok else 1


if __name__ == "__main__":
    sys.exit(main())
