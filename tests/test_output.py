"""Frame dumps (npz, PLY, VTU) read back, and stats.csv columns and float round trip."""

import csv
import math

import meshio
import numpy as np
import pytest

from mrsph.io.output import FORMATS, StatsWriter, frame_path, read_ply, stats_columns, write_frame

DIMS = [2, 3]


def particles(dim: int, n: int = 37, seed: int = 0) -> dict:
    """Random particles shaped like Simulation.particles(), virtual ones included."""
    rng = np.random.default_rng(seed)
    return {
        "x": rng.random((n, dim)).astype(np.float32),
        "v": rng.standard_normal((n, dim)).astype(np.float32),
        "m": rng.random(n) * 1e-3 + 1e-4,
        "rho": 1000.0 + rng.standard_normal(n),
        "p": rng.random(n) * 1e4,  # pressure, Pa (both solvers write it)
        "lam": rng.random(n),  # extra arrays are ignored
        "level": rng.integers(0, 3, n).astype(np.int32),
        "kind": rng.integers(0, 6, n).astype(np.int32),
    }


def padded(a: np.ndarray) -> np.ndarray:
    return np.concatenate([a, np.zeros((len(a), 3 - a.shape[1]), a.dtype)], axis=1)


@pytest.mark.parametrize("dim", DIMS)
def test_npz_round_trip(tmp_path, dim):
    parts = particles(dim)
    path = write_frame(tmp_path, 7, parts, dim)
    assert path == tmp_path / "frame_00007.npz"
    with np.load(path) as f:
        assert sorted(f.files) == sorted(["x", "v", "m", "rho", "p", "level", "kind"])
        assert f["x"].shape == (37, dim) and f["v"].shape == (37, dim)
        assert f["level"].dtype == np.int32 and f["kind"].dtype == np.int32
        for key in f.files:
            np.testing.assert_array_equal(f[key], parts[key])


@pytest.mark.parametrize("dim", DIMS)
def test_ply_header_and_values(tmp_path, dim):
    parts = particles(dim)
    path = write_frame(tmp_path, 0, parts, dim, fmt="ply")
    assert path.name == "frame_00000.ply"
    raw = path.read_bytes()
    header, _, body = raw.partition(b"end_header\n")
    lines = header.decode("ascii").splitlines()
    assert lines[:2] == ["ply", "format binary_little_endian 1.0"]
    assert "element vertex 37" in lines
    props = [ln.split()[2] for ln in lines if ln.startswith("property")]
    assert props == ["x", "y", "z", "vx", "vy", "vz", "m", "rho", "p", "level", "kind"]
    # the body is exactly N records of the declared types, nothing more
    sizes = {"float": 4, "double": 8, "int": 4}
    record = sum(sizes[ln.split()[1]] for ln in lines if ln.startswith("property"))
    assert len(body) == 37 * record

    back = read_ply(path)
    x, v = padded(parts["x"]), padded(parts["v"])
    for k, name in enumerate("xyz"):
        np.testing.assert_array_equal(back[name], x[:, k])
        np.testing.assert_array_equal(back["v" + name], v[:, k])
    for name in ("m", "rho", "p", "level", "kind"):
        np.testing.assert_array_equal(back[name], parts[name])


@pytest.mark.parametrize("dim", DIMS)
def test_vtu_reads_back_with_meshio(tmp_path, dim):
    parts = particles(dim)
    path = write_frame(tmp_path, 12, parts, dim, fmt="vtk")
    assert path == frame_path(tmp_path, 12, "vtk") and path.name == "frame_00012.vtu"
    mesh = meshio.read(path)
    np.testing.assert_allclose(mesh.points, padded(parts["x"]), rtol=0, atol=0)
    assert [c.type for c in mesh.cells] == ["vertex"]
    np.testing.assert_array_equal(mesh.cells[0].data.ravel(), np.arange(37))
    np.testing.assert_array_equal(mesh.point_data["v"], padded(parts["v"]))
    for name in ("m", "rho", "p", "level", "kind"):
        np.testing.assert_array_equal(mesh.point_data[name], parts[name])
    # the XML check the empty frame relies on agrees with meshio here (zlib-compressed)
    assert vtu_array_lengths(path) == {
        "Points": 37,
        "connectivity": 37,
        "offsets": 37,
        "types": 37,
        "v": 37,
        "m": 37,
        "rho": 37,
        "p": 37,
        "level": 37,
        "kind": 37,
    }


