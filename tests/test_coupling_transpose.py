"""The level coupling's two maps are each other's transpose: a virtual parent moves with
its children's mass-weighted mean velocity (``coupling.follow_owners``), so the reaction
on it reaches each child in the share of its mass (``coupling.hand_on``). That is what
keeps DFSPH's density operator symmetric in the volume-weighted inner product, which its
conjugate gradients need (``pressure/dfsph/krylov.py``). A split leaves a group's masses
equal, where even shares are the same; an absorption or a gather leaves them unequal, and
there even shares are not the transpose."""

import numpy as np
from scenekit import REAL_KINDS, T_BOTH, T_CHILD, V_PARENT, make_sim, refined_blob_scene, with_solver

from mrsph.sph.particles import is_real


def unequal_groups(sim) -> int:
    """Double the mass of one transient child in each group, as an absorption leaves a
    group, and give each virtual parent its group's mass: the groups changed."""
    n = sim.pool.count()
    kind = sim.pool.p.kind.to_numpy()[:n]
    parent = sim.pool.p.parent.to_numpy()[:n]
    m = sim.pool.p.m.to_numpy()
    children = np.flatnonzero(np.isin(kind, (T_CHILD, T_BOTH)))
    firsts = children[np.unique(parent[children], return_index=True)[1]]
    m[firsts] *= 2.0
    for vp in np.flatnonzero(kind == V_PARENT):
        m[vp] = m[children[parent[children] == vp]].sum()
    sim.pool.p.m.from_numpy(m)
    return len(firsts)


def test_dfsph_operator_is_symmetric_with_groups_of_unequal_mass(dim, fresh_program):
    """<x, A y>_V = <A x, y>_V for random x, y over the real particles, V_i = m_i/ρ_i, with
    every group's masses unequal. With the reaction split evenly instead the two differ by
    1e-2 of either (2D and 3D); with shares by mass they agree to single precision's
    round-off."""
    import taichi as ti

    sim = make_sim(with_solver(refined_blob_scene(dim), "dfsph"), threads=1)
    for _ in range(3):
        sim.step()
    groups = unequal_groups(sim)
    assert groups > 10, f"{dim}D: only {groups} groups of transient children at the core"
    n = sim.run_phases("density")
    kr = sim.pressure.krylov
    cap = kr.d.shape[0]
    real = np.isin(sim.pool.p.kind.to_numpy()[:n], REAL_KINDS)
    rng = np.random.default_rng(7 + dim)
    fields = {}
    for name in ("x", "y", "ax", "ay"):
        fields[name] = ti.field(float, shape=cap)
    for name in ("x", "y"):
        values = np.zeros(cap, np.float32)
        values[:n][real] = rng.normal(size=int(real.sum()))
        fields[name].from_numpy(values)

    @ti.kernel
    def product(n: ti.i32, src: ti.template(), dst: ti.template()):
        for i in range(n):
            kr.on[i] = 1 if is_real(sim.pool.p[i].kind) else 0
        kr._product(n, src, dst, 1.0)

    product(n, fields["x"], fields["ax"])
    product(n, fields["y"], fields["ay"])
    vol = sim.pool.p.m.to_numpy()[:n][real].astype(np.float64) / sim.pool.p.rho.to_numpy()[:n][real]
    x, y, ax, ay = (fields[k].to_numpy()[:n][real].astype(np.float64) for k in ("x", "y", "ax", "ay"))
    xay, axy = float(np.sum(vol * x * ay)), float(np.sum(vol * ax * y))
    asym = abs(xay - axy) / max(abs(xay), abs(axy))
    assert asym < 1e-5, (
        f"{dim}D, {groups} groups of unequal mass: <x, Ay>_V = {xay:.6e}, <Ax, y>_V = {axy:.6e}, "
        f"relative difference {asym:.2e} (expected < 1e-5: the reaction's shares the transpose of the "
        "virtual parent's mass-weighted velocity)"
    )
