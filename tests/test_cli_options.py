"""Tests of the command line's newer options, run in-process through ``main(argv)``: ``--units`` and the
CAD/BIM exports (``--ifc --step --piping --catalogue``), ``--crop`` and ``--voxel``, ``canalsurf info``,
the note about files not written, and what a run imports.

The export modules (:mod:`canalsurf.ifc`, :mod:`canalsurf.step`, :mod:`canalsurf.piping`) are stood in
for by recording fakes: these tests check what the command line hands them and how it writes their
files, not the formats themselves.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import make_interp_spline

from canalsurf import cli, load_model
from canalsurf.errors import InputError
from canalsurf.io import write_points
from canalsurf.model import CanalModel
from canalsurf.network import Network
from canalsurf.pipeline import STAGES
from canalsurf.pointcloud import crop, point_spacing, voxel_downsample
from canalsurf.spine import constant_spline
from canalsurf.synth import make_tube

#: The cloud of these tests: the paper's Figure 9 pipe (true radius 1), with its true normals.
CLOUD = ("fig9-pipe", 2000, 1)
#: The files every reconstruction writes (with the 'dxf' extra installed, as for the tests).
BASE_FILES = {"model.json", "surface.ply", "spine.csv", "spine.dxf"}
#: What the notes say of a run without --units.
NO_UNITS = "no --units given: spine.dxf is unitless"
GIVE_UNITS = " — give --units m|mm|ft|in to state the unit of the input's coordinates"


def _error_line(err: str) -> str:
    """The single stderr line of an expected failure (fails unless there is exactly one)."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("canalsurf: error: ") and "Traceback" not in err, err
    return lines[0]


def _names(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir()} - {".canalsurf-manifest.json"}


@pytest.fixture(scope="module")
def truth():
    return make_tube(CLOUD[0], n=CLOUD[1], rng=CLOUD[2])


@pytest.fixture(scope="module")
def cloud(tmp_path_factory, truth) -> Path:
    """The Figure 9 pipe as a PLY with normals."""
    path = tmp_path_factory.mktemp("cloud") / "pipe.ply"
    write_points(path, truth.points, truth.normals)
    return path


@pytest.fixture
def seen(monkeypatch) -> list:
    """Stand in for the pipeline: record the (points, normals) it is given, return a straight pipe at once."""
    calls = []

    def reconstruct(points, *, normals=None, progress=None, **kwargs):
        calls.append((np.array(points), None if normals is None else np.array(normals)))
        for stage in STAGES:
            progress(stage)
        u = np.linspace(0.0, 1.0, 5)
        spine = make_interp_spline(u, np.column_stack([10 * u, 0 * u, 0 * u]), k=3)
        return Network([CanalModel("pipe", spine, constant_spline(1.0), False)], [], {"R": 0.5},
                       {"n_points": len(points)})

    monkeypatch.setattr("canalsurf.pipeline.reconstruct", reconstruct)
    return calls


@pytest.fixture
def never(monkeypatch):
    def reconstruct(*args, **kwargs):
        raise AssertionError("reconstruction should not start")

    monkeypatch.setattr("canalsurf.pipeline.reconstruct", reconstruct)


@pytest.fixture
def exports(monkeypatch) -> dict:
    """Recording stand-ins for canalsurf.ifc, canalsurf.step and canalsurf.piping; name -> call."""
    calls = {}
    pieces = ["pipe NPS 2 x 10", "cap"]

    def decompose(network, points=None, *, units, catalogue):
        # the pieces are fitted to the points reconstructed: record how many were given
        calls["decompose"] = {"network": network, "points": None if points is None else len(points), "units": units,
                              "catalogue": catalogue}
        return pieces

    def write_pipes_csv(path, given, *, units):
        calls["write_pipes_csv"] = {"name": path.name, "pieces": given, "units": units}
        path.write_text("piece\n" + "\n".join(given) + "\n")

    def write_ifc(path, network, *, units, pieces=None):
        calls["write_ifc"] = {"name": path.name, "network": network, "units": units, "pieces": pieces}
        path.write_text("ISO-10303-21;\n")

    def write_step(path, network, *, units):
        calls["write_step"] = {"name": path.name, "network": network, "units": units}
        path.write_text("ISO-10303-21;\n")

    for name, functions in (("piping", [decompose, write_pipes_csv]), ("ifc", [write_ifc]), ("step", [write_step])):
        module = types.ModuleType(f"canalsurf.{name}")
        for function in functions:
            setattr(module, function.__name__, function)
        monkeypatch.setitem(sys.modules, f"canalsurf.{name}", module)
    calls["pieces"] = pieces
    return calls


