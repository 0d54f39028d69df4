"""Round trips for every file format and a clean one-line error for every kind of bad file.

All files are generated here, from seeded random clouds, in pytest's tmp_path: no committed blobs.
"""

from __future__ import annotations

import json
import os
import pathlib
import sys

import numpy as np
import pytest

from canalsurf import io
from canalsurf.errors import InputError
from canalsurf.io import (
    DXF_UNITS,
    MESH_FORMATS,
    POINT_FORMAT_NAMES,
    POINT_FORMATS,
    PointFileInfo,
    atomic_write,
    point_file_info,
    read_points,
    write_json,
    write_mesh,
    write_spine_csv,
    write_points,
    write_spine_dxf,
)

plyfile = pytest.importorskip("plyfile")

SEED = 20240611
N = 300
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0
ROOT_REASON = "running as root: file permissions do not stop root from reading or writing"


@pytest.fixture
def cloud(random_cloud):
    return random_cloud(N)


def _f32(a):
    """What a float32 field holds of a float64 array, back in float64."""
    return np.asarray(a, dtype=np.float32).astype(np.float64)


def _assert_reads_as(path, points, normals):
    """``read_points(path)`` gives exactly ``points``, and ``normals`` (``None``: no normals)."""
    got_points, got_normals = read_points(path)
    np.testing.assert_array_equal(got_points, points)
    if normals is None:
        assert got_normals is None
    else:
        np.testing.assert_array_equal(got_normals, normals)


def _assert_one_line(exc_info):
    message = str(exc_info.value)
    assert "\n" not in message and message.strip() == message


# ---------------------------------------------------------------------------------------------------
# PLY


def _write_ply(path, points, normals, *, text, dtype):
    names = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    vertex = np.empty(len(points), dtype=[(n, dtype) for n in names])
    data = points if normals is None else np.hstack([points, normals])
    for i, name in enumerate(names):
        vertex[name] = data[:, i]
    plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")], text=text).write(str(path))


@pytest.mark.parametrize("text", [True, False], ids=["ascii", "binary"])
@pytest.mark.parametrize("dtype", ["f4", "f8"])
@pytest.mark.parametrize("with_normals", [True, False], ids=["normals", "no-normals"])
def test_ply_round_trip(tmp_path, cloud, text, dtype, with_normals):
    points, normals = cloud
    path = tmp_path / "scan.ply"
    _write_ply(path, points, normals if with_normals else None, text=text, dtype=dtype)
    got_points, got_normals = read_points(path)
    exact = (lambda a: a) if dtype == "f8" else _f32
    assert got_points.dtype == np.float64 and got_points.shape == (N, 3)
    # plyfile writes ASCII with %.18g, so even ASCII doubles come back bit-exact
    np.testing.assert_array_equal(got_points, exact(points))
    if with_normals:
        np.testing.assert_array_equal(got_normals, exact(normals))
    else:
        assert got_normals is None


def test_suffix_is_case_insensitive(tmp_path, cloud):
    path = tmp_path / "SCAN.PLY"
    _write_ply(path, cloud[0], None, text=False, dtype="f8")
    np.testing.assert_array_equal(read_points(path)[0], cloud[0])


@pytest.mark.parametrize("text", [True, False], ids=["ascii", "binary"])
def test_ply_truncated(tmp_path, text):
    points = np.random.default_rng(SEED).normal(size=(2000, 3))
    path = tmp_path / "scan.ply"
    _write_ply(path, points, None, text=text, dtype="f8")
    raw = path.read_bytes()
    header_end = raw.index(b"end_header\n") + len(b"end_header\n")
    if text:
        lines = raw[header_end:].splitlines(keepends=True)
        path.write_bytes(raw[:header_end] + b"".join(lines[:1200]))
    else:
        path.write_bytes(raw[: header_end + 1200 * 24 + 7])  # 1200 rows and a piece of the next
    with pytest.raises(InputError, match=r"scan\.ply: PLY file is truncated \(header says 2000 vertices, data holds 1200\) — re-export"):
        read_points(path)


@pytest.mark.parametrize("text", [True, False], ids=["ascii", "binary"])
def test_ply_header_count_too_high(tmp_path, text):
    points = np.random.default_rng(SEED).normal(size=(100, 3))
    path = tmp_path / "scan.ply"
    _write_ply(path, points, None, text=text, dtype="f8")
    path.write_bytes(path.read_bytes().replace(b"element vertex 100\n", b"element vertex 150\n"))
    with pytest.raises(InputError, match=r"truncated \(header says 150 vertices, data holds 100\)"):
        read_points(path)


@pytest.mark.parametrize("text", [True, False], ids=["ascii", "binary"])
def test_ply_header_count_too_low(tmp_path, text):
    points = np.random.default_rng(SEED).normal(size=(100, 3))
    path = tmp_path / "scan.ply"
    _write_ply(path, points, None, text=text, dtype="f8")
    path.write_bytes(path.read_bytes().replace(b"element vertex 100\n", b"element vertex 60\n"))
    with pytest.raises(InputError, match=r"PLY header says 60 vertices but more data follows"):
        read_points(path)


def test_ply_header_claiming_huge_count_fails_without_allocating(tmp_path):
    path = tmp_path / "scan.ply"
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex 100000000000\nproperty double x\n"
    path.write_bytes(header + b"property double y\nproperty double z\nend_header\n" + bytes(240))
    with pytest.raises(InputError, match=r"truncated \(header says 100000000000 vertices, data holds 10\)"):
        read_points(path)


def test_ply_without_xyz(tmp_path):
    vertex = np.zeros(5, dtype=[("x", "f8"), ("y", "f8")])
    path = tmp_path / "flat.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")]).write(str(path))
    with pytest.raises(InputError, match=r"flat\.ply: PLY vertices lack z"):
        read_points(path)


