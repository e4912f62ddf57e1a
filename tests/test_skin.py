"""Neighbour lists that outlive a step (``particles.skin``; sph/grid.py, sph/neighbours.py,
sph/density.py): the scene key and its rules; when a step builds the lists again (a
particle past half the skin, a list that overflowed, an adaptivity pass, an emitter);
and a run with a skin against the same run without one. The lists themselves against
brute force are in test_grid.py."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from mrsph.limits import AUTO_SKIN, MAX_SKIN, max_capacity, skin_list_length
from mrsph.pressure import SOLVERS
from mrsph.scene.config import SceneError, load_scene

SKIN = 0.3


def minimal(dim: int, **particles) -> dict:
    return {
        "description": f"minimal {dim}D scene",
        "dim": dim,
        "domain": {"min": [0.0] * dim, "max": [1.0] * dim},
        "particles": {"spacing": 0.05, **particles},
        "fluid": {"blocks": [{"min": [0.0] * dim, "max": [0.5] * dim}]},
    }


def problems(scene: dict, overrides=None) -> list[str]:
    with pytest.raises(SceneError) as info:
        load_scene(scene, overrides)
    return info.value.problems


# ------------------------------------------------------------------ the key
@pytest.mark.parametrize("solver", SOLVERS)
def test_the_automatic_skin_is_the_solvers_and_a_given_one_stays(dim, solver):
    auto = load_scene(minimal(dim), [f'fluid.solver="{solver}"'])
    assert auto.params.particles.skin == AUTO_SKIN[solver], (
        f"{dim}D {solver}: particles.skin = -1 became {auto.params.particles.skin}, expected {AUTO_SKIN[solver]}"
    )
    given = load_scene(minimal(dim, skin=0.25), [f'fluid.solver="{solver}"'])
    assert given.params.particles.skin == 0.25 and given.data["particles"]["skin"] == 0.25


def test_a_skin_that_is_not_a_share_of_h_is_refused(dim):
    assert problems(minimal(dim, skin=-0.5)) == [
        "<dict>: particles.skin: out of range (got -0.5; expected a share of h >= 0, or -1 for the solver's)"
    ]
    assert problems(minimal(dim, skin=MAX_SKIN + 0.5)) == [
        f"<dict>: particles.skin: out of range (got {MAX_SKIN + 0.5}; expected a number in [-1, {MAX_SKIN:g}])"
    ]


def test_the_capacity_limit_follows_the_skin_lists(dim):
    """The skin lists hold (1 + skin)^dim as many entries a slot as the lists, and a
    Taichi field is indexed with 32 bits: the largest capacity shrinks with the skin."""
    limit = max_capacity(dim, 1.0)
    assert limit * (skin_list_length(dim, 1.0) + 1) < 2**31 < (limit + 10**6) * (skin_list_length(dim, 1.0) + 1)
    assert limit < max_capacity(dim, 0.0)
    assert problems(minimal(dim, skin=1.0, capacity=limit + 1)) == [
        f"<dict>: particles.capacity: too many slots for the neighbour lists "
        f"(got {limit + 1}; expected <= {limit} in {dim}D with particles.skin = 1.0)"
    ]
    assert load_scene(minimal(dim, skin=1.0, capacity=limit)).params.particles.capacity == limit


# ------------------------------------------------------------------ when the lists are built
def dam(dim: int, skin: float, *extra: str):
    name, spacing = ("dam_break_2d", 0.01) if dim == 2 else ("dam_break_3d", 0.03)
    return load_scene(name, [f"particles.spacing={spacing}", f"particles.skin={skin}", *extra])


def build_now(sim) -> None:
    """The lists built at the particles' present positions (the grid and density passes)."""
    sim.grids.invalidate()
    sim.run_phases("grid", "density")
    assert sim.grids.rebuild[None] == 1


@pytest.mark.usefixtures("fresh_program")
def test_a_particle_moved_past_half_the_skin_builds_the_lists_again(dim):
    """Nothing moved since the lists were built: the next step keeps them. One particle
    moved 0.45 skin h from where they were built: kept; 0.55 skin h: built again."""
    from mrsph.simulation import Simulation

    sim = Simulation(dam(dim, SKIN), threads=1)
    sim.advance(0.01)
    build_now(sim)
    sim.run_phases("grid", "density")
    assert sim.grids.rebuild[None] == 0, f"{dim}D: nothing moved, and the step built the lists again"
    n = sim.pool.count()
    i = n // 2
    h = sim.h0 * 2.0 ** int(sim.pool.p.level.to_numpy()[i])
    away = np.zeros(dim, np.float32)
    away[0] = 1.0
    for share, built in ((0.45, 0), (0.55, 1)):
        x = sim.pool.p.x.to_numpy()
        x[i] = sim.grids.x_built.to_numpy()[i] + (share * SKIN * h) * away
        sim.pool.p.x.from_numpy(x)
        sim.run_phases("grid", "density")
        assert sim.grids.rebuild[None] == built, (
            f"{dim}D: a particle {share} skin h from where the lists were built, and the step "
            f"{'kept' if built else 'built'} them (expected them {'built' if built else 'kept'} past 0.5)"
        )
    assert np.allclose(sim.grids.x_built.to_numpy()[:n], sim.pool.p.x.to_numpy()[:n]), (
        f"{dim}D: the lists built again, and the positions they were built at are not the particles'"
    )