# --- --units ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("units, insunits", [(None, 0), ("m", 6), ("mm", 4), ("ft", 2), ("in", 1)])
def test_units_are_declared_in_spine_dxf(units, insunits, cloud, tmp_path, capsys, seen):
    ezdxf = pytest.importorskip("ezdxf")
    argv = ["reconstruct", str(cloud), "-o", str(tmp_path)] + ([] if units is None else ["--units", units])
    assert cli.main(argv) == 0
    assert ezdxf.readfile(tmp_path / "spine.dxf").header["$INSUNITS"] == insunits
    out = capsys.readouterr().out
    # without a unit the summary says the drawing is unitless; with one there is nothing to say
    assert (f"\nnote: {NO_UNITS}{GIVE_UNITS}\n" in out) == (units is None)
    assert cli.main([*argv, "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["units"] == units and record["not_written"] == {}
    assert record["notes"] == ([f"{NO_UNITS}{GIVE_UNITS}"] if units is None else [])
    assert "units" not in json.loads((tmp_path / "model.json").read_text())  # model.json is left as it is


def test_demo_takes_units_and_exports(tmp_path, capsys, seen, exports):
    ezdxf = pytest.importorskip("ezdxf")
    assert cli.main(["demo", "-o", str(tmp_path), "--units", "in", "--piping", "--catalogue", "en"]) == 0
    assert ezdxf.readfile(tmp_path / "spine.dxf").header["$INSUNITS"] == 1
    assert _names(tmp_path) == BASE_FILES | {"input.ply", "pipes.csv"}
    assert exports["decompose"]["units"] == "in" and exports["decompose"]["catalogue"] == "en"
    assert exports["decompose"]["points"] == cli.DEMO_POINTS
    out = capsys.readouterr().out
    assert "pipes.csv" in out and "note" not in out


# --- --ifc, --step, --piping -----------------------------------------------------------------------


def test_exports_are_written_with_the_rest(cloud, tmp_path, capsys, seen, exports):
    argv = ["reconstruct", str(cloud), "-o", str(tmp_path), "--ifc", "--step", "--piping", "--units", "mm",
            "--catalogue", "en"]
    assert cli.main(argv) == 0
    assert _names(tmp_path) == BASE_FILES | {"model.ifc", "model.step", "pipes.csv"}
    network = exports["decompose"]["network"]
    assert isinstance(network, Network) and network.branches[0].mean_radius == 1.0
    assert exports["decompose"] == {"network": network, "points": network.diagnostics["n_points"], "units": "mm",
                                    "catalogue": "en"}
    # pipes.csv and model.ifc are made of the same pieces, decomposed once
    assert exports["write_pipes_csv"] == {"name": "pipes.csv", "pieces": exports["pieces"], "units": "mm"}
    assert exports["write_ifc"] == {"name": "model.ifc", "network": network, "units": "mm",
                                    "pieces": exports["pieces"]}
    assert exports["write_step"] == {"name": "model.step", "network": network, "units": "mm"}
    assert (tmp_path / "pipes.csv").read_text() == "piece\npipe NPS 2 x 10\ncap\n"
    out = capsys.readouterr().out
    assert "model.ifc" in out and "model.step" in out and "pipes.csv" in out and "note" not in out
    assert load_model(tmp_path / "model.json").kind == "pipe"


def test_exports_without_units_assume_metres_and_say_so(cloud, tmp_path, capsys, seen, exports):
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path), "--ifc", "--piping"]) == 0
    assert exports["decompose"]["units"] == exports["write_ifc"]["units"] == "m"
    assert exports["decompose"]["catalogue"] == "asme"  # the default catalogue
    assert "write_step" not in exports
    assert capsys.readouterr().out.endswith(
        f"\nnote: {NO_UNITS}; model.ifc and pipes.csv assume metres{GIVE_UNITS}\n")


