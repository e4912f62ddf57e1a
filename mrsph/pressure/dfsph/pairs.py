"""What the DFSPH factor pass keeps of each particle's pairs for the step's Jacobi
iterations (``solver.py``), so that each iteration reads them instead of computing a
square root and a division per pair again."""

import taichi as ti

# The mirror-image pairs (a neighbour's image across a wall or the obstacle, or i's own)
# each particle keeps with its factor, m_j ∇W_ij and m_j Lᵀ ∇W_ij, as ``gw`` keeps its
# listed neighbours': every iteration then reads them instead of finding the image's
# candidates and their gradients again, which was a third of a Jacobi sweep in demo_2d
# (0.64 -> 0.38 ms at 6.4k particles with the images left out). A particle near a corner
# with more image pairs than this sums them on the fly.
IMAGE_PAIRS = {2: 32, 3: 64}


@ti.data_oriented
class StoredPairs:
    """What the factor pass keeps of each real particle's pairs for the step's iterations,
    which then read them instead of recomputing a square root and a division per pair
    (SPlisHSPlasH's precomputed values do the same): m_j ∇W_ij of each listed neighbour
    (``gw``), and the mirror-image pairs (``IMAGE_PAIRS`` a particle: j, m_j ∇W_ij and
    m_j Lᵀ ∇W_ij; ``img_n[i]`` their count, IMAGE_PAIRS + 1 when more did not fit)."""

    def __init__(self, pool, dim: int, max_neighbours: int, grad, add_factor):
        """grad and add_factor: the solver's pair gradient and factor sums (``ti.func``)."""
        self.pool, self.max_images, self.dim = pool, IMAGE_PAIRS[dim], dim
        self.grad, self.add_factor = grad, add_factor
        cap = pool.capacity
        self.gw = ti.Vector.field(dim, float, shape=(cap, max_neighbours))
        self.img_j = ti.field(ti.i32, shape=(cap, self.max_images))
        self.img_g = ti.Vector.field(dim, float, shape=(cap, self.max_images))
        self.img_gl = ti.Vector.field(dim, float, shape=(cap, self.max_images))
        self.img_n = ti.field(ti.i32, shape=cap)

    @ti.func
    def listed_pair(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """The factor pass's visit of the q-th listed neighbour (q counted in acc's last
        slot): its part of the factor sums, m_j ∇W_ij kept in ``gw``."""
        ok, g = self.grad(i, j, xq, L, p0, nrm, check, ctx)
        q = ti.cast(acc[self.dim + 1], ti.i32)
        mg = ti.Vector.zero(float, self.dim)
        if ok:
            mg = self.pool.p[j].m * g
            self.add_factor(i, j, mg, g, acc)
        self.gw[i, q] = mg
        acc[self.dim + 1] += 1.0

    @ti.func
    def image_pair(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """The factor pass's visit of an image pair: its part of the factor sums, kept."""
        ok, g = self.grad(i, j, xq, L, p0, nrm, check, ctx)
        if ok:
            mg = self.pool.p[j].m * g
            self.add_factor(i, j, mg, g, acc)
            self.keep_image(i, j, mg, L)

    @ti.func
    def keep_image(self, i, j, mg, L):
        """Image pair j of i (m_j ∇W_ij = mg, the image's reflection L), while it fits."""
        k = self.img_n[i]
        if k < ti.static(self.max_images):
            self.img_j[i, k] = j
            self.img_g[i, k] = mg
            self.img_gl[i, k] = L.transpose() @ mg
        self.img_n[i] = ti.min(k + 1, ti.static(self.max_images + 1))

    @ti.func
    def images_kept(self, i):
        return self.img_n[i] <= ti.static(self.max_images)

    @ti.func
    def image_rate(self, i, rate, vel: ti.template()):
        """``rate`` plus Σ m_j (u_i − L u_j)·∇W_ij = Σ u_i·(m_j ∇W_ij) − u_j·(m_j Lᵀ ∇W_ij)
        over i's kept image pairs, u the velocity field ``vel``."""
        vi = vel[i]
        for k in range(self.img_n[i]):
            rate += vi.dot(self.img_g[i, k]) - vel[self.img_j[i, k]].dot(self.img_gl[i, k])
        return rate
