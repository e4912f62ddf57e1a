#!/usr/bin/env python3
"""MARIN's dam break past a box (tools/validate.py's box case) in OpenFOAM's interFoam, a volume-of-
fluid code with air: whether a code of the experiment's own family, read by mrsph's gauge rule,
puts the water at H1, behind the box, where the data does.

OpenFOAM is no dependency of mrsph; Debian packages it (v1912):

    apt-get install -y openfoam
    python3 tools/peer_vof.py --layers 27     # cells 0.55 m / 27 = mrsph's spacing: 27 min on 2 MPI ranks
    python3 tools/peer_vof.py --layers 20 --slip   # 5 min; free-slip walls, as SPH's mirror images
    python3 tools/peer_box.py --report        # the table and figure, beside SPlisHSPlasH and mrsph

The set-up is mrsph's scene (scenes/dam_break_box_3d.toml), its tank, box and reservoir read from
its file, on a mesh of cubes about ``0.55 / layers`` m whose block edges lie on the box's faces,
the gate and the water's surface, so that the box and the reservoir are exact:
- water (1000 kg/m³, 1e-6 m²/s) and air (1 kg/m³, 1.48e-5 m²/s), surface tension 0.07 N/m,
  laminar (no model of turbulence), no slip at every wall (``--slip``: free slip), the tank's top
  open to the air; ``--viscosity`` sets the water's;
- the reservoir released at t = 0 from rest, as mrsph's;
- the height at a probe as mrsph's gauge reads it (``validate.water_level``): from the floor up,
  the first height where the water's fraction falls below 1/2, here interpolated between cell
  centres, in the gauge's cell's column (averaged over the two either side where the gauge lies on
  a cell face, as the centre line may);
- the water above the box and in its shadow, as tools/box_overtop.py counts mrsph's.
The run's heights and those volumes go to docs/validation/peer/box-openfoam-*.json.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import peer_box as P  # noqa: E402  (the scene's geometry, read from its file)
import validate as V  # noqa: E402  (the probes, the data and the crossings: numpy only)

END_S = P.END_S
MIN_LAYERS = 8  # the box is then 2 cells high
ZONES = ("above", "shadow")
HEADER = "FoamFile {{ version 2.0; format ascii; class {cls}; object {obj}; }}\n"
# Debian's OpenFOAM finds its etc/ through WM_PROJECT_DIR; Open MPI runs as root only when told to
FOAM_ENV = {
    "WM_PROJECT_DIR": "/usr/share/openfoam",
    "OMPI_ALLOW_RUN_AS_ROOT": "1",
    "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
}


def edges(layers: int) -> tuple[list, list, list]:
    """The blocks' edges along x, y and z: every face of the box, the gate and the water's
    surface; and how many cells each block gets, the nearest to cubes 0.55 / layers m wide."""
    h = P.DEPTH / layers
    (bx0, _, bz0), (bx1, by1, bz1) = P.BOX
    cuts = ([0, bx0, bx1, P.GATE, P.TANK[0]], [0, by1, P.DEPTH, P.TANK[1]], [0, bz0, bz1, P.TANK[2]])
    return [(c, [max(1, round((b - a) / h)) for a, b in zip(c, c[1:])]) for c in cuts]


def centres(cut: list, n: list) -> np.ndarray:
    """The cell centres along one axis."""
    return np.concatenate([a + (np.arange(k) + 0.5) * (b - a) / k for a, b, k in zip(cut, cut[1:], n)])


def block_mesh(layers: int) -> str:
    """blockMeshDict: the tank cut into blocks at the box, the gate and the surface, less the box's
    block; its faces and the tank's are the patch ``walls``, the top ``atmosphere``."""
    (xs, nx), (ys, ny), (zs, nz) = edges(layers)
    index = {}
    verts = []
    for k, z in enumerate(zs):
        for j, y in enumerate(ys):
            for i, x in enumerate(xs):
                index[i, j, k] = len(verts)
                verts.append(f"({x:.6g} {y:.6g} {z:.6g})")
    blocks, top = [], []
    for k in range(len(nz)):
        for j in range(len(ny)):
            for i in range(len(nx)):
                if (i, j, k) == (1, 0, 1):  # the box
                    continue
                v = [index[i + a, j + b, k + c] for c in (0, 1) for a, b in ((0, 0), (1, 0), (1, 1), (0, 1))]
                blocks.append(f"hex ({' '.join(map(str, v))}) ({nx[i]} {ny[j]} {nz[k]}) simpleGrading (1 1 1)")
                if j == len(ny) - 1:
                    t = len(ys) - 1
                    face = [index[i, t, k], index[i, t, k + 1], index[i + 1, t, k + 1], index[i + 1, t, k]]
                    top.append(f"({' '.join(map(str, face))})")
    return (
        HEADER.format(cls="dictionary", obj="blockMeshDict")
        + "convertToMeters 1;\nvertices (\n"
        + "\n".join(verts)
        + "\n);\nblocks (\n"
        + "\n".join(blocks)
        + "\n);\nedges ();\nboundary (\n atmosphere { type patch; faces (\n"
        + "\n".join(top)
        + "\n); }\n);\ndefaultPatch { name walls; type wall; }\nmergePatchPairs ();\n"
    )


