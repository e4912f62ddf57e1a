"""Per-level constants (METHOD.md §1–2): one object that every pass reads.

Level l has support h_l = 2^l h0, spacing s_l = 2^l s0 and nominal mass m_l = 2^(d l) m0,
so the density is the same at every level. The kernel constants are taken once per level
here, so that no inner loop takes a power. s/h is the same at every level, so one lattice
calibration of the spiky gradient (``kernels.lattice_gradient_factor``) serves them all.
"""

import math

import taichi as ti

from .kernels import constants, lattice_density_sum, lattice_gradient_factor

# A transient parent's virtual children lie within sqrt(d)/2 fine spacings of it and reach
# one fine support beyond; measured with a uniform-pressure probe (no gravity, a refined
# box inside a block), factors >= 1.2 leave transient children balanced to 0.1 % of
# p/(rho s), smaller ones double-count groups near the parent. 1.5 keeps a margin.
REACH_FACTOR = 1.5


@ti.data_oriented
class Levels:
    """h, s, m and the kernel constants of each level, as fields (read in kernels) and as
    host numbers (``h0``, ``s0``, ``m0``)."""

    def __init__(
        self, dim: int, count: int, spacing: float, support: float, rest_density: float, symmetric_coupling: bool
    ):
        self.dim, self.count = dim, count
        self.rest_density = float(rest_density)  # ρ0, which every level's mass reproduces
        self.s0 = float(spacing)
        self.h0 = float(support) * self.s0
        self.m0 = rest_density / lattice_density_sum(self.s0, self.h0, dim)
        self.grad_factor = lattice_gradient_factor(self.s0, self.h0, dim)
        self.h = ti.field(float, shape=count)
        self.s = ti.field(float, shape=count)
        self.m = ti.field(float, shape=count)
        self.poly6 = ti.field(float, shape=count)
        self.spiky = ti.field(float, shape=count)  # divided by the lattice calibration
        self.visc = ti.field(float, shape=count)
        # squared distance within which a transient parent of level l meets a virtual
        # parent's children through its own virtual children (symmetric coupling only,
        # see ``multires.coupling.Symmetric``); 0 elsewhere
        self.reach2 = ti.field(float, shape=count)
        for l in range(count):
            h = self.h0 * 2**l
            c = constants(h, dim)
            self.h[l], self.s[l] = h, self.s0 * 2**l
            self.m[l] = self.m0 * 2 ** (dim * l)
            self.poly6[l], self.visc[l] = c["poly6"], c["visc"]
            self.spiky[l] = c["spiky"] / self.grad_factor
            if l > 0 and symmetric_coupling:
                fine_h, fine_s = self.h0 * 2 ** (l - 1), self.s0 * 2 ** (l - 1)
                self.reach2[l] = (REACH_FACTOR * (fine_h + 0.5 * math.sqrt(dim) * fine_s)) ** 2

    def spacing(self, l: int) -> float:
        return self.s0 * 2**l

    def support(self, l: int) -> float:
        return self.h0 * 2**l