def test_ifc_alone_is_built_without_pieces(cloud, tmp_path, seen, exports):
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path), "--ifc", "--units", "ft", "-q"]) == 0
    assert exports["write_ifc"]["pieces"] is None and exports["write_ifc"]["units"] == "ft"
    assert "decompose" not in exports
    assert _names(tmp_path) == BASE_FILES | {"model.ifc"}


#: The one line of an export whose extra is missing.
MISSING = {"--ifc": "--ifc (writing model.ifc) needs the 'ifc' extra — pip install 'canalsurf[ifc]'",
           "--step": "--step (writing model.step) needs the 'step' extra — pip install 'canalsurf[step]'",
           "--piping": "--piping (writing pipes.csv) needs the module canalsurf.piping, which cannot be imported — "
                       "reinstall canalsurf"}


@pytest.mark.parametrize("option", MISSING)
def test_an_export_module_that_cannot_be_imported_fails_before_any_work(option, cloud, tmp_path, capsys,
                                                                         monkeypatch, never):
    monkeypatch.setitem(sys.modules, f"canalsurf.{option[2:]}", None)  # the import fails
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), option]) == 2
    captured = capsys.readouterr()
    assert _error_line(captured.err) == f"canalsurf: error: {MISSING[option]}"
    assert captured.out == "" and not out.exists()


@pytest.mark.parametrize("option, library", [("--ifc", "ifcopenshell"), ("--step", "OCP")])
@pytest.mark.parametrize("stand_in", [True, False], ids=["stand-in", "real-module"])
def test_a_missing_library_fails_before_any_work(option, library, stand_in, cloud, tmp_path, capsys, monkeypatch,
                                                 never, request):
    """The writers import their library only when writing: the command line looks it up first."""
    if stand_in:
        request.getfixturevalue("exports")
    monkeypatch.setitem(sys.modules, library, None)  # as if not installed
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), option, "--units", "mm"]) == 2
    assert _error_line(capsys.readouterr().err) == f"canalsurf: error: {MISSING[option]}"
    assert not out.exists()


def test_an_export_failing_while_writing_leaves_nothing(cloud, tmp_path, capsys, seen, exports):
    def write_step(path, network, *, units):
        path.write_text("half")
        raise InputError("writing STEP files needs the 'step' extra — pip install 'canalsurf[step]'")

    sys.modules["canalsurf.step"].write_step = write_step
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "--step", "--piping"]) == 2
    assert _error_line(capsys.readouterr().err) == (
        f"canalsurf: error: {cloud}: writing STEP files needs the 'step' extra — pip install 'canalsurf[step]'")
    assert not out.exists()  # not even pipes.csv or model.json: all or nothing


def test_ifc_end_to_end_in_the_unit_given(cloud, tmp_path, capsys):
    """The real canalsurf.ifc, through the command line: the project's length unit is --units."""
    ifcopenshell = pytest.importorskip("ifcopenshell")
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path), "--ifc", "--units", "mm", "-q"]) == 0
    model = ifcopenshell.open(str(tmp_path / "model.ifc"))
    (assignment,) = model.by_type("IfcUnitAssignment")
    length = [u for u in assignment.Units if u.UnitType == "LENGTHUNIT"]
    assert [(u.Prefix, u.Name) for u in length] == [("MILLI", "METRE")]
    assert len(model.by_type("IfcPipeSegment")) >= 1
    assert _names(tmp_path) == BASE_FILES | {"model.ifc"}


def test_catalogue_without_piping_is_refused(cloud, tmp_path, capsys, never, exports):
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path / "out"), "--catalogue", "en"]) == 2
    assert _error_line(capsys.readouterr().err) == (
        "canalsurf: error: --catalogue chooses the pipe sizes of --piping: add --piping — see "
        "'canalsurf reconstruct --help'")


# --- --crop, --voxel -------------------------------------------------------------------------------


