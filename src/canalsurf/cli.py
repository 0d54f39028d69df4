"""The ``canalsurf`` command: a thin shell over :func:`canalsurf.reconstruct` and the writers.

``main(argv) -> int`` parses the arguments, runs one subcommand handler and returns the exit code; it is
the only place in canalsurf that prints, configures logging and shows progress bars.

Subcommands
    ``demo``         reconstruct the built-in Figure 9 pipe and compare with the truth (no input needed);
    ``reconstruct``  point files -> model.json, surface mesh, spine.csv, spine.dxf; on request report.html,
                     points.ply, model.ifc, model.step, pipes.csv;
    ``info``         what point files hold: points, bounding box, spacing, fields;
    ``synth``        write a sampled test surface as a point file;
    ``paper``        reproduce the paper's experiments (:mod:`canalsurf.experiments`).

Slow imports wait until they are needed: SciPy's interpolation and the pipeline only for a
reconstruction, :mod:`canalsurf.synth` only for ``synth`` and ``demo``, tqdm only for a progress bar
on a terminal, the CAD/BIM writers only when asked for -- ``canalsurf --help`` or ``info`` on a small
file does not pay for a reconstruction.

Exit codes
    0 success; 1 a reconstruction failed (:class:`ReconstructionError`, or an unexpected internal
    error, reported as ``internal error (<type>: <message>) — please report it``, with its traceback
    under ``-v``); 2 bad input, bad output path or bad usage (:class:`InputError`, ``OSError`` on
    output, argparse errors); 130 interrupted (Ctrl-C), 143 terminated (SIGTERM), see
    :mod:`canalsurf._interrupt`.  With several inputs each succeeds or fails on its own and the code
    is the highest of the failures'.  Every failure prints one line
    ``canalsurf: error: <what> — <what to do>`` to stderr, never a traceback.

Outputs
    Each result folder is written as one unit, under a lock (:mod:`canalsurf._outputs`); files an
    earlier run wrote there and this run does not write (report.html without ``--report``) are
    removed.  Folder names made from input names are made safe (no ``..``, separators or names
    Windows reserves) and every folder is checked to lie inside ``-o``.  The reports of several
    inputs share one ``plotly.min.js`` in ``-o`` (written before the first of them) instead of each
    holding its own copy; a single report holds its own and stands alone.  What a run does not
    write and why (spine.dxf without ezdxf; no unit declared) is said in notes after the summary
    lines, and in each ``--json`` record (``not_written``, ``notes``).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import json
import logging
import math
import os
import re
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NamedTuple

import numpy as np

from . import __version__
from ._interrupt import INTERRUPTED
from ._outputs import check_output_folder as _check_output_folder
from ._outputs import make_dirs as _make_dirs
from ._outputs import remove_dirs as _remove_dirs
from ._outputs import write_files as _write_files
from .errors import CanalsurfError, InputError, ReconstructionError
from .io import POINT_WRITE_FORMATS, write_points

__all__ = ["main", "build_parser"]

log = logging.getLogger(__name__)

PROG = "canalsurf"
#: Exit codes (module docstring).
EXIT_OK, EXIT_FAILED, EXIT_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
#: The built-in example of ``canalsurf demo``: the paper's Figure 9 pipe, as the paper sampled it.
DEMO_SURFACE, DEMO_POINTS, DEMO_SEED, DEMO_OUTDIR = "fig9-pipe", 2000, 0, "canalsurf-demo"
#: Largest length (-R, --delta, -H) accepted, in the input's units.  float64 keeps about 16 significant
#: digits, so coordinates near 1e15 have no digit left below 0.1 units: no scan measures lengths
#: beyond this, and anything larger is a typo (1e308 overflows as soon as it is squared).
MAX_LENGTH = 1e15
#: Mesh formats offered by ``--mesh-format`` (suffixes of :data:`canalsurf.io.MESH_FORMATS`).
MESH_CHOICES = ("ply", "obj", "stl", "glb", "off")
#: Length units of ``--units`` (their DXF codes are :data:`canalsurf.io.DXF_UNITS`).
UNITS = ("m", "mm", "ft", "in")
#: The unit model.ifc, model.step and pipes.csv take without ``--units``: those formats need a real
#: one (an IFC project declares its length unit, pipe sizes are millimetres or inches), so they
#: assume metres, and the summary says so.
DEFAULT_EXPORT_UNITS = "m"
#: Pipe catalogues of ``--catalogue`` (:func:`canalsurf.piping.decompose`), the first the default.
CATALOGUES = ("asme", "en")


class _Export(NamedTuple):
    """A CAD/BIM file the command line can write, and what writing it needs."""

    file: str                    # the file written
    module: str                  # the module of canalsurf that writes it, imported only when asked for
    extra: str | None            # the extra that installs its libraries (None: needs nothing optional)
    libraries: tuple[str, ...]   # those libraries, looked up (not imported) before any work


#: The CAD/BIM exports by option.  The writers import their libraries only when they write, so the
#: libraries are looked up here first: a missing extra fails in a moment, not after the reconstruction.
EXPORTS = {"ifc": _Export("model.ifc", "ifc", "ifc", ("ifcopenshell",)),
           "step": _Export("model.step", "step", "step", ("OCP",)),
           "piping": _Export("pipes.csv", "piping", None, ())}
#: What a note says of spine.dxf when ezdxf is not installed.
DXF_MISSING = "needs the 'dxf' extra (pip install 'canalsurf[dxf]')"
#: The bounding box of ``--crop``, as it is typed.
CROP_FORMAT = "xmin,ymin,zmin,xmax,ymax,zmax"
#: Most points ``reconstruct`` keeps of a file (inside ``--crop``): a larger file is read in chunks
#: and a seeded uniform random sample of this many is reconstructed (canalsurf.io.read_points_sample),
#: so memory stays bounded whatever the file's size.  The pipeline itself works on random subsets of
#: its input: at most 30,000 points for its stages and fit (constants.MAX_FIT_POINTS) and 200,000 for
#: the residuals (MAX_RESIDUAL_POINTS).  Drawn from a sample 67 and 10 times as large, they are still
#: uniform random subsets of the scan, so the result is statistically that of the whole file; the
#: sample takes 48 MB as float64 coordinates (96 MB with normals), and --voxel still has a dense
#: cloud to thin.
STREAM_POINTS = 2_000_000
#: Seed of that sample: the same file always gives the same sample, and so the same model.
STREAM_SEED = 0


class _UsageError(Exception):
    """An argparse usage error, raised instead of argparse's print-usage-and-exit."""

    def __init__(self, message: str, prog: str):
        super().__init__(message)
        self.prog = prog


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors become one ``canalsurf: error:`` line (see :func:`main`).

    ``complete(parser)``, if given, fills in what needs a slow import (the synth command's list of
    surfaces) the first time this parser parses or shows its help, so other commands never pay for it.
    """

    def __init__(self, *args, complete: Callable[[argparse.ArgumentParser], None] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self._complete = complete

    def _completed(self) -> None:
        if self._complete is not None:
            complete, self._complete = self._complete, None
            complete(self)

    def parse_known_args(self, args=None, namespace=None):  # noqa: D102 -- argparse hook
        self._completed()
        args = _join_number_lists(sys.argv[1:] if args is None else list(args))
        return super().parse_known_args(args, namespace)

    def format_help(self):  # noqa: D102 -- argparse hook
        self._completed()
        return super().format_help()

    def error(self, message):  # noqa: D102 -- argparse hook
        raise _UsageError(" ".join(str(message).split()), self.prog)

    def _get_values(self, action, arg_strings):  # noqa: D102 -- argparse hook
        # '-k=--': argparse (3.11, 3.12) drops the '--' and stores an empty list, unconverted
        if action.option_strings and action.nargs is None and arg_strings == ["--"]:
            self.error(f"argument {'/'.join(action.option_strings)}: expected one argument, got '--'")
        return super()._get_values(action, arg_strings)


# --------------------------------------------------------------------------------------------------
# argument parsing


def _number(kind: type, *, low: float | None = None, high: float | None = None, strict: bool = False,
            what: str = "a number") -> Callable[[str], float]:
    """argparse ``type=`` for a finite number in a range (usage error before any work is done)."""

    def convert(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if not math.isfinite(value) or (low is not None and (value <= low if strict else value < low)) \
                or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        if value and abs(value) < sys.float_info.min:  # subnormal: most digits lost, 1/value overflows
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}, too small to compute with "
                                             f"(below {sys.float_info.min:.4g})")
        return value

    return convert


_LENGTH = _number(float, low=0.0, strict=True, high=MAX_LENGTH,
                  what=f"a positive length up to {MAX_LENGTH:g}")


def _output_folder(text: str) -> Path:
    """argparse ``type=`` for an output folder: an empty path would mean the current folder."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected a folder, got {text!r} (for the current folder "
                                         "give '-o .')")
    return Path(text)