def test_ply_without_vertex_element(tmp_path):
    other = np.zeros(5, dtype=[("x", "f8")])
    path = tmp_path / "odd.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(other, "camera")]).write(str(path))
    with pytest.raises(InputError, match=r"odd\.ply: PLY file has no 'vertex' element"):
        read_points(path)


@pytest.mark.parametrize(
    "body",
    [
        b"ply\nformat binary_little_endian 1.0\n",  # a valid start, then garbage
        b"ply\nformat ascii 1.0\nelement vertex 50\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
    ],
    ids=["binary-header-garbage", "ascii-body-garbage"],
)
def test_ply_garbage_after_valid_start(tmp_path, body):
    path = tmp_path / "scan.ply"
    path.write_bytes(body + np.random.default_rng(SEED).bytes(4096))
    with pytest.raises(InputError, match=r"scan\.ply: (not a readable PLY file|PLY file is truncated)") as info:
        read_points(path)
    _assert_one_line(info)


def test_megabyte_of_random_bytes_named_ply(tmp_path):
    path = tmp_path / "noise.ply"
    path.write_bytes(np.random.default_rng(SEED).bytes(1 << 20))
    with pytest.raises(InputError, match=r"noise\.ply: not a PLY file") as info:
        read_points(path)
    _assert_one_line(info)


# ---------------------------------------------------------------------------------------------------
# text formats


@pytest.mark.parametrize("suffix", [".xyz", ".txt", ".csv", ".asc"])
@pytest.mark.parametrize("delimiter", [",", ";", "\t", " "], ids=["comma", "semicolon", "tab", "space"])
@pytest.mark.parametrize("header", [True, False], ids=["header", "no-header"])
@pytest.mark.parametrize("with_normals", [True, False], ids=["normals", "no-normals"])
def test_text_round_trip(tmp_path, cloud, suffix, delimiter, header, with_normals):
    points, normals = cloud
    table = np.hstack([points, normals]) if with_normals else points
    names = "x y z nx ny nz".split()[: table.shape[1]]
    path = tmp_path / f"scan{suffix}"
    np.savetxt(path, table, fmt="%.17g", delimiter=delimiter,
               header=delimiter.join(names) if header else "", comments="")
    _assert_reads_as(path, points, normals if with_normals else None)


@pytest.mark.parametrize("header", ["", "//X Y Z R G B\n", "x,y,z,red,green,blue\n"],
                         ids=["no-header", "cloudcompare-header", "csv-header"])
def test_text_colours_in_the_last_three_columns_are_not_read_as_normals(tmp_path, cloud, header):
    """X Y Z R G B, the commonest six columns: colours taken for normals sent every normal the same way
    (a grey scan: 'normals contain zero vectors') or any way, and no tube was found."""
    from canalsurf.io import read_points_sample

    points, _ = cloud
    colours = np.random.default_rng(1).integers(0, 256, (len(points), 3))
    delimiter = "," if "," in header else " "
    path = tmp_path / ("scan.csv" if delimiter == "," else "scan.xyz")
    rows = [delimiter.join(f"{v:.17g}" for v in p) + delimiter + delimiter.join(str(c) for c in rgb)
            for p, rgb in zip(points, colours)]
    path.write_text(header + "\n".join(rows) + "\n")
    _assert_reads_as(path, points, None)
    sample = read_points_sample(path, 100, rng=0)
    assert sample.normals is None and len(sample.points) == 100


@pytest.mark.parametrize("header, scale, read", [
    ("X Y Z Nx Ny Nz\n", 1.0, True),        # named normals are read as they are,
    ("X Y Z normal_x normal_y normal_z\n", 2.0, True),
    ("", 1.0 + 5e-3, True),                  # unnamed ones when they are unit vectors (to 1 %),
    ("", 2.0, False),                        # else they are read past
])
def test_text_normals_by_their_names_or_by_being_unit_vectors(tmp_path, cloud, header, scale, read):
    points, normals = cloud
    path = tmp_path / "scan.xyz"
    np.savetxt(path, np.hstack([points, scale * normals]), fmt="%.17g", header=header.strip(), comments="")
    _assert_reads_as(path, points, scale * normals if read else None)


def test_text_spaces_after_commas_comments_and_blank_lines(tmp_path):
    path = tmp_path / "scan.csv"
    path.write_text("# exported by hand\nX, Y, Z\n\n1.5, 2, 3\n# a note\n4, 5e-3, -6\n\n")
    points, normals = read_points(path)
    np.testing.assert_array_equal(points, [[1.5, 2, 3], [4, 5e-3, -6]])
    assert normals is None


def test_text_non_numeric_row_names_the_line(tmp_path):
    path = tmp_path / "scan.xyz"
    path.write_text("x y z\n1 2 3\n4 5 6\n7 oops 9\n10 11 12\n")
    with pytest.raises(InputError, match=r"scan\.xyz: line 4 is not numeric \('7 oops 9'\)"):
        read_points(path)


def test_text_second_header_line_is_rejected(tmp_path):
    path = tmp_path / "scan.csv"
    path.write_text("x,y,z\nmetres,metres,metres\n1,2,3\n")
    with pytest.raises(InputError, match=r"scan\.csv: line 2 is not numeric"):
        read_points(path)


@pytest.mark.parametrize("ncols", [1, 2])
def test_text_wrong_column_count(tmp_path, ncols):
    path = tmp_path / "scan.txt"
    np.savetxt(path, np.ones((5, ncols)))
    with pytest.raises(InputError, match=rf"scan\.txt: line 1 has {ncols} columns — give numeric columns x y z"):
        read_points(path)


