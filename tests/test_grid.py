"""Neighbour grids (mrsph/sph/grid.py) against brute force, and the counting sort's bookkeeping.

A pool with particles of two levels is sorted by ``LevelGrids.sort``; a small Taichi
kernel then enumerates, for every particle, the candidates of the grid block around its
own cell on its level (the rows ``around``/``row`` give the solver: 3^d cells of h_l,
5^d of h_l/2, or the solver's own cells, h_l across and h_l/k along the rows) and keeps
those closer than h_l. The lists must be exactly the
brute-force neighbour sets (same level, |x_i - x_j| < h_l), computed with a k-d tree.
"""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from mrsph.sph.particles import DEAD, REGULAR, TRANSIENT_CHILD, VIRTUAL_CHILD, VIRTUAL_PARENT

pytestmark = pytest.mark.usefixtures("taichi_f32")

LEVELS = 2
H0 = 0.1
DOMAIN_MIN = -0.3  # not at the origin, so that a missing origin shift shows
DOMAIN_MAX = 0.7
MAX_NEIGHBOURS = 160
# Pairs whose distance is within this fraction of h of the cut-off may be decided
# either way by single-precision round-off; they are counted and excluded.
BORDERLINE = 1e-5


# Pools and grids built by ``build(..., reuse=True)``, by (dim, cells per support, sort
# form): a test refills one instead of building its own. Building is most of a grid
# test's time (Taichi builds and compiles a new object's kernels, ~3.5 s), and the sort
# must find any contents anyway: a Simulation sorts the same pool every step. Each entry
# holds the Taichi program it was built in, and is built again in another.
_BUILT: dict = {}
REUSED_CAPACITY = {2: 2048, 3: 5120}  # slots: every reused test's particles fit


def _program():
    import taichi as ti

    return ti.lang.impl.get_runtime().prog


def build(dim, xs, levels, kinds=None, extra_capacity=8, cells_per_support=1, parallel=False, reuse=False, skin=0.0):
    """A ParticlePool and LevelGrids holding the given particles (ids stored in ``slot``);
    ``parallel``: the sort's GPU form (atomic ranks, three-tier prefix sum), run here on
    the CPU. ``reuse``: refill the pool and grids that an earlier test of this module
    built with the same dim, cells, sort form and skin (``_BUILT``), their next sort a
    full one. ``skin``: cells of (1 + skin) h_l / k."""
    from mrsph.sph.grid import LevelGrids
    from mrsph.sph.particles import ParticlePool

    def new(capacity):
        pool = ParticlePool(dim, capacity)
        return (
            pool,
            LevelGrids(
                dim,
                LEVELS,
                [DOMAIN_MIN] * dim,
                [DOMAIN_MAX] * dim,
                H0,
                pool.capacity,
                cells_per_support,
                parallel,
                skin,
            ),
            _program(),
        )

    n = len(xs)
    if not reuse:
        pool, grids, _ = new(n + extra_capacity)
    else:
        key = (dim, cells_per_support, parallel, skin)
        if key not in _BUILT or _BUILT[key][2] is not _program() or _BUILT[key][0].capacity < n + extra_capacity:
            _BUILT[key] = new(max(n + extra_capacity, REUSED_CAPACITY[dim]))
        pool, grids, _ = _BUILT[key]
        grids.sorted_n[None] = -1  # as a new grid: no sort to skip
    cap = pool.capacity  # rounded up to an odd multiple of 16 (storage_slots)
    pad = lambda a, fill: np.concatenate([a, np.full((cap - n,) + a.shape[1:], fill, a.dtype)])  # noqa: E731
    pool.p.x.from_numpy(pad(xs.astype(np.float32), 0.0))
    pool.p.v.from_numpy(pad((xs * 3.0 + 1.0).astype(np.float32), 0.0))
    pool.p.m.from_numpy(pad(np.arange(n, dtype=np.float32) + 0.5, 0.0))
    pool.p.level.from_numpy(pad(levels.astype(np.int32), 0))
    pool.p.kind.from_numpy(pad(np.full(n, REGULAR, np.int32) if kinds is None else kinds.astype(np.int32), DEAD))
    pool.p.slot.from_numpy(pad(np.arange(n, dtype=np.int32), -1))
    pool.p.parent.from_numpy(np.full(cap, -1, np.int32))
    pool.p.nchild.from_numpy(np.zeros(cap, np.int32))
    pool.n[None] = n
    return pool, grids


