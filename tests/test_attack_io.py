"""Hostile input: corrupted point files and model files, absurd numbers and sizes.

Every file is generated here from a seeded cloud with the format's own library (or canalsurf's
writers) and then damaged the way a bad disk, a broken exporter or an attacker would: bytes
duplicated, flipped or cut, counts in a header changed.  Each must end with a one-line
:class:`InputError` (or be read correctly) -- never a traceback, a crash, unbounded memory or time,
or points the file does not hold.  The worst cases run the command line in a child process with a
memory limit and a timeout, since an abort or an endless read cannot be caught in-process.
"""

from __future__ import annotations

import io
import json
import math
import re
import struct
import subprocess
import sys
import time
import zipfile

import crc32c
import numpy as np
import pytest

import canalsurf
from canalsurf._validate import MAX_COORDINATE
from canalsurf.errors import InputError
from canalsurf.io import read_points, write_points
from canalsurf.model import (
    MAX_MODEL_BYTES,
    CanalModel,
    load_model,
    model_from_dict,
    radius_from_dict,
    spline_from_dict,
)
from canalsurf.shrink import MAX_MOVES, shrink, shrink_by_concentration
from canalsurf.spine import constant_spline
from canalsurf.surface import MAX_MESH_VERTICES, surface_mesh

SEED = 20240611
#: Address-space limit of the child processes: a reader that tries to allocate what a corrupted
#: header claims fails here instead of swapping the machine.
MEMORY_LIMIT = 4 << 30
#: Seconds a child process may take (reading a small file and, when it is valid, reconstructing it).
CHILD_TIMEOUT = 60