@pytest.mark.parametrize("header, xyz, normals", [
    ("", [0, 1, 2], None),                                    # X Y Z I (no header)
    ("x y z intensity", [0, 1, 2], None),
    ("id X Y Z", [1, 2, 3], None),                            # x y z placed by the header
    ("x y z i nx ny nz", [0, 1, 2], [4, 5, 6]),               # and the normals
    ("//X Y Z R G B Nx Ny Nz", [0, 1, 2], [6, 7, 8]),         # CloudCompare's spelling
])
def test_text_columns_beyond_x_y_z_and_normals_are_read_past(tmp_path, cloud, header, xyz, normals):
    points, unit = cloud
    ncols = max(xyz + (normals or [])) + 1 if header else 4
    table = np.random.default_rng(2).integers(0, 256, (len(points), ncols)).astype(float)
    table[:, xyz] = points
    if normals:
        table[:, normals] = unit
    path = tmp_path / "scan.txt"
    np.savetxt(path, table, fmt="%.17g", header=header, comments="")
    _assert_reads_as(path, points, unit if normals else None)


def test_text_header_naming_more_columns_than_the_rows_hold(tmp_path):
    """A header of normals over rows of x y z only (a file cut short, found by benchmarks/fuzz.py): the rows
    are the points, and there are no normals to read."""
    path = tmp_path / "scan.csv"
    path.write_text("x,y,z,nx,ny,nz\n1,2,3\n4,5,6\n")
    points, normals = read_points(path)
    np.testing.assert_array_equal(points, [[1, 2, 3], [4, 5, 6]])
    assert normals is None

def test_text_column_count_changes(tmp_path):
    path = tmp_path / "scan.csv"
    path.write_text("1,2,3\n4,5,6\n7,8,9,10\n")
    with pytest.raises(InputError, match=r"scan\.csv: line 3 has 4 columns, earlier lines have 3"):
        read_points(path)


def test_text_header_without_data(tmp_path):
    path = tmp_path / "scan.csv"
    path.write_text("x,y,z\n")
    with pytest.raises(InputError, match=r"scan\.csv: holds a header line but no data rows"):
        read_points(path)


def test_text_only_comments(tmp_path):
    path = tmp_path / "scan.xyz"
    path.write_text("# nothing here\n\n")
    with pytest.raises(InputError, match=r"scan\.xyz: holds no data rows"):
        read_points(path)


# ---------------------------------------------------------------------------------------------------
# numpy formats


@pytest.mark.parametrize("with_normals", [True, False], ids=["normals", "no-normals"])
def test_npy_round_trip(tmp_path, cloud, with_normals):
    points, normals = cloud
    path = tmp_path / "scan.npy"
    np.save(path, np.hstack([points, normals]) if with_normals else points)
    _assert_reads_as(path, points, normals if with_normals else None)


def test_npy_float32_and_int_are_widened(tmp_path):
    path = tmp_path / "scan.npy"
    np.save(path, np.arange(12, dtype=np.int32).reshape(4, 3))
    points, _ = read_points(path)
    assert points.dtype == np.float64
    np.testing.assert_array_equal(points, np.arange(12).reshape(4, 3))


@pytest.mark.parametrize("shape", [(10,), (10, 4), (2, 5, 3)])
def test_npy_wrong_shape(tmp_path, shape):
    path = tmp_path / "scan.npy"
    np.save(path, np.zeros(shape))
    with pytest.raises(InputError, match=r"scan\.npy: the file holds an array of shape .* expected \(N, 3\)"):
        read_points(path)


