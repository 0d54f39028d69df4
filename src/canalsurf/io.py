"""Reading point clouds and writing results, one small function per file format.

Readers and writers sit in registries keyed by the (lower-case) file suffix, each a thin layer over a
maintained library, so a new format is one function and one registry entry.  Every reader returns
``(points, normals)``: an ``(N, 3)`` float64 array and an ``(N, 3)`` float64 array or ``None``.
Checking that the numbers are finite and numerous enough is left to :mod:`canalsurf._validate`; the
readers only promise that a file which cannot be read gives a one-line :class:`InputError` naming the
file, the problem and what to do -- never a traceback from the library underneath.

Point formats (``POINT_FORMATS``)
    ``.ply`` (plyfile, core), ``.xyz .txt .csv .asc`` (numpy), ``.npy .npz`` (numpy),
    ``.pcd`` (pypcd4, extra ``pcd``), ``.las .laz`` (laspy + lazrs, extra ``las``),
    ``.e57`` (pye57, extra ``e57``).
Mesh formats (``MESH_FORMATS``)
    ``.ply`` (plyfile, core), ``.obj .stl .off .glb`` (trimesh, extra ``mesh``).
Other writers
    :func:`write_spine_csv`, :func:`write_spine_dxf` (ezdxf, extra ``dxf``; the drawing's unit from
    ``units``), :func:`write_json`.
What a file holds
    :func:`point_file_info`: the format and the per-point fields, from the header.
Files larger than memory
    :func:`read_points_sample`: a seeded uniform sample of at most a given number of points (and
    a crop box), read in chunks; :func:`iter_point_chunks`: all the points, a chunk at a time, for a
    second pass; :func:`write_labelled_chunks`: a labelled point file written a chunk at a time.
    LAS/LAZ (laspy's chunk iterator), binary PLY and ``.npy`` (memory maps), text and ASCII PLY
    (chunks of lines) are read in bounded memory; the other formats are read whole first.

Hostile files.  Each reader checks what can be checked from a file's start before reading it whole:
the leading bytes, the header against the file's size (PLY, .npy and each .npz member, PCD, LAS/LAZ
and the LASzip chunk table, with struct, before laspy or lazrs see the file) and a sample of the first
lines of text; E57 scans are read in bounded pieces and must hold the points they declare.  So a
corrupted file is refused in bounded time and memory, and a header that counts fewer rows than the
data holds is refused like one that counts more (the rest would be dropped silently).
``benchmarks/fuzz.py`` checks this on damaged files of every format (docs/reliability.md).

Every writer goes through :func:`atomic_write`: the data is written to a temporary file in the
target folder and moved over the target only once complete, so an interrupted run never leaves a
half-written file behind under the real name.
"""

from __future__ import annotations

import contextlib
import importlib
import itertools
import json
import logging
import math
import os
import pathlib
import re
import secrets
import stat
import struct
import warnings
import zipfile
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

import numpy as np

from ._validate import as_table
from .errors import InputError

__all__ = [
    "MESH_FORMATS",
    "POINT_FORMATS",
    "POINT_FORMAT_NAMES",
    "POINT_WRITE_FORMATS",
    "DXF_UNITS",
    "PointFileInfo",
    "PointSample",
    "atomic_write",
    "iter_point_chunks",
    "point_file_info",
    "read_points",
    "read_points_sample",
    "write_points",
    "write_json",
    "write_labelled_chunks",
    "write_labelled_points",
    "write_mesh",
    "write_spine_csv",
    "write_spine_dxf",
]

PathLike = str | os.PathLike

log = logging.getLogger(__name__)

#: Field names under which normals are stored, per format family.  PLY uses the meshlab/CloudCompare
#: names, PCD the PCL names; LAS has no standard normal dimension, so both spellings are accepted as
#: extra-bytes dimensions (CloudCompare writes ``NormalX`` ..., PDAL ``NormalX`` or ``nx``).
_PLY_NORMALS = ("nx", "ny", "nz")
_PCD_NORMALS = ("normal_x", "normal_y", "normal_z")
_LAS_NORMALS = (("normal_x", "normal_y", "normal_z"), ("normalx", "normaly", "normalz"), ("nx", "ny", "nz"))

#: Application id under which :func:`write_spine_dxf` stores radii as DXF extended data.
DXF_APPID = "CANALSURF"
#: Length units a drawing can declare, with their DXF ``$INSUNITS`` codes (AutoCAD's table: 1 inches,
#: 2 feet, 4 millimetres, 6 metres; 0 is "unitless", written when no unit is given).
DXF_UNITS = {"m": 6, "mm": 4, "ft": 2, "in": 1}
#: ``$INSUNITS`` of a drawing whose unit is not known.
DXF_UNITLESS = 0
#: Point formats :func:`write_points` writes, by suffix.
POINT_WRITE_FORMATS = {".ply": "ply", ".xyz": "text", ".txt": "text", ".asc": "text", ".csv": "csv",
                 ".npy": "npy", ".npz": "npz"}

#: Delimiters a text point file may use, in the order they are tried on the first data line.  ``;``
#: comes before ``,`` because spreadsheets in decimal-comma locales write ``1,5;2,0;3,25``: a ``,`` in
#: such a line must not be taken for the delimiter (the row then fails with a line-numbered error
#: instead of silently splitting numbers).  ``None`` means runs of whitespace.
_TEXT_DELIMITERS = (";", "\t", ",")

# Bounds that let a reader refuse a bad file after reading its start, never after reading it whole.
#: Bytes sampled at the start of a text point file before it is parsed: hundreds of lines, and a
#: file that is not text (NUL bytes, invalid UTF-8) is refused after reading this much.
_TEXT_SAMPLE_BYTES = 1 << 16
#: Longest line of a text point file: six numbers at full precision take about 150 characters; a
#: longer "line" is binary data, which must not be read into memory whole in search of a newline.
_MAX_LINE_CHARS = 4096
#: Most bytes a PLY or PCD header may take: real ones take hundreds of bytes (a few KB with
#: comments); a file whose header does not end within this is not one.
_MAX_HEADER_BYTES = 1 << 20


# --------------------------------------------------------------------------------------------------
# helpers


def _missing_extra(suffix: str, extra: str, verb: str = "reading") -> InputError:
    return InputError(
        f"{verb} {suffix} files needs the '{extra}' extra — pip install 'canalsurf[{extra}]'"
    )


def _import_extra(module: str, suffix: str, extra: str, verb: str = "reading") -> Any:
    """Import an optional dependency, or raise the error that names the extra to install."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise _missing_extra(suffix, extra, verb) from None


def _one_line(exc: BaseException) -> str:
    """The library's message, squeezed onto one line (CLI errors are a single stderr line)."""
    # libE57 appends a multi-line debug dump after "****"; the first sentence is the message
    text = " ".join(str(exc).split("****", 1)[0].split()) or type(exc).__name__
    return text if len(text) <= 200 else text[:197] + "..."


@contextlib.contextmanager
def _translating(path: pathlib.Path, what: str, fix: str) -> Iterator[None]:
    """Turn any exception a third-party parser raises into a one-line :class:`InputError`.

    The parsers raise a zoo of types on malformed input (ValueError, struct.error, EOFError,
    UnicodeDecodeError, MemoryError on a header that claims 10^12 points, library-specific errors),
    so the net is deliberately wide; it wraps only library calls, never canalsurf's own logic.
    """
    try:
        yield
    except (InputError, KeyboardInterrupt, SystemExit, GeneratorExit):
        raise
    except BaseException as exc:  # noqa: BLE001 -- see docstring
        # BaseException, not Exception: pyo3 turns a panic of Rust code (lazrs) into PanicException,
        # which derives from BaseException.
        raise InputError(f"{path}: not a readable {what} file ({_one_line(exc)}) — {fix}") from exc


def _as_path(path: Any, what: str = "path") -> pathlib.Path:
    """``path`` as a :class:`pathlib.Path`, or :class:`InputError` if it is not a file path at all."""
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"{what} must be a file path (str or os.PathLike), got {type(path).__name__}")
    try:
        result = pathlib.Path(path)
    except TypeError:  # an os.PathLike whose __fspath__ gives bytes
        raise InputError(f"{what} must be a text file path, got {type(path).__name__}") from None
    if "\0" in str(result):
        raise InputError(f"{what} {str(result)!r} contains a NUL character — give a file name")
    return result


def _truncated(path: pathlib.Path, what: str, declared: int, held: int, rows: str = "points") -> InputError:
    """The error of a file whose header promises more rows than its data holds."""
    return InputError(f"{path}: {what} file is truncated (header says {declared} {rows}, data holds {held}) "
                      "— re-export the file")


def _more_data(path: pathlib.Path, what: str, declared: int, rows: str = "points") -> InputError:
    """The error of a file whose header promises fewer rows than its data holds (the rest would be dropped)."""
    return InputError(f"{path}: {what} header says {declared} {rows} but more data follows — the file is "
                      "corrupted; re-export the file")


