"""Emitters (scene ``[[emitters]]``): inflow through a disc (a segment in 2D), one layer of
its level's lattice every s/|U| seconds, and a nozzle that holds the fluid it contains at
the inflow velocity (METHOD.md §1, Eq. 21: the inflow's external force).
"""

import numpy as np
import taichi as ti

from mrsph.sph.particles import is_real

from .config import emitter_disc


@ti.data_oriented
class Emitters:
    def __init__(self, core, emitters, seeder):
        """emitters: the scene's [[emitters]] params; seeder: places their layers."""
        d, L = core.dim, core.levels
        self.specs = emitters
        self.levels, self.pool, self.seeder = L, core.pool, seeder
        s0, h0 = core.lev.s0, core.lev.h0
        # the nozzles (see ``hold``): centre, unit normal, velocity, radius and
        # half-length of each, and whether it emits this step
        ne = max(len(self.specs), 1)
        self.nozzle_c = ti.Vector.field(d, float, shape=ne)
        self.nozzle_n = ti.Vector.field(d, float, shape=ne)
        self.nozzle_u = ti.Vector.field(d, float, shape=ne)
        self.nozzle_r = ti.field(float, shape=ne)
        self.nozzle_len = ti.field(float, shape=ne)
        self.nozzle_on = ti.field(ti.i32, shape=ne)
        self.s0 = s0
        for e_idx, e in enumerate(self.specs):
            vel = np.asarray(e.velocity, np.float64)
            level = min(e.level, L - 1)
            self.nozzle_c[e_idx] = list(map(float, e.center))
            self.nozzle_n[e_idx] = (vel / np.linalg.norm(vel)).tolist()
            self.nozzle_u[e_idx] = vel.tolist()
            self.nozzle_r[e_idx] = e.radius + 0.5 * s0 * 2**level
            self.nozzle_len[e_idx] = h0 * 2**level
        self.reset()

    def reset(self) -> None:
        self.on = [False] * len(self.specs)
        self.nozzle_on.fill(0)
        self.progress = [0.0] * len(self.specs)  # distance flowed since the last layer

    def any_on(self) -> bool:
        return any(self.on)

    def emit(self, time: float, dt: float) -> bool:
        """Place the layers due for a step of ``dt`` at ``time``; returns
        whether the pool refused some (the caller warns)."""
        refused = False
        for e_idx, e in enumerate(self.specs):
            on = bool(e.start <= time < e.stop)
            if on != self.on[e_idx]:
                self.on[e_idx] = on
                self.nozzle_on[e_idx] = int(on)
            if not on:
                continue
            vel = np.asarray(e.velocity, np.float64)
            speed = float(np.linalg.norm(vel))
            level = min(e.level, self.levels - 1)
            s = self.s0 * 2**level
            self.progress[e_idx] += speed * dt
            while self.progress[e_idx] >= s:
                self.progress[e_idx] -= s
                normal = vel / speed
                xs = emitter_disc(e.center, e.radius, normal, s) + self.progress[e_idx] * normal
                took = self.seeder.append(xs, np.tile(vel, (len(xs), 1)), level)
                refused |= took < len(xs)
        return refused

    @ti.kernel
    def hold(self, count: ti.i32):
        """The nozzles: every real particle within one support (of the emitted level) of
        an emitting disc, ahead of it or behind, and within its radius (plus half a
        spacing), leaves the step at the emitter's velocity.

        Why: an emitter places a layer of its disc every s / |U| seconds whatever the fluid
        ahead does. Without a nozzle a layer that pressure slowed was caught up by the next
        one, which landed closer, was slowed more and pushed back: a free jet was thrown
        back out of its outlet, and a hose turned sideways sprayed a tenth of its fluid
        behind its disc (docs/performance.md keeps the figures). The nozzle holds the fluid
        it contains at the inflow velocity, as the pipe of a real hose does."""
        p = ti.static(self.pool.p)
        for i in range(self.pool.n[None]):
            if is_real(p[i].kind):
                for e in range(count):
                    if self.nozzle_on[e]:
                        d = p[i].x - self.nozzle_c[e]
                        along = d.dot(self.nozzle_n[e])
                        if (
                            ti.abs(along) < self.nozzle_len[e]
                            and (d - along * self.nozzle_n[e]).norm() <= self.nozzle_r[e]
                        ):
                            p[i].v = self.nozzle_u[e]
