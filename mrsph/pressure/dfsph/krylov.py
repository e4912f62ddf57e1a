"""DFSPH's density solve by Krylov iterations: the system of the paper's Jacobi sweeps,
solved for the step's whole pressure instead of built up from compression-only
increments.

Why: a Jacobi sweep carries pressure one neighbour further, so the pressure that holds a
column N particles deep takes of order N² sweeps to build, and a solve that stops on the
density error stops long before: the missing pressure is smooth, and a smooth pressure
error shows in the density only where it ends, at the floor. The column sinks until its
floor is compressed past the largest error allowed, then a burst of sweeps throws it up
again (docs/validation.md, the deep tank). Krylov iterations reach across the column in
of order N iterations, and started from the whole last pressure they need few: the 2D
tank 80 deep holds at rest with 13 a step, where 2,400 sweeps a step were needed for the
same (docs/METHOD.md §16).

The system, for the real particles i in it (``on``): the density error a pressure κ (= p/ρ)
leaves is e(κ) = b − A κ. b_i is the error the kicked flow would leave, ρ_i − ρ0 − δρ_i
(δρ a split child's, ``fade``) times dt / ``dfsph.correction_time`` (at most 1), plus
dt Σ_j m_j (u*_i − u*_j')·∇W_ij; at a free surface (``SURFACE_DEFICIT``) only a
compression counts, an expansion is held where it is, as SPlisHSPlasH's DFSPH clamps
ρ_adv, so that the surface is not drawn in. A κ = −dt² Σ_j m_j (w_i − w_j')·∇W_ij is the
density the pressure removes, w its velocity change per unit time (``operator.py``).

The solve is conjugate gradients, preconditioned by the Jacobi diagonal α_i / dt², its
products weighted by the particles' volumes V_i = m_i / ρ_i. The pair push and the rate are
adjoint, the rate of particle i being ρ_i / m_i times the push's transpose: A = diag(ρ/m) S
with S symmetric and positive definite, through the level coupling too (a virtual
particle's reaction handed to its owners is the transpose of its velocity following
theirs). In the inner product Σ V_i x_i y_i A is symmetric. With masses equal that is the
plain one; with levels it is not, and there unweighted conjugate gradients diverged (the
2D adaptive tank: r·z grew 1000-fold within 100 iterations), and BiCGSTAB broke down at
times (a step's whole pressure came out negative); weighted, conjugate gradients hold.

A particle is in the system where the kicked flow compresses it or, within the fluid, it
carried pressure the last step; the others keep κ = 0: at a free surface the pressure is
where a compression is and nowhere else. A surface particle kept for its last pressure
alone, its row asking for no compression, drifts where its κ hardly moves its neighbours:
a lone fine particle among coarse ones (0.2 ρ0 at its level) rose from 6.6 to 143 kPa in
0.11 s in a pool whose floor reads 3.1 kPa (docs/METHOD.md §16). The iterations start
from the whole last pressure and move the velocities with κ as they go (u += a dt w), so a step that stops at any
iteration leaves the velocities its pressure makes. At the end a negative κ, a pull, is
taken back (its push undone): a pressure solve of a liquid does not pull.
"""

import taichi as ti

from mrsph.sph.particles import is_real, is_virtual

from .counts import DENSITY
from .tolerance import DONE, RUNS

# A particle whose density is this far below ρ0 is at a free surface (its kernel reaches
# past the fluid): its source is a compression only; within the fluid an expansion is
# pulled back as a compression is pushed, or a column that rose would never come down. A
# layer under the surface misses nothing of a support two spacings wide; the surface
# layer misses about a third.
SURFACE_DEFICIT = 0.01

# scalars of the iteration (``sc``): r·z (the last iteration's and this one's) and d·A d,
# each weighted by the particles' volumes (``_vol``)
RZ, RZ_NEW, DQ = range(3)


