"""DFSPH's divergence solve (Bender & Koschier 2017, Algorithm 2): Jacobi sweeps on the
velocities. Each measures the density's rate of change of the current velocities,
Dρ_i/Dt = Σ_j m_j (u_i − u_j')·∇W_ij (compression only), sets κ_i = Dρ_i/Dt α_i, and
moves the velocities, u_i −= Σ_j m_j (κ_i/ρ_i + κ'_j/ρ_j) ∇W_ij (``operator.py``), until
the average Dρ/Dt times the step is within ``dfsph.divergence_tolerance`` of ρ0.

The paper's density solve sweeps the same way, from half the last pressure and adding
compression-only increments. A sweep carries pressure one neighbour further, so a column
N particles deep needs of order N² of them to build its weight's pressure, and a stopping
rule on the density error, which sees a smooth pressure error only where it ends, stops
long before: the 80-deep tank at rest sank and was thrown up again in bursts, 2,400
sweeps a step holding it (docs/METHOD.md §16). The density solve is ``krylov.py``'s.
"""

import taichi as ti

from mrsph.sph.particles import is_real

from .counts import DIVERGENCE
from .tolerance import DONE, RUNS

# Jacobi iterations per kernel launch: the host reads the convergence after each launch.
# More saves a launch and a read (~15 µs, against ~1.5 ms an iteration at 10k particles)
# per iteration, but each is a copy of the iteration's code in the kernel, and Taichi's
# compile time grows faster than the code: the DFSPH kernels took ~4 minutes to compile
# on this CPU with two (the window's solver switch waited for them, and the five first
# DFSPH compiles were half of the test suite's time).
ITERATIONS_PER_LAUNCH = 1


@ti.data_oriented
class Sweeps:
    def __init__(self, solver):
        """solver: the DFSPH solver whose factors, operator and stopping rule the sweeps use
        (``solver.py``)."""
        self.s = solver
        self.pool, self.op, self.stop = solver.pool, solver.op, solver.stop

    def solve(self, n: int) -> tuple:
        """Sweeps, ``ITERATIONS_PER_LAUNCH`` a launch, each launch returning whether the
        device says done (its outcome is read once, at the end: a state read per launch was
        13 of a demo_2d step's 43 calls); returns (iterations, average error, stopped at
        the maximum)."""
        self.stop.start()
        while not self.sweep(n, *self.stop.args(DIVERGENCE)):
            pass
        iterations, error, hit_max = self.stop.outcome()
        return int(iterations), float(error), bool(hit_max)

    @ti.kernel
    def sweep(self, n: ti.i32, tol: ti.f64, min_it: ti.i32, max_it: ti.i32) -> ti.i32:
        """``ITERATIONS_PER_LAUNCH`` sweeps, each first deciding on the device whether to
        stop (``Stopping``: converged after at least ``min_it`` updates, or ``max_it``
        reached)."""
        s = self.s
        p = ti.static(self.pool.p)
        h_dt = ti.cast(s.state.dt[None], float)  # this step's (the last one's before the kick)
        state = ti.static(self.stop.state)
        for _ in ti.static(range(ITERATIONS_PER_LAUNCH)):
            s.err[None] = 0.0
            state[RUNS] = 1 - state[DONE]
            for i in range(n):
                if state[RUNS] and is_real(p[i].kind):
                    e = ti.max(self.op.rate(i), 0.0)  # Dρ/Dt, compression only
                    self.op.kappa[i] = e * s.alpha[i]
                    s.err[None] += ti.cast(e * h_dt, ti.f64)
            if state[RUNS]:
                avg = s.err[None] / ti.max(s.n_real[None], 1) / ti.static(s.rest_density)
                self.stop.decide(DIVERGENCE, avg, tol, min_it, max_it)
            self.op.update_into(n, 1.0, self.pool.p.v, state[RUNS])
        return state[DONE]