@pytest.mark.parametrize("fmt", FORMATS)
def test_empty_frame_is_written(tmp_path, fmt):
    """A pour scene starts with no particles; its frame 0 is still a valid file."""
    empty = {k: v[:0] for k, v in particles(2).items()}
    path = write_frame(tmp_path, 0, empty, 2, fmt=fmt)
    assert path.is_file() and path.stat().st_size > 0
    if fmt == "ply":
        back = read_ply(path)
        assert list(back) == ["x", "y", "z", "vx", "vy", "vz", "m", "rho", "p", "level", "kind"]
        assert all(len(a) == 0 for a in back.values()), {k: len(a) for k, a in back.items()}
    elif fmt == "npz":
        with np.load(path) as f:
            shapes = {k: f[k].shape for k in f.files}
        assert shapes == {"x": (0, 2), "v": (0, 2), "m": (0,), "rho": (0,), "p": (0,), "level": (0,), "kind": (0,)}, (
            f"empty npz frame holds {shapes}"
        )
    elif fmt == "obj":
        # no fluid, no surface: the file names its object and holds no vertex or face
        lines = path.read_text().splitlines()
        assert "o fluid" in lines and not any(l.startswith(("v ", "f ")) for l in lines), lines
    else:
        # meshio cannot read an empty .vtu back (IndexError in vtk_cells_from_data, even on
        # a minimal hand-written valid one with ascii, empty DataArrays; meshio 5.3.5), so
        # the XML is checked here as a VTK reader sees it.
        assert vtu_array_lengths(path) == {
            "Points": 0,
            "connectivity": 0,
            "offsets": 0,
            "types": 0,
            "v": 0,
            "m": 0,
            "rho": 0,
            "p": 0,
            "level": 0,
            "kind": 0,
        }


