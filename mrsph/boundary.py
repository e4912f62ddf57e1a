"""Solid boundaries as signed distances (METHOD.md §1, last point).

The domain box and the static obstacles (boxes, spheres — circles in 2D) are analytic
shapes. A particle found inside one is projected back onto its surface along the
distance gradient and loses the velocity component into it (times ``1 + restitution``),
plus a share ``friction`` of its tangential velocity. Nothing here depends on particle
size or spacing, so the same response holds at every resolution level.
"""

import numpy as np
import taichi as ti

from .kernels import constants

MAX_SHAPES = 32   # obstacles of each shape; plenty for hand-written scenes
TABLE_SIZE = 128  # samples of the wall integrals over q = distance / h in [0, 1]


def wall_tables(dim: int, size: int = TABLE_SIZE, res: int = 800):
    """Half-space integrals of the kernels for a wall at distance q·h (h = 1).

    vol[q]  = ∫_{y < −q} W_poly6 dV: the share of a particle's density that the solid
              would supply if it were fluid at rest density (no density deficit at walls);
    grad[q] = ∫_{y < −q} |∂W_spiky/∂y| dV: the matching pressure-gradient integral.
    Both are dimensionless functions of q alone, so the same wall acts the same way on
    every resolution level (the wall integrals scale as h⁰ and h⁻¹ respectively).
    """
    c = constants(1.0, dim)
    # (x, y) quadrature over the lower half of the unit disc; in 3D x is the radius of a
    # ring of circumference 2πx around the y axis.
    xs = (np.arange(res) + 0.5) / res * (1.0 if dim == 3 else 2.0) - (0.0 if dim == 3 else 1.0)
    ys = -(np.arange(res) + 0.5) / res
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    R = np.sqrt(X * X + Y * Y)
    dA = (xs[1] - xs[0]) * (ys[0] - ys[1])
    weight = dA * (2.0 * np.pi * X if dim == 3 else np.ones_like(X))
    inside = R < 1.0
    w_poly6 = np.where(inside, c["poly6"] * (1.0 - R * R) ** 3, 0.0) * weight
    dw = np.where(inside, 3.0 * c["spiky"] * (1.0 - R) ** 2 * np.abs(Y) / np.maximum(R, 1e-12), 0.0) * weight
    qs = np.linspace(0.0, 1.0, size)
    vol = np.array([w_poly6[Y < -q].sum() for q in qs])
    grad = np.array([dw[Y < -q].sum() for q in qs])
    return vol, grad


