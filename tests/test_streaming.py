"""Reading files larger than memory: a seeded sample read in chunks, a second chunked pass, labels written
a chunk at a time, and the command line on a file larger than what it keeps.

Every file is generated here, seeded, in pytest's tmp_path.  The chunk size is made small where a test
needs many chunks of a small file (``io._STREAM_CHUNK_POINTS``), and so is the command line's sample
(``cli.STREAM_POINTS``).
"""

from __future__ import annotations

import json
import tracemalloc

import laspy
import numpy as np
import plyfile
import pypcd4
import pytest

from canalsurf import cli, io, load_model
from canalsurf.errors import InputError
from canalsurf.io import (
    PointSample,
    iter_point_chunks,
    read_points,
    read_points_sample,
    write_labelled_chunks,
    write_labelled_points,
    write_points,
)
from canalsurf.pointcloud import crop
from canalsurf.synth import make_tube

SEED = 20240611
#: Points of the small test clouds: several chunks of the small chunk size below.
N = 3000
#: A chunk size that cuts the small clouds into many uneven chunks.
SMALL_CHUNK = 257


@pytest.fixture
def cloud(random_cloud):
    return random_cloud(N)


@pytest.fixture
def small_chunks(monkeypatch):
    monkeypatch.setattr(io, "_STREAM_CHUNK_POINTS", SMALL_CHUNK)


def _write_ply(path, points, normals, *, text, dtype="f8"):
    names = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    vertex = np.empty(len(points), dtype=[(n, dtype) for n in names] + [("intensity", "u2")])
    table = points if normals is None else np.hstack([points, normals])
    for i, name in enumerate(names):
        vertex[name] = table[:, i]
    vertex["intensity"] = np.arange(len(points)) % 65536
    plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")], text=text).write(str(path))


def _write_las(path, points, normals=None, *, scale=0.001, offset=(10.0, -20.0, 5.0), chunk=None):
    """A LAS/LAZ file with a scale and offset, written with laspy's chunked writer ``chunk`` points at a time."""
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.full(3, scale)
    header.offsets = np.asarray(offset, dtype=float)
    if normals is not None:
        header.add_extra_dims([laspy.ExtraBytesParams(name=n, type=np.float64)
                               for n in ("NormalX", "NormalY", "NormalZ")])
    chunk = chunk or len(points)
    with laspy.open(path, mode="w", header=header) as writer:
        for start in range(0, len(points), chunk):
            part = slice(start, start + chunk)
            record = laspy.ScaleAwarePointRecord.zeros(len(points[part]), header=header)
            record.x, record.y, record.z = points[part].T
            if normals is not None:
                record.NormalX, record.NormalY, record.NormalZ = normals[part].T
            writer.write_points(record)


def _write_pcd(path, points, normals):
    data = np.hstack([points, normals])
    fields = ("x", "y", "z", "normal_x", "normal_y", "normal_z")
    pypcd4.PointCloud.from_points(data, fields, [np.float64] * 6).save(path, encoding=pypcd4.Encoding("binary"))


#: Every way a point file is written here: name -> (file name, write(path, points, normals)).
FORMATS = {
    "ply-binary-f8": ("scan.ply", lambda p, x, n: _write_ply(p, x, n, text=False)),
    "ply-binary-f4-big-endian": ("scan.ply", lambda p, x, n: plyfile.PlyData(
        [plyfile.PlyElement.describe(np.rec.fromarrays(list(x.T), names="x,y,z").astype(
            [("x", ">f4"), ("y", ">f4"), ("z", ">f4")]), "vertex")], byte_order=">").write(str(p))),
    "ply-ascii-f4": ("scan.ply", lambda p, x, n: _write_ply(p, x, n, text=True, dtype="f4")),
    "ply-ascii-f8": ("scan.ply", lambda p, x, n: _write_ply(p, x, n, text=True)),
    "xyz": ("scan.xyz", lambda p, x, n: write_points(p, x, n)),
    "csv-with-header": ("scan.csv", lambda p, x, n: write_points(p, x, None)),
    "txt-with-comments": ("scan.txt", lambda p, x, n: p.write_text(
        "# a scan\n" + "".join(f"{a!r} {b!r} {c!r}\n" + ("# between\n\n" if i % 100 == 7 else "")
                               for i, (a, b, c) in enumerate(x.tolist())))),
    "npy": ("scan.npy", lambda p, x, n: write_points(p, x, n)),
    "npy-fortran-f4": ("scan.npy", lambda p, x, n: np.save(p, np.asfortranarray(x.astype(np.float32)))),
    "npz": ("scan.npz", lambda p, x, n: write_points(p, x, n)),
    "las": ("scan.las", lambda p, x, n: _write_las(p, x, n, chunk=1000)),
    "laz": ("scan.laz", lambda p, x, n: _write_las(p, x, n, chunk=1000)),
    "pcd": ("scan.pcd", _write_pcd),
}


