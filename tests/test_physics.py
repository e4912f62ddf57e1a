"""Single-resolution SPH physics (METHOD.md §1) held to numbers: conservation, a fluid at
rest, a dam break against the experiment, blow-up reporting and the time-step bounds.

Scenes are built in code, small and coarse, so that the file stays within a few minutes
on a 2-core CPU. Each test starts a fresh Taichi program (``fresh_program``) so that the
offline cache of an earlier run serves its kernels.
"""

import math
import re

import numpy as np
import pytest
from scenekit import (
    DIMS_3D_SLOW,
    SolveLog,
    advance_logged,
    box,
    case_id,
    dim_solver_params,
    known_xfail,
    watch_solves,
    with_solver,
    worst_leak,
)

from mrsph.scene.config import load_scene

G = 9.81
RHO0 = 1000.0
DIMS = (2, 3)

pytestmark = pytest.mark.usefixtures("fresh_program")

# Tests that fail because of the library, with what was measured when they were marked
# (reported to the lead; the tolerance is not loosened): {(test key, case id): reason}. A
# test listed here runs and reports its numbers, but its failure does not fail the suite
# (``known_xfail``: xfail, not strict).
KNOWN_FAILURES: dict[tuple[str, str], str] = {}
# None today: the resting tanks settle under both solvers (docs/validation.md, "Resting tank").


def stiffness_for(height: float) -> float:
    """k with sqrt(k) = 10 sqrt(2 g H): sound ten times the largest free-fall speed, so
    that the density varies by about 1 % (weakly compressible SPH)."""
    return (10.0 * math.sqrt(2.0 * G * height)) ** 2


def make_sim(scene: dict):
    from mrsph.simulation import Simulation

    return Simulation(load_scene(scene), arch="cpu")


def real(sim) -> dict:
    return sim.particles(virtual=False)


def alive_slots(sim, name: str) -> np.ndarray:
    """An attribute of the pool slots [0, n) (no DEAD slots right after a sort)."""
    return getattr(sim.pool.p, name).to_numpy()[: sim.pool.count()]


def set_alive_slots(sim, name: str, values: np.ndarray):
    field = getattr(sim.pool.p, name)
    full = field.to_numpy()
    full[: sim.pool.count()] = values
    field.from_numpy(full)


def gap_to_walls(sim, x: np.ndarray) -> float:
    lo = np.asarray(sim.scene.domain.min, float)
    hi = np.asarray(sim.scene.domain.max, float)
    return float(min((x - lo).min(), (hi - x).min()))


# ================================================================== momentum
def blob_scene(dim):
    """A cube of fluid in the middle of a large box, gravity off: in 100 steps no particle
    comes within h of a wall, so only internal forces act."""
    lo, hi = box(dim, (0.0, 0.0), (1.0, 1.0), (0.0, 1.0))
    blo, bhi = box(dim, (0.4, 0.4), (0.6, 0.6), (0.4, 0.6))
    return {
        "description": "free blob, gravity off",
        "dim": dim,
        "domain": {"min": lo, "max": hi},
        "particles": {"spacing": 0.025},
        "fluid": {"viscosity": 1.0, "stiffness": 1000.0, "blocks": [{"min": blo, "max": bhi}]},
        "physics": {"gravity": [0.0] * dim, "cfl": 0.2},
    }


# the DFSPH cases compile a second solver (minutes on 2 cores): slow; the default run
# keeps the per-solve check in test_multires' variational-dfsph coupling case
@pytest.mark.parametrize(("dim", "solver"), dim_solver_params(slow=("2d-dfsph", "3d-dfsph")))
def test_internal_forces_conserve_momentum(dim, solver):
    """Pair forces are antisymmetric, so the total momentum of a free blob does not
    change. With DFSPH the pressure is in the solves' velocity updates, not in ``a``:
    their pushes (Σ m |Δv| of each solve) count in the impulse, and each solve's own
    Σ m Δv over the particles must vanish."""
    sim = make_sim(with_solver(blob_scene(dim), solver))
    solves = watch_solves(sim)
    case = f"{dim}D {solver}"
    n = sim.pool.count()
    rng = np.random.default_rng(1234 + dim)
    # random velocities of 0.5 m/s scale shear and compress the blob in every direction,
    # so that pressure and viscosity forces are far from zero
    set_alive_slots(sim, "v", rng.normal(0.0, 0.5, size=(n, dim)))
    p0 = real(sim)
    m0 = p0["m"].astype(np.float64)
    mom0 = (m0[:, None] * p0["v"]).sum(axis=0)
    scale = float((m0 * np.linalg.norm(p0["v"], axis=1)).sum())  # Σ m |v|
    impulse = 0.0  # Σ_steps dt Σ m |a|
    for _ in range(100):
        dt = sim.step()
        a = alive_slots(sim, "a").astype(np.float64)
        impulse += dt * float((alive_slots(sim, "m") * np.linalg.norm(a, axis=1)).sum())
    impulse += sum(push for _which, _dp, push, _noise in solves)
    p1 = real(sim)
    assert len(p1["m"]) == len(m0), "particles were created or lost"
    gap = gap_to_walls(sim, p1["x"])
    assert gap > sim.h0, f"a particle came within {gap:.3g} m of a wall (h = {sim.h0}); the test proves nothing"
    mom1 = (p1["m"].astype(np.float64)[:, None] * p1["v"]).sum(axis=0)
    dp = float(np.linalg.norm(mom1 - mom0))
    print(
        f"\n{case} momentum: |ΔP| = {dp:.3e}, Σ m|v| = {scale:.3e}, ratio {dp / scale:.2e}, "
        f"Σ dt Σ m|a| = {impulse:.3e} kg m/s"
    )
    # the forces did real work: their total impulse dwarfs the bound below
    assert impulse > 1e3 * 1e-5 * scale, f"internal forces too weak to test (impulse {impulse:.3e})"
    assert dp <= 1e-5 * scale, (
        f"{case}: internal forces changed the total momentum by |ΔP| = {dp:.3e} kg m/s in 100 steps; "
        f"expected <= 1e-5 · Σ m|v| = {1e-5 * scale:.3e} (ratio {dp / scale:.2e})"
    )
    if solves:
        which, leak, push, floor, ratio = worst_leak(solves)
        print(
            f"{case}: {len(solves)} solves; worst (|Σ m Δv| - round-off {floor:.2e}) / Σ m|Δv| = "
            f"{ratio:.2e} ({which} solve)"
        )
        assert ratio <= 1e-4, (
            f"{case}: a {which} solve changed the momentum by |Σ m Δv| = {leak:.3e} kg m/s while pushing "
            f"Σ m|Δv| = {push:.3e}; expected <= 1e-4 of it beyond the float32 round-off {floor:.2e} "
            f"(ratio {ratio:.2e})"
        )


# ================================================================== fluid at rest
TANK_H = 0.3  # fluid depth, m
TANK_W = 0.3  # tank width (and depth in 3D), m


def tank_scene(dim):
    spacing = 0.02 if dim == 2 else 0.03
    lo, hi = box(dim, (0.0, 0.0), (TANK_W, 2.0 * TANK_H), (0.0, TANK_W))
    blo, bhi = box(dim, (0.0, 0.0), (TANK_W, TANK_H), (0.0, TANK_W))
    return {
        "description": "fluid at rest in a tank",
        "dim": dim,
        "domain": {"min": lo, "max": hi},
        "particles": {"spacing": spacing},
        "fluid": {"viscosity": 2.0, "stiffness": stiffness_for(TANK_H), "blocks": [{"min": blo, "max": bhi}]},
        "physics": {"cfl": 0.2},
    }


