"""Frame dumps (npz, PLY, VTU, OBJ surface) and ``stats.csv``; numpy only, no Taichi.

A frame dump holds every alive particle, virtual ones included, with the arrays

=======  ========  ===========================================================
``x``    (N, d)    position, m
``v``    (N, d)    velocity, m/s
``m``    (N,)      mass, kg
``rho``  (N,)      density, kg/m^3
``p``    (N,)      pressure, Pa (WCSPH: the equation of state's; DFSPH: the solve's)
``level`` (N,)     int32, resolution level (0 = finest)
``kind`` (N,)      int32, kind code (docs/ARCHITECTURE.md; virtual = kind >= 4)
=======  ========  ===========================================================

``frame_00000.npz`` keeps them as they are. ``frame_00000.ply`` is a binary
little-endian point cloud (ParaView, MeshLab, Blender) with the properties
``x y z vx vy vz m rho p level kind``; 2D positions and velocities get z = 0.
``frame_00000.vtu`` is a VTK unstructured grid of vertex cells (ParaView) with ``v``,
``m``, ``rho``, ``p``, ``level`` and ``kind`` as point data, written by meshio.
``frame_00000.obj`` is not the particles but the fluid's surface (:mod:`mrsph.io.surface`,
the window's water view) as a Wavefront OBJ triangle mesh for Blender and the like:
3D, a closed mesh with vertex normals, wound outward; 2D, the filled area as triangles
in the plane z = 0. Vertices are shared between triangles (merged to 1e-9 m).
"""

from __future__ import annotations

import csv
import math
import re
import warnings
from pathlib import Path

import numpy as np

FORMATS = ("npz", "ply", "vtk", "obj")
FRAME_ARRAYS = ("x", "v", "m", "rho", "p", "level", "kind")
#: File name of frame i: frame_00000.npz; five digits keep frames sorted by name.
FRAME_NAME = "frame_{:05d}.{}"
_SUFFIX = {"npz": "npz", "ply": "ply", "vtk": "vtu", "obj": "obj"}
DUMP_SUFFIXES = tuple(_SUFFIX.values())
_PLY_TYPES = {np.dtype("<f4"): "float", np.dtype("<f8"): "double", np.dtype("<i4"): "int"}


def clear_frames(directory, suffixes) -> int:
    """Remove the frame files (``frame_NNNNN.<suffix>``) that an earlier run left in
    ``directory``, so that a shorter run does not leave the tail of a longer one to be
    read as part of its series; warns (RuntimeWarning) with the count. Other files stay."""
    d = Path(directory)
    if not d.is_dir():
        return 0
    pattern = re.compile(r"frame_\d{5,}\.(?:" + "|".join(map(re.escape, suffixes)) + ")")  # FRAME_NAME
    old = [f for f in d.iterdir() if pattern.fullmatch(f.name) and f.is_file()]
    for f in old:
        f.unlink()
    if old:
        warnings.warn(f"{d}: removed {len(old)} frame file(s) of an earlier run", RuntimeWarning, stacklevel=2)
    return len(old)


def frame_path(directory, frame_index: int, fmt: str = "npz") -> Path:
    """Where :func:`write_frame` puts frame ``frame_index`` in format ``fmt``."""
    if fmt not in FORMATS:
        raise ValueError(f"fmt: expected one of {', '.join(FORMATS)} (got {fmt!r})")
    return Path(directory) / FRAME_NAME.format(int(frame_index), _SUFFIX[fmt])


def _frame_arrays(parts: dict, dim: int) -> dict:
    """The documented arrays of ``parts`` with checked shapes and fixed dtypes. ``p`` may
    be left out (a stand-in without a pressure): it is written as zeros."""
    if "p" not in parts and "rho" in parts:
        parts = {**parts, "p": np.zeros(np.shape(parts["rho"]), np.asarray(parts["rho"]).dtype)}
    missing = [k for k in FRAME_ARRAYS if k not in parts]
    if missing:
        raise ValueError(f"parts: missing arrays {', '.join(missing)} (expected {', '.join(FRAME_ARRAYS)})")
    x = np.asarray(parts["x"])
    n = len(x)
    out = {}
    for key in FRAME_ARRAYS:
        a = np.asarray(parts[key])
        if key in ("level", "kind"):
            a = a.astype(np.int32)
        elif a.dtype.kind != "f":
            a = a.astype(np.float64)
        a = a.reshape(n, dim) if key in ("x", "v") else a.reshape(n)
        out[key] = np.ascontiguousarray(a)
    return out


def _pad3(a: np.ndarray) -> np.ndarray:
    """(N, d) -> (N, 3), zeros in the missing components."""
    if a.shape[1] == 3:
        return a
    return np.concatenate([a, np.zeros((len(a), 3 - a.shape[1]), a.dtype)], axis=1)