def probe_columns(layers: int) -> tuple[list, np.ndarray]:
    """Where the probes sample: for each gauge (H1-H4 on the centre line, then ``validate.LEE``),
    two columns at every cell centre up to the top, both through the gauge's cell, or a quarter
    cell either side of it where it lies on a cell face (the centre line does); and those centres'
    heights."""
    (xs, nx), (ys, ny), (zs, nz) = edges(layers)
    y = centres(ys, ny)
    faces = [
        np.concatenate([np.linspace(a, b, k + 1) for a, b, k in zip(c, c[1:], n)]) for c, n in ((xs, nx), (zs, nz))
    ]
    quarter = P.DEPTH / layers / 4
    gauges = [(px, P.TANK[2] / 2) for px in V.PROBES] + list(V.LEE)
    pts = []
    for x, z in gauges:
        dx, dz = (quarter if np.isclose(f, c, atol=1e-9).any() else 0.0 for f, c in zip(faces, (x, z)))
        pts += [(x + side * dx, yy, z + side * dz) for side in (-1, 1) for yy in y]
    return pts, y


def write_case(case: Path, layers: int, ranks: int, nu: float = 1e-6, slip: bool = False) -> None:
    """Every file of the case: the mesh, the water, the fields' boundaries, the solver's settings."""
    files = {
        "system/blockMeshDict": block_mesh(layers),
        "system/controlDict": controldict(layers),
        "system/fvSchemes": FV_SCHEMES,
        "system/fvSolution": FV_SOLUTION,
        "system/setFieldsDict": set_fields(),
        "system/topoSetDict": topo_set(),
        "system/decomposeParDict": HEADER.format(cls="dictionary", obj="decomposeParDict")
        + f"numberOfSubdomains {ranks};\nmethod simple;\nsimpleCoeffs {{ n ({ranks} 1 1); delta 0.001; }}\n",
        "constant/transportProperties": transport(nu),
        "constant/turbulenceProperties": HEADER.format(cls="dictionary", obj="turbulenceProperties")
        + "simulationType laminar;\n",
        "constant/g": HEADER.format(cls="uniformDimensionedVectorField", obj="g")
        + "dimensions [0 1 -2 0 0 0 0];\nvalue (0 -9.81 0);\n",
        "0/alpha.water": FIELD.format(
            cls="volScalarField", obj="alpha.water", dim="[0 0 0 0 0 0 0]", value="0",
            walls="zeroGradient;", atmosphere="inletOutlet; inletValue uniform 0; value uniform 0;",
        ),
        "0/U": FIELD.format(
            cls="volVectorField", obj="U", dim="[0 1 -1 0 0 0 0]", value="(0 0 0)",
            walls="slip;" if slip else "noSlip;", atmosphere="pressureInletOutletVelocity; value uniform (0 0 0);",
        ),
        "0/p_rgh": FIELD.format(
            cls="volScalarField", obj="p_rgh", dim="[1 -1 -2 0 0 0 0]", value="0",
            walls="fixedFluxPressure; value uniform 0;", atmosphere="totalPressure; p0 uniform 0;",
        ),
    }  # fmt: skip
    for name, text in files.items():
        (case / name).parent.mkdir(parents=True, exist_ok=True)
        (case / name).write_text(text)


