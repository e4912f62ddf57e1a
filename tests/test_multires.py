"""The multiresolution scheme (METHOD.md §2–8) held to its invariants: the links between
real and virtual particles at every step of a run whose refined region keeps moving, the
total mass through splits and merges (bit for bit), the momentum through an adaptivity
pass and through the forces that cross a level interface via virtual particles; merging
back, absorption, seeding, and the split fade's offsets. The step, saved states and the
pool's capacity have files of their own (test_step.py, test_state.py, test_capacity.py);
the raw pool, its link checks and the scenes they share are in scenekit.py.

Scenes are built in code, small (2D ~1–2k, 3D ~3–6k slots), gravity off and far from
the walls. Each test starts a fresh Taichi program (``fresh_program``), as in
``test_physics.py``.

Link checks read the raw pool (slots ``[0, n)``, DEAD rows skipped by kind), not
``Simulation.particles()``, which drops DEAD rows and so renumbers the slots that
``parent`` and the children table point to.
"""

import math

import numpy as np
import pytest
from scenekit import (
    BAND,
    CHILD_ROLE,
    DIMS_3D_SLOW,
    PARENT_ROLE,
    REAL_KINDS,
    REGULAR,
    RULE_E_KINDS,
    S0,
    T_BOTH,
    T_CHILD,
    T_PARENT,
    V_CHILD,
    V_PARENT,
    case_label,
    describe,
    dim_solver_params,
    for_solver,
    link_violations,
    make_sim,
    moving_region_scene,
    raw_pool,
    real_first_moment,
    real_mass,
    real_momentum,
    refined_blob_scene,
    watch_solves,
    with_solver,
    worst_leak,
)
from scipy.spatial import cKDTree

from mrsph.scene.config import load_scene

pytestmark = pytest.mark.usefixtures("fresh_program")


# ================================================================== 1. links at every step
# the dfsph cases compile a second solver's kernels (a minute or more each): the default
# suite keeps the 2D links and the 2D coupling momentum with dfsph, -m slow the rest
@pytest.mark.parametrize(("dim", "solver"), dim_solver_params(slow=("3d", "2d-dfsph", "3d-dfsph")))
def test_links_hold_at_every_step_of_a_moving_refinement(dim, solver):
    """METHOD.md §3, §8: every virtual particle has a live owner that lists it, every
    transient child's virtual parent lists it, groups hold at most 2^d children, and no
    regular particle neighbours a regular one two levels finer: after every step of a run
    in which splits and merges keep happening (interval 1, 3 levels).

    Rule (e) holds for regular particles. It does not hold for all real ones with this
    narrow band: a level-1 particle split at the fine pair of a pass can leave a level-0
    transient child within h_2 of a level-2 transient parent until the next pass (measured
    when this was written: 0.079 m < h_2 = 0.08 m in 2D, 0.140 m < 0.16 m in 3D)."""
    sim = make_sim(for_solver(moving_region_scene(dim), solver))
    case = case_label(dim, solver)
    steps = 80
    bad = link_violations(sim, raw_pool(sim))
    assert not bad, f"{case}, after construction: " + "; ".join(bad)
    splits = merges = 0
    kinds_seen = set()
    # steps at which regular level-0 and level-2 particles came within 2.5 h_2 of each
    # other, so that rule (e) (none within h_2) was tested where it could fail. 2.5, not 2:
    # the 3D dfsph run's closest approach is 2.26 h_2 (one thread, 120 steps, main at
    # 0953515 and since; CI had passed it at 2 h_2 with other float sequences)
    two_apart = 0
    h2 = sim.h0 * 4
    for step in range(1, steps + 1):
        sim.step()
        ev = sim.stats()
        splits += ev["splits"]
        merges += ev["merges"]
        pool = raw_pool(sim)
        kinds_seen.update(np.unique(pool["kind"]).tolist())
        reg = np.isin(pool["kind"], RULE_E_KINDS)
        x0, x2 = (pool["x"][reg & (pool["level"] == l)].astype(np.float64) for l in (0, 2))
        if len(x0) and len(x2):
            two_apart += bool(cKDTree(x0).query(x2, k=1)[0].min() < 2.5 * h2)
        bad = link_violations(sim, pool)
        assert not bad, (
            f"{case}, step {step} (t = {sim.time:.4g} s, {splits} splits and {merges} merges so far): " + "; ".join(bad)
        )
    print(
        f"\n{case} links: {steps} steps, {splits} splits, {merges} merges, kinds seen {sorted(kinds_seen)}, "
        f"{pool['n']} slots at the end; rule (e) had regular levels 0 and 2 within 2.5 h_2 at {two_apart} steps"
    )
    assert two_apart > 0, (
        f"{case}: rule (e) was never exercised (at no step were regular levels 0 and 2 within 2.5 h_2 of each other)"
    )
    assert splits > 0 and merges > 0, (
        f"{case}: the run did not exercise the scheme: {splits} splits, {merges} merges in {steps} steps"
    )
    missing = {T_PARENT, T_CHILD, V_CHILD, V_PARENT} - kinds_seen
    assert not missing, f"{case}: kinds {sorted(missing)} never appeared (seen {sorted(kinds_seen)})"


# ================================================================== 2. mass
def event_steps(sim, events: int = 100, max_steps: int = 150):
    """Step until at least ``events`` splits and as many merges (at most ``max_steps``
    steps), yielding (steps, splits so far, merges so far, stats row) after each step."""
    splits = merges = steps = 0
    while steps < max_steps and (splits < events or merges < events):
        sim.step()
        steps += 1
        ev = sim.stats()
        splits += ev["splits"]
        merges += ev["merges"]
        yield steps, splits, merges, ev


@pytest.mark.parametrize(("dim", "solver"), dim_solver_params(slow=("3d", "2d-dfsph", "3d-dfsph")))
def test_mass_is_bit_identical_through_splits_and_merges(dim, solver):
    """METHOD.md §5, §6, §8: with full groups only (merge_min_children = 2^d),
    the total real mass (math.fsum of the masses) is bit-identical at every step of a run
    with at least a hundred splits and a hundred merges, and every real particle keeps its level's nominal
    mass m_l = 2^(d l) m0 exactly (dividing by 2^d and summing 2^d equal masses are exact)."""
    scene = moving_region_scene(dim, half_period_steps=25)
    scene["adaptivity"]["merge_min_children"] = 2**dim
    sim = make_sim(for_solver(scene, solver))
    assert sim.multires.merge_min == 2**dim, f"merge_min_children resolved to {sim.multires.merge_min}"
    nominal = sim.lev.m.to_numpy()
    pool = raw_pool(sim)
    m_start = real_mass(pool)
    case = case_label(dim, solver)
    for steps, splits, merges, ev in event_steps(sim):
        assert ev["total_mass"] == m_start, (
            f"{case}, step {steps}: total real mass {ev['total_mass']!r} != {m_start!r} at the start "
            f"(difference {ev['total_mass'] - m_start:.3e} kg after {splits} splits, {merges} merges)"
        )
    pool = raw_pool(sim)
    m_end = real_mass(pool)
    print(f"\n{case} mass: {steps} steps, {splits} splits, {merges} merges; total {m_start!r} -> {m_end!r}")
    assert splits >= 100 and merges >= 100, (
        f"{case}: too few events to test: {splits} splits, {merges} merges in {steps} steps"
    )
    assert m_end == m_start, f"{case}: total real mass {m_end!r} != {m_start!r} (Δ = {m_end - m_start:.3e} kg)"
    real = np.isin(pool["kind"], REAL_KINDS)
    off = real & (pool["m"] != nominal[np.clip(pool["level"], 0, len(nominal) - 1)])
    if off.any():
        i = int(np.flatnonzero(off)[0])
        pytest.fail(
            f"{case}: {int(off.sum())} real particles do not have their level's nominal mass; "
            f"first {describe(pool, i)}: m = {pool['m'][i]!r}, nominal {nominal[pool['level'][i]]!r}"
        )


