"""One time step as an ordered list of named passes (METHOD.md §1), and the two ways of
running it: a pass a launch (each timed when profiling), or, where every pass between
the host's own is a device function, the whole list as one kernel launch.

``Simulation`` builds the list once (``simulation.py``, ``_passes``), from the parts' own
passes in the method's order, which ``docs/ARCHITECTURE.md``'s step table names and
``tests/test_passes.py`` checks.

A step of a few thousand particles is launch-bound: each call from Python into Taichi
costs 15-30 µs on the CPU (its arguments, its result, the pool's wake-up), and the
default demo's step made nine of them. So where the list holds no host work between
its device passes (``Pass.func`` set for each: a weakly compressible step, a
position-based one), ``Stepper`` composes those functions, in the list's order, into one
kernel: the same device functions, the same arithmetic. Compiled apart, LLVM may
contract a multiply-add in one form and not the other, so a fused and a pass-by-pass
run agree to round-off (``tests/test_step.py``), on the demo bit for bit.

The scalars every pass may read (the sound speed, whether a disturbance is active, the
time-step bound's numbers, the end of the frame, the time) are set once a step in
``StepState`` (the fused launch's arguments, or one small launch), which also holds the
step's dt and whether it goes, once the time-step pass has chosen them.
"""

import time
from collections.abc import Callable
from typing import NamedTuple

import taichi as ti


class Pass(NamedTuple):
    """One pass of a step, as ``docs/ARCHITECTURE.md``'s step table names it.

    ``timer``: the profile's bucket (``bench``'s phase shares). ``kernel(n)``: the pass
    launched alone (``n`` the particle count; a counting pass, the sort, takes none and
    returns n; the time-step pass returns the step's dt, or -1 when the step does not
    go; a later pass that ``decides`` may shorten the step: it returns the new dt, or
    None for the step's own). ``func(n)``: the same work as a device function, for the fused launch; None
    for work the host drives (an iterative solve's stopping, particles appended).
    ``when``: for a host pass, whether it runs this step (evaluated each step).
    ``repeat``: launches a step (a solver's iterations); ``again``: then, up to ``most``
    launches in all, one more while it says so (a host read, the solve's own stop);
    ``alone``: a launch of its own when fused; ``loops``: the loops over every particle's
    neighbours a launch makes (what ``bench`` counts as neighbour passes)."""

    name: str
    timer: str
    kernel: Callable
    func: Callable | None = None
    counts: bool = False
    decides: bool = False
    when: Callable[[], bool] | None = None
    repeat: int = 1
    again: Callable[[], bool] | None = None
    most: int = 0
    alone: bool = False
    loops: int = 0


@ti.data_oriented
class StepState:
    """The scalars a step's passes read, set once a step, and the step's outcome.

    In: ``c_sound`` (the pressure solver's signal speed), ``stirred`` (a disturbance is
    active), ``cfl`` and ``force_factor`` (λ of the CFL and force bounds), ``cap`` (the
    largest dt this step: dt_max, the disturbances' and viscous bounds), ``dt_min``,
    ``max_dt`` (the end of the frame) and ``t`` (the time at the start of the step).
    Out: ``dt`` (the step's, set by the time-step pass: until then the last step's) and
    ``go`` (whether the step may move the particles: no NaN, dt not below dt_min)."""

    def __init__(self):
        self.c_sound = ti.field(float, shape=())
        self.stirred = ti.field(ti.i32, shape=())
        self.cfl = ti.field(ti.f64, shape=())
        self.force_factor = ti.field(ti.f64, shape=())
        self.cap = ti.field(ti.f64, shape=())
        self.dt_min = ti.field(ti.f64, shape=())
        self.max_dt = ti.field(ti.f64, shape=())
        self.t = ti.field(ti.f64, shape=())
        # f64, so that a step cut to the end of a frame ends on it
        self.dt = ti.field(ti.f64, shape=())
        self.go = ti.field(ti.i32, shape=())

    @ti.func
    def store(self, c_sound, stirred, cfl, force_factor, cap, dt_min, max_dt, t):
        self.c_sound[None] = c_sound
        self.stirred[None] = stirred
        self.cfl[None] = cfl
        self.force_factor[None] = force_factor
        self.cap[None] = cap
        self.dt_min[None] = dt_min
        self.max_dt[None] = max_dt
        self.t[None] = t

    @ti.kernel
    def set(
        self,
        c_sound: float,
        stirred: ti.i32,
        cfl: ti.f64,
        force_factor: ti.f64,
        cap: ti.f64,
        dt_min: ti.f64,
        max_dt: ti.f64,
        t: ti.f64,
    ):
        self.store(c_sound, stirred, cfl, force_factor, cap, dt_min, max_dt, t)

    @ti.func
    def outcome(self):
        """The step's dt, or -1 when it does not go (the time-step pass says why)."""
        out = self.dt[None]
        if not self.go[None]:
            out = -1.0
        return out

    def set_dt(self, dt: float) -> None:
        """The last step's dt, as a reset or a restored state has it."""
        self.dt[None] = float(dt)
        self.go[None] = 1