def transport(nu: float) -> str:
    """transportProperties: water of kinematic viscosity ``nu`` and air."""
    return HEADER.format(cls="dictionary", obj="transportProperties") + (
        "phases (water air);\n"
        f"water {{ transportModel Newtonian; nu {nu:g}; rho 1000; }}\n"
        "air { transportModel Newtonian; nu 1.48e-05; rho 1; }\n"
        "sigma 0.07;\n"
    )


def set_fields() -> str:
    """setFieldsDict: water in the reservoir's cells, from the gate to the end wall, to its depth."""
    box = f"({P.GATE} -1 -1) ({P.TANK[0] + 1} {P.DEPTH} {P.TANK[2] + 1})"
    return HEADER.format(cls="dictionary", obj="setFieldsDict") + (
        "defaultFieldValues ( volScalarFieldValue alpha.water 0 );\n"
        f"regions ( boxToCell {{ box {box}; fieldValues ( volScalarFieldValue alpha.water 1 ); }} );\n"
    )


def zones() -> dict:
    """The regions whose water each run records, as tools/box_overtop.py counts mrsph's: above the
    box's top over its footprint, and its shadow between x = 0.3 m and its back face, 5 cm inside
    its width."""
    (x0, _, z0), (x1, y1, z1) = P.BOX
    return {
        "above": ((x0, y1, z0), (x1, P.TANK[1] + 1, z1)),
        "shadow": ((0.3, -1, z0 + 0.05), (x0, P.TANK[1] + 1, z1 - 0.05)),
    }


def topo_set() -> str:
    """topoSetDict: each of ``zones()`` a cell zone of the cells whose centres lie in it."""
    actions = "".join(
        f"{{ name {z}; type cellSet; action new; source boxToCell; box ({' '.join(map(str, lo))}) "
        f"({' '.join(map(str, hi))}); }}\n{{ name {z}; type cellZoneSet; action new; source setToCellZone; "
        f"set {z}; }}\n"
        for z, (lo, hi) in zones().items()
    )
    return HEADER.format(cls="dictionary", obj="topoSetDict") + f"actions (\n{actions});\n"


def controldict(layers: int) -> str:
    """controlDict: the run to ``END_S`` at a Courant number of 0.5, the gauges' columns sampled
    every step and each zone's water integrated every step."""
    pts, _ = probe_columns(layers)
    locations = "\n".join(f"({x:.6g} {y:.6g} {z:.6g})" for x, y, z in pts)
    return HEADER.format(cls="dictionary", obj="controlDict") + (
        f"application interFoam;\nstartFrom startTime;\nstartTime 0;\nstopAt endTime;\nendTime {END_S};\n"
        "deltaT 0.0002;\nwriteControl adjustable;\nwriteInterval 0.1;\npurgeWrite 0;\nwriteFormat binary;\n"
        "writePrecision 6;\nwriteCompression off;\ntimeFormat general;\ntimePrecision 6;\n"
        "runTimeModifiable no;\nadjustTimeStep yes;\nmaxCo 0.5;\nmaxAlphaCo 0.5;\nmaxDeltaT 0.002;\n"
        "functions { gauges { type probes; libs (\"libsampling.so\"); writeControl timeStep; writeInterval 1;\n"
        f"fields (alpha.water); probeLocations (\n{locations}\n); }}\n"
        + "".join(
            f"{zone} {{ type volFieldValue; libs (\"libfieldFunctionObjects.so\"); writeControl timeStep; "
            f"writeInterval 1; log false; writeFields false; regionType cellZone; name {zone}; "
            "operation volIntegrate; fields (alpha.water); }\n"
            for zone in ZONES
        )
        + "}\n"
    )


