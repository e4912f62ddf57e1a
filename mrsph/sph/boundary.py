"""Solid boundaries as signed distances (METHOD.md §1, last point).

The domain box and the static obstacles (boxes, spheres — circles in 2D) are analytic
shapes. A particle found inside one is projected back onto its surface along the
distance gradient and loses the velocity component into it (times ``1 + restitution``),
plus a share ``friction`` of its tangential velocity. Nothing here depends on particle
size or spacing, so the same response holds at every resolution level.

A box's face that lies on a wall of the domain (a post standing on the floor) is shut:
a particle inside the box is never projected through it, since that would leave it on
the wall inside the box's footprint, a slot of no width where it sits on its own images
and the pressure crushing it grows without bound (a stirred demo's post filled so).
"""

import numpy as np
import taichi as ti

from mrsph.limits import MAX_OBSTACLES


@ti.data_oriented
class Boundary:
    def __init__(self, dim: int, domain, obstacles):
        """domain: the scene's [domain] params (the box, restitution, friction);
        obstacles: its [[obstacles]] (boxes and spheres)."""
        self.dim = dim
        self.lo = ti.Vector(list(map(float, domain.min)))
        self.hi = ti.Vector(list(map(float, domain.max)))
        self.restitution = domain.restitution
        self.friction = domain.friction
        boxes = [o for o in obstacles if o.shape == "box"]
        spheres = [o for o in obstacles if o.shape == "sphere"]
        # the scene check (scene/config/rules.py) refuses more; one built by hand gets this
        if max(len(boxes), len(spheres)) > MAX_OBSTACLES:
            raise ValueError(
                f"obstacles: {len(boxes)} boxes and {len(spheres)} spheres (expected at most {MAX_OBSTACLES} of each)"
            )
        self.n_boxes, self.n_spheres = len(boxes), len(spheres)
        self.box_c = ti.Vector.field(dim, float, shape=max(1, len(boxes)))
        self.box_half = ti.Vector.field(dim, float, shape=max(1, len(boxes)))
        # per axis, 1 where the box's low (high) face lies on or past the domain's wall
        self.box_shut_lo = ti.Vector.field(dim, int, shape=max(1, len(boxes)))
        self.box_shut_hi = ti.Vector.field(dim, int, shape=max(1, len(boxes)))
        self.sph_c = ti.Vector.field(dim, float, shape=max(1, len(spheres)))
        self.sph_r = ti.field(float, shape=max(1, len(spheres)))
        for i, b in enumerate(boxes):
            lo, hi = np.asarray(b.min, float), np.asarray(b.max, float)
            self.box_c[i] = ((lo + hi) / 2).tolist()
            self.box_half[i] = ((hi - lo) / 2).tolist()
            shut_lo, shut_hi = shut_faces(lo, hi, np.asarray(domain.min, float), np.asarray(domain.max, float))
            self.box_shut_lo[i] = shut_lo.tolist()
            self.box_shut_hi[i] = shut_hi.tolist()
        for i, s in enumerate(spheres):
            self.sph_c[i] = list(map(float, s.center))
            self.sph_r[i] = s.radius

    @ti.func
    def domain_image(self, x, h, mask):
        """(valid, mirrored x, linear part as ±1 per axis) for the set of axes ``mask``."""
        valid = True
        xr = x
        sign = ti.Vector.one(float, self.dim)
        for k in ti.static(range(self.dim)):
            if (mask >> k) & 1:
                if x[k] - self.lo[k] < h:
                    xr[k] = 2.0 * self.lo[k] - x[k]
                    sign[k] = -1.0
                elif self.hi[k] - x[k] < h:
                    xr[k] = 2.0 * self.hi[k] - x[k]
                    sign[k] = -1.0
                else:
                    valid = False
        return valid, xr, sign

    @ti.func
    def obstacle_image(self, x, h):
        """(valid, mirrored x, unit normal) across the nearest obstacle's tangent plane."""
        phi, n = self.obstacle_sdf(x)
        return phi < h, x - 2.0 * phi * n, n

    @ti.func
    def corner_image(self, x, h, mask, p0, nrm):
        """(valid, image, linear part of the wall mirror as ±1 per axis): x mirrored across
        the walls of ``mask`` (none for mask 0), then across the obstacle's tangent plane
        (p0, nrm). Valid for mask 0, and where that plane meets each of those walls at a
        right angle (a box standing on the floor): the two mirrors then commute, and their
        image fills the corner's quadrant, which neither mirror alone reaches."""
        valid, xr, sign = self.domain_image(x, h, mask)
        for k in ti.static(range(self.dim)):
            if (mask >> k) & 1 and ti.abs(nrm[k]) > 1e-6:
                valid = False
        return valid, xr - 2.0 * (xr - p0).dot(nrm) * nrm, sign

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
                # inside: the nearest open face, over the axes the largest (least negative)
                # distance; an axis whose nearer face is shut offers its far face
                dist = -1e30
                for k in ti.static(range(self.dim)):
                    side = 1 if d[k] >= 0.0 else -1
                    qk = q[k]
                    if (self.box_shut_hi[b][k] if side > 0 else self.box_shut_lo[b][k]) == 1:
                        side = -side
                        qk = -1e30
                        if (self.box_shut_hi[b][k] if side > 0 else self.box_shut_lo[b][k]) == 0:
                            qk = -(self.box_half[b][k] + ti.abs(d[k]))
                    if qk > dist:
                        dist = qk
                        n = ti.Vector.zero(float, self.dim)
                        n[k] = float(side)
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
        """Project (x, v) back into the domain box, then out of the obstacles. In that
        order: a step that crosses the floor beneath a post lands on the floor inside the
        post, which then pushes it out by a side; the other way round, the post (seen from
        below the floor) let it be, and the floor kept it in the post's footprint."""
        e, mu = self.restitution, self.friction
        for k in ti.static(range(self.dim)):
            if x[k] < self.lo[k] or x[k] > self.hi[k]:
                x[k] = ti.min(ti.max(x[k], self.lo[k]), self.hi[k])
                inward = 1.0 if x[k] <= self.lo[k] else -1.0
                if v[k] * inward < 0.0:
                    for j in ti.static(range(self.dim)):
                        if j != k:
                            v[j] *= 1.0 - mu
                    v[k] = -e * v[k]
        phi, n = self.obstacle_sdf(x)
        if phi < 0.0:
            x -= phi * n
            vn = v.dot(n)
            if vn < 0.0:
                vt = v - vn * n
                v = vt * (1.0 - mu) - e * vn * n
            # a box leaves by a face inside the domain; a sphere through a wall may not
            x = ti.min(ti.max(x, self.lo), self.hi)
        return x, v


def shut_faces(lo, hi, domain_lo, domain_hi):
    """Per axis, whether a box's low and high faces lie on or past the domain's walls (as
    int arrays, 1 shut). A box that reaches every wall keeps its faces open: shut, it
    would have no face to leave by."""
    tol = 1e-6 * (domain_hi - domain_lo)
    shut_lo = (lo <= domain_lo + tol).astype(int)
    shut_hi = (hi >= domain_hi - tol).astype(int)
    if np.all(shut_lo & shut_hi):
        shut_lo[:] = shut_hi[:] = 0
    return shut_lo, shut_hi