_SEARCHES: dict = {}  # id(grids) -> (grids, its program, search kernel, the kernel's fields)


def _search_of(pool, grids):
    """The test's own neighbour search over ``grids`` (built once a pool and grids)."""
    import taichi as ti

    known = _SEARCHES.get(id(grids))
    if known is not None and known[0] is grids and known[1] is _program():
        return known[2], known[3]
    cap = pool.capacity
    cnt = ti.field(ti.i32, shape=cap)
    nb = ti.field(ti.i32, shape=(cap, MAX_NEIGHBOURS))
    overflow = ti.field(ti.i32, shape=())
    wrong_level = ti.field(ti.i32, shape=())
    h = ti.field(float, shape=LEVELS)
    for l in range(LEVELS):
        h[l] = H0 * 2**l

    @ti.kernel
    def search(pool: ti.template(), grids: ti.template(), n: ti.i32):
        p = ti.static(pool.p)
        for i in range(n):
            c = 0
            l = p[i].level
            hl = h[l]
            base = grids.around(p[i].x, l)
            for o in ti.grouped(ti.ndrange(*grids.row_axes)):
                lo, hi = grids.row(base, o, l)
                for j in range(lo, hi):
                    if p[j].level != l:
                        wrong_level[None] += 1
                    # deliberately no level filter: the grid alone must keep levels apart
                    if j != i and (p[i].x - p[j].x).norm_sqr() < hl * hl:
                        if c < MAX_NEIGHBOURS:
                            nb[i, c] = p[j].slot
                        else:
                            overflow[None] += 1
                        c += 1
            cnt[i] = c

    _SEARCHES[id(grids)] = (grids, _program(), search, (cnt, nb, overflow, wrong_level))
    return search, (cnt, nb, overflow, wrong_level)


def grid_neighbours(pool, grids, n):
    """For each sorted slot, the ids (slot) of the particles the grid finds within h_l."""
    search, (cnt, nb, overflow, wrong_level) = _search_of(pool, grids)
    overflow[None] = 0
    wrong_level[None] = 0
    search(pool, grids, n)
    assert overflow[None] == 0, f"test kernel: more than {MAX_NEIGHBOURS} neighbours ({overflow[None]} dropped)"
    assert wrong_level[None] == 0, (
        f"{wrong_level[None]} candidates of another level found in the cells of a level's grid"
    )
    ids = pool.p.slot.to_numpy()[:n]
    counts = cnt.to_numpy()
    lists = nb.to_numpy()
    return {int(ids[i]): set(lists[i, : counts[i]].tolist()) for i in range(n)}


def brute_force(xs, levels):
    """Same-level pairs closer than h_l, and the pairs too close to the cut-off to call."""
    xs = xs.astype(np.float32).astype(np.float64)  # what the pool holds
    sets = {i: set() for i in range(len(xs))}
    borderline = set()
    for l in range(LEVELS):
        h = H0 * 2**l
        idx = np.flatnonzero(levels == l)
        tree = cKDTree(xs[idx])
        for a, b in tree.query_pairs(h * (1 + BORDERLINE)):
            i, j = int(idx[a]), int(idx[b])
            r = np.linalg.norm(xs[i] - xs[j])
            if r >= h * (1 - BORDERLINE):
                borderline.update({(i, j), (j, i)})
            else:
                sets[i].add(j)
                sets[j].add(i)
    return sets, borderline


def compare(found, expected, borderline, label):
    assert set(found) == set(expected), f"{label}: the sort lost or invented particles"
    bad = []
    for i in expected:
        fi = {j for j in found[i] if (i, j) not in borderline}
        if fi != expected[i]:
            bad.append((i, sorted(expected[i] - fi), sorted(fi - expected[i])))
    assert not bad, f"{label}: {len(bad)} particle(s) with wrong neighbour sets; first (id, missed, extra): {bad[:3]}"
    total = sum(len(s) for s in expected.values())
    assert total > 4 * len(expected), f"{label}: only {total} neighbour pairs; the test would prove little"
    assert len(borderline) <= 0.001 * total, f"{label}: {len(borderline)} borderline pairs of {total}"


def random_positions(rng, dim, n):
    return rng.uniform(DOMAIN_MIN, DOMAIN_MAX, size=(n, dim))