FIELD = (
    HEADER
    + "dimensions {dim};\ninternalField uniform {value};\n"
    + "boundaryField {{ walls {{ type {walls} }} atmosphere {{ type {atmosphere} }} }}\n"
)
FV_SCHEMES = HEADER.format(cls="dictionary", obj="fvSchemes") + (
    "ddtSchemes { default Euler; }\ngradSchemes { default Gauss linear; }\n"
    "divSchemes { div(rhoPhi,U) Gauss linearUpwind grad(U); div(phi,alpha) Gauss vanLeer;\n"
    " div(phirb,alpha) Gauss linear; div(((rho*nuEff)*dev2(T(grad(U))))) Gauss linear; }\n"
    "laplacianSchemes { default Gauss linear corrected; }\ninterpolationSchemes { default linear; }\n"
    "snGradSchemes { default corrected; }\n"
)
FV_SOLUTION = HEADER.format(cls="dictionary", obj="fvSolution") + (
    "solvers {\n"
    ' "alpha.water.*" { nAlphaCorr 2; nAlphaSubCycles 1; cAlpha 1; MULESCorr yes; nLimiterIter 5;\n'
    "  solver smoothSolver; smoother symGaussSeidel; tolerance 1e-8; relTol 0; }\n"
    ' "pcorr.*" { solver PCG; preconditioner DIC; tolerance 1e-5; relTol 0; }\n'
    " p_rgh { solver GAMG; smoother DIC; tolerance 1e-7; relTol 0.05; }\n"
    " p_rghFinal { $p_rgh; relTol 0; }\n"
    ' "U.*" { solver smoothSolver; smoother symGaussSeidel; tolerance 1e-6; relTol 0; }\n'
    "}\n"
    "PIMPLE { momentumPredictor no; nOuterCorrectors 1; nCorrectors 3; nNonOrthogonalCorrectors 0; }\n"
)


def read_probes(case: Path) -> tuple[np.ndarray, np.ndarray]:
    """The probes' water fractions (every time step, every sampled point), from OpenFOAM's file."""
    files = sorted((case / "postProcessing" / "gauges").glob("*/alpha.water"), key=lambda p: float(p.parent.name))
    t, rows = [], []
    for path in files:
        for line in path.read_text().splitlines():
            if line.startswith("#") or not line.strip():
                continue
            vals = line.split()
            t.append(float(vals[0]))
            rows.append([float(v) for v in vals[1:]])
    return np.array(t), np.array(rows)


def zone_water(case: Path) -> dict:
    """Each zone's water (litres) against time, every step, from OpenFOAM's volFieldValue files."""
    out = {}
    for z in ZONES:
        rows = [ln.split() for ln in (case / "postProcessing" / z / "0" / "volFieldValue.dat").read_text().splitlines()]
        data = np.array([[float(v) for v in r] for r in rows if r and not r[0].startswith("#")])
        out[z] = {"t": data[:, 0].round(5).tolist(), "litres": (data[:, 1] * 1000).round(3).tolist()}
    return out


def gauge(case: Path, layers: int) -> tuple[np.ndarray, np.ndarray]:
    """Time and each gauge's height (H1-H4, then ``validate.LEE``) by mrsph's rule."""
    t, alpha = read_probes(case)
    _, y = probe_columns(layers)
    n = len(y)
    gauges = alpha.shape[1] // (2 * n)
    out = np.zeros((len(t), gauges))
    for g in range(gauges):
        cols = alpha[:, 2 * g * n : 2 * (g + 1) * n].reshape(len(t), 2, n).mean(axis=1)
        out[:, g] = [V.surface_height(y, c) for c in cols]  # below the lowest centre, the lowest cell's
    return t, out


