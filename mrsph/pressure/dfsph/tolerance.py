"""When a DFSPH solve stops (``solver.py``): its tolerance, tightened in slow flow, the
largest error any particle may keep, and its minimum and maximum iterations, decided on
the device after each iteration; the host reads the outcome once a solve.

The tolerances in slow flow (keys ``dfsph.rest_tolerance`` and ``dfsph.slow_flow``). The
density error a solve leaves, η, is undone over the next steps at a speed of about
η s / correction_time. Where the particles move a good part of a spacing a step, that is
a small share of their speed; in water at rest it is a noise of its own that no flow
outgrows, and a smooth error of the pressure, which holds the water up, shows in the
density only where it ends, at the floor, so both the average and the largest error
allowed tighten as the flow slows: the 80-deep tank at rest moved at 0.0037 sqrt(gH) with
its pressure within 2 % of hydrostatic at 1e-5 (docs/METHOD.md §16)."""

import taichi as ti

from .counts import DENSITY

# Stopping.state[]: iterations applied, done, hit the maximum, whether this iteration runs
ITERS, DONE, HIT_MAX, RUNS = range(4)


@ti.data_oriented
class RestTolerance:
    """η_step = max(rest_tolerance, density_tolerance · min(1, m / slow_flow)), m the
    spacings the real particles move on average in the step (the mean, not the fastest:
    a splash leaves the water at rest around it as still). Kept in fields, not compiled
    in, so that a scene's values do not compile the solver's kernels again."""

    def __init__(self, cfg, density_tolerance: float):  # cfg: the [dfsph] params
        self.share = ti.field(ti.f64, shape=())  # m / slow_flow, from ``note_step``
        self.floor = ti.field(ti.f64, shape=())  # rest_tolerance, at most the scene's
        self.slow = ti.field(ti.f64, shape=())  # slow_flow
        self.share[None] = 1.0
        self.floor[None] = min(cfg.rest_tolerance, density_tolerance)
        self.slow[None] = cfg.slow_flow

    @ti.func
    def note_step(self, moved):
        """The step just chosen: m = mean_i |u_i| dt / s_i."""
        self.share[None] = moved / self.slow[None]

    @ti.func
    def of(self, tol):
        """This step's tolerance, ``tol`` the scene's density_tolerance."""
        return ti.max(self.floor[None], tol * ti.min(self.share[None], 1.0))

    @ti.func
    def scale(self, tol):
        """This step's tolerance over the scene's (1 in a fast flow, down to
        rest_tolerance / density_tolerance at rest): the largest error allowed scales with it."""
        return self.of(tol) / tol


@ti.data_oriented
class Stopping:
    """The stopping rule of both solves (``DENSITY``, ``DIVERGENCE``) and its state: a
    solve stops when its average error is within its tolerance after at least its minimum
    iterations and, in the density solve, no particle's error is above
    ``dfsph.max_density_error`` (a hot spot of a few dozen particles hides in the average
    of thousands; scaled in slow flow as the tolerance is); or at its maximum, counted as
    unconverged unless within the scene's own tolerances (short of ones tightened at rest
    only: converged as asked)."""

    def __init__(self, cfg, rest_density: float):  # cfg: the [dfsph] params
        self.tolerance = (cfg.density_tolerance, cfg.divergence_tolerance)
        self.min_iterations = (cfg.min_iterations, cfg.divergence_min_iterations)
        self.max_iterations = (cfg.max_iterations, cfg.divergence_max_iterations)
        self.rest = RestTolerance(cfg, self.tolerance[DENSITY])
        self.limit = ti.field(float, shape=())  # the largest error allowed, ρ* − ρ0
        self.limit[None] = cfg.max_density_error * rest_density
        self.state = ti.field(ti.i32, shape=4)
        self.error = ti.field(ti.f64, shape=())  # the last iteration's average error
        self.peak = ti.field(float, shape=())  # its largest error (density solve)

    def args(self, which: int) -> tuple:
        """The kernel arguments of solve ``which``: tolerance, min and max iterations."""
        return self.tolerance[which], self.min_iterations[which], self.max_iterations[which]

    @ti.kernel
    def start(self):
        for k in ti.static(range(4)):
            self.state[k] = 0
        self.error[None] = 0.0

    @ti.func
    def decide(self, which, avg, tol, min_it, max_it):
        """After an iteration whose average error is ``avg``: done, or one more."""
        self.error[None] = avg
        its = self.state[ITERS]
        stop, peak_ok, peak_asked = tol, True, True  # the divergence solve has no largest error
        if which == DENSITY:
            stop = self.rest.of(tol)
            peak_ok = self.peak[None] <= self.limit[None] * self.rest.scale(tol)
            peak_asked = self.peak[None] <= self.limit[None]
        if avg <= stop and its >= min_it and peak_ok:
            self.state[DONE] = 1
            self.state[RUNS] = 0
        elif its >= max_it:
            self.state[DONE] = 1
            self.state[HIT_MAX] = 0 if avg <= tol and peak_asked else 1
            self.state[RUNS] = 0
        else:
            self.state[ITERS] = its + 1

    @ti.kernel
    def outcome(self) -> ti.types.vector(3, ti.f64):
        """(iterations, the last average error, stopped at the maximum)."""
        return ti.Vector([self.state[ITERS], self.error[None], self.state[HIT_MAX]], ti.f64)