def test_npy_object_array_is_refused(tmp_path):
    path = tmp_path / "scan.npy"
    np.save(path, np.array([[1, "a", None]] * 3, dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match=r"scan\.npy: not a readable NumPy \.npy file"):
        read_points(path)


def test_npz_points_and_normals(tmp_path, cloud):
    points, normals = cloud
    path = tmp_path / "scan.npz"
    np.savez(path, points=points, normals=normals)
    got_points, got_normals = read_points(path)
    np.testing.assert_array_equal(got_points, points)
    np.testing.assert_array_equal(got_normals, normals)


def test_npz_points_only_and_single_array(tmp_path, cloud):
    points, normals = cloud
    np.savez(tmp_path / "a.npz", points=points)
    np.savez_compressed(tmp_path / "b.npz", np.hstack([points, normals]))
    got, none = read_points(tmp_path / "a.npz")
    np.testing.assert_array_equal(got, points)
    assert none is None
    got_points, got_normals = read_points(tmp_path / "b.npz")
    np.testing.assert_array_equal(got_points, points)
    np.testing.assert_array_equal(got_normals, normals)


@pytest.mark.parametrize("suffix", [".npy", ".npz"])
def test_numpy_formats_check_the_leading_bytes(tmp_path, suffix):
    path = tmp_path / f"scan{suffix}"
    path.write_text("1 2 3\n")
    with pytest.raises(InputError, match=rf"scan\{suffix}: not a NumPy \{suffix} file \(it lacks the format's leading bytes\)"):
        read_points(path)


def test_npz_without_points(tmp_path):
    path = tmp_path / "scan.npz"
    np.savez(path, a=np.zeros((3, 3)), b=np.zeros((3, 3)))
    with pytest.raises(InputError, match=r"scan\.npz: \.npz holds arrays \['a', 'b'\] but no 'points'"):
        read_points(path)


def test_npz_normals_of_other_shape(tmp_path):
    path = tmp_path / "scan.npz"
    np.savez(path, points=np.zeros((5, 3)), normals=np.zeros((4, 3)))
    with pytest.raises(InputError, match=r"'normals' has shape \(4, 3\) but 'points' has \(5, 3\)"):
        read_points(path)


# ---------------------------------------------------------------------------------------------------
# PCD


def _write_pcd(path, points, normals, *, dtype, encoding):
    pypcd4 = pytest.importorskip("pypcd4")
    fields = ("x", "y", "z") + (("normal_x", "normal_y", "normal_z") if normals is not None else ())
    data = points if normals is None else np.hstack([points, normals])
    cloud = pypcd4.PointCloud.from_points(data.astype(dtype), fields, [dtype] * len(fields))
    cloud.save(path, encoding=pypcd4.Encoding(encoding))


@pytest.mark.parametrize("encoding", ["ascii", "binary", "binary_compressed"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["f4", "f8"])
@pytest.mark.parametrize("with_normals", [True, False], ids=["normals", "no-normals"])
def test_pcd_round_trip(tmp_path, cloud, encoding, dtype, with_normals):
    points, normals = cloud
    path = tmp_path / "scan.pcd"
    _write_pcd(path, points, normals if with_normals else None, dtype=dtype, encoding=encoding)
    got_points, got_normals = read_points(path)
    expected = points if dtype == np.float64 else _f32(points)
    # pypcd4 writes ASCII with 10 decimals: exact for float32 fields is then not guaranteed either
    atol = 0.0 if encoding != "ascii" else 6e-11 if dtype == np.float64 else 1e-5
    np.testing.assert_allclose(got_points, expected, rtol=0, atol=atol)
    if with_normals:
        np.testing.assert_allclose(got_normals, normals if dtype == np.float64 else _f32(normals), rtol=0, atol=atol)
    else:
        assert got_normals is None


def test_pcd_nan_points_are_dropped(tmp_path, cloud):
    points = cloud[0].copy()
    points[[3, 7]] = np.nan
    path = tmp_path / "organized.pcd"
    _write_pcd(path, points, None, dtype=np.float64, encoding="binary")
    got, _ = read_points(path)
    np.testing.assert_array_equal(got, np.delete(points, [3, 7], axis=0))


@pytest.mark.parametrize("encoding,cut", [("binary", 24 * 7), ("ascii", None)])
def test_pcd_truncated(tmp_path, cloud, encoding, cut):
    path = tmp_path / "scan.pcd"
    _write_pcd(path, cloud[0], None, dtype=np.float64, encoding=encoding)
    raw = path.read_bytes()
    if cut is None:  # drop the last 7 text lines
        raw = b"".join(raw.splitlines(keepends=True)[:-7])
    else:
        raw = raw[:-cut]
    path.write_bytes(raw)
    with pytest.raises(InputError, match=rf"scan\.pcd: PCD file is truncated \(header says {N} points, data holds {N - 7}\)"):
        read_points(path)


def test_pcd_without_xyz(tmp_path):
    pypcd4 = pytest.importorskip("pypcd4")
    path = tmp_path / "scan.pcd"
    pypcd4.PointCloud.from_points(np.zeros((4, 2)), ("x", "y"), [np.float32] * 2).save(path)
    with pytest.raises(InputError, match=r"scan\.pcd: PCD file lacks fields z"):
        read_points(path)


# ---------------------------------------------------------------------------------------------------
# LAS / LAZ


def _write_las(path, points, normals):
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([1_000_000.0, 2_000_000.0, 0.0])
    if normals is not None:
        header.add_extra_dims([laspy.ExtraBytesParams(name=n, type=np.float32) for n in ("NormalX", "NormalY", "NormalZ")])
    las = laspy.LasData(header)
    las.x, las.y, las.z = points.T
    if normals is not None:
        las.NormalX, las.NormalY, las.NormalZ = normals.T
    las.write(path)
    return header.scales, header.offsets


@pytest.mark.parametrize("suffix", [".las", ".laz"])
@pytest.mark.parametrize("with_normals", [True, False], ids=["normals", "no-normals"])
def test_las_round_trip_keeps_georeferenced_precision(tmp_path, cloud, suffix, with_normals):
    if suffix == ".laz":
        pytest.importorskip("lazrs")
    points, normals = cloud
    # survey coordinates: a million metres east, two million north, millimetre resolution
    geo = points + [1_000_123.0, 2_000_456.0, 87.0]
    path = tmp_path / f"scan{suffix}"
    scales, offsets = _write_las(path, geo, normals if with_normals else None)
    got_points, got_normals = read_points(path)
    assert got_points.dtype == np.float64
    # exact to the scale: within half a millimetre of the input (float32 would be off by ~6 cm) ...
    np.testing.assert_array_less(np.abs(got_points - geo), np.broadcast_to(scales / 2 * (1 + 1e-6), geo.shape))
    # ... and sitting on the file's integer grid
    grid = (got_points - offsets) / scales
    np.testing.assert_allclose(grid, np.round(grid), rtol=0, atol=1e-6)
    if with_normals:
        np.testing.assert_array_equal(got_normals, _f32(normals))
    else:
        assert got_normals is None


def test_las_truncated(tmp_path, cloud):
    path = tmp_path / "scan.las"
    _write_las(path, cloud[0] + 1e6, None)
    point_size = 34  # LAS point format 3
    path.write_bytes(path.read_bytes()[: -7 * point_size])
    with pytest.raises(InputError, match=r"scan\.las: (LAS file is truncated|not a readable LAS file)"):
        read_points(path)


# ---------------------------------------------------------------------------------------------------
# E57


def test_e57_round_trip_with_two_posed_scans(tmp_path, cloud):
    pye57 = pytest.importorskip("pye57")
    points = cloud[0]
    first, second = points[:100], points[100:]
    shift = np.array([10.0, -5.0, 2.5])
    path = tmp_path / "scan.e57"
    with pye57.E57(str(path), mode="w") as e57:
        for part, translation in ((first, np.zeros(3)), (second, shift)):
            data = {f"cartesian{a}": np.ascontiguousarray(part[:, i]) for i, a in enumerate("XYZ")}
            e57.write_scan_raw(data, translation=translation)
    got_points, got_normals = read_points(path)
    # pye57 stores single-precision coordinates; the second scan is moved by its pose
    np.testing.assert_allclose(got_points, np.vstack([first, second + shift]), rtol=0, atol=1e-5)
    assert got_normals is None


# ---------------------------------------------------------------------------------------------------
# what a file holds: point_file_info


@pytest.mark.parametrize("suffix", [".ply", ".xyz", ".csv", ".npy", ".npz"])
@pytest.mark.parametrize("with_normals", [True, False], ids=["normals", "no-normals"])
def test_point_file_info_of_the_files_canalsurf_writes(tmp_path, cloud, suffix, with_normals):
    points, normals = cloud
    path = tmp_path / f"scan{suffix}"
    write_points(path, points, normals if with_normals else None)
    info = point_file_info(path)
    assert info.fields == (("x", "y", "z", "nx", "ny", "nz") if with_normals else ("x", "y", "z"))
    assert info.format.startswith(POINT_FORMAT_NAMES[suffix])
    assert set(POINT_FORMAT_NAMES) == set(POINT_FORMATS)  # every format has a name
    detail = {".ply": "PLY, binary little-endian", ".xyz": "text, space separated", ".csv": "text, comma separated",
              ".npy": f"NumPy .npy, float64 array of shape ({N}, {6 if with_normals else 3})",
              ".npz": "NumPy .npz, arrays points" + (", normals" if with_normals else "")}[suffix]
    assert info == PointFileInfo(detail, info.fields)
    # what read_points says of the normals agrees
    assert (read_points(path)[1] is not None) == with_normals


def test_point_file_info_names_every_ply_property(tmp_path):
    vertex = np.zeros(3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("intensity", "u2"), ("red", "u1"),
                                ("scalar_Classification", "f4")])
    face = np.array([([0, 1, 2],)], dtype=[("vertex_indices", "i4", (3,))])
    path = tmp_path / "scan.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex"), plyfile.PlyElement.describe(face, "face")],
                    text=True).write(str(path))
    assert point_file_info(path) == PointFileInfo(
        "PLY, ASCII", ("x", "y", "z", "intensity", "red", "scalar_Classification"))  # not the face's list