@ti.data_oriented
class Boundary:
    def __init__(self, dim: int, domain_min, domain_max, obstacles, restitution: float, friction: float):
        self.dim = dim
        self.lo = ti.Vector(list(map(float, domain_min)))
        self.hi = ti.Vector(list(map(float, domain_max)))
        self.restitution = restitution
        self.friction = friction
        boxes = [o for o in obstacles if o["shape"] == "box"]
        spheres = [o for o in obstacles if o["shape"] == "sphere"]
        if len(boxes) > MAX_SHAPES or len(spheres) > MAX_SHAPES:
            raise ValueError(f"obstacles: at most {MAX_SHAPES} boxes and {MAX_SHAPES} spheres")
        self.n_boxes, self.n_spheres = len(boxes), len(spheres)
        self.box_c = ti.Vector.field(dim, float, shape=max(1, len(boxes)))
        self.box_half = ti.Vector.field(dim, float, shape=max(1, len(boxes)))
        self.sph_c = ti.Vector.field(dim, float, shape=max(1, len(spheres)))
        self.sph_r = ti.field(float, shape=max(1, len(spheres)))
        for i, b in enumerate(boxes):
            lo, hi = np.asarray(b["min"], float), np.asarray(b["max"], float)
            self.box_c[i] = ((lo + hi) / 2).tolist()
            self.box_half[i] = ((hi - lo) / 2).tolist()
        for i, s in enumerate(spheres):
            self.sph_c[i] = list(map(float, s["center"]))
            self.sph_r[i] = float(s["radius"])
        vol, grad = wall_tables(dim)
        self.wall_vol = ti.field(float, shape=TABLE_SIZE)
        self.wall_grad = ti.field(float, shape=TABLE_SIZE)
        self.wall_vol.from_numpy(vol)
        self.wall_grad.from_numpy(grad.astype(vol.dtype))

    @ti.func
    def _table(self, table: ti.template(), q):
        t = ti.min(ti.max(q, 0.0), 1.0) * (TABLE_SIZE - 1)
        k = ti.min(ti.cast(t, ti.i32), TABLE_SIZE - 2)
        a = t - k
        return (1.0 - a) * table[k] + a * table[k + 1]

    @ti.func
    def nearest_surface(self, x):
        """Distance to the nearest solid surface (domain wall or obstacle) and the normal
        pointing from the solid into the fluid."""
        best = 1e30
        normal = ti.Vector.zero(float, self.dim)
        for k in ti.static(range(self.dim)):
            for side in ti.static((0, 1)):
                d = x[k] - self.lo[k] if side == 0 else self.hi[k] - x[k]
                if d < best:
                    best = d
                    normal = ti.Vector.zero(float, self.dim)
                    normal[k] = 1.0 if side == 0 else -1.0
        phi, n = self.obstacle_sdf(x)
        if phi < best:
            best = phi
            normal = n
        return best, normal

    @ti.func
    def wall_terms(self, x, h):
        """(share of rest density supplied by the solid, wall-gradient integral · normal / h).

        Only the nearest surface counts: summing two walls would count the solid quadrant
        of a corner twice, and an over-estimated density pushes fluid out of corners,
        whereas an under-estimate only lets corner particles sit slightly closer.
        """
        vol = 0.0
        grad = ti.Vector.zero(float, self.dim)
        d, n = self.nearest_surface(x)
        if d < h:
            q = ti.max(d, 0.0) / h
            vol = self._table(self.wall_vol, q)
            grad = self._table(self.wall_grad, q) / h * n
        return vol, grad

    @ti.func
    def obstacle_sdf(self, x):
        """Signed distance to the nearest obstacle (positive outside) and its outward normal."""
        best = 1e30
        normal = ti.Vector.zero(float, self.dim)
        for b in range(self.n_boxes):
            d = x - self.box_c[b]
            q = ti.abs(d) - self.box_half[b]
            outside = ti.max(q, 0.0)
            out_len = outside.norm()
            dist = out_len
            n = ti.Vector.zero(float, self.dim)
            if out_len > 0.0:
                n = outside * ti.math.sign(d) / out_len
            else:
                # inside: the nearest face is the axis with the largest (least negative) q
                axis = 0
                for k in ti.static(range(1, self.dim)):
                    if q[k] > q[axis]:
                        axis = k
                dist = q[axis]
                for k in ti.static(range(self.dim)):
                    if k == axis:
                        n[k] = 1.0 if d[k] >= 0.0 else -1.0
            if dist < best:
                best = dist
                normal = n
        for s in range(self.n_spheres):
            d = x - self.sph_c[s]
            r = d.norm()
            dist = r - self.sph_r[s]
            if dist < best:
                best = dist
                n = ti.Vector.zero(float, self.dim)
                n[1] = 1.0
                if r > 1e-12:
                    n = d / r
                normal = n
        return best, normal

    @ti.func
    def collide(self, x, v):
        """Project (x, v) out of obstacles and back into the domain box."""
        e, mu = self.restitution, self.friction
        phi, n = self.obstacle_sdf(x)
        if phi < 0.0:
            x -= phi * n
            vn = v.dot(n)
            if vn < 0.0:
                vt = v - vn * n
                v = vt * (1.0 - mu) - e * vn * n
        for k in ti.static(range(self.dim)):
            if x[k] < self.lo[k] or x[k] > self.hi[k]:
                x[k] = ti.min(ti.max(x[k], self.lo[k]), self.hi[k])
                inward = 1.0 if x[k] <= self.lo[k] else -1.0
                if v[k] * inward < 0.0:
                    for j in ti.static(range(self.dim)):
                        if j != k:
                            v[j] *= 1.0 - mu
                    v[k] = -e * v[k]
        return x, v