def test_crop_gives_the_reconstruction_the_points_inside(cloud, truth, tmp_path, capsys, seen):
    box = (-10.0, -10.0, -10.0, 10.0, 0.0, 10.0)  # y <= 0: part of the pipe
    argv = ["reconstruct", str(cloud), "-o", str(tmp_path), "--crop", ",".join(map(str, box)), "--json"]
    assert cli.main(argv) == 0
    (points, normals), = seen
    expected, expected_normals = crop(truth.points, box, normals=truth.normals)
    assert 200 < len(expected) < 1900
    np.testing.assert_array_equal(points, expected)
    np.testing.assert_array_equal(normals, expected_normals)
    record = json.loads(capsys.readouterr().out)
    assert (record["points_read"], record["crop"], record["points_in_crop"], record["points"]) == (
        2000, list(box), len(expected), len(expected))
    assert cli.main(argv[:-1]) == 0
    assert f": {len(expected)} of 2000 points in the crop box; pipe, radius 1" in capsys.readouterr().out


def test_crop_with_a_negative_corner_needs_no_equals_sign(cloud, tmp_path, seen):
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path), "--crop", "-100,-100,-1e2,100,100,100", "-q"]) == 0
    assert len(seen[0][0]) == 2000
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path), "--crop=-100,-100,-100,100,100,0", "-q"]) == 0
    assert len(seen[1][0]) == np.sum(seen[0][0][:, 2] <= 0)


@pytest.mark.parametrize("text, problem", [
    ("1,2,3", "expected xmin,ymin,zmin,xmax,ymax,zmax (six numbers separated by commas), got '1,2,3'"),
    ("a,b,c,d,e,f", "expected xmin,ymin,zmin,xmax,ymax,zmax (six numbers separated by commas), got 'a,b,c,d,e,f'"),
    ("0,0,0,1,1,inf", "expected xmin,ymin,zmin,xmax,ymax,zmax (six numbers separated by commas), got '0,0,0,1,1,inf'"),
    ("0,0,5,1,1,1", "zmin 5 is larger than zmax 1 in '0,0,5,1,1,1': give the lower corner first, "
                    "xmin,ymin,zmin,xmax,ymax,zmax"),
])
def test_a_bad_crop_box_is_a_usage_error(text, problem, cloud, tmp_path, capsys, never):
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "--crop", text]) == 2
    captured = capsys.readouterr()
    assert _error_line(captured.err) == (f"canalsurf: error: argument --crop: {problem} — see "
                                         "'canalsurf reconstruct --help'")
    assert captured.out == "" and not out.exists()


def test_a_crop_box_missing_the_points(cloud, truth, tmp_path, capsys, never):
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "--crop", "100,100,100,101,101,101"]) == 2
    lo, hi = truth.points.min(axis=0), truth.points.max(axis=0)
    span = ", ".join(f"{a} {lo[i]:.6g}..{hi[i]:.6g}" for i, a in enumerate("xyz"))
    assert _error_line(capsys.readouterr().err) == (
        f"canalsurf: error: {cloud}: no points inside the crop box 100,100,100,101,101,101 (the points span "
        f"{span}) — give a box that overlaps them ('canalsurf info {cloud}')")
    assert not out.exists()


def test_voxel_gives_the_reconstruction_one_point_per_voxel(cloud, truth, tmp_path, capsys, seen):
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path), "--voxel", "0.5"]) == 0
    (points, normals), = seen
    expected, expected_normals = voxel_downsample(truth.points, 0.5, normals=truth.normals)
    assert 300 < len(expected) < 1500
    np.testing.assert_array_equal(points, expected)
    np.testing.assert_array_equal(normals, expected_normals)  # each point with its own normal
    assert f": {len(expected)} of 2000 points left by --voxel 0.5; pipe" in capsys.readouterr().out