def _crop_box(text: str) -> tuple[float, ...]:
    """argparse ``type=`` for ``--crop``: six finite numbers, each minimum at most its maximum."""
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected {CROP_FORMAT} (six numbers separated by commas), got "
                                         f"{text!r}")
    for axis, low, high in zip("xyz", values[:3], values[3:]):
        if low > high:
            raise argparse.ArgumentTypeError(f"{axis}min {low:g} is larger than {axis}max {high:g} in {text!r}: "
                                             f"give the lower corner first, {CROP_FORMAT}")
    return values


#: Options whose value is a list of numbers that may start with a minus sign (``--crop -5,0,0,...``):
#: argparse would take such a value for an option.
_NUMBER_LIST_OPTIONS = ("--crop",)


def _join_number_lists(argv: list[str]) -> list[str]:
    """``--crop -5,...`` as ``--crop=-5,...``, so a negative lower corner needs no ``=``."""
    joined, i = [], 0
    while i < len(argv):
        word = argv[i]
        if word in _NUMBER_LIST_OPTIONS and i + 1 < len(argv) and re.match(r"-[0-9.]", argv[i + 1]):
            joined.append(f"{word}={argv[i + 1]}")
            i += 2
        else:
            joined.append(word)
            i += 1
    return joined


def _add_export_options(parser: argparse.ArgumentParser) -> None:
    """--units and the CAD/BIM files, shared by reconstruct and demo."""
    g = parser.add_argument_group("units, CAD and BIM files")
    g.add_argument("--units", choices=UNITS,
                   help="length unit of the input's coordinates: declared in spine.dxf ($INSUNITS) so CAD "
                        "inserts it at scale, and the unit of model.ifc, model.step and pipes.csv (default: "
                        "none given -- spine.dxf is unitless, and those three assume metres, as the "
                        "summary says)")
    g.add_argument("--ifc", action="store_true",
                   help="also write model.ifc: the network as IFC pipe segments and fittings for BIM "
                        "(needs the 'ifc' extra: pip install 'canalsurf[ifc]')")
    g.add_argument("--step", action="store_true",
                   help="also write model.step: the surfaces as a STEP solid model for CAD (needs the "
                        "'step' extra: pip install 'canalsurf[step]')")
    g.add_argument("--piping", action="store_true",
                   help="also write pipes.csv: the network as a list of straight pipes and fittings of "
                        "nominal sizes (--catalogue); with --ifc, model.ifc is built from the same pieces")
    g.add_argument("--catalogue", choices=CATALOGUES,
                   help=f"pipe sizes of --piping: asme (NPS, inches) or en (DN, millimetres); default "
                        f"{CATALOGUES[0]}")


