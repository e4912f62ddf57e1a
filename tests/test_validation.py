"""tools/validate.py's quick runs against the validation targets (docs/validation.md), a
representative few in ``-m slow``: every solver at rest in the 2D deep tank (dfsph in 3D too)
and on Martin & Moyce's 2D front, one adaptive run against its uniform twin, and wcsph and dfsph
on Lobovsky's 2D wall pressure; and dfsph's 2D tank, uniform and adaptive, at the 80 layers the
validation asks. The rest (3D but dfsph's tank, the other adaptive runs, MARIN's box) is the
command's: ``python3 tools/validate.py --quick`` runs every one and marks each target held or
missed in its table, and docs/validation.md holds what it gave.

The quick runs are the scenes at twice their spacing, about five minutes together on one core,
so that the slow tier stays short. dfsph's adaptive 2D tank is held at the scene's spacing only:
40 layers deep, its level interface reads 6-8 % of rho0 g H low and its pressure by depth 2.8 %
or 5.6 % off on two machines, past the 5 % on one (docs/validation.md, "Known limitations"). A
run may take overrides (``SETS``; none today). A target a quick run misses for a measured cause
that docs/validation.md states as a known limitation would be in ``KNOWN`` with the number
measured, run as xfail (not strict); none is.
"""

import pytest
from toolload import load_tool

V = load_tool("validate")
R = load_tool("validate_report")

#: (case, dim, solver, mode) -> why its quick run misses a target, with what was measured
#: (docs/validation.md, "Known limitations"): none today
KNOWN: dict = {}

#: (case, dim, solver, mode) -> the overrides its quick run takes here, with the id's suffix: none
#: today, every run holds its targets at the scene's settings
SETS: dict = {}

_RUNS: dict = {}


def quick(case: str, dim: int, solver: str, mode: str) -> dict:
    """The quick run, made once per process (its own fresh Taichi program)."""
    from mrsph import runtime

    key = (case, dim, solver, mode)
    if key not in _RUNS:
        runtime.reset()
        spacing = V.scene_spacing(case, dim) * V.QUICK[case]
        _RUNS[key] = V.run_one(case, dim, solver, mode, spacing, list(SETS.get(key, ((), ""))[0]))
        runtime.reset()
    return _RUNS[key]


#: the quick runs the slow tier holds, (case, dim, solver, mode): the rest is the command's
SLOW = [
    *[("tank", 2, s, "uniform") for s in V.SOLVERS],
    ("tank", 3, "dfsph", "uniform"),
    *[("front", 2, s, "uniform") for s in V.SOLVERS],
    ("front", 2, "wcsph", "adaptive"),
    ("pressure", 2, "wcsph", "uniform"),
    ("pressure", 2, "dfsph", "uniform"),
]


def params(keys):
    return [
        pytest.param(
            c,
            d,
            s,
            m,
            id="-".join(filter(None, (c, f"{d}d", s, m, SETS.get((c, d, s, m), ((), ""))[1]))),
            marks=[pytest.mark.slow, pytest.mark.xdist_group(f"validation-{c}-{d}d")],
        )
        for c, d, s, m in keys
    ]


def _hold(request, run: dict, uni: dict | None = None) -> None:
    key = (run["case"], run["dim"], run["solver"], run["mode"])
    checks = R.checks(run, uni)
    text = "; ".join(
        f"{what} {value if value is None else round(value, 4)}{'' if ok else ' (MISSED)'}" for what, value, ok in checks
    )
    print(f"\n{run['key']}: {text}")
    assert checks, f"{run['key']}: no target applies"
    if key in KNOWN:
        request.applymarker(pytest.mark.xfail(strict=False, reason=f"{KNOWN[key]} (this run: {text})"))
    missed = [c for c in checks if not c[2]]
    assert not missed, f"{run['key']} at s = {run['spacing']:.4g} m misses its targets: {text}"


@pytest.mark.parametrize(("case", "dim", "solver", "mode"), params(SLOW))
def test_quick_run_holds_its_targets(request, case, dim, solver, mode):
    run = quick(case, dim, solver, mode)
    _hold(request, run, quick(case, dim, solver, "uniform") if mode == "adaptive" else None)


@pytest.mark.slow
@pytest.mark.xdist_group("validation-tank-2d")
@pytest.mark.parametrize("mode", ["uniform", "adaptive"])
def test_dfsph_holds_the_80_deep_tank_at_rest(mode):
    """The issue's depth: the 2D tank at the scene's spacing, 80 layers, under dfsph (the quick
    runs above are 40 deep), held to the same targets: mean speed after 2 s and the pressure
    by depth (docs/validation.md). The paper's Jacobi density solve read 0.015 sqrt(gH) and
    26 % here; the Krylov solve 0.0035 and 1-2 % (about 45 s); adaptive 0.0035 and 1.7 %
    (2026-12-07, about 90 s)."""
    from mrsph import runtime

    runtime.reset()
    run = V.run_one("tank", 2, "dfsph", mode, V.scene_spacing("tank", 2), [])
    runtime.reset()
    checks = R.checks(run, None)
    print(f"\n{run['key']}: {checks}")
    assert checks and all(ok for _, _, ok in checks), f"{run['key']}: {checks}"