@pytest.mark.parametrize("chunked", [False, True], ids=["default-chunks", "small-chunks"])
@pytest.mark.parametrize("fmt", list(FORMATS))
def test_below_the_cap_the_sample_is_what_read_points_gives(fmt, chunked, cloud, tmp_path, monkeypatch):
    if chunked:
        monkeypatch.setattr(io, "_STREAM_CHUNK_POINTS", SMALL_CHUNK)
    name, write = FORMATS[fmt]
    path = tmp_path / name
    write(path, *cloud)
    points, normals = read_points(path)
    for cap in (len(points), 10 * len(points)):
        sample = read_points_sample(path, cap, rng=5)
        assert isinstance(sample, PointSample) and (sample.total, sample.in_box) == (N, N)
        np.testing.assert_array_equal(sample.points, points)  # the same numbers in the same order
        if normals is None:
            assert sample.normals is None
        else:
            np.testing.assert_array_equal(sample.normals, normals)
    # the second pass gives the same points, in chunks no larger than the chunk size
    parts = list(iter_point_chunks(path))
    assert max(len(p) for p, _ in parts) <= io._STREAM_CHUNK_POINTS
    np.testing.assert_array_equal(np.concatenate([p for p, _ in parts]), points)


@pytest.mark.parametrize("fmt", ["ply-binary-f8", "ply-ascii-f8", "xyz", "npy", "laz", "npz"])
def test_above_the_cap_a_seeded_sample_of_exactly_the_cap(fmt, cloud, tmp_path, small_chunks):
    name, write = FORMATS[fmt]
    path = tmp_path / name
    write(path, *cloud)
    points, normals = read_points(path)
    first = read_points_sample(path, 500, rng=1)
    assert (len(first.points), len(first.normals), first.total, first.in_box) == (500, 500, N, N)
    # each kept point is a row of the file with its own normal, and the rows come in file order
    rows = {tuple(p): i for i, p in enumerate(points)}
    index = np.array([rows[tuple(p)] for p in first.points])
    assert np.all(np.diff(index) > 0)
    np.testing.assert_array_equal(first.normals, normals[index])
    again = read_points_sample(path, 500, rng=1)
    np.testing.assert_array_equal(again.points, first.points)
    other = read_points_sample(path, 500, rng=2)
    assert len({tuple(p) for p in other.points} & {tuple(p) for p in first.points}) < 250


@pytest.mark.parametrize("fmt", ["ply-binary-f8", "ply-ascii-f4", "txt-with-comments", "npy", "laz", "pcd"])
def test_the_sample_does_not_depend_on_the_chunk_size(fmt, cloud, tmp_path, monkeypatch):
    name, write = FORMATS[fmt]
    path = tmp_path / name
    write(path, *cloud)
    samples = []
    for chunk in (1 << 16, 1000, SMALL_CHUNK, 10):
        monkeypatch.setattr(io, "_STREAM_CHUNK_POINTS", chunk)
        for cap in (1, 300, 2999):
            sample = read_points_sample(path, cap, rng=SEED)
            assert len(sample.points) == cap
            samples.append((chunk, cap, sample.points))
    for chunk, cap, points in samples:
        reference = next(p for c, k, p in samples if k == cap)
        np.testing.assert_array_equal(points, reference, err_msg=f"chunk {chunk}, cap {cap}")