def free_surface_height(x: np.ndarray, spacing: float, lo: float, hi: float) -> float:
    """Mean height of the top of the fluid between ``lo`` and ``hi`` in x: the highest
    particle of each column of width ``spacing``, plus half a spacing (a particle stands
    for the cell around it)."""
    inside = (x[:, 0] > lo) & (x[:, 0] < hi)
    cols = np.floor(x[inside, 0] / spacing).astype(int)
    tops = [x[inside][cols == c, 1].max() for c in np.unique(cols)]
    return float(np.mean(tops)) + 0.5 * spacing


def test_lattice_block_starts_at_rest_density(dim):
    """m0 = rho0 / lattice_density_sum puts every particle of a lattice block at rest
    density, next to the walls and in the corners too (mirror ghosts), so that a block
    without gravity stays exactly at rest."""
    scene = tank_scene(dim)
    scene["physics"]["gravity"] = [0.0] * dim
    sim = make_sim(scene)
    for _ in range(5):
        sim.step()
    p = real(sim)
    x = p["x"].astype(np.float64)
    below_surface = x[:, 1] < TANK_H - sim.h0  # the free surface has less density
    rho = p["rho"][below_surface].astype(np.float64)
    err = np.abs(rho / RHO0 - 1.0)
    k = int(np.argmax(err))
    assert below_surface.sum() > 0.5 * len(x)
    # f32: the sum of a few dozen terms, each rounded to ~6e-8
    assert err[k] <= 2e-5, (
        f"{dim}D: density {rho[k]:.4f} at {x[below_surface][k].round(3)}; expected "
        f"{RHO0} within 2e-5 relative in a lattice block at rest"
    )
    # at rest up to round-off: a density error of 1e-3 anywhere (a missing wall image, say)
    # would push with about k rho0 1e-3 / (rho0 h) = 15 m/s², far beyond this bound
    speed = float(np.linalg.norm(p["v"], axis=1).max())
    bound = 0.01 * G * sim.time
    assert speed <= bound, (
        f"{dim}D: a lattice block without gravity started moving: max speed "
        f"{speed:.3g} m/s after {sim.time:.2e} s; expected <= {bound:.2e} m/s "
        f"(1 % of what gravity would have given)"
    )


SETTLE_S = 1.5  # simulated seconds before measuring
MEASURE_S = 0.3  # then averaged over this long: several periods of the pool's sound
SAMPLE_S = 0.002  # modes (4 H / c = 0.05 s), which viscosity damps only slowly;
# sampled every 2 ms, physics.dt_max: every step of a DFSPH run, whose pressure swings by
# ±20 % over a cycle of ~6 steps around the hydrostatic mean (its Jacobi solves stop at
# their tolerance at a different point of the cycle each step); every fifth step, as
# first written, locked onto the cycle's peaks and read +12 % on a 2D tank whose mean
# over 40 steps was +2 %


@pytest.fixture(scope="module", params=dim_solver_params(slow=("3d", "2d-dfsph", "3d-dfsph"), fixture=True))
def tank_run(request):
    """One settled tank per dimension and pressure solver, measured; shared by the tank
    tests below. A DFSPH run reads its stats row after every step (``SolveLog``). The
    DFSPH tanks are long (900 steps of dt_max and a row a step): marked slow; so is the
    3D one (the quick run keeps 2D; conftest.py, "two tiers")."""
    from mrsph import runtime

    runtime.reset()
    dim, solver = request.param
    sim = make_sim(with_solver(tank_scene(dim), solver))
    log = SolveLog()
    s, h = float(sim.s0), float(sim.h0)
    lo = np.asarray(sim.scene.domain.min, float)
    hi = np.asarray(sim.scene.domain.max, float)
    p0 = real(sim)
    out = {
        "dim": dim,
        "solver": solver,
        "case": case_id(dim, solver),
        "log": log,
        "spacing": s,
        "lo": lo,
        "hi": hi,
        "n0": len(p0["m"]),
        "mass0": math.fsum(p0["m"].astype(np.float64).tolist()),
    }
    advance_logged(sim, SETTLE_S, log)
    speeds, band_p, band_ref, tops = [], [], [], []
    for _ in range(int(round(MEASURE_S / SAMPLE_S))):
        # a position-based step is tied to the frame: sampled a step at a time, not cut
        advance_logged(sim, sim.pressure.bound().dt_max if solver == "pbf" else SAMPLE_S, log)
        p = real(sim)
        x = p["x"].astype(np.float64)
        speeds.append(float(np.linalg.norm(p["v"], axis=1).mean()))
        # more than h from the side walls (and from the front and back walls in 3D)
        away = np.ones(len(x), bool)
        for k in [0] + ([2] if dim == 3 else []):
            away &= (x[:, k] > lo[k] + h) & (x[:, k] < hi[k] - h)
        surface = free_surface_height(x[away], s, lo[0] + h, hi[0] - h)
        depth = surface - x[:, 1]
        band = away & (depth > 0.3 * TANK_H) & (depth < 0.7 * TANK_H)
        band_p.append(float(p["p"][band].mean()))
        band_ref.append(float(RHO0 * G * depth[band].mean()))
        tops.append(float(x[:, 1].max()))
    p = real(sim)
    out.update(
        x=p["x"],
        n1=len(p["m"]),
        mass1=math.fsum(p["m"].astype(np.float64).tolist()),
        speed=float(np.mean(speeds)),
        pressure=float(np.mean(band_p)),
        reference=float(np.mean(band_ref)),
        top=max(tops),
    )
    out["v_ref"] = math.sqrt(G * TANK_H)
    out["error"] = out["pressure"] / out["reference"] - 1.0
    print(
        f"\n{dim}D {solver} tank after {SETTLE_S + MEASURE_S:.1f} s: mean speed {out['speed']:.4f} m/s = "
        f"{out['speed'] / out['v_ref']:.4f} sqrt(gH); band pressure {out['pressure']:.1f} Pa vs "
        f"rho0 g depth {out['reference']:.1f} Pa ({100 * out['error']:+.2f} %); highest particle "
        f"{out['top']:.4f} m" + (f"; {log.summary()}" if solver == "dfsph" else "")
    )
    runtime.reset()
    return out


def test_tank_keeps_its_fluid(tank_run, request):
    """Nothing escapes, nothing is created or lost, nothing is flung above the surface."""
    r = tank_run
    d, x = f"{r['dim']}D {r['solver']}", r["x"]
    gap = float(np.minimum(x - r["lo"], r["hi"] - x).min())
    known_xfail(request, KNOWN_FAILURES, r["case"], "tank_wall", gap)
    assert r["n1"] == r["n0"], f"{d}: particle count {r['n1']}, started with {r['n0']}"
    assert np.all(np.isfinite(x)), f"{d}: {int((~np.isfinite(x)).any(axis=1).sum())} non-finite positions"
    # the walls clamp any particle that reaches them onto them; below the free surface the
    # mirror images' pressure must hold the fluid off before that (the bottom layer rests
    # half a spacing above). A surface particle below rest density has no pressure to push
    # it off (the free-surface clamp): after the 3D lattice rearranges one rests against a
    # side wall at 0.2 spacings under dfsph, which only the clamp may not reach.
    below = x[:, 1] < x[:, 1].max() - 2.0 * r["spacing"]
    deep_gap = float(np.minimum(x[below] - r["lo"], r["hi"] - x[below]).min())
    assert deep_gap >= 0.25 * r["spacing"] and gap >= 0.1 * r["spacing"], (
        f"{d}: a particle came within {deep_gap:.2e} m of a wall below the surface, {gap:.2e} m at it "
        f"(spacing {r['spacing']} m; expected >= a quarter of it below, a tenth at the surface)"
    )
    assert r["top"] <= TANK_H + 2.0 * r["spacing"], (
        f"{d}: a particle rose to {r['top']:.4f} m above a {TANK_H} m deep pool at rest"
    )
    assert r["mass1"] == r["mass0"], f"{d}: total mass {r['mass1']!r}, started with {r['mass0']!r}"