def test_measures_read_what_they_should():
    """The measures on made-up fields: the water level of a block of particles, the wall value of a
    linear field, a first crossing, the best gate shift of a shifted curve."""
    import numpy as np

    s = 0.01
    g = np.arange(0.5, 20) * s
    x = np.array([(a, b) for a in g for b in g if b < 0.1])  # 0.2 m wide, 0.1 m deep
    vol = np.full(len(x), s * s)
    h = np.full(len(x), 2 * s)
    assert abs(V.water_level(x, vol, h, (0.1,), 0.3) - 0.1) < 0.05 * s
    assert abs(V.water_level(x, vol, h, (0.5 * s,), 0.3, wall=True) - 0.1) < 0.05 * s
    p = 1000.0 * 9.81 * (0.1 - x[:, 1])
    wall = V.shepard(np.array([[0.2, 0.05]]), x, vol, h, p)[0]
    assert abs(wall / (1000 * 9.81 * 0.05) - 1) < 0.02, wall
    t = np.linspace(0, 1, 11)
    assert V.first_crossing(t, t**2, 0.2) == pytest.approx(0.2**0.5, abs=0.005)
    T = np.linspace(0, 4, 401)
    _, rms, shift = V.shifted_rms(T, 1 + (T + 0.2) ** 2, np.array([1.0, 2.0, 3.0]), 1 + np.array([1.0, 2.0, 3.0]) ** 2)
    assert rms < 1e-3 and shift == pytest.approx(-0.2, abs=0.006)


def test_marin_s_box_sensors_sit_on_the_scene_s_box():
    """P1-P4 on the box's face towards the reservoir, P5-P8 on its top, within its width, as the
    data's header places them; a sensor's first impact at ``RISE`` over ``IMPACT_S`` on a made-up
    signal."""
    import numpy as np

    from mrsph.scene.config import load_scene

    box = load_scene(V.SCENES["box"]).data["obstacles"][0]
    (x0, _, z0), (x1, top, z1) = box["min"], box["max"]
    for k, (x, y, z) in enumerate(V.BOX_SENSORS):
        assert z0 < z < z1 and abs(z - 0.5 * (z0 + z1)) < 0.035, (k, z)
        if k < 4:
            assert x == pytest.approx(x1) and 0.0 < y < top, (k, x, y)
        else:
            assert y == pytest.approx(top) and x0 < x < x1 and x1 - x == pytest.approx(0.021 + 0.04 * (k - 4)), (k, x)
    t = np.linspace(0.0, 1.0, 1001)
    p = np.where(t >= 0.4, 2000.0, 0.0) + np.where(t >= 0.55, 5000.0, 0.0)  # a later load is past the impact
    hit = V.impact(t, p, V.RISE, V.IMPACT_S)
    assert hit["arrival"] == pytest.approx(0.4, abs=0.001) and hit["mean"] == pytest.approx(2000.0, rel=0.02), hit
    assert hit["peak"] == 2000.0, hit
    assert V.impact(t, 0.4 * p * (t < 0.55), V.RISE, V.IMPACT_S)["arrival"] is None


def test_ritter_s_dam_break_holds_the_reservoir_s_water():
    """Ritter's depth: 4/9 of the reservoir's at the gate at every time, none past the front
    x = 2 sqrt(g H) t, and as much water downstream of the gate as has left the reservoir."""
    import numpy as np

    H, t = 0.55, 0.4
    c0 = (V.G * H) ** 0.5
    assert V.ritter_depth(np.array([0.0, 0.0]), np.array([0.1, 1.0]), H) == pytest.approx([4 * H / 9] * 2)
    past = np.array([2.0, 2.2, 3.0]) * c0 * t
    assert V.ritter_depth(past, t, H) == pytest.approx([0.0, 0.0, 0.0], abs=1e-12)

    def integral(f, x):
        return float((0.5 * (f[1:] + f[:-1]) * np.diff(x)).sum())

    x = np.linspace(-c0 * t, 0.0, 4001)  # the reservoir's side, which the rarefaction has reached
    drained = integral(H - (2 * c0 - x / t) ** 2 / (9 * V.G), x)
    x = np.linspace(0.0, 2.0 * c0 * t, 4001)
    assert integral(V.ritter_depth(x, t, H), x) == pytest.approx(drained, rel=1e-4)