def _tube(n: int = 2000, seed: int = SEED) -> np.ndarray:
    """Points on a bent tube of radius 1 (a quarter torus of spine radius 5)."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0, np.pi / 2, n), rng.uniform(0, 2 * np.pi, n)
    ring = 5 + np.cos(v)
    return np.column_stack([ring * np.cos(u), ring * np.sin(u), np.sin(v)])


def _one_line(info) -> str:
    message = str(info.value)
    assert "\n" not in message and message.strip() == message
    return message


def _limit_memory():  # runs in the child, before exec
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def _run_cli(path, out) -> subprocess.CompletedProcess:
    """``canalsurf reconstruct path -o out`` in a child with a memory limit and a timeout."""
    if sys.platform == "win32":
        pytest.skip("a child's memory is limited with setrlimit, which Windows lacks")
    return subprocess.run([sys.executable, "-m", "canalsurf.cli", "reconstruct", str(path), "-o", str(out)],
                          capture_output=True, text=True, timeout=CHILD_TIMEOUT, preexec_fn=_limit_memory)


def _assert_clean_exit(proc: subprocess.CompletedProcess) -> list[str]:
    """Exit 0, 1 or 2 (no signal), no traceback, and a failure told in exactly one stderr line."""
    assert proc.returncode in (0, 1, 2), (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr and "panicked" not in proc.stderr, proc.stderr[-2000:]
    lines = proc.stderr.splitlines()
    if proc.returncode:
        assert len(lines) == 1 and lines[0].startswith("canalsurf: error: "), proc.stderr
    return lines


# ---------------------------------------------------------------------------------------------------
# LAS / LAZ


def _las(path, *, version="1.2", point_format=3, n=2000):
    laspy = pytest.importorskip("laspy")
    if path.suffix == ".laz":
        pytest.importorskip("lazrs")
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([500_000.0, 4_000_000.0, 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = (_tube(n) + [500_123.0, 4_000_456.0, 12.0]).T
    las.write(path)
    return path.read_bytes()


def _duplicate_middle(raw: bytes, size: int = 500) -> bytes:
    middle = len(raw) // 2
    return raw[:middle] + raw[middle - size:middle] + raw[middle:]


def _packed(raw: bytes, offset: int, fmt: str, value) -> bytes:
    out = bytearray(raw)
    struct.pack_into(fmt, out, offset, value)
    return bytes(out)


def _flipped(raw: bytes, seed: int, end: int = 375, flips: int = 3) -> bytes:
    """``flips`` seeded bytes among the first ``end`` XOR-ed with a random non-zero byte."""
    rng = np.random.default_rng(seed)
    out = bytearray(raw)
    for i in rng.choice(min(end, len(raw)), size=flips, replace=False):
        out[i] ^= int(rng.integers(1, 256))
    return bytes(out)


#: Damage done to a LAS/LAZ file: name -> function of the file's bytes.  Offsets are the LAS
#: header's: 100 the count of variable-length records, 107 the legacy point count, 131 the x scale.
LAS_DAMAGE = {
    "500-bytes-duplicated": _duplicate_middle,
    "huge-vlr-count": lambda raw: _packed(raw, 100, "<I", 2**31),
    "scale-inf": lambda raw: _packed(raw, 131, "<d", math.inf),
    "truncated": lambda raw: raw[: len(raw) * 2 // 3],
    **{f"header-flips-{seed}": (lambda raw, seed=seed: _flipped(raw, seed)) for seed in range(3)},
}


@pytest.mark.parametrize("damage", list(LAS_DAMAGE))
@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_damaged_las_ends_cleanly_in_a_memory_limited_process(tmp_path, suffix, damage):
    path = tmp_path / f"scan{suffix}"
    path.write_bytes(LAS_DAMAGE[damage](_las(path)))
    proc = _run_cli(path, tmp_path / "out")
    lines = _assert_clean_exit(proc)
    if not damage.startswith("header-flips"):  # these are refused, and with nothing printed before
        assert proc.returncode == 2 and len(lines) == 1, proc.stderr


@pytest.mark.parametrize("suffix", [".las", ".laz"])
@pytest.mark.parametrize("damage, message", [
    ("500-bytes-duplicated", r"(header says 2000 points but more data follows|chunk table)"),
    ("huge-vlr-count", r"header lists 2147483648 variable-length records, more than fit before the point data"),
    ("scale-inf", r"scale factors and offsets must be finite and the scales non-zero, the header has inf"),
    ("truncated", r"(file is truncated \(header says 2000 points, data holds 1\d{3}\)|chunk table)"),
])
def test_damaged_las_messages(tmp_path, suffix, damage, message):
    path = tmp_path / f"scan{suffix}"
    path.write_bytes(LAS_DAMAGE[damage](_las(path)))
    with pytest.raises(InputError, match=rf"scan\{suffix}: {suffix[1:].upper()} {message}") as info:
        read_points(path)
    assert _one_line(info).endswith("re-export the file")


def test_laz_layer_size_beyond_its_chunk_is_refused_in_a_memory_limited_process(tmp_path):
    """Point format 6 is compressed in layers whose sizes each chunk announces; lazrs allocates them."""
    path = tmp_path / "scan.laz"
    raw = _las(path, version="1.4", point_format=6)
    offset = struct.unpack_from("<I", raw, 96)[0]
    # the first chunk: the 8-byte chunk table offset, a raw 30-byte point, a point count, layer sizes
    path.write_bytes(_packed(raw, offset + 8 + 30 + 4, "<I", 0xF0000000))
    proc = _run_cli(path, tmp_path / "out")
    lines = _assert_clean_exit(proc)
    assert proc.returncode == 2 and "LAZ chunk 1 announces more compressed data than it holds" in lines[0]



@pytest.mark.parametrize("point_format, version", [(3, "1.2"), (6, "1.4")])
def test_laz_whose_record_declares_huge_chunks_is_read_whole_in_a_memory_limited_process(
        tmp_path, point_format, version):
    """A LASzip record whose chunk size was damaged to billions of points: lazrs's parallel decoder sets a
    whole chunk aside and aborts the process when it cannot; the file's 2,000 points are read all the same."""
    path = tmp_path / "scan.laz"
    raw = _las(path, version=version, point_format=point_format)
    before = read_points(path)[0]
    # the record's payload follows its 54-byte header, whose user id starts at byte 2; the chunk size is
    # at byte 12 of the payload
    payload = raw.index(b"laszip encoded") - 2 + 54
    path.write_bytes(_packed(raw, payload + 12, "<I", 0xF0000000))
    proc = _run_cli(path, tmp_path / "out")
    _assert_clean_exit(proc)
    assert proc.returncode == 0 and (tmp_path / "out" / "model.json").exists(), proc.stderr
    np.testing.assert_array_equal(read_points(path)[0], before)