def test_tank_settles_to_rest(tank_run, request):
    r = tank_run
    ratio = r["speed"] / r["v_ref"]
    known_xfail(request, KNOWN_FAILURES, r["case"], "tank_speed", ratio)
    assert r["speed"] <= 0.01 * r["v_ref"], (
        f"{r['dim']}D {r['solver']}: mean speed {r['speed']:.4f} m/s after {SETTLE_S} s (averaged over the next "
        f"{MEASURE_S} s); expected <= 1 % of sqrt(g H) = {0.01 * r['v_ref']:.4f} m/s "
        f"(measured {ratio:.4f} sqrt(gH))"
    )


def test_tank_pressure_is_hydrostatic(tank_run, request):
    r = tank_run
    known_xfail(request, KNOWN_FAILURES, r["case"], "tank_pressure", r["error"])
    # the position-based solver's pressure is its multipliers' (a few Jacobi iterations a
    # step, as it is meant to run): within 10 %, the others' within 5 %, 3D dfsph's within 6 %:
    # this tank is 10 layers of 3 cm, and where its surface layer rests moves the band's
    # reference by several per cent. It read -4.0 % (surface measured at 0.305 m) while the
    # surface particles kept the pressure the hydrostatic start gave them, +5.1 % (0.298 m)
    # since they give it up where nothing compresses them (2026-12-05, docs/METHOD.md §16);
    # the 80-layer tanks hold within 5 % (docs/validation.md)
    bound = 0.10 if r["solver"] == "pbf" else 0.06 if r["case"] == "3d-dfsph" else 0.05
    assert abs(r["error"]) <= bound, (
        f"{r['dim']}D {r['solver']}: mean pressure {r['pressure']:.1f} Pa in the band 0.3 H..0.7 H below the "
        f"surface; rho0 g depth = {r['reference']:.1f} Pa ({100 * r['error']:+.2f} %, expected "
        f"within {100 * bound:.0f} %)"
    )


def test_tank_density_error_stays_within_tolerance(tank_run):
    """DFSPH: after every step of the tank's run the stats row's average density error is
    within dfsph.density_tolerance, and no solve stopped at its maximum iterations."""
    r = tank_run
    if r["solver"] != "dfsph":
        pytest.skip("wcsph has no density solve to hold to a tolerance")
    r["log"].check(r["case"] + " tank")


# ================================================================== dam break
# Martin & Moyce (1952), column of width a and height 2a (n² = 2): surge front Z = x/a at
# T = t sqrt(2 g / a), as digitised from their plot (the values widely used to validate
# dam-break codes). Ritter's shallow-water solution, Z = 1 + 2T for this column, is an
# upper bound: no real front outruns the frictionless, hydrostatic one.
MARTIN_MOYCE = ((1.43, 1.67), (1.97, 2.33), (2.50, 3.00), (2.96, 3.67))
# Allowed Z_sim - Z_experiment, in column widths a. The 10-particle column at mu = 1 Pa s
# runs behind the experiment (measured: -0.10, -0.23, -0.29, -0.38 in 2D and -0.10,
# -0.21, -0.27, -0.37 in 3D at the four times), so the band is wide behind and narrow
# ahead: a front faster than the experiment is too little dissipation or too much drive
# (gravity x1.3 gives +0.10, +0.10, +0.18, +0.21 and fails; a symmetric 0.5 let it pass).
MM_BEHIND, MM_AHEAD = 0.5, 0.15

DAM_A = 0.2  # column width, m; its height is 2a
DAM_L = 1.0  # tank length, m (Z = 5 at the far wall)
DAM_END_S = 1.5
FRAME_S = 0.02


def dam_scene(dim):
    spacing = 0.02 if dim == 2 else 0.025
    lo, hi = box(dim, (0.0, 0.0), (DAM_L, 0.6), (0.0, 0.1))
    blo, bhi = box(dim, (0.0, 0.0), (DAM_A, 2.0 * DAM_A), (0.0, 0.1))
    return {
        "description": "dam break, Martin & Moyce n^2 = 2",
        "dim": dim,
        "domain": {"min": lo, "max": hi},
        "particles": {"spacing": spacing},
        "fluid": {"viscosity": 1.0, "stiffness": stiffness_for(2.0 * DAM_A), "blocks": [{"min": blo, "max": bhi}]},
        "physics": {"cfl": 0.2},
    }


@pytest.fixture(scope="module", params=dim_solver_params(slow=("3d", "2d-dfsph", "3d-dfsph"), fixture=True))
def dam_run(request):
    """One dam break per dimension and pressure solver to t = 1.5 s, checked every frame
    for NaN and for its mass at the end; returns the front history. Shared by the
    dam-break tests below. The 3D runs and the DFSPH ones (2D: ~75 s on a loaded core)
    are long validation, marked ``slow`` (``python3 -m pytest -q -m slow``). A DFSPH run
    reads its stats row after every step (``SolveLog``). (Particles cannot leave the
    domain: the boundary pass clamps them into it.)"""
    from mrsph import runtime

    runtime.reset()
    dim, solver = request.param
    sim = make_sim(with_solver(dam_scene(dim), solver))
    log = SolveLog()
    s = float(sim.s0)
    mass0 = math.fsum(real(sim)["m"].astype(np.float64).tolist())
    times, lead, p99, problems = [], [], [], []
    x = real(sim)["x"]
    while True:
        times.append(sim.time)
        # the leading particle stands for the cell around it: its x plus half a spacing
        lead.append(float(x[:, 0].max()) + 0.5 * s)
        p99.append(float(np.percentile(x[:, 0], 99)))
        if sim.time >= DAM_END_S - 1e-9:
            break
        advance_logged(sim, FRAME_S, log)
        p = real(sim)
        x = p["x"]
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(p["v"]))):
            problems.append(f"NaN at t = {sim.time:.2f} s")
            break
    if math.fsum(real(sim)["m"].astype(np.float64).tolist()) != mass0:
        problems.append("total mass changed")
    runtime.reset()
    if solver == "dfsph":
        print(f"\n{dim}D dfsph dam break: {log.summary()}")
    return {
        "dim": dim,
        "solver": solver,
        "case": case_id(dim, solver),
        "log": log,
        "spacing": s,
        "t": np.array(times),
        "lead": np.array(lead),
        "p99": np.array(p99),
        "problems": problems,
        "t_end": sim.time,
    }


def test_dam_break_runs_clean_and_front_advances(dam_run):
    r = dam_run
    d, s = f"{r['dim']}D {r['solver']}", r["spacing"]
    assert not r["problems"], f"{d} dam break: {'; '.join(r['problems'])}"
    assert r["t_end"] >= DAM_END_S - 1e-9, f"{d}: stopped at t = {r['t_end']:.3f} s"
    # the front advances monotonically until it reaches the far wall
    hit = np.flatnonzero(r["lead"] >= DAM_L - s)
    assert len(hit), f"{d}: the front never reached the far wall (furthest {r['lead'].max():.3f} m)"
    end = int(hit[0])
    t = r["t"]
    for name in ("lead", "p99"):
        drops = np.diff(r[name][: end + 1])
        k = int(np.argmin(drops))
        assert drops[k] >= -0.5 * s, (
            f"{d}: front ({name}) went back by {-drops[k]:.4f} m between t = {t[k]:.2f} "
            f"and {t[k + 1]:.2f} s; expected non-decreasing within half a spacing ({0.5 * s} m)"
        )