def test_crop_comes_before_voxel(cloud, truth, tmp_path, capsys, seen):
    box = (-10.0, -10.0, -10.0, 10.0, 10.0, 0.0)
    argv = ["reconstruct", str(cloud), "-o", str(tmp_path), "--voxel", "0.4", "--crop", "-10,-10,-10,10,10,0", "--json"]
    assert cli.main(argv) == 0
    inside, inside_normals = crop(truth.points, box, normals=truth.normals)
    expected, _ = voxel_downsample(inside, 0.4, normals=inside_normals)
    np.testing.assert_array_equal(seen[0][0], expected)
    record = json.loads(capsys.readouterr().out)
    assert (record["points_read"], record["points_in_crop"], record["voxel"], record["points_after_voxel"],
            record["points"]) == (2000, len(inside), 0.4, len(expected), len(expected))


def test_labels_cover_every_point_in_the_crop_box_even_with_voxel(cloud, truth, tmp_path, seen):
    plyfile = pytest.importorskip("plyfile")
    box = (-10.0, -10.0, -10.0, 10.0, 10.0, 0.0)
    argv = ["reconstruct", str(cloud), "-o", str(tmp_path), "--crop", "-10,-10,-10,10,10,0", "--voxel", "0.5",
            "--labels", "-q"]
    assert cli.main(argv) == 0
    inside, _ = crop(truth.points, box)
    assert len(seen[0][0]) < len(inside)  # the reconstruction had the thinned points ...
    vertex = plyfile.PlyData.read(str(tmp_path / "points.ply"))["vertex"]
    labelled = np.column_stack([vertex["x"], vertex["y"], vertex["z"]])
    np.testing.assert_array_equal(labelled, inside)  # ... the labels cover them all


def test_a_voxel_leaving_too_few_points(cloud, truth, tmp_path, capsys, never):
    kept = len(voxel_downsample(truth.points, 8.0)[0])
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path / "out"), "--voxel", "8"]) == 2
    assert _error_line(capsys.readouterr().err) == (
        f"canalsurf: error: {cloud}: only {kept} of 2000 points are left after --voxel 8, fewer than the 50 a "
        "reconstruction needs — give a smaller --voxel")