def vtu_array_lengths(path) -> dict:
    """Parse a .vtu of one piece (VTK XML, ascii or inline base64 "binary", plain or
    zlib), check NumberOfPoints / NumberOfCells against its arrays, and return the number
    of tuples of every DataArray by name."""
    import base64
    import xml.etree.ElementTree as ET
    import zlib

    root = ET.parse(path).getroot()
    assert root.tag == "VTKFile" and root.get("type") == "UnstructuredGrid", root.attrib
    assert root.get("byte_order", "LittleEndian") == "LittleEndian", root.attrib
    header = np.dtype("<u8" if root.get("header_type") == "UInt64" else "<u4")
    compressed = root.get("compressor")
    assert compressed in (None, "vtkZLibDataCompressor"), root.attrib
    types = {
        "Int8": "<i1",
        "UInt8": "<u1",
        "Int32": "<i4",
        "UInt32": "<u4",
        "Int64": "<i8",
        "UInt64": "<u8",
        "Float32": "<f4",
        "Float64": "<f8",
    }
    pieces = root.findall("./UnstructuredGrid/Piece")
    assert len(pieces) == 1, f"{len(pieces)} pieces"
    piece = pieces[0]
    lengths = {}
    for arr in piece.iter("DataArray"):
        name, dtype = arr.get("Name"), np.dtype(types[arr.get("type")])
        text = (arr.text or "").strip()
        if arr.get("format") == "ascii":
            values = np.array(text.split(), dtype=dtype)
        else:
            assert arr.get("format") == "binary", arr.attrib
            # base64 of the header, then (encoded separately) base64 of the data
            b64len = lambda nbytes: 4 * -(-nbytes // 3)  # noqa: E731
            first = int(np.frombuffer(base64.b64decode(text[: b64len(header.itemsize)]), header, 1)[0])
            if compressed:  # header [blocks, block size, last size, compressed sizes...]
                head = b64len((3 + first) * header.itemsize)
                sizes = np.frombuffer(base64.b64decode(text[:head]), header, 3 + first)[3:]
                raw = base64.b64decode(text[head:])
                assert len(raw) == int(sizes.sum()), f"{name}: {len(raw)} compressed bytes, header {sizes}"
                ends = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
                data = b"".join(zlib.decompress(raw[ends[i] : ends[i + 1]]) for i in range(first))
            else:  # header [byte count]
                data = base64.b64decode(text[b64len(header.itemsize) :])
                assert len(data) == first, f"{name}: header says {first} bytes, {len(data)} follow"
            values = np.frombuffer(data, dtype)
        ncomp = int(arr.get("NumberOfComponents", 1))
        assert values.size % ncomp == 0, f"{name}: {values.size} values, {ncomp} components"
        lengths[name] = values.size // ncomp
    n_points, n_cells = int(piece.get("NumberOfPoints")), int(piece.get("NumberOfCells"))
    assert lengths["Points"] == n_points and lengths["types"] == lengths["offsets"] == n_cells, (
        f"NumberOfPoints {n_points}, NumberOfCells {n_cells}, arrays {lengths}"
    )
    for sect in piece.findall("PointData"):
        for arr in sect.iter("DataArray"):
            assert lengths[arr.get("Name")] == n_points, f"point data {arr.get('Name')}: {lengths}"
    return lengths


def test_missing_array_is_refused(tmp_path):
    parts = particles(2)
    del parts["kind"]
    with pytest.raises(ValueError, match="kind"):
        write_frame(tmp_path, 0, parts, 2)
    with pytest.raises(ValueError, match="fmt"):
        write_frame(tmp_path, 0, particles(2), 2, fmt="xyz")


def stats_row(dim: int, levels: int, frame: int = 0) -> dict:
    """A row shaped like Simulation.stats(), with awkward floats."""
    row = {
        "frame": frame,
        "time": frame / 30.0,
        "dt": 1.0 / 3.0 * 1e-4,
        "n_real": 1234,
        "n_virtual": 56,
        "total_mass": math.fsum([0.1] * 7 + [1e-17]),
        "kinetic_energy": 2.0 / 3.0,
        "max_density_ratio": 1.0 + 1e-15,
    }
    for k, ax in enumerate("xyz"[:dim]):
        row[f"momentum_{ax}"] = (-1) ** k * 1e-7 / 3.0
    for l in reversed(range(levels)):  # the writer orders columns itself
        row[f"n_level_{l}"] = 100 + l
        row[f"n_virtual_level_{l}"] = l
    row.update({"refused": 0, "merges": 2, "absorbed": 1, "splits": 3, "n_transient": 8})
    return row


@pytest.mark.parametrize("dim", DIMS)
def test_stats_csv_columns(tmp_path, dim):
    levels = 3
    with StatsWriter(tmp_path / "stats.csv", dim, levels) as w:
        for frame in range(3):
            w.write(stats_row(dim, levels, frame))
    with open(tmp_path / "stats.csv", newline="") as f:
        rows = list(csv.reader(f))
    momenta = ["momentum_x", "momentum_y"] + (["momentum_z"] if dim == 3 else [])
    expected = (
        ["frame", "time", "dt", "n_real", "n_virtual", "total_mass"]
        + momenta
        + [
            "kinetic_energy",
            "max_density_ratio",
            "n_level_0",
            "n_level_1",
            "n_level_2",
            "n_virtual_level_0",
            "n_virtual_level_1",
            "n_virtual_level_2",
            "n_transient",
            "splits",
            "merges",
            "absorbed",
            "refused",
        ]
    )
    assert rows[0] == expected
    assert rows[0][: len(stats_columns(dim, levels))] == stats_columns(dim, levels)
    assert len(rows) == 4 and all(len(r) == len(expected) for r in rows)
    assert [r[0] for r in rows[1:]] == ["0", "1", "2"]


@pytest.mark.parametrize("dim", DIMS)
def test_stats_csv_floats_round_trip_exactly(tmp_path, dim):
    row = stats_row(dim, 1)
    row["total_mass"] = np.float64(row["total_mass"])  # numpy scalars too
    with StatsWriter(tmp_path / "stats.csv", dim, 1) as w:
        w.write(row)
    with open(tmp_path / "stats.csv", newline="") as f:
        back = next(csv.DictReader(f))
    for key, value in row.items():
        if isinstance(value, (float, np.floating)):
            assert float(back[key]) == value, key
        else:
            assert int(back[key]) == value, key


def test_stats_header_without_rows_and_mismatched_rows(tmp_path):
    with StatsWriter(tmp_path / "a.csv", 2, 2):
        pass
    assert (tmp_path / "a.csv").read_text().splitlines() == [",".join(stats_columns(2, 2))]
    with StatsWriter(tmp_path / "b.csv", 2, 1) as w:
        w.write(stats_row(2, 1))
        with pytest.raises(ValueError, match="surprise"):
            w.write({**stats_row(2, 1), "surprise": 1})
        bad = stats_row(2, 1)
        del bad["total_mass"]
        with pytest.raises(ValueError, match="total_mass"):
            w.write(bad)