def foam(case: Path, log: str, *cmd: str) -> None:
    """One OpenFOAM command in the case, its output to ``log``; a failure is one line."""
    with open(case / f"log.{log}", "w") as f:
        done = subprocess.run(cmd, cwd=case, stdout=f, stderr=subprocess.STDOUT, env={**FOAM_ENV, **os.environ})
    if done.returncode:
        tail = (case / f"log.{log}").read_text().strip().splitlines()[-3:]
        P.fail(f"{' '.join(cmd)} failed in {case} (exit {done.returncode}): {' '.join(tail)}")


def run(layers: int, ranks: int, work: Path, nu: float = 1e-6, slip: bool = False) -> dict:
    if work.exists():
        shutil.rmtree(work)
    commit = V._commit()  # the code this run loads, read now: HEAD may move while it runs
    write_case(work, layers, ranks, nu, slip)
    wall = time.perf_counter()
    foam(work, "blockMesh", "blockMesh")
    foam(work, "topoSet", "topoSet")
    foam(work, "setFields", "setFields")
    if ranks > 1:
        foam(work, "decomposePar", "decomposePar")
        foam(work, "interFoam", "mpirun", "-np", str(ranks), "--allow-run-as-root", "interFoam", "-parallel")
    else:
        foam(work, "interFoam", "interFoam")
    cells = re.search(r"nCells:\s*(\d+)", (work / "log.blockMesh").read_text())
    t, levels = gauge(work, layers)
    version = subprocess.run(["dpkg-query", "-W", "-f=${Version}", "openfoam"], capture_output=True, text=True)
    return {
        "code": f"OpenFOAM {version.stdout.strip() or '?'} interFoam (VOF, water and air)",
        "date": datetime.date.today().isoformat(),
        "commit": commit,
        "layers": layers,
        "cell": P.DEPTH / layers,
        "viscosity": nu,
        "walls": "slip" if slip else "no slip",
        "cells": int(cells.group(1)) if cells else None,
        "ranks": ranks,
        "wall_s": round(time.perf_counter() - wall, 1),
        "water": zone_water(work),
        **P.measured(t, levels[:, :4], levels[:, 4:]),
    }


def name(layers: int, nu: float = 1e-6, slip: bool = False) -> str:
    return f"box-openfoam-{layers}" + (f"-nu{nu:g}" if nu != 1e-6 else "") + ("-slip" if slip else "")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--layers", type=int, default=27, help="cells over the water's depth (27: mrsph's spacing)")
    ap.add_argument("--viscosity", type=float, default=1e-6, help="the water's kinematic viscosity, m²/s (water's)")
    ap.add_argument("--slip", action="store_true", help="free-slip walls, as SPH's mirror images (else no slip)")
    ap.add_argument("--ranks", type=int, default=2, help="MPI ranks (1: no MPI)")
    ap.add_argument("--work", type=Path, default=None, help="scratch folder for the case")
    args = ap.parse_args()
    if args.layers < MIN_LAYERS:
        P.fail(
            f"--layers {args.layers}: expected at least {MIN_LAYERS} (the box is 161 mm high, the water 550 mm deep)"
        )
    if not args.viscosity > 0:
        P.fail(f"--viscosity {args.viscosity:g}: expected a kinematic viscosity > 0 (m²/s)")
    if args.ranks < 1:
        P.fail(f"--ranks {args.ranks}: expected at least 1")
    if shutil.which("interFoam") is None:
        P.fail("OpenFOAM's interFoam is not on PATH: apt-get install -y openfoam (see this tool's docstring)")
    work = args.work or Path(tempfile.gettempdir()) / f"peer_vof_{args.layers}"
    out = run(args.layers, args.ranks, work, args.viscosity, args.slip)
    P.OUT.mkdir(parents=True, exist_ok=True)
    (P.OUT / f"{name(args.layers, args.viscosity, args.slip)}.json").write_text(json.dumps(out))
    P.summary(out, f"{out['cells']} cells, {out['wall_s']} s")


if __name__ == "__main__":
    main()
