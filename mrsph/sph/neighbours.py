"""The one neighbour visitor: same-level candidates and the wall and obstacle images.

Every pass that sums over a particle's neighbourhood (forces, the level coupling, the
pressure solvers) visits it through this object; the density pass writes the lists it
reads (below), and the adaptivity's searches for particles of a kind near a point (a
split child's push, the fade's re-measure, the limiter's and the merge's scans) walk the
grid block (``Grids.around`` and ``row``) as ``grid_candidates`` does, without images:

- ``candidates(i, xq, …, l, listed, with_self, visit, acc)`` calls ``visit(i, j, …, ctx, acc)`` for each
  candidate j near the point xq at level l: i's neighbour list (``listed``; i itself first
  with ``with_self``, as an image of x_i sees i), or the rows of the grid block around xq.
  The visit tests the distance; a list holds every particle within h of x_i, which is
  every particle within h of a mirror image of x_i across the domain walls (mirroring
  only moves a point on the fluid side away from the others on that side).
- ``images(i, h, visit, acc)`` calls ``visit(i, xq, L, p0, nrm, check, ctx, acc)`` for each wall
  image of x_i within h of a wall (xq the image, L the reflection's linear part, so that
  x_i − x_j' = L (xq − x_j) and u_j' = L u_j) and for its obstacle image (``check`` true:
  only particles whose own image lies inside the obstacle count, ``image_in_solid``), and
  where the obstacle meets a wall at a right angle, the wall's image of the obstacle's.

The density, force and coupling passes keep one partial sum per image (the image's visit
sums its candidates and adds the result), so that sums are grouped as the method writes
them: own level, then each image. The implicit pressure solver, which needs no partial
sums, visits its own level with ``listed_candidates`` or ``grid_candidates`` and then its
images, into one sum.
The lists are written by the density pass (``density.py``), which is the only place that
scans the grid for the whole pool; a particle with more neighbours than a list holds (a
fluid compressed ~3×) falls back to the grid everywhere (``is_listed``).

With a skin (``particles.skin``) each particle also has a skin list (``near``: every
particle of its level within (1 + skin) h when it was built, ``grid.py`` says when), and
the density pass writes each step's lists from it instead of scanning the grid: a
particle that is within h now was within (1 + skin) h then, both having moved at most
skin h / 2. So every reader sees the same lists, within h, whatever the skin.
"""

import taichi as ti

from mrsph.limits import MAX_NEIGHBOURS, skin_list_length  # the lists' lengths, which bound the pool