def _add_global_options(parser: argparse.ArgumentParser, *, in_subcommand: bool) -> None:
    """-v / -q / --json, accepted before and after the subcommand.

    In a subcommand the defaults are suppressed, so an option given before the subcommand is not
    overwritten by the subcommand's default.
    """
    group = parser.add_argument_group("general options")
    default = {"default": argparse.SUPPRESS} if in_subcommand else {}
    group.add_argument("-v", "--verbose", action="count", **({"default": 0} | default),
                       help="log what was decided (parameters chosen, iterations, stop rule, timings) "
                            "to stderr")
    group.add_argument("-q", "--quiet", action="store_true", **({"default": False} | default),
                       help="no progress bar, no summary, no warnings; errors are still reported")
    group.add_argument("--json", action="store_true", **({"default": False} | default),
                       help="print a machine-readable summary to stdout instead of the human one: "
                            "one JSON object per line (per input)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``canalsurf`` command."""
    fmt = argparse.RawDescriptionHelpFormatter
    parser = _Parser(
        prog=PROG, formatter_class=fmt,
        description="Reconstruct pipe and canal surfaces (a B-spline spine and a radius) from unorganized "
                    "3D point clouds, by shrinking the points onto the spine and thinning them with "
                    "moving least squares.",
        epilog="examples:\n"
               "  canalsurf demo                                # try it: no input needed\n"
               "  canalsurf reconstruct scan.ply -o out/         # model.json, surface.ply, spine.csv\n"
               "  canalsurf reconstruct *.las -o results/ -v     # one folder per input, with a log\n"
               "  canalsurf info scan.laz                        # points, extent, spacing, fields\n"
               "  canalsurf synth fig14-canal -o canal.ply       # a test cloud\n"
               "  canalsurf synth --list\n\n"
               "exit codes: 0 success, 1 reconstruction failed (not a tube) or an internal error, 2 bad "
               "input, output path or usage, 130/143 interrupted (Ctrl-C / SIGTERM).\n"
               "Run 'canalsurf COMMAND --help' for the options of a command.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    _add_global_options(parser, in_subcommand=False)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, title="commands")

    # demo ------------------------------------------------------------------------------------------
    p = sub.add_parser(
        "demo", formatter_class=fmt, help="reconstruct a built-in example pipe and compare with the truth",
        description=f"Sample the paper's Figure 9 pipe ({DEMO_POINTS} points, noise ±0.1, seed {DEMO_SEED}; "
                    "true radius 1), write it as DIR/input.ply, reconstruct it with automatic "
                    "parameters, write the results into DIR as 'canalsurf reconstruct' does and print "
                    "how close the result is to the truth.",
        epilog="examples:\n"
               "  canalsurf demo\n"
               "  canalsurf demo -o /tmp/demo -v      # also log the parameters chosen\n"
               "  canalsurf demo --report             # also write canalsurf-demo/report.html\n"
               "  canalsurf reconstruct canalsurf-demo/input.ply -o again/   # the same, from the file")
    p.add_argument("-o", "--output", metavar="DIR", type=_output_folder, default=Path(DEMO_OUTDIR),
                   help=f"folder for input.ply and the results (default: {DEMO_OUTDIR})")
    p.add_argument("--report", action="store_true",
                   help="also write DIR/report.html, a self-contained page with a 3-D view, the radius "
                        "and the stages (needs the 'report' extra)")
    _add_export_options(p)
    _add_global_options(p, in_subcommand=True)
    p.set_defaults(handler=_cmd_demo)

    # reconstruct -----------------------------------------------------------------------------------
    from . import constants as C
    from .io import POINT_FORMATS

    p = sub.add_parser(
        "reconstruct", formatter_class=fmt, help="reconstruct pipe/canal models from point files",
        description="Reconstruct the pipe and canal surfaces in each INPUT -- one tube, or a network of "
                    "branches\nmeeting at junctions; points on no tube are left out -- and write into OUTDIR:\n"
                    "  model.json      per branch spine B-spline, radius, samples, ends; junctions; "
                    "parameters, diagnostics\n"
                    "  surface.<fmt>   triangle mesh (watertight: tubes united at junctions, ends capped)\n"
                    "  spine.csv       branch,t,x,y,z,radius at points evenly spaced along each spine\n"
                    "  spine.dxf       each spine as a CAD SPLINE with radii, in --units (needs the 'dxf' "
                    "extra;\n                  without it a note says it was not written)\n"
                    "  report.html     with --report: one self-contained page (works offline) with a 3-D "
                    "view of\n                  points, spines, junctions and surface, the radii, the "
                    "stages and the parameters\n"
                    "  points.ply      with --labels: the input points with their branch (-1: on no tube) "
                    "and signed distance\n"
                    "  model.ifc       with --ifc: pipe segments and fittings for BIM ('ifc' extra)\n"
                    "  model.step      with --step: the surfaces as a STEP solid model ('step' extra)\n"
                    "  pipes.csv       with --piping: straight pipes and fittings of nominal sizes "
                    "(--catalogue)\n"
                    "With one INPUT the files go into OUTDIR itself, with several into "
                    "OUTDIR/<input name>/.\nAn input that fails is reported and the others go on; "
                    "nothing is written for it.\n\n"
                    f"Point formats: {' '.join(POINT_FORMATS)} (.las/.laz, .pcd, .e57 need extras).\n"
                    "Parameters left out are chosen from the data (see -v) and recorded in model.json, "
                    "so any run can be repeated exactly.\n"
                    f"A file of more than {STREAM_POINTS:,} points (inside --crop) is read in chunks, in "
                    f"bounded memory, and a seeded\nrandom sample of {STREAM_POINTS:,} of them is "
                    "reconstructed; the summary says so.",
        epilog="examples:\n"
               "  canalsurf reconstruct scan.ply -o out/\n"
               "  canalsurf reconstruct a.xyz b.xyz c.laz -o results/ --mesh-format stl\n"
               "  canalsurf reconstruct pipe.ply -o out/ --kind pipe -R 0.2 --delta 0.05 -v\n"
               "  canalsurf reconstruct scan.e57 -o out/ --json > summary.jsonl\n"
               "  canalsurf reconstruct scan.ply -o out/ --report  # and out/report.html\n"
               "  canalsurf reconstruct plant.laz -o out/ --units m --ifc --piping --catalogue en\n"
               "  canalsurf reconstruct scan.e57 -o out/ --crop -5,-5,0,5,5,3 --voxel 0.01\n\n"
               "exit codes: 0 all inputs succeeded; otherwise the highest of the failures' codes "
               "(2 bad input, 1 reconstruction failed or an internal error); 130/143 interrupted.\n"
               "A run into a folder removes the files an earlier run wrote there and it does not write "
               "again\n(report.html without --report); other files are left alone.")
    p.add_argument("inputs", nargs="+", metavar="INPUT", type=Path, help="point cloud file(s)")
    p.add_argument("-o", "--output", metavar="OUTDIR", type=_output_folder, required=True,
                   help="output folder (created if needed)")
    g = p.add_argument_group("method (the paper's parameters; default: chosen from the data)")
    g.add_argument("--kind", choices=("auto", "pipe", "canal"), default="auto",
                   help="pipe: constant radius; canal: radius varies along the spine; auto (default): "
                        "a canal only if a varying radius fits clearly better")
    g.add_argument("-R", "--R", dest="R", type=_LENGTH, metavar="R",
                   help="neighbour radius of the shrinking, in the input's units (default: "
                        f"{C.R_PER_RADIUS:g} x the first radius estimate, at least "
                        f"{C.R_PER_COLLAPSED_SPACING:g} x the spacing of the collapsed points); "
                        "larger if shrinking does not stop")
    g.add_argument("--delta", type=_LENGTH,
                   help=f"shrink step, input units (default: {C.DELTA_PER_RADIUS:.3g} x the first radius "
                        "estimate); smaller is more precise and slower")
    g.add_argument("--mu", type=_number(float, low=0, high=1, what="a number in [0, 1]"),
                   help="break portion: stop when this share of the points has met an opposite "
                        f"normal (default {C.MU:g} with --kind pipe or --stop paper, else "
                        f"{C.MU_CANAL_AUTO:g})")
    g.add_argument("--tau", type=_number(float, low=-1, high=1, what="a number in [-1, 1]"),
                   help=f"canal: cosine tolerance of the normal test (default {C.TAU:.4g} = cos 80°)")
    g.add_argument("-H", "--H", dest="H", type=_LENGTH, metavar="H",
                   help="weighting radius of the MLS thinning, input units (default: "
                        f"{C.H_PER_RADIUS:g} x the first radius estimate)")
    g.add_argument("-k", type=_number(int, low=3, what="an integer >= 3"),
                   help=f"neighbours for estimating normals (default {C.NORMAL_NEIGHBOURS})")
    g.add_argument("--stop", choices=("auto", "paper"), default="auto",
                   help="paper: only the printed mu rule; auto (default): also the peak/patience rules")
    g.add_argument("--neighbours", choices=("kdtree", "gauss"), default="kdtree",
                   help="neighbour search of the shrinking: KD-tree (default) or the paper's Gauss map")
    g.add_argument("--no-refine", dest="refine", action="store_false",
                   help="return the paper's own result instead of the final fit to all points")
    g.add_argument("--normals", choices=("auto", "estimate"), default="auto",
                   help="auto (default): use the file's normals if it has them; estimate: always "
                        "estimate them")
    g = p.add_argument_group("input points (--crop while reading, before a large file is sampled; --voxel "
                             "then, before reconstructing)")
    g.add_argument("--crop", type=_crop_box, metavar=CROP_FORMAT.upper(),
                   help="keep only the points inside this box (faces included), in the input's units; "
                        "'canalsurf info FILE' shows the points' bounding box")
    g.add_argument("--voxel", type=_LENGTH, metavar="SIZE",
                   help="keep at most one point per cube of edge SIZE, in the input's units: the point "
                        "nearest the centroid of the points in its cube, a measured point with its own "
                        "normal (the centroid would sit inside a curved surface and shrink the radius); "
                        "thins dense scans, e.g. to a tenth of the smallest radius")
    g = p.add_argument_group("files")
    g.add_argument("--mesh-format", choices=MESH_CHOICES, default="ply",
                   help="format of surface.<fmt> (default ply; obj stl glb off need trimesh)")
    g.add_argument("--caps", action=argparse.BooleanOptionalAction, default=True,
                   help="close the ends of an open tube so the mesh is watertight (default); "
                        "--no-caps leaves them open")
    g.add_argument("--report", action="store_true",
                   help="also write report.html: a self-contained page (works offline) with a 3-D "
                        "view of the points coloured by branch (grey: on no tube) or by their distance "
                        "from the surface, the junctions, the radius along each branch, the stages and "
                        "the parameters (needs the 'report' extra: pip install 'canalsurf[report]')")
    g.add_argument("--labels", action="store_true",
                   help="also write points.ply: the input points (those inside --crop, all of them even "
                        "with --voxel or when a large file is sampled: they are then read again, in chunks) "
                        "with the branch each lies on (-1: on no tube) and its signed distance from the "
                        "surface, to colour or split the scan")
    g = p.add_argument_group("Dask (needs the 'dask' extra: pip install 'canalsurf[dask]')")
    g.add_argument("--dask", nargs="?", const="", metavar="ADDRESS",
                   help="fit the branches, and label the points of a large file, as Dask tasks: on a local "
                        "cluster of one worker process per core, or on the running scheduler at ADDRESS "
                        "(tcp://host:8786; canalsurf installed on its workers); the files written are the "
                        "same as without")
    _add_export_options(p)
    _add_global_options(p, in_subcommand=True)
    p.set_defaults(handler=_cmd_reconstruct)

    # info ------------------------------------------------------------------------------------------
    from .pointcloud import SPACING_SAMPLE

    p = sub.add_parser(
        "info", formatter_class=fmt, help="what point files hold: points, extent, spacing, fields",
        description="Describe each FILE without reconstructing it: its format, the number of points, "
                    "whether it has normals\nand which other per-point fields it stores (intensity, "
                    "colour, classification, ...), the bounding box\nand the typical spacing (the median "
                    "distance from a point to its nearest neighbour, over a seeded\nsample of at most "
                    f"{SPACING_SAMPLE} points).  Nothing is written.\n\n"
                    f"Point formats: {' '.join(POINT_FORMATS)} (.las/.laz, .pcd, .e57 need extras).",
        epilog="examples:\n"
               "  canalsurf info scan.ply\n"
               "  canalsurf info a.laz b.e57 --json > clouds.jsonl\n\n"
               "exit codes: 0 every file was read; 2 a file could not be read (it is reported, the others "
               "are still described).")
    p.add_argument("inputs", nargs="+", metavar="FILE", type=Path, help="point cloud file(s)")
    _add_global_options(p, in_subcommand=True)
    p.set_defaults(handler=_cmd_info)

    # synth -----------------------------------------------------------------------------------------
    def whole(low: int, what: str) -> Callable[[str], int]:
        """argparse ``type=`` for an integer >= ``low`` of any size (never converted to float, so a huge
        one cannot overflow; make_tube / make_network refuse one too large for memory)."""

        def convert(text: str) -> int:
            shown = text if len(text) <= 40 else f"{text[:20]}...{text[-10:]}"  # not 5000 digits back
            try:
                value = int(text)
            except ValueError:
                raise argparse.ArgumentTypeError(f"expected {what}, got {shown!r}") from None
            if value < low:
                raise argparse.ArgumentTypeError(f"expected {what}, got {shown!r}")
            return value

        return convert

    def synth_details(parser: argparse.ArgumentParser) -> None:
        """What the synth command takes from canalsurf.synth, imported only when synth is used."""
        from .synth import NETWORKS, SURFACES, make_network

        defaults = make_network.__kwdefaults__
        parser.description += f"\n\nSurfaces: {', '.join(SURFACES)}.\nNetworks: {', '.join(NETWORKS)} (see --list)."
        name.choices = (*SURFACES, *NETWORKS)
        n.help = (f"number of points (default {DEMO_POINTS} for a surface, as in the paper; {defaults['n']} "
                  "for a network, clutter included)")
        noise.help = ("half-width of the offset along the normal: for a surface in its units (default: the "
                      "paper's value for NAME); for a network RELATIVE to the local radius, below 0.5 (default "
                      f"{defaults['noise']:g}: ±{100 * defaults['noise']:g} %% of the radius); with --scanner the "
                      "standard deviation along the ray, in the scene's units")

    p = sub.add_parser(
        "synth", formatter_class=fmt, help="write a sampled test surface or tube network", complete=synth_details,
        description="Sample one of the built-in surfaces with a uniform random offset along the normal "
                    "(the paper's epsilon), or one of the tube networks (branches joined at junctions, "
                    "racks, crossings, clutter; noise relative to the radius), and write the points.  The "
                    f"format follows FILE's suffix: {' '.join(POINT_WRITE_FORMATS)}.",
        epilog="examples:\n"
               "  canalsurf synth --list\n"
               "  canalsurf synth fig9-pipe -o pipe.ply\n"
               "  canalsurf synth torus -o torus.xyz --n 5000 --noise 0 --seed 3 --normals\n"
               "  canalsurf synth elbow -o scan.ply --arc 200 --outliers 0.05   # as a scanner sees it\n"
               "  canalsurf synth t-junction -o tee.ply --noise 0.01 --clutter 0.2   # a network on a floor\n"
               "  canalsurf synth plant -o plant.ply --n 1000000 --size 10\n"
               "  canalsurf synth scene -o scan.ply --scanner 2 --quantum 0.01   # what 2 scanners see")
    # NAME's choices and the defaults in the help of --n and --noise: synth_details
    name = p.add_argument("name", nargs="?", metavar="NAME", help="surface or network to sample")
    p.add_argument("-o", "--output", metavar="FILE", type=Path, help="point file to write")
    p.add_argument("--list", action="store_true", help="list the surfaces and networks and exit")
    n = p.add_argument("--n", type=whole(1, "a positive integer"))
    noise = p.add_argument("--noise", type=_number(float, low=0, what="a number >= 0"))
    p.add_argument("--seed", type=whole(0, "a non-negative integer"), default=0,
                   help="random seed, an integer >= 0 (default 0)")
    p.add_argument("--normals", action="store_true", help="also write the true normals (nx, ny, nz)")
    g = p.add_argument_group("surfaces only")
    g.add_argument("--sampling", choices=("area", "parameter"), default="area",
                   help="uniform by surface area (default, like a scanner) or uniform in the surface "
                        "parameters (s, t), as the paper most likely sampled")
    g.add_argument("--gaussian", action="store_true",
                   help="Gaussian offsets with standard deviation --noise instead of uniform ones")
    g.add_argument("--arc", type=_number(float, low=0, high=360, strict=True, what="degrees in (0, 360]"), default=360.0,
                   help="degrees of each cross-section the scan sees, facing one side (default 360; "
                        "180-270 for a one-sided scan)")
    g.add_argument("--outliers", type=_number(float, low=0, high=0.99, what="a share in [0, 0.99]"), default=0.0,
                   help="share of the points that are stray, uniform in the bounding box (default 0)")
    g.add_argument("--density-ratio", type=_number(float, low=1, what="a number >= 1"), default=1.0,
                   help="density falls by this factor from one end of the spine to the other (default 1)")
    g = p.add_argument_group("networks only")
    g.add_argument("--clutter", metavar="SHARE", type=_number(float, low=0, high=0.9, what="a share in [0, 0.9]"),
                   help="share of the points on clutter: floor and boxes (default: the network's own, 0.3 for "
                        "floor-clutter, 0.2 for scene and plant, else 0; above 0 a network without clutter "
                        "gets a floor under it)")
    g.add_argument("--size", type=whole(1, "a positive integer"),
                   help="plant only: number of bays of 23 tubes each (default 1)")
    g = p.add_argument_group("simulated scan (surfaces and networks)")
    g.add_argument("--scanner", metavar="N", nargs="?", const=1, type=whole(1, "a positive number of scanners"),
                   help="write what N terrestrial scanners (default 1) see instead of a sample uniform by area: "
                        "rays on a regular angular grid, the first hit of each (a tube hides its far side and "
                        "what stands behind it), spacing growing with range, Gaussian noise along the ray "
                        "(--noise is then its standard deviation at range 0, in the scene's units; default 1 %% "
                        "of the smallest radius, doubling out to the scene), a ground plane")
    g.add_argument("--step", metavar="DEGREES", type=_number(float, low=0, high=90, strict=True,
                                                             what="an angle in (0, 90] degrees"),
                   help="angular step of the scanner (default: 0.15 of the smallest radius, seen from the "
                        "scene's centre)")
    g.add_argument("--quantum", metavar="Q", type=_LENGTH,
                   help="round the coordinates to whole multiples of Q, as a LAS file stores them (e.g. 0.01)")
    _add_global_options(p, in_subcommand=True)
    p.set_defaults(handler=_cmd_synth)

    # paper -----------------------------------------------------------------------------------------
    p = sub.add_parser(
        "paper", formatter_class=fmt, help="reproduce the paper's experiments",
        description="Run the paper's Section 4 experiments over several seeds and write the "
                    "reproduction document, OUTDIR/paper-reproduction.md (Markdown tables: the paper's "
                    "figures beside ours), into OUTDIR.",
        epilog="examples:\n"
               "  canalsurf paper -o docs/paper\n"
               "  canalsurf paper -o /tmp/paper --seeds 3 -v")
    p.add_argument("-o", "--output", metavar="OUTDIR", type=_output_folder, required=True,
                   help="output folder")
    p.add_argument("--seeds", type=_number(int, low=1, what="a positive integer"), default=10,
                   help="random seeds per experiment (default 10)")
    _add_global_options(p, in_subcommand=True)
    p.set_defaults(handler=_cmd_paper)
    return parser


# --------------------------------------------------------------------------------------------------
# console: logging, progress, messages


class _Console:
    """Where a run's messages go: summaries and JSON to stdout, errors, logs and progress to stderr."""

    def __init__(self, args):
        self.quiet = bool(args.quiet)
        self.json = bool(args.json)
        # Looked up now, not at import: tests (and embedding programs) swap sys.stdout/sys.stderr.
        self.out, self.err = sys.stdout, sys.stderr
        self.progress_enabled = not self.quiet and _isatty(self.err)

    def say(self, text: str = "") -> None:
        """A human summary line (not with --quiet or --json)."""
        if not (self.quiet or self.json):
            print(text, file=self.out)

    def record(self, obj: dict) -> None:
        """One JSON summary line (only with --json)."""
        if self.json:
            print(json.dumps(obj, default=str, ensure_ascii=False), file=self.out, flush=True)

    def error(self, message: str) -> None:
        """The one stderr line of an expected failure."""
        _write_line(f"{PROG}: error: {_one_line(message)}", self.err)


def _write_line(text: str, stream) -> None:
    """Write one line to ``stream`` without breaking a progress bar being drawn there.

    A bar can only be on screen once tqdm has been imported; until then tqdm is not loaded just for
    a message.
    """
    tqdm = sys.modules.get("tqdm")
    if tqdm is None:
        print(text, file=stream)
    else:
        tqdm.tqdm.write(text, file=stream)


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


class _TqdmHandler(logging.StreamHandler):
    """Log records to stderr without breaking a progress bar that is being drawn."""

    def emit(self, record):
        try:
            _write_line(self.format(record), self.stream)
        except Exception:  # noqa: BLE001 -- logging's own convention
            self.handleError(record)


@contextlib.contextmanager
def _logging(verbose: int, quiet: bool):
    """Send canalsurf's log records to stderr for the duration of one ``main`` call.

    Only the ``canalsurf`` logger is touched (never the root logger), and it is restored afterwards, so
    calling ``main`` repeatedly in one process (tests, notebooks) adds no duplicate handlers.
    """
    logger = logging.getLogger(PROG)
    level = logging.DEBUG if verbose > 1 else logging.INFO if verbose else \
        logging.ERROR if quiet else logging.WARNING
    handler = _TqdmHandler(sys.stderr)
    # The handler filters too: a library part may lower its own logger's level to read its records
    # (the paper runner does), and those records must not reach the console past -q.
    handler.setLevel(level)
    handler.setFormatter(logging.Formatter("%(name)s: %(message)s"))
    old_level = logger.level
    logger.addHandler(handler)
    logger.setLevel(level)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old_level)


@contextlib.contextmanager
def _warnings_to_log():
    """Show library warnings as one log line each (``canalsurf.cli: warning: ...``).

    The active warning filters still apply (so ``-W error`` or pytest's strict mode still raise).
    """
    caught = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            yield
    finally:  # also when the run fails: the warnings may explain why
        for w in caught:
            log.warning("warning: %s", _one_line(str(w.message)))


class _StageBar:
    """A tqdm bar over the pipeline's stages; ``bar(stage)`` is reconstruct's ``progress`` callback.

    Without a bar to show (``-q``, or stderr not a terminal) tqdm is not even imported.
    """

    def __init__(self, label: str, console: _Console):
        from .pipeline import STAGES

        self.stages = STAGES
        self.bar = None
        if console.progress_enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=len(STAGES), desc=label, unit="stage", file=console.err, leave=False,
                            dynamic_ncols=True)

    def __call__(self, stage: str) -> None:
        if self.bar is None:
            return
        done = self.stages.index(stage) if stage in self.stages else self.bar.n
        self.bar.update(done - self.bar.n)
        self.bar.set_postfix_str(stage)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.close()