def test_ascii_ply_with_binary_bytes_after_its_rows_is_refused(tmp_path):
    path = tmp_path / "scan.ply"
    write_points(tmp_path / "tmp.xyz", _tube(60), None)
    rows = (tmp_path / "tmp.xyz").read_bytes()
    header = b"ply\nformat ascii 1.0\nelement vertex 50\nproperty double x\nproperty double y\nproperty double z\n"
    # past the block the text reader decodes with the last row: found by the check for more data
    path.write_bytes(header + b"end_header\n" + b"\n".join(rows.splitlines()[:50]) + b"\n" * 10_000 + b"\xfa 1\n")
    with pytest.raises(InputError, match=r"scan\.ply: PLY header says 50 vertices but more data follows"):
        read_points(path)



def test_ascii_ply_whose_format_line_is_split_by_a_control_byte_is_read_as_text(tmp_path):
    """plyfile splits the format line as text, where 0x1e is whitespace, and reads it as ASCII: opened as
    binary, plyfile's text wrapper closed the file when collected, while it was still being read (seen in
    a development-mode interpreter, which warns of the file left open)."""
    path = tmp_path / "scan.ply"
    write_points(tmp_path / "tmp.xyz", _tube(60), None)
    rows = (tmp_path / "tmp.xyz").read_bytes().splitlines()
    path.write_bytes(b"ply\nformat ascii\x1e1.0\nelement vertex 60\nproperty double x\nproperty double y\n"
                     b"property double z\nend_header\n" + b"\n".join(rows) + b"\n")
    code = ("import gc, sys; from canalsurf.io import read_points; "
            "print(len(read_points(sys.argv[1])[0])); gc.collect()")
    proc = subprocess.run([sys.executable, "-X", "dev", "-W", "error::ResourceWarning", "-c", code, str(path)],
                          capture_output=True, text=True, timeout=CHILD_TIMEOUT)
    assert (proc.returncode, proc.stdout.strip()) == (0, "60"), proc.stderr
    assert "ResourceWarning" not in proc.stderr and "closed file" not in proc.stderr, proc.stderr

def test_ply_coordinate_that_is_a_list_is_refused(tmp_path):
    path = tmp_path / "scan.ply"
    path.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 2\nproperty list uchar float x\nproperty float y\n"
                     b"property float z\nend_header\n2 1 2 3 4\n1 5 6 7\n")
    with pytest.raises(InputError, match=r"scan\.ply: PLY vertex properties x are lists, not numbers — re-export"):
        read_points(path)


@pytest.mark.parametrize("version, point_format, count_at, fmt", [("1.2", 3, 107, "<I"), ("1.4", 6, 247, "<Q")])
def test_las_header_counting_fewer_points_than_the_data_is_refused(tmp_path, version, point_format, count_at, fmt):
    path = tmp_path / "scan.las"
    raw = _las(path, version=version, point_format=point_format)
    path.write_bytes(_packed(raw, count_at, fmt, 1990))
    with pytest.raises(InputError, match=r"scan\.las: LAS (header says 1990 points but more data follows — the "
                                         r"file is corrupted|header holds two different point counts)"):
        read_points(path)


def test_las_normal_dimensions_with_several_values_are_refused(tmp_path):
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.add_extra_dims([laspy.ExtraBytesParams(name=n, type="2f4") for n in ("NormalX", "NormalY", "NormalZ")])
    las = laspy.LasData(header)
    las.x, las.y, las.z = _tube(100).T
    path = tmp_path / "scan.las"
    las.write(path)
    with pytest.raises(InputError, match=r"scan\.las: LAS normal dimensions \['NormalX', 'NormalY', 'NormalZ'\] "
                                         r"hold several values per point, not one — re-export the file$"):
        read_points(path)


def test_las_1_4_round_trip_still_reads(tmp_path):
    path = tmp_path / "scan.las"
    _las(path, version="1.4", point_format=6)
    points, normals = read_points(path)
    np.testing.assert_allclose(points, _tube() + [500_123.0, 4_000_456.0, 12.0], rtol=0, atol=5e-4 + 1e-9)
    assert normals is None