@pytest.mark.slow_params("3d")  # the quick run keeps 2D (conftest.py, "two tiers")
def test_mass_is_kept_to_round_off_with_partial_groups(dim):
    """METHOD.md §6 ("a group need not be full"): with groups of any size allowed to merge
    once they can gather no more (merge_min_children = 1) merged particles carry
    non-nominal masses, which later splits divide again, so the sums are no longer exact;
    in float64 the total real mass stays within 1e-12 relative of the start at every step
    of a run with at least a hundred splits and a hundred merges."""
    case = case_label(dim, "wcsph")
    scene = moving_region_scene(dim, half_period_steps=25)
    scene["adaptivity"]["merge_min_children"] = 1
    scene["particles"]["precision"] = "f64"
    sim = make_sim(scene)
    nominal = sim.lev.m.to_numpy()
    m_start = real_mass(raw_pool(sim))
    partial = 0  # steps after which some real particle had a non-nominal mass
    worst = 0.0
    for steps, splits, merges, _ev in event_steps(sim):
        pool = raw_pool(sim)
        assert pool["m"].dtype == np.float64, f"precision f64 gave {pool['m'].dtype} masses"
        real = np.isin(pool["kind"], REAL_KINDS)
        partial += bool((pool["m"][real] != nominal[pool["level"][real]]).any())
        rel = abs(real_mass(pool) - m_start) / m_start
        worst = max(worst, rel)
        assert rel <= 1e-12, (
            f"{case}, step {steps}: total real mass {real_mass(pool)!r} against "
            f"{m_start!r} at the start ({rel:.2e} relative, expected <= 1e-12) "
            f"after {splits} splits, {merges} merges"
        )
    print(
        f"\n{case} mass, partial groups: {steps} steps, {splits} splits, {merges} merges, "
        f"non-nominal masses after {partial} steps; worst relative drift {worst:.2e}"
    )
    assert splits >= 100 and merges >= 100, (
        f"{case}: too few events to test: {splits} splits, {merges} merges in {steps} steps"
    )
    assert partial > 0, f"{case}: no partial group merged in {steps} steps ({merges} merges)"
    snap = sim.snapshot(stats=False)  # what --dump writes: the run's own precision
    assert snap.x.dtype == snap.v.dtype == np.float64, (
        f"{case}: an f64 run's snapshot holds {snap.x.dtype} positions, {snap.v.dtype} velocities"
    )


# ================================================================== 3. momentum through a pass
@pytest.mark.parametrize(("dim", "solver"), dim_solver_params(slow=("3d", "2d-dfsph", "3d-dfsph")))
def test_adaptivity_pass_keeps_momentum(dim, solver):
    """METHOD.md §5, §6, §8: a split gives the children the parent's velocity and a merge
    gives the merged particle the group's mass-weighted mean velocity, so the total real
    momentum Σ m v is unchanged by an adaptivity pass, up to round-off. The fluid carries
    random velocities (set once) so that momentum is far from zero; the pass is called
    directly (``Multires.adapt``) between steps, while the refined box sweeps the slab.
    A merge also puts the merged particle at its group's centre of mass, so a pass that
    only merges keeps Σ m x of the real particles (splits spread their children, and a
    particle that absorbs a light group keeps its place, ``absorb.py``: both move it)."""
    scene = moving_region_scene(dim, half_period_steps=30)
    scene["adaptivity"]["interval"] = 1000  # only the direct calls below adapt
    # one thread: the same passes every run (see the profiled test)
    sim = make_sim(for_solver(scene, solver), threads=1)
    n = sim.pool.count()
    kind = sim.pool.p.kind.to_numpy()[:n]
    v = sim.pool.p.v.to_numpy()
    rng = np.random.default_rng(4321 + dim)
    real = np.isin(kind, REAL_KINDS)
    v[:n][real] = rng.normal(0.0, 0.5, size=(int(real.sum()), dim)) + 0.3  # a net drift too
    sim.pool.p.v.from_numpy(v)
    case = case_label(dim, solver)
    worst, worst_at = 0.0, None
    total = {"splits": 0, "merges": 0}
    passes = 0
    merge_only = []
    for step in range(1, 41):
        sim.step()
        sim.multires.take_counters()  # the step's own pass (the first step has one)
        before = raw_pool(sim)
        p0, scale0 = real_momentum(before)
        sim.multires.adapt(sim.time)
        ev = sim.multires.take_counters()
        after = raw_pool(sim)
        p1, scale1 = real_momentum(after)
        if ev["splits"] + ev["merges"] == 0:
            continue
        if ev["splits"] == 0 and ev["absorbed"] == 0:  # an absorbed group's receiver keeps its place
            (q0, xscale), (q1, _) = real_first_moment(before), real_first_moment(after)
            moved = float(np.linalg.norm(q1 - q0)) / xscale
            merge_only.append(moved)
            assert moved <= 1e-8, (  # measured: 4e-10 (2D), 1e-10 (3D)
                f"{case}, pass after step {step} ({ev['merges']} merges, no split): Σ m x of the real "
                f"particles moved by {np.linalg.norm(q1 - q0):.3e} kg m ({moved:.2e} of Σ m|x|); a merged "
                f"particle belongs at its group's centre of mass"
            )
        passes += 1
        total["splits"] += ev["splits"]
        total["merges"] += ev["merges"]
        rel = float(np.linalg.norm(p1 - p0)) / scale0
        if rel > worst:
            worst, worst_at = rel, (step, ev["splits"], ev["merges"], p0, p1, scale0)
        assert rel <= 1e-6, (
            f"{case}, pass after step {step} ({ev['splits']} splits, {ev['merges']} merges): total real "
            f"momentum {p0.tolist()} -> {p1.tolist()}, |ΔP| = {np.linalg.norm(p1 - p0):.3e}; expected "
            f"<= 1e-6 · Σ m|v| = {1e-6 * scale0:.3e} (ratio {rel:.2e})"
        )
    print(
        f"\n{case} momentum through passes: {passes} passes with events, {total['splits']} splits, "
        f"{total['merges']} merges; worst |ΔP|/Σ m|v| = {worst:.2e}"
        + (f" (after step {worst_at[0]}: {worst_at[1]} splits, {worst_at[2]} merges)" if worst_at else "")
    )
    assert total["splits"] > 0 and total["merges"] > 0, (
        f"{case}: the passes did not split and merge ({total['splits']} splits, {total['merges']} merges)"
    )
    print(
        f"{case}: {len(merge_only)} passes merged without splitting; Σ m x moved by at most "
        f"{max(merge_only, default=0):.2e} of Σ m|x|"
    )
    if solver == "wcsph":
        # the centre-of-mass check is the topology's, whatever the solver; its flow is the
        # one that gives merge-only passes (the dfsph run of this slab gave none, 2D)
        assert merge_only, f"{case}: no pass merged without splitting, so the centre of mass went unchecked"