def test_dam_break_front_matches_experiment(dam_run):
    """The bulk front (99th percentile of x: a few particles shot ahead of the surge do
    not make the front) against Martin & Moyce; the leading particle is reported too."""
    r = dam_run
    d = f"{r['dim']}D {r['solver']}"
    assert not r["problems"], f"{d} dam break: {'; '.join(r['problems'])}"
    T = r["t"] * math.sqrt(2.0 * G / DAM_A)
    rows = []
    for t_exp, z_exp in MARTIN_MOYCE:
        rows.append(
            (
                t_exp,
                z_exp,
                float(np.interp(t_exp, T, r["p99"] / DAM_A)),
                float(np.interp(t_exp, T, r["lead"] / DAM_A)),
                1.0 + 2.0 * t_exp,
            )
        )
    table = "; ".join(
        f"T={t:.2f}: Z={z:.2f} (experiment {ze:.2f}, leading particle {zl:.2f}, Ritter {zr:.2f})"
        for t, ze, z, zl, zr in rows
    )
    print(f"\n{d} dam break front: {table}")
    for t_exp, z_exp, z_sim, z_lead, z_ritter in rows:
        assert z_lead <= z_ritter + 0.5 * r["spacing"] / DAM_A, (
            f"{d}: front faster than Ritter's ideal dam break: {table}"
        )
        assert -MM_BEHIND <= z_sim - z_exp <= MM_AHEAD, (
            f"{d}: surge front at T = {t_exp:.2f} is {z_sim - z_exp:+.2f} a off Martin & Moyce "
            f"(allowed -{MM_BEHIND} .. +{MM_AHEAD} a): {table}"
        )


def test_dam_break_density_error_stays_within_tolerance(dam_run):
    """DFSPH: after every step of the dam break (impact on the far wall included) the
    stats row's average density error is within dfsph.density_tolerance, and no solve
    stopped at its maximum iterations."""
    r = dam_run
    if r["solver"] != "dfsph":
        pytest.skip("wcsph has no density solve to hold to a tolerance")
    r["log"].check(r["case"] + " dam break")


@pytest.mark.parametrize("dim", DIMS_3D_SLOW)
def test_emitter_delivers_its_flux_at_its_velocity(dim):
    """An emitter puts out one layer of its disc every s / |U| seconds, each particle at
    the emitter's velocity: over a run the fluid it adds is rho0 |U| A (stop - start) to
    within one layer, with no gravity to bend the jet. A start past t = 0 and a stop
    between steps check that the clock counts only the open interval. The jet stays whole
    and moves at U: without the nozzle (emitters.Emitters.hold) the 2D jet broke up
    at its outlet and was thrown back out of it, its mean velocity 1.54 m/s for 1.5."""
    from mrsph.scene.config import emitter_disc

    s, speed, start, stop = 0.02, 1.5, 0.04, 0.4437
    lo, hi = box(dim, (0.0, 0.0), (1.0, 0.5), (0.0, 0.4))
    centre = [0.1] + [0.25] * (dim - 1) if dim == 2 else [0.1, 0.25, 0.2]
    vel = [speed] + [0.0] * (dim - 1)
    scene = {
        "description": "a jet in free space",
        "dim": dim,
        "domain": {"min": lo, "max": hi},
        "particles": {"spacing": s},
        "physics": {"gravity": [0.0] * dim},
        "fluid": {"stiffness": stiffness_for(0.1)},
        "emitters": [{"center": centre, "radius": 0.05, "velocity": vel, "start": start, "stop": stop}],
    }
    sim = make_sim(scene)
    per_layer = len(emitter_disc(centre, 0.05, vel, s))
    sim.advance(start - 0.01)
    assert sim.stats()["n_real"] == 0, f"{dim}D: the emitter put out fluid before its start"
    sim.advance(stop + 0.02 - sim.time)
    p = real(sim)
    layers = len(p["x"]) / per_layer
    want = speed * (stop - start) / s
    assert len(p["x"]) % per_layer == 0 and abs(layers - want) <= 1.0, (
        f"{dim}D: {len(p['x'])} particles = {layers:.2f} layers of {per_layer}; expected "
        f"{want:.2f} layers (|U| (stop - start) / s) within one"
    )
    # each emitted particle has the level's mass, the one a block's particles get (m0:
    # rho0 over the kernel sum of the lattice, so that it reads rho0 there)
    m0 = p["m"].dtype.type(sim.m0)
    assert np.all(p["m"] == m0), f"{dim}D: emitted masses {np.unique(p['m'])} kg; expected m0 = {m0!r} kg each"
    behind = int((p["x"][:, 0] < centre[0] - 0.5 * s).sum())
    assert behind == 0, (
        f"{dim}D: {behind} of {len(p['x'])} particles behind the emitting disc "
        f"(x < {centre[0] - 0.5 * s} m); expected none: the jet flows forward"
    )
    mean_u = p["v"].astype(np.float64).mean(axis=0)
    assert abs(mean_u[0] / speed - 1.0) <= 0.02, (
        f"{dim}D: the emitted jet's mean velocity {mean_u.round(3)} m/s; expected {vel} within 2 %"
    )


@pytest.mark.parametrize("dim", DIMS_3D_SLOW)
def test_a_horizontal_hose_does_not_spray_back(dim):
    """The pour scene's inflow turned sideways, with gravity: nothing comes out behind the
    disc. Without the nozzle, 76-87 of 540 particles (2D) and 24-31 of 870 (3D) were
    behind it after 0.3 s (one thread, two), thrown back out of the outlet."""
    from mrsph.simulation import Simulation

    centre = [0.1, 0.65] if dim == 2 else [0.08, 0.55, 0.15]
    vel = [1.0] + [0.0] * (dim - 1)
    scene = load_scene(f"pour_{dim}d", [f"emitters.0.center={centre}", f"emitters.0.velocity={vel}"])
    sim = Simulation(scene, arch="cpu")
    sim.advance(0.3)
    x = real(sim)["x"]
    behind = int((x[:, 0] < centre[0] - 0.5 * sim.s0).sum())
    assert len(x) > 400 and behind == 0, (
        f"{dim}D: {behind} of {len(x)} particles behind a sideways hose's disc after 0.3 s; expected none"
    )


@pytest.mark.slow_params("3d")  # the quick run keeps 2D (conftest.py, "two tiers")
def test_short_time_step_names_the_bound_that_set_it(dim):
    """dt below physics.dt_min: the message names the bound that made it. A resting tank
    whose dt_min is half its sound-speed step runs; one particle set moving at 150 m/s
    (under max_speed) makes the CFL bound ~6x shorter, and the report says so and gives
    the speed, rather than blaming the sound speed."""
    from mrsph.simulation import SimulationError

    scene = tank_scene(dim)
    probe = make_sim(scene)
    sound_dt = 0.2 * probe.h0 / probe.pressure.signal_speed()
    scene["physics"]["dt_min"] = 0.5 * sound_dt
    sim = make_sim(scene)
    sim.step()
    v = alive_slots(sim, "v")
    v[0, 0] = 150.0
    set_alive_slots(sim, "v", v)
    with pytest.raises(SimulationError) as info:
        sim.step()
    msg = str(info.value)
    found = re.search(
        r"the CFL bound sets it \(.*a particle at about ([0-9.e+]+) m/s if at the "
        r"finest level\)",
        msg,
    )
    assert found, f"message does not name the CFL bound and a speed: {msg}"
    assert float(found.group(1)) == pytest.approx(150.0, rel=0.02), msg


