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
    :func:`write_spine_csv`, :func:`write_spine_dxf` (ezdxf, extra ``dxf``), :func:`write_json`.

Every writer goes through :func:`atomic_write`: the data is written to a temporary file in the
target folder and moved over the target only once complete, so an interrupted run never leaves a
half-written file behind under the real name.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import pathlib
import secrets
import stat
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from .errors import InputError

__all__ = [
    "MESH_FORMATS",
    "POINT_FORMATS",
    "POINT_WRITE_FORMATS",
    "atomic_write",
    "read_points",
    "write_points",
    "write_json",
    "write_mesh",
    "write_spine_csv",
    "write_spine_dxf",
]

PathLike = str | os.PathLike

#: Field names under which normals are stored, per format family.  PLY uses the meshlab/CloudCompare
#: names, PCD the PCL names; LAS has no standard normal dimension, so both spellings are accepted as
#: extra-bytes dimensions (CloudCompare writes ``NormalX`` ..., PDAL ``NormalX`` or ``nx``).
_PLY_NORMALS = ("nx", "ny", "nz")
_PCD_NORMALS = ("normal_x", "normal_y", "normal_z")
_LAS_NORMALS = (("normal_x", "normal_y", "normal_z"), ("normalx", "normaly", "normalz"), ("nx", "ny", "nz"))

#: Application id under which :func:`write_spine_dxf` stores radii as DXF extended data.
DXF_APPID = "CANALSURF"
#: Point formats :func:`write_points` writes, by suffix.
POINT_WRITE_FORMATS = {".ply": "ply", ".xyz": "text", ".txt": "text", ".asc": "text", ".csv": "csv",
                 ".npy": "npy", ".npz": "npz"}

#: Delimiters a text point file may use, in the order they are tried on the first data line.  ``;``
#: comes before ``,`` because spreadsheets in decimal-comma locales write ``1,5;2,0;3,25``: a ``,`` in
#: such a line must not be taken for the delimiter (the row then fails with a line-numbered error
#: instead of silently splitting numbers).  ``None`` means runs of whitespace.
_TEXT_DELIMITERS = (";", "\t", ",")


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
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 -- see docstring
        raise InputError(f"{path}: not a readable {what} file ({_one_line(exc)}) — {fix}") from exc


def _as_xyz(columns: list[np.ndarray]) -> np.ndarray:
    """Stack three 1-D columns into a fresh C-contiguous ``(N, 3)`` float64 array."""
    return np.column_stack([np.asarray(c, dtype=np.float64) for c in columns])