def test_the_sample_is_uniform_over_the_file(tmp_path, small_chunks):
    """On a file sorted by x, a sample biased to any part of the file (its start, its chunks' starts)
    would show in the distribution of x; a uniform one matches the file's to sampling error."""
    rng = np.random.default_rng(SEED)
    points = rng.gamma(2.0, size=(60_000, 3))
    points = points[np.argsort(points[:, 0])]
    path = tmp_path / "sorted.npy"
    np.save(path, points)
    n = 6000
    x = np.sort(points[:, 0])
    sampled = np.sort(read_points_sample(path, n, rng=3).points[:, 0])
    # Kolmogorov-Smirnov distance between the sample and the file: its 1 % critical value for a sample of
    # n is 1.63 / sqrt(n) = 0.021 (a little less without replacement)
    cdf = np.searchsorted(x, sampled, side="right") / len(x)
    ks = max(np.max(np.arange(1, n + 1) / n - cdf), np.max(cdf - np.arange(n) / n))
    assert ks < 1.63 / np.sqrt(n)
    # the mean to within 3 standard errors
    assert abs(sampled.mean() - x.mean()) < 3 * x.std() / np.sqrt(n)
    # and each part of the file gives its share: tenths of the rows, each 10 % of the sample +- 4 sigma
    rows = np.searchsorted(x, sampled)
    share = np.bincount(rows * 10 // len(x), minlength=10) / n
    assert np.all(np.abs(share - 0.1) < 4 * np.sqrt(0.1 * 0.9 / n))


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_coordinates_are_scaled_and_offset_in_float64(suffix, tmp_path, small_chunks):
    rng = np.random.default_rng(SEED)
    # survey coordinates: millions of metres, millimetre grid -- float32 would lose the millimetres
    points = rng.uniform(0, 50, size=(5000, 3)) + [500_000.0, 4_000_000.0, 100.0]
    path = tmp_path / f"survey{suffix}"
    _write_las(path, points, offset=(500_000.0, 4_000_000.0, 100.0), chunk=777)
    with laspy.open(path) as reader:
        las = reader.read()
        header = reader.header
    truth = np.column_stack([las.X * header.scales[0] + header.offsets[0], las.Y * header.scales[1] + header.offsets[1],
                             las.Z * header.scales[2] + header.offsets[2]])
    np.testing.assert_allclose(truth, points, rtol=0, atol=0.0005 + 1e-9)  # on the file's millimetre grid
    whole = read_points_sample(path, 10_000)
    np.testing.assert_array_equal(whole.points, truth)
    sample = read_points_sample(path, 100, rng=4)
    rows = {tuple(p): i for i, p in enumerate(truth)}
    assert all(tuple(p) in rows for p in sample.points) and sample.total == 5000


def test_a_crop_box_is_applied_while_reading(cloud, tmp_path, small_chunks):
    points, normals = cloud
    path = tmp_path / "scan.npy"
    write_points(path, points, normals)
    box = (-5.0, -20.0, -20.0, 20.0, 5.0, 0.0)
    inside, inside_normals = crop(points, box, normals=normals)
    all_inside = read_points_sample(path, N, box=box)
    np.testing.assert_array_equal(all_inside.points, inside)
    np.testing.assert_array_equal(all_inside.normals, inside_normals)
    assert (all_inside.total, all_inside.in_box) == (N, len(inside))
    # above the cap: as many points as the cap, all of them inside the box
    sample = read_points_sample(path, 100, box=box, rng=2)
    assert len(sample.points) == 100 and sample.in_box == len(inside)
    assert {tuple(p) for p in sample.points} <= {tuple(p) for p in inside}
    chunks = [p for p, _ in iter_point_chunks(path, box=box)]
    assert all(len(p) for p in chunks)  # no empty chunk is handed out
    np.testing.assert_array_equal(np.concatenate(chunks), inside)
    nowhere = read_points_sample(path, 100, box=(100, 100, 100, 101, 101, 101))
    assert (nowhere.points.shape, nowhere.normals.shape, nowhere.in_box, nowhere.total) == ((0, 3), (0, 3), 0, N)


@pytest.mark.parametrize("fmt, row", [("xyz", 1234), ("npy", 2999), ("ply-binary-f8", 0), ("ply-ascii-f8", 700)])
def test_a_point_with_nan_or_inf_is_refused_by_its_row(fmt, row, cloud, tmp_path, small_chunks):
    points, _ = cloud
    points = points.copy()
    points[row, 1] = np.nan if row % 2 else -np.inf
    name, write = FORMATS[fmt]
    path = tmp_path / name
    write(path, points, None)
    with pytest.raises(InputError, match=rf"^{path}: point {row} \(counting from 0\) has NaN or inf coordinates — "
                                         r"remove the rows with NaN or inf$"):
        read_points_sample(path, 100)


@pytest.mark.parametrize("cap", [0, -3, 2.5, True, None])
def test_a_bad_cap_is_refused(cap, cloud, tmp_path):
    path = tmp_path / "scan.npy"
    write_points(path, *cloud)
    with pytest.raises(InputError, match=r"^max_points must be a whole number >= 1, got "):
        read_points_sample(path, cap)


def test_a_bad_text_line_in_a_later_chunk_is_named(cloud, tmp_path, small_chunks):
    points, _ = cloud
    lines = [" ".join(map(repr, p)) for p in points.tolist()]
    lines[2000] = "1.0 2.0 oops"
    path = tmp_path / "scan.xyz"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"line 2001 is not numeric \('1.0 2.0 oops'\)"):
        read_points_sample(path, 100)
    lines[2000] = "1.0 2.0 3.0 4.0"
    path.write_text("\n".join(lines[:1900]) + "\n" + "\n".join(line + " 0" for line in lines[1900:]) + "\n")
    with pytest.raises(InputError, match=r"line 1901 has 4 columns, earlier lines have 3"):
        read_points_sample(path, 100)