# ================================================================== 4. momentum through coupling
# the quick run: the symmetric coupling under wcsph, the variational one under dfsph
@pytest.mark.slow_params("2d-variational", "3d-symmetric", "3d-variational", "3d-variational-dfsph")
@pytest.mark.parametrize(
    ("coupling", "solver"),
    [
        pytest.param("variational", "wcsph", id="variational"),
        pytest.param("symmetric", "wcsph", id="symmetric"),
        pytest.param("variational", "dfsph", id="variational-dfsph"),
        pytest.param("variational", "pbf", id="variational-pbf"),
    ],
)
def test_virtual_coupling_conserves_momentum(dim, coupling, solver):
    """METHOD.md §4, §8: the reaction of every force between a real and a virtual particle
    goes back to the real particle(s) the virtual one stands for, so internal forces across
    a level interface sum to zero over real particles. Random velocities shear and
    compress a refined blob far from the walls for 100 steps (no adaptivity after the
    first step): |ΔP| <= 1e-5 Σ m|v|. Both couplings: the variational one hands the
    reactions on in the force pass, the symmetric one in a pass of its own.

    Under the symmetric coupling only virtual children carry reactions here: a transient
    parent skips the virtual parents within its support (``interacts``; the pair meets
    at the fine level), and every coarse particle next to the refined core is one. So a
    wrong split of a virtual parent's reaction (each child taking all of it) fails the
    variational cases (|ΔP| / Σ m|v| = 7e-2 in 2D, 1e-1 in 3D) and not the symmetric ones."""
    scene = refined_blob_scene(dim)
    scene["adaptivity"]["coupling"] = coupling
    sim = make_sim(for_solver(scene, solver))
    case = case_label(dim, solver)
    solves = watch_solves(sim)
    n = sim.pool.count()
    kind = sim.pool.p.kind.to_numpy()[:n]
    counts = {k: int((kind == k).sum()) for k in (REGULAR, T_PARENT, T_CHILD, T_BOTH, V_CHILD, V_PARENT)}
    assert counts[T_PARENT] > 0 and counts[T_CHILD] > 0 and counts[V_CHILD] > 0 and counts[V_PARENT] > 0, (
        f"{case}: no level interface in the blob (kind counts {counts})"
    )
    v = sim.pool.p.v.to_numpy()
    rng = np.random.default_rng(1234 + dim)
    real = np.isin(kind, REAL_KINDS)
    v[:n][real] = rng.normal(0.0, 0.5, size=(int(real.sum()), dim))
    sim.pool.p.v.from_numpy(v)
    p0, scale = real_momentum(raw_pool(sim))
    impulse = 0.0  # Σ_steps dt Σ_real m |a|
    events = {"splits": 0, "merges": 0}
    for _ in range(100):
        dt = sim.step()
        pool = raw_pool(sim)
        r = np.isin(pool["kind"], REAL_KINDS)
        a = sim.pool.p.a.to_numpy()[: pool["n"]][r].astype(np.float64)
        impulse += dt * float((pool["m"][r] * np.linalg.norm(a, axis=1)).sum())
        impulse += sum(push for _name, _dp, push, _noise in solves[-2:]) if solves else 0.0
        ev = sim.stats()
        events["splits"] += ev["splits"]
        events["merges"] += ev["merges"]
    pool = raw_pool(sim)
    p1, _ = real_momentum(pool)
    r = np.isin(pool["kind"], REAL_KINDS)
    x, lv = pool["x"][r].astype(np.float64), pool["level"][r]
    gap = np.minimum(x.min(axis=1), (1.0 - x).min(axis=1)) - sim.h0 * 2.0**lv
    assert gap.min() > 0, (
        f"{case}: a particle came within its h of a wall (margin {gap.min():.3g} m); the test proves nothing"
    )
    kind_end = pool["kind"]
    assert (kind_end == V_CHILD).any() and (kind_end == V_PARENT).any(), f"{case}: the interface vanished"
    dp = float(np.linalg.norm(p1 - p0))
    print(
        f"\n{case} {coupling} coupling: kinds at start {counts}; events after construction {events}; "
        f"|ΔP| = {dp:.3e}, Σ m|v| = {scale:.3e}, ratio {dp / scale:.2e}, Σ dt Σ m|a| = {impulse:.3e}"
    )
    assert impulse > 1e3 * 1e-5 * scale, f"{case}: internal forces too weak to test (impulse {impulse:.3e})"
    assert dp <= 1e-5 * scale, (
        f"{case}: internal forces across the level interface changed the total real momentum by "
        f"|ΔP| = {dp:.3e} kg m/s in 100 steps (P {p0.tolist()} -> {p1.tolist()}); expected <= 1e-5 · Σ m|v| "
        f"= {1e-5 * scale:.3e} (ratio {dp / scale:.2e})"
    )
    if solver == "dfsph":
        # each solve on its own: Σ m Δv over the real particles (what the solve's pressure
        # accelerations add up to) against Σ m |Δv| (how hard it pushed)
        which, leak, push, floor, ratio = worst_leak(solves)
        pushed = sum(s[2] for s in solves)
        print(
            f"{case}: {len(solves)} pressure solves, Σ m|Δv| = {pushed:.3e} in all; worst (|Σ m Δv| - "
            f"round-off {floor:.2e}) / Σ m|Δv| = {ratio:.2e} ({which} solve)"
        )
        assert len(solves) == 200 and pushed > 1e3 * 1e-5 * scale, (
            f"{case}: {len(solves)} solves pushed Σ m|Δv| = {pushed:.3e} in all; too little to test"
        )
        assert ratio <= 1e-4, (
            f"{case}: a {which} solve changed the real particles' momentum by |Σ m Δv| = "
            f"{leak:.3e} kg m/s while pushing Σ m|Δv| = {push:.3e}; expected <= 1e-4 of it beyond "
            f"the float32 round-off {floor:.2e} (ratio {ratio:.2e}): a pressure reaction is not "
            f"handed back in full"
        )


def test_symmetric_coupling_is_refused_with_dfsph(dim):
    """The implicit solver hands a virtual particle's reaction to its owners within each
    iteration; the symmetric coupling's own reaction pass cannot: the scene is refused,
    in one line naming the key, its value and what to use."""
    from mrsph.scene.config import SceneError

    scene = for_solver(refined_blob_scene(dim), "dfsph")
    scene["adaptivity"]["coupling"] = "symmetric"
    with pytest.raises(SceneError) as info:
        load_scene(scene)
    lines = info.value.problems
    assert (
        len(lines) == 1
        and "adaptivity.coupling" in lines[0]
        and "dfsph" in lines[0]
        and "symmetric" in lines[0]
        and "\n" not in lines[0]
    ), f"{dim}D: expected one line naming adaptivity.coupling, its value and dfsph; got {lines}"
    scene["adaptivity"]["coupling"] = "variational"
    load_scene(scene)  # the same scene with the variational coupling loads
    scene["adaptivity"]["coupling"] = "symmetric"
    load_scene(with_solver(scene, "wcsph"))  # and so does the symmetric one with wcsph