@ti.data_oriented
class Segment:
    """Device passes run as one kernel launch: the step's inputs stored, n counted (the
    sort's, or the pool's own count after it), each pass's device function in order; it
    returns the step's outcome (dt, or -1), which the last launch of a step passes back.
    A pass after the time-step pass (``gated``) runs over no particle when the step does
    not go, as the pass-by-pass step, which stops there, leaves them."""

    def __init__(self, passes: tuple, state: StepState, count: Callable, gated: tuple):
        self.passes, self.state, self.count = passes, state, count
        self.gated = gated

    @ti.kernel
    def run(
        self,
        c_sound: float,
        stirred: ti.i32,
        cfl: ti.f64,
        force_factor: ti.f64,
        cap: ti.f64,
        dt_min: ti.f64,
        max_dt: ti.f64,
        t: ti.f64,
    ) -> ti.f64:
        self.state.store(c_sound, stirred, cfl, force_factor, cap, dt_min, max_dt, t)
        n = 0
        if ti.static(not self.passes[0].counts):
            n = self.count()
        for k in ti.static(range(len(self.passes))):
            p = ti.static(self.passes[k])
            if ti.static(p.counts):
                n = p.func()
            elif ti.static(self.gated[k]):
                p.func(ti.select(self.state.go[None] != 0, n, 0))
            else:
                p.func(n)
        return self.state.outcome()