# ---------------------------------------------------------------------------------------------------
# E57: a header that claims more points than stored, a pose that is not a rotation


def _edit_e57(path, old: bytes, new: bytes) -> None:
    """Replace ``old`` by ``new`` (same length) in an E57 file, re-computing its page checksums.

    E57 files are 1024-byte pages of 1020 data bytes and a big-endian CRC-32C.
    """
    assert len(old) == len(new)
    raw = path.read_bytes()
    logical = bytearray(b"".join(raw[i:i + 1020] for i in range(0, len(raw), 1024)))
    at = logical.index(old)
    logical[at:at + len(old)] = new
    pages = [bytes(logical[i:i + 1020]) for i in range(0, len(logical), 1020)]
    path.write_bytes(b"".join(p + struct.pack(">I", crc32c.crc32c(p)) for p in pages))


def _e57(path, points, translation=(0.0, 0.0, 0.0)):
    pye57 = pytest.importorskip("pye57")
    with pye57.E57(str(path), mode="w") as e57:
        data = {f"cartesian{a}": np.ascontiguousarray(points[:, i]) for i, a in enumerate("XYZ")}
        e57.write_scan_raw(data, translation=np.asarray(translation, dtype=float))


def test_e57_claiming_more_points_than_stored_is_refused(tmp_path):
    path = tmp_path / "scan.e57"
    _e57(path, _tube(300))
    _edit_e57(path, b'recordCount="300"', b'recordCount="900"')
    with pytest.raises(InputError, match=r"scan\.e57: E57 file is truncated \(header says 900 points in scan 0, "
                                         r"data holds 300\) — re-export the file") as info:
        read_points(path)
    _one_line(info)


def test_e57_pose_that_is_not_a_rotation_is_named(tmp_path):
    path = tmp_path / "scan.e57"
    _e57(path, _tube(300), translation=(10.0, 0.0, 0.0))
    # libE57 reads the non-number as 0: a quaternion of length 0, which rotates nothing anywhere
    _edit_e57(path, b'<w type="Float">1</w>', b'<w type="Float">N</w>')
    with pytest.raises(InputError, match=r"scan\.e57: E57 scan 0 has a pose that is not a finite rotation and "
                                         r"translation \(quaternion \[0\.0, 0\.0, 0\.0, 0\.0\]") as info:
        read_points(path)
    _one_line(info)


def test_e57_pose_is_applied_as_before(tmp_path):
    path = tmp_path / "scan.e57"
    points = _tube(300)
    _e57(path, points, translation=(10.0, -2.0, 0.5))
    got, normals = read_points(path)
    np.testing.assert_allclose(got, points + [10.0, -2.0, 0.5], rtol=0, atol=1e-5)  # stored as float32
    assert normals is None


# ---------------------------------------------------------------------------------------------------
# headers that count fewer rows than the data holds: refused by every format alike


def _npy_shape(raw: bytes, shape: str) -> bytes:
    """A .npy file's bytes with another shape in its header (padding adjusted, the data unchanged)."""
    end = raw.index(b"\n") + 1
    header = raw[:end].decode("latin1")
    start = header.index("'shape': ") + len("'shape': ")
    old = header[start:header.index(")", start) + 1]
    header = (header[:start] + shape + header[start + len(old):]).rstrip("\n ")
    return header.encode("latin1").ljust(end - 1) + b"\n" + raw[end:]


@pytest.mark.parametrize("shape, message", [
    ("(90, 3)", r"NumPy \.npy header says 90 points but more data follows — the file is corrupted; re-export the "
                r"file$"),
    ("(1000000000000, 3)", r"NumPy \.npy file is truncated \(header says 1000000000000 points, data holds 100\)"),
])
def test_npy_header_with_another_count_is_refused(tmp_path, shape, message):
    path = tmp_path / "scan.npy"
    np.save(path, _tube(100))
    path.write_bytes(_npy_shape(path.read_bytes(), shape))
    with pytest.raises(InputError, match=rf"scan\.npy: {message}"):
        read_points(path)