# ================================================================== 5. merging into the coarsest level
@pytest.mark.slow
def test_refined_fluid_merges_back_into_the_coarsest_level(dim):
    """METHOD.md §6: particles merge wherever the merged particle would not meet the split
    criterion. With two levels, the fluid the refined box has left behind wants level 1
    (the background) and must coarsen again from the transition layer inward."""
    sim = make_sim(moving_region_scene(dim, half_period_steps=25, levels=2))
    splits = merges = 0
    for _ in range(60):
        sim.step()
        ev = sim.stats()
        splits += ev["splits"]
        merges += ev["merges"]
    lam = sim.particles(virtual=False)["lam"]
    print(
        f"\n{dim}D two levels: {splits} splits, {merges} merges in 60 steps; wanted level of real "
        f"particles in [{lam.min():.3g}, {lam.max():.3g}]"
    )
    assert splits > 0, f"{dim}D: the box refined nothing ({splits} splits)"
    assert merges > 0, (
        f"{dim}D: {splits} splits but {merges} merges in 60 steps, while the wanted level of real "
        f"particles reaches {lam.max():.3g} (= background level 1) behind the box"
    )


def stirred_slab_scene(dim: int, **adaptivity) -> dict:
    """A slab at rest, gravity off, two levels: a stirrer crosses it in 0.1 s, refining the
    fluid around it (the disturbance criterion) and stirring it, so that the split groups
    drift apart and are released; at 0.12 s it has left for a far corner, and nothing
    wants the fine level any more."""
    s0 = S0[dim]
    mid = [0.5] * (dim - 1)
    return {
        "description": "slab crossed by a stirrer",
        "dim": dim,
        "domain": {"min": [0.0] * dim, "max": [1.0] * dim},
        "particles": {"spacing": s0},
        "fluid": {
            "viscosity": 1.0,
            "stiffness": 1000.0,
            "blocks": [{"min": [0.2] + [0.3] * (dim - 1), "max": [0.8] + [0.7] * (dim - 1)}],
        },
        "physics": {"gravity": [0.0] * dim},
        "adaptivity": {"enabled": True, "levels": 2, "band": BAND[dim], **adaptivity},
        "criteria": [{"type": "disturbance", "level": 0}],
        "stirrers": [
            {
                "radius": 0.1,
                "strength": 20.0,
                "loop": False,
                "path": [[0.0, 0.25] + mid, [0.1, 0.75] + mid, [0.12, 0.95] + [0.05] * (dim - 1)],
            }
        ],
    }


@pytest.mark.slow_params("2d-default", "3d-default", "3d-merge-remnants")
@pytest.mark.parametrize("remnants", [False, True], ids=["default", "merge-remnants"])
def test_fine_fluid_a_stirrer_left_merges_back(dim, remnants):
    """METHOD.md §6: particles merge wherever the merged particle would not meet the split
    criterion. After a stir the released fine particles must gather again into groups
    that can merge. In 3D some are left, groups of 1–3 that no group can join, which
    ``merge_remnants`` merges where they sit among coarse particles, except those with no
    receiver for their light group within one coarse spacing (``ABSORB_REACH``). The
    bounds, 15 % of the real particles by default and 1 % with ``merge_remnants``, sit
    above what was measured (docs/validation.md, "Fine fluid merging back")."""
    sim = make_sim(stirred_slab_scene(dim, merge_remnants=remnants))
    sim.advance(0.2)
    p = sim.particles(virtual=False)
    fine = p["level"] == 0
    stuck = int((fine & (p["lam"] > 1.0 + sim.scene.adaptivity.hysteresis)).sum())
    n = len(p["level"])
    rel = p["m"] / (sim.m0 * 2.0 ** (dim * p["level"]))
    print(
        f"\n{dim}D merge_remnants={remnants}: {fine.sum()} fine of {n} real at 0.2 s, {stuck} of them "
        f"wanting level 1; {(rel < 0.999).sum()} lighter than nominal (lightest {rel.min():.3f})"
    )
    assert fine.sum() < n, f"{dim}D: nothing merged ({fine.sum()} fine of {n}); the test proves nothing"
    if remnants:
        assert stuck <= 0.01 * n, (
            f"{dim}D: {stuck} of {n} real particles are fine, want level 1 and have "
            f"not merged 0.08 s after the stirrer left, with merge_remnants on; "
            f"expected at most 1 %"
        )
    else:
        # 3D leaves groups of 1-3 (190 of 1791, 11 %); 2D all but a few (2 of 695)
        share = 0.15 if dim == 3 else 0.02
        assert stuck <= share * n, (
            f"{dim}D: {stuck} of {n} real particles are fine, want level 1 and have "
            f"not merged 0.08 s after the stirrer left; expected at most "
            f"{100 * share:g} %"
        )


@pytest.mark.slow_params("2d-merged", "3d-absorbed", "3d-merged")
@pytest.mark.parametrize("absorb", [0.5, 0.0], ids=["absorbed", "merged"])
def test_no_particle_falls_below_half_its_level_mass(dim, absorb):
    """Light groups go to a coarse neighbour (``adaptivity.absorb_below``): no real
    particle ends up lighter than half its level's nominal mass or heavier than twice it
    (``ABSORB_CAP``), and the real mass holds. Without it
    (absorb_below = 0) a remnant of one fine particle merges into a coarse particle of
    2^-d of its level's mass, whose children are as light, and so on down (METHOD.md §15):
    the second case shows the check can fail."""
    from mrsph.multires.absorb import ABSORB_CAP

    sim = make_sim(stirred_slab_scene(dim, merge_remnants=True, absorb_below=absorb))
    p0 = sim.particles(virtual=False)
    mass0 = math.fsum(p0["m"].astype(np.float64))
    absorbed, lightest = 0, math.inf
    for _ in range(20):
        sim.advance(0.01)
        p = sim.particles(virtual=False)
        rel = p["m"] / (sim.m0 * 2.0 ** (dim * p["level"]))
        lightest = min(lightest, float(rel.min()))
        absorbed += sim.stats()["absorbed"]
        if absorb:
            assert rel.min() >= 0.5 * (1 - 1e-6) and rel.max() <= ABSORB_CAP * (1 + 1e-6), (
                f"{dim}D at t = {sim.time:.2f} s: masses from {rel.min():.4f} to {rel.max():.4f} of "
                f"their level's nominal; expected within [0.5, {ABSORB_CAP}]"
            )
    mass = math.fsum(p["m"].astype(np.float64))
    assert abs(mass - mass0) <= 1e-6 * mass0, f"{dim}D: real mass {mass} against {mass0} at the start"
    print(f"\n{dim}D absorb_below={absorb}: {absorbed} groups absorbed, lightest particle {lightest:.3f} of nominal")
    if absorb:
        assert absorbed > 0, f"{dim}D: no group was absorbed; the test proves nothing"
    else:
        assert lightest < 0.5, f"{dim}D without absorption: lightest {lightest:.3f}; the stir made no cascade"


def coarse_block_scene(dim: int, half: int, band: float) -> dict:
    """A block at rest, ``half`` coarse spacings either side of the domain's centre, seeded
    coarse on two levels, for a fine particle put into it by hand."""
    s1 = 2 * S0[dim]
    return {
        "description": "coarse block with one fine particle",
        "dim": dim,
        "domain": {"min": [0.0] * dim, "max": [1.0] * dim},
        "particles": {"spacing": S0[dim]},
        "fluid": {
            "viscosity": 1.0,
            "stiffness": 1000.0,
            "hydrostatic_start": False,
            "blocks": [{"min": [0.5 - half * s1] * dim, "max": [0.5 + half * s1] * dim}],
        },
        "physics": {"gravity": [0.0] * dim},
        "adaptivity": {"enabled": True, "levels": 2, "interval": 1000, "band": band, "merge_remnants": True},
    }