@ti.data_oriented
class Stepper:
    """Runs a step's pass list: pass by pass (each timed into ``timers`` when
    ``profile()`` is true), or, when ``fuse`` and every device pass has a ``func``, the
    device passes in as few launches as the list allows between the host passes before
    and after them: one, unless a pass asks to be launched alone (``Pass.alone``: a
    large one, whose compile time would otherwise grow that of all the rest) or again
    and again (``Pass.repeat``: an iteration of a solver), each such a launch of its own.
    ``count``: a device function that returns the pool's particle count (the sort's),
    ``count_host`` the same on the host (for passes before the sort: a step that predicts
    first)."""

    def __init__(
        self, passes: list[Pass], state: StepState, fuse: bool, profile: Callable[[], bool], count, count_host
    ):
        self.state, self.profile, self.fuse, self.count, self.count_host = state, profile, fuse, count, count_host
        self._layout(tuple(passes))
        self.timers = dict.fromkeys((p.timer for p in self.passes), 0.0)

    def _layout(self, passes: tuple) -> None:
        """The host passes before the device ones, the device ones, the host ones after,
        and the launches the device ones make when fused."""
        self.passes = passes
        names = [p.name for p in self.passes]
        if len(set(names)) != len(names):
            raise ValueError(f"Stepper: pass names repeat: {names}")
        device = [i for i, p in enumerate(self.passes) if p.when is None]
        inner = self.passes[device[0] : device[-1] + 1] if device else ()
        # the device passes can be fused if no host pass sits among them
        self.fusable = bool(inner) and all(p.func is not None for p in inner)
        self.fused = self.fusable and self.fuse
        self._head = self.passes[: device[0]] if device else self.passes
        self._inner = tuple(inner)
        self._tail = self.passes[device[-1] + 1 :] if device else ()
        self.launches = []  # (Segment, the pass it repeats or None) of a fused step
        deciding = [k for k, p in enumerate(self._inner) if p.decides]
        after = [bool(deciding) and k > deciding[0] for k in range(len(self._inner))]
        run = []

        def segment(ks):
            return Segment(tuple(self._inner[k] for k in ks), self.state, self.count, tuple(after[k] for k in ks))

        for k, p in enumerate(self._inner if self.fused else ()):
            if p.repeat > 1 or p.again is not None or p.alone:
                if run:
                    self.launches.append((segment(run), None))
                    run = []
                self.launches.append((segment([k]), p))
            else:
                run.append(k)
        if run:
            self.launches.append((segment(run), None))

    # ------------------------------------------------------------------ host
    def wrap(self, name: str, wrapper: Callable) -> None:
        """Pass ``name``'s kernel replaced by ``wrapper(kernel)`` (a test watching what a
        pass does); the step then runs pass by pass."""
        if name not in [p.name for p in self.passes]:
            raise ValueError(f"wrap: no pass {name!r}")
        self._layout(
            tuple(p._replace(kernel=wrapper(p.kernel), func=None) if p.name == name else p for p in self.passes)
        )

    def run(self, args: tuple) -> float:
        """One step; ``args`` are ``StepState``'s inputs (c_sound, stirred, cfl,
        force_factor, cap, dt_min, max_dt, t). Returns dt, or -1 when the step did not go
        (the time-step pass left why, and what it found; no particle moved, though a
        fused step whose solver predicts first has sorted them by then)."""
        for p in self._head:
            if p.when():
                self._timed(p.timer, p.kernel, None)
        if self.fused and not self.profile():
            dt = -1.0
            for segment, p in self.launches:
                for _ in launches(p):
                    dt = segment.run(*args)
        else:
            dt = self._by_pass(args)
        if dt >= 0.0:
            for p in self._tail:
                if p.when():
                    self._timed(p.timer, p.kernel, None)
        return dt

    def run_span(self, first: str, last: str, args: tuple) -> int:
        """The device passes from ``first`` to ``last``, pass by pass (a look inside a step,
        for tests and tools: nothing integrates unless asked); returns n."""
        names = [p.name for p in self._inner]
        for name in (first, last):
            if name not in names:
                raise ValueError(f"run_span: no pass {name!r} (expected one of {names})")
        self.state.set(*args)
        n = 0
        for p in self._inner[names.index(first) : names.index(last) + 1]:
            out = self._launch(p, n)
            if p.counts:
                n = out
        return n

    def _by_pass(self, args: tuple) -> float:
        self._timed("timestep", self.state.set, None, *args)
        n, dt = (0 if self._inner[0].counts else self.count_host()), 0.0
        for p in self._inner:
            for _ in launches(p):
                out = self._launch(p, n)
            if p.counts:
                n = out
            elif p.decides and out is not None:
                dt = out
                if dt < 0.0:
                    return dt  # nothing moved: the host reports why
        return dt

    def _launch(self, p: Pass, n: int):
        if p.counts:
            return self._timed(p.timer, p.kernel, None)
        return self._timed(p.timer, p.kernel, n)

    def _timed(self, timer: str, fn, n, *args):
        """``fn(n)`` (or ``fn(*args)``, or ``fn()`` for n None), its wall time added to
        ``timers[timer]`` when profiling."""
        call = (lambda: fn(*args)) if args else (lambda: fn()) if n is None else (lambda: fn(n))
        if not self.profile():
            return call()
        ti.sync()
        t0 = time.perf_counter()
        out = call()
        ti.sync()
        self.timers[timer] = self.timers.get(timer, 0.0) + time.perf_counter() - t0
        return out


def launches(p: Pass | None):
    """A pass's launches, one at a time: ``repeat``, then while ``again`` (up to ``most``);
    a fused run of passes (None) is launched once."""
    if p is None:
        yield None
        return
    for k in range(p.repeat):
        yield k
    k = p.repeat
    while p.again is not None and k < p.most and p.again():
        yield k
        k += 1