def test_point_file_info_reads_a_text_header(tmp_path):
    path = tmp_path / "scan.txt"
    path.write_text("# exported\nX;Y;Z\n1;2;3\n4;5;6\n")
    assert point_file_info(path) == PointFileInfo("text, semicolon separated", ("X", "Y", "Z"))


@pytest.mark.parametrize("encoding", ["ascii", "binary"])
def test_point_file_info_of_pcd(tmp_path, cloud, encoding):
    _write_pcd(tmp_path / "scan.pcd", *cloud, dtype=np.float32, encoding=encoding)
    assert point_file_info(tmp_path / "scan.pcd") == PointFileInfo(
        f"PCD, DATA {encoding}", ("x", "y", "z", "normal_x", "normal_y", "normal_z"))


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_point_file_info_of_las_names_its_dimensions(tmp_path, cloud, suffix):
    if suffix == ".laz":
        pytest.importorskip("lazrs")
    path = tmp_path / f"scan{suffix}"
    _write_las(path, cloud[0] + 1e6, cloud[1])
    info = point_file_info(path)
    assert info.format == f"{suffix[1:].upper()}, version 1.2, point format 3"
    assert info.fields[:4] == ("X", "Y", "Z", "intensity")
    assert {"classification", "gps_time", "red", "green", "blue", "NormalX", "NormalY", "NormalZ"} <= set(info.fields)


def test_point_file_info_of_e57_gathers_the_fields_of_every_scan(tmp_path, cloud):
    pye57 = pytest.importorskip("pye57")
    points = cloud[0]
    path = tmp_path / "scan.e57"
    with pye57.E57(str(path), mode="w") as e57:
        e57.write_scan_raw({f"cartesian{a}": np.ascontiguousarray(points[:100, i]) for i, a in enumerate("XYZ")})
        e57.write_scan_raw({f"cartesian{a}": np.ascontiguousarray(points[100:, i]) for i, a in enumerate("XYZ")}
                           | {"intensity": np.ones(N - 100)})
    assert point_file_info(path) == PointFileInfo(
        "E57, 2 scans", ("cartesianX", "cartesianY", "cartesianZ", "intensity"))


@pytest.mark.parametrize("suffix", [".ply", ".xyz", ".npy", ".npz", ".pcd", ".las", ".e57"])
def test_point_file_info_fails_like_read_points(tmp_path, suffix):
    path = tmp_path / f"scan{suffix}"
    path.write_bytes(os.urandom(2048) if suffix != ".xyz" else b"\0" * 2048)
    with pytest.raises(InputError, match=rf"scan\{suffix}: ") as info:
        point_file_info(path)
    _assert_one_line(info)
    with pytest.raises(InputError, match=r"missing\.ply: file not found — check the path"):
        point_file_info(tmp_path / "missing.ply")
    with pytest.raises(InputError, match=r"unknown point format '\.vtk'"):
        point_file_info(tmp_path / "scan.vtk")


def test_the_examples_in_the_docstrings_run():
    """read_points, point_file_info, atomic_write and canalsurf.pointcloud: their examples are doctests."""
    import doctest

    import canalsurf.pointcloud

    for module in (io, canalsurf.pointcloud):
        result = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE)
        assert result.failed == 0 and result.attempted >= 5, module.__name__
    assert "Examples" in canalsurf.read_points.__doc__ and canalsurf.read_points is read_points
    assert "read_points" in canalsurf.__all__ and "read_points" in dir(canalsurf)


# ---------------------------------------------------------------------------------------------------
# errors shared by every point format


def test_unknown_suffix_lists_the_known_ones(tmp_path):
    path = tmp_path / "scan.obj"
    path.write_text("v 0 0 0\n")
    with pytest.raises(InputError, match=r"scan\.obj: unknown point format '\.obj' — use one of \.ply, \.xyz, .*\.e57"):
        read_points(path)