def test_voxel_thins_a_dense_scan_without_changing_the_result(tmp_path, capsys):
    """The real pipeline on a 4x denser Figure 9 pipe, thinned back to about the paper's density."""
    dense = make_tube("fig9-pipe", n=8000, rng=2)
    path = tmp_path / "dense.ply"
    write_points(path, dense.points, None)
    assert cli.main(["reconstruct", str(path), "-o", str(tmp_path / "out"), "--voxel", "0.5", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert 1000 < record["points"] < 3000
    model = load_model(tmp_path / "out" / "model.json")
    assert model.kind == "pipe" and abs(model.mean_radius - 1.0) < 0.02  # true radius 1, noise ±0.1
    assert json.loads((tmp_path / "out" / "model.json").read_text())["diagnostics"]["n_points"] == record["points"]


# --- info ------------------------------------------------------------------------------------------


def test_info_describes_a_file(cloud, truth, capsys):
    assert cli.main(["info", str(cloud)]) == 0
    captured = capsys.readouterr()
    lo, hi = truth.points.min(axis=0), truth.points.max(axis=0)
    spacing = point_spacing(truth.points)
    assert captured.err == ""
    assert captured.out.splitlines() == [
        f"{cloud}: PLY, binary little-endian; 2000 points, with normals",
        "  bounding box   " + ", ".join(f"{a} {lo[i]:.6g} .. {hi[i]:.6g}" for i, a in enumerate("xyz"))
        + f"  (size {' x '.join(f'{d:.4g}' for d in hi - lo)})",
        f"  spacing        {spacing:.4g}  (median distance to the nearest point, over all 2000 points)",
        "  fields         x y z nx ny nz",
    ]
    assert 0.05 < spacing < 0.5  # 2000 points on a pipe of radius 1 and length about 28


def test_info_json_of_several_files_one_bad(truth, tmp_path, capsys):
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = np.full(3, 0.001), np.array([1e6, 2e6, 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = (truth.points + [1e6, 2e6, 0.0]).T
    las.classification = np.full(len(truth.points), 2, dtype=np.uint8)
    las.write(tmp_path / "scan.las")
    text = tmp_path / "gaps.xyz"
    text.write_text("0 0 0\n1 0 0\nnan 0 0\n0 2 0\n")
    missing = tmp_path / "missing.ply"
    assert cli.main(["info", str(tmp_path / "scan.las"), str(missing), str(text), "--json"]) == 2
    captured = capsys.readouterr()
    scan, bad, gaps = (json.loads(line) for line in captured.out.splitlines())
    assert _error_line(captured.err) == f"canalsurf: error: {missing}: file not found — check the path"
    assert bad == {"input": str(missing), "error": f"{missing}: file not found — check the path", "exit_code": 2}
    assert scan["format"] == "LAS, version 1.2, point format 3" and scan["points"] == 2000
    assert scan["normals"] is False and {"intensity", "classification", "gps_time"} <= set(scan["fields"])
    np.testing.assert_allclose(scan["bounds"]["min"], truth.points.min(axis=0) + [1e6, 2e6, 0], atol=6e-4)
    np.testing.assert_allclose(scan["size"], np.ptp(truth.points, axis=0), atol=1.1e-3)
    assert scan["spacing"] == pytest.approx(point_spacing(truth.points), rel=0.02)  # on the file's mm grid
    assert (gaps["points"], gaps["non_finite_points"], gaps["bounds"], gaps["spacing"]) == (
        4, 1, {"min": [0.0, 0.0, 0.0], "max": [1.0, 2.0, 0.0]}, 1.0)
    assert gaps["fields"] == ["x", "y", "z"] and gaps["format"] == "text, space separated"


def test_info_says_what_it_left_out(tmp_path, capsys):
    text = tmp_path / "gaps.csv"
    text.write_text("x,y,z\n0,0,0\ninf,0,0\n")
    assert cli.main(["info", str(text)]) == 0
    assert capsys.readouterr().out.splitlines()[1:] == [
        "  not finite     1 points with NaN or inf coordinates (left out below; a reconstruction refuses them)",
        "  bounding box   x 0 .. 0, y 0 .. 0, z 0 .. 0  (size 0 x 0 x 0)",
        "  spacing        —  (median distance to the nearest point, over all 1 points)",
        "  fields         x y z",
    ]


# --- what a run imports ----------------------------------------------------------------------------


#: Modules a reconstruction into model.json, surface.ply, spine.csv and spine.dxf never needs.
NOT_NEEDED = ("canalsurf.synth", "canalsurf.report", "canalsurf.ifc", "canalsurf.step", "canalsurf.piping",
              "tqdm", "plotly", "matplotlib", "trimesh", "laspy", "jsonschema")


def _modules_after(argv: list[str], cwd: Path) -> set[str]:
    """The modules loaded by ``main(argv)`` in a fresh interpreter (stdout and stderr not a terminal)."""
    code = ("import sys; from canalsurf.cli import main; code = main(sys.argv[1:]); "
            "print('\\n'.join(sorted(sys.modules)), file=sys.stderr); sys.exit(code)")
    done = subprocess.run([sys.executable, "-c", code, *argv], cwd=cwd, capture_output=True, text=True,
                          timeout=120, env={**os.environ, "PYTHONWARNINGS": "error"})
    assert done.returncode == 0, done.stderr
    return set(done.stderr.split())


def test_a_reconstruction_imports_only_what_it_needs(cloud, tmp_path):
    loaded = _modules_after(["reconstruct", str(cloud), "-o", str(tmp_path / "out"), "-q"], tmp_path)
    assert "canalsurf.pipeline" in loaded and "scipy.spatial" in loaded  # it did reconstruct
    assert sorted(loaded & set(NOT_NEEDED)) == []


def test_help_and_info_import_no_reconstruction(cloud, tmp_path):
    loaded = _modules_after(["info", str(cloud), "-q"], tmp_path)
    assert "scipy.spatial" in loaded  # the spacing
    assert sorted(loaded & {"canalsurf.pipeline", "canalsurf.synth", "scipy.interpolate", "ezdxf", *NOT_NEEDED}) == []
    loaded = _modules_after(["--version"], tmp_path)
    assert sorted(loaded & {"scipy", "canalsurf.synth", "canalsurf.pipeline"}) == []