def test_a_probe_s_rise_tells_a_leading_film_from_the_body():
    """The rise figure and the body row read a film ahead of the body as a flat start; H3's depth
    is the mean over ``H3_WINDOW``."""
    import numpy as np

    t = np.linspace(0.0, 1.0, 501)
    # 1 cm of film from 0.2 s, then the body rising 1 m/s from 0.3 s to 11 cm
    level = np.where(t >= 0.2, 0.01, 0.0) + np.clip(t - 0.3, 0.0, 0.1)
    rise = R.rise(t, level)
    assert rise[R.LEVELS.tolist().index(0.005)] == pytest.approx(0.2, abs=0.002)
    assert rise[R.LEVELS.tolist().index(V.BODY)] == pytest.approx(0.35, abs=0.002)
    assert rise[-1] is None
    later = np.clip(t - 0.5, 0.0, 0.1)  # 6 cm at 0.56 s
    assert R.bodies(t, [later, 0.5 * level, level]) == [
        pytest.approx(0.56, abs=0.002),
        None,
        pytest.approx(0.35, abs=0.002),
    ]
    assert R.h3_depth(t, np.where(t < 0.5, 0.08, 0.12)) == pytest.approx(0.1, abs=0.003)
    # Ritter's at 0.504 m from the gate of 0.55 m of water, the mean over 0.3-0.7 s every 10 ms
    assert V.H3_WINDOW == (0.3, 0.7) and R.h3_ritter() == pytest.approx(0.1456, abs=0.0002)


def test_the_box_s_new_rows_read_a_run_s_heights():
    """The body row and H3's depth row, on a made-up run: its probes late by known amounts, one
    never reaching 6 cm."""
    import numpy as np

    exp = R.marin()
    t = np.arange(0.0, 1.5, 0.002)

    def run(solver, late, scale):
        level = [scale[k] * np.interp(t - late[k], exp["t"], exp[f"H{k + 1}"]) for k in range(4)]
        r = {"case": "box", "dim": 3, "solver": solver, "mode": "uniform", "sets": [], "t": t, "level": level}
        return solver, dict(r, spacing=V.scene_spacing("box", 3))

    runs = dict([run("wcsph", (0.1, 0.0, 0.02, 0.0), (1, 0.2, 1, 1)), run("dfsph", (0, 0, 0, 0), (1, 1, 1.1, 1))])
    assert R._cell(runs, "box", 3, "wcsph", "uniform", "body") == "1.07 / dry / 0.30 s (+0.10 / — / +0.02)"
    assert R._cell(runs, "box", 3, "dfsph", "uniform", "H3_depth") == "0.113 m (+10 %)"


def test_the_table_reads_the_scene_s_spacing_and_leaves_studies_out():
    """Of a case's cached runs the table and its figures take, per solver and mode, the run at the
    scene's spacing, or the quick one where no full run was made; a run finer than the scene's
    (``--spacing``) or with overrides is a study, drawn against the spacing only."""
    full = V.scene_spacing("box", 3)

    def run(spacing, sets=(), solver="wcsph"):
        r = {"case": "box", "dim": 3, "solver": solver, "mode": "uniform", "spacing": spacing, "sets": list(sets)}
        return f"{solver}-{spacing}-{len(sets)}", r

    runs = dict([run(full * 27 / 14), run(full), run(full * 27 / 40), run(full, ["fluid.viscosity=0.01"])])
    runs.update([run(full * 27 / 14, solver="pbf")])
    picked = R._runs(runs, "box", 3)
    assert picked[("wcsph", "uniform")]["spacing"] == full, picked
    assert picked[("wcsph", "uniform")]["sets"] == [], picked
    assert picked[("pbf", "uniform")]["spacing"] == full * 27 / 14, picked


def _tank_speeds(cap: float, until: float = 0.5, sets: tuple = ()) -> list[float]:
    """The quick 2D deep tank (40 layers) under dfsph at its own step: the mean speed over
    sqrt(gH) every 0.05 s."""
    import math

    import numpy as np

    from mrsph import runtime
    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    over = ['fluid.solver="dfsph"', "particles.spacing=0.01", f"fluid.artificial_viscosity_cap={cap}", *sets]
    runtime.reset()
    sim = Simulation(load_scene("tank_rest_2d", over), arch="cpu", threads=1)
    speeds = []
    while sim.time < until - 1e-9:
        sim.advance(0.05)
        v = sim.particles(virtual=False)["v"].astype(np.float64)
        speeds.append(float(np.linalg.norm(v, axis=1).mean() / math.sqrt(9.81 * 0.4)))
    runtime.reset()
    return speeds


def test_a_capped_artificial_viscosity_keeps_dfsphs_deep_tank_still():
    """``fluid.artificial_viscosity_cap`` (forces.Forces.av_strength): the explicit term
    overshoots past dt = 0.35 h / (alpha c), here 1.25 ms. With the step at dfsph's dt_max,
    2 ms (``dfsph.pressure_cfl = 0``; the pressure bound keeps this tank's step near the
    limit), the uncapped artificial viscosity sets the column ringing at once, 0.006-0.030
    sqrt(gH) over its first 0.25 s; capped at 0.15 (the default) it stays within 0.0007
    (2026-12-05; docs/METHOD.md §16)."""
    early = _tank_speeds(0.15, 0.25, ("dfsph.pressure_cfl=0",))
    assert max(early) <= 0.002, f"capped: mean speed {[round(s, 4) for s in early]} sqrt(gH) over 0.25 s"