def write_frame(directory, frame_index: int, parts: dict, dim: int, fmt: str = "npz", domain=None) -> Path:
    """Write one frame of particles to ``directory`` (created if needed); returns the path.

    ``parts`` is ``Simulation.particles()`` (or a snapshot's arrays): at least x, v, m,
    rho, level and kind; other arrays are ignored. ``domain``: (min, max), the tank whose
    walls the water's surface (``obj``) reaches and stays within.
    """
    path = frame_path(directory, frame_index, fmt)
    path.parent.mkdir(parents=True, exist_ok=True)
    a = _frame_arrays(parts, int(dim))
    if fmt == "npz":
        np.savez(path, **a)
    elif fmt == "ply":
        _write_ply(path, a)
    elif fmt == "obj":
        _write_obj(path, a, int(dim), domain)
    else:
        _write_vtu(path, a)
    return path


def _write_ply(path: Path, a: dict) -> None:
    n = len(a["x"])
    fdt = np.dtype("<f8") if a["x"].dtype == np.float64 or a["v"].dtype == np.float64 else np.dtype("<f4")
    sdt = np.dtype("<f8") if any(a[k].dtype == np.float64 for k in ("m", "rho", "p")) else np.dtype("<f4")
    fields = [(name, fdt) for name in ("x", "y", "z", "vx", "vy", "vz")]
    fields += [("m", sdt), ("rho", sdt), ("p", sdt), ("level", np.dtype("<i4")), ("kind", np.dtype("<i4"))]
    rec = np.empty(n, dtype=np.dtype(fields))
    for k, name in enumerate(("x", "y", "z")):
        rec[name] = _pad3(a["x"])[:, k]
    for k, name in enumerate(("vx", "vy", "vz")):
        rec[name] = _pad3(a["v"])[:, k]
    for name in ("m", "rho", "p", "level", "kind"):
        rec[name] = a[name]
    header = ["ply", "format binary_little_endian 1.0", "comment written by mrsph", f"element vertex {n}"]
    header += [f"property {_PLY_TYPES[dt]} {name}" for name, dt in fields]
    header += ["end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(rec.tobytes())


def read_ply(path) -> dict:
    """Read a PLY written by :func:`write_frame` back into a dict of column arrays."""
    names = {"float": "<f4", "double": "<f8", "int": "<i4"}
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            raise ValueError(f"{path}: not a PLY file")
        fields, n = [], None
        while True:
            line = f.readline()
            if not line:
                raise ValueError(f"{path}: PLY header without end_header")
            words = line.decode("ascii").split()
            if words[:1] == ["end_header"]:
                break
            if words[:1] == ["format"] and words[1] != "binary_little_endian":
                raise ValueError(f"{path}: expected binary_little_endian (got {words[1]})")
            if words[:2] == ["element", "vertex"]:
                n = int(words[2])
            elif words[:1] == ["property"]:
                fields.append((words[2], names[words[1]]))
        rec = np.frombuffer(f.read(), dtype=np.dtype(fields), count=n)
    return {name: rec[name].copy() for name, _ in fields}


def _write_obj(path: Path, a: dict, dim: int, domain=None) -> None:
    """The water's surface. With the particles mirrored at the domain's walls the body
    reaches them, and the smoothed surface passes them by up to the mirrored particles'
    reach (a few spacings): kept in the domain, it lies on them where the water meets
    them, and a mirror image of water near a wall, wholly beyond it, is left out. Not
    mirrored at the obstacles, whose mirrored water would fill them (demo_3d's post: 7 %
    of the water's volume)."""
    from .surface import _VIRTUAL_KIND, surface

    walls = None if domain is None else (*domain, ())
    found = surface(a["x"], a["m"], a["rho"], a["level"], a["kind"], dim, walls=walls)
    lines = ["# fluid surface written by mrsph (mrsph/io/surface.py)", "o fluid"]
    if found is not None and len(found[1]):
        corners = _pad3(np.asarray(found[1], np.float64))
        normals = _pad3(np.asarray(found[2], np.float64)) if dim == 3 else None
        key = np.round(corners / 1e-9).astype(np.int64)
        _, first, index = np.unique(key, axis=0, return_index=True, return_inverse=True)
        faces = index.reshape(-1, 3)
        verts = corners[first]
        if domain is not None:
            lo, hi = (_pad3(np.asarray(b, np.float64)[None, :])[0] for b in domain)
            water = np.asarray(a["x"], np.float64)[np.asarray(a["kind"]) < _VIRTUAL_KIND]
            keep = _reaching_in(verts, faces, water, lo, hi)
            used, faces = np.unique(faces[keep], return_inverse=True)
            faces = faces.reshape(-1, 3)
            verts = np.clip(verts[used], lo, hi)
            if normals is not None:
                normals = normals.reshape(-1, 3, 3)[keep].reshape(-1, 3)
        lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in verts.tolist()]
        if normals is not None:
            vn = np.zeros_like(verts)
            np.add.at(vn, faces.reshape(-1), normals)
            vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)
            lines += [f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vn.tolist()]
            lines += [f"f {i}//{i} {j}//{j} {k}//{k}" for i, j, k in (faces + 1).tolist()]
        else:
            lines += [f"f {i} {j} {k}" for i, j, k in (faces + 1).tolist()]
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


