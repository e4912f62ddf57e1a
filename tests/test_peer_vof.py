"""tools/peer_vof.py: MARIN's box in OpenFOAM's interFoam (docs/validation.md, MARIN's H1). What it
sets up and how it reads the water is checked here without OpenFOAM, which mrsph does not depend
on: the mesh must be the box scene's tank less its box, with the box, the gate and the water's
surface on cell faces; the water the reservoir's; the gauge mrsph's rule."""

import os
import re
import subprocess
import sys

import numpy as np
import pytest
from toolload import load_tool

F = load_tool("peer_vof")
P = load_tool("peer_box")
V = load_tool("validate")


def _blocks(layers):
    """Each hex block of the blockMeshDict as (lower corner, upper corner, cells), and the top faces."""
    text = F.block_mesh(layers)
    verts = np.array(
        [[float(c) for c in v.split()] for v in re.findall(r"^\(([-\d.e ]+)\)$", text.split("blocks")[0], re.M)]
    )
    blocks = []
    for ids, cells in re.findall(r"hex \(([\d ]+)\) \(([\d ]+)\)", text):
        corners = verts[[int(i) for i in ids.split()]]
        blocks.append((corners.min(axis=0), corners.max(axis=0), [int(c) for c in cells.split()], corners))
    top = text.split("atmosphere")[1].split(");")[0]
    faces = [verts[[int(i) for i in f.split()]] for f in re.findall(r"\(([\d ]+)\)", top)]
    return blocks, faces


@pytest.mark.parametrize("layers", [14, 27])
def test_the_mesh_is_the_tank_less_the_box_in_near_cubes(layers):
    blocks, _ = _blocks(layers)
    lo_box, hi_box = np.array(P.BOX[0]), np.array(P.BOX[1])
    assert len(blocks) == 4 * 3 * 3 - 1
    volume = 0.0
    h = P.DEPTH / layers
    for lo, hi, cells, corners in blocks:
        assert not ((lo < hi_box - 1e-9) & (hi > lo_box + 1e-9)).all()  # no block inside the box
        volume += np.prod(hi - lo)
        assert (hi - lo) / cells == pytest.approx(np.full(3, h), rel=0.3)
        # blockMesh's order: the lower face anticlockwise seen from above the block's z, then the upper
        assert (corners[:4, 2] == lo[2]).all() and (corners[4:, 2] == hi[2]).all()
        assert np.cross(corners[1] - corners[0], corners[3] - corners[0])[2] > 0
    assert volume == pytest.approx(np.prod(P.TANK) - np.prod(hi_box - lo_box))


def test_the_box_the_gate_and_the_surface_lie_on_cell_faces():
    (xs, _), (ys, _), (zs, _) = F.edges(27)
    assert {P.BOX[0][0], P.BOX[1][0], P.GATE} <= set(xs)
    assert {P.BOX[1][1], P.DEPTH} <= set(ys)
    assert {P.BOX[0][2], P.BOX[1][2]} <= set(zs)
    text = F.set_fields()
    box = [float(v) for v in re.search(r"box \(([^)]*)\) \(([^)]*)\)", text).group(1, 2)[0].split()]
    top = [float(v) for v in re.search(r"box \(([^)]*)\) \(([^)]*)\)", text).group(1, 2)[1].split()]
    assert box[0] == P.GATE and top[1] == P.DEPTH and top[0] > P.TANK[0] and box[1] < 0


def test_the_top_is_open_and_its_faces_point_out():
    _, faces = _blocks(27)
    assert len(faces) == 4 * 3
    for f in faces:
        assert (f[:, 1] == P.TANK[1]).all()
        assert np.cross(f[1] - f[0], f[2] - f[0])[1] > 0  # blockMesh wants a boundary face's normal outwards


def test_the_gauge_reads_from_the_floor_up_to_where_the_fraction_falls_below_a_half():
    y = (np.arange(20) + 0.5) * 0.05  # cells 5 cm high
    wet = np.where(y < 0.3, 1.0, 0.0)
    assert V.surface_height(y, wet) == pytest.approx(0.3)  # the crossing between centres 0.275 and 0.325
    assert V.surface_height(y, np.where(y > 0.5, 1.0, 0.0)) == 0.0  # spray over a dry floor
    spray = wet.copy()
    spray[15] = 1.0
    assert V.surface_height(y, spray) == pytest.approx(0.3)  # spray above the water does not count
    assert V.surface_height(y, np.ones(20)) == pytest.approx(y[-1])
    half = wet.copy()
    half[6] = 0.75  # the cell 0.30-0.35 m three quarters full: the half crossed a quarter of the way up
    assert V.surface_height(y, half) == pytest.approx(0.325 + 0.25 / 0.75 * 0.05)