def jittered_lattice(rng, dim, spacing):
    ax = np.arange(DOMAIN_MIN + 0.5 * spacing, DOMAIN_MAX, spacing)
    pts = np.stack(np.meshgrid(*([ax] * dim), indexing="ij"), -1).reshape(-1, dim)
    return pts + rng.uniform(-0.2, 0.2, size=pts.shape) * spacing


CELLS = pytest.mark.parametrize("cells", [1, 2, "solver"], ids=["h-cells", "half-h-cells", "solver-cells"])
# the sort's two forms: serial (CPU) and parallel (GPU; in 3D with the solver's cells its
# prefix sum has several runs of blocks)
SORTS = pytest.mark.parametrize("parallel", [False, True], ids=["serial-sort", "parallel-sort"])


def per_axis(cells, dim):
    """Cells per support along each axis: an int for every axis, or the solver's choice."""
    from mrsph.simulation import CELLS_PER_SUPPORT

    return tuple(CELLS_PER_SUPPORT[dim]) if cells == "solver" else (cells,) * dim


@SORTS
@CELLS
@pytest.mark.parametrize("layout", ["random", "lattice"])
def test_grid_neighbours_equal_brute_force(dim, layout, cells, parallel):
    rng = np.random.default_rng(100 * dim + (layout == "lattice"))
    if layout == "random":
        xs = random_positions(rng, dim, 1500 if dim == 2 else 2500)
    else:
        xs = jittered_lattice(rng, dim, 0.025 if dim == 2 else 0.06)
    # two levels, interleaved in space and in the pool
    levels = (rng.uniform(size=len(xs)) < 0.35).astype(np.int32)
    # put the particles at the domain edges and corners too (clamped cells, padding)
    xs[:dim, :] = DOMAIN_MIN
    xs[dim : 2 * dim, :] = DOMAIN_MAX
    pool, grids = build(dim, xs, levels, cells_per_support=per_axis(cells, dim), parallel=parallel, reuse=True)
    n = grids.sort(pool)
    assert n == len(xs), f"sort returned {n} particles; expected {len(xs)} (none is DEAD)"
    expected, borderline = brute_force(xs, levels)
    compare(grid_neighbours(pool, grids, n), expected, borderline, f"{dim}D {layout}, {cells} cell(s) per h")


@SORTS
@CELLS
def test_a_sort_after_the_particles_moved_finds_their_new_neighbours(dim, cells, parallel):
    """Each sort starts from cell counts that the previous one left zeroed (its prefix
    pass clears them): a second sort, after every particle moved, must still bin them
    right."""
    rng = np.random.default_rng(31 + dim)
    xs = random_positions(rng, dim, 1200 if dim == 2 else 2000)
    levels = (rng.uniform(size=len(xs)) < 0.35).astype(np.int32)
    pool, grids = build(dim, xs, levels, cells_per_support=per_axis(cells, dim), parallel=parallel, reuse=True)
    n = grids.sort(pool)
    moved = random_positions(rng, dim, len(xs))
    ids = pool.p.slot.to_numpy()[:n]
    x = pool.p.x.to_numpy()
    x[:n] = moved[ids].astype(np.float32)
    pool.p.x.from_numpy(x)
    n = grids.sort(pool)
    expected, borderline = brute_force(moved, levels)
    compare(grid_neighbours(pool, grids, n), expected, borderline, f"{dim}D, second sort, {cells} cell(s) per h")


@SORTS
def test_a_grid_with_a_skin_finds_every_neighbour_until_a_particle_moves_half_the_skin(dim, parallel):
    """With a skin the step does not sort until some particle has moved more than
    skin h_l / 2 since the last sort: a grid of cells (1 + skin) h_l / k must still hold,
    in the block around any particle's new position, every particle within h_l of it.
    Every particle moves 0.49 skin h_l in a random direction after the sort, and the
    search over the unsorted grid must find the brute-force sets at the new positions."""
    skin = 0.3
    rng = np.random.default_rng(71 + dim)
    xs = random_positions(rng, dim, 1200 if dim == 2 else 2000)
    levels = (rng.uniform(size=len(xs)) < 0.35).astype(np.int32)
    cells = per_axis("solver", dim)
    pool, grids = build(dim, xs, levels, cells_per_support=cells, parallel=parallel, reuse=True, skin=skin)
    n = grids.sort(pool)
    ids = pool.p.slot.to_numpy()[:n]
    step = rng.normal(size=(len(xs), dim))
    step *= (0.49 * skin * H0 * 2.0 ** levels[:, None]) / np.linalg.norm(step, axis=1, keepdims=True)
    moved = xs + step
    x = pool.p.x.to_numpy()
    x[:n] = moved[ids].astype(np.float32)
    pool.p.x.from_numpy(x)
    expected, borderline = brute_force(moved, levels)
    compare(grid_neighbours(pool, grids, n), expected, borderline, f"{dim}D, unsorted after a move of 0.49 skin h")


