"""tools/peer_box.py: MARIN's box in SPlisHSPlasH (docs/validation.md, MARIN's H1). What it sets up
is checked here without SPlisHSPlasH, which mrsph does not depend on: the geometry must be the box
scene's, moved by what a volume map keeps between a particle and its mesh, the reservoir as many
particles as mrsph's, and the cube's faces wound outwards (a volume map's inside is where they
point away from)."""

import importlib.util
import subprocess
import sys

import numpy as np
import pytest
from toolload import load_tool

P = load_tool("peer_box")
V = load_tool("validate")


def test_the_geometry_is_the_box_scene_s():
    from mrsph.scene.config import load_scene

    box = load_scene(V.SCENES["box"]).data
    assert list(P.TANK) == list(box["domain"]["max"]) and list(box["domain"]["min"]) == [0, 0, 0]
    obstacle = box["obstacles"][0]
    assert obstacle["shape"] == "box" and [list(obstacle["min"]), list(obstacle["max"])] == [list(c) for c in P.BOX]
    block = box["fluid"]["blocks"][0]
    assert block["min"][0] == P.GATE and block["max"][1] == P.DEPTH
    assert box["particles"]["spacing"] == pytest.approx(P.DEPTH / 27)


def _extent(body):
    c, s = np.array(body["translation"]), np.array(body["scale"])
    return c - s / 2, c + s / 2


@pytest.mark.parametrize("layers", [27, 40])
def test_the_meshes_move_so_that_the_water_rests_where_mrsph_s_does(layers):
    s = P.DEPTH / layers
    r, dl = s / 2, (P.REST - 1) * s / 2
    settle, release = P.scene(s, 0.01, gate=True), P.scene(s, 0.01, gate=False)
    tank, box, gate = settle["RigidBodies"]
    assert len(release["RigidBodies"]) == 2
    assert tank["mapInvert"] and not box["mapInvert"] and not gate["mapInvert"]
    lo, hi = _extent(tank)
    assert lo == pytest.approx([-dl] * 3) and hi == pytest.approx(np.array(P.TANK) + dl)
    lo, hi = _extent(box)
    assert lo[[0, 2]] == pytest.approx(np.array(P.BOX[0])[[0, 2]] + dl) and lo[1] < 0
    assert hi == pytest.approx(np.array(P.BOX[1]) - dl)
    assert _extent(gate)[1][0] == pytest.approx(P.GATE - dl)
    assert settle["Configuration"]["particleRadius"] == pytest.approx(r)


@pytest.mark.parametrize("layers, within", [(27, 0.002), (40, 0.015)])
def test_the_reservoir_is_mrsph_s_water_started_clear_of_the_walls(layers, within):
    """SPlisHSPlasH's block puts particles from 2 r inside its start to 2 r inside its end; each
    one must start 3 r from every mesh, and the count be mrsph's (60 x 27 x 49 at the scene's)."""
    s = P.DEPTH / layers
    r = s / 2
    first, last, target = P.lattice(s)
    if layers == 27:
        assert target == 60 * 27 * 49
    block = P.scene(s, 0.01, gate=True)["FluidBlocks"][0]
    assert np.array(block["start"]) + 2 * r == pytest.approx(first)
    assert np.array(block["end"]) - 2 * r == pytest.approx(last, abs=1e-5)
    counts = np.rint((np.array(last) - np.array(first)) / s).astype(int) + 1
    assert abs(counts.prod() / target - 1) < within
    dl = (P.REST - 1) * r
    assert first[0] - (P.GATE - dl) == pytest.approx(3 * r) and first[1] + dl == pytest.approx(3 * r)
    assert (np.array(P.TANK) + dl - np.array(last) >= 3 * r - 1e-9).all()