def test_npz_member_counting_fewer_rows_is_refused(tmp_path):
    buffer = io.BytesIO()
    np.save(buffer, _tube(100))
    path = tmp_path / "scan.npz"
    with zipfile.ZipFile(path, "w") as archive:  # as numpy.savez writes it, with another header
        archive.writestr("points.npy", _npy_shape(buffer.getvalue(), "(90, 3)"))
    with pytest.raises(InputError, match=r"scan\.npz: NumPy \.npz \('points'\) header says 90 points but more "
                                         r"data follows"):
        read_points(path)


def test_binary_pcd_header_counting_fewer_points_is_refused(tmp_path):
    pypcd4 = pytest.importorskip("pypcd4")
    path = tmp_path / "scan.pcd"
    pypcd4.PointCloud.from_xyz_points(_tube(100)).save(path, encoding=pypcd4.Encoding.BINARY)
    raw = path.read_bytes()
    path.write_bytes(raw.replace(b"WIDTH 100", b"WIDTH 90 ").replace(b"POINTS 100", b"POINTS 90 "))
    with pytest.raises(InputError, match=r"scan\.pcd: PCD header says 90 points but more data follows"):
        read_points(path)


def test_pcd_width_and_points_that_disagree_are_refused(tmp_path):
    pypcd4 = pytest.importorskip("pypcd4")
    path = tmp_path / "scan.pcd"
    pypcd4.PointCloud.from_xyz_points(_tube(100)).save(path, encoding=pypcd4.Encoding.BINARY_COMPRESSED)
    path.write_bytes(path.read_bytes().replace(b"POINTS 100", b"POINTS 900"))
    with pytest.raises(InputError, match=r"scan\.pcd: PCD header says WIDTH x HEIGHT = 100 x 1 but POINTS 900"):
        read_points(path)


# ---------------------------------------------------------------------------------------------------
# .npy named .npz and the reverse: read by what they hold


@pytest.mark.parametrize("holds, named", [(".npy", ".npz"), (".npz", ".npy")])
def test_numpy_file_under_the_other_suffix_is_read(tmp_path, holds, named):
    points = _tube(100)
    write_points(tmp_path / f"scan{holds}", points, None)
    (tmp_path / f"scan{holds}").rename(tmp_path / f"scan{named}")
    got, normals = read_points(tmp_path / f"scan{named}")
    np.testing.assert_array_equal(got, points)
    assert normals is None


# ---------------------------------------------------------------------------------------------------
# large files are refused from their start, not after reading them whole


@pytest.mark.parametrize("name, start, message", [
    ("zeros.xyz", b"", r"not a text file \(it holds NUL bytes\)"),
    ("zeros.csv", b"x,y,z\n1,2,3\n", r"not a text file \(it holds NUL bytes\)"),
    ("noline.xyz", b"1 2 3 " * 20_000, r"a line is longer than 4096 characters \(not a point text file\)"),
    ("zeros.ply", b"ply\nformat ascii 1.0\n", r"not a readable PLY file \(its header has no end_header line in its "
                                              r"first 1 MiB\)"),
    ("zeros.pcd", b"# .PCD v0.7\nVERSION 0.7\n", r"not a readable PCD file \(no DATA line ends its header\)"),
])
def test_a_gigabyte_file_is_refused_from_its_start(tmp_path, name, start, message):
    if name.endswith(".pcd"):
        pytest.importorskip("pypcd4")
    path = tmp_path / name
    with open(path, "wb") as fh:
        fh.write(start)
        fh.truncate(1 << 30)  # sparse: a gigabyte that costs no disk
    begin = time.perf_counter()
    with pytest.raises(InputError, match=rf"{re.escape(name)}: {message}") as info:
        read_points(path)
    assert time.perf_counter() - begin < 2.0
    _one_line(info)


# ---------------------------------------------------------------------------------------------------
# coordinates too large or too close together for float64


@pytest.mark.parametrize("scale", [1e153, 1e200, 1e300, 1e305, 1e308 / 6, -1e308 / 6])
def test_huge_coordinates_are_named(scale):
    with pytest.raises(InputError, match=r"^points coordinates are too large \(max \|x\| = .*, more than "
                                         rf"{re.escape(f'{MAX_COORDINATE:.0e}')}: float64 keeps only 16 digits\) "
                                         r"— subtract an offset \(e\.g\. the mean\) or use a larger unit$"):
        canalsurf.reconstruct(_tube() * scale + [0.0, 0.0, 1.5 * scale])  # from -scale/2 to 2.5 scale