# --------------------------------------------------------------------------------------------------
# writing: a set of files all-or-nothing, under a lock (canalsurf._outputs)


def _output_error(exc: OSError, folder: Path) -> InputError:
    """An OSError while writing, as the one-line error the user sees."""
    where = exc.filename or folder
    reason = exc.strerror or type(exc).__name__
    return InputError(f"{where}: cannot write ({reason}) — choose another output folder or free space")


# --------------------------------------------------------------------------------------------------
# reconstruct


_DXF_AVAILABLE: bool | None = None


def _dxf_available() -> bool:
    """ezdxf is installed (checked once per process).

    It is not imported here: that takes longer than a small reconstruction, and happens only when
    spine.dxf is written.
    """
    global _DXF_AVAILABLE
    if _DXF_AVAILABLE is None:
        if "ezdxf" in sys.modules:  # imported already, or blocked by a None entry
            _DXF_AVAILABLE = sys.modules["ezdxf"] is not None
        else:
            _DXF_AVAILABLE = importlib.util.find_spec("ezdxf") is not None
    return _DXF_AVAILABLE


def _output_files(model, *, mesh_format: str = "ply", caps: bool = True, report_points=None,
                  source: str | None = None, label_points=None,
                  label_chunks: tuple[int, Callable[[], Iterator[np.ndarray]]] | None = None, client=None,
                  units: str | None = None, exports: dict | None = None, catalogue: str | None = None,
                  plotly_js: str | None = None, scan_points=None) -> dict[str, Callable]:
    """Everything a reconstruction writes, computed now; name -> ``write(path)`` callables.

    With ``report_points`` (the input points) the files include ``report.html`` about ``source``
    (referring to a shared plotly.js at ``plotly_js`` if given); with ``label_points`` (the input
    points) ``points.ply``, each point with its branch id (-1: on no tube) and its signed distance
    from the surface.  ``label_chunks``, ``(count, chunks)`` with ``chunks()`` giving the input points
    a chunk at a time, writes the same file for points too many to hold: each chunk is labelled and
    written as it comes, when the file is written (not now).  ``units`` is declared in spine.dxf;
    ``exports`` (option -> module, from :func:`_export_modules`) adds model.ifc, model.step and
    pipes.csv, in ``units`` or, without, :data:`DEFAULT_EXPORT_UNITS`; its pipe pieces are fitted to
    ``scan_points`` (the points reconstructed) when given.

    Raises
    ------
    ReconstructionError
        The model has no valid surface mesh (e.g. the radius changes faster than the spine).
    InputError
        ``report_points`` are given and the 'report' extra is missing.
    """
    from .io import (write_json, write_labelled_chunks, write_labelled_points, write_mesh, write_spine_csv,
                     write_spine_dxf)
    from .network import network_mesh

    data = model.to_dict()
    try:
        vertices, faces = network_mesh(model, caps=caps)
    except InputError as exc:
        raise ReconstructionError(f"the reconstructed surface cannot be meshed: {exc} — "
                                  "try --kind pipe or a larger -H") from None
    samples = [(b["id"], *(np.asarray(b["samples"][key], dtype=float) for key in ("t", "points", "radius")))
               for b in data["branches"]]
    branch = np.concatenate([np.full(len(t), i) for i, t, _, _ in samples])
    t, points, radius = (np.concatenate([s[k] for s in samples]) for k in (1, 2, 3))
    files = {
        "model.json": lambda path: write_json(path, data),
        f"surface.{mesh_format}": lambda path: write_mesh(path, vertices, faces),
        "spine.csv": lambda path: write_spine_csv(path, t, points, radius, branch),
    }
    if _dxf_available():
        splines = [(b.spine.t, b.spine.c, b.spine.k, s[2], s[3]) for b, s in zip(model.branches, samples)]
        files["spine.dxf"] = lambda path: write_spine_dxf(path, splines, units=units)
    files.update(_export_files(model, exports or {}, units=units or DEFAULT_EXPORT_UNITS,
                               catalogue=catalogue or CATALOGUES[0], points=scan_points))
    if label_points is not None:
        label, distance = model.classify(label_points)
        files["points.ply"] = lambda path: write_labelled_points(path, label_points, label, distance)
    elif label_chunks is not None:
        count, chunks = label_chunks

        def write_labels(path: Path) -> None:
            log.info("%s: labelling %d points a chunk at a time", source, count)
            if client is None:
                labelled = ((points, *model.classify(points)) for points in chunks())
            else:
                from .cluster import labelled_chunks

                labelled = labelled_chunks(client, model, chunks())
            write_labelled_chunks(path, count, labelled)

        files["points.ply"] = write_labels
    if report_points is not None:
        from .report import render_report

        page = render_report(model, report_points, source=source, plotly_js=plotly_js)
        files["report.html"] = lambda path: path.write_text(page, encoding="utf-8")
    return files