def test_ascii_ply_read_in_chunks_checks_its_count(cloud, tmp_path, small_chunks):
    points, _ = cloud
    path = tmp_path / "scan.ply"
    _write_ply(path, points, None, text=True)
    head, body = path.read_text().split("end_header\n")
    rows = body.splitlines()
    path.write_text(head + "end_header\n" + "\n".join(rows[:2500]) + "\n")
    with pytest.raises(InputError, match=r"PLY file is truncated \(header says 3000 vertices, data holds 2500\)"):
        read_points_sample(path, 100)
    path.write_text(head + "end_header\n" + "\n".join(rows + rows[:5]) + "\n")
    with pytest.raises(InputError, match=r"PLY header says 3000 vertices but more data follows"):
        read_points_sample(path, 100)
    # each value must be one of its declared type, as plyfile reads them: no missing value, no fraction
    # or out-of-range number for an integer
    for bad in ("1 2", "1 2 3 1.5", "1 2 3 70000", "1 2 3 4 5"):
        rows[1500] = bad
        path.write_text(head + "end_header\n" + "\n".join(rows) + "\n")
        with pytest.raises(InputError, match=rf"PLY vertex 1501 \('{bad}'\) is not one value of each type the "
                                             r"header declares \(double double double ushort\)"):
            read_points_sample(path, 100)
        with pytest.raises(InputError):
            read_points(path)