@pytest.mark.slow_params("3d")  # the quick run keeps 2D (conftest.py, "two tiers")
def test_a_lone_fine_particle_among_coarse_ones_is_absorbed(dim):
    """A remnant of one fine particle in fluid that wants the coarse level (a drag's
    wake, when the fine fluid has merged back round it) is too light to merge alone, so
    it goes to a coarse neighbour (``absorb.py``). Its coarse neighbours are transient
    parents, made so by the remnant itself (every real coarse particle within h_c of a
    real fine one carries virtual children), so a receiver of any real kind must do:
    with regular receivers only, it stayed fine for good, at the centre of a coarse
    particle's virtual children, where its own level's density read above rho0 wherever
    it went. Under dfsph demo_2d's density solve then pumped it to megapascals and ran to
    its maximum iterations every step (after a drag in the window: 0.004-0.008x real
    time; docs/validation.md, "A cursor in resting water").
    Here: one fine particle in a coarse block at rest, four adaptivity passes."""
    s1 = 2 * S0[dim]
    sim = make_sim(coarse_block_scene(dim, 4, BAND[dim]))
    pool = raw_pool(sim)
    assert (pool["level"][np.isin(pool["kind"], REAL_KINDS)] == 1).all(), f"{dim}D: the seed is not all coarse"
    mass = real_mass(pool)
    # between four coarse particles (a lattice cell's centre), as a merged-back wake leaves one
    x = np.full((1, dim), 0.5 + 0.5 * s1 - 0.1 * S0[dim])
    sim.seeder.append(x, np.zeros((1, dim)), 0)
    mass += float(sim.lev.m[0])
    sim.multires.take_counters()
    for _ in range(4):
        sim.multires.adapt(sim.time)
    absorbed = sim.multires.take_counters()["absorbed"]
    after = raw_pool(sim)
    real = np.isin(after["kind"], REAL_KINDS)
    fine = np.flatnonzero(real & (after["level"] == 0))
    assert len(fine) == 0 and absorbed == 1, (
        f"{dim}D: after four passes {len(fine)} fine particle(s) left "
        f"({', '.join(describe(after, int(i)) for i in fine)}), {absorbed} group(s) absorbed; "
        f"expected the lone one absorbed by a coarse neighbour"
    )
    assert abs(real_mass(after) - mass) <= 1e-6 * mass, f"{dim}D: real mass {real_mass(after)} against {mass}"
    bad = link_violations(sim, after)
    assert not bad, f"{dim}D: " + "; ".join(bad)
    # the transient parents it made dropped their virtual children once it was gone
    assert not (after["kind"] == V_CHILD).any(), f"{dim}D: virtual children left with no fine particle"


@pytest.mark.slow_params("3d")  # the quick run keeps 2D (conftest.py, "two tiers")
@pytest.mark.parametrize("where", ["caged", "between"])
def test_a_fine_particle_caged_in_a_coarse_one_is_absorbed_whatever_the_criteria_want(dim, where):
    """A lone fine particle at a real coarse particle's place sits at the centre of that
    particle's virtual children, whose pushes cancel there and return to their owner: no
    pressure lowers its density, and in the stirred demo under dfsph its pressure rose to
    0.5 GPa and the step fell a hundredfold, while the criteria's hysteresis kept it from
    merging (``absorb.py``, ``caged``). Such a one is given to the coarse particle whatever
    the criteria want; one between coarse particles ("between") is left to them.
    Here the criteria want level 1.1 everywhere near it (a level-0 sphere 1.1 bands away),
    inside the hysteresis band: nothing splits or merges by them. Without ``caged`` the
    caged one stays."""
    s1 = 2 * S0[dim]
    band = 0.45  # the block (3 s1 either side) wants 0.83-1.37: nothing splits
    far = [0.5] * dim
    far[0] = 0.5 - 1.1 * band
    scene = coarse_block_scene(dim, 3, band)
    scene["criteria"] = [{"type": "region", "shape": "sphere", "level": 0, "center": far, "radius": 1e-3}]
    sim = make_sim(scene)
    pool = raw_pool(sim)
    real = np.isin(pool["kind"], REAL_KINDS)
    assert (pool["level"][real] == 1).all(), f"{dim}D: the seed is not all coarse"
    mass = real_mass(pool)
    # the coarse particle nearest the block's centre, and a lattice cell's centre beside it
    xs = pool["x"][real].astype(float)
    host = xs[np.argmin(np.linalg.norm(xs - 0.5, axis=1))]
    x = host + (1e-3 * S0[dim] if where == "caged" else 0.5 * s1)
    sim.seeder.append(x[None, :], np.zeros((1, dim)), 0)
    mass += float(sim.lev.m[0])
    sim.multires.take_counters()
    for _ in range(4):
        sim.multires.adapt(sim.time)
    counts = sim.multires.take_counters()
    after = raw_pool(sim)
    real = np.isin(after["kind"], REAL_KINDS)
    fine = np.flatnonzero(real & (after["level"] == 0))
    assert counts["splits"] == 0, f"{dim}D: the criteria split {counts['splits']}; they should want 1.1"
    if where == "caged":
        assert len(fine) == 0 and counts["absorbed"] == 1, (
            f"{dim}D: after four passes {len(fine)} fine particle(s) left "
            f"({', '.join(describe(after, int(i)) for i in fine)}), {counts['absorbed']} absorbed; "
            f"expected the caged one given to the coarse particle round it"
        )
    else:
        assert len(fine) == 1 and counts["absorbed"] == 0, (
            f"{dim}D: {len(fine)} fine particle(s) left, {counts['absorbed']} absorbed; expected the one "
            f"between coarse particles left fine, the criteria wanting neither level"
        )
    assert abs(real_mass(after) - mass) <= 1e-6 * mass, f"{dim}D: real mass {real_mass(after)} against {mass}"
    bad = link_violations(sim, after)
    assert not bad, f"{dim}D: " + "; ".join(bad)


@pytest.mark.slow_params("3d-criteria-only", "3d-near-regular")
@pytest.mark.parametrize("on", [False, True], ids=["criteria-only", "near-regular"])
def test_transient_parent_next_to_a_regular_fine_particle_splits_when_asked(dim, on):
    """METHOD.md §5.2's other trigger (``adaptivity.split_near_regular``): a transient
    parent with a regular particle of the finer level in its support splits, unless the
    criteria want that place merged. Here a regular level-0 particle is put beside a
    transient parent of the refined blob's interface whose wanted level (between the split
    and merge thresholds) does not ask for a split, and one adaptivity pass runs."""
    scene = refined_blob_scene(dim)
    scene["adaptivity"]["split_near_regular"] = on
    sim = make_sim(scene)
    pool = raw_pool(sim)
    lam = sim.pool.p.lam.to_numpy()[: pool["n"]]
    eta = float(scene["adaptivity"].get("hysteresis", 0.25))
    parents = np.flatnonzero(
        np.isin(pool["kind"], PARENT_ROLE) & (pool["level"] == 1) & (lam >= 1 - eta) & (lam <= 1 + eta)
    )
    assert len(parents) > 0, f"{dim}D: no transient parent between the thresholds to test"
    # the one furthest from the refined box, so that no other fine particle is near it
    target = parents[np.argmax(lam[parents])]
    xt = pool["x"][target].astype(np.float64)
    away = np.sign(xt - 0.5)
    sim.seeder.append((xt + 0.25 * S0[dim] * away)[None], np.zeros((1, dim)), 0)
    sim.multires.adapt(sim.time)  # (sorts the pool: slots move, so find the parent by place)
    after = raw_pool(sim)
    coarse = np.flatnonzero((after["level"] == 1) & np.isin(after["kind"], REAL_KINDS + (V_PARENT,)))
    here = coarse[np.argmin(np.linalg.norm(after["x"][coarse] - xt, axis=1))]
    assert np.linalg.norm(after["x"][here] - xt) < 1e-6, f"{dim}D: the parent at {xt} is gone"
    split = after["kind"][here] == V_PARENT
    assert split == on, (
        f"{dim}D, split_near_regular = {on}: the transient parent at {xt} "
        f"(wanted level {lam[target]:.3f}) {'split' if split else 'did not split'}"
    )