def test_the_probes_file_becomes_each_gauge_s_height(tmp_path):
    """A made-up probes file: every gauge's two columns full to its own height, which the gauge
    must read back in the order H1-H4, then validate.LEE."""
    pts, y = F.probe_columns(14)
    gauges = 4 + len(V.LEE)
    assert len(pts) == gauges * 2 * len(y)
    centre = P.TANK[2] / 2
    assert pts[0][0] == V.PROBES[0] and pts[0][2] < centre < pts[len(y)][2]  # the centre line is a face
    lee = pts[2 * len(y) * 5 :][: 2 * len(y)]  # validate.LEE's second, 1.5 mm inside the box's shadow
    assert {(p[0], p[2]) for p in lee} == {tuple(V.LEE[1])}
    heights = 0.05 + 0.03 * np.arange(gauges)
    rows = []
    for t in (0.1, 0.2):
        alpha = [float(yy < hh) for hh in heights for _ in (0, 1) for yy in y]
        rows.append(f"{t} " + " ".join(map(str, alpha)))
    out = tmp_path / "postProcessing" / "gauges" / "0"
    out.mkdir(parents=True)
    (out / "alpha.water").write_text("# Probe 0 (0 0 0)\n# Time\n" + "\n".join(rows) + "\n")
    t, levels = F.gauge(tmp_path, 14)
    assert t.tolist() == [0.1, 0.2]
    step = np.diff(y).max()
    assert np.abs(levels - heights).max() <= step / 2 + 1e-9


def test_the_zones_are_where_box_overtop_counts_mrsph_s_water(tmp_path):
    """Above the box's top over its footprint; its shadow from x = 0.3 m to its back face, 5 cm
    inside its width (tools/box_overtop.py); and their files read back in litres."""
    (x0, _, z0), (x1, top, z1) = P.BOX
    above, shadow = F.zones()["above"], F.zones()["shadow"]
    assert above[0] == (x0, top, z0) and above[1][0] == x1 and above[1][2] == z1 and above[1][1] > P.TANK[1]
    assert shadow[0][0] == 0.3 and shadow[1][0] == x0
    assert (shadow[0][2], shadow[1][2]) == pytest.approx((z0 + 0.05, z1 - 0.05))
    assert shadow[0][1] < 0 and shadow[1][1] > P.TANK[1]
    text = F.topo_set()
    for name, (lo, hi) in F.zones().items():
        box = f"box ({' '.join(map(str, lo))}) ({' '.join(map(str, hi))})"
        assert f"name {name}; type cellSet; action new; source boxToCell; {box}" in text
        assert f"name {name}; type cellZoneSet; action new; source setToCellZone; set {name};" in text
    for k, name in enumerate(F.ZONES):
        out = tmp_path / "postProcessing" / name / "0"
        out.mkdir(parents=True)
        (out / "volFieldValue.dat").write_text(f"# Time volIntegrate({name},alpha.water)\n0.1 {k + 1}e-3\n0.2 0.01\n")
    water = F.zone_water(tmp_path)
    assert water["above"] == {"t": [0.1, 0.2], "litres": [1.0, 10.0]} and water["shadow"]["litres"] == [2.0, 10.0]


def test_the_water_s_viscosity_and_the_walls_are_what_the_run_asks(tmp_path):
    F.write_case(tmp_path / "a", 10, 2, nu=0.01, slip=True)
    assert (
        "water { transportModel Newtonian; nu 0.01; rho 1000; }"
        in (tmp_path / "a/constant/transportProperties").read_text()
    )
    assert "walls { type slip; }" in (tmp_path / "a/0/U").read_text()
    F.write_case(tmp_path / "b", 10, 2)
    assert "nu 1e-06; rho 1000" in (tmp_path / "b/constant/transportProperties").read_text()
    assert "walls { type noSlip; }" in (tmp_path / "b/0/U").read_text()
    assert [F.name(27), F.name(27, 0.01, True)] == ["box-openfoam-27", "box-openfoam-27-nu0.01-slip"]


@pytest.mark.parametrize(
    "args, path, line",
    [
        (["--layers", "3"], None, "--layers 3: expected at least 8 (the box is 161 mm high, the water 550 mm deep)"),
        (["--ranks", "0"], None, "--ranks 0: expected at least 1"),
        (["--viscosity", "0"], None, "--viscosity 0: expected a kinematic viscosity > 0 (m²/s)"),
        ([], "", "OpenFOAM's interFoam is not on PATH: apt-get install -y openfoam (see this tool's docstring)"),
    ],
)
def test_a_bad_argument_or_no_openfoam_is_one_line(args, path, line):
    env = dict(os.environ) if path is None else {**os.environ, "PATH": path}
    proc = subprocess.run(
        [sys.executable, "tools/peer_vof.py", *args], capture_output=True, text=True, timeout=60, env=env
    )
    assert proc.returncode == 2, proc.stderr
    assert [ln for ln in proc.stderr.splitlines() if ln.strip()] == [line]
