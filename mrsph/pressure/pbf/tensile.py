"""The tensile correction of position based fluids (Macklin & Müller 2013, §4) and the part of
the pressure it carries.

s_corr,ij = k (W(r_ij) / W(Δq h))^n, in units of the coarsest level's rest-lattice
multiplier, joins the multipliers in each pair's correction, −m_j (δq_i + δq'_j + s_corr) ∇W_ij:
a pair pushed apart as a pressure would push it, most where the pair is closer than a lattice's
spacing, so that a free surface does not clump. One unit on every level, so that it is one
pressure (δq ρ²/dt²) across the levels: in each level's own unit it grows as the spacing
squared, and the coarse side pushed into the fine one at every interface. A wall or obstacle
image pair takes it at the image's distance, as its gradient does.

It carries part of the weight (0.2 % of ρ0 g H at the bottom of a still column 20 particles
deep, more at a level interface), which the multipliers' pressure would leave out of a dump:
the passes tally it per particle as a multiplier, q^t_i, half the mean of i's s_corr weighted by
m_j |∇W_ij| (exact where s_corr is the same for every pair), and a dump reads
p_i + q^t_i ρ_i² / dt².
"""

import numpy as np
import taichi as ti


@ti.data_oriented
class TensileCorrection:
    def __init__(self, core, cfg, knobs, at, den_rest):
        """knobs[at]: ``pbf.artificial_pressure``, read from the solver's field at run time,
        so that changing it compiles nothing; den_rest: D of a rest lattice per level."""
        self.pool, self.levels = core.pool, core.levels
        self.rest_density = core.lev.rest_density
        self.exponent = cfg.artificial_pressure_exponent
        self.knobs, self.at, self.den_rest = knobs, at, den_rest
        self.w_ref = ti.field(float, shape=core.levels)  # (h² − (Δq h)²)³ per level
        for l in range(core.levels):
            h = core.lev.support(l)
            dq = cfg.artificial_pressure_radius * h
            self.w_ref[l] = (h * h - dq * dq) ** 3
        self.qt = ti.field(float, shape=core.pool.capacity)  # the step's corrections, as a multiplier

    @ti.func
    def term(self, i, j, xq, h):
        """s_corr of the pair (0 without one) at its distance: from j to x_i, or to x_i's
        mirror image xq for an image pair."""
        p = ti.static(self.pool.p)
        corr = 0.0
        k = self.knobs[self.at]
        if k > 0.0:
            d = ti.max(h * h - (xq - p[j].x).norm_sqr(), 0.0)
            w = (d * d * d) / self.w_ref[p[i].level]
            unit = self.den_rest[self.levels - 1]  # the coarsest level's, on every level
            corr = k * self.rest_density / unit * ti.pow(w, self.exponent)
        return corr

    @ti.func
    def start(self, i):
        self.qt[i] = 0.0

    @ti.func
    def tally(self, j, g, corr, acc: ti.template(), at: ti.template()):
        """The pair's s_corr and its weight m_j |∇W| into acc[at], acc[at + 1]."""
        wt = self.pool.p[j].m * g.norm()
        acc[at] += corr * wt
        acc[at + 1] += wt

    @ti.func
    def close(self, i, acc: ti.template(), at: ti.template()):
        """Half the pass's weighted mean into i's multiplier."""
        if acc[at + 1] > 0.0:
            self.qt[i] += 0.5 * acc[at] / acc[at + 1]

    def reported(self, p: np.ndarray, rho: np.ndarray, dt: float) -> np.ndarray:
        """p plus the last step's corrections as a pressure, slot by slot (rho: the step's
        last measured densities)."""
        n = len(p)
        qt = self.qt.to_numpy()[:n].astype(np.float64)
        return (p + qt * rho[:n].astype(np.float64) ** 2 / (dt * dt)).astype(p.dtype)

    def forget(self) -> None:
        """The slots hold other particles now (a reset, a restore, a sort outside a step)."""
        self.qt.fill(0.0)