# ================================================================== 6. seeding a block
@pytest.mark.slow_params("3d")  # the quick run keeps 2D (conftest.py, "two tiers")
def test_adaptive_seed_holds_the_uniform_runs_fluid(dim):
    """A block whose sides are not whole cells of the coarsest level (0.31, 0.27 and
    0.13 m against 4 cm: 7, 6 and 3 cells, and 3 or 1 cm left over) is seeded with the
    coarsest lattice where whole cells fit and finer ones in the slabs left over (a 2 cm
    layer, then a 1 cm one), so that the adaptive run starts with exactly the fluid of its
    uniform twin at the finest spacing: the same mass, the block filled to its sides and
    no further, no two seeds closer than the finer one's spacing. Seeding only the
    coarsest lattice left a 1-3 cm gap on the far sides (here 20 % less fluid in 2D,
    26 % in 3D). The mass is also read after the first adaptivity passes, which split
    coarse seeds next to fine ones (§8 rule e)."""
    s0 = 0.01
    lo, hi = [0.0] * dim, [0.31, 0.27, 0.13][:dim]
    scene = {
        "description": "incommensurate block",
        "dim": dim,
        "domain": {"min": [0.0] * dim, "max": [0.4] * dim},
        "particles": {"spacing": s0},
        "fluid": {"blocks": [{"min": lo, "max": hi}], "hydrostatic_start": False},
        "adaptivity": {"enabled": True, "levels": 3},
    }
    sim = make_sim(scene)
    seeds = sim.seeder.block_lattices(lo, hi)
    x = np.concatenate([xs for _, xs in seeds])
    s_own = np.concatenate([np.full(len(xs), s0 * 2.0**level) for level, xs in seeds])
    per_level = {level: sum(len(xs) for l2, xs in seeds if l2 == level) for level in range(3)}
    uniform_n = sim.scene.estimate_particles()
    m0 = float(sim.lev.m[0])
    mass = real_mass(raw_pool(sim))
    print(
        f"\n{dim}D seed: {per_level} particles per level, mass after the first passes "
        f"{mass / m0:.4f} m0 (uniform lattice {uniform_n})"
    )
    assert min(per_level.values()) > 0, f"{dim}D: expected seeds at every level, got {per_level}"
    seeded = sum(n * 2 ** (dim * level) for level, n in per_level.items())
    assert seeded == uniform_n, f"{dim}D: the seed holds {seeded} m0, the uniform lattice {uniform_n} m0"
    assert abs(mass / m0 - uniform_n) <= 1e-5 * uniform_n, (
        f"{dim}D: the adaptive run starts with {mass / m0:.4f} m0 of fluid, the uniform lattice {uniform_n} m0"
    )
    cells_lo = (x - 0.5 * s_own[:, None]).min(axis=0)
    cells_hi = (x + 0.5 * s_own[:, None]).max(axis=0)
    assert np.allclose(cells_lo, lo, atol=1e-9) and np.allclose(cells_hi, hi, atol=1e-9), (
        f"{dim}D: the seed's cells span {cells_lo.tolist()} to {cells_hi.tolist()}, the block {lo} to {hi}"
    )
    d, j = cKDTree(x).query(x, k=2)
    closest = d[:, 1] / np.minimum(s_own, s_own[j[:, 1]])
    assert closest.min() >= 1.0 - 1e-9, (
        f"{dim}D: seeds overlap: nearest neighbour at {closest.min():.3f} of the finer spacing"
    )


# ================================================================== 9. split compression
def jittered_block_scene(dim: int, solver: str, fade: float) -> dict:
    """A block of coarse fluid at rest, gravity off, refined to level 0 wherever the mouse
    is (none yet); no pass but the ones the test runs (``interval``)."""
    s0 = S0[dim]
    scene = {
        "description": "coarse block, refined under the mouse",
        "dim": dim,
        "domain": {"min": [0.0] * dim, "max": [1.0] * dim},
        "particles": {"spacing": s0},
        "fluid": {"viscosity": 1.0, "stiffness": 1000.0, "blocks": [{"min": [0.3] * dim, "max": [0.7] * dim}]},
        "physics": {"gravity": [0.0] * dim, "cfl": 0.2},
        "adaptivity": {"enabled": True, "levels": 2, "interval": 100000, "band": BAND[dim], "split_fade": fade},
        "criteria": [{"type": "disturbance", "level": 0}],
    }
    return for_solver(scene, solver)