def test_no_suffix(tmp_path):
    with pytest.raises(InputError, match=r"unknown point format '\(no suffix\)'"):
        read_points(tmp_path / "scan")


@pytest.mark.parametrize("suffix", POINT_FORMATS)
def test_missing_file(tmp_path, suffix):
    with pytest.raises(InputError, match=rf"nothere\{suffix}: file not found — check the path"):
        read_points(tmp_path / f"nothere{suffix}")


@pytest.mark.parametrize("suffix", POINT_FORMATS)
def test_directory(tmp_path, suffix):
    folder = tmp_path / f"scans{suffix}"
    folder.mkdir()
    with pytest.raises(InputError, match=r"is a folder, not a point file"):
        read_points(folder)


@pytest.mark.parametrize("suffix", POINT_FORMATS)
def test_empty_file(tmp_path, suffix):
    path = tmp_path / f"empty{suffix}"
    path.touch()
    with pytest.raises(InputError, match=rf"empty\{suffix}: file is empty — re-export"):
        read_points(path)


@pytest.mark.skipif(IS_ROOT, reason=ROOT_REASON)
def test_unreadable_file(tmp_path, cloud):
    path = tmp_path / "locked.npy"
    np.save(path, cloud[0])
    path.chmod(0)
    try:
        with pytest.raises(InputError, match=r"locked\.npy: cannot be read \(permission denied\)"):
            read_points(path)
    finally:
        path.chmod(0o600)


def test_unreadable_file_simulated(tmp_path, monkeypatch, cloud):
    """The same branch as above, reachable as root: the open() call is made to refuse."""
    path = tmp_path / "locked.npy"
    np.save(path, cloud[0])

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(io, "open", refuse, raising=False)  # shadows the builtin inside canalsurf.io
    with pytest.raises(InputError, match=r"locked\.npy: cannot be read \(permission denied\) — check the file"):
        read_points(path)


@pytest.mark.skipif(IS_ROOT, reason=ROOT_REASON)
def test_file_in_a_folder_without_permission(tmp_path, cloud):
    folder = tmp_path / "locked"
    folder.mkdir()
    np.save(folder / "scan.npy", cloud[0])
    folder.chmod(0)
    try:
        with pytest.raises(InputError, match=r"scan\.npy: cannot be read \(permission denied on a folder above it\)"):
            read_points(folder / "scan.npy")
    finally:
        folder.chmod(0o700)


def test_file_in_a_folder_without_permission_simulated(tmp_path, monkeypatch, cloud):
    """The same branch as above, reachable as root: looking the file up is made to fail."""
    path = tmp_path / "locked" / "scan.npy"

    def refuse(self, *args, **kwargs):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(pathlib.Path, "stat", refuse)
    with pytest.raises(InputError, match=r"scan\.npy: cannot be read \(permission denied on a folder above it\) — "
                                         r"check the folder permissions"):
        read_points(path)


@pytest.mark.parametrize("case", ["link loop", "file as folder"])
def test_paths_that_cannot_be_looked_up(tmp_path, case):
    if case == "link loop":
        path = tmp_path / "loop.ply"
        path.symlink_to(path)
        reason = "Too many levels of symbolic links"
    else:
        (tmp_path / "scan.ply").write_text("ply\n")
        path = tmp_path / "scan.ply" / "inner.ply"
        reason = "Not a directory"
    with pytest.raises(InputError, match=rf"{path.name}: cannot be read \({reason}\) — check the path") as info:
        read_points(path)
    _assert_one_line(info)


@pytest.mark.parametrize("suffix", POINT_FORMATS)
def test_random_bytes_fail_cleanly(tmp_path, suffix):
    path = tmp_path / f"noise{suffix}"
    path.write_bytes(np.random.default_rng(SEED).bytes(4096))
    with pytest.raises(InputError, match=rf"noise\{suffix}: ") as info:
        read_points(path)
    _assert_one_line(info)
    assert path.stat().st_size == 4096  # a failed read never touches the user's file


@pytest.mark.parametrize(
    "suffix,module,extra",
    [(".las", "laspy", "las"), (".laz", "laspy", "las"), (".pcd", "pypcd4", "pcd"), (".e57", "pye57", "e57")],
)
def test_missing_extra_names_it(tmp_path, monkeypatch, suffix, module, extra):
    path = tmp_path / f"scan{suffix}"
    path.write_bytes(b"anything")
    monkeypatch.setitem(sys.modules, module, None)  # makes `import module` fail
    message = rf"reading \{suffix} files needs the '{extra}' extra — pip install 'canalsurf\[{extra}\]'"
    with pytest.raises(InputError, match=message):
        read_points(path)


def test_laz_without_lazrs_names_the_extra(tmp_path, monkeypatch, cloud):
    laspy = pytest.importorskip("laspy")
    path = tmp_path / "scan.laz"
    path.write_bytes(b"anything")
    monkeypatch.setattr(laspy.LazBackend, "detect_available", staticmethod(lambda: ()))
    with pytest.raises(InputError, match=r"reading \.laz files needs the 'las' extra"):
        read_points(path)


# ---------------------------------------------------------------------------------------------------
# atomic_write


def _tmp_leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".tmp" in p.name)


def test_atomic_write_success_uses_a_sibling_temp_with_the_suffix(tmp_path):
    target = tmp_path / "model.ply"
    seen = []

    def write(tmp):
        seen.append(tmp)
        assert tmp.exists() and tmp.stat().st_size == 0 and not target.exists()
        tmp.write_bytes(b"new")

    atomic_write(target, write)
    assert target.read_bytes() == b"new"
    assert seen[0].parent == tmp_path and seen[0].suffix == ".ply" and seen[0] != target
    assert _tmp_leftovers(tmp_path) == []