@pytest.mark.usefixtures("fresh_program")
def test_an_overflowed_skin_list_builds_the_lists_again_and_sums_over_the_grid(dim, monkeypatch):
    """Skin lists shorter than the neighbourhoods (``MAX_NEIGHBOURS`` cut, as in
    test_capacity.py): every build overflows, so every step builds them again, and the
    densities are those of the listed run from the same state (the grid's sums instead
    of the list's, in another order: to float32 round-off)."""
    import mrsph.sph.neighbours
    from mrsph.simulation import Simulation

    listed = Simulation(dam(dim, SKIN), threads=1)
    listed.advance(0.01)
    state = listed.save_state()
    monkeypatch.setattr(mrsph.sph.neighbours, "MAX_NEIGHBOURS", {2: 8, 3: 16})
    short = Simulation(dam(dim, SKIN), threads=1)
    short.restore_state(state)
    for sim in (listed, short):
        build_now(sim)
        sim.run_phases("grid", "density")
    assert listed.grids.rebuild[None] == 0 and listed.grids.overflowed[None] == 0
    n = short.pool.count()
    over = short.neighbours.near_count.to_numpy()[:n] > short.neighbours.max_near
    assert over.mean() > 0.5, f"{dim}D: only {over.sum()} of {n} skin lists of {short.neighbours.max_near} overflowed"
    assert short.grids.overflowed[None] == 1 and short.grids.rebuild[None] == 1, (
        f"{dim}D: skin lists overflowed at their build, and the next step kept them "
        f"(overflowed {short.grids.overflowed[None]}, rebuild {short.grids.rebuild[None]})"
    )
    a, b = listed.pool.p.rho.to_numpy()[:n], short.pool.p.rho.to_numpy()[:n]
    worst = float(np.max(np.abs(b / a - 1.0)))
    assert worst < 1e-5, f"{dim}D: densities from overflowed skin lists off the listed ones by {worst:.2e} (relative)"


# the quick run: 2D; 3D compiles an adaptive step and an emitter's
@pytest.mark.slow_params("3d")
@pytest.mark.usefixtures("fresh_program")
def test_an_adaptivity_pass_or_an_emitter_builds_the_lists_again(dim):
    """Every step that follows an adaptivity pass (it sorts the pool, splits and merges)
    builds the lists again, and so does every step whose emitters added particles; the
    steps between keep them."""
    from mrsph.simulation import Simulation

    region = Simulation(load_scene(f"region_{dim}d", ["particles.spacing=0.02", f"particles.skin={SKIN}"]), threads=1)
    every = region.scene.params.adaptivity.interval
    kept = 0
    for _ in range(3 * every):
        adapting = region.steps % every == 0
        region.step()
        if adapting:
            assert region.grids.rebuild[None] == 1, (
                f"{dim}D: step {region.steps} kept the lists after an adaptivity pass"
            )
        kept += 1 - region.grids.rebuild[None]
    assert kept > 0, f"{dim}D: no step between the adaptivity passes kept the lists; the test proves nothing"

    pour = Simulation(load_scene(f"pour_{dim}d", [f"particles.skin={SKIN}"]), threads=1)
    emitted = kept = 0
    for _ in range(60):
        before = pour.pool.count()
        pour.step()
        if pour.pool.count() != before:
            emitted += 1
            assert pour.grids.rebuild[None] == 1, f"{dim}D: step {pour.steps} emitted particles and kept the lists"
        elif before > 0:
            kept += 1 - pour.grids.rebuild[None]
    assert emitted > 0 and kept > 0, f"{dim}D: {emitted} steps emitted and {kept} kept the lists; expected both"


# ------------------------------------------------------------------ a run with a skin
@pytest.mark.slow_params("3d")
@pytest.mark.usefixtures("fresh_program")
def test_a_run_with_a_skin_agrees_with_one_without_to_round_off(dim):
    """The same dam break, 150 steps in double precision, with and without a skin. Both
    sum the same neighbours, in other orders (a skin list's order, the pool's order
    since its last build), so they agree to round-off: within 1e-9 of the spacing (x),
    the fastest speed (u) and ρ0 (ρ), where this run's round-off is ~1e-13 and one
    neighbour missed at 0.99 h would move a density by ~1e-6. The skin's run builds its
    lists a few times, the other every step, as the stats count."""
    from mrsph import runtime
    from mrsph.simulation import Simulation

    runs = {}
    for skin in (0.0, SKIN):
        runtime.reset()
        sim = Simulation(dam(dim, skin, 'particles.precision="f64"'), threads=1)
        sim.stats()
        for _ in range(150):
            sim.step()
        runs[skin] = (sim.particles(), sim.stats()["rebuilds"], sim.s0, sim.rest_density)
    (a, built_a, s0, rho0), (b, built_b, _, _) = runs[0.0], runs[SKIN]
    assert built_a == 150 and 0 < built_b < 30, (
        f"{dim}D: the lists were built {built_a} times without a skin and {built_b} times with one in 150 steps"
    )
    # the pools are in other orders: match each particle to the nearest of the other run
    dist, near = cKDTree(a["x"]).query(b["x"])
    assert len(set(near.tolist())) == len(a["x"]) == len(b["x"]), f"{dim}D: the runs' particles do not pair up"
    du = float(np.abs(b["v"] - a["v"][near]).max())
    drho = float(np.abs(b["rho"] - a["rho"][near]).max())
    speed = float(np.abs(a["v"]).max())
    assert dist.max() < 1e-9 * s0 and du < 1e-9 * speed and drho < 1e-9 * rho0, (
        f"{dim}D: with a skin of {SKIN} the run is off the one without by {dist.max():.2e} m (x), "
        f"{du:.2e} m/s (u, fastest {speed:.3g}), {drho:.2e} kg/m^3 (rho)"
    )