@pytest.mark.parametrize(("dim", "solver"), dim_solver_params(slow=("3d", "3d-dfsph")))
def test_split_children_start_at_their_parents_pressure(dim, solver):
    """``adaptivity.split_fade`` (multires/fade.py): the children of a split of a
    disordered coarse fluid read more than their parent did where they land near another
    parent's; each carries that excess (``drho``, over its parent's density, rho0 at
    least), measured at its first density pass; the pressure leaves it out (the
    equation of state reads rho - drho); it follows the child's density down as the
    children spread, and decays as exp(-t/tau) at most. The coarse block is jittered by
    up to a fifth of its spacing, as a fluid that has flowed is, so that the children
    overlap."""
    from mrsph.scene.interaction import Disturbance

    tau = 0.01
    scene = jittered_block_scene(dim, solver, tau)
    sim = make_sim(scene, threads=1)
    state = sim.save_state()
    rng = np.random.default_rng(7)
    n = state["n"]
    s1 = 2.0 * S0[dim]
    x = state["attributes"]["x"]
    inside = np.flatnonzero(np.linalg.norm(x[:n] - 0.5, axis=1) < 0.08)  # all split below
    x[inside] += rng.uniform(-0.2 * s1, 0.2 * s1, size=(len(inside), dim)).astype(x.dtype)
    sim.restore_state(state)
    # no density pass before the split: the parents keep the density they were seeded
    # with, rho0, as a settled pool's do (demo_2d at rest: 1.003 rho0 on the median)
    # though they are not on a lattice; one taken here would read the jitter as a
    # compression of the coarse fluid, which the split rightly hands on
    before = raw_pool(sim)
    coarse_rho = {
        tuple(xc): r
        for xc, r, k, l in zip(before["x"], sim.pool.p.rho.to_numpy()[: before["n"]], before["kind"], before["level"])
        if k in REAL_KINDS and l == 1
    }
    sim.set_disturbance(Disturbance((0.5,) * dim, 0.1, 1e-6, "push", (0.0,) * dim))
    sim.multires.adapt(sim.time)
    sim.run_phases("grid", "density")
    pool = raw_pool(sim)
    rho = sim.pool.p.rho.to_numpy()[: pool["n"]]
    drho = sim.pool.p.drho.to_numpy()[: pool["n"]]
    pres = sim.pool.p.p.to_numpy()[: pool["n"]]
    kids = np.flatnonzero(np.isin(pool["kind"], CHILD_ROLE) & (pool["level"] == 0))
    assert len(kids) >= 8, f"{case_label(dim, solver)}: only {len(kids)} split children to test"
    parent_rho = np.array(
        [max(coarse_rho[tuple(pool["x"][pool["parent"][i]])], 1000.0) for i in kids], np.float32
    )  # its parent's density, rho0 at least
    expected = np.maximum(rho[kids] - parent_rho, np.float32(0.0))
    worst = np.max(np.abs(drho[kids] - expected))
    assert worst <= 1e-3, (
        f"{case_label(dim, solver)}: a child's drho differs from its density's excess "
        f"over its parent's by {worst:.3g} kg/m^3 (expected round-off)"
    )
    offset = kids[drho[kids] > 1.0]
    assert len(offset) >= len(kids) // 10, (
        f"{case_label(dim, solver)}: {len(offset)} of {len(kids)} children read more than 1 kg/m^3 above "
        f"their parent (the jitter should overlap a tenth at least); largest excess {drho[kids].max():.3g}"
    )
    if solver == "wcsph":
        k, rho0 = 1000.0, 1000.0  # the linear equation of state, p = k (rho - rho0)
        want = np.maximum(k * (rho[offset].astype(np.float64) - drho[offset] - rho0), 0.0)
        err = np.max(np.abs(pres[offset] - want))
        assert err <= 1e-3 * rho0 * k, (
            f"{case_label(dim, solver)}: a split child's pressure is off p(rho - drho) by {err:.3g} Pa"
        )
    total0 = float(drho[pool["level"] == 0].sum())
    for _ in range(20):
        sim.step()
    n = sim.pool.count()
    rho, drho = sim.pool.p.rho.to_numpy()[:n], sim.pool.p.drho.to_numpy()[:n]
    ref = sim.pool.p.rho_ref.to_numpy()[:n]
    # followed: never more than what the child still reads above its reference
    over = drho - np.maximum(rho - ref, 0.0)
    worst = int(np.argmax(over))
    assert over[worst] <= 1e-3, (
        f"{case_label(dim, solver)}: a child keeps drho {drho[worst]:.4g} kg/m^3 out "
        f"of its pressure while it reads {rho[worst]:.6g} against its reference "
        f"{ref[worst]:.6g}"
    )
    # and faded: at most what exp(-t/tau) leaves
    total, most = float(drho.sum()), total0 * math.exp(-sim.time / tau)
    assert total <= 1.001 * most, (
        f"{case_label(dim, solver)}: after {sim.time * 1e3:.2f} ms the children's "
        f"drho sums to {total:.4g}, more than {most:.4g} = {total0:.4g} "
        f"exp(-t/{tau})"
    )
    # what it is for: the fluid does not take the sampling error for a compression.
    # Measured after these 20 steps (2.5 ms in 2D, 5 ms in 3D): 0.56, 0.78 m/s (2D, 3D),
    # 0.35, 1.01 m/s with dfsph; with split_fade = 0 5.2, 3.9, 6.6 and 16 m/s
    fastest = float(np.linalg.norm(sim.particles(virtual=False)["v"], axis=1).max())
    # pbf's tensile correction is one pressure on every level, in the coarsest level's unit
    # (METHOD.md §17), four times the finest level's own here: its fresh children are
    # pushed harder (2.27 m/s, 2026-12-02)
    most = 2.5 if solver == "pbf" else 2.0
    assert fastest <= most, (
        f"{case_label(dim, solver)}: a split of the jittered block at rest threw a "
        f"particle at {fastest:.2f} m/s within {sim.time * 1e3:.2f} ms (expected <= {most})"
    )


def split_under_a_cursor(dim: int, jitter_radius: float = 0.08):
    """The jittered block (wcsph, tau = 1 s; jittered within ``jitter_radius`` of its
    centre) split under a still cursor, three steps on: the children carry their
    offsets, measured and followed."""
    from mrsph.scene.interaction import Disturbance

    sim = make_sim(jittered_block_scene(dim, "wcsph", 1.0), threads=1)
    state = sim.save_state()
    rng = np.random.default_rng(7)
    n, s1 = state["n"], 2.0 * S0[dim]
    x = state["attributes"]["x"]
    inside = np.flatnonzero(np.linalg.norm(x[:n] - 0.5, axis=1) < jitter_radius)
    x[inside] += rng.uniform(-0.2 * s1, 0.2 * s1, size=(len(inside), dim)).astype(x.dtype)
    sim.restore_state(state)
    sim.set_disturbance(Disturbance((0.5,) * dim, 0.1, 1e-6, "push", (0.0,) * dim))
    sim.multires.adapt(sim.time)
    for _ in range(3):
        sim.step()
    return sim


@pytest.mark.parametrize("dim", DIMS_3D_SLOW)
def test_a_merge_starts_at_the_pressure_its_group_had(dim):
    """``adaptivity.split_fade`` for a merge: a merged particle's reference density is
    what its group's pressure read, the children's mass-weighted rho - drho (rho0 at
    least), not their raw density. Against the raw density, children that still carried
    a split's offset made merged particles whose compression their pressure took in
    full: demo_2d, the cursor held still at the mouse's strength for 0.1 s and let go,
    the kinetic energy reached 44-52 J within 20 ms at four places and times, 14-42 J
    against rho - drho (docs/validation.md, "A cursor in resting water")."""
    sim = split_under_a_cursor(dim)
    pool = raw_pool(sim)
    rho = sim.pool.p.rho.to_numpy()[: pool["n"]].astype(np.float64)
    drho = sim.pool.p.drho.to_numpy()[: pool["n"]].astype(np.float64)
    centres, seen, raw = [], [], []  # each group's centre of mass, and what it read
    for vp in np.flatnonzero(pool["kind"] == V_PARENT):
        ch = pool["children"][vp][: pool["nchild"][vp]]
        m = pool["m"][ch].astype(np.float64)
        centres.append((m[:, None] * pool["x"][ch]).sum(axis=0) / m.sum())
        seen.append(float((m * (rho[ch] - np.maximum(drho[ch], 0.0))).sum() / m.sum()))
        raw.append(float((m * rho[ch]).sum() / m.sum()))
    seen, raw = np.array(seen), np.array(raw)
    carried = int((raw - seen > 1.0).sum())
    # the stats read the density the pressure reads (docs/output.md)
    real = np.isin(pool["kind"], REAL_KINDS)
    want = float((rho - np.maximum(drho, 0.0))[real].max()) / 1000.0
    got = sim.stats()["max_density_ratio"]
    assert abs(got - want) <= 1e-6, (
        f"{dim}D: stats max_density_ratio {got:.6f}, the largest rho - drho "
        f"{want:.6f} rho0 (raw {rho[real].max() / 1000.0:.6f})"
    )
    sim.set_disturbance(None)
    sim.multires.adapt(sim.time)
    after = raw_pool(sim)
    ref = sim.pool.p.rho_ref.to_numpy()[: after["n"]]
    born = sim.pool.p.drho.to_numpy()[: after["n"]] == -1.0
    merged = np.flatnonzero((after["kind"] == REGULAR) & (after["level"] == 1) & born)
    # a merged particle stands at its group's centre of mass (a gathered group's is
    # elsewhere: those match none)
    dist, g = cKDTree(np.array(centres)).query(after["x"][merged].astype(np.float64))
    hit = dist < 1e-4 * S0[dim]
    matched = int(hit.sum())
    worst = float(np.max(np.abs(ref[merged[hit]] - np.maximum(seen[g[hit]], 1000.0)), initial=0.0))
    assert carried >= 4 and matched >= 4, (
        f"{dim}D: {carried} of {len(centres)} groups carry an offset and "
        f"{matched} of {len(merged)} merged particles matched one (expected "
        f">= 4 each: the test is void)"
    )
    assert worst <= 0.05, (
        f"{dim}D: a merged particle's reference density is off its group's mass-weighted "
        f"rho - drho (rho0 at least) by {worst:.3g} kg/m^3"
    )