def test_atomic_write_gives_umask_permissions(tmp_path):
    umask = os.umask(0o022)
    try:
        atomic_write(tmp_path / "a.json", lambda tmp: tmp.write_text("{}"))
    finally:
        os.umask(umask)
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o644


def test_atomic_write_failure_leaves_no_file(tmp_path):
    target = tmp_path / "model.ply"

    def write(tmp):
        tmp.write_bytes(b"half")
        raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError, match="disk on fire"):
        atomic_write(target, write)
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_failure_keeps_the_old_file(tmp_path):
    target = tmp_path / "model.json"
    target.write_text("old")

    def write(tmp):
        tmp.write_text("new, but incomplete")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(target, write)
    assert target.read_text() == "old"
    assert _tmp_leftovers(tmp_path) == []


def test_atomic_write_missing_folder(tmp_path):
    with pytest.raises(InputError, match=r"out[/\\]model\.ply: folder '.*out' does not exist — create it first"):
        atomic_write(tmp_path / "out" / "model.ply", lambda tmp: None)


def test_atomic_write_onto_a_folder(tmp_path):
    (tmp_path / "model.ply").mkdir()
    with pytest.raises(InputError, match=r"model\.ply: is a folder — give a file name"):
        atomic_write(tmp_path / "model.ply", lambda tmp: None)


@pytest.mark.skipif(IS_ROOT, reason=ROOT_REASON)
def test_atomic_write_read_only_folder(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        with pytest.raises(InputError, match=r"ro[/\\]model\.ply: cannot write in folder .*\(permission denied\)"):
            atomic_write(folder / "model.ply", lambda tmp: None)
    finally:
        folder.chmod(0o700)


def test_atomic_write_read_only_folder_simulated(tmp_path, monkeypatch):
    """The same branch as above, reachable as root: creating the temp file is made to fail."""

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(io.os, "open", refuse)
    with pytest.raises(InputError, match=r"model\.ply: cannot write in folder .*\(permission denied\)"):
        atomic_write(tmp_path / "model.ply", lambda tmp: None)


# ---------------------------------------------------------------------------------------------------
# meshes


def _octahedron():
    vertices = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    faces = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    return vertices * 1.25 + [3.0, -2.0, 0.5], faces  # volume 4/3 * 1.25**3


OCTAHEDRON_VOLUME = 4 / 3 * 1.25**3


def test_mesh_ply_round_trip(tmp_path):
    vertices, faces = _octahedron()
    path = tmp_path / "tube.ply"
    write_mesh(path, vertices, faces)
    data = plyfile.PlyData.read(str(path))
    assert not data.text and data.byte_order == "<"
    got_vertices = np.column_stack([data["vertex"][c] for c in "xyz"])
    np.testing.assert_array_equal(got_vertices, vertices)
    np.testing.assert_array_equal(np.vstack(data["face"]["vertex_indices"]), faces)
    np.testing.assert_array_equal(read_points(path)[0], vertices)  # our own reader takes it too


@pytest.mark.parametrize("suffix", [".obj", ".stl", ".off", ".glb", ".ply"])
def test_mesh_round_trip_through_trimesh(tmp_path, suffix):
    trimesh = pytest.importorskip("trimesh")
    vertices, faces = _octahedron()
    path = tmp_path / f"tube{suffix}"
    write_mesh(path, vertices, faces)
    mesh = trimesh.load(path, force="mesh")
    assert (len(mesh.vertices), len(mesh.faces)) == (len(vertices), len(faces))
    assert mesh.is_watertight
    np.testing.assert_allclose(mesh.volume, OCTAHEDRON_VOLUME, rtol=1e-6)


def test_mesh_formats_are_registered():
    assert set(MESH_FORMATS) == {".ply", ".obj", ".stl", ".off", ".glb"}


def test_mesh_unknown_suffix(tmp_path):
    with pytest.raises(InputError, match=r"tube\.fbx: unknown mesh format '\.fbx' — use one of \.ply, \.obj"):
        write_mesh(tmp_path / "tube.fbx", *_octahedron())


def test_mesh_bad_arrays(tmp_path):
    vertices, faces = _octahedron()
    with pytest.raises(InputError, match=r"vertices must have shape \(V, 3\)"):
        write_mesh(tmp_path / "t.ply", vertices[:, :2], faces)
    with pytest.raises(InputError, match=r"faces must be integer indices"):
        write_mesh(tmp_path / "t.ply", vertices, faces.astype(float))
    with pytest.raises(InputError, match=r"faces index vertices 0\.\.5 only, got 0\.\.6"):
        write_mesh(tmp_path / "t.ply", vertices, np.vstack([faces, [[0, 1, 6]]]))
    assert list(tmp_path.iterdir()) == []


def test_mesh_missing_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "trimesh", None)
    with pytest.raises(InputError, match=r"writing \.obj files needs the 'mesh' extra — pip install 'canalsurf\[mesh\]'"):
        write_mesh(tmp_path / "tube.obj", *_octahedron())
    write_mesh(tmp_path / "tube.ply", *_octahedron())  # PLY needs no extra


# ---------------------------------------------------------------------------------------------------
# spine CSV / DXF


def _spine():
    rng = np.random.default_rng(SEED)
    degree = 3
    control = np.cumsum(rng.normal(size=(9, 3)), axis=0)
    inner = np.sort(rng.uniform(0, 1, size=len(control) - degree - 1))
    knots = np.r_[[0.0] * (degree + 1), inner, [1.0] * (degree + 1)]
    t = np.linspace(0, 1, 57)
    samples = rng.normal(size=(57, 3))
    radius = 0.5 + rng.uniform(size=57) / 3
    return t, knots, control, degree, samples, radius