def _export_files(model, exports: dict, *, units: str, catalogue: str, points=None) -> dict[str, Callable]:
    """model.ifc, model.step and pipes.csv as asked for (``exports``: option -> module).

    The pipe pieces are decomposed now, once (fitted to the scan's ``points`` when given), and model.ifc
    is built from the same pieces when both are asked for.
    """
    files = {}
    pieces = None
    if "piping" in exports:
        piping = exports["piping"]
        with _warnings_to_log():
            pieces = piping.decompose(model, points, units=units, catalogue=catalogue)
        files[EXPORTS["piping"].file] = lambda path: piping.write_pipes_csv(path, pieces, units=units)
    if "ifc" in exports:
        ifc = exports["ifc"]
        shared = {} if pieces is None else {"pieces": pieces}
        files[EXPORTS["ifc"].file] = lambda path: ifc.write_ifc(path, model, units=units, **shared)
    if "step" in exports:
        step = exports["step"]
        files[EXPORTS["step"].file] = lambda path: step.write_step(path, model, units=units)
    return files


def _export_modules(args) -> dict:
    """The modules of the exports asked for (option -> module), imported now and their libraries
    looked up, so that a missing extra fails before any work."""
    modules = {}
    for option, export in EXPORTS.items():
        if not getattr(args, option, False):
            continue
        try:
            modules[option] = importlib.import_module(f".{export.module}", __package__)
            found = all(importlib.util.find_spec(library) is not None for library in export.libraries)
        except ImportError:
            found = False
        if not found and export.extra is None:
            raise InputError(f"--{option} (writing {export.file}) needs the module canalsurf.{export.module}, "
                             "which cannot be imported — reinstall canalsurf")
        if not found:
            raise InputError(f"--{option} (writing {export.file}) needs the '{export.extra}' extra — "
                             f"pip install 'canalsurf[{export.extra}]'")
    if getattr(args, "catalogue", None) is not None and "piping" not in modules:
        raise _UsageError("--catalogue chooses the pipe sizes of --piping: add --piping", f"{PROG} {args.command}")
    return modules


def _run_notes(args, exports: dict) -> tuple[dict[str, str], list[str]]:
    """What a run does not write, and why (file -> reason), and the notes the summary ends with."""
    not_written = {} if _dxf_available() else {"spine.dxf": DXF_MISSING}
    notes = [f"{name} not written: {why}" for name, why in not_written.items()]
    if args.units is None:
        said = []
        if "spine.dxf" not in not_written:
            said.append("spine.dxf is unitless")
        assumed = [EXPORTS[option].file for option in exports]
        if assumed:
            said.append(f"{_and(assumed)} assume {_UNIT_NAMES[DEFAULT_EXPORT_UNITS]}")
        if said:
            notes.append(f"no --units given: {'; '.join(said)} — give --units {'|'.join(UNITS)} to state the "
                         "unit of the input's coordinates")
    return not_written, notes


#: Units as the notes name them.
_UNIT_NAMES = {"m": "metres", "mm": "millimetres", "ft": "feet", "in": "inches"}


def _and(words: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} and {words[-1]}"


def _check_report_extra() -> None:
    """Fail before any work if ``--report`` was asked for and plotly or matplotlib is missing."""
    from .report import require_report_extra

    require_report_extra()


def _spine_length(model) -> float:
    from .spine import curve_length

    return curve_length(model.spine)


def _reconstruct_cloud(points, normals, label: str, options: dict, console: _Console):
    """Run :func:`canalsurf.reconstruct` with a progress bar, warnings and a log of the outcome."""
    from .pipeline import reconstruct

    start = time.perf_counter()
    with _StageBar(label, console) as bar, _warnings_to_log():
        model = reconstruct(points, normals=normals, progress=bar, **options)
    d = model.diagnostics
    log.info("%s: %s; shrinking stopped by %s after %s moves; RMS residual of the points on a tube %.4g",
             label, _describe(model), d.get("stop_rule"), d.get("iterations"),
             d.get("inlier_rms_residual") or float("nan"))
    seconds = d.get("seconds", {})
    log.info("%s: timings %s; total %.2f s", label,
             ", ".join(f"{k} {v:.2f} s" for k, v in seconds.items()), time.perf_counter() - start)
    return model