def _split_columns(arr: np.ndarray, path: pathlib.Path, what: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Split an ``(N, 3)`` or ``(N, 6)`` numeric array into points and optional normals."""
    if arr.dtype.kind not in "iuf" or arr.ndim != 2 or arr.shape[1] not in (3, 6):
        raise InputError(
            f"{path}: {what} holds an array of shape {arr.shape} and dtype {arr.dtype}; "
            "expected (N, 3) points or (N, 6) points and normals"
        )
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
    import plyfile

    fix = "re-export the file"
    with open(path, "rb") as fh:
        # bounded reads: a huge file of random bytes may have no newline at all
        magic = fh.readline(16).strip()
        fmt = fh.readline(64).split()
    if magic != b"ply" or len(fmt) < 2 or fmt[0] != b"format":
        raise InputError(f"{path}: not a PLY file (it does not start with 'ply' and a format line) — {fix}")
    text = fmt[1] == b"ascii"

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
                raise InputError(
                    f"{path}: PLY file is truncated (header says {element.count} {_rows(element.name)}, "
                    f"data holds {exc.row}) — {fix}"
                ) from None
            raise InputError(f"{path}: not a readable PLY file ({_one_line(exc)}) — {fix}") from None
        except Exception as exc:  # noqa: BLE001 -- plyfile raises many types on garbage; see _translating
            raise InputError(f"{path}: not a readable PLY file ({_one_line(exc)}) — {fix}") from None
        trailing = fh.read(1 << 16)

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
            raise InputError(
                f"{path}: PLY header says {vertex.count} {_rows('vertex')} but more data follows — {fix}"
            )
        props = vertex.data.dtype.names or ()
        missing = [p for p in "xyz" if p not in props]
        if missing:
            raise InputError(
                f"{path}: PLY vertices lack {', '.join(missing)} (they have {list(props)}) — {fix}"
            )
        points = _as_xyz([vertex[p] for p in "xyz"])
        normals = _as_xyz([vertex[p] for p in _PLY_NORMALS]) if set(_PLY_NORMALS) <= set(props) else None
    return points, normals


def _first_lines(path: pathlib.Path, count: int) -> list[tuple[int, str]]:
    """Up to ``count`` non-blank, non-comment lines with their 1-based line numbers."""
    found = []
    with open(path, encoding="utf-8-sig") as fh:
        for number, line in enumerate(fh, start=1):
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


def _read_text(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    fix = "give 3 (x y z) or 6 (x y z nx ny nz) numeric columns"
    try:
        head = _first_lines(path, 2)
    except UnicodeDecodeError:
        raise _not_text(path) from None
    if not head:
        raise InputError(f"{path}: holds no data rows — export the points as text, one point a line")

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
    if ncols not in (3, 6):
        raise InputError(f"{path}: line {number} has {ncols} columns — {fix}")

    try:
        # numpy's C parser does the bulk work; only on failure do we walk the lines in Python to
        # name the offending one (loadtxt's own row numbers skip blanks and the header).
        arr = np.loadtxt(
            path, dtype=np.float64, delimiter=delimiter, comments="#", skiprows=header_lines,
            ndmin=2, encoding="utf-8-sig",
        )
    except (ValueError, UnicodeDecodeError) as exc:
        raise _explain_text_error(path, header_lines, delimiter, ncols, fix, exc) from None
    return _split_columns(arr, path, "the file")


def _explain_text_error(
    path: pathlib.Path, header_lines: int, delimiter: str | None, ncols: int, fix: str, exc: Exception
) -> InputError:
    """Find the first bad line of a text point file and say what is wrong with it."""
    try:
        with open(path, encoding="utf-8-sig") as fh:
            for number, line in enumerate(fh, start=1):
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
    return InputError(f"{path}: not a readable point text file ({_one_line(exc)}) — {fix}")


#: Leading bytes of a .npy file and of a zip archive (.npz).  Checked before np.load because, on
#: anything else, np.load assumes a pickle and its error suggests loading the file unsafely.
_NPY_MAGIC = b"\x93NUMPY"
_ZIP_MAGIC = b"PK\x03\x04"


def _check_magic(path: pathlib.Path, magics: tuple[bytes, ...], what: str, fix: str) -> None:
    with open(path, "rb") as fh:
        head = fh.read(max(len(m) for m in magics))
    if not any(head.startswith(m) for m in magics):
        raise InputError(f"{path}: not a {what} file (it lacks the format's leading bytes) — {fix}")


def _read_npy(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    fix = "save an (N, 3) or (N, 6) array with numpy.save"
    _check_magic(path, (_NPY_MAGIC,), "NumPy .npy", fix)
    with _translating(path, "NumPy .npy", fix):
        # allow_pickle=False: a point file must never be able to run code on load
        arr = np.load(path, allow_pickle=False)
        return _split_columns(np.asarray(arr), path, "the file")


def _read_npz(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    fix = "save with numpy.savez(file, points=..., normals=...)"
    _check_magic(path, (_ZIP_MAGIC, _NPY_MAGIC), "NumPy .npz", fix)
    with _translating(path, "NumPy .npz", fix):
        with np.load(path, allow_pickle=False) as npz:
            if not hasattr(npz, "files"):  # np.load gives a bare array for a .npy named .npz
                return _split_columns(np.asarray(npz), path, "the file")
            keys = list(npz.files)
            if "points" in keys:
                points, extra = _split_columns(npz["points"], path, "'points'")
                if extra is not None:
                    raise InputError(f"{path}: 'points' must have 3 columns when stored by name — {fix}")
                if "normals" not in keys:
                    return points, None
                normals, _ = _split_columns(npz["normals"], path, "'normals'")
                if normals.shape != points.shape:
                    raise InputError(
                        f"{path}: 'normals' has shape {normals.shape} but 'points' has {points.shape} — {fix}"
                    )
                return points, normals
            if len(keys) == 1:
                return _split_columns(npz[keys[0]], path, f"'{keys[0]}'")
            raise InputError(f"{path}: .npz holds arrays {keys} but no 'points' — {fix}")


def _read_pcd(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    pypcd4 = _import_extra("pypcd4", ".pcd", "pcd")
    fix = "re-export the file"
    with _translating(path, "PCD", fix):
        cloud = pypcd4.PointCloud.from_path(path)
        fields = cloud.fields
    # pypcd4 reads what is there without comparing with the header's POINTS, so a truncated
    # file would silently give fewer points.
    data = np.atleast_1d(cloud.pc_data)  # loadtxt gives a 0-d record for a one-point ASCII file
    held, declared = len(data), cloud.points
    if held != declared:
        raise InputError(
            f"{path}: PCD file is truncated (header says {declared} points, data holds {held}) — {fix}"
        )
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


def _read_las(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    suffix = path.suffix.lower()
    laspy = _import_extra("laspy", suffix, "las")
    if suffix == ".laz" and not laspy.LazBackend.detect_available():
        raise _missing_extra(suffix, "las")
    fix = "re-export the file"
    with _translating(path, suffix[1:].upper(), fix):
        las = laspy.read(path)
        declared = int(las.header.point_count)
        held = len(las.points)
        # las.x etc. are the integer records times scale plus offset, computed in float64 -- the
        # full precision of the file (never cast through float32, which loses millimetres at 1e6).
        points = _as_xyz([las.x, las.y, las.z])
        names = {name.lower(): name for name in las.point_format.extra_dimension_names}
        normals = None
        for spelling in _LAS_NORMALS:
            if all(s in names for s in spelling):
                normals = _as_xyz([las[names[s]] for s in spelling])
                break
    if held != declared:
        raise InputError(
            f"{path}: LAS file is truncated (header says {declared} points, data holds {held}) — {fix}"
        )
    return points, normals


def _read_e57(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray | None]:
    pye57 = _import_extra("pye57", ".e57", "e57")
    with _translating(path, "E57", "re-export the file"):
        with pye57.E57(str(path)) as e57:
            # Every scan, each moved into the file's common frame by its pose; invalid returns are
            # dropped by pye57.  pye57 reads no normals, so E57 clouds come without them.
            scans = [
                e57.read_scan(i, transform=True, ignore_missing_fields=True) for i in range(e57.scan_count)
            ]
    if not scans:
        return np.empty((0, 3)), None
    points = np.vstack([_as_xyz([s["cartesianX"], s["cartesianY"], s["cartesianZ"]]) for s in scans])
    return points, None


_READERS: dict[str, Callable[[pathlib.Path], tuple[np.ndarray, np.ndarray | None]]] = {
    ".ply": _read_ply,
    ".xyz": _read_text,
    ".txt": _read_text,
    ".csv": _read_text,
    ".asc": _read_text,
    ".npy": _read_npy,
    ".npz": _read_npz,
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
        .asc``) hold 3 columns (x y z) or 6 (x y z nx ny nz), optionally one header line, separated
        by ``,``, ``;``, tabs or spaces; ``#`` starts a comment.  ``.npy`` holds an ``(N, 3)`` or
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

    Examples
    --------
    >>> import pathlib, tempfile
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (folder / "cloud.csv").write_text("x,y,z\\n0,0,0\\n1,0,0\\n0,1,0.5\\n")
    >>> points, normals = read_points(folder / "cloud.csv")
    >>> points.shape, normals is None
    ((3, 3), True)
    """
    path = pathlib.Path(path)
    reader = _READERS.get(path.suffix.lower())
    if reader is None:
        raise InputError(
            f"{path}: unknown point format {path.suffix or '(no suffix)'!r} — "
            f"use one of {', '.join(POINT_FORMATS)}"
        )
    _check_readable(path)
    return reader(path)


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
    path = pathlib.Path(path)
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
    path = pathlib.Path(path)
    family = POINT_WRITE_FORMATS.get(path.suffix.lower())
    if family is None:
        raise InputError(f"{path}: cannot write points as {path.suffix or '(no suffix)'!r} — "
                         f"use one of {', '.join(POINT_WRITE_FORMATS)}")
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
    path = pathlib.Path(path)
    writer = _MESH_WRITERS.get(path.suffix.lower())
    if writer is None:
        raise InputError(
            f"{path}: unknown mesh format {path.suffix or '(no suffix)'!r} — "
            f"use one of {', '.join(MESH_FORMATS)}"
        )
    v, f = _check_mesh(vertices, faces)
    writer(path, v, f)


def write_spine_csv(path: PathLike, t, points, radius) -> None:
    """Write spine samples as CSV with header ``t,x,y,z,radius`` and full float64 precision.

    Parameters
    ----------
    path : str or os.PathLike
    t : (M,) array_like
        Curve parameter of each sample.
    points : (M, 3) array_like
        Spine points.
    radius : (M,) array_like
        Pipe/canal radius at each sample.

    Notes
    -----
    Numbers are written with ``%.17g``, enough digits for every float64 to read back bit-exact.
    """
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    pts = np.asarray(points, dtype=np.float64)
    r = np.asarray(radius, dtype=np.float64).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] != 3 or not len(t) == len(pts) == len(r):
        raise InputError(
            f"spine CSV needs t (M,), points (M, 3) and radius (M,), got {t.shape}, {pts.shape}, {r.shape}"
        )
    table = np.column_stack([t, pts, r])
    atomic_write(
        path,
        lambda tmp: np.savetxt(tmp, table, fmt="%.17g", delimiter=",", header="t,x,y,z,radius", comments=""),
    )