@ti.data_oriented
class Neighbours:
    def __init__(self, dim: int, pool, grids, boundary):
        self.dim = dim
        self.pool, self.grids, self.boundary = pool, grids, boundary
        self.max_neighbours = MAX_NEIGHBOURS[dim]
        # neighbour lists (same level, r < h, self excluded), filled by the density pass
        # and read by the force and coupling passes, which then visit ~13 (2D) / ~33 (3D)
        # neighbours instead of the ~36 / ~125 candidates of the grid block. One spare
        # slot: the density pass writes every candidate and keeps the neighbours.
        self.lists = ti.field(ti.i32, shape=(pool.capacity, self.max_neighbours + 1))
        self.count = ti.field(ti.i32, shape=pool.capacity)
        # the skin lists (same level, r < (1 + skin) h at their build, self excluded), as
        # long as the lists scaled by the ball's volume; one spare slot, as above
        self.skin = grids.skin
        self.max_near = skin_list_length(dim, self.skin, self.max_neighbours)
        if self.skin > 0.0:
            self.near = ti.field(ti.i32, shape=(pool.capacity, self.max_near + 1))
            self.near_count = ti.field(ti.i32, shape=pool.capacity)

    @ti.func
    def is_near_listed(self, i):
        """Does i's skin list hold every particle within (1 + skin) h of its build?"""
        return self.near_count[i] <= ti.static(self.max_near)

    @ti.func
    def is_listed(self, i):
        """Does i's list hold all its neighbours (else it overflowed: use the grid)?"""
        return self.count[i] <= ti.static(self.max_neighbours)

    @ti.func
    def candidates(
        self,
        i,
        xq,
        L,
        p0,
        nrm,
        check: ti.template(),
        l,
        listed,
        with_self: ti.template(),
        visit: ti.template(),
        ctx: ti.template(),
        acc: ti.template(),
    ):
        """``visit(i, j, xq, L, p0, nrm, check, ctx, acc)`` for each candidate j of level l
        near xq (x_i or one of its images, with the image's context, see ``images``): i's
        list when ``listed`` (i itself first with ``with_self``), else the grid block's
        rows; always the grid for an obstacle image (``check``), whose neighbours are not
        i's. ``ctx``: the pass's constants for particle i (a local vector, read only);
        ``acc``: what the visit adds to."""
        if ti.static(check):
            self.grid_candidates(i, xq, L, p0, nrm, check, l, visit, ctx, acc)
        elif listed:
            self.listed_candidates(i, xq, L, p0, nrm, check, with_self, visit, ctx, acc)
        else:
            self.grid_candidates(i, xq, L, p0, nrm, check, l, visit, ctx, acc)

    # The two halves of ``candidates``, for a pass that knows which one it needs: every
    # copy of a visit inlined into a kernel costs compile time (about a second each for
    # the implicit solver's, docs/performance.md).
    @ti.func
    def listed_candidates(
        self,
        i,
        xq,
        L,
        p0,
        nrm,
        check: ti.template(),
        with_self: ti.template(),
        visit: ti.template(),
        ctx: ti.template(),
        acc: ti.template(),
    ):
        if ti.static(with_self):
            visit(i, i, xq, L, p0, nrm, check, ctx, acc)
        for q in range(self.count[i]):
            visit(i, self.lists[i, q], xq, L, p0, nrm, check, ctx, acc)

    @ti.func
    def grid_candidates(
        self, i, xq, L, p0, nrm, check: ti.template(), l, visit: ti.template(), ctx: ti.template(), acc: ti.template()
    ):
        base = self.grids.around(xq, l)
        for o in ti.grouped(ti.ndrange(*self.grids.row_axes)):
            lo, hi = self.grids.row(base, o, l)
            for j in range(lo, hi):
                visit(i, j, xq, L, p0, nrm, check, ctx, acc)

    @ti.func
    def images(self, i, h, visit: ti.template(), ctx: ti.template(), acc: ti.template()):
        """``visit(i, xq, L, p0, nrm, check, ctx, acc)`` for each wall image xq of x_i within h
        of its walls (``check`` False) and for its obstacle image (``check`` True, p0 and
        nrm the obstacle's tangent plane)."""
        xi = self.pool.p[i].x
        for mask in range(1, 2**self.dim):
            ok, xr, sgn = self.boundary.domain_image(xi, h, mask)
            if ok:
                Ld = ti.Matrix.zero(float, self.dim, self.dim)
                for k in ti.static(range(self.dim)):
                    Ld[k, k] = sgn[k]
                visit(i, xr, Ld, xi, xi, False, ctx, acc)
        ok, xo, nrm = self.boundary.obstacle_image(xi, h)
        if ok:
            Lo = ti.Matrix.identity(float, self.dim) - 2.0 * nrm.outer_product(nrm)
            p0 = 0.5 * (xi + xo)
            # mask 0: the obstacle's image; the others: a wall's image of it where the two
            # meet at a right angle (without, a particle in the corner of a box on the
            # floor read 3-4 % light). One visit in a loop: each inlined copy costs compile time
            for mask in range(2**self.dim):
                okc, xq, sgn = self.boundary.corner_image(xi, h, mask, p0, nrm)
                if okc:
                    Lc = ti.Matrix.zero(float, self.dim, self.dim)
                    for k in ti.static(range(self.dim)):
                        Lc[k, k] = sgn[k]
                    visit(i, xq, Lc @ Lo, p0, nrm, True, ctx, acc)

    @ti.func
    def image_normal(self, x, L, nrm, check: ti.template()):
        """The unit normal into the fluid of the wall(s) an image of x reflects across: the
        obstacle's normal ``nrm`` (``check``), or the sum of the domain walls' inward axes
        (where L[k, k] = −1: the nearer of lo and hi on that axis)."""
        n = nrm
        if ti.static(not check):
            n = ti.Vector.zero(float, self.dim)
            for k in ti.static(range(self.dim)):
                if L[k, k] < 0.0:
                    n[k] = 1.0 if x[k] - self.boundary.lo[k] < self.boundary.hi[k] - x[k] else -1.0
            n = n.normalized()
        return n

    @ti.func
    def image_in_solid(self, xj, p0, nrm):
        """Is x_j's mirror image across the plane (p0, nrm) inside an obstacle? Near a
        convex corner the tangent-plane mirror puts some images back in the fluid; those
        must not count, or the corner pushes fluid away."""
        img = xj - 2.0 * (xj - p0).dot(nrm) * nrm
        phi, _n = self.boundary.obstacle_sdf(img)
        return phi < 0.0


@ti.data_oriented
class ImageNeighbours:
    """An image visit (for ``Neighbours.images``) that visits the image's candidates with
    the pair visit ``pair``: i and i's list for a domain-wall image of a listed particle
    (its list holds everything within h of such an image), else the grid around it."""

    def __init__(self, neighbours: Neighbours, pair):
        self.nb, self.pair = neighbours, pair

    @ti.func
    def visit(self, i, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        self.nb.candidates(
            i, xq, L, p0, nrm, check, self.nb.pool.p[i].level, self.nb.is_listed(i), True, self.pair, ctx, acc
        )