@CELLS
def test_a_sort_with_nothing_moved_skips_and_any_change_resorts(dim, cells):
    """A sort that finds every particle in the cell its slot had (the sorts between the
    level pairs of a quiet adaptivity pass) leaves the pool and the grid as they are;
    one particle moved to another cell, one killed, or one appended, and it sorts in
    full again."""
    rng = np.random.default_rng(53 + dim)
    xs = random_positions(rng, dim, 1200 if dim == 2 else 2000)
    levels = (rng.uniform(size=len(xs)) < 0.35).astype(np.int32)
    pool, grids = build(dim, xs, levels, cells_per_support=per_axis(cells, dim), reuse=True)
    n = grids.sort(pool)
    before = pool.p.slot.to_numpy().copy()
    starts = grids.start.to_numpy().copy()
    assert grids.sort(pool) == n and grids.moved[None] == 0, (
        f"{dim}D: a second sort with nothing moved did the full sort (moved = {grids.moved[None]})"
    )
    assert np.array_equal(pool.p.slot.to_numpy(), before) and np.array_equal(grids.start.to_numpy(), starts), (
        f"{dim}D: a sort with nothing moved changed the pool or the cell starts"
    )

    # one particle to the place of another far away (another cell)
    x = pool.p.x.to_numpy()
    x[0] = x[n - 1] + 1e-3
    pool.p.x.from_numpy(x)
    n = grids.sort(pool)
    assert grids.moved[None] == 1, f"{dim}D: a particle moved to another cell, and the sort skipped"
    ids = pool.p.slot.to_numpy()[:n]
    by_id = np.empty((len(xs), dim))
    by_id[ids] = pool.p.x.to_numpy()[:n]
    expected, borderline = brute_force(by_id, levels)
    compare(
        grid_neighbours(pool, grids, n),
        expected,
        borderline,
        f"{dim}D, one particle moved after a skipped sort, {cells} cell(s) per h",
    )

    # one particle killed in place: n shrinks, no DEAD slot stays inside [0, n)
    kind = pool.p.kind.to_numpy()
    kind[n // 2] = DEAD
    pool.p.kind.from_numpy(kind)
    m = grids.sort(pool)
    assert m == n - 1 and not np.any(pool.p.kind.to_numpy()[:m] == DEAD), (
        f"{dim}D: after killing one of {n} particles the sort left n = {m}"
    )

    # one particle appended past n, in the cell of slot 0: n grows and the grid lists it
    x, kind, slot = pool.p.x.to_numpy(), pool.p.kind.to_numpy(), pool.p.slot.to_numpy()
    x[m], kind[m], slot[m] = x[0], REGULAR, 10_000
    pool.p.x.from_numpy(x)
    pool.p.kind.from_numpy(kind)
    pool.p.slot.from_numpy(slot)
    pool.n[None] = m + 1
    k = grids.sort(pool)
    assert k == m + 1 and 10_000 in pool.p.slot.to_numpy()[:k].tolist(), (
        f"{dim}D: a particle appended past n was not sorted in (n = {k}, expected {m + 1})"
    )


@SORTS
@CELLS
def test_sort_orders_by_cell_and_carries_every_attribute(dim, cells, parallel):
    rng = np.random.default_rng(7 + dim)
    xs = random_positions(rng, dim, 400)
    levels = (rng.uniform(size=len(xs)) < 0.5).astype(np.int32)
    pool, grids = build(dim, xs, levels, cells_per_support=per_axis(cells, dim), parallel=parallel, reuse=True)
    n = grids.sort(pool)
    ids = pool.p.slot.to_numpy()[:n]
    assert sorted(ids.tolist()) == list(range(len(xs))), "the sort is not a permutation"
    x = pool.p.x.to_numpy()[:n]
    assert np.array_equal(x, xs[ids].astype(np.float32)), "positions not carried with their particle"
    assert np.array_equal(pool.p.v.to_numpy()[:n], (xs[ids] * 3.0 + 1.0).astype(np.float32)), (
        "velocities not carried with their particle"
    )
    assert np.array_equal(pool.p.m.to_numpy()[:n], ids.astype(np.float32) + 0.5), "masses not carried"
    assert np.array_equal(pool.p.level.to_numpy()[:n], levels[ids]), "levels not carried"
    # keys: offset of the level + linear cell index, non-decreasing along the pool
    from mrsph.sph.grid import PAD_SUPPORTS

    keys = []
    offset = 0
    offsets = []
    for l in range(LEVELS):
        offsets.append(offset)
        offset += int(np.prod(grids.res_host[l]))
    for xi, l in zip(x.astype(np.float64), levels[ids]):
        k = np.array(per_axis(cells, dim))
        size = H0 * 2**l / k
        res = np.array(grids.res_host[l])
        c = np.clip(np.floor((xi - (DOMAIN_MIN - PAD_SUPPORTS * k * size)) / size).astype(int), 0, res - 1)
        keys.append(offsets[l] + int(np.ravel_multi_index(tuple(c), tuple(res))))
    keys = np.array(keys)
    assert np.all(np.diff(keys) >= 0), (
        f"pool not in cell order after the sort: {int((np.diff(keys) < 0).sum())} descents"
    )
    # the serial sort is stable within a cell (ids ascending), so it is deterministic;
    # the parallel one ranks by atomic counts, in whatever order the threads come
    same = np.diff(keys) == 0
    if not parallel:
        assert np.all(np.diff(ids)[same] > 0), "particles of one cell are not in their original order"


@SORTS
def test_sort_compacts_dead_slots_and_remaps_links(dim, parallel):
    """DEAD holes vanish; parent and children indices follow their particles."""
    rng = np.random.default_rng(31 + dim)
    nreal = 300
    xs = random_positions(rng, dim, nreal)
    levels = np.zeros(nreal, np.int32)
    kinds = np.full(nreal, REGULAR, np.int32)
    nmax = 2**dim
    # groups of transient children (level 0), each under a virtual parent (level 1)
    groups = [list(range(g, g + (1 + g % nmax))) for g in range(0, 200, 10)]
    parents = []
    for members in groups:
        kinds[members] = TRANSIENT_CHILD
        parents.append(len(xs))
        xs = np.vstack([xs, xs[members].mean(axis=0)])
        levels = np.append(levels, 1)
        kinds = np.append(kinds, VIRTUAL_PARENT)
    dead = rng.choice(np.flatnonzero(kinds == REGULAR), 60, replace=False)
    kinds[dead] = DEAD
    pool, grids = build(dim, xs, levels, kinds, parallel=parallel)
    parent = np.full(len(xs), -1, np.int32)
    nchild = np.zeros(len(xs), np.int32)
    children = np.full((pool.capacity, nmax), -1, np.int32)
    for members, par in zip(groups, parents):
        parent[members] = par
        nchild[par] = len(members)
        children[par, : len(members)] = members
        # entries past nchild are never read (the sort leaves them as they were)
        if len(members) < nmax:
            children[par, len(members)] = members[0]
    pad = np.full(pool.capacity - len(xs), -1, np.int32)
    pool.p.parent.from_numpy(np.concatenate([parent, pad]))
    pool.p.nchild.from_numpy(np.concatenate([nchild, 0 * pad]))
    pool.children.from_numpy(children)

    n = grids.sort(pool)
    alive = len(xs) - len(dead)
    assert n == alive and pool.count() == alive, (
        f"after the sort n = {n}, pool.count() = {pool.count()}; expected {alive} alive particles"
    )
    kind_after = pool.p.kind.to_numpy()
    assert not np.any(kind_after[:n] == DEAD), f"{int((kind_after[:n] == DEAD).sum())} DEAD slots left inside [0, n)"
    assert np.all(kind_after[n : len(xs)] == DEAD), "slots past n are not all DEAD"
    ids = pool.p.slot.to_numpy()[:n]
    assert set(ids.tolist()) == set(range(len(xs))) - set(dead.tolist()), "the alive set changed"
    slot_of = {int(i): s for s, i in enumerate(ids)}
    par_after = pool.p.parent.to_numpy()[:n]
    nch_after = pool.p.nchild.to_numpy()[:n]
    ch_after = pool.children.to_numpy()[:n]
    for s, i in enumerate(ids):
        if parent[i] >= 0:
            assert par_after[s] == slot_of[int(parent[i])], (
                f"particle {i}: parent slot {par_after[s]}, expected {slot_of[int(parent[i])]}"
            )
        else:
            assert par_after[s] == -1, f"particle {i} gained a parent ({par_after[s]})"
        assert nch_after[s] == nchild[i], f"particle {i}: nchild {nch_after[s]}, expected {nchild[i]}"
        want = [slot_of[int(c)] for c in children[i, : nchild[i]]]
        assert ch_after[s, : nchild[i]].tolist() == want, (
            f"particle {i}: children slots {ch_after[s].tolist()}, expected {want}"
        )
    # every child's parent lists it (the invariant of METHOD.md §8)
    for s in np.flatnonzero(par_after >= 0):
        par = par_after[s]
        assert s in ch_after[par, : nch_after[par]], f"slot {s} not listed by its parent {par}"


@pytest.mark.parametrize("asked", [1, 300, 1024, 58_624, 249_856])
def test_pool_arrays_are_sized_so_that_they_do_not_alias(asked):
    """The pool holds at least what was asked, at most 31 slots more, and every one of its
    arrays has that many slots, a byte length (f32) 64 bytes past a multiple of 4 KiB or
    more: at a multiple of 4 KiB (249 856 slots, a 3D scene's automatic capacity) the
    same index of every attribute falls in one L1 set, and the sort's copy took 3.7x
    as long (particles.storage_slots)."""
    from mrsph.sph.particles import ParticlePool, storage_slots

    pool = ParticlePool(3, asked)
    slots = pool.capacity
    assert slots == storage_slots(asked) and asked <= slots < asked + 32, (
        f"asked {asked} slots, the pool has {slots}; expected {asked} ... {asked + 31}"
    )
    assert slots % 32 == 16 and (4 * slots) % 4096 != 0, (
        f"{slots} slots: 4 * slots = {4 * slots} = {4 * slots % 4096} mod 4096; expected an odd multiple of 16 slots"
    )
    sizes = {name: getattr(pool.p, name).shape[0] for name in ("x", "v", "m", "kind", "parent")}
    sizes.update(tmp_x=pool.tmp.x.shape[0], children=pool.children.shape[0], tmp_children=pool.tmp_children.shape[0])
    assert set(sizes.values()) == {slots}, f"arrays of other lengths than the pool's {slots} slots: {sizes}"


def test_a_claim_leaves_its_reserve_free_for_claims_without_one():
    """``ParticlePool.claim(count, reserve)``: splits claim with a reserve so that a full
    pool can still coarsen (the gathers a merge starts from claim without one; see
    ``multires.topology.MERGE_RESERVE``). A claim that would eat into its reserve is
    refused and counted, and does not use up the reserve for a claim without one."""
    import taichi as ti

    from mrsph.sph.particles import ParticlePool

    pool = ParticlePool(2, 16)
    cap = pool.capacity

    @ti.kernel
    def claim(count: ti.i32, reserve: ti.i32) -> ti.i32:
        return pool.claim(count, reserve)

    got = [claim(4, 8) for _ in range(cap // 4)]
    fitted = [b for b in got if b >= 0]
    assert fitted == list(range(0, cap - 8, 4)), (
        f"capacity {cap}, claims of 4 with a reserve of 8 got {got}; expected slots up to {cap - 8} only"
    )
    refused = int(pool.refused[None])
    assert refused == len(got) - len(fitted), f"{refused} refusals counted for {got}"
    last = [claim(1, 0) for _ in range(10)]
    assert last[:8] == list(range(cap - 8, cap)) and last[8:] == [-1, -1], (
        f"claims of 1 without a reserve after those got {last}; expected the reserve's slots "
        f"{cap - 8} ... {cap - 1}, then refusals"
    )


# ------------------------------------------------------------------ the density pass
DENSITY_RUNS = {  # scene, overrides, simulated seconds before the check (the fluid moves)
    (2, False): ("dam_break_2d", ["particles.spacing=0.01"], 0.15),
    (3, False): ("dam_break_3d", ["particles.spacing=0.02"], 0.15),
    (2, True): ("region_2d", ["particles.spacing=0.01"], 0.1),
    (3, True): ("region_3d", ["particles.spacing=0.02"], 0.1),
}


@pytest.mark.slow_params("2d-uniform", "3d-adaptive")  # the quick run: 2D adaptive, 3D uniform
@pytest.mark.parametrize("adaptive", [False, True], ids=["uniform", "adaptive"])
def test_density_pass_equals_brute_force_sums_and_lists(dim, adaptive):
    """The solver's density pass (``_density``: runs of consecutive particles in a column
    of cells summed in one scan of the grid, the others one by one) against a k-d tree,
    on a moving fluid. Every particle it sums that is more than a support from the walls
    (no wall image) must get ρ_i = Σ_j m_j W_poly6(x_i − x_j, h_l) over the particles of
    its level, and its neighbour list must be the brute-force set. Without a skin: a
    grid scan every step."""
    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    name, sets, warm = DENSITY_RUNS[(dim, adaptive)]
    sim = Simulation(load_scene(name, sets + ["particles.skin=0"]), threads=2)
    sim.advance(warm)
    n = sim.run_phases("grid", "density")
    check_density_and_lists(sim, n, adaptive, f"{dim}D {name}")


# the quick run: 2D uniform, 3D adaptive (the other halves of the test above)
@pytest.mark.slow_params("2d-adaptive", "3d-uniform")
@pytest.mark.parametrize("adaptive", [False, True], ids=["uniform", "adaptive"])
def test_density_pass_with_a_skin_equals_brute_force_after_reused_steps(dim, adaptive):
    """With a skin (``particles.skin``) the density pass sums over each particle's skin
    list, built steps ago, and writes the step's lists from it. Step by step, a step
    builds the lists again exactly when some particle is more than skin h_l / 2 from where
    they were built (or an adaptivity pass ran, or a list overflowed); once they have
    outlived two steps and a particle has moved most of that margin, the density and the
    lists must still be the brute-force ones (an adaptive run: once they are as old as its
    adaptivity passes let them be), and each skin list must hold the particles that were
    within (1 + skin) h of it at its build (``grids.x_built``), itself excluded."""
    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    skin = 0.3
    name, sets, warm = DENSITY_RUNS[(dim, adaptive)]
    sim = Simulation(load_scene(name, sets + [f"particles.skin={skin}"]), threads=2)
    sim.advance(warm)
    every = sim.scene.params.adaptivity.interval
    reused, moved, log = 0, 0.0, []
    for _ in range(300):  # until the lists have outlived two steps and most of their margin
        n = sim.pool.count()
        level = sim.pool.p.level.to_numpy()[:n]
        off = sim.pool.p.x.to_numpy()[:n] - sim.grids.x_built.to_numpy()[:n]
        moved = float(np.max(np.linalg.norm(off, axis=1) / (0.5 * skin * sim.h0 * 2.0**level)))
        due = bool(sim.grids.overflowed[None]) or (sim.adaptive and sim.steps % every == 0)
        sim.step()
        rebuilt = bool(sim.grids.rebuild[None])
        log.append((round(moved, 3), rebuilt))
        if not due and abs(moved - 1.0) > 1e-4:
            assert rebuilt == (moved > 1.0), (
                f"{dim}D {name}: a step {'rebuilt' if rebuilt else 'kept'} the lists with the farthest particle "
                f"{moved:.3f} half-skins from their build (steps: (half-skins moved, rebuilt) {log[-8:]})"
            )
        reused = 0 if rebuilt else reused + 1
        # an adaptive run builds them at every adaptivity pass: as old as those let them be
        old = moved > 0.6 or (sim.adaptive and reused == every - 1)
        if reused >= 2 and old:
            break
    n = sim.run_phases("grid", "density")
    assert reused >= 2 and old and sim.grids.rebuild[None] == 0, (
        f"{dim}D {name}: no step reused lists built two steps before and 0.6 half-skins ago; the test proves "
        f"nothing (steps: (half-skins moved, rebuilt) {log[-12:]})"
    )
    check_density_and_lists(sim, n, adaptive, f"{dim}D {name}, skin {skin}, lists {reused + 1} steps old")
    nb, p = sim.neighbours, sim.pool.p
    built = sim.grids.x_built.to_numpy()[:n].astype(np.float64)
    level = p.level.to_numpy()[:n]
    kind = p.kind.to_numpy()[:n]
    near, count = nb.near.to_numpy()[:n], nb.near_count.to_numpy()[:n]
    assert (count <= nb.max_near).all(), f"{dim}D {name}: {(count > nb.max_near).sum()} skin lists overflowed"
    bad = []
    summed = kind < VIRTUAL_CHILD if sim.coupling.variational else np.ones(n, bool)  # the particles listed
    for l in np.unique(level):
        reach = (1.0 + skin) * sim.h0 * 2.0**l
        same = np.flatnonzero(level == l)
        tree = cKDTree(built[same])
        for i in np.flatnonzero((level == l) & summed):
            want = set(same[tree.query_ball_point(built[i], reach * (1 - 1e-5))].tolist()) - {i}
            edge = set(same[tree.query_ball_point(built[i], reach * (1 + 1e-5))].tolist()) - {i}
            got = set(near[i, : count[i]].tolist())
            if not want <= got <= edge:
                bad.append((i, sorted(want - got), sorted(got - edge)))
    assert not bad, (
        f"{dim}D {name}: {len(bad)} skin lists off their build's sets; first (slot, missed, extra): {bad[0]}"
    )


def check_density_and_lists(sim, n, adaptive, label):
    """Every particle summed that is more than a support from the walls has the
    brute-force density over its level and the brute-force neighbour list (k-d tree)."""
    from mrsph.sph.kernels import constants
    from mrsph.sph.particles import VIRTUAL_CHILD

    dim = sim.dim
    p = sim.pool.p
    x = p.x.to_numpy()[:n].astype(np.float64)
    m = p.m.to_numpy()[:n].astype(np.float64)
    level = p.level.to_numpy()[:n]
    kind = p.kind.to_numpy()[:n]
    rho = p.rho.to_numpy()[:n].astype(np.float64)
    count = sim.neighbours.count.to_numpy()[:n]
    lists = sim.neighbours.lists.to_numpy()[:n]
    summed = kind < VIRTUAL_CHILD if sim.coupling.variational else np.ones(n, bool)
    if adaptive:
        assert len(set(level[summed].tolist())) >= 2, "the adaptive run should hold two levels or more"
        assert (~summed).any(), "the adaptive run should hold virtual particles"
    lo, hi = np.array(sim.scene.data["domain"]["min"]), np.array(sim.scene.data["domain"]["max"])
    h = sim.h0 * 2.0**level
    inside = np.all((x - lo > h[:, None]) & (hi - x > h[:, None]), axis=1)
    worst, checked, bad_lists = 0.0, 0, []
    for l in np.unique(level):
        hl = sim.h0 * 2.0**l
        c6 = constants(hl, dim)["poly6"]
        same = np.flatnonzero(level == l)
        tree = cKDTree(x[same])
        for i in np.flatnonzero((level == l) & summed & inside):
            near = same[tree.query_ball_point(x[i], hl)]
            r2 = np.sum((x[near] - x[i]) ** 2, axis=1)
            want = c6 * np.sum(m[near] * np.clip(hl * hl - r2, 0.0, None) ** 3)
            worst = max(worst, abs(rho[i] / want - 1.0))
            checked += 1
            # pairs within 1e-5 h of the cut-off may fall either way in single precision
            sure = near[(near != i) & (np.abs(np.sqrt(r2) / hl - 1.0) > 1e-5)]
            if count[i] <= sim.neighbours.max_neighbours:
                got = set(lists[i, : count[i]].tolist())
                if not set(sure.tolist()) <= got or len(got - set(near.tolist())):
                    bad_lists.append(i)
    assert checked > 0.3 * summed.sum(), f"only {checked} of {summed.sum()} particles away from the walls"
    assert worst < 2e-5, (
        f"{label}: density pass off a brute-force sum by {worst:.2e} "
        f"(relative, worst of {checked} particles; expected single-precision rounding)"
    )
    assert not bad_lists, (
        f"{label}: {len(bad_lists)} of {checked} neighbour lists differ from "
        f"the brute-force sets, first at slot {bad_lists[0]}"
    )