@pytest.mark.parametrize("points, message", [
    (_tube() * 1e-300, r"^points span only 6e-300, too little for float64 arithmetic \(at least 1e-150\) — use a "
                       r"smaller unit \(scale the points up\)$"),
    (_tube() * 1e-6 + 1e6, r"^points span only 6e-06 at coordinates as large as 1e\+06, too little to resolve in "
                           r"float64 — subtract an offset \(e\.g\. the mean\) first$"),
])
def test_points_too_close_together_are_named(points, message):
    with pytest.raises(InputError, match=message.replace("6e-300", r"\d(\.\d+)?e-300").replace("6e-06", r"\de-06")):
        canalsurf.reconstruct(points)


def test_huge_coordinates_through_the_command_line(tmp_path):
    path = tmp_path / "far.npy"
    np.save(path, _tube() * 1e305)
    proc = _run_cli(path, tmp_path / "out")
    lines = _assert_clean_exit(proc)
    assert proc.returncode == 2 and "coordinates are too large (max |x| = 6e+305" in lines[0]


# ---------------------------------------------------------------------------------------------------
# the Python API: numbers, paths, arrays and sizes


@pytest.mark.parametrize("value, message", [
    (10**400, r"^R is too large for a float64 number, got 1000000000000000000000000000000000000\.\.\.$"),
    (True, r"^R must be a real number, got bool True$"),
    (1 + 2j, r"^R must be a real number, got complex \(1\+2j\)$"),
    ("1", r"^R must be a real number, got str '1'$"),
    (5e-324, r"^R = 4\.94e-324 is too small for float64 arithmetic \(at least 2\.23e-308\) — give a larger R or "
             r"use a smaller unit$"),
])
def test_reconstruct_refuses_numbers_that_are_not(value, message):
    with pytest.raises(InputError, match=message):
        canalsurf.reconstruct(_tube(), R=value)


def test_read_points_of_none_and_write_points_of_two_columns(tmp_path):
    with pytest.raises(InputError, match=r"^path must be a file path \(str or os\.PathLike\), got NoneType$"):
        read_points(None)
    with pytest.raises(InputError, match=r"^model path must be a file path \(str or os\.PathLike\), got int$"):
        load_model(3)
    with pytest.raises(InputError, match=r"^points must have shape \(N, 3\), got \(10, 2\)$"):
        write_points(tmp_path / "scan.ply", np.zeros((10, 2)), None)
    with pytest.raises(InputError, match=r"^normals must have the shape of the points \(10, 3\), got \(9, 3\)$"):
        write_points(tmp_path / "scan.ply", np.zeros((10, 3)), np.ones((9, 3)))
    assert not list(tmp_path.iterdir())


def test_surface_mesh_refuses_sizes_that_cannot_fit_before_allocating():
    spine = canalsurf.make_tube("fig9-pipe").spine
    begin = time.perf_counter()
    with pytest.raises(InputError, match=rf"^a mesh of 1,000,000,000 rings of 32 vertices would have 3\.2e\+10 "
                                         rf"vertices, more than the {MAX_MESH_VERTICES:,} that fit in memory — "
                                         r"give a smaller n_along or n_around$"):
        surface_mesh(spine, constant_spline(1.0), n_along=10**9)
    with pytest.raises(InputError, match=r"^a mesh of 16 rings of 1,000,000,000 vertices"):
        surface_mesh(spine, constant_spline(1.0), n_around=10**9)
    assert time.perf_counter() - begin < 1.0


@pytest.fixture
def shrink_inputs(cylinder):
    points, normals, _, _ = cylinder(500)
    return points, normals