def _reaching_in(verts: np.ndarray, faces: np.ndarray, water: np.ndarray, lo, hi) -> np.ndarray:
    """The faces of the mesh's connected parts that hold water, as against a mirror image
    of water near a wall, wholly beyond it: a part with a vertex within (lo, hi), or, for
    water filling the domain to every wall, whose bounding box holds a particle of
    ``water`` (N, d)."""
    label = np.arange(len(verts))
    while True:  # each part's smallest vertex index, spread along the faces
        new = label.copy()
        np.minimum.at(new, faces.reshape(-1), np.repeat(label[faces].min(axis=1), 3))
        new = new[new]
        if np.array_equal(new, label):
            break
        label = new
    dim = water.shape[1]
    keep = np.zeros(len(verts), bool)
    keep[label[np.all((verts[:, :dim] > lo[:dim]) & (verts[:, :dim] < hi[:dim]), axis=1)]] = True
    for part in np.setdiff1d(label[faces[:, 0]], np.flatnonzero(keep)):  # few: wholly outside
        corner = verts[label == part, :dim]
        keep[part] = np.any(np.all((water >= corner.min(axis=0)) & (water <= corner.max(axis=0)), axis=1))
    return keep[label[faces[:, 0]]]


def _write_vtu(path: Path, a: dict) -> None:
    import meshio

    n = len(a["x"])
    points = _pad3(a["x"]).astype(np.float64)
    cells = [meshio.CellBlock("vertex", np.arange(n, dtype=np.int64).reshape(n, 1))]
    point_data = {"v": _pad3(a["v"]).astype(np.float64)}
    for name in ("m", "rho", "p", "level", "kind"):
        point_data[name] = a[name]
    # An empty frame (a pour before its first particle) is written uncompressed, so that
    # no zero-length zlib block appears; ParaView opens it, meshio's reader cannot read
    # empty meshes back at all.
    meshio.Mesh(points, cells, point_data=point_data).write(path, file_format="vtu", compression="zlib" if n else None)


# ------------------------------------------------------------------------- stats.csv
#: Columns a stats row may carry beyond the base ones, in the order they are written;
#: per-level columns come in level order. Any other key follows, sorted by name.
_EXTRA_ORDER = (
    "n_virtual_level_*",
    "n_transient",
    "solver",
    "density_iterations",
    "divergence_iterations",
    "density_error",
    "unconverged",
    "shortened",
    "splits",
    "merges",
    "absorbed",
    "refused",
)


def stats_columns(dim: int, levels: int) -> list[str]:
    """The base columns of stats.csv, always present and in this order."""
    cols = ["frame", "time", "dt", "n_real", "n_virtual", "total_mass"]
    cols += [f"momentum_{ax}" for ax in "xyz"[:dim]]
    cols += ["kinetic_energy", "max_density_ratio"]
    cols += [f"n_level_{l}" for l in range(levels)]
    return cols


def _extra_columns(keys, base: list[str]) -> list[str]:
    rest = [k for k in keys if k not in base]
    ordered = []
    for pattern in _EXTRA_ORDER:
        if pattern.endswith("*"):
            prefix = pattern[:-1]
            found = [k for k in rest if k.startswith(prefix) and k[len(prefix) :].isdigit()]
            ordered += sorted(found, key=lambda k: int(k[len(prefix) :]))
        elif pattern in rest:
            ordered.append(pattern)
    return ordered + sorted(k for k in rest if k not in ordered)


def _cell(value) -> str:
    """Floats as repr (shortest text that reads back to the same double), ints as ints."""
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return str(int(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return repr(v) if math.isfinite(v) else str(v)
    return str(value)


class StatsWriter:
    """Writes stats rows (``Simulation.stats()``) to a CSV file, one row per frame.

    The header is the base columns (:func:`stats_columns`) followed by the extra keys of
    the first row (n_virtual_level_*, n_transient, splits, merges, refused, then any
    other, sorted). It is written with the first row, or on close if there was none.
    Every row must carry every base column; a later row with a key the header lacks is
    an error rather than a silently dropped column.
    """

    def __init__(self, path, dim: int, levels: int):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.base = stats_columns(int(dim), int(levels))
        self.columns: list[str] | None = None
        self._file = open(self.path, "w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._file, lineterminator="\n")

    def write(self, row: dict) -> None:
        if self.columns is None:
            self.columns = self.base + _extra_columns(row.keys(), self.base)
            self._csv.writerow(self.columns)
        missing = [k for k in self.base if k not in row]
        unknown = [k for k in row if k not in self.columns]
        if missing or unknown:
            raise ValueError(
                f"{self.path}: stats row does not match the header (missing {missing}, not in the header {unknown})"
            )
        self._csv.writerow([_cell(row.get(k)) for k in self.columns])
        self._file.flush()

    def close(self) -> None:
        if self._file.closed:
            return
        if self.columns is None:
            self.columns = list(self.base)
            self._csv.writerow(self.columns)
        self._file.close()

    def __enter__(self) -> StatsWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