def _summary(label, folder, model, files) -> dict:
    data = model.to_dict()
    branches = [{"id": b.id, "kind": b.kind, "closed": bool(b.closed), "radius": b.mean_radius,
                 "length": _spine_length(b), "ends": list(b.ends)} for b in model.branches]
    return {"input": label, "outdir": str(folder), "branches": branches,
            "junctions": len(model.junctions), "components": model.components,
            "parameters": data["parameters"],
            "diagnostics": {**data["diagnostics"], "seconds": model.diagnostics.get("seconds", {})},
            "files": [str(f) for f in files]}


def _radius_text(branch) -> str:
    """``radius 1`` for a pipe; ``radius mean 1.68 (1.12-2.25)`` for a canal."""
    if branch.kind == "pipe":
        return f"radius {branch.mean_radius:.6g}"
    r = branch.sample()[1]
    return f"radius mean {branch.mean_radius:.6g} ({r.min():.6g}-{r.max():.6g})"


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _describe(model) -> str:
    """One line about a network: the tube itself when it is one, else its branches and junctions."""
    if len(model.branches) == 1:
        b = model.branches[0]
        text = (f"{b.kind}, {_radius_text(b)}, {'closed' if b.closed else 'open'} spine of length "
                f"{_spine_length(b):.6g}")
    else:
        kinds = [b.kind for b in model.branches]
        text = (f"{len(kinds)} branches ({_count(kinds.count('pipe'), 'pipe')}, "
                f"{_count(kinds.count('canal'), 'canal')}), {_count(len(model.junctions), 'junction')}, "
                f"{_count(len(model.components), 'separate network')}")
    share = model.diagnostics.get("no_tube_share")
    if share:
        text += f"; {share:.1%} of the points on no tube"
    quality = model.diagnostics.get("quality")
    if quality:
        reasons = model.diagnostics.get("quality_reasons") or []
        text = f"quality {quality}" + (f" ({'; '.join(reasons)})" if reasons else "") + f": {text}"
    return text


#: Characters that cannot be in a folder name on some system: separators, Windows' reserved ones.
_UNSAFE_CHARS = frozenset('/\\:*?"<>|')
#: Device names Windows reserves, also with an extension (``CON.scan``): no folder can have them.
_WINDOWS_RESERVED = frozenset(["CON", "PRN", "AUX", "NUL", *(f"{d}{i}" for d in ("COM", "LPT")
                                                            for i in [*"123456789", "¹", "²", "³"])])
#: Longest folder name made from an input name, in UTF-8 bytes: file systems allow 255, and the
#: ``-2`` of a repeated name must still fit.
FOLDER_NAME_BYTES = 200


def _safe_folder_name(stem: str) -> str:
    """``stem`` made into a name that is a plain folder on every system.

    Separators, control and unprintable characters (and ``: * ? " < > |``) become ``_``; leading
    dots, dashes and spaces (hidden folders, option look-alikes, ``..``) and trailing dots and spaces
    (which Windows drops) are removed; names Windows reserves (``CON``, ``NUL``, ``COM1``...) get a
    leading ``_``; what is left empty becomes ``input``.
    """
    name = "".join("_" if c in _UNSAFE_CHARS or not c.isprintable() else c for c in stem)
    name = name.encode("utf-8")[:FOLDER_NAME_BYTES].decode("utf-8", "ignore")
    name = name.lstrip(" .-").rstrip(" .") or "input"
    if name.split(".")[0].rstrip(" ").upper() in _WINDOWS_RESERVED:
        name = f"_{name}"
    return name


def _folder_names(inputs: list[Path]) -> list[str]:
    """One output folder name per input: its stem, made safe (:func:`_safe_folder_name`) and unique
    (``scan``, ``scan-2``, ...)."""
    used, names = set(), []
    for path in inputs:
        stem = _safe_folder_name(path.stem or path.name)
        name, i = stem, 1
        while name.casefold() in used:  # case-insensitive file systems
            i += 1
            name = f"{stem}-{i}"
        used.add(name.casefold())
        names.append(name)
    return names


def _with_path(path: Path, exc: Exception) -> str:
    """The error message, naming the input file unless it already does."""
    text = _one_line(exc)
    return text if text.startswith(str(path)) else f"{path}: {text}"


def _exit_code(exc: BaseException) -> int:
    return EXIT_FAILED if isinstance(exc, ReconstructionError) else EXIT_INPUT


def _internal_error(exc: Exception) -> str:
    """The one line about an unexpected exception (a bug); its traceback goes to the log (-v)."""
    log.info("internal error:", exc_info=exc)
    what = f"{type(exc).__name__}: {_one_line(exc)}" if str(exc).strip() else type(exc).__name__
    return f"internal error ({what}) — please report it"


def _failure(path: Path, exc: Exception) -> tuple[str, int]:
    """Message and exit code of an input that failed: an expected error, or a bug (code 1)."""
    if isinstance(exc, CanalsurfError):
        return _with_path(path, exc), _exit_code(exc)
    return f"{path}: {_internal_error(exc)}", EXIT_FAILED


def _prepare_points(path: Path, sample, args) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, dict]:
    """``--voxel`` (:mod:`canalsurf.pointcloud`) on what :func:`canalsurf.io.read_points_sample` kept.

    ``sample`` holds the points inside ``--crop`` (cropped while reading), all of them or, from a
    larger file, a seeded sample of :data:`STREAM_POINTS`.  Returns those points (what ``--labels``
    labels when they are all of them), the points and normals left after the voxel grid (what is
    reconstructed) and a record of what was done (for the summary).
    """
    from ._validate import MIN_POINTS
    from .pointcloud import voxel_downsample

    points, normals = sample.points, sample.normals
    record = {"points_read": sample.total}
    if args.crop is not None:
        if not sample.in_box and sample.total:
            lower, upper = _bounds(path)
            span = ", ".join(f"{axis} {a:.6g}..{b:.6g}" for axis, a, b in zip("xyz", lower, upper))
            raise InputError(f"{path}: no points inside the crop box {','.join(f'{v:g}' for v in args.crop)} (the "
                             f"points span {span}) — give a box that overlaps them ('canalsurf info {path}')")
        record["crop"] = list(args.crop)
        record["points_in_crop"] = sample.in_box
    if len(points) < sample.in_box:
        record["points_sampled"] = len(points)
        record["sample_seed"] = STREAM_SEED
    region = points
    if args.voxel is not None:
        kept, normals = voxel_downsample(points, args.voxel, normals=normals)
        if len(kept) < MIN_POINTS <= len(points):
            raise InputError(f"{path}: only {len(kept)} of {len(points)} points are left after --voxel {args.voxel:g}, "
                             f"fewer than the {MIN_POINTS} a reconstruction needs — give a smaller --voxel")
        points = kept
        record["voxel"] = args.voxel
        record["points_after_voxel"] = len(points)
    record["points"] = len(points)
    return region, points, normals, record