def test_short_time_step_set_by_a_disturbance_names_it(dim):
    """A mouse disturbance so strong that its stability cap 0.5/strength falls below
    physics.dt_min: the message names the disturbance and its strength (it used to blame
    the CFL bound, with a particle speed nothing had)."""
    from mrsph.scene.interaction import Disturbance
    from mrsph.simulation import SimulationError

    scene = tank_scene(dim)
    sim = make_sim(scene)
    strength = 2.0 / float(sim.scene.data["physics"]["dt_min"])  # cap 0.25 dt_min
    centre = [0.5 * (a + b) for a, b in zip(scene["domain"]["min"], scene["domain"]["max"])]
    sim.set_disturbance(Disturbance(tuple(centre), 0.05, strength))
    with pytest.raises(SimulationError) as info:
        sim.step()
    msg = str(info.value)
    assert "the disturbance bound 0.5/strength sets it" in msg and f"{strength:.3g} 1/s" in msg, msg


@pytest.mark.parametrize(
    "bad",
    [
        dict(radius=float("nan")),
        dict(radius=0.0),
        dict(strength=-1.0),
        dict(strength=float("inf")),
        dict(velocity=(1.0,)),
        dict(center=(0.5, float("nan"))),
    ],
    ids=["radius-nan", "radius-0", "strength-negative", "strength-inf", "velocity-length", "centre-nan"],
)
def test_bad_disturbance_is_refused(bad):
    """The window and scripts build Disturbance values; a bad one is refused where it is
    made, with the field's name, not taken into the step (an infinite strength made a
    zero time step; a short velocity was replaced by zero)."""
    from mrsph.scene.interaction import Disturbance

    args = dict(center=(0.5, 0.5), radius=0.1, strength=10.0, velocity=(0.0, 0.0)) | bad
    field = next(iter(bad))
    with pytest.raises(ValueError, match=f"Disturbance.{field}: expected"):
        Disturbance(**args)


# ================================================================== blow-up report
@pytest.mark.slow_params("3d-adaptive-nan", "3d-adaptive-speed")
@pytest.mark.parametrize(
    ("poison", "solver"), [("nan", "wcsph"), ("speed", "wcsph"), ("speed", "pbf")], ids=["nan", "speed", "speed-pbf"]
)
@pytest.mark.parametrize("adaptive", [True, False], ids=["adaptive", "uniform"])
def test_nan_velocity_raises_simulation_error_naming_step_particle_level(dim, adaptive, poison, solver):
    """Adaptive and uniform runs find a bad particle in different loops (a uniform run
    takes the accelerations in its force pass): both must report it, a NaN velocity as
    well as a finite one past ``physics.max_speed``. Under pbf too, whose projection runs
    after the time-step pass: a step that does not go must leave the particles as they
    were, or the message reads the projected velocity (the stirred soak's read "acceleration
    9.81 m/s^2, past what the step can take" of a particle flagged for its speed)."""
    from mrsph.simulation import SimulationError

    scene = tank_scene(dim)
    scene["fluid"]["solver"] = solver
    # two levels, no refinement criterion: the block is seeded at level 1 (the slabs that
    # whole coarse cells leave at its far sides at level 0) and a level-1 particle is
    # poisoned, so that a message which always said "level 0" would be caught
    bad_level = 1 if adaptive else 0
    if adaptive:
        scene["adaptivity"] = {"enabled": True, "levels": 2}
    sim = make_sim(scene)
    for _ in range(3):
        sim.step()
    x = alive_slots(sim, "x")
    level = alive_slots(sim, "level")
    assert np.count_nonzero(level == bad_level) > 7, (
        f"expected level-{bad_level} particles, got {np.bincount(level)} per level"
    )
    # the poisoned particle is moved to an empty spot high above the pool, further than
    # h from every other particle and every wall, so that it is the only bad one
    victim = int(np.flatnonzero(level == bad_level)[7])
    spot = np.asarray(sim.scene.domain.max, float) * 0.5
    spot[1] = 0.75 * float(sim.scene.domain.max[1])
    h1 = 2.0 * sim.h0
    clear = min(float(np.linalg.norm(x - spot, axis=1).min()), gap_to_walls(sim, spot[None]))
    assert clear > h1, f"test set-up: the spot {spot} is only {clear:.3f} m from fluid or wall (h1 = {h1})"
    x[victim] = spot
    v = alive_slots(sim, "v")
    limit = float(sim.scene.data["physics"]["max_speed"])
    v[victim, 0] = np.nan if poison == "nan" else 1.5 * limit
    set_alive_slots(sim, "x", x)
    set_alive_slots(sim, "v", v)
    step = sim.steps
    with pytest.raises(SimulationError) as info:
        sim.step()
    msg = str(info.value)
    print(f"\n{dim}D: {msg}")
    assert f"step {step}" in msg, f"message does not name step {step}: {msg}"
    found = re.search(r"particle (\d+)", msg)
    assert found, f"message does not name a particle: {msg}"
    slot = int(found.group(1))
    # the slot named is where the sort put the poisoned particle (pbf sorts again after
    # the time-step pass: there the place the message gives is checked instead)
    if solver != "pbf":
        xs = alive_slots(sim, "x")
        assert np.allclose(xs[slot], spot, atol=1e-5), (
            f"message names particle {slot} at {xs[slot]}, the NaN was put at {spot}: {msg}"
        )
    at = re.search(r"x = \[([^\]]*)\]", msg)
    assert at and np.allclose([float(c) for c in at.group(1).split(",")], spot, atol=1e-4), (
        f"message does not place the particle at {spot}: {msg}"
    )
    assert f"level {bad_level}" in msg, f"message does not name the particle's level ({bad_level}): {msg}"
    assert re.search(r"\b1 particle", msg), f"only one particle was poisoned: {msg}"
    why = (
        "NaN/Inf velocity or acceleration$"
        if poison == "nan"
        else rf"speed {1.5 * limit:.4g} m/s above physics.max_speed = {limit:g} m/s$"
    )
    assert re.search(why, msg), f"message does not say why the particle is bad ({why}): {msg}"