@contextlib.contextmanager
def _library_logs(name: str) -> Iterator[None]:
    """Pass a library's log records on to canalsurf's logger at INFO level while it reads a file.

    Without a handler of its own, a record such as laspy's warning about an odd extra-bytes record
    goes to Python's last-resort handler, which prints it to stderr around the command line's output.
    """

    class Relay(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            log.info("%s: %s", record.name, record.getMessage())

    logger, relay = logging.getLogger(name), Relay()
    logger.addHandler(relay)
    try:
        yield
    finally:
        logger.removeHandler(relay)


def _as_xyz(columns: list[np.ndarray]) -> np.ndarray:
    """Stack three 1-D columns into a fresh C-contiguous ``(N, 3)`` float64 array."""
    return np.column_stack([np.asarray(c, dtype=np.float64) for c in columns])


def _check_columns(arr: np.ndarray, path: pathlib.Path, what: str) -> None:
    """Refuse an array that is not ``(N, 3)`` or ``(N, 6)`` numbers."""
    if arr.dtype.kind not in "iuf" or arr.ndim != 2 or arr.shape[1] not in (3, 6):
        raise InputError(
            f"{path}: {what} holds an array of shape {arr.shape} and dtype {arr.dtype}; "
            "expected (N, 3) points or (N, 6) points and normals"
        )


def _split_columns(arr: np.ndarray, path: pathlib.Path, what: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Split an ``(N, 3)`` or ``(N, 6)`` numeric array into points and optional normals."""
    _check_columns(arr, path, what)
    arr = np.array(arr, dtype=np.float64)  # a copy: never hand out a memmap or the caller's array
    if arr.shape[1] == 6:
        return np.ascontiguousarray(arr[:, :3]), np.ascontiguousarray(arr[:, 3:])
    return arr, None


def _check_readable(path: pathlib.Path) -> None:
    """Fail early, with a plain message, on the file-system problems every format shares."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        if path.is_symlink():
            raise InputError(f"{path}: is a link to {os.readlink(path)!r}, which does not exist — "
                             "check the link") from None
        raise InputError(f"{path}: file not found — check the path") from None
    except PermissionError:
        raise InputError(
            f"{path}: cannot be read (permission denied on a folder above it) — check the folder "
            "permissions"
        ) from None
    except OSError as exc:  # a link loop, a file used as a folder, a name too long
        raise InputError(f"{path}: cannot be read ({exc.strerror or _one_line(exc)}) — check the path") from None
    if stat.S_ISDIR(mode):
        raise InputError(f"{path}: is a folder, not a point file — give a file such as scan.ply")
    if not stat.S_ISREG(mode):
        # Opening a named pipe blocks until something writes to it, and the readers need a file they
        # can read more than once (sniffing, then parsing; plyfile memory-maps binary data).
        kind = "a named pipe" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else "a device"
        raise InputError(f"{path}: is {kind}, not a regular file — save the points to a file first")
    try:
        with open(path, "rb") as fh:
            first = fh.read(1)
    except PermissionError:
        raise InputError(
            f"{path}: cannot be read (permission denied) — check the file permissions"
        ) from None
    except OSError as exc:
        raise InputError(
            f"{path}: cannot be read ({exc.strerror or _one_line(exc)}) — check the disk, or copy the "
            "file to a local folder and try again"
        ) from None
    if not first:
        raise InputError(f"{path}: file is empty — re-export the point cloud")


# --------------------------------------------------------------------------------------------------
# readers


def _rows(element: str) -> str:
    return "vertices" if element == "vertex" else f"'{element}' rows"


def _read_ply(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    with _ply_vertex(path) as (data, normals):
        return _ply_columns(data, normals)


def _ply_columns(data: np.ndarray, normals: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (and normals) of rows of a PLY vertex array, as float64."""
    points = _as_xyz([data[p] for p in "xyz"])
    return points, _as_xyz([data[p] for p in _PLY_NORMALS]) if normals else None


@contextlib.contextmanager
def _ply_vertex(path: pathlib.Path) -> Iterator[tuple[np.ndarray, bool]]:
    """The checked vertex rows of a PLY file and whether they hold normals.

    Binary rows are memory-mapped by plyfile (valid also after the block), so a slice of them reads
    only its own part of the file; ASCII rows are parsed whole.
    """
    import plyfile

    fix = "re-export the file"
    with open(path, "rb") as fh:
        # bounded reads: a huge file of random bytes may have no newline at all
        magic = fh.readline(16).strip()
        # split as plyfile splits it, as text (whose whitespace includes control bytes such as 0x1e):
        # else a format line plyfile reads as ASCII opens here as binary, and plyfile's text wrapper of
        # the binary file closes it when collected, while it is still being read
        fmt = fh.readline(64).decode("ascii", "replace").split()
    if magic != b"ply" or len(fmt) < 2 or fmt[0] != "format":
        raise InputError(f"{path}: not a PLY file (it does not start with 'ply' and a format line) — {fix}")
    text = fmt[1] == "ascii"
    # plyfile reads the header line by line: bound it, or a file with no newline is read whole
    with open(path, "rb") as fh:
        head = fh.read(_MAX_HEADER_BYTES)
    if b"end_header" not in head:
        where = f" in its first {_MAX_HEADER_BYTES >> 20} MiB" if len(head) == _MAX_HEADER_BYTES else ""
        raise InputError(f"{path}: not a readable PLY file (its header has no end_header line{where}) — {fix}")

    # ASCII PLY is opened as text so that the stream position after parsing is meaningful (plyfile
    # wraps a binary stream in a TextIOWrapper it then discards); binary is memory-mapped by plyfile,
    # which also checks the file size against the header before touching the data.
    opener = (lambda: open(path, encoding="ascii")) if text else (lambda: open(path, "rb"))
    with opener() as fh:
        try:
            data = plyfile.PlyData.read(fh)
        except plyfile.PlyElementParseError as exc:
            element = exc.element
            if exc.message in ("early end-of-file", "early end-of-line") and element is not None:
                raise _truncated(path, "PLY", element.count, exc.row, _rows(element.name)) from None
            raise InputError(f"{path}: not a readable PLY file ({_one_line(exc)}) — {fix}") from None
        except Exception as exc:  # noqa: BLE001 -- plyfile raises many types on garbage; see _translating
            raise InputError(f"{path}: not a readable PLY file ({_one_line(exc)}) — {fix}") from None
        try:
            trailing = fh.read(1 << 16)
        except UnicodeDecodeError:  # bytes that are not ASCII after the last ASCII row: more data
            trailing = "\0"

        names = [el.name for el in data.elements]
        if "vertex" not in names:
            raise InputError(f"{path}: PLY file has no 'vertex' element (it has {names}) — {fix}")
        vertex = data["vertex"]
        # Data after the last element means the header under-counts its rows (plyfile stops reading
        # at the declared count and would silently drop the rest).  A lone trailing newline or a
        # few padding bytes, shorter than one row, are tolerated.
        row_bytes = vertex.data.dtype.itemsize
        extra = trailing.strip() if text else trailing
        if (text and extra) or (not text and len(extra) >= row_bytes):
            raise _more_data(path, "PLY", vertex.count, _rows("vertex"))
        props = vertex.data.dtype.names or ()
        missing = [p for p in "xyz" if p not in props]
        if missing:
            raise InputError(
                f"{path}: PLY vertices lack {', '.join(missing)} (they have {list(props)}) — {fix}"
            )
        used = list("xyz") + (list(_PLY_NORMALS) if set(_PLY_NORMALS) <= set(props) else [])
        lists = [p for p in used if vertex.data.dtype[p].kind not in "iuf"]
        if lists:
            raise InputError(f"{path}: PLY vertex properties {', '.join(lists)} are lists, not numbers — {fix}")
        yield vertex.data, len(used) == 6


def _check_text_start(path: pathlib.Path, what: str = "text", fix: str = "export the points as text",
                      offset: int = 0) -> None:
    """Refuse a file whose first ``_TEXT_SAMPLE_BYTES`` (from ``offset``) are not lines of UTF-8 text."""
    with open(path, "rb") as fh:
        fh.seek(offset)
        sample = fh.read(_TEXT_SAMPLE_BYTES)
    try:
        sample.decode("utf-8")
    except UnicodeDecodeError as exc:
        # a multi-byte character cut in two by the end of the sample is no error
        if not (len(sample) == _TEXT_SAMPLE_BYTES and exc.start >= len(sample) - 3
                and exc.reason == "unexpected end of data"):
            raise InputError(f"{path}: not a {what} file (it holds non-UTF-8 bytes) — {fix}") from None
    if b"\0" in sample:  # valid UTF-8, but no text file holds it
        raise InputError(f"{path}: not a {what} file (it holds NUL bytes) — {fix}")
    if len(sample) == _TEXT_SAMPLE_BYTES and max(map(len, sample.split(b"\n"))) > _MAX_LINE_CHARS:
        raise _long_line(path, fix=f"{fix}, one point a line")


def _long_line(path: pathlib.Path, number: int | None = None,
               fix: str = "export the points as text, one point a line") -> InputError:
    which = "a line" if number is None else f"line {number}"
    return InputError(f"{path}: {which} is longer than {_MAX_LINE_CHARS} characters (not a point text file) "
                      f"— {fix}")


def _lines(path: pathlib.Path) -> Iterator[tuple[int, str]]:
    """The lines of a text file with their 1-based numbers, each read with a bounded length."""
    with open(path, encoding="utf-8-sig") as fh:
        number = 0
        while line := fh.readline(_MAX_LINE_CHARS + 1):
            number += 1
            if len(line) > _MAX_LINE_CHARS:
                raise _long_line(path, number)
            yield number, line


def _first_lines(path: pathlib.Path, count: int) -> list[tuple[int, str]]:
    """Up to ``count`` non-blank, non-comment lines with their 1-based line numbers."""
    found = []
    for number, line in _lines(path):
        if line.strip() and not line.lstrip().startswith("#"):
            found.append((number, line))
            if len(found) == count:
                break
    return found


def _sniff_delimiter(line: str) -> str | None:
    for delimiter in _TEXT_DELIMITERS:
        if delimiter in line:
            return delimiter
    return None


def _fields(line: str, delimiter: str | None) -> list[str]:
    return [f.strip() for f in line.strip().split(delimiter)]


def _is_numeric_row(fields: list[str]) -> bool:
    try:
        [float(f) for f in fields]
    except ValueError:
        return False
    return True


def _not_text(path: pathlib.Path) -> InputError:
    return InputError(f"{path}: not a text file (it holds non-UTF-8 bytes) — export the points as text")


#: What to do about a text point file whose rows are not numbers.
_TEXT_FIX = "give numeric columns x y z, and optionally nx ny nz"
#: Header names of a text file's normal columns, in the order x, y, z (compared in lower case, without
#: spaces or punctuation: ``Nx``, ``normal_x``, ``//nx``).
_TEXT_NORMAL_NAMES = tuple(tuple(f"{prefix}{axis}" for axis in "xyz") for prefix in ("n", "normal", "normals"))
#: Columns 4 to 6 that a header does not name as normals are normals when they are unit vectors, to within
#: this, on the first _TEXT_NORMAL_ROWS data rows: colours (X Y Z R G B, the commonest six columns) and
#: intensities are not.
_TEXT_UNIT_TOLERANCE = 0.01
_TEXT_NORMAL_ROWS = 1000


def _text_columns(path: pathlib.Path, header_lines: int, delimiter: str | None, ncols: int
                  ) -> tuple[list[int], list[int] | None]:
    """The columns of a text point file that hold x y z, and those that hold normals (``None``: none).

    A header line that names x, y and z (in any case: ``X``, ``//X``) places them, else they are the first
    three columns; one that names normals (:data:`_TEXT_NORMAL_NAMES`) places those.  Otherwise the 4th to
    6th columns are normals when they are unit vectors (:data:`_TEXT_UNIT_TOLERANCE`).  Other columns
    (colours, intensities) are read past.
    """
    names = []
    if header_lines:
        line = _text_head(path)[0][1]
        # only the names of columns the data has (a header may name more than its rows hold)
        names = [re.sub(r"[^0-9a-z]", "", name.lower()) for name in _fields(line, _sniff_delimiter(line))][:ncols]
    xyz = [names.index(a) for a in "xyz"] if all(a in names for a in "xyz") else [0, 1, 2]
    for spelling in _TEXT_NORMAL_NAMES:
        if all(name in names for name in spelling):
            return xyz, [names.index(name) for name in spelling]
    if ncols < 6 or {3, 4, 5} & set(xyz):
        return xyz, None
    try:
        with open(path, encoding="utf-8-sig") as fh, warnings.catch_warnings():
            warnings.filterwarnings("ignore", "loadtxt: input contained no data", UserWarning)
            rows = np.loadtxt(itertools.islice(fh, header_lines, header_lines + _TEXT_NORMAL_ROWS),
                              dtype=np.float64, delimiter=delimiter, comments="#", ndmin=2)
    except (ValueError, UnicodeDecodeError):
        return xyz, None  # the whole file's parse names the bad line
    if rows.shape[1] == ncols and np.all(np.abs(np.linalg.norm(rows[:, 3:6], axis=1) - 1.0) <= _TEXT_UNIT_TOLERANCE):
        return xyz, [3, 4, 5]
    log.info("%s: columns 4 to 6 are not unit vectors, not normals: read past", path)
    return xyz, None


def _text_points(table: np.ndarray, columns: tuple[list[int], list[int] | None]) -> tuple[np.ndarray, np.ndarray | None]:
    """The points and normals (or ``None``) of a parsed text table, from :func:`_text_columns`."""
    xyz, normals = columns
    return (np.ascontiguousarray(table[:, xyz]),
            None if normals is None else np.ascontiguousarray(table[:, normals]))


def _read_text(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    header_lines, delimiter, ncols = _text_layout(path)
    columns = _text_columns(path, header_lines, delimiter, ncols)
    try:
        # numpy's C parser does the bulk work; only on failure do we walk the lines in Python to
        # name the offending one (loadtxt's own row numbers skip blanks and the header).
        arr = np.loadtxt(
            path, dtype=np.float64, delimiter=delimiter, comments="#", skiprows=header_lines,
            ndmin=2, encoding="utf-8-sig",
        )
    except (ValueError, UnicodeDecodeError) as exc:
        raise _explain_text_error(path, header_lines, delimiter, ncols, _TEXT_FIX, exc) from None
    return _text_points(arr, columns)


def _text_head(path: pathlib.Path) -> list:
    """The first two lines of a text point file (checked to be text with data rows)."""
    _check_text_start(path)
    try:
        head = _first_lines(path, 2)
    except UnicodeDecodeError:
        raise _not_text(path) from None
    if not head:
        raise InputError(f"{path}: holds no data rows — export the points as text, one point a line")
    return head


def _text_layout(path: pathlib.Path) -> tuple[int, str | None, int]:
    """Lines to skip (up to the header line, if any), the delimiter and the number of columns."""
    fix = _TEXT_FIX
    head = _text_head(path)

    # One header line is allowed: the first line is a header if it does not parse as numbers.  The
    # delimiter is sniffed from the first *data* line, since a header may be spelled differently.
    header_lines = 0
    number, line = head[0]
    if not _is_numeric_row(_fields(line, _sniff_delimiter(line))):
        header_lines = number
        if len(head) < 2:
            raise InputError(f"{path}: holds a header line but no data rows — export the points again")
        number, line = head[1]
    delimiter = _sniff_delimiter(line)
    ncols = len(_fields(line, delimiter))
    if ncols < 3:
        raise InputError(f"{path}: line {number} has {ncols} columns — {fix}")
    return header_lines, delimiter, ncols


def _explain_text_error(
    path: pathlib.Path, header_lines: int, delimiter: str | None, ncols: int, fix: str, exc: Exception
) -> InputError:
    """Find the first bad line of a text point file and say what is wrong with it."""
    try:
        for number, line in _lines(path):
            content = line.split("#", 1)[0]
            if number <= header_lines or not content.strip():
                continue
            fields = _fields(content, delimiter)
            if len(fields) != ncols:
                return InputError(
                    f"{path}: line {number} has {len(fields)} columns, earlier lines have {ncols} — {fix}"
                )
            if not _is_numeric_row(fields):
                shown = line.strip()
                shown = shown if len(shown) <= 60 else shown[:57] + "..."
                return InputError(f"{path}: line {number} is not numeric ({shown!r}) — {fix}")
    except UnicodeDecodeError:
        return _not_text(path)
    except InputError as too_long:
        return too_long
    return InputError(f"{path}: not a readable point text file ({_one_line(exc)}) — {fix}")


#: Leading bytes of a .npy file and of a zip archive (.npz).  Checked before np.load because, on
#: anything else, np.load assumes a pickle and its error suggests loading the file unsafely.
_NPY_MAGIC = b"\x93NUMPY"
_ZIP_MAGIC = b"PK\x03\x04"
#: Largest ratio of deflate (a 258-byte match coded in about 2 bits): a zip member claiming to unpack
#: to more than this many times its stored size is corrupted, and is refused before numpy allocates it.
_DEFLATE_MAX_RATIO = 1032


def _numpy_kind(path: pathlib.Path) -> str | None:
    """``"npy"``, ``"npz"`` or ``None``, from the file's leading bytes (whatever its suffix says)."""
    with open(path, "rb") as fh:
        head = fh.read(max(len(_NPY_MAGIC), len(_ZIP_MAGIC)))
    return "npy" if head.startswith(_NPY_MAGIC) else "npz" if head.startswith(_ZIP_MAGIC) else None


def _read_numpy(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    """A .npy or .npz file; which of the two is decided by its leading bytes, not by its suffix."""
    suffix = path.suffix.lower()
    kind = _numpy_kind(path)
    if kind is None:
        fix = ("save an (N, 3) or (N, 6) array with numpy.save" if suffix == ".npy"
               else "save with numpy.savez(file, points=..., normals=...)")
        raise InputError(f"{path}: not a NumPy {suffix} file (it lacks the format's leading bytes) — {fix}")
    if f".{kind}" != suffix:
        log.info("%s: holds a NumPy .%s %s; read as such", path, kind, "array" if kind == "npy" else "archive")
    return _read_npy(path) if kind == "npy" else _read_npz(path)


def _npy_header(fh, path: pathlib.Path, what: str, fix: str) -> tuple[tuple[int, ...], np.dtype, int]:
    """Shape, dtype and header length of the .npy data that ``fh`` starts at."""
    with _translating(path, what, fix):
        version = np.lib.format.read_magic(fh)
        # version 3.0 differs from 2.0 only in allowing UTF-8 field names
        read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = read(fh)
        return tuple(shape), dtype, fh.tell()


def _check_npy_size(shape: tuple[int, ...], dtype: np.dtype, data_bytes: int, path: pathlib.Path, what: str,
                    fix: str) -> None:
    """Refuse .npy data that holds Python objects, or more or fewer bytes than its header declares."""
    if dtype.hasobject:
        raise InputError(f"{path}: not a readable {what} file (it holds Python objects, which are never "
                         f"loaded) — {fix}")
    if any(d < 0 for d in shape):
        raise InputError(f"{path}: not a readable {what} file (its header gives the shape {shape}) — {fix}")
    rows = shape[0] if shape else 1
    row_bytes = dtype.itemsize * math.prod(shape[1:])
    declared = rows * row_bytes
    if data_bytes < declared:
        raise _truncated(path, what, rows, data_bytes // row_bytes if row_bytes else 0)
    if data_bytes - declared >= max(row_bytes, 1):
        raise _more_data(path, what, rows)


#: What to do about a .npy file that does not hold points.
_NPY_FIX = "save an (N, 3) or (N, 6) array with numpy.save"


def _check_npy(path: pathlib.Path) -> tuple[int, ...]:
    """Check a .npy file's header against its size; its shape."""
    with open(path, "rb") as fh:
        shape, dtype, header = _npy_header(fh, path, "NumPy .npy", _NPY_FIX)
    _check_npy_size(shape, dtype, path.stat().st_size - header, path, "NumPy .npy", _NPY_FIX)
    return shape


def _read_npy(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    fix = _NPY_FIX
    _check_npy(path)
    with _translating(path, "NumPy .npy", fix):
        # allow_pickle=False: a point file must never be able to run code on load
        arr = np.load(path, allow_pickle=False)
        return _split_columns(np.asarray(arr), path, "the file")


def _npz_array(npz, key: str, path: pathlib.Path, fix: str) -> np.ndarray:
    """Array ``key`` of an open .npz, after checking its header against the member's size."""
    what = f"NumPy .npz ('{key}')"
    zf = npz.zip
    name = f"{key}.npy" if f"{key}.npy" in zf.namelist() else key
    info = zf.getinfo(name)
    # numpy stores or deflates; the other methods zip knows have no useful bound
    ratio = {zipfile.ZIP_STORED: 1, zipfile.ZIP_DEFLATED: _DEFLATE_MAX_RATIO}.get(info.compress_type)
    if ratio is not None and info.file_size > ratio * info.compress_size:
        raise InputError(f"{path}: {what} claims to unpack {info.compress_size} bytes to {info.file_size} — "
                         "the file is corrupted; re-export the file")
    with zf.open(info) as fh:
        if not fh.read(len(_NPY_MAGIC)).startswith(_NPY_MAGIC):
            raise InputError(f"{path}: {what} is not a NumPy array — {fix}")
        fh.seek(0)
        shape, dtype, header = _npy_header(fh, path, what, fix)
    _check_npy_size(shape, dtype, info.file_size - header, path, what, fix)
    return npz[key]


def _read_npz(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    fix = "save with numpy.savez(file, points=..., normals=...)"
    # np.load is given an open file: on a broken archive it would leave its own one open
    with _translating(path, "NumPy .npz", fix), open(path, "rb") as fh:
        with np.load(fh, allow_pickle=False) as npz:
            keys = list(npz.files)
            if "points" in keys:
                points, extra = _split_columns(_npz_array(npz, "points", path, fix), path, "'points'")
                if extra is not None:
                    raise InputError(f"{path}: 'points' must have 3 columns when stored by name — {fix}")
                if "normals" not in keys:
                    return points, None
                normals, _ = _split_columns(_npz_array(npz, "normals", path, fix), path, "'normals'")
                if normals.shape != points.shape:
                    raise InputError(
                        f"{path}: 'normals' has shape {normals.shape} but 'points' has {points.shape} — {fix}"
                    )
                return points, normals
            if len(keys) == 1:
                return _split_columns(_npz_array(npz, keys[0], path, fix), path, f"'{keys[0]}'")
            raise InputError(f"{path}: .npz holds arrays {keys} but no 'points' — {fix}")


#: pypcd4 stops reading a PCD header after this many lines without DATA (PCL writes 10 or 11).
_PCD_HEADER_LINES = 10
#: Most values (the sum of COUNT) a PCD point may have: feature descriptors reach a few hundred
#: (SHOT 352); a corrupted COUNT of a billion would otherwise build a billion-field dtype.
_MAX_PCD_VALUES = 10_000
#: Largest ratio of LZF (PCD binary_compressed): a 3-byte back-reference copies at most 264 bytes.
_LZF_MAX_RATIO = 100


def _pcd_header(path: pathlib.Path, fix: str) -> tuple[list[str], int]:
    """The header lines of a PCD file as pypcd4 reads them, and the byte where its data starts."""
    with open(path, "rb") as fh:
        head = fh.read(_MAX_HEADER_BYTES)
    lines: list[str] = []
    pos = 0
    while len(lines) < _PCD_HEADER_LINES and not (lines and lines[-1].startswith("DATA")):
        end = head.find(b"\n", pos)
        if end < 0:
            break
        try:
            line = head[pos:end].decode("utf-8").strip()
        except UnicodeDecodeError:
            raise InputError(f"{path}: not a PCD file (its header is not text) — {fix}") from None
        pos = end + 1
        if line and not line.startswith("#"):
            lines.append(line)
    if not (lines and lines[-1].startswith("DATA")):
        raise InputError(f"{path}: not a readable PCD file (no DATA line ends its header) — {fix}")
    return lines, pos


def _check_pcd_data(path: pathlib.Path, metadata, start: int, fix: str) -> None:
    """Refuse a PCD file whose data cannot hold, or holds more than, the points its header declares."""
    count, row = metadata.points, metadata.build_dtype().itemsize
    data = path.stat().st_size - start
    encoding = metadata.data.value
    if encoding == "ascii":
        _check_text_start(path, "PCD ASCII", fix, offset=start)
    elif encoding == "binary":
        if data < count * row:
            raise _truncated(path, "PCD", count, data // row)
        if data - count * row >= row:
            raise _more_data(path, "PCD", count)
    else:  # binary_compressed: two uint32 sizes, then the LZF data of every field in turn
        with open(path, "rb") as fh:
            fh.seek(start)
            sizes = fh.read(8)
        if len(sizes) < 8:
            raise _truncated(path, "PCD", count, 0)
        packed, unpacked = struct.unpack("<II", sizes)
        if packed > data - 8:
            raise InputError(f"{path}: PCD file is truncated (its compressed data takes {packed} bytes, the file "
                             f"holds {data - 8}) — re-export the file")
        if unpacked != count * row or unpacked > _LZF_MAX_RATIO * packed:
            raise InputError(f"{path}: PCD header says {count} points of {row} bytes but its compressed data "
                             f"unpacks to {unpacked} bytes — the file is corrupted; re-export the file")
        if data - 8 - packed >= row:
            raise _more_data(path, "PCD", count)


def _read_pcd(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    pypcd4 = _import_extra("pypcd4", ".pcd", "pcd")
    fix = "re-export the file"
    lines, start = _pcd_header(path, fix)
    with _translating(path, "PCD", fix):
        metadata = pypcd4.MetaData.parse_header(lines)
    if sum(metadata.count) > _MAX_PCD_VALUES:
        raise InputError(f"{path}: PCD header declares {sum(metadata.count)} values per point (COUNT) — the "
                         "file is corrupted; re-export the file")
    if metadata.width * metadata.height != metadata.points:
        raise InputError(f"{path}: PCD header says WIDTH x HEIGHT = {metadata.width} x {metadata.height} but "
                         f"POINTS {metadata.points} — the file is corrupted; re-export the file")
    with _translating(path, "PCD", fix):
        _check_pcd_data(path, metadata, start, fix)
        cloud = pypcd4.PointCloud.from_path(path)
        fields = cloud.fields
    # pypcd4 reads what is there without comparing with the header's POINTS (ASCII data above all),
    # so a truncated file would silently give fewer points, an under-counting header more.
    data = np.atleast_1d(cloud.pc_data)  # loadtxt gives a 0-d record for a one-point ASCII file
    held, declared = len(data), cloud.points
    if held < declared:
        raise _truncated(path, "PCD", declared, held)
    if held > declared:
        raise _more_data(path, "PCD", declared)
    missing = [f for f in "xyz" if f not in fields]
    if missing:
        raise InputError(
            f"{path}: PCD file lacks fields {', '.join(missing)} (it has {list(fields)}) — {fix}"
        )
    points = _as_xyz([data[f] for f in "xyz"])
    normals = _as_xyz([data[f] for f in _PCD_NORMALS]) if set(_PCD_NORMALS) <= set(fields) else None
    # In PCL's organized clouds NaN coordinates are the format's own marker for "no return here",
    # not a measurement, so such rows are dropped like invalid points in E57.
    keep = np.isfinite(points).all(axis=1)
    if not keep.all():
        points = points[keep]
        normals = None if normals is None else normals[keep]
    return points, normals


# LAS / LAZ.  The header is checked against the file size here, with struct, before laspy reads
# anything: laspy trusts its counts (it reads a billion variable-length records if the header says
# so), and lazrs allocates the chunk table the file announces, aborting the process when that fails.

#: Least header size of each LAS 1.x minor version (the fields up to the 1.4 point counts).
_LAS_HEADER_BYTES = {0: 227, 1: 227, 2: 227, 3: 235, 4: 375}
#: Bytes of a point record of each point format 0 - 10 (extra bytes may follow).
_LAS_POINT_BYTES = (20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67)
#: Header bytes of a variable-length record and of an extended one (LAS 1.4).
_LAS_VLR_BYTES, _LAS_EVLR_BYTES = 54, 60
#: Most (extended) variable-length records a LAS file may list: real files carry a handful
#: (projection, extra bytes, LASzip, COPC index); each is walked before laspy reads them.
_MAX_LAS_VLRS = 65_535
#: Most points a LAZ file may hold per byte of compressed data: identical points in LASzip's
#: 50,000-point chunks take about 150 points a byte (measured), real scans 1 - 3 bytes a point.
_MAX_LAZ_POINTS_PER_BYTE = 500
#: Points decoded at a time, so memory follows the points a file really holds, not what it claims.
_LAS_CHUNK_POINTS = 1 << 20
#: Points of a LAZ file decoded at once, by laspy's parallel decoder: two to three of LASzip's 50,000-point
#: chunks, which the cores decode side by side (the one-thread decoder left all but one core idle), in
#: 4.5 MB of records (point format 3).
_LAZ_DECODE_POINTS = 1 << 17
#: Largest LASzip chunk (in bytes of records) decoded by the parallel decoder: LASzip writes chunks of
#: 50,000 points (at most 3.4 MB of records of point format 10); a file of larger ones is decoded on one thread.
_LAZ_PARALLEL_CHUNK_BYTES = 64 << 20
#: The variable-length record that describes LASzip compression.
_LASZIP_USER_ID, _LASZIP_RECORD_ID = b"laszip encoded", 22204
#: Layers of each "layered" LASzip item (LAS 1.4 point formats 6 - 10), by item type: Point14 (x, y
#: and returns, z, classification, flags, intensity, scan angle, user data, point source, GPS time),
#: RGB14, RGBNIR14 (RGB, NIR), Wavepacket14; Byte14 has one layer per extra byte (``None``).
_LASZIP_LAYERS = {10: 9, 11: 1, 12: 2, 13: 1, 14: None}


class _LasLayout(NamedTuple):
    """What :func:`_las_layout` found in a LAS/LAZ header, checked against the file."""

    compressed: bool
    count: int         # points the header declares
    offset: int        # byte where the point data starts
    end: int           # byte where it must end: extended records, waveforms or the file's end follow
    laszip: bytes      # payload of the LASzip record (compressed files), else b""
    record_bytes: int  # bytes of one point record


def _las_layout(path: pathlib.Path, what: str) -> _LasLayout:
    """Read and check the LAS header, its variable-length records and sizes, without laspy."""
    size = path.stat().st_size

    def bad(problem: str) -> InputError:
        return InputError(f"{path}: {problem} — the file is corrupted; re-export the file")

    with open(path, "rb") as fh:
        head = fh.read(_LAS_HEADER_BYTES[4])
        if not head.startswith(b"LASF"):
            raise InputError(f"{path}: not a {what} file (it does not start with 'LASF') — re-export the file")
        if len(head) < _LAS_HEADER_BYTES[0]:
            raise InputError(f"{path}: {what} header is truncated ({len(head)} bytes) — re-export the file")
        major, minor = head[24], head[25]
        if major != 1 or minor not in _LAS_HEADER_BYTES:
            raise InputError(f"{path}: {what} version {major}.{minor} is not supported (1.0 to 1.4 are) — "
                             "re-export the file as LAS 1.4 or older")
        header_size, offset, n_vlrs, point_format, record_bytes, count = struct.unpack_from("<HIIBHI", head, 94)
        if not _LAS_HEADER_BYTES[minor] <= header_size <= min(size, offset):
            raise bad(f"{what} header size {header_size} does not fit version 1.{minor} and the point data "
                      f"offset {offset}")
        if offset > size:
            raise bad(f"{what} point data would start at byte {offset}, past the end of the {size}-byte file")
        if n_vlrs > _MAX_LAS_VLRS or header_size + n_vlrs * _LAS_VLR_BYTES > offset:
            raise bad(f"{what} header lists {n_vlrs} variable-length records, more than fit before the point "
                      f"data at byte {offset}")
        laszip = b""
        pos = header_size
        for i in range(n_vlrs):
            fh.seek(pos)
            record = fh.read(_LAS_VLR_BYTES)
            length = struct.unpack_from("<H", record, 20)[0] if len(record) == _LAS_VLR_BYTES else offset
            if pos + _LAS_VLR_BYTES + length > offset:
                raise bad(f"{what} variable-length record {i + 1} runs past the start of the point data")
            user, (record_id,) = record[2:18].rstrip(b"\0"), struct.unpack_from("<H", record, 18)
            if (user, record_id) == (_LASZIP_USER_ID, _LASZIP_RECORD_ID):
                laszip = fh.read(length)
            pos += _LAS_VLR_BYTES + length

        # laspy's rule: bit 7 set and bit 6 clear marks compressed points
        fmt, compressed = point_format & 0x3F, point_format & 0xC0 == 0x80
        if fmt >= len(_LAS_POINT_BYTES) or record_bytes < _LAS_POINT_BYTES[fmt]:
            raise bad(f"{what} point format {fmt} with {record_bytes}-byte records is not valid")
        if compressed and not laszip:
            raise bad(f"{what} points are marked compressed but the file has no LASzip record")
        scales, offsets = struct.unpack_from("<3d", head, 131), struct.unpack_from("<3d", head, 155)
        # the integers are int32: every coordinate lies within |scale| * 2**31 + |offset|
        if not all(math.isfinite(abs(k) * 2.0**31 + abs(o)) and k != 0 for k, o in zip(scales, offsets)):
            shown = ", ".join(f"{v:.3g}" for v in scales + offsets)
            raise bad(f"{what} scale factors and offsets must be finite and the scales non-zero, the header "
                      f"has {shown}")

        end = size
        if minor >= 4:
            first_evlr, n_evlrs, count64 = struct.unpack_from("<QIQ", head, 235)
            if count not in (0, count64):  # the legacy 32-bit count is 0 or the same number
                raise bad(f"{what} header holds two different point counts, {count} and {count64}")
            count = count64
            if n_evlrs:
                if (n_evlrs > _MAX_LAS_VLRS or first_evlr < offset
                        or first_evlr + n_evlrs * _LAS_EVLR_BYTES > size):
                    raise bad(f"{what} header lists {n_evlrs} extended records from byte {first_evlr}, which "
                              f"do not fit between the point data and the end of the file")
                pos = first_evlr
                for i in range(n_evlrs):
                    fh.seek(pos)
                    record = fh.read(_LAS_EVLR_BYTES)
                    length = struct.unpack_from("<Q", record, 20)[0] if len(record) == _LAS_EVLR_BYTES else size
                    pos += _LAS_EVLR_BYTES + length
                    if pos > size:
                        raise bad(f"{what} extended record {i + 1} runs past the end of the file")
                end = first_evlr
        (global_encoding,) = struct.unpack_from("<H", head, 6)
        if minor >= 3 and global_encoding & 2:  # waveform packets stored in the file, after the points
            (waveforms,) = struct.unpack_from("<Q", head, 227)
            if offset <= waveforms < end:
                end = waveforms

    data = end - offset
    if not compressed:
        if count * record_bytes > data:
            raise _truncated(path, what, count, data // record_bytes)
        if data - count * record_bytes >= record_bytes:
            raise _more_data(path, what, count)
    elif count > _MAX_LAZ_POINTS_PER_BYTE * data:
        raise bad(f"{what} header says {count} points, more than {data} bytes of compressed data can hold")
    return _LasLayout(compressed, count, offset, end, laszip, record_bytes)


def _check_laz_chunks(path: pathlib.Path, layout: _LasLayout, lazrs, what: str) -> int:
    """Check the LASzip chunk table against the file and the header's count before lazrs decodes; the
    points of its largest chunk, as the LASzip record declares them."""

    def bad(problem: str) -> InputError:
        return InputError(f"{path}: {problem} — the file is corrupted; re-export the file")

    first = layout.offset + 8  # the chunks follow the 8-byte offset of the chunk table
    with open(path, "rb") as fh:
        fh.seek(layout.offset)
        raw = fh.read(8)
        if len(raw) < 8:
            raise _truncated(path, what, layout.count, 0)
        (table,) = struct.unpack("<q", raw)
        if table == -1:  # written by a streaming writer: the offset is in the file's last 8 bytes
            fh.seek(-8, os.SEEK_END)
            (table,) = struct.unpack("<q", fh.read(8))
        if not first <= table <= layout.end - 8:
            raise bad(f"{what} chunk table at byte {table} lies outside the compressed points")
        fh.seek(table)
        _, n_chunks = struct.unpack("<II", fh.read(8))
        # every chunk starts with one point stored raw, of at least the smallest record size
        if n_chunks * min(_LAS_POINT_BYTES) > table - first:
            raise bad(f"{what} chunk table lists {n_chunks} chunks, more than {table - first} bytes of "
                      "compressed points can hold")
        with _translating(path, what, "re-export the file"):
            vlr = lazrs.LazVlr(layout.laszip)
            fh.seek(layout.offset)
            chunks = lazrs.read_chunk_table(fh, vlr)
    held_bytes = sum(int(b) for _, b in chunks)
    if held_bytes != table - first:
        raise bad(f"{what} chunk table lists {held_bytes} bytes of compressed points, the file holds "
                  f"{table - first}")
    _check_laz_layers(path, layout.laszip, first, [int(b) for _, b in chunks], what)
    if vlr.uses_variable_size_chunks():
        held = sum(int(n) for n, _ in chunks)
        if held < layout.count:
            raise _truncated(path, what, layout.count, held)
        if held > layout.count:
            raise _more_data(path, what, layout.count)
        return max((int(n) for n, _ in chunks), default=0)
    # chunks of chunk_size points; the last may hold fewer
    size = int(vlr.chunk_size())
    if layout.count > len(chunks) * size:
        raise _truncated(path, what, layout.count, len(chunks) * size)
    if layout.count <= (len(chunks) - 1) * size:
        raise _more_data(path, what, layout.count)
    return size


def _check_laz_layers(path: pathlib.Path, laszip: bytes, first: int, chunk_bytes: list[int], what: str) -> None:
    """Check that the layers of every chunk of a layered LAZ file fit in the chunk.

    A layered chunk is the first point stored raw, a point count, the byte size of every layer and
    the layers; lazrs allocates each layer at the size the chunk announces, and aborts the process
    when that fails, so the sizes are checked here first.  Point formats 0 - 5 are not layered.
    """
    n_items = struct.unpack_from("<H", laszip, 32)[0] if len(laszip) >= 34 else len(laszip)
    if len(laszip) < 34 + 6 * n_items:
        raise InputError(f"{path}: {what} LASzip record is cut short — the file is corrupted; re-export the file")
    items = [struct.unpack_from("<HHH", laszip, 34 + 6 * i) for i in range(n_items)]  # type, size, version
    if not any(kind in _LASZIP_LAYERS for kind, _, _ in items):
        return
    raw = sum(size for _, size, _ in items)
    n_layers = sum(size if _LASZIP_LAYERS.get(kind, 0) is None else _LASZIP_LAYERS.get(kind, 0)
                   for kind, size, _ in items)
    start = first
    with open(path, "rb") as fh:
        for i, size in enumerate(chunk_bytes):
            fh.seek(start + raw + 4)
            sizes = fh.read(4 * n_layers)
            layers = sum(struct.unpack(f"<{n_layers}I", sizes)) if len(sizes) == 4 * n_layers else size
            if raw + 4 + len(sizes) + layers > size:
                raise InputError(f"{path}: {what} chunk {i + 1} announces more compressed data than it holds — "
                                 "the file is corrupted; re-export the file")
            start += size


def _read_las(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    parts = list(_las_chunks(path, _LAS_CHUNK_POINTS))
    points = np.concatenate([p for p, _ in parts])
    return points, None if parts[0][1] is None else np.concatenate([n for _, n in parts])


def _las_chunks(path: pathlib.Path, chunk: int) -> Iterator[tuple[np.ndarray, np.ndarray | None]]:
    """The points (and normals) of a LAS/LAZ file, ``chunk`` at a time, in file order.

    At least one (perhaps empty) chunk is given; a file that holds fewer points than its header
    declares fails after its last chunk.
    """
    suffix = path.suffix.lower()
    laspy = _import_extra("laspy", suffix, "las")
    what = suffix[1:].upper()
    fix = "re-export the file"
    if suffix == ".laz" and not laspy.LazBackend.detect_available():
        raise _missing_extra(suffix, "las")
    layout = _las_layout(path, what)
    backend = None
    if layout.compressed:
        if not laspy.LazBackend.detect_available():
            raise _missing_extra(".laz", "las")
        largest = _check_laz_chunks(path, layout, _import_extra("lazrs", ".laz", "las"), what)
        # LASzip's chunks decoded over the cores, _LAZ_DECODE_POINTS at a time, handed out ``chunk`` at a
        # time.  The parallel decoder sets aside a whole chunk at the size the LASzip record declares, and
        # aborts the process when it cannot (a damaged record declared chunks of billions of points): the
        # one-thread decoder writes into laspy's buffers, whose size follows the points read.
        parallel = largest * layout.record_bytes <= _LAZ_PARALLEL_CHUNK_BYTES
        backend = laspy.LazBackend.LazrsParallel if parallel else laspy.LazBackend.Lazrs
    held = 0
    with _translating(path, what, fix), _library_logs("laspy"):
        with laspy.open(path, laz_backend=backend) as reader:
            header = reader.header
            names = {name.lower(): name for name in header.point_format.extra_dimension_names}
            spelling = next((s for s in _LAS_NORMALS if all(n in names for n in s)), None)
            scales, offsets = header.scales, header.offsets
            decoded = reader.chunk_iterator(max(chunk, _LAZ_DECODE_POINTS) if layout.compressed else chunk)
            for records in (part[start:start + chunk] for part in decoded for start in range(0, len(part), chunk)):
                # errstate: extra dimensions with odd scales may overflow; the result is then refused
                # as non-finite.  Held only here, not while the caller has the chunk.
                with np.errstate(all="ignore"):
                    # the integer records times scale plus offset, in float64 -- the full precision of
                    # the file (never cast through float32, which loses millimetres at 1e6)
                    points = _as_xyz([np.asarray(records[axis]) * scales[i] + offsets[i]
                                      for i, axis in enumerate("XYZ")])
                    normals = None
                    if spelling is not None:
                        columns = [np.asarray(records[names[n]]) for n in spelling]
                        if any(c.ndim != 1 for c in columns):
                            raise InputError(f"{path}: {what} normal dimensions {[names[n] for n in spelling]} "
                                             "hold several values per point, not one — re-export the file")
                        normals = _as_xyz(columns)
                held += len(points)
                yield points, normals
    if held != layout.count:
        raise _truncated(path, what, layout.count, held)
    if not held:
        yield np.empty((0, 3)), None if spelling is None else np.empty((0, 3))


#: Points read from an E57 scan per call into bounded buffers: memory follows what the file stores,
#: whatever count its header claims.
_E57_CHUNK_POINTS = 1 << 20
_E57_CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
_E57_SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")


def _e57_pose(header, path: pathlib.Path, index: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Rotation matrix and translation of a scan's pose (``None`` without one), checked to be finite."""
    if not header.has_pose():
        return None
    pose = header.node["pose"]

    def values(name: str, keys: str, default: tuple[float, ...]) -> np.ndarray:
        if not pose.isDefined(name):
            return np.array(default, dtype=np.float64)
        node = pose[name]
        return np.array([node[k].value() if node.isDefined(k) else d for k, d in zip(keys, default)],
                        dtype=np.float64)

    q = values("rotation", "wxyz", (1.0, 0.0, 0.0, 0.0))
    t = values("translation", "xyz", (0.0, 0.0, 0.0))
    norm = float(np.linalg.norm(q)) if np.isfinite(q).all() else math.nan
    if not (np.isfinite(t).all() and math.isfinite(norm) and norm > 0):
        raise InputError(f"{path}: E57 scan {index} has a pose that is not a finite rotation and translation "
                         f"(quaternion {q.tolist()}, translation {t.tolist()}) — re-export the file")
    w, x, y, z = q / norm
    rotation = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                         [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                         [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    return rotation, t


def _e57_scan(e57, index: int, path: pathlib.Path) -> np.ndarray:
    """The valid points of scan ``index`` in the file's common frame."""
    header = e57.get_header(index)
    fields = set(header.point_fields)
    if set(_E57_CARTESIAN) <= fields:
        coords, state = _E57_CARTESIAN, "cartesianInvalidState"
    elif set(_E57_SPHERICAL) <= fields:
        coords, state = _E57_SPHERICAL, "sphericalInvalidState"
    else:
        raise InputError(f"{path}: E57 scan {index} has no cartesian or spherical coordinates (it has "
                         f"{sorted(fields)}) — re-export the file")
    names = list(coords) + ([state] if state in fields else [])
    pose = _e57_pose(header, path, index)
    declared = int(header.point_count)
    # Bounded buffers, read until the reader has nothing more: pye57's read_scan allocates what the
    # header claims and returns the unfilled rest as points (uninitialised memory).
    buffers_data, buffers = e57.make_buffers(names, max(1, min(declared, _E57_CHUNK_POINTS)))
    reader = header.points.reader(buffers)
    parts, held = [], 0
    try:
        while held <= declared and (n := reader.read()):
            held += n
            parts.append(np.column_stack([buffers_data[name][:n].astype(np.float64) for name in names]))
    finally:
        reader.close()
    if held < declared:
        raise _truncated(path, "E57", declared, held, f"points in scan {index}")
    if held > declared:
        raise _more_data(path, "E57", declared, f"points in scan {index}")
    table = np.concatenate(parts) if parts else np.empty((0, len(names)))
    if state in fields:  # 0 marks a valid return; invalid ones are no measurement
        table = table[table[:, 3] == 0]
    if coords == _E57_SPHERICAL:
        from pye57.utils import convert_spherical_to_cartesian

        xyz = np.asarray(convert_spherical_to_cartesian(table[:, :3]), dtype=np.float64)
    else:
        xyz = table[:, :3]
    if pose is not None:
        rotation, translation = pose
        xyz = xyz @ rotation.T + translation
    return np.ascontiguousarray(xyz, dtype=np.float64)


def _read_e57(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    pye57 = _import_extra("pye57", ".e57", "e57")
    with _translating(path, "E57", "re-export the file"), np.errstate(all="ignore"):
        with pye57.E57(str(path)) as e57:
            # Every scan, each moved into the file's common frame by its pose.  pye57 reads no
            # normals, so E57 clouds come without them.
            scans = [_e57_scan(e57, i, path) for i in range(e57.scan_count)]
    if not scans:
        return np.empty((0, 3)), None
    return np.vstack(scans), None


_READERS: dict[str, Callable[[pathlib.Path], tuple[np.ndarray, np.ndarray | None]]] = {
    ".ply": _read_ply,
    ".xyz": _read_text,
    ".txt": _read_text,
    ".csv": _read_text,
    ".asc": _read_text,
    ".npy": _read_numpy,
    ".npz": _read_numpy,
    ".pcd": _read_pcd,
    ".las": _read_las,
    ".laz": _read_las,
    ".e57": _read_e57,
}

#: File suffixes :func:`read_points` understands.
POINT_FORMATS: tuple[str, ...] = tuple(_READERS)


def read_points(path: PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a point cloud, choosing the format by the file suffix (case-insensitive).

    Parameters
    ----------
    path : str or os.PathLike
        A file with one of the suffixes in :data:`POINT_FORMATS`.  Text files (``.xyz .txt .csv
        .asc``) hold numeric columns, optionally under one header line, separated by ``,``, ``;``, tabs or
        spaces; ``#`` starts a comment.  x y z are the columns the header names so (any case: ``X``,
        ``//X``), else the first three; normals are the columns it names ``nx ny nz`` (or ``normal_x``
        ...), else the 4th to 6th where they are unit vectors; other columns (colours, intensities:
        ``X Y Z R G B``) are read past.  ``.npy`` holds an ``(N, 3)`` or
        ``(N, 6)`` array, ``.npz`` arrays ``points`` and optionally ``normals`` (or one array).
        PLY, PCD and LAS/LAZ normals are read when the file has them (``nx ny nz``;
        ``normal_x normal_y normal_z``; LAS extra dimensions of either spelling).

    Returns
    -------
    points : (N, 3) float64 ndarray
        In the file's own coordinates, at the file's full precision (LAS: scaled and offset in
        float64; E57: every scan moved into the common frame by its pose).
    normals : (N, 3) float64 ndarray or None
        As stored (not re-normalised), or ``None`` when the file has none.

    Raises
    ------
    InputError
        The suffix is unknown, the file is missing, not a regular file (a folder, pipe or socket),
        empty, unreadable or malformed, or the optional library for the format is not installed (the
        message names the extra to install).

    Notes
    -----
    Rows that the format itself marks as "no point" are dropped: invalid returns in E57 and NaN
    coordinates in PCD (PCL's organized clouds).  Nothing else is checked here -- finiteness and
    point count are checked by the pipeline.

    See Also
    --------
    point_file_info : the format and the per-point fields of a file, without reading its points.
    canalsurf.pointcloud.crop, canalsurf.pointcloud.voxel_downsample : keep part of the points.
    canalsurf.reconstruct : what the points are usually read for.

    Examples
    --------
    A text file with a header line, then a PLY file with normals:

    >>> import pathlib, tempfile
    >>> import numpy as np
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (folder / "cloud.csv").write_text("x,y,z\\n0,0,0\\n1,0,0\\n0,1,0.5\\n")
    >>> points, normals = read_points(folder / "cloud.csv")
    >>> points.shape, normals is None
    ((3, 3), True)
    >>> write_points(folder / "cloud.ply", points, np.tile([0.0, 0.0, 1.0], (3, 1)))
    >>> points, normals = read_points(folder / "cloud.ply")
    >>> points[2], normals[2]
    (array([0. , 1. , 0.5]), array([0., 0., 1.]))

    A scan is then reconstructed with its normals, if it has them::

        network = canalsurf.reconstruct(points, normals=normals)
    """
    path, reader = _reader(path)
    _check_readable(path)
    return reader(path)


def _reader(path: PathLike) -> tuple[pathlib.Path, Callable]:
    """``path`` as a Path and the reader of its suffix, or the error that lists the known suffixes."""
    path = _as_path(path)
    reader = _READERS.get(path.suffix.lower())
    if reader is None:
        raise InputError(
            f"{path}: unknown point format {path.suffix or '(no suffix)'!r} — "
            f"use one of {', '.join(POINT_FORMATS)}"
        )
    return path, reader


# --------------------------------------------------------------------------------------------------
# streaming: files larger than memory, read in chunks

#: Points converted at a time when a file is streamed: 2**16 points are 1.5 MB as float64
#: coordinates, and a chunk of a LAZ file takes about 9 MB with laspy's buffers and the conversion
#: (measured with tracemalloc; 4 times as much at 2**18, no faster), far below the sample kept,
#: while the work per chunk (a few numpy calls) stays negligible beside the points' own.
_STREAM_CHUNK_POINTS = 1 << 16
#: The rows kept are cut back to the sample's size whenever this share of it more has piled up: each
#: cut copies what is held, so a cut per ``_SAMPLE_SLACK`` samples of new rows copies each row about
#: (1 + slack) / slack times, while at most (1 + slack) samples are held beside one chunk -- 2 x 48 MB
#: of coordinates for the command line's 2,000,000 points.
_SAMPLE_SLACK = 1.0
#: numpy types of the scalar property types of PLY (both spellings of the specification).
_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}

_Chunks = Iterator[tuple[np.ndarray, "np.ndarray | None"]]


def _whole_chunks(path: pathlib.Path, reader: Callable, chunk: int) -> _Chunks:
    """A format without a chunked reader: read whole, then handed out in chunks."""
    points, normals = reader(path)
    for start in range(0, max(len(points), 1), chunk):
        yield points[start:start + chunk], None if normals is None else normals[start:start + chunk]


def _ply_chunks(path: pathlib.Path, chunk: int) -> _Chunks:
    """Binary PLY through plyfile's memory map, a slice at a time; ASCII PLY of vertices only parsed in
    chunks of lines; any other ASCII PLY (more elements) read whole."""
    layout = _ascii_ply_layout(path)
    if layout is not None:
        yield from _ascii_ply_chunks(path, *layout, chunk)
        return
    with _ply_vertex(path) as (data, normals):
        for start in range(0, max(len(data), 1), chunk):
            yield _ply_columns(data[start:start + chunk], normals)


def _ascii_ply_layout(path: pathlib.Path) -> tuple[int, list[str], list[str]] | None:
    """Vertex count, property names and their PLY types of an ASCII PLY 1.0 file whose only element is
    ``vertex`` with scalar ``x y z``; ``None`` for any other file (read by :func:`_ply_vertex`, which
    also names what is wrong with a bad one)."""
    with open(path, "rb") as fh:
        head = fh.read(_MAX_HEADER_BYTES)
    lines, start = [], 0
    while (end := head.find(b"\n", start)) >= 0:
        try:
            words = head[start:end].decode("ascii").split()
        except UnicodeDecodeError:
            return None
        start = end + 1
        if words == ["end_header"]:
            break
        lines.append(words)
    else:
        return None
    if lines[:1] != [["ply"]] or len(lines) < 2 or lines[1] != ["format", "ascii", "1.0"]:
        return None
    elements: list[tuple[str, str, list[list[str]]]] = []
    for words in lines[2:]:
        if words[:1] == ["element"] and len(words) == 3:
            elements.append((words[1], words[2], []))
        elif words[:1] == ["property"] and elements:
            elements[-1][2].append(words[1:])
        elif words[:1] not in (["comment"], ["obj_info"]):
            return None  # not a header plyfile reads: let it say what is wrong
    if len(elements) != 1 or elements[0][0] != "vertex" or not elements[0][1].isdigit():
        return None
    _, count, props = elements[0]
    names = [words[-1] for words in props]
    if (any(len(words) != 2 or words[0] not in _PLY_TYPES for words in props) or len(set(names)) != len(names)
            or not set("xyz") <= set(names)):
        return None
    return int(count), names, [words[0] for words in props]


def _ascii_ply_chunks(path: pathlib.Path, count: int, names: list[str], types: list[str], chunk: int) -> _Chunks:
    """The vertices of an ASCII PLY file (see :func:`_ascii_ply_layout`), ``chunk`` lines at a time.

    Each value is parsed into its declared type, as plyfile does: a ``float`` x holds float32 values, an
    ``int`` property refuses ``1.5`` and a ``uchar`` 300.
    """
    fix = "re-export the file"
    record = np.dtype([(name, _PLY_TYPES[kind]) for name, kind in zip(names, types)])
    normals = set(_PLY_NORMALS) <= set(names)

    def parse(rows: list[str]) -> np.ndarray | None:
        """The rows as records, or None if one is not a value of each declared type (or blank)."""
        try:
            table = np.loadtxt(rows, dtype=record, comments=None, ndmin=1)
        except ValueError:
            return None
        return table if len(table) == len(rows) else None

    held = 0
    try:
        with open(path, encoding="ascii") as fh:
            for line in iter(lambda: fh.readline(_MAX_LINE_CHARS), ""):
                if line.split() == ["end_header"]:
                    break
            while lines := list(itertools.islice(fh, chunk)):
                rows, rest = lines[:count - held], lines[count - held:]
                if any(line.strip() for line in rest):
                    raise _more_data(path, "PLY", count, _rows("vertex"))
                if not rows:
                    continue
                table = parse(rows)
                if table is None:  # the first bad row, by halving (a parse of at most twice the rows)
                    good, bad = 0, len(rows)
                    while bad - good > 1:
                        middle = (good + bad) // 2
                        good, bad = (middle, bad) if parse(rows[:middle]) is not None else (good, middle)
                    shown = rows[good].strip()
                    shown = shown if len(shown) <= 60 else shown[:57] + "..."
                    raise InputError(f"{path}: PLY vertex {held + good + 1} ({shown!r}) is not one value of each "
                                     f"type the header declares ({' '.join(types)}) — {fix}")
                held += len(rows)
                yield (_as_xyz([table[name] for name in "xyz"]),
                       _as_xyz([table[name] for name in _PLY_NORMALS]) if normals else None)
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a readable PLY file (its ASCII data holds other bytes) — {fix}") from None
    if held < count:
        raise _truncated(path, "PLY", count, held, _rows("vertex"))
    if not count:
        yield np.empty((0, 3)), np.empty((0, 3)) if normals else None


def _text_chunks(path: pathlib.Path, chunk: int) -> _Chunks:
    """A text point file, ``chunk`` lines at a time (numpy's parser on each)."""
    header_lines, delimiter, ncols = _text_layout(path)
    columns = _text_columns(path, header_lines, delimiter, ncols)
    try:
        with open(path, encoding="utf-8-sig") as fh:
            for _ in itertools.islice(fh, header_lines):
                pass
            while lines := list(itertools.islice(fh, chunk)):
                with warnings.catch_warnings():
                    # a chunk of comment lines only is no error here (the file has data, see above)
                    warnings.filterwarnings("ignore", "loadtxt: input contained no data", UserWarning)
                    table = np.loadtxt(lines, dtype=np.float64, delimiter=delimiter, comments="#", ndmin=2)
                if not table.size:
                    continue
                if table.shape[1] != ncols:  # a chunk whose rows all have another number of columns
                    raise ValueError(f"{table.shape[1]} columns")
                yield _text_points(table, columns)
    except (ValueError, UnicodeDecodeError) as exc:
        if isinstance(exc, InputError):
            raise
        raise _explain_text_error(path, header_lines, delimiter, ncols, _TEXT_FIX, exc) from None


def _npy_chunks(path: pathlib.Path, chunk: int) -> _Chunks:
    """A .npy array memory-mapped, a slice of rows at a time (a .npz archive named .npy: read whole)."""
    if _numpy_kind(path) != "npy":
        yield from _whole_chunks(path, _read_numpy, chunk)
        return
    shape = _check_npy(path)
    with _translating(path, "NumPy .npy", _NPY_FIX):
        # allow_pickle=False: a point file must never be able to run code on load
        table = np.load(path, mmap_mode="r" if math.prod(shape) else None, allow_pickle=False)
    _check_columns(table, path, "the file")
    for start in range(0, max(len(table), 1), chunk):
        yield _split_columns(table[start:start + chunk], path, "the file")


#: Readers that give a file's points in chunks, by suffix; other formats are read whole.
_CHUNK_READERS: dict[str, Callable[[pathlib.Path, int], _Chunks]] = {
    ".ply": _ply_chunks,
    ".xyz": _text_chunks,
    ".txt": _text_chunks,
    ".csv": _text_chunks,
    ".asc": _text_chunks,
    ".npy": _npy_chunks,
    ".las": _las_chunks,
    ".laz": _las_chunks,
}


def _chunks(path: pathlib.Path, reader: Callable) -> _Chunks:
    """The points (and normals) of a checked file, at most ``_STREAM_CHUNK_POINTS`` at a time, in file
    order; at least one chunk, perhaps empty."""
    chunked = _CHUNK_READERS.get(path.suffix.lower())
    if chunked is None:
        return _whole_chunks(path, reader, _STREAM_CHUNK_POINTS)
    return chunked(path, _STREAM_CHUNK_POINTS)


def _box_mask(points: np.ndarray, corners: np.ndarray | None) -> np.ndarray | None:
    """Which points lie inside the box (faces included), as :func:`canalsurf.pointcloud.crop` keeps them."""
    if corners is None:
        return None
    return np.all((points >= corners[0]) & (points <= corners[1]), axis=1)


def _as_corners(box) -> np.ndarray | None:
    if box is None:
        return None
    from .pointcloud import _as_box

    return _as_box(box)


class PointSample(NamedTuple):
    """What :func:`read_points_sample` returns."""

    #: ``(M, 3)`` float64: the points kept, in file order.
    points: np.ndarray
    #: ``(M, 3)`` float64 normals of those points, or ``None`` when the file has none.
    normals: np.ndarray | None
    #: Points in the file.
    total: int
    #: Points the sample was drawn from: those inside ``box`` (``total`` without a box).  ``M`` is
    #: ``min(in_box, max_points)``; the sample holds all of them when ``M == in_box``.
    in_box: int


def read_points_sample(path: PathLike, max_points: int, *, rng=0, box=None) -> PointSample:
    """Read a seeded uniform random sample of at most ``max_points`` points, in bounded memory.

    The file is read in chunks and only the sample is kept, so memory follows ``max_points`` and the
    chunk size, not the file: LAS/LAZ through laspy's chunk iterator, binary PLY and ``.npy`` through
    a memory map, text and ASCII PLY in chunks of lines.  Other formats (``.npz``, PCD, E57, PLY
    with more elements than vertices in ASCII) are read whole first: the sample is the same, the
    memory is not bounded.

    Parameters
    ----------
    path : str or os.PathLike
        A point file, as for :func:`read_points`.
    max_points : int
        Most points kept (at least 1).  A file with at most this many (inside ``box``) gives all
        of them: then the result is what :func:`read_points` (and :func:`canalsurf.pointcloud.crop`)
        give, point for point.
    rng : int or numpy.random.Generator, optional
        Seed or generator of the sample.  The same seed gives the same sample of the same file,
        whatever the chunk size.
    box : sequence of 6 floats, optional
        ``(xmin, ymin, zmin, xmax, ymax, zmax)``: keep only points inside (faces included), before
        sampling -- a small box in a large scan keeps up to ``max_points`` of its own points.

    Returns
    -------
    PointSample
        ``points`` and ``normals`` of the sample, in file order; ``total``, the points in the file;
        ``in_box``, those inside ``box``.

    Raises
    ------
    InputError
        As :func:`read_points`; also a point with NaN or infinite coordinates (the row is named),
        a ``max_points`` below 1 or a bad ``box``.

    Notes
    -----
    Every point (inside the box) gets a uniform random key, drawn from one generator in file order;
    the sample is the ``max_points`` points of the smallest keys (of two equal keys, the earlier
    point's).  That is a uniform sample without replacement, and it does not depend on how the file
    is cut into chunks.  Rows whose keys cannot reach the sample any more are dropped at once, and the
    rows kept are cut back to ``max_points`` whenever as many again have piled up: memory is
    O(chunk + max_points), time O(N) plus O(max_points log(N / max_points)) for the cuts (rows reach
    the sample ever more rarely as the file goes on).

    Examples
    --------
    >>> import pathlib, tempfile
    >>> import numpy as np
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "cloud.npy"
    >>> np.save(path, np.random.default_rng(0).normal(size=(10_000, 3)))
    >>> sample = read_points_sample(path, 1000, rng=1)
    >>> sample.points.shape, sample.normals, sample.total, sample.in_box
    ((1000, 3), None, 10000, 10000)
    >>> bool(np.array_equal(read_points_sample(path, 20_000).points, read_points(path)[0]))
    True
    """
    path, reader = _reader(path)
    if isinstance(max_points, bool) or not isinstance(max_points, (int, np.integer)) or max_points < 1:
        raise InputError(f"max_points must be a whole number >= 1, got {max_points!r}")
    corners = _as_corners(box)
    _check_readable(path)
    generator = np.random.default_rng(rng)
    total = 0

    def keyed() -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray | None]]:
        nonlocal total
        for points, normals in _chunks(path, reader):
            finite = np.isfinite(points)
            if not finite.all():
                first = total + int(np.flatnonzero(~finite.all(axis=1))[0])
                raise InputError(f"{path}: point {first} (counting from 0) has NaN or inf coordinates — remove "
                                 "the rows with NaN or inf")
            total += len(points)
            inside = _box_mask(points, corners)
            if inside is not None:
                points = points[inside]
                normals = None if normals is None else normals[inside]
            yield generator.random(len(points)), points, normals

    in_box, points, normals = _smallest_keys(keyed(), int(max_points))
    log.info("%s: %d of %d points kept (seeded sample of at most %d)", path, len(points), in_box, max_points)
    return PointSample(points, normals, total, in_box)


def _smallest_keys(chunks, k: int) -> tuple[int, np.ndarray, np.ndarray | None]:
    """The rows of the ``k`` smallest keys over all ``(keys, points, normals)`` chunks, in row order.

    Ties go to the earlier row, so the rows kept do not depend on how the rows are cut into chunks.
    Rows are only ever dropped, never reordered: what is kept stays in row order throughout.
    Returns the number of rows seen, and the points and normals kept.
    """
    kept: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = []
    held = seen = 0
    limit = np.inf  # the largest key kept, once k are kept: a row with a larger key never gets in
    for keys, points, normals in chunks:
        seen += len(keys)
        if limit < np.inf:
            near = keys < limit
            keys, points = keys[near], points[near]
            normals = None if normals is None else normals[near]
        kept.append((keys, points, normals))
        held += len(keys)
        if held > k + max(1, int(_SAMPLE_SLACK * k)):
            kept = [_cut(kept, k)]
            held, limit = k, float(kept[0][0].max())
    _, points, normals = _cut(kept, k)
    return seen, points, normals


def _cut(parts: list, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The ``k`` rows of ``parts`` (in row order) with the smallest keys, the earlier of equal keys first;
    all of them if fewer; joined, in row order."""
    keys = np.concatenate([part[0] for part in parts])
    keep = None
    if len(keys) > k:
        kth = np.partition(keys, k - 1)[k - 1]
        keep = keys < kth
        tied = np.flatnonzero(keys == kth)  # in row order
        keep[tied[:k - np.count_nonzero(keep)]] = True
    # Each part is cut by its share of the mask and the pieces joined: the points are copied once, in
    # sequence (a mask, not a list of rows, also keeps the row order).
    masks = [slice(None)] * len(parts) if keep is None else np.split(keep, np.cumsum([len(p[0]) for p in parts])[:-1])
    points = np.concatenate([part[1][mask] for part, mask in zip(parts, masks)])
    normals = None if parts[0][2] is None else np.concatenate([part[2][mask] for part, mask in zip(parts, masks)])
    return keys if keep is None else keys[keep], points, normals


def iter_point_chunks(path: PathLike, *, box=None) -> Iterator[tuple[np.ndarray, np.ndarray | None]]:
    """The points (and normals) of a file, a chunk at a time, in file order, in bounded memory.

    The chunks are those :func:`read_points_sample` reads (a few hundred thousand points each; the
    formats it reads whole are read whole here too); with ``box`` only the points inside it, and
    chunks left empty are skipped.  For a second pass over a file too large to hold, such as
    labelling every point of a scan with :meth:`canalsurf.network.Network.classify`.

    Parameters
    ----------
    path : str or os.PathLike
        A point file, as for :func:`read_points`.
    box : sequence of 6 floats, optional
        ``(xmin, ymin, zmin, xmax, ymax, zmax)``, faces included.

    Yields
    ------
    points : (n, 3) float64 ndarray
    normals : (n, 3) float64 ndarray or None

    Raises
    ------
    InputError
        As :func:`read_points` (a damaged part of a file only when it is reached).
    """
    path, reader = _reader(path)
    corners = _as_corners(box)
    _check_readable(path)
    for points, normals in _chunks(path, reader):
        inside = _box_mask(points, corners)
        if inside is not None:
            points = points[inside]
            normals = None if normals is None else normals[inside]
        if len(points):
            yield points, normals


class PointFileInfo(NamedTuple):
    """What :func:`point_file_info` finds in a point file's header."""

    #: The format as a person names it, with the details a header gives: ``"PLY, binary little-endian"``,
    #: ``"LAS 1.4, point format 6"``, ``"text, comma separated"``.
    format: str
    #: The per-point fields the file stores, in the file's own spelling and order (``x y z nx ny nz``
    #: for a file with normals; LAS: every dimension of its point format, e.g. ``intensity``,
    #: ``classification``, ``gps_time``; E57: the fields of any of its scans).
    fields: tuple[str, ...]


#: Names of the point formats by suffix, as :attr:`PointFileInfo.format` starts.
POINT_FORMAT_NAMES = {".ply": "PLY", ".xyz": "text", ".txt": "text", ".csv": "text", ".asc": "text",
                      ".npy": "NumPy .npy", ".npz": "NumPy .npz", ".pcd": "PCD", ".las": "LAS", ".laz": "LAZ",
                      ".e57": "E57"}
#: The PLY header's names of its encodings, as a person writes them.
_PLY_ENCODINGS = {"ascii": "ASCII", "binary_little_endian": "binary little-endian",
                  "binary_big_endian": "binary big-endian"}
#: Field names of a file that stores coordinates and, perhaps, normals only (text, NumPy).
_XYZ, _XYZ_NORMALS = ("x", "y", "z"), ("x", "y", "z", "nx", "ny", "nz")


def point_file_info(path: PathLike) -> PointFileInfo:
    """The format of a point file and the per-point fields it stores, read from its header.

    What :func:`read_points` returns are the coordinates and normals; a scan often carries more
    (intensity, colour, classification, return numbers, time), which this names -- to see what a
    file holds before reconstructing it (``canalsurf info``).

    Parameters
    ----------
    path : str or os.PathLike
        A file with one of the suffixes in :data:`POINT_FORMATS`.

    Returns
    -------
    PointFileInfo
        ``format`` (e.g. ``"PLY, binary little-endian"``) and ``fields`` (e.g. ``("x", "y", "z",
        "intensity")``).

    Raises
    ------
    InputError
        As :func:`read_points`, for the header: unknown suffix, a file that is missing, unreadable,
        not of its format, or whose optional library is missing.  A file whose header reads may
        still fail in :func:`read_points`, whose checks of the data this does not repeat.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> import numpy as np
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "cloud.ply"
    >>> write_points(path, np.zeros((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1)))
    >>> point_file_info(path)
    PointFileInfo(format='PLY, binary little-endian', fields=('x', 'y', 'z', 'nx', 'ny', 'nz'))
    """
    path, reader = _reader(path)
    _check_readable(path)
    name = POINT_FORMAT_NAMES[path.suffix.lower()]
    if reader is _read_ply:
        detail, fields = _ply_fields(path)
    elif reader is _read_text:
        detail, fields = _text_fields(path)
    elif reader is _read_numpy:
        detail, fields = _numpy_fields(path)
    elif reader is _read_pcd:
        detail, fields = _pcd_fields(path)
    elif reader is _read_las:
        detail, fields = _las_fields(path)
    else:
        detail, fields = _e57_fields(path)
    return PointFileInfo(f"{name}, {detail}" if detail else name, tuple(fields))


def _ply_fields(path: pathlib.Path) -> tuple[str, list[str]]:
    fix = "re-export the file"
    with open(path, "rb") as fh:
        head = fh.read(_MAX_HEADER_BYTES)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise InputError(f"{path}: not a PLY file (no 'ply' ... 'end_header' header) — {fix}")
    try:
        lines = [line.split() for line in head[:end].decode("ascii").splitlines()]
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a readable PLY file (its header is not ASCII) — {fix}") from None
    encoding, fields, element = "", [], None
    for words in lines:
        if words[:1] == ["format"] and len(words) > 1:
            encoding = _PLY_ENCODINGS.get(words[1], words[1])
        elif words[:1] == ["element"] and len(words) > 1:
            element = words[1]
        elif words[:1] == ["property"] and len(words) > 2 and element == "vertex":
            fields.append(words[-1])  # 'property float x', 'property list uchar int x'
    return encoding, fields


def _text_fields(path: pathlib.Path) -> tuple[str, list[str]]:
    head = _text_head(path)
    first = head[0][1]
    data = first if _is_numeric_row(_fields(first, _sniff_delimiter(first))) else head[-1][1]
    delimiter = _sniff_delimiter(data)
    detail = {";": "semicolon separated", "\t": "tab separated", ",": "comma separated"}.get(
        delimiter, "space separated")
    if data is not first:  # a header line names the columns
        return detail, _fields(first, delimiter)
    ncols = len(_fields(data, delimiter))
    names = [str(i + 1) for i in range(ncols)]  # columns read past, by number
    xyz, normals = _text_columns(path, 0, delimiter, ncols)
    for index, name in zip(xyz + (normals or []), _XYZ_NORMALS):
        names[index] = name
    return detail, names


def _numpy_fields(path: pathlib.Path) -> tuple[str, list[str]]:
    kind = _numpy_kind(path)
    if kind is None:
        raise InputError(f"{path}: not a NumPy {path.suffix.lower()} file (it lacks the format's leading bytes) "
                         "— save the points with numpy.save or numpy.savez")
    fix = "save with numpy.save or numpy.savez"
    if kind == "npy":
        with open(path, "rb") as fh:
            shape, dtype, _ = _npy_header(fh, path, "NumPy .npy", fix)
        columns = shape[1] if len(shape) == 2 else 0
        return f"{dtype} array of shape {shape}", list(_XYZ_NORMALS if columns == 6 else _XYZ)
    with _translating(path, "NumPy .npz", fix), zipfile.ZipFile(path) as zf:
        keys = [name[:-4] if name.endswith(".npy") else name for name in zf.namelist()]
        if "points" in keys:
            return f"arrays {', '.join(keys)}", list(_XYZ_NORMALS if "normals" in keys else _XYZ)
        if len(keys) != 1:
            raise InputError(f"{path}: .npz holds arrays {keys} but no 'points' — save with "
                             "numpy.savez(file, points=..., normals=...)")
        with zf.open(zf.namelist()[0]) as fh:
            shape, _, _ = _npy_header(fh, path, f"NumPy .npz ('{keys[0]}')", fix)
    return f"array {keys[0]}", list(_XYZ_NORMALS if len(shape) == 2 and shape[1] == 6 else _XYZ)


def _pcd_fields(path: pathlib.Path) -> tuple[str, list[str]]:
    lines, _ = _pcd_header(path, "re-export the file")
    words = {line.split()[0].upper(): line.split()[1:] for line in lines if line.split()}
    return f"DATA {' '.join(words.get('DATA', ['?']))}", words.get("FIELDS", [])


def _las_fields(path: pathlib.Path) -> tuple[str, list[str]]:
    suffix = path.suffix.lower()
    laspy = _import_extra("laspy", suffix, "las")
    what = suffix[1:].upper()
    _las_layout(path, what)  # the header and its records are checked before laspy reads them
    with _translating(path, what, "re-export the file"), _library_logs("laspy"):
        with open(path, "rb") as fh:
            header = laspy.LasHeader.read_from(fh)
        fields = list(header.point_format.dimension_names)
        return f"version {header.version}, point format {header.point_format.id}", fields


def _e57_fields(path: pathlib.Path) -> tuple[str, list[str]]:
    pye57 = _import_extra("pye57", ".e57", "e57")
    fields: dict[str, None] = {}
    with _translating(path, "E57", "re-export the file"), pye57.E57(str(path)) as e57:
        for i in range(e57.scan_count):
            fields.update(dict.fromkeys(e57.get_header(i).point_fields))
        count = e57.scan_count
    return f"{count} scan{'s' * (count != 1)}", list(fields)


# --------------------------------------------------------------------------------------------------
# writers


def atomic_write(path: PathLike, write: Callable[[pathlib.Path], None]) -> None:
    """Write a file all-or-nothing: ``write`` fills a temporary file that then replaces ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        The target.  Its folder must exist; an existing file is replaced only once ``write`` has
        succeeded, so readers never see a half-written file.
    write : callable
        ``write(tmp_path)`` writes the complete content to ``tmp_path`` (a fresh, empty file in the
        target folder whose name ends with the target's suffix, for libraries that look at it).

    Raises
    ------
    InputError
        The folder does not exist or cannot be written, or ``path`` is a folder.
    Exception
        Whatever ``write`` raises, after the temporary file has been removed.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "note.txt"
    >>> atomic_write(target, lambda tmp: tmp.write_text("done"))
    >>> target.read_text()
    'done'
    """
    path = _as_path(path)
    folder = path.parent
    if path.is_dir():
        raise InputError(f"{path}: is a folder — give a file name to write")
    if not folder.is_dir():
        raise InputError(f"{path}: folder {str(folder)!r} does not exist — create it first")
    tmp = _create_temp(path)
    try:
        write(tmp)
        # Flush to disk before the rename, so a crash cannot leave the new name on empty data.
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


def _create_temp(path: pathlib.Path) -> pathlib.Path:
    """Create an empty, hidden temp file beside ``path``; fail with InputError if we cannot write there."""
    for _ in range(100):
        tmp = path.with_name(f".{path.stem}.{secrets.token_hex(4)}.tmp{path.suffix}")
        try:
            # os.open with mode 0o666 (not tempfile.mkstemp, which forces 0o600) so the final file
            # gets the permissions the user's umask gives any new file.
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        except PermissionError:
            raise InputError(
                f"{path}: cannot write in folder {str(path.parent)!r} (permission denied) — "
                "choose another output folder"
            ) from None
        except OSError as exc:
            raise InputError(
                f"{path}: cannot write ({exc.strerror or _one_line(exc)}) — choose another output path"
            ) from None
        os.close(fd)
        return tmp
    raise InputError(
        f"{path}: cannot create a temporary file beside it — clean up .{path.stem}.*.tmp files"
    )


def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and f.dtype.kind not in "iu"):
        raise InputError(f"faces must be integer indices of shape (F, 3), got {f.shape} {f.dtype}")
    f = f.astype(np.int64)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise InputError(f"faces index vertices 0..{len(v) - 1} only, got {f.min()}..{f.max()}")
    return v, f


def _write_mesh_ply(path: pathlib.Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    # Binary PLY is a text header and the packed rows; numpy writes the rows in one go, where
    # plyfile walks the faces (a list property) one by one.
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment written by canalsurf\n"
        f"element vertex {len(vertices)}\nproperty double x\nproperty double y\nproperty double z\n"
        # uint8 list length: the convention every mesh tool reads
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    face = np.empty(len(faces), dtype=[("count", "u1"), ("vertex_indices", "<i4", (3,))])
    face["count"] = 3
    face["vertex_indices"] = faces

    def write(tmp: pathlib.Path) -> None:
        with open(tmp, "wb") as fh:
            fh.write(header.encode("ascii"))
            fh.write(np.ascontiguousarray(vertices, dtype="<f8").tobytes())
            fh.write(face.tobytes())

    atomic_write(path, write)


def _write_mesh_trimesh(path: pathlib.Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    suffix = path.suffix.lower()
    trimesh = _import_extra("trimesh", suffix, "mesh", verb="writing")
    # process=False: keep the vertices and faces exactly as given (no merging or reordering)
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    atomic_write(path, lambda tmp: mesh.export(tmp, file_type=suffix[1:]))


_MESH_WRITERS: dict[str, Callable[[pathlib.Path, np.ndarray, np.ndarray], None]] = {
    ".ply": _write_mesh_ply,
    ".obj": _write_mesh_trimesh,
    ".stl": _write_mesh_trimesh,
    ".off": _write_mesh_trimesh,
    ".glb": _write_mesh_trimesh,
}

#: File suffixes :func:`write_mesh` understands.
MESH_FORMATS: tuple[str, ...] = tuple(_MESH_WRITERS)


def write_points(path: PathLike, points: np.ndarray, normals: np.ndarray | None) -> None:
    """Write a point cloud (with optional normals ``nx, ny, nz``) atomically; format by suffix.

    PLY (binary, float64) through plyfile; ``.xyz .txt .asc`` (space separated) and ``.csv`` (with a
    header) at full precision; ``.npy`` (an (N, 3) or (N, 6) array) and ``.npz`` (``points``, ``normals``).
    """
    path = _as_path(path)
    family = POINT_WRITE_FORMATS.get(path.suffix.lower())
    if family is None:
        raise InputError(f"{path}: cannot write points as {path.suffix or '(no suffix)'!r} — "
                         f"use one of {', '.join(POINT_WRITE_FORMATS)}")
    points = as_table(points, "points")
    if normals is not None:
        normals = as_table(normals, "normals")
        if normals.shape != points.shape:
            raise InputError(f"normals must have the shape of the points {points.shape}, got {normals.shape}")
    table = points if normals is None else np.column_stack([points, normals])
    names = ["x", "y", "z"] + ([] if normals is None else ["nx", "ny", "nz"])
    if family == "ply":
        import plyfile

        vertex = np.empty(len(table), dtype=[(n, "<f8") for n in names])
        for i, n in enumerate(names):
            vertex[n] = table[:, i]
        data = plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")], text=False,
                               byte_order="<", comments=["written by canalsurf"])
        atomic_write(path, lambda tmp: data.write(str(tmp)))
    elif family in ("text", "csv"):
        header, sep = (",".join(names), ",") if family == "csv" else ("", " ")
        atomic_write(path, lambda tmp: np.savetxt(tmp, table, fmt="%.17g", delimiter=sep, header=header,
                                                  comments=""))
    elif family == "npy":
        def write(tmp):
            with open(tmp, "wb") as fh:
                np.save(fh, table)
        atomic_write(path, write)
    else:  # npz
        arrays = {"points": points} | ({} if normals is None else {"normals": normals})

        def write(tmp):
            with open(tmp, "wb") as fh:
                np.savez(fh, **arrays)
        atomic_write(path, write)


#: The vertex record of a labelled point file: coordinates, branch id and signed distance.
_LABELLED_RECORD = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("branch", "<i4"), ("distance", "<f8")])
#: Its PLY header (the vertex count goes into the ``{}``), as plyfile writes it for that record.
_LABELLED_HEADER = ("ply\nformat binary_little_endian 1.0\ncomment written by canalsurf: branch -1 is on no tube\n"
                    "element vertex {}\nproperty double x\nproperty double y\nproperty double z\n"
                    "property int branch\nproperty double distance\nend_header\n")


def write_labelled_points(path: PathLike, points, label, distance) -> None:
    """Write points with their branch id and signed distance as a binary PLY, atomically.

    The vertex element holds ``x, y, z`` (float64), ``branch`` (int32; -1 for a point on no tube) and
    ``distance`` (float64, from the surface, positive outside; NaN where unknown): scalar fields that
    CloudCompare and most point tools colour by or split on.

    See Also
    --------
    write_labelled_chunks : the same file, written a chunk at a time.
    """
    points = np.asarray(points, dtype=np.float64)
    write_labelled_chunks(path, len(points), [(points, label, distance)])


def write_labelled_chunks(path: PathLike, count: int, chunks) -> None:
    """Write labelled points that come in chunks, as :func:`write_labelled_points` does, atomically.

    For a file too large to hold: the header (with ``count``) is written first, then the records of
    each chunk as it comes, so memory follows one chunk.  The file is the same, byte for byte, as
    :func:`write_labelled_points` writes for all the points at once.

    Parameters
    ----------
    path : str or os.PathLike
    count : int
        Points in all the chunks together.
    chunks : iterable of tuple
        ``(points, label, distance)`` per chunk: ``(n, 3)``, ``(n,)`` and ``(n,)`` arrays.

    Raises
    ------
    InputError
        A chunk of mismatched shapes, or chunks holding other than ``count`` points (no file is left).
    """
    count = int(count)

    def write(tmp: pathlib.Path) -> None:
        written = 0
        with open(tmp, "wb") as fh:
            fh.write(_LABELLED_HEADER.format(count).encode("ascii"))
            for points, label, distance in chunks:
                points = np.asarray(points, dtype=np.float64)
                label = np.asarray(label).reshape(-1)
                distance = np.asarray(distance, dtype=np.float64).reshape(-1)
                if points.ndim != 2 or points.shape[1] != 3 or not len(points) == len(label) == len(distance):
                    raise InputError(f"labelled points need points (N, 3), label (N,) and distance (N,), got "
                                     f"{points.shape}, {label.shape}, {distance.shape}")
                record = np.empty(len(points), dtype=_LABELLED_RECORD)
                record["x"], record["y"], record["z"] = points.T
                record["branch"] = label
                record["distance"] = np.where(np.isfinite(distance), distance, np.nan)
                written += len(record)
                if written > count:
                    break
                fh.write(record.tobytes())
        if written != count:
            got = "more" if written > count else str(written)
            raise InputError(f"{path}: {count} points were to be labelled, the chunks held {got} — the input "
                             "changed while it was read; run again")

    atomic_write(path, write)


def write_mesh(path: PathLike, vertices, faces) -> None:
    """Write a triangle mesh, choosing the format by the file suffix (case-insensitive).

    Parameters
    ----------
    path : str or os.PathLike
        Target with a suffix from :data:`MESH_FORMATS`.  ``.ply`` is written as binary
        little-endian with float64 vertices (core dependency plyfile); ``.obj .stl .off .glb`` go
        through trimesh (extra ``mesh``).  STL and GLB hold float32 vertices.
    vertices : (V, 3) array_like of float
    faces : (F, 3) array_like of int
        Indices into ``vertices``, counter-clockwise seen from outside.

    Raises
    ------
    InputError
        Unknown suffix, arrays of the wrong shape, the 'mesh' extra missing, or an unwritable folder.
    """
    path = _as_path(path)
    writer = _MESH_WRITERS.get(path.suffix.lower())
    if writer is None:
        raise InputError(
            f"{path}: unknown mesh format {path.suffix or '(no suffix)'!r} — "
            f"use one of {', '.join(MESH_FORMATS)}"
        )
    v, f = _check_mesh(vertices, faces)
    writer(path, v, f)


def write_spine_csv(path: PathLike, t, points, radius, branch=None) -> None:
    """Write spine samples as CSV with header ``branch,t,x,y,z,radius`` and full float64 precision.

    Parameters
    ----------
    path : str or os.PathLike
    t : (M,) array_like
        Curve parameter of each sample (on its branch).
    points : (M, 3) array_like
        Spine points.
    radius : (M,) array_like
        Pipe/canal radius at each sample.
    branch : (M,) array_like of int, optional
        Branch id of each sample (default: all 0, a single tube).

    Notes
    -----
    Numbers are written with ``%.17g``, enough digits for every float64 to read back bit-exact.
    """
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    pts = np.asarray(points, dtype=np.float64)
    r = np.asarray(radius, dtype=np.float64).reshape(-1)
    ids = np.zeros(len(t), dtype=np.int64) if branch is None else np.asarray(branch).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] != 3 or not len(t) == len(pts) == len(r) == len(ids):
        raise InputError(
            "spine CSV needs branch (M,), t (M,), points (M, 3) and radius (M,), got "
            f"{ids.shape}, {t.shape}, {pts.shape}, {r.shape}"
        )
    table = np.column_stack([t, pts, r])

    def write(tmp):
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.write("branch,t,x,y,z,radius\n")
            for b, row in zip(ids.tolist(), table):
                f.write(f"{int(b)}," + ",".join(f"{v:.17g}" for v in row) + "\n")

    atomic_write(path, write)


def write_spine_dxf(path: PathLike, branches, *, units: str | None = None) -> None:
    """Write the spines as a CAD drawing: one exact SPLINE per branch plus its radius samples.

    Parameters
    ----------
    path : str or os.PathLike
    branches : iterable of tuple
        Per branch ``(knots, control_points, degree, sample_points, sample_radius)``:
    knots : (n + degree + 1,) array_like
        Full knot vector of the B-spline (``BSpline.t`` in scipy).
    control_points : (n, 3) array_like
        Control points (``BSpline.c``); the SPLINE is the same curve as scipy's BSpline, not a
        re-fit through samples.
    degree : int
        Spline degree (``BSpline.k``).
    sample_points : (M, 3) array_like
        Points on the spine where the radius was sampled.
    sample_radius : (M,) array_like
        Radius at each sample point.
    units : {None, 'm', 'mm', 'ft', 'in'}, optional
        The length unit of the coordinates, declared in the drawing's header (``$INSUNITS``, see
        :data:`DXF_UNITS`; ``$MEASUREMENT`` metric or imperial to match) so that a CAD program
        inserts it at the right scale.  ``None`` (default) declares the drawing unitless
        (``$INSUNITS`` 0): the numbers are the scan's, whatever its unit.

    Notes
    -----
    The drawing (DXF R2010, ezdxf extra ``dxf``) holds

    * on layer ``SPINE``: per branch one SPLINE entity built from ``knots`` and ``control_points``;
    * on layer ``RADIUS``: per branch one 3D POLYLINE through ``sample_points``; **each of its vertices
      carries its radius as extended data** (XDATA, application ``CANALSURF``, group code 1040).

    Per-vertex XDATA was chosen over one XDATA list on the SPLINE because AutoCAD caps XDATA at
    16 KB per entity (about 1600 radii), while a polyline has no such limit, shows where the radius
    was measured, and a CAD user can list a vertex's radius with the standard XDATA tools.

    Examples
    --------
    Reading the radii back with ezdxf::

        doc = ezdxf.readfile("spine.dxf")
        line = doc.modelspace().query("POLYLINE[layer=='RADIUS']")[0]
        radii = [v.get_xdata("CANALSURF")[0].value for v in line.vertices]
    """
    if units is not None and units not in DXF_UNITS:
        raise InputError(f"units must be one of {', '.join(map(repr, DXF_UNITS))} or None, got {units!r}")
    ezdxf = _import_extra("ezdxf", ".dxf", "dxf", verb="writing")
    doc = ezdxf.new("R2010", setup=False, units=DXF_UNITLESS if units is None else DXF_UNITS[units])
    doc.appids.add(DXF_APPID)
    doc.layers.add("SPINE")
    doc.layers.add("RADIUS")
    msp = doc.modelspace()
    for branch in branches:
        _add_dxf_branch(msp, *branch)
    atomic_write(path, lambda tmp: doc.saveas(tmp))


def _add_dxf_branch(msp, knots, control_points, degree, sample_points, sample_radius) -> None:
    """One branch of :func:`write_spine_dxf`: its SPLINE and its radius polyline."""
    knots = np.asarray(knots, dtype=np.float64).reshape(-1)
    cps = np.asarray(control_points, dtype=np.float64)
    degree = int(degree)
    samples = np.asarray(sample_points, dtype=np.float64)
    radius = np.asarray(sample_radius, dtype=np.float64).reshape(-1)
    if cps.ndim != 2 or cps.shape[1] != 3 or len(cps) <= degree:
        raise InputError(f"control_points must have shape (n, 3) with n > degree={degree}, got {cps.shape}")
    if len(knots) != len(cps) + degree + 1:
        raise InputError(
            f"knots must hold n + degree + 1 = {len(cps) + degree + 1} values for {len(cps)} control points, "
            f"got {len(knots)}"
        )
    if samples.ndim != 2 or samples.shape[1] != 3 or len(samples) != len(radius) or len(samples) < 2:
        raise InputError(
            "sample_points (M, 3) and sample_radius (M,) with M >= 2 are needed, "
            f"got {samples.shape}, {radius.shape}"
        )
    msp.add_open_spline(cps.tolist(), degree=degree, knots=knots.tolist(), dxfattribs={"layer": "SPINE"})
    line = msp.add_polyline3d(samples.tolist(), dxfattribs={"layer": "RADIUS"})
    for vertex, r in zip(line.vertices, radius.tolist()):
        vertex.set_xdata(DXF_APPID, [(1040, r)])


def _json_default(obj: Any) -> Any:
    # numpy scalars and arrays appear in results and parameters; json knows only Python numbers
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"Object of type {type(obj).__name__} is not JSON serializable")


def write_json(path: PathLike, obj: Any) -> None:
    """Write ``obj`` as JSON (``indent=1``, keys in insertion order, UTF-8, trailing newline).

    numpy scalars and arrays are converted to Python numbers and lists.

    Raises
    ------
    ValueError
        ``obj`` contains NaN or infinity, which JSON cannot represent -- raised before any file is
        touched, so a model.json is never written with a non-standard ``NaN``.
    TypeError
        ``obj`` contains something JSON cannot hold.
    """
    text = json.dumps(
        obj, indent=1, sort_keys=False, allow_nan=False, ensure_ascii=False, default=_json_default
    )
    atomic_write(path, lambda tmp: tmp.write_text(text + "\n", encoding="utf-8"))