def test_shrink_refuses_more_than_max_moves(shrink_inputs):
    points, normals = shrink_inputs
    with pytest.raises(InputError, match=rf"^delta is 4e\+06 times smaller than the shrink distance, so shrinking "
                                         rf"could take 4e\+06 moves \(at most {MAX_MOVES:,}\) — give a larger delta "
                                         r"\(the default, r0 / 20, takes 80\)$"):
        shrink(points, normals, R=0.2, delta=1e-6, mu=0.7, max_distance=4.0)
    with pytest.raises(InputError, match=r"^delta is 4e\+09 times smaller"):
        shrink_by_concentration(points, normals, R=0.2, delta=1e-9, max_distance=4.0,
                                neighbours=np.zeros((500, 1), int))
    with pytest.raises(InputError, match=r"^delta = 4\.94e-324 \(relative to the scan's size\) is too small for "
                                         r"float64 arithmetic — give a larger delta$"):
        shrink(points, normals, R=0.2, delta=5e-324, mu=0.7, max_distance=4.0)
    with pytest.raises(InputError, match=r"^R must be a positive finite number, got inf"):
        shrink(points, normals, R=math.inf, delta=0.05, mu=0.7, max_distance=4.0)
    # the pipeline's default ratio (4 r0 / (r0 / 20) = 80 moves) and the bound itself still run
    assert shrink(points, normals, R=0.2, delta=0.05, mu=0.7, max_distance=4.0).converged
    assert shrink(points, normals, R=0.2, delta=4.0 / MAX_MOVES, mu=0.7, max_distance=4.0).iterations < MAX_MOVES


def test_reconstruct_with_a_tiny_delta_names_delta():
    with pytest.raises(InputError, match=r"^delta is \S+ times smaller than the shrink distance"):
        canalsurf.reconstruct(_tube(), delta=1e-9)


# ---------------------------------------------------------------------------------------------------
# model files


def _pipe_dict() -> dict:
    tube = canalsurf.make_tube("fig9-pipe")
    return CanalModel("pipe", tube.spine, constant_spline(1.0), False, {"R": 0.2}, {"iterations": 5}).to_dict()


def _closed_canal_dict() -> dict:
    from scipy.interpolate import make_interp_spline

    tube = canalsurf.make_tube("torus")
    u = np.linspace(0.0, 1.0, 41)
    r = 1.0 + 0.3 * np.sin(2 * np.pi * u)
    r[-1] = r[0]
    return CanalModel("canal", tube.spine, make_interp_spline(u, r, k=3, bc_type="periodic"), True).to_dict()


def _write_model(tmp_path, content) -> str:
    path = tmp_path / "model.json"
    path.write_text(content if isinstance(content, str) else json.dumps(content), encoding="utf-8")
    return str(path)


@pytest.mark.parametrize("make", [_pipe_dict, _closed_canal_dict])
def test_valid_models_still_load_exactly(make):
    data = make()
    model = model_from_dict(json.loads(json.dumps(data)))
    assert model.to_dict() == data


def _damage(data: dict, name: str) -> dict:
    sp = data["spine"]
    if name == "knots-one-short":
        sp["knots"] = sp["knots"][:-1]
    elif name == "knots-shifted":
        sp["knots"] = [k + 5 for k in sp["knots"]]
    elif name == "knots-decreasing":
        sp["knots"][5], sp["knots"][6] = sp["knots"][6], sp["knots"][5]
    elif name == "degree-3.7":
        sp["degree"] = 3.7
    elif name == "degree-true":
        sp["degree"] = True
    elif name == "degree-9":
        sp["degree"] = 9
    elif name == "closed-null":
        sp["closed"] = None
    elif name == "parameters-5":
        data["parameters"] = 5
    elif name == "diagnostics-null":
        data["diagnostics"] = None
    elif name == "radius-negative":
        data["kind"] = "canal"
        data["radius"] = {"degree": 3, "knots": [0, 0, 0, 0, 1, 1, 1, 1], "coefficients": [1, 1, -3, 1]}
    elif name == "radius-constant-zero":
        data["radius"] = {"constant": 0}
    elif name == "pipe-with-radius-spline":
        data["radius"] = {"degree": 3, "knots": [0, 0, 0, 0, 1, 1, 1, 1], "coefficients": [1, 1, 1, 1]}
    elif name == "control-point-huge":
        sp["control_points"][0][0] = 1e300
    elif name == "samples-unequal":
        data["samples"]["t"] = data["samples"]["t"][:-1]
    return data