def test_spine_csv_round_trip(tmp_path):
    t, _, _, _, samples, radius = _spine()
    branch = np.repeat([0, 1, 2], [20, 20, 17])
    path = tmp_path / "spine.csv"
    write_spine_csv(path, t, samples, radius, branch)
    assert path.read_text().splitlines()[0] == "branch,t,x,y,z,radius"
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    np.testing.assert_array_equal(table, np.column_stack([branch, t, samples, radius]))  # bit-exact


def test_spine_csv_of_one_tube_is_branch_0(tmp_path):
    t, _, _, _, samples, radius = _spine()
    write_spine_csv(tmp_path / "spine.csv", t, samples, radius)
    assert np.all(np.loadtxt(tmp_path / "spine.csv", delimiter=",", skiprows=1)[:, 0] == 0)


def test_spine_csv_bad_shapes(tmp_path):
    t, _, _, _, samples, radius = _spine()
    with pytest.raises(InputError, match=r"spine CSV needs branch \(M,\), t \(M,\), points \(M, 3\) and radius \(M,\)"):
        write_spine_csv(tmp_path / "spine.csv", t[:-1], samples, radius)


def test_spine_dxf_round_trip(tmp_path):
    """One exact SPLINE and one radius polyline per branch."""
    ezdxf = pytest.importorskip("ezdxf")
    _, knots, control, degree, samples, radius = _spine()
    path = tmp_path / "spine.dxf"
    second = (knots, control + 10.0, degree, samples + 10.0, radius * 2)
    write_spine_dxf(path, [(knots, control, degree, samples, radius), second])
    doc = ezdxf.readfile(path)
    splines = doc.modelspace().query("SPLINE")
    lines = doc.modelspace().query("POLYLINE[layer=='RADIUS']")
    assert len(splines) == 2 and len(lines) == 2
    for spline, line, shift, scale in zip(splines, lines, (0.0, 10.0), (1.0, 2.0)):
        assert spline.dxf.layer == "SPINE" and spline.dxf.degree == degree
        np.testing.assert_array_equal(np.array(spline.control_points), control + shift)
        np.testing.assert_array_equal(np.array(spline.knots), knots)
        vertices = list(line.vertices)
        np.testing.assert_array_equal([list(v.dxf.location) for v in vertices], samples + shift)
        got_radius = [v.get_xdata(io.DXF_APPID)[0].value for v in vertices]
        np.testing.assert_array_equal(got_radius, radius * scale)


@pytest.mark.parametrize("units, insunits, metric", [(None, 0, 1), ("m", 6, 1), ("mm", 4, 1), ("ft", 2, 0),
                                                     ("in", 1, 0)])
def test_spine_dxf_declares_its_units(tmp_path, units, insunits, metric):
    """$INSUNITS from the unit (AutoCAD's codes), unitless without one; $MEASUREMENT to match."""
    ezdxf = pytest.importorskip("ezdxf")
    _, knots, control, degree, samples, radius = _spine()
    path = tmp_path / "spine.dxf"
    write_spine_dxf(path, [(knots, control, degree, samples, radius)], units=units)
    doc = ezdxf.readfile(path)
    assert doc.header["$INSUNITS"] == insunits and doc.units == insunits
    assert doc.header["$MEASUREMENT"] == metric
    if units is not None:
        assert DXF_UNITS[units] == insunits
    # the unit is a label: the numbers are the same whatever it is
    np.testing.assert_array_equal(np.array(doc.modelspace().query("SPLINE")[0].control_points), control)


def test_spine_dxf_unknown_unit(tmp_path):
    _, knots, control, degree, samples, radius = _spine()
    with pytest.raises(InputError, match=r"units must be one of 'm', 'mm', 'ft', 'in' or None, got 'yd'"):
        write_spine_dxf(tmp_path / "spine.dxf", [(knots, control, degree, samples, radius)], units="yd")
    assert list(tmp_path.iterdir()) == []


def test_spine_dxf_knot_count_is_checked(tmp_path):
    pytest.importorskip("ezdxf")
    _, knots, control, degree, samples, radius = _spine()
    with pytest.raises(InputError, match=r"knots must hold n \+ degree \+ 1 = 13 values for 9 control points, got 12"):
        write_spine_dxf(tmp_path / "spine.dxf", [(knots[:-1], control, degree, samples, radius)])
    assert list(tmp_path.iterdir()) == []


def test_spine_dxf_missing_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ezdxf", None)
    _, knots, control, degree, samples, radius = _spine()
    with pytest.raises(InputError, match=r"writing \.dxf files needs the 'dxf' extra — pip install 'canalsurf\[dxf\]'"):
        write_spine_dxf(tmp_path / "spine.dxf", [(knots, control, degree, samples, radius)])


# ---------------------------------------------------------------------------------------------------
# JSON


def test_json_round_trip_keeps_order_and_numpy_values(tmp_path):
    obj = {"z": 1, "a": np.float64(0.1), "n": np.int64(7), "arr": np.arange(3), "nested": {"ok": True}}
    path = tmp_path / "model.json"
    write_json(path, obj)
    text = path.read_text(encoding="utf-8")
    assert text.endswith("}\n") and text.startswith('{\n "z": 1,')  # indent=1, insertion order
    assert json.loads(text) == {"z": 1, "a": 0.1, "n": 7, "arr": [0, 1, 2], "nested": {"ok": True}}


@pytest.mark.parametrize("bad", [float("nan"), np.float32("inf"), np.array([1.0, np.nan])])
def test_json_refuses_nan_before_touching_the_file(tmp_path, bad):
    path = tmp_path / "model.json"
    path.write_text("old")
    with pytest.raises(ValueError, match="Out of range float values are not JSON compliant"):
        write_json(path, {"residual": bad})
    assert path.read_text() == "old"
    assert _tmp_leftovers(tmp_path) == []