def _bounds(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The lower and upper corner of all the points of a file, read again a chunk at a time."""
    from .io import iter_point_chunks

    lower, upper = np.full(3, np.inf), np.full(3, -np.inf)
    for points, _ in iter_point_chunks(path):
        lower, upper = np.minimum(lower, points.min(axis=0)), np.maximum(upper, points.max(axis=0))
    return lower, upper


def _prepared_text(record: dict) -> str:
    """``1532 of 3000000 points in the crop box; 801 of 1532 points left by --voxel 0.05; `` (empty if
    nothing was done; ``N of M points read (seeded sample)`` between the two when a large file was sampled)."""
    parts = []
    count = record["points_read"]
    if "crop" in record:
        parts.append(f"{record['points_in_crop']} of {count} points in the crop box")
        count = record["points_in_crop"]
    if "points_sampled" in record:
        parts.append(f"{record['points_sampled']} of {count} points read (seeded sample)")
        count = record["points_sampled"]
    if "voxel" in record:
        parts.append(f"{record['points_after_voxel']} of {count} points left by --voxel {record['voxel']:g}")
    return "; ".join(parts) + "; " if parts else ""


def _cmd_reconstruct(args, console: _Console) -> int:
    if args.mesh_format != "ply":
        try:
            importlib.import_module("trimesh")
        except ImportError:
            raise InputError(f"writing .{args.mesh_format} meshes needs the 'mesh' extra — "
                             "pip install 'canalsurf[mesh]', or use --mesh-format ply") from None
    if args.report:
        _check_report_extra()
    exports = _export_modules(args)
    _check_output_folder(args.output)
    not_written, notes = _run_notes(args, exports)
    options = {"kind": args.kind, "R": args.R, "delta": args.delta, "mu": args.mu, "tau": args.tau,
               "H": args.H, "k": args.k, "stop": args.stop, "neighbours": args.neighbours,
               "refine": args.refine, "client": None}
    if args.dask is None:
        return _reconstruct_inputs(args, console, options, exports, not_written, notes)
    from .cluster import connect

    with connect(args.dask or None) as client:
        return _reconstruct_inputs(args, console, options | {"client": client}, exports, not_written, notes)


def _reconstruct_inputs(args, console: _Console, options: dict, exports: dict, not_written: dict,
                        notes: list) -> int:
    """Reconstruct every input of ``canalsurf reconstruct``; the worst exit code."""
    from .io import iter_point_chunks, read_points_sample

    several = len(args.inputs) > 1
    # Reports of a batch share one plotly.js in OUTDIR (4.6 MB each otherwise); one report stands alone.
    shared_js = several and args.report
    names = _folder_names(args.inputs)
    worst, done = EXIT_OK, 0
    for path, name in zip(args.inputs, names):
        folder = args.output / name if several else args.output
        try:
            start = time.perf_counter()
            sample = read_points_sample(path, STREAM_POINTS, rng=STREAM_SEED, box=args.crop)
            seconds_read = time.perf_counter() - start
            log.info("%s: read in %.2f s", path, seconds_read)
            region, points, normals, prepared = _prepare_points(path, sample, args)
            prepared["read_seconds"] = seconds_read
            if args.normals == "estimate":
                normals = None
            if args.k is not None and args.k > len(points):
                # checked here, not left to reconstruct, so the message can name the option to change
                raise InputError(f"{len(points)} points are fewer than the {args.k} neighbours -k asks "
                                 "for — give a smaller -k or a denser scan")
            log.info("%s: %d points, normals %s", path, len(points),
                     "from the file" if normals is not None else "estimated")
            model = _reconstruct_cloud(points, normals, str(path), options, console)
            # Labels are for every point (inside --crop): those of a sampled file are read again.
            sampled = "points_sampled" in prepared
            label_chunks = None
            if args.labels and sampled:
                label_chunks = (sample.in_box, lambda path=path: (chunk for chunk, _ in
                                                                 iter_point_chunks(path, box=args.crop)))
            files = _output_files(model, mesh_format=args.mesh_format, caps=args.caps,
                                  report_points=points if args.report else None, source=str(path),
                                  label_points=region if args.labels and not sampled else None,
                                  label_chunks=label_chunks, client=options["client"], units=args.units,
                                  exports=exports, catalogue=args.catalogue, scan_points=points,
                                  plotly_js=f"../{_plotly_js_name()}" if shared_js else None)
            try:
                if shared_js and not done:
                    _write_shared_plotly_js(args.output)
                written = _write_files(folder, files, inside=args.output)
            except OSError as exc:
                raise _output_error(exc, folder) from None
        except Exception as exc:  # noqa: BLE001 -- even a bug fails this input only
            message, code = _failure(path, exc)
            console.error(message)
            console.record({"input": str(path), "outdir": str(folder), "error": message, "exit_code": code})
            worst = max(worst, code)
            continue
        done += 1
        console.record(_summary(str(path), folder, model, written) | prepared |
                       {"units": args.units, "not_written": not_written, "notes": notes})
        console.say(f"{path}: {_prepared_text(prepared)}{_describe(model)} -> {folder}{os.sep} "
                    f"({', '.join(f.name for f in written)})")
    if done:
        for note in notes:
            console.say(f"note: {note}")
    return worst


def _plotly_js_name() -> str:
    from .report import PLOTLY_JS_NAME

    return PLOTLY_JS_NAME


def _write_shared_plotly_js(folder: Path) -> None:
    """Write OUTDIR/plotly.min.js, which the reports of a batch refer to, before the first of them."""
    from .report import write_plotly_js

    _make_dirs(folder)
    write_plotly_js(folder / _plotly_js_name())


# --------------------------------------------------------------------------------------------------
# demo


def _cmd_demo(args, console: _Console) -> int:
    from .metrics import compare
    from .synth import SURFACES, make_tube

    folder = args.output
    if args.report:
        _check_report_extra()
    exports = _export_modules(args)
    _check_output_folder(folder)
    not_written, notes = _run_notes(args, exports)
    tube = make_tube(DEMO_SURFACE, n=DEMO_POINTS, rng=DEMO_SEED)
    log.info("demo: %s, %d points, noise %g, seed %d", DEMO_SURFACE, DEMO_POINTS, tube.noise, DEMO_SEED)
    model = _reconstruct_cloud(tube.points, None, "demo", {}, console)
    files = {"input.ply": lambda path: write_points(path, tube.points, None)}
    files.update(_output_files(model, report_points=tube.points if args.report else None,
                               source=f"canalsurf demo ({DEMO_SURFACE})", units=args.units, exports=exports,
                               catalogue=args.catalogue, scan_points=tube.points))
    try:
        written = _write_files(folder, files)
    except OSError as exc:
        raise _output_error(exc, folder) from None

    m = compare(model, tube)
    true_r = m["mean_radius"]
    summary = _summary(str(folder / "input.ply"), folder, model, written)
    summary.update(surface=DEMO_SURFACE, true_radius=true_r, spine_length=_spine_length(model),
                   metrics=m, units=args.units, not_written=not_written, notes=notes)
    console.record(summary)
    pct = 100.0 / true_r
    console.say(f"canalsurf demo: {SURFACES[DEMO_SURFACE][-1]}")
    console.say(f"  sampled {DEMO_POINTS} points, noise ±{tube.noise:g} along the normal, seed {DEMO_SEED}")
    console.say(f"  kind           {model.kind} ({'closed' if model.closed else 'open'} spine)")
    console.say(f"  radius found   {model.mean_radius:.4f}  (true {true_r:.4f}, "
                f"error {abs(model.mean_radius - true_r) * pct:.2f} %)")
    console.say(f"  spine length   {summary['spine_length']:.4g}")
    console.say(f"  spine error    mean {m['spine_mean'] * pct:.2f} %, max {m['spine_max'] * pct:.2f} % "
                "of the radius (closest-point distance to the true spine)")
    console.say(f"  radius error   mean {m['radius']['mean'] * pct:.2f} %, max {m['radius']['max'] * pct:.2f} %")
    console.say(f"  files written  {', '.join(str(f) for f in written)}")
    for note in notes:
        console.say(f"  note           {note}")
    console.say(f"  next: canalsurf reconstruct {folder / 'input.ply'} -o OUTDIR -v")
    return EXIT_OK


# --------------------------------------------------------------------------------------------------
# info


def _cmd_info(args, console: _Console) -> int:
    from .io import point_file_info, read_points
    from .pointcloud import SPACING_SAMPLE, point_spacing

    worst = EXIT_OK
    for path in args.inputs:
        try:
            # read_points first: it checks the whole file, so its header is then safe to read again
            points, normals = read_points(path)
            info = point_file_info(path)
            finite = np.isfinite(points).all(axis=1)
            good = points if finite.all() else points[finite]
            spacing = point_spacing(good) if len(good) else math.nan
        except Exception as exc:  # noqa: BLE001 -- even a bug fails this file only
            message, code = _failure(path, exc)
            console.error(message)
            console.record({"input": str(path), "error": message, "exit_code": code})
            worst = max(worst, code)
            continue
        lo, hi = (good.min(axis=0), good.max(axis=0)) if len(good) else (None, None)
        sample = min(len(good), SPACING_SAMPLE)
        console.record({"input": str(path), "format": info.format, "points": len(points),
                        "normals": normals is not None, "fields": list(info.fields),
                        "non_finite_points": int(len(points) - len(good)),
                        "bounds": None if lo is None else {"min": lo.tolist(), "max": hi.tolist()},
                        "size": None if lo is None else (hi - lo).tolist(),
                        "spacing": None if math.isnan(spacing) else spacing, "spacing_sample": sample})
        console.say(f"{path}: {info.format}; {_count(len(points), 'point')}, "
                    f"{'with' if normals is not None else 'no'} normals")
        if len(good) < len(points):
            console.say(f"  not finite     {len(points) - len(good)} points with NaN or inf coordinates (left "
                        "out below; a reconstruction refuses them)")
        if lo is not None:
            extent = ", ".join(f"{axis} {a:.6g} .. {b:.6g}" for axis, a, b in zip("xyz", lo, hi))
            console.say(f"  bounding box   {extent}  (size {' x '.join(f'{d:.4g}' for d in hi - lo)})")
        console.say(f"  spacing        {'—' if math.isnan(spacing) else f'{spacing:.4g}'}  (median distance to "
                    f"the nearest point, over {'all ' if sample == len(good) else ''}{sample} points)")
        console.say(f"  fields         {' '.join(info.fields) or '—'}")
    return worst


# --------------------------------------------------------------------------------------------------
# synth


def _cmd_synth(args, console: _Console) -> int:
    from .synth import NETWORKS, SURFACES, make_network, make_tube

    if args.list:
        entries = {name: spec[-1] for name, spec in SURFACES.items()}
        entries.update({name: f"network: {spec[-1]}" for name, spec in NETWORKS.items()})
        if console.json:
            console.record(entries)
        else:
            width = max(map(len, entries))
            for name, text in entries.items():
                print(f"{name:<{width}}  {text}", file=console.out)
        return EXIT_OK
    if args.name is None or args.output is None:
        raise _UsageError("synth needs NAME and -o FILE (or --list)", f"{PROG} synth")
    path = args.output
    if path.suffix.lower() not in POINT_WRITE_FORMATS:
        raise InputError(f"{path}: cannot write points as {path.suffix or '(no suffix)'!r} — "
                         f"use one of {', '.join(POINT_WRITE_FORMATS)}")
    network = args.name in NETWORKS
    # options that do not apply to NAME are refused rather than silently ignored
    if args.scanner is None:
        stray = [option for option, set_ in (("--step", args.step), ("--quantum", args.quantum)) if set_ is not None]
        if stray:
            raise _UsageError(f"{stray[0]} is an option of a simulated scan: add --scanner", f"{PROG} synth")
    else:
        given = {"--n": args.n is not None, "--sampling": args.sampling != "area", "--gaussian": args.gaussian,
                 "--arc": args.arc != 360, "--outliers": args.outliers != 0, "--density-ratio": args.density_ratio != 1,
                 "--clutter": args.clutter is not None}
        wrong = [option for option, set_ in given.items() if set_]
        if wrong:
            raise _UsageError(f"{wrong[0]} does not apply to a simulated scan (--scanner): its points follow "
                              "--step and what the scanners see", f"{PROG} synth")
    if network:
        given = {"--sampling": args.sampling != "area", "--gaussian": args.gaussian, "--arc": args.arc != 360,
                 "--outliers": args.outliers != 0, "--density-ratio": args.density_ratio != 1}
    else:
        given = {"--clutter": args.clutter is not None, "--size": args.size is not None}
    wrong = [option for option, set_ in given.items() if set_]
    if wrong:
        kind = "surfaces, not of the network" if network else "networks, not of the surface"
        raise _UsageError(f"{wrong[0]} is an option of the {kind} {args.name!r}", f"{PROG} synth")
    if args.scanner is not None:
        from .synth import scan

        cloud = scan(args.name, positions=args.scanner, step=args.step, noise=args.noise, quantum=args.quantum,
                     rng=args.seed, **({} if args.size is None else {"size": args.size}))
        info, n = cloud.scan, len(cloud.points)
        share = float(np.mean(cloud.label < 0 if network else cloud.outlier))
        s = len(info.positions)
        shape = (f"simulated scan from {s} scanner{'s' * (s != 1)}, step {info.step:.4g}°, Gaussian noise along "
                 f"the ray σ = {info.noise:.3g} + {info.range_noise:.3g} × range, "
                 + (f"coordinates on a {info.quantum:g} grid" if info.quantum else "not quantised")
                 + (f", ground at z = {info.ground:.4g}" if info.ground is not None else "")
                 + f"; {100 * share:.3g} % of the points off the tubes")
        record = {"network": network, "scanner": True, "positions": info.positions.tolist(), "step": info.step,
                  "noise_model": "gaussian along the ray, sigma = noise + range_noise * range",
                  "range_noise": info.range_noise, "quantum": info.quantum, "ground": info.ground,
                  "rays": info.rays, "dropped": info.dropped, "off_tubes": share}
    elif network:
        options = {key: value for key, value in (("n", args.n), ("noise", args.noise), ("clutter", args.clutter),
                                                  ("size", args.size)) if value is not None}
        cloud = make_network(args.name, rng=args.seed, **options)
        n, share = len(cloud.points), float(cloud.clutter.mean())
        b, j = len(cloud.branches), len(cloud.junctions)
        shape = (f"{b} branch{'es' * (b != 1)}, {j} junction{'s' * (j != 1)}; uniform noise "
                 f"±{100 * cloud.noise:g} % of the radius{f', {100 * share:g} % on clutter' if share else ''}")
        record = {"network": True, "branches": len(cloud.branches), "junctions": len(cloud.junctions),
                  "components": len(cloud.components), "noise_model": "uniform, relative to the radius",
                  "clutter": share}
    else:
        n = DEMO_POINTS if args.n is None else args.n
        cloud = make_tube(args.name, n=n, noise=args.noise, rng=args.seed, sampling=args.sampling,
                          noise_model="gaussian" if args.gaussian else "uniform", arc=args.arc,
                          outliers=args.outliers, density_ratio=args.density_ratio)
        shape = (f"Gaussian noise of standard deviation {cloud.noise:g}" if args.gaussian
                 else f"uniform noise ±{cloud.noise:g}")
        shape += "".join(text for text, on in (
            (f", one-sided scan of {args.arc:g}°", args.arc != 360),
            (f", {100 * args.outliers:g} % stray points", args.outliers != 0),
            (f", density falling {args.density_ratio:g}x along the spine", args.density_ratio != 1),
            (", uniform in the surface parameters", args.sampling != "area")) if on)
        record = {"network": False, "closed": cloud.closed, "noise_model": cloud.noise_model, "arc": cloud.arc,
                  "outliers": args.outliers, "density_ratio": args.density_ratio, "sampling": args.sampling}
    created = _make_dirs(path.parent)
    try:
        write_points(path, cloud.points, cloud.normals if args.normals else None)
    except BaseException:
        _remove_dirs(created)
        raise
    console.record({"name": args.name, "output": str(path), "n": int(n), "noise": cloud.noise,
                    "seed": args.seed, "normals": bool(args.normals), **record})
    console.say(f"{path}: {n} points of {args.name} ({shape}, seed {args.seed}"
                f"{', with true normals' if args.normals else ''})")
    return EXIT_OK


# --------------------------------------------------------------------------------------------------
# paper


def _cmd_paper(args, console: _Console) -> int:
    try:
        from .experiments import run_paper
    except ImportError as exc:
        raise InputError(f"the paper experiments cannot be loaded ({_one_line(exc)}) — "
                         "install canalsurf with its extras: pip install 'canalsurf[all]'") from None
    from tqdm import tqdm

    _check_output_folder(args.output)
    bar = tqdm(desc="paper", unit="step", file=console.err, leave=False,
               disable=not console.progress_enabled, dynamic_ncols=True)

    def progress(*info, **_):
        """Accepts ``progress(message)``, ``progress(done, total)`` or ``progress(done, total, message)``."""
        counts = [x for x in info if isinstance(x, int) and not isinstance(x, bool)]
        text = " ".join(str(x) for x in info if not isinstance(x, (int, float)))
        if len(counts) >= 2:
            bar.total = counts[1]
            bar.update(counts[0] - bar.n)
        else:
            bar.update(1)
        if text:
            bar.set_postfix_str(text[:60])

    start = time.perf_counter()
    try:
        with bar, _warnings_to_log():
            result = run_paper(args.output, seeds=args.seeds, progress=progress)
    except OSError as exc:
        raise _output_error(exc, args.output) from None
    log.info("paper: %d seeds in %.1f s", args.seeds, time.perf_counter() - start)
    record = {"outdir": str(args.output), "seeds": int(args.seeds)}
    if result is not None:
        record["result"] = result
    console.record(record)
    console.say(f"paper reproduction ({args.seeds} seeds) written to {args.output}{os.sep}")
    return EXIT_OK


# --------------------------------------------------------------------------------------------------
# entry point


def main(argv: list[str] | None = None) -> int:
    """Run the ``canalsurf`` command with ``argv`` (default ``sys.argv[1:]``); return the exit code.

    Examples
    --------
    >>> main(["--version"])  # doctest: +SKIP
    canalsurf 0.1.0
    0
    """
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _UsageError as exc:
        print(f"{PROG}: error: {exc} — see '{exc.prog} --help'", file=sys.stderr)
        return EXIT_INPUT
    except SystemExit as exc:  # --help and --version
        return exc.code if isinstance(exc.code, int) else EXIT_OK

    console = _Console(args)
    with _logging(args.verbose, args.quiet):
        try:
            return args.handler(args, console)
        except _UsageError as exc:
            console.error(f"{exc} — see '{exc.prog} --help'")
            return EXIT_INPUT
        except CanalsurfError as exc:
            console.error(str(exc))
            return _exit_code(exc)
        except OSError as exc:
            console.error(str(_output_error(exc, Path(getattr(args, "output", ".") or "."))))
            return EXIT_INPUT
        except Exception as exc:  # noqa: BLE001 -- a bug: one line, not a traceback
            console.error(_internal_error(exc))
            return EXIT_FAILED
        except KeyboardInterrupt:
            console.error(INTERRUPTED)
            return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