@pytest.mark.parametrize("damage, problem", [
    ("knots-one-short", r"spine has 9 knots; 6 control_points of degree 3 need 10"),
    ("knots-shifted", r"spine is defined on \[5, 6\], not on \[0, 1\]"),
    ("knots-decreasing", r"spine knots decrease at index 6"),
    ("degree-3.7", r"spine degree must be an integer from 1 to 5, got 3\.7"),
    ("degree-true", r"spine degree must be an integer from 1 to 5, got true"),
    ("degree-9", r"spine degree must be an integer from 1 to 5, got 9"),
    ("closed-null", r"spine closed must be true or false, got null"),
    ("parameters-5", r"parameters must be an object, got a number"),
    ("diagnostics-null", r"diagnostics must be an object, got null"),
    ("radius-negative", r"radius must be positive on \[0, 1\], its least value there is -\d[\d.]*"),
    ("radius-constant-zero", r"radius constant must be a positive number, got 0"),
    ("pipe-with-radius-spline", r"a pipe has a constant radius"),
    ("control-point-huge", r"spine control_points must be finite numbers of at most 1e\+15 in size"),
    ("samples-unequal", r"samples t, points and radius differ in length"),
])
def test_corrupted_models_are_refused(tmp_path, damage, problem):
    path = _write_model(tmp_path, _damage(_pipe_dict(), damage))
    with pytest.raises(InputError, match=rf"^.*model\.json: corrupted model \({problem}\) — re-run the "
                                         r"reconstruction$"):
        load_model(path)


@pytest.mark.parametrize("content, message", [
    ('{"version": true, "format": "canalsurf.model"}', r"model version true is not supported"),
    ("5", r'not a canalsurf model \(no "format": "canalsurf\.model"\)'),
    ("[" * 100_000 + "]" * 100_000, r"not a model \(its JSON nests deeper than 32 levels\)"),
    ('{"a":' * 40 + "1" + "}" * 40, r"not a model \(its JSON nests deeper than 32 levels\)"),
    ('{"format": "canalsurf.model", "version": 1, "n": ' + "9" * 400 + "}",
     r"corrupted model \(the number 9999999999999999999999999999999999999\.\.\. is out of range"),
    ('{"format": "canalsurf.model", "version": 1, "n": 1e400}', r"corrupted model \(the number 1e400 is out"),
    ('{"format": "canalsurf.model", "version": 1, "n": NaN}', r"corrupted model \(the number NaN is out"),
    ('{"format": "canalsurf.model", "version": 1, "n": -Infinity}', r"corrupted model \(the number -Infinity"),
])
def test_hostile_json_is_refused(tmp_path, content, message):
    path = _write_model(tmp_path, content)
    with pytest.raises(InputError, match=rf"^.*model\.json: {message}") as info:
        load_model(path)
    _one_line(info)


def test_oversized_model_is_refused_before_reading(tmp_path):
    path = tmp_path / "model.json"
    with open(path, "wb") as fh:
        fh.truncate(MAX_MODEL_BYTES + 1)
    with pytest.raises(InputError, match=r"model\.json: is 64 MiB, more than the 64 MiB a model file can take"):
        load_model(path)


def test_spline_from_dict_accepts_open_and_periodic_splines():
    for data, key in ((_pipe_dict()["spine"], "control_points"), (_closed_canal_dict()["radius"], "coefficients")):
        spline = spline_from_dict(data, "x", "here")
        np.testing.assert_array_equal(spline.t, data["knots"])
        np.testing.assert_array_equal(spline.c, data[key])
    closed = _closed_canal_dict()
    assert closed["spine"]["knots"][0] < 0 < 1 < closed["spine"]["knots"][-1]  # a periodic spine extends past [0, 1]
    np.testing.assert_allclose(radius_from_dict(closed["radius"], "radius", "here")(0.25), 1.3, atol=1e-3)
    with pytest.raises(InputError, match=r"^here: corrupted model \(branch 2 spine needs either control_points or "
                                         r"coefficients\) — re-run the reconstruction$"):
        spline_from_dict({"degree": 3, "knots": [0, 1]}, "branch 2 spine", "here")