def test_labelled_chunks_are_the_file_written_at_once(cloud, tmp_path):
    points, _ = cloud
    rng = np.random.default_rng(SEED)
    label = rng.integers(-1, 4, len(points))
    distance = rng.normal(size=len(points))
    distance[::7] = np.inf  # unknown: written as NaN
    write_labelled_points(tmp_path / "whole.ply", points, label, distance)
    cuts = [0, 1, 500, 501, 2999, 3000]
    write_labelled_chunks(tmp_path / "chunks.ply", len(points),
                          ((points[a:b], label[a:b], distance[a:b]) for a, b in zip(cuts, cuts[1:])))
    assert (tmp_path / "chunks.ply").read_bytes() == (tmp_path / "whole.ply").read_bytes()
    vertex = plyfile.PlyData.read(str(tmp_path / "chunks.ply"))["vertex"]
    np.testing.assert_array_equal(np.column_stack([vertex["x"], vertex["y"], vertex["z"]]), points)
    np.testing.assert_array_equal(vertex["branch"], label)
    assert np.isnan(vertex["distance"][::7]).all()
    # chunks that hold other than the points announced leave no file
    for count in (len(points) - 1, len(points) + 1):
        with pytest.raises(InputError, match=rf"{count} points were to be labelled, the chunks held "
                                             r"(more|3000) — the input changed while it was read"):
            write_labelled_chunks(tmp_path / "bad.ply", count, [(points, label, distance)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["chunks.ply", "whole.ply"]


def test_streaming_a_laz_file_keeps_memory_bounded(tmp_path):
    """Peak memory (numpy's and laspy's buffers, as tracemalloc sees them) of the sample of a 2M-point LAZ
    file against reading it whole: a chunk and the sample, not the file."""
    n = 2_000_000
    rng = np.random.default_rng(SEED)
    path = tmp_path / "big.laz"
    # written in parts, so the test itself holds only one part of random points at a time
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = np.full(3, 0.001), np.zeros(3)
    with laspy.open(path, mode="w", header=header) as writer:
        for _ in range(4):
            record = laspy.ScaleAwarePointRecord.zeros(n // 4, header=header)
            record.x, record.y, record.z = rng.uniform(0, 100, size=(3, n // 4))
            writer.write_points(record)
    full_bytes = n * 3 * 8
    tracemalloc.start()
    try:
        sample = read_points_sample(path, 20_000, rng=0)
        _, streamed = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        points, _ = read_points(path)
        _, whole = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert (sample.total, len(sample.points), len(points)) == (n, 20_000, n)
    assert whole >= full_bytes  # the measure sees the arrays
    assert streamed < 0.3 * full_bytes, f"{streamed / 2**20:.1f} MB streamed, {full_bytes / 2**20:.0f} MB whole"


# --- the command line ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def pipe_file(tmp_path_factory):
    """The Figure 9 pipe (true radius 1), 12,000 points, as a LAZ file on a 0.1 mm grid."""
    tube = make_tube("fig9-pipe", n=12_000, rng=SEED)
    path = tmp_path_factory.mktemp("pipe") / "pipe.laz"
    _write_las(path, tube.points, scale=1e-4, offset=(0.0, 0.0, 0.0), chunk=5000)
    return path


@pytest.fixture(scope="module")
def full_run(pipe_file, tmp_path_factory):
    """The reconstruction of the whole file (it is below the command line's sample size)."""
    out = tmp_path_factory.mktemp("full")
    assert len(read_points(pipe_file)[0]) < cli.STREAM_POINTS
    assert cli.main(["reconstruct", str(pipe_file), "-o", str(out), "-q"]) == 0
    return load_model(out / "model.json")


def test_the_command_line_reconstructs_a_sample_of_a_large_file(pipe_file, full_run, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli, "STREAM_POINTS", 6000)
    monkeypatch.setattr(io, "_STREAM_CHUNK_POINTS", 1000)
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(pipe_file), "-o", str(out), "--labels", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert (record["points_read"], record["points_sampled"], record["sample_seed"], record["points"]) == (
        12_000, 6000, cli.STREAM_SEED, 6000)
    assert record["read_seconds"] > 0
    model = load_model(out / "model.json")
    assert model.kind == full_run.kind == "pipe"
    assert abs(model.mean_radius - full_run.mean_radius) < 0.01 * full_run.mean_radius
    assert abs(model.mean_radius - 1.0) < 0.01
    # every point of the file is labelled, as the model labels them all at once
    points, _ = read_points(pipe_file)
    vertex = plyfile.PlyData.read(str(out / "points.ply"))["vertex"]
    np.testing.assert_array_equal(np.column_stack([vertex["x"], vertex["y"], vertex["z"]]), points)
    label, distance = model.classify(points)
    np.testing.assert_array_equal(vertex["branch"], label)
    np.testing.assert_allclose(vertex["distance"], distance, rtol=0, atol=1e-9)
    assert (label >= 0).mean() > 0.95
    # the summary says what was read
    assert cli.main(["reconstruct", str(pipe_file), "-o", str(out)]) == 0
    assert capsys.readouterr().out.startswith(f"{pipe_file}: 6000 of 12000 points read (seeded sample); quality ")


def test_the_crop_box_comes_before_the_sample_and_the_labels_cover_it(pipe_file, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli, "STREAM_POINTS", 3000)
    monkeypatch.setattr(io, "_STREAM_CHUNK_POINTS", 1000)
    points, _ = read_points(pipe_file)
    half = float(np.median(points[:, 0]))
    box = (-100.0, -100.0, -100.0, half, 100.0, 100.0)
    inside, _ = crop(points, box)
    out = tmp_path / "out"
    argv = ["reconstruct", str(pipe_file), "-o", str(out), "--crop", ",".join(map(repr, box)), "--voxel", "0.05",
            "--labels", "--json"]
    assert cli.main(argv) == 0
    record = json.loads(capsys.readouterr().out)
    assert (record["points_read"], record["points_in_crop"], record["points_sampled"]) == (12_000, len(inside), 3000)
    assert record["points_after_voxel"] == record["points"] <= 3000
    vertex = plyfile.PlyData.read(str(out / "points.ply"))["vertex"]
    np.testing.assert_array_equal(np.column_stack([vertex["x"], vertex["y"], vertex["z"]]), inside)
    assert cli.main(argv[:-1]) == 0
    assert (f": {len(inside)} of 12000 points in the crop box; 3000 of {len(inside)} points read (seeded sample); "
            f"{record['points']} of 3000 points left by --voxel 0.05; ") in capsys.readouterr().out


def test_a_file_with_nan_fails_with_one_line(tmp_path, capsys):
    points = make_tube("fig9-pipe", n=500, rng=1).points
    points[321] = np.nan
    path = tmp_path / "nan.npy"
    np.save(path, points)
    assert cli.main(["reconstruct", str(path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err == (f"canalsurf: error: {path}: point 321 (counting from 0) has NaN or inf coordinates — remove the "
                   "rows with NaN or inf\n")
    assert not (tmp_path / "out").exists()