@ti.data_oriented
class Krylov:
    def __init__(self, solver, capacity: int):
        """solver: the DFSPH solver whose factors, κ sums, operator and stopping rule this
        uses (``solver.py``)."""
        self.s = solver
        self.pool, self.op, self.stop, self.coupling = solver.pool, solver.op, solver.stop, solver.coupling
        self.dim, self.adaptive = solver.dim, solver.adaptive
        self.r = ti.field(float, shape=capacity)  # the residual, b − A κ
        self.z = ti.field(float, shape=capacity)  # a preconditioned vector
        self.d = ti.field(float, shape=capacity)  # the search direction
        self.q = ti.field(float, shape=capacity)  # A times it
        self.slack = ti.field(float, shape=capacity)  # b_i minus the error the kicked flow leaves
        self.on = ti.field(ti.i32, shape=capacity)  # in the system
        self.w = ti.Vector.field(self.dim, float, shape=capacity)  # a velocity change per unit time
        self.visit = solver.op.visit_of(self.w)
        self.sc = ti.field(ti.f64, shape=3)
        self.n_on = ti.field(ti.i32, shape=())

    def solve(self, n: int, args) -> tuple:
        """The density solve (``args``: the stopping rule's tolerance and iterations):
        (iterations, average |r| over ρ0, stopped at the maximum)."""
        self.stop.start()
        self.start(n)
        while not self.iterate(n, *args):
            pass
        iterations, error, hit_max = self.stop.outcome()
        self.finish(n)
        return int(iterations), float(error), bool(hit_max)

    def loops(self, iterations: float) -> float:
        """Neighbour loops of a solve of this many iterations: the start's three (rate, push,
        rate), two an iteration (the product with A), the end's push."""
        return 4.0 + 2.0 * iterations

    # ------------------------------------------------------------------ device
    @ti.func
    def _apply(self, n, field: ti.template(), scale, vel: ti.template()):
        """vel += scale × the velocity change per unit time of the pressure in ``field``."""
        for i in range(n):
            self.op.kappa[i] = field[i] if is_real(self.pool.p[i].kind) else 0.0
        self.op.update_into(n, scale, vel, 1)

    @ti.func
    def _product(self, n, src: ti.template(), dst: ti.template(), dt2):
        """dst = A src on the system, w the velocity change per unit time of src."""
        for i in range(n):
            self.w[i] = ti.Vector.zero(float, self.dim)
        self._apply(n, src, 1.0, self.w)
        for i in range(n):
            if self.on[i]:
                dst[i] = -dt2 * self.op.rate_of(i, self.visit)

    @ti.func
    def _move(self, n, step, h_dt, src: ti.template()):
        """κ += step × src, and the velocities with it (w holding src's change)."""
        p = ti.static(self.pool.p)
        for i in range(n):
            if is_real(p[i].kind):
                p[i].v += step * h_dt * self.w[i]
                if self.on[i]:
                    self.s.ksum[i] += step * src[i]
        if ti.static(self.adaptive):
            for j in range(n):
                if is_virtual(p[j].kind):
                    self.coupling.follow_owners(j, self.pool.p.v)

    @ti.func
    def _vol(self, i):
        """V_i = m_i / ρ_i, the weight of CG's products: A = diag(ρ/m) S with S symmetric."""
        return self.pool.p[i].m / self.pool.p[i].rho

    @ti.func
    def _measure(self, i, r):
        """Particle i's |r| into the stopping rule's sum and largest."""
        e = ti.abs(r)
        self.s.err[None] += ti.cast(e, ti.f64)
        if e > self.stop.peak[None]:  # a float max is a compare-and-swap loop
            ti.atomic_max(self.stop.peak[None], e)

    @ti.func
    def _decide(self, tol, min_it, max_it):
        avg = self.s.err[None] / ti.max(self.n_on[None], 1) / ti.static(self.s.rest_density)
        self.stop.decide(DENSITY, avg, tol, min_it, max_it)

    @ti.kernel
    def start(self, n: ti.i32):
        """b from the kicked velocities, the system's particles, κ the last pressure where
        in it (applied to the velocities), the residual and the first direction."""
        p = ti.static(self.pool.p)
        s = self.s
        h_dt = ti.cast(s.state.dt[None], float)
        share = s.inherited_share()
        self.stop.state[RUNS] = 1
        self.n_on[None] = 0
        for i in range(n):
            self.on[i] = 0
            self.r[i] = 0.0
            self.d[i] = 0.0
            s.ksum[i] = 0.0
            if is_real(p[i].kind):
                c = s.excess(i)
                x = share * c + h_dt * self.op.rate(i)
                k = ti.max(p[i].p, 0.0) / p[i].rho
                inside = c > -SURFACE_DEFICIT * ti.static(s.rest_density)
                b = x if inside else ti.max(x, 0.0)
                self.slack[i] = b - x
                if (b > 0.0 or (k > 0.0 and inside)) and s.alpha[i] > 0.0:
                    self.on[i] = 1
                    s.ksum[i] = k
                    self.n_on[None] += 1
        self._apply(n, s.ksum, h_dt, self.pool.p.v)
        self.sc[RZ] = 0.0
        for i in range(n):
            if self.on[i]:
                r = self.slack[i] + share * s.excess(i) + h_dt * self.op.rate(i)
                z = s.alpha[i] * r / (h_dt * h_dt)
                self.r[i] = r
                self.d[i] = z
                self.sc[RZ] += ti.cast(self._vol(i) * r * z, ti.f64)

    @ti.kernel
    def iterate(self, n: ti.i32, tol: ti.f64, min_it: ti.i32, max_it: ti.i32) -> ti.i32:
        """One iteration of preconditioned conjugate gradients: q = A d, a = r·z / d·q,
        κ += a d (the velocities with it), r −= a q, the stopping rule (``Stopping``, on the
        average and largest |r|), then d = z + (r·z)'/(r·z) d."""
        s = self.s
        h_dt = ti.cast(s.state.dt[None], float)
        dt2 = h_dt * h_dt
        self._product(n, self.d, self.q, dt2)
        self.sc[DQ] = 0.0
        for i in range(n):
            if self.on[i]:
                self.sc[DQ] += ti.cast(self._vol(i) * self.d[i] * self.q[i], ti.f64)
        a = ti.cast(0.0, ti.f64)  # the scalars in f64, as their sums are
        if self.sc[DQ] > 0.0:
            a = self.sc[RZ] / self.sc[DQ]
        step = ti.cast(a, float)
        self._move(n, step, h_dt, self.d)
        self.sc[RZ_NEW] = 0.0
        s.err[None] = 0.0
        self.stop.peak[None] = 0.0
        for i in range(n):
            if self.on[i]:
                r = self.r[i] - step * self.q[i]
                z = s.alpha[i] * r / dt2
                self.r[i] = r
                self.z[i] = z
                self.sc[RZ_NEW] += ti.cast(self._vol(i) * r * z, ti.f64)
                self._measure(i, r)
        self._decide(tol, min_it, max_it)
        beta = ti.cast(0.0, ti.f64)
        if self.sc[RZ] > 0.0:
            beta = self.sc[RZ_NEW] / self.sc[RZ]
        self.sc[RZ] = self.sc[RZ_NEW]
        b = ti.cast(beta, float)
        for i in range(n):
            if self.on[i]:
                self.d[i] = self.z[i] + b * self.d[i]
        return self.stop.state[DONE]

    @ti.kernel
    def finish(self, n: ti.i32):
        """Take back the pulls: the push of every negative κ undone, κ then >= 0."""
        s = self.s
        h_dt = ti.cast(s.state.dt[None], float)
        for i in range(n):
            self.z[i] = ti.min(s.ksum[i], 0.0) if self.on[i] else 0.0
        self._apply(n, self.z, -h_dt, self.pool.p.v)
        for i in range(n):
            s.ksum[i] = ti.max(s.ksum[i], 0.0)