@pytest.mark.parametrize("by_pass", [False, True], ids=["fused", "by-pass"])
def test_a_refused_pbf_step_leaves_every_particle_where_it_was(dim, by_pass):
    """pbf's step predicts, then sorts and projects after the time-step pass. When that
    pass refuses the step, the pass-by-pass step stops there and the fused launch runs the
    rest over no particle (``step.Segment``'s gate): either way each particle keeps its
    place and velocity (the fused one may have sorted them), the refused step is not
    counted in the solver's stats, and what the last step measured is not read onto the
    slots as they are now (a reader sees the pool's density)."""
    from mrsph.pressure.pbf.counts import STEPS
    from mrsph.simulation import SimulationError

    scene = tank_scene(dim)
    scene["fluid"]["solver"] = "pbf"
    sim = make_sim(scene)
    sim.profile = by_pass
    for _ in range(3):
        sim.step()
    v = alive_slots(sim, "v")
    v[len(v) // 2, 1] = 1.5 * float(sim.scene.data["physics"]["max_speed"])
    set_alive_slots(sim, "v", v)

    def rows():
        xv = np.hstack([alive_slots(sim, "x"), alive_slots(sim, "v")])
        return xv[np.lexsort(xv.T[::-1])]

    before, steps = rows(), float(sim.pressure.counts.stats[STEPS])
    with pytest.raises(SimulationError, match="above physics.max_speed"):
        sim.step()
    after = rows()
    moved = np.flatnonzero(np.any(after != before, axis=1))
    assert moved.size == 0, (
        f"{dim}D: {moved.size} of {len(before)} particles moved in a refused step, e.g. "
        f"x, v {before[moved[0]].tolist()} -> {after[moved[0]].tolist()}"
    )
    assert float(sim.pressure.counts.stats[STEPS]) == steps, f"{dim}D: the refused step was counted in pbf's stats"
    real = alive_slots(sim, "kind") < 4
    seen = sim.particles()["rho"][real]
    assert np.array_equal(seen, alive_slots(sim, "rho")[real]), f"{dim}D: a refused step's reader saw the last rho"


@pytest.mark.parametrize("g", [1e20, 1e31])
def test_overflowing_acceleration_is_named(dim, g):
    """Gravity of 1e31 m/s² (past the 1e30 bound) or 1e20 (finite, but its square is past
    f32's range, the default precision): every particle's acceleration is refused, and
    the report names it (it used to give the particle's speed, 0 m/s, as the reason)."""
    from mrsph.simulation import SimulationError

    scene = tank_scene(dim)
    scene["physics"]["gravity"] = [0.0, -g] + [0.0] * (dim - 2)
    sim = make_sim(scene)
    with pytest.raises(SimulationError) as info:
        sim.step()
    msg = str(info.value)
    found = re.search(r": acceleration ([0-9.e+]+) m/s\^2, past what the step can take$", msg)
    assert found and float(found.group(1)) == pytest.approx(g, rel=1e-3), msg


def test_stats_dt_is_the_chosen_step_not_the_frame_remainder(dim):
    """The stats row's dt after a frame is the time step the bounds chose, which the
    next step (uncut) reproduces within a few per cent, not the sliver that ended the
    frame exactly."""
    scene = tank_scene(dim)
    sim = make_sim(scene)
    assert sim.stats()["dt"] == 0.0, f"{dim}D: frame 0, before any step, reports dt {sim.stats()['dt']}"
    rows = []
    for _ in range(3):
        sim.advance_frame()
        rows.append(sim.stats()["dt"])
        step = sim.step()
        assert rows[-1] == pytest.approx(step, rel=0.05), (
            f"{dim}D: stats dt {rows[-1]:.4g} s after frame {sim.frame}, the next step {step:.4g} s"
        )


def _deep_tank(dim, sets=()):
    """tank_rest_{dim}d under dfsph at twice its spacing (40 layers of 0.4 m of water), one thread."""
    from mrsph.simulation import Simulation

    over = ['fluid.solver="dfsph"', "particles.spacing=0.01", *sets]
    return Simulation(load_scene(f"tank_rest_{dim}d", over), arch="cpu", threads=1)


@pytest.mark.slow_params("3d")  # the quick run keeps 2D (conftest.py, "two tiers")
def test_dfsph_pressure_bound_sets_the_step_in_deep_water(dim):
    """dfsph.pressure_cfl: at rest the flow sets no step, and the pressure's hold on the
    lattice does, dt = λ_p s / sqrt(max p/ρ) (docs/METHOD.md §16); at 0 the step is the
    scene's dt_max, past which the full-spacing tank rang at 0.05 sqrt(gH)."""
    sim = _deep_tank(dim)
    lam = float(sim.scene.data["dfsph"]["pressure_cfl"])
    for _ in range(29):
        sim.step()
    # the pressure the next step's bound reads: the last step's (read after the step, it is
    # the next one's, which in 3D moved by 2.8 % in a step as the lattice rearranged)
    p = sim.particles(virtual=False)
    bound = lam * float(sim.s0) / math.sqrt(float((p["p"] / p["rho"]).max()))
    dt = sim.step()
    assert 0.9 * bound <= dt <= 1.001 * bound, (
        f"{dim}D deep tank at rest: dt {dt:.4g} s; the pressure bound {lam} s / sqrt(max p/rho) reads {bound:.4g} s"
    )
    free = _deep_tank(dim, ["dfsph.pressure_cfl=0"])
    for _ in range(30):
        dt_free = free.step()
    assert dt_free > 1.2 * bound, f"{dim}D: with dfsph.pressure_cfl = 0 dt {dt_free:.4g} s, not above the bound"


def test_implicit_steps_are_equal_within_a_frame_and_grow_slowly(dim):
    """Under dfsph a frame's steps are what is left of it over the fewest steps its bounds
    allow, and dt grows by at most STEP_GROWTH a step: a step cut short at the frame's end,
    and any jump of dt, rang the deep tank's pressure (docs/METHOD.md §9). Here the tank at
    rest with its step at dt_max (no pressure bound), so that the bound is steady: every
    step of a frame is the same (the last two sharing what was left read 0.67 of the
    others), and after one step cut to a tenth the next ones grow back 1.25-fold. dt_max is
    1 ms, not the scene's 2: the 3D column leaves its cubic lattice at 0.06 s, and the force
    bound then fell to 1.75 ms for a step in the measured frames on one machine of two."""
    from mrsph.sph.integrator import STEP_GROWTH

    sim = _deep_tank(dim, ["dfsph.pressure_cfl=0", "physics.dt_max=0.001"])
    sim.advance(0.05)
    frame = 1.0 / 30.0
    ratios = []
    for _ in range(2):
        end = sim.time + frame
        dts = []
        while sim.time < end - 1e-12:
            dts.append(sim.step(max_dt=end - sim.time))
        ratios.append(min(dts) / max(dts))
    assert min(ratios) >= 1.0 - 1e-6, f"{dim}D: a frame's shortest step over its longest {min(ratios):.4f}, not 1"
    full = dts[0]
    steps = [sim.step(max_dt=0.1 * full)] + [sim.step() for _ in range(12)]
    grow = [b / a for a, b in zip(steps, steps[1:])]
    assert max(grow) <= STEP_GROWTH * (1 + 1e-6) and steps[-1] >= full, (
        f"{dim}D: steps after one cut to a tenth {[round(d * 1e3, 3) for d in steps]} ms: growth up to "
        f"{max(grow):.3f} (<= {STEP_GROWTH}), back to {full * 1e3:.3f} ms or more"
    )


def test_dfsph_holds_a_deep_column_at_hydrostatic_pressure():
    """The deep tank (40 layers here, 80 in the validation) under dfsph, started at rest:
    its density solve, a Krylov solve of the whole pressure from the last one
    (docs/METHOD.md §16), carries the column's weight every step, so for 0.2 s the floor's
    pressure stays within 3 % of hydrostatic on average (30 % each step sampled: a step's
    pressure of the column as a whole is as exact as the floor's error allowed, about
    H / (λ_p² s) times dfsph.rest_tolerance's largest, 4 % here, and swings by ±7 % step
    to step, -19 % once in a step shortened by a spike of the pressure bound, -26 % once on
    another machine, whose last bits differ) and the water below 0.1 % of sqrt(gH). The
    paper's Jacobi sweeps let the column sink from its first steps (its floor at 0.05 of
    hydrostatic after 9 ms, 0.03 sqrt(gH)). (Later an odd-even motion of the lowest layers
    grows to about 0.6 % and decays, docs/validation.md: the validation holds the 2 s.)
    2D only: the 3D column (6 x 40 x 6 here) leaves its cubic lattice within 0.2 s under
    every solver (at 0.06 s under dfsph, 0.013 sqrt(gH); from 0.12 s under wcsph, 0.009),
    so its rest is held after 2 s, by the validation's quick 3D tank in -m slow."""
    dim = 2
    sim = _deep_tank(dim)
    H = float(sim.scene.data["fluid"]["blocks"][0]["max"][1])
    U = math.sqrt(9.81 * H)
    speed, floor = [], []
    while sim.time < 0.2 - 1e-9:
        sim.advance(0.025)
        p = sim.particles(virtual=False)
        y = p["x"][:, 1].astype(np.float64)
        low = y < 0.05
        top = float(y.max()) + 0.5 * float(sim.s0)
        floor.append(float(np.mean(p["p"][low] / (1000.0 * 9.81 * (top - y[low])))))
        speed.append(float(np.linalg.norm(p["v"], axis=1).mean() / U))
    ok = max(speed) <= 0.001 and all(abs(f - 1.0) <= 0.3 for f in floor) and abs(np.mean(floor) - 1.0) <= 0.03
    assert ok, (
        f"{dim}D deep tank: mean speed up to {max(speed):.4f} sqrt(gH) (<= 0.001), floor pressure over "
        f"hydrostatic {[round(f, 3) for f in floor]} (each within 30 %, their mean {np.mean(floor):.3f} within 3 %)"
    )


# ================================================================== DFSPH solve reporting
SOLVE_COLUMNS = ("solver", "density_iterations", "divergence_iterations", "density_error", "unconverged")


@pytest.mark.slow_params("3d")  # the quick run keeps 2D (conftest.py, "two tiers")
def test_dfsph_solve_stopped_at_its_maximum_is_counted_warned_once_and_written(dim, tmp_path):
    """A density solve that stops at dfsph.max_iterations before its tolerance is never
    silent: each such step is counted in the stats row (``unconverged``), a
    RuntimeWarning naming the key and its value is given once for the run, and stats.csv
    carries the solver's columns. Here max_iterations = 1 against a tolerance of 1e-9 in
    a tank just let go (the lattice compresses under gravity), so every density solve stops
    at its maximum; the divergence solve is left to converge, and no step is halved
    (``dfsph.shorten_steps = 0``; halving: the next test)."""
    import csv
    import warnings

    from mrsph.io.output import StatsWriter

    scene = with_solver(tank_scene(dim), "dfsph")
    scene["dfsph"] = {"max_iterations": 1, "density_tolerance": 1e-9, "shorten_steps": 0}
    sim = make_sim(scene)
    steps = 6
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with StatsWriter(tmp_path / "stats.csv", dim, sim.levels) as out:
            rows = []
            for _ in range(2):
                for _ in range(steps // 2):
                    sim.step()
                rows.append(sim.stats())
                out.write(rows[-1])
    hits = [w for w in caught if issubclass(w.category, RuntimeWarning) and "dfsph" in str(w.message)]
    counted = sum(r["unconverged"] for r in rows)
    print(
        f"\n{dim}D max_iterations = 1: rows {[{k: r[k] for k in SOLVE_COLUMNS} for r in rows]}; "
        f"warnings {[str(w.message) for w in hits]}"
    )
    assert counted == steps, (
        f"{dim}D: {counted} unconverged solves counted in the stats rows over {steps} "
        f"steps that each stopped at max_iterations = 1; expected {steps}"
    )
    assert all(r["density_error"] > 1e-9 for r in rows), (
        f"{dim}D: density errors {[r['density_error'] for r in rows]}; expected above the 1e-9 tolerance"
    )
    assert len(hits) == 1 and "dfsph.max_iterations = 1" in str(hits[0].message), (
        f"{dim}D: expected one RuntimeWarning naming dfsph.max_iterations = 1 for {steps} unconverged "
        f"solves, got {len(hits)}: {[str(w.message) for w in hits]}"
    )
    with open(tmp_path / "stats.csv", newline="") as f:
        back = list(csv.DictReader(f))
    missing = [c for c in SOLVE_COLUMNS if c not in back[0]]
    assert not missing, f"{dim}D: stats.csv lacks the columns {missing} (has {list(back[0])})"
    assert [r["solver"] for r in back] == ["dfsph", "dfsph"], f"{dim}D: solver column {[r['solver'] for r in back]}"
    assert [int(r["unconverged"]) for r in back] == [r["unconverged"] for r in rows], (
        f"{dim}D: stats.csv unconverged {[r['unconverged'] for r in back]}, rows {[r['unconverged'] for r in rows]}"
    )
    for key in ("density_iterations", "divergence_iterations", "density_error"):
        assert [float(r[key]) for r in back] == [r[key] for r in rows], f"{dim}D: stats.csv {key} does not read back"
    assert all(r["density_iterations"] == 1.0 for r in rows), (
        f"{dim}D: density iterations a step {[r['density_iterations'] for r in rows]}; expected 1 (the maximum)"
    )


def test_dfsph_solve_stopped_at_its_maximum_halves_its_step_first(dim):
    """``dfsph.shorten_steps``: a density solve that stops at its maximum short of its
    tolerance runs again on a step half as long, up to that many times, before it is
    counted. With max_iterations = 1 against 1e-9 no halving helps: each step is halved
    twice (the step the host advances by is a quarter of the one its bounds chose, the
    stats row counts 2 halvings a step and 3 solves' iterations), the solve is counted
    once a step, and the one warning says so."""
    import warnings

    scene = with_solver(tank_scene(dim), "dfsph")
    scene["dfsph"] = {"max_iterations": 1, "density_tolerance": 1e-9, "shorten_steps": 2}
    sim = make_sim(scene)
    steps, taken = 4, []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(steps):
            t0 = sim.time
            sim.step()
            taken.append((sim.time - t0, sim.integrator.chosen_dt()))
        row = sim.stats()
    hits = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning) and "dfsph" in str(w.message)]
    assert all(dt == pytest.approx(chosen / 4.0, rel=1e-6) for dt, chosen in taken), (
        f"{dim}D: (step taken, step chosen) {taken}; expected each a quarter of the chosen"
    )
    assert row["shortened"] == 2 * steps and row["unconverged"] == steps, row
    assert row["density_iterations"] == 3.0, row
    assert len(hits) == 1 and "halved 2 time(s)" in hits[0], hits