def test_the_cube_is_closed_and_wound_outwards(tmp_path):
    P.cube_obj(tmp_path / "cube.obj")
    lines = (tmp_path / "cube.obj").read_text().splitlines()
    v = np.array([[float(c) for c in ln.split()[1:]] for ln in lines if ln.startswith("v ")])
    f = np.array([[int(c) - 1 for c in ln.split()[1:]] for ln in lines if ln.startswith("f ")])
    assert v.shape == (8, 3) and f.shape == (12, 3)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    normals = np.cross(b - a, c - a)
    assert (np.einsum("ij,ij->i", normals, (a + b + c) / 3) > 0).all()
    edges = {}
    for tri in f:
        for i in range(3):
            e = (tri[i], tri[(i + 1) % 3])
            edges[e] = edges.get(e, 0) + 1
    assert all(edges.get((b, a)) == 1 for a, b in edges)  # each edge once each way: closed, one winding


def test_a_row_reads_when_each_probe_stands_2_and_6_cm():
    t = np.arange(0, 1.3, 0.002)
    levels = [np.clip((t - t0) * 1.0, 0, None) for t0 in (1.0, 0.4, 0.25)]
    row = P.row("made up", t, levels)
    assert row.startswith("| made up | 1.020 / 1.060 s | 1.020 / 1.060 s | 0.420 / 0.460 s | 0.270 / 0.310 s |")


def test_a_level_held_is_the_water_s_not_a_splash_passing():
    """A spike to 10 cm at 0.9 s for 20 ms, then water rising from 1.0 s: the first crossing reads
    the spike, the held one the water; a level reached in the last 30 ms is not held."""
    t = np.arange(0, 1.3, 0.002)
    f = np.clip(t - 1.0, 0, None) + np.where((t >= 0.9) & (t < 0.92), 0.1, 0.0)
    assert V.first_crossing(t, f, 0.02) < 0.91
    assert P.held_crossing(t, f, 0.02) == pytest.approx(1.02)
    assert P.held_crossing(t, f, 0.06) == pytest.approx(1.06)
    assert P.held_crossing(t, f, 0.29) is None  # reached at 1.29 s, 10 ms before the record ends
    assert P.held_crossing(t, f, 0.02, hold=0.01) == pytest.approx(0.9)


@pytest.mark.parametrize(
    "args, line",
    [
        (["--layers", "3"], "--layers 3: expected at least 8 (the box is 161 mm high, the water 550 mm deep)"),
        (["--viscosity", "-1"], "--viscosity -1: expected a kinematic viscosity >= 0 (m²/s)"),
        ([], "pysplishsplash is not installed here: run this tool in its own environment (see its docstring)"),
    ],
)
def test_a_bad_argument_or_no_splishsplash_is_one_line(args, line):
    if not args and importlib.util.find_spec("pysplishsplash"):  # found, not imported: its import may crash
        pytest.skip("SPlisHSPlasH is installed here")
    proc = subprocess.run([sys.executable, "tools/peer_box.py", *args], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert [ln for ln in proc.stderr.splitlines() if ln.strip()] == [line]


def test_a_peer_run_stores_its_arrivals_beside_the_data_s():
    """Both peers store what ``measured`` reads: H1-H3 reached at 2 and 6 cm, each lee point at 2 cm,
    H3's mean over its window, and the data's arrivals from the shipped CSV."""
    t = np.arange(0, 1.3, 0.002)
    levels = np.stack([np.clip(t - t0, 0, None) for t0 in (1.0, 0.4, 0.25)], axis=1)
    lee = np.stack([np.clip(t - 0.5 - 0.1 * k, 0, None) for k in range(len(V.LEE))], axis=1)
    out = P.measured(t, levels, lee)
    assert [(p["name"], round(p["arrival"], 3), round(p["body"], 3)) for p in out["probes"]] == [
        ("H1", 1.02, 1.06),
        ("H2", 0.42, 0.46),
        ("H3", 0.27, 0.31),
    ]
    assert [round(p["arrival_exp"], 3) for p in out["probes"]] == [0.92, 0.367, 0.218]
    assert [round(entry["arrival"], 3) for entry in out["lee"]] == [round(0.52 + 0.1 * k, 3) for k in range(len(V.LEE))]
    assert out["h3_mean"] == pytest.approx(np.mean(t[(t >= 0.3) & (t <= 0.7)] - 0.25))
    assert np.array(out["level"]).shape == (3, len(t))