@pytest.mark.parametrize("dim", DIMS_3D_SLOW)
def test_merging_back_compresses_nothing_around_it(dim):
    """``adaptivity.split_fade`` around a change of level: a particle whose neighbourhood
    an adaptivity pass changed (a merge, an absorption or a new virtual parent within
    h_c; a split or new virtual children of a coarse particle within h_c of a fine one)
    re-measures its offset against what its pressure read, so that no pass alone, the
    positions unchanged, raises the density any particle's pressure reads (rho - drho)
    above what it read before, rho0 at least. The cursor leaves; three passes, each
    followed by a density pass. Measured first on demo_2d: with only the merged
    particle's own offset, its neighbours' densities rose a pass later, unhidden, and
    the release of a cursor held at the mouse's strength peaked at 19-44 J; with its
    neighbours re-measured, 3-6 J (docs/validation.md, "A cursor in resting water")."""
    sim = split_under_a_cursor(dim)
    sim.run_phases("grid", "density")

    def seen():
        pool = raw_pool(sim)
        real = np.flatnonzero(np.isin(pool["kind"], REAL_KINDS))
        rho = sim.pool.p.rho.to_numpy()[: pool["n"]][real].astype(np.float64)
        drho = sim.pool.p.drho.to_numpy()[: pool["n"]][real].astype(np.float64)
        return pool["x"][real].astype(np.float64), rho - np.maximum(drho, 0.0)

    x0, eff0 = seen()
    sim.set_disturbance(None)
    n_before, checked = len(x0), 0
    for npass in range(3):
        sim.multires.adapt(sim.time)
        sim.run_phases("grid", "density")
        x1, eff1 = seen()
        dist, j = cKDTree(x0).query(x1)
        same = dist < 1e-7  # there before the pass, and not moved by it
        rise = eff1[same] - np.maximum(eff0[j[same]], 1000.0)
        worst = int(np.argmax(rise))
        assert rise[worst] <= 1e-3, (
            f"{dim}D, pass {npass + 1} after the cursor left: a particle's pressure read "
            f"{eff0[j[same]][worst]:.6g} kg/m^3 before the pass and {eff1[same][worst]:.6g} after it, at the "
            f"same place ({int((rise > 1e-3).sum())} of {int(same.sum())} rose above rho0 and their density "
            f"before)"
        )
        checked += int(same.sum())
        x0, eff0 = x1, eff1
    assert len(x0) < n_before and checked > 0, (
        f"{dim}D: {n_before} real particles before the passes, {len(x0)} after: nothing merged, the test is void"
    )


@pytest.mark.parametrize("dim", DIMS_3D_SLOW)
def test_a_split_moves_no_mass(dim):
    """The placement of a split's children (``multires/placement.py``, the spacing
    relaxation) spreads them about their parent's place and does not move the group: its
    centre of mass is where the parent was, which is where its virtual parent, standing
    for it at the coarse level, stays. A transient parent, next to fine particles, split
    when the cursor grows: the relaxation pushes its children away from the fine ones.
    Moved as a group, towards the coarse side, the virtual parent followed them at the
    step's end and its coarse neighbours took the mass it brought for a compression: in
    demo_2d under a dragged cursor a parent moved 7 mm, a quarter of its spacing, its
    coarse neighbours went to 1.03-1.08 rho0 in a step, and the density solve threw its
    children at 2.6 m/s (docs/validation.md, "A cursor in resting water")."""
    from mrsph.scene.interaction import Disturbance

    sim = split_under_a_cursor(dim, jitter_radius=0.16)
    before = raw_pool(sim)
    was_real = np.isin(before["kind"], REAL_KINDS) & (before["level"] == 1)
    coarse = cKDTree(before["x"][was_real].astype(np.float64))
    sim.set_disturbance(Disturbance((0.5,) * dim, 0.14, 1e-6, "push", (0.0,) * dim))
    sim.multires.adapt(sim.time)
    pool = raw_pool(sim)
    s1 = 2.0 * S0[dim]
    worst, spread, groups = 0.0, 0.0, 0
    for vp in np.flatnonzero((pool["kind"] == V_PARENT) & (pool["level"] == 1)):
        dist, _ = coarse.query(pool["x"][vp].astype(np.float64))
        ch = pool["children"][vp][: pool["nchild"][vp]]
        if dist > 1e-9 or len(ch) != 2**dim:
            continue  # not a particle split in this pass
        m = pool["m"][ch].astype(np.float64)
        xc = pool["x"][ch].astype(np.float64)
        centre = (m[:, None] * xc).sum(axis=0) / m.sum()
        worst = max(worst, float(np.linalg.norm(centre - pool["x"][vp])))
        # how far the placement moved the children off their lattice about the parent,
        # on which each is sqrt(d)/2 fine spacings from it
        off = np.abs(np.linalg.norm(xc - pool["x"][vp], axis=1) - 0.5 * math.sqrt(dim) * S0[dim]).max()
        spread = max(spread, float(off))
        groups += 1
    assert groups >= 4 and spread > 0.05 * S0[dim], (
        f"{dim}D: {groups} particles split in the pass, their children moved at most {spread / S0[dim]:.3g} "
        f"fine spacings off the lattice (expected >= 4 splits and a move > 0.05: the test is void)"
    )
    assert worst <= 1e-5 * s1, (
        f"{dim}D: a split's children have their centre of mass "
        f"{worst / s1:.3g} coarse spacings from their parent's place (expected round-off)"
    )


def test_scratch_flags_are_distinct_single_bits():
    """The adaptivity pass ORs and masks its scratch flags: two flags on one bit would
    make a particle carry the other's meaning."""
    from mrsph.multires import topology

    bits = sorted(topology._FLAGS)
    assert bits == [1 << k for k in range(len(bits))], f"flag bits {bits} are not distinct single bits"


def test_mass_is_the_only_attribute_divided_on_split_or_summed_on_merge():
    """The split and merge kernels (multires/topology.py) write the divide/sum rules of
    the mass by hand, as the merge's mass-weighted means need it; an attribute given
    either rule would be carried wrongly."""
    from mrsph.sph.particles import ATTRIBUTES

    ruled = [a.name for a in ATTRIBUTES if a.on_split == "divide" or a.on_merge == "sum"]
    assert ruled == ["m"], f"attributes with divide/sum rules: {ruled}; topology.py writes only the mass"