def test_dfsph_converged_solves_are_not_counted(dim):
    """The other side: at its default tolerance and maximum the same tank's solves
    converge, the rows count none unconverged and nothing is warned."""
    import warnings

    sim = make_sim(with_solver(tank_scene(dim), "dfsph"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(6):
            sim.step()
        row = sim.stats()
    hits = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    tol = float(sim.scene.data["dfsph"]["density_tolerance"])
    assert row["unconverged"] == 0 and not hits and row["density_error"] <= tol, (
        f"{dim}D: {row['unconverged']} unconverged, density error {row['density_error']:.3g} "
        f"(tolerance {tol:g}), warnings {hits}; expected none, within the tolerance"
    )
    assert row["solver"] == "dfsph" and row["density_iterations"] >= 1.0, row


def _dfsph_tank_rows(dim, sets, steps=15):
    from mrsph.simulation import Simulation

    sim = Simulation(load_scene(with_solver(tank_scene(dim), "dfsph"), sets), arch="cpu")
    rows = []
    for _ in range(steps):
        sim.step()
        rows.append(sim.stats())
    return sim, rows


@pytest.mark.slow_params("3d")  # the quick run keeps 2D (conftest.py, "two tiers")
def test_dfsph_tightens_its_tolerance_in_water_at_rest(dim):
    """In water at rest (its particles move on average far less than dfsph.slow_flow of a
    spacing a step) every density solve stops within dfsph.rest_tolerance, not only
    dfsph.density_tolerance: what the solve leaves is undone over the next steps, the
    resting tanks' noise (test_tank_settles_to_rest). With slow_flow so small that every
    flow counts as fast, the same tank's solves stop beyond rest_tolerance: the scaling,
    not the tank, holds the first bound. rest_tolerance 1e-7 here, below the 1.6e-6 (3D)
    and 7e-6 (2D) a conjugate-gradient solve of this tank reaches when it stops on
    density_tolerance. Held over steps 13 to 16: in its first steps the surface layer gives
    up the pressure the hydrostatic start gave it and settles (2D solves stopping at up to
    1.6e-6 in steps 2-12), and from about step 18 the 3D column leaves its cubic lattice
    (test_tank_keeps_its_fluid)."""
    rest_set = "dfsph.rest_tolerance=1e-7"
    sim, rows = _dfsph_tank_rows(dim, [rest_set], steps=17)
    rows = rows[13:]
    cfg = sim.scene.data["dfsph"]
    rest, tol = float(cfg["rest_tolerance"]), float(cfg["density_tolerance"])
    assert rest < tol, cfg
    worst = max(r["density_error"] for r in rows)
    assert worst <= rest and all(r["unconverged"] == 0 for r in rows), (
        f"{dim}D tank at rest: density error {worst:.3g} at worst over {len(rows)} steps; expected "
        f"within dfsph.rest_tolerance = {rest:g} (density_tolerance {tol:g}), none unconverged"
    )
    _, fast = _dfsph_tank_rows(dim, [rest_set, "dfsph.slow_flow=1e-9"])
    loose = max(r["density_error"] for r in fast)
    assert rest < loose <= tol, (
        f"{dim}D tank, every flow fast: density error {loose:.3g} at worst; "
        f"expected above rest_tolerance {rest:g} (else this test guards "
        f"nothing) and within density_tolerance {tol:g}"
    )


def test_dfsph_solve_short_of_the_rest_tolerance_is_not_unconverged(dim):
    """A solve that reaches its maximum iterations short of the tolerance tightened at
    rest but within the scene's own (dfsph.density_tolerance) converged as asked: a row
    counts a solve unconverged exactly when it stopped beyond the scene's tolerance."""
    sim, rows = _dfsph_tank_rows(dim, ["dfsph.rest_tolerance=1e-7", "dfsph.max_iterations=5"])
    tol = float(sim.scene.data["dfsph"]["density_tolerance"])
    wrong = [
        (k, r["density_error"], r["unconverged"])
        for k, r in enumerate(rows)
        if r["unconverged"] != (r["density_error"] > tol)
    ]
    assert not wrong, (
        f"{dim}D: (step, density error, unconverged) counted against the scene's tolerance {tol:g}: {wrong}"
    )
    capped = [r for r in rows if r["density_iterations"] == 5 and r["density_error"] <= tol]
    assert capped, (
        f"{dim}D: no solve stopped at the maximum within the tolerance "
        f"({[(r['density_iterations'], r['density_error']) for r in rows]}); the test checks nothing"
    )


# ================================================================== time step
@pytest.mark.parametrize("bound", ["cfl", "force"])
def test_time_step_obeys_cfl_and_force_bounds(dim, bound):
    scene = dam_scene(dim)
    if bound == "force":
        # a small force factor makes the force condition the binding one
        scene["physics"]["force_factor"] = 0.002
    sim = make_sim(scene)
    sim.advance(0.1)  # the column is collapsing: speeds and accelerations vary
    ph = sim.scene.data["physics"]
    c = math.sqrt(float(sim.scene.fluid.stiffness))
    h = float(sim.h0)
    for _ in range(5):
        dt = sim.step()
        a = alive_slots(sim, "a").astype(np.float64)  # accelerations of this step
        v1 = alive_slots(sim, "v").astype(np.float64)
        v0 = v1 - dt * a  # velocities the step started from
        cfl = float(ph["cfl"]) * h / (c + np.linalg.norm(v0, axis=1).max())
        force = float(ph["force_factor"]) * math.sqrt(h / np.linalg.norm(a, axis=1).max())
        allowed = min(cfl, force, float(ph["dt_max"]))
        assert dt <= allowed * (1 + 1e-4), (
            f"{dim}D: dt = {dt:.4e} s exceeds min(CFL {cfl:.4e}, force {force:.4e}, dt_max "
            f"{ph['dt_max']}) at t = {sim.time:.4f} s"
        )
        # and it is not needlessly small: the binding bound sets it
        assert dt >= allowed * (1 - 1e-3), (
            f"{dim}D: dt = {dt:.4e} s is below the bounds min(CFL {cfl:.4e}, force {force:.4e}, "
            f"dt_max {ph['dt_max']}) by more than round-off"
        )
        binding = "cfl" if cfl <= force else "force"
        assert binding == bound, f"{dim}D: the {binding} bound binds (CFL {cfl:.4e}, force {force:.4e})"


def test_viscous_bound_keeps_a_fluid_made_very_viscous_live_stable(dim):
    """physics.viscous_factor: explicit viscosity is unstable past dt ~ 0.067 h^2 rho/mu
    (integrator.Integrator.bounds). The viscosity is raised live, as the window's slider does,
    until the viscous bound is a fifth of the CFL step: dt must follow it, and the
    column, honey-thick now, must creep. At the CFL step instead (the bound taken out)
    the same run rings at 5-9 m/s within 0.02 s."""
    sim = make_sim(dam_scene(dim))
    ph = sim.scene.data["physics"]
    h = float(sim.h0)
    cfl_dt = float(ph["cfl"]) * h / math.sqrt(float(sim.scene.fluid.stiffness))
    factor = float(ph["viscous_factor"])
    mu = factor * h * h * sim.rest_density / (0.2 * cfl_dt)
    sim.set_param("fluid.viscosity", mu)
    bound = factor * h * h * sim.rest_density / mu
    while sim.time < 0.02:
        dt = sim.step()
        assert bound * (1 - 1e-6) <= dt <= bound * (1 + 1e-6), (
            f"{dim}D: dt = {dt:.4e} s at t = {sim.time:.4f} s, the viscous bound is {bound:.4e} s "
            f"(mu = {mu:.0f} Pa s, CFL step {cfl_dt:.4e} s)"
        )
    speed = float(np.linalg.norm(alive_slots(sim, "v"), axis=1).max())
    g = float(np.linalg.norm(sim.scene.data["physics"]["gravity"]))
    assert speed <= 2.0 * g * sim.time, (
        f"{dim}D: a fluid of {mu:.0f} Pa s reached {speed:.3f} m/s in {sim.time:.3f} s "
        f"(2 g t = {2.0 * g * sim.time:.3f} m/s): the viscous term is unstable"
    )


def test_frame_within_a_wall_budget_stops_early_and_whole_frames_end_exactly(dim):
    """The window's slow motion (``advance_frame(wall_budget)``): a spent budget stops
    the frame after one step, and a frame without one ends exactly on 1/fps."""
    sim = make_sim(dam_scene(dim))
    frame = 1.0 / float(sim.scene.data["run"]["fps"])
    steps = sim.advance_frame(wall_budget=0.0)
    assert steps == 1, f"{dim}D: {steps} steps within a spent budget, expected exactly 1"
    assert 0.0 < sim.time == sim.dt < frame, (
        f"{dim}D: one step should advance by its dt ({sim.dt:.3e} s), less than a frame "
        f"({frame:.4f} s); the time is {sim.time:.6e} s"
    )
    start = sim.time
    steps = sim.advance_frame()
    assert steps > 1 and sim.time == start + frame, (
        f"{dim}D: a whole frame from t = {start:.6e} s ended at {sim.time!r} in {steps} steps, "
        f"expected {start + frame!r}"
    )
    assert sim.frame == 2, f"{dim}D: frame counter {sim.frame} after two frames"