def write_spine_dxf(path: PathLike, knots, control_points, degree, sample_points, sample_radius) -> None:
    """Write the spine as a CAD drawing: one exact SPLINE plus its radius samples.

    Parameters
    ----------
    path : str or os.PathLike
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

    Notes
    -----
    The drawing (DXF R2010, ezdxf extra ``dxf``) holds

    * on layer ``SPINE``: one SPLINE entity built from ``knots`` and ``control_points``;
    * on layer ``RADIUS``: one 3D POLYLINE through ``sample_points``; **each of its vertices
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
    ezdxf = _import_extra("ezdxf", ".dxf", "dxf", verb="writing")
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

    doc = ezdxf.new("R2010", setup=False)
    doc.appids.add(DXF_APPID)
    doc.layers.add("SPINE")
    doc.layers.add("RADIUS")
    msp = doc.modelspace()
    msp.add_open_spline(cps.tolist(), degree=degree, knots=knots.tolist(), dxfattribs={"layer": "SPINE"})
    line = msp.add_polyline3d(samples.tolist(), dxfattribs={"layer": "RADIUS"})
    for vertex, r in zip(line.vertices, radius.tolist()):
        vertex.set_xdata(DXF_APPID, [(1040, r)])
    atomic_write(path, lambda tmp: doc.saveas(tmp))


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
