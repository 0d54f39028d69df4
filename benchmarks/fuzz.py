"""Mutation fuzzing of every point reader and of the model loader.

Each case takes a valid file -- written by canalsurf's own writers or by the format's library, from a
seeded cloud -- damages it (bytes flipped, the file cut short, a slice duplicated, numbers in its
header or a type in it changed, counts made huge) and reads it with :func:`canalsurf.read_points` or
:func:`canalsurf.load_model` in a child process limited to 4 GB of address space, with a timeout per
case.  A case ends in one of five outcomes:

``ok``           the file was read (a damaged file may still be a valid one);
``InputError``   refused with a one-line :class:`canalsurf.errors.InputError`;
``other``        any other exception -- also a multi-line InputError, a warning, or a result that is
                 not ``(N, 3)`` float64 points with ``None`` or ``(N, 3)`` normals;
``crash``        the child died (a signal, an abort in a native library);
``timeout``      the child took longer than the timeout.

Failures are the last three.  Cases are seeded: the same ``--seed`` gives the same sequence of cases
(how many run depends on the machine's speed), and ``--keep DIR`` keeps the file of every failure.

Run from the repository root::

    python benchmarks/fuzz.py                   # one minute
    python benchmarks/fuzz.py --minutes 2 --markdown docs/reliability.md
"""

from __future__ import annotations

import argparse
import io
import json
import os
import re
import select
import struct
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import crc32c
import numpy as np

#: Address-space limit of the child that reads the files: a reader that allocates what a corrupted
#: header claims fails there instead of swapping the machine.
MEMORY_LIMIT = 4 << 30
#: Default seconds a single case may take (reading a file of a few hundred kB).
TIMEOUT = 20.0
OUTCOMES = ("ok", "InputError", "other", "crash", "timeout")
FAILURES = ("other", "crash", "timeout")
#: The targets, in the order of the table: name -> file suffix.
TARGETS = {
    "ply ascii": ".ply", "ply binary": ".ply", "xyz": ".xyz", "csv": ".csv", "npy": ".npy", "npz": ".npz",
    "pcd ascii": ".pcd", "pcd binary": ".pcd", "las": ".las", "laz": ".laz", "e57": ".e57",
    "model.json": ".json",
}
#: Huge and odd values written over counts and other header numbers.
ODD_NUMBERS = (0, 1, 2**31 - 1, 2**31, 2**32 - 1, 2**32, 2**63 - 1, 10**12, 10**18, 10**30)


# --------------------------------------------------------------------------------------------------
# valid files


def _cloud(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A noisy bent tube of radius 1 and its unit normals, at georeferenced-like coordinates."""
    u, v = rng.uniform(0, np.pi / 2, n), rng.uniform(0, 2 * np.pi, n)
    normals = np.column_stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)])
    ring = 5 + np.cos(v) + rng.normal(scale=0.01, size=n)
    points = np.column_stack([ring * np.cos(u), ring * np.sin(u), np.sin(v)])
    return points + rng.uniform(-1e3, 1e3, 3), normals


def _ply(path: Path, points, normals, text: bool) -> None:
    import plyfile

    names = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    data = points if normals is None else np.hstack([points, normals])
    vertex = np.empty(len(points), dtype=[(n, "f8") for n in names])
    for i, name in enumerate(names):
        vertex[name] = data[:, i]
    plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")], text=text).write(str(path))


def _pcd(path: Path, points, normals, encoding: str) -> None:
    import pypcd4

    fields = ("x", "y", "z") + (("normal_x", "normal_y", "normal_z") if normals is not None else ())
    data = points if normals is None else np.hstack([points, normals])
    pypcd4.PointCloud.from_points(data, fields, [np.float64] * len(fields)).save(
        path, encoding=pypcd4.Encoding(encoding))


def _las(path: Path, points, normals, version: str, point_format: int) -> None:
    import laspy

    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.round(points.min(axis=0))
    if normals is not None:
        header.add_extra_dims([laspy.ExtraBytesParams(name=n, type=np.float32)
                               for n in ("NormalX", "NormalY", "NormalZ")])
    las = laspy.LasData(header)
    las.x, las.y, las.z = points.T
    if normals is not None:
        las.NormalX, las.NormalY, las.NormalZ = normals.T
    las.write(path)


def _e57(path: Path, points, scans: int) -> None:
    import pye57

    with pye57.E57(str(path), mode="w") as e57:
        for i, part in enumerate(np.array_split(points, scans)):
            data = {f"cartesian{a}": np.ascontiguousarray(part[:, k]) for k, a in enumerate("XYZ")}
            e57.write_scan_raw(data, translation=np.array([float(i), 0.0, 0.0]))


def _model(path: Path, rng: np.random.Generator, variant: int) -> None:
    import canalsurf
    from canalsurf.model import CanalModel

    name = ("fig9-pipe", "fig16-canal", "torus")[variant % 3]
    tube = canalsurf.make_tube(name, n=200, rng=int(rng.integers(1 << 30)))
    kind = "pipe" if name.endswith("pipe") else "canal"
    radius = tube.radius if kind == "canal" else canalsurf.synth.constant_spline(1.0)
    model = CanalModel(kind, tube.spine, radius, tube.closed, {"R": 0.2, "delta": 0.05}, {"iterations": 12})
    path.write_text(json.dumps(model.to_dict(), indent=1), encoding="utf-8")


def valid_files(folder: Path, seed: int) -> dict[str, list[bytes]]:
    """A few valid files of every target (with and without normals, other sizes), as bytes."""
    from canalsurf.io import write_points

    rng = np.random.default_rng(seed)
    files: dict[str, list[bytes]] = {name: [] for name in TARGETS}
    for variant, n in enumerate((120, 700)):
        points, normals = _cloud(rng, n)
        with_normals = normals if variant == 0 else None
        makers = {
            "ply ascii": lambda p: _ply(p, points, with_normals, True),
            "ply binary": lambda p: _ply(p, points, with_normals, False),
            "xyz": lambda p: write_points(p, points, with_normals),
            "csv": lambda p: write_points(p, points, with_normals),
            "npy": lambda p: write_points(p, points, with_normals),
            "npz": lambda p: (write_points(p, points, with_normals) if variant == 0 else
                              np.savez_compressed(p, points=points)),
            "pcd ascii": lambda p: _pcd(p, points, with_normals, "ascii"),
            "pcd binary": lambda p: _pcd(p, points, with_normals, ("binary", "binary_compressed")[variant]),
            "las": lambda p: _las(p, points, with_normals, ("1.2", "1.4")[variant], (3, 6)[variant]),
            "laz": lambda p: _las(p, points, with_normals, ("1.4", "1.2")[variant], (6, 1)[variant]),
            "e57": lambda p: _e57(p, points, variant + 1),
            "model.json": lambda p: _model(p, rng, variant),
        }
        for name, make in makers.items():
            path = folder / f"valid-{variant}{TARGETS[name]}"
            make(path)
            files[name].append(path.read_bytes())
            path.unlink()
    files["model.json"].append(_model_bytes(folder, rng, 2))
    return files


def _model_bytes(folder: Path, rng, variant: int) -> bytes:
    path = folder / "valid.json"
    _model(path, rng, variant)
    raw = path.read_bytes()
    path.unlink()
    return raw


# --------------------------------------------------------------------------------------------------
# mutations


def _header_end(raw: bytes, target: str) -> int:
    """Bytes of the file's header (where the counts live), for mutations aimed at it."""
    if target.startswith("ply"):
        return raw.find(b"end_header") + 11
    if target.startswith("pcd"):
        return raw.find(b"DATA") + 20
    if target in ("las", "laz"):
        return struct.unpack_from("<I", raw, 96)[0] if len(raw) > 100 else len(raw)
    if target == "npy":
        return raw.find(b"\n") + 1
    if target == "e57":
        return min(len(raw), 1024)
    return min(len(raw), 400)


def flip_bytes(raw: bytes, rng, target: str) -> tuple[bytes, str]:
    out = bytearray(raw)
    # half the flips in the header, where one byte changes what the reader believes
    end = max(1, _header_end(raw, target)) if rng.random() < 0.5 else len(raw)
    count = int(rng.integers(1, 9))
    for i in rng.integers(0, min(end, len(raw)), count):
        out[i] ^= int(rng.integers(1, 256))
    return bytes(out), f"flip {count} bytes in the first {end}"


def truncate(raw: bytes, rng, target: str) -> tuple[bytes, str]:
    cut = int(rng.integers(1, len(raw)))
    return raw[:cut], f"cut at {cut} of {len(raw)}"


def duplicate_slice(raw: bytes, rng, target: str) -> tuple[bytes, str]:
    size = int(rng.choice([1, 7, 64, 500, 4096]))
    start = int(rng.integers(0, max(1, len(raw) - size)))
    at = int(rng.integers(0, len(raw)))
    return raw[:at] + raw[start:start + size] + raw[at:], f"duplicate {size} bytes from {start} at {at}"


def _odd_number(rng) -> int:
    return int(rng.choice(ODD_NUMBERS)) if rng.random() < 0.6 else int(rng.integers(0, 1 << 16))


def change_header_number(raw: bytes, rng, target: str) -> tuple[bytes, str]:
    """Change one number of the header: a text number in text headers, a binary field in LAS."""
    if target in ("las", "laz"):
        # offset, (type, width) of the LAS header's numbers: header size, point data offset, VLR
        # count, point format, record length, legacy count, scales, offsets, 1.4 EVLR start/count and count
        fields = [(94, "<H"), (96, "<I"), (100, "<I"), (104, "<B"), (105, "<H"), (107, "<I"),
                  (131, "<d"), (139, "<d"), (155, "<d"), (235, "<Q"), (243, "<I"), (247, "<Q")]
        offset, fmt = fields[int(rng.integers(len(fields)))]
        out = bytearray(raw)
        if fmt == "<d":
            value = float(rng.choice([0.0, -0.0, 1e-320, 1e300, np.inf, np.nan, 1e15]))
        else:
            value = _odd_number(rng) % (1 << (8 * struct.calcsize(fmt)))
        if offset + struct.calcsize(fmt) <= len(out):
            struct.pack_into(fmt, out, offset, value)
        return bytes(out), f"header field at {offset} = {value}"
    if target == "e57":
        return _e57_number(raw, rng)
    end = _header_end(raw, target)
    head = raw[:end]
    numbers = [m for m in re.finditer(rb"-?\d+(\.\d+)?(e[-+]?\d+)?", head)]
    if not numbers:
        return flip_bytes(raw, rng, target)
    m = numbers[int(rng.integers(len(numbers)))]
    new = str(_odd_number(rng) * int(rng.choice([1, -1]))).encode()
    return raw[:m.start()] + new + raw[m.end():], f"number {m.group().decode()} -> {new.decode()}"


#: Words of text headers and what a mutation may put in their place: types, encodings, names.
HEADER_WORDS = {
    "ply": {b"double": [b"float", b"uchar", b"list uchar double", b"int64"], b"ascii": [b"binary_little_endian"],
            b"binary_little_endian": [b"ascii", b"binary_big_endian"], b"vertex": [b"face", b"vertex vertex"],
            b"property double x": [b"property double q", b"property list uchar double x"]},
    "pcd": {b"F": [b"U", b"I", b"Q"], b"8": [b"1", b"3", b"16"], b"binary": [b"ascii", b"binary_compressed"],
            b"ascii": [b"binary"], b"binary_compressed": [b"binary"], b"x": [b"x x", b"_"]},
    "npy": {b"<f8": [b"<f4", b"|O", b">f8", b"<c16", b"<U3", b"V24"], b"False": [b"True"],
            b"'shape'": [b"'shapes'"]},
}


def change_header_word(raw: bytes, rng, target: str) -> tuple[bytes, str]:
    """Replace a word of a text header (a type, an encoding, a name) by another the format knows."""
    words = HEADER_WORDS.get(target.split()[0])
    end = _header_end(raw, target)
    found = [w for w in (words or {}) if re.search(rb"(?<![\w<>|])" + re.escape(w) + rb"(?!\w)", raw[:end])]
    if not found:
        return flip_bytes(raw, rng, target)
    old = found[int(rng.integers(len(found)))]
    new = words[old][int(rng.integers(len(words[old])))]
    matches = list(re.finditer(rb"(?<![\w<>|])" + re.escape(old) + rb"(?!\w)", raw[:end]))
    m = matches[int(rng.integers(len(matches)))]
    return raw[:m.start()] + new + raw[m.end():], f"header word {old.decode()} -> {new.decode()}"


def huge_count(raw: bytes, rng, target: str) -> tuple[bytes, str]:
    """Replace a count-like number (rows, points, records) by a huge one."""
    if target in ("las", "laz"):
        out = bytearray(raw)
        offset, fmt = [(100, "<I"), (107, "<I"), (247, "<Q"), (243, "<I")][int(rng.integers(4))]
        value = int(rng.choice([2**31, 2**32 - 1, 10**12, 2**63 - 1])) % (1 << (8 * struct.calcsize(fmt)))
        if offset + struct.calcsize(fmt) <= len(out):
            struct.pack_into(fmt, out, offset, value)
        return bytes(out), f"count at {offset} = {value}"
    patterns = {"ply ascii": rb"(element vertex )(\d+)", "ply binary": rb"(element vertex )(\d+)",
                "pcd ascii": rb"(POINTS |WIDTH )(\d+)", "pcd binary": rb"(POINTS |WIDTH )(\d+)",
                "npy": rb"('shape': \()(\d+)", "npz": rb"('shape': \()(\d+)", "e57": rb'(recordCount=")(\d+)',
                "model.json": rb'("degree": )(\d+)'}
    if target == "e57":
        return _e57_number(raw, rng, rb'recordCount="(\d+)"')
    if target == "npz":
        return _npz_member_header(raw, rng)
    pattern = patterns.get(target)
    m = re.search(pattern, raw) if pattern else None
    if m is None:
        return duplicate_slice(raw, rng, target)
    new = str(int(rng.choice([10**6, 2**31, 10**12, 10**18, 10**40]))).encode()
    return raw[:m.start(2)] + new + raw[m.end(2):], f"count {m.group(2).decode()} -> {new.decode()}"


def _npz_member_header(raw: bytes, rng) -> tuple[bytes, str]:
    """Rewrite the archive with one member's shape changed (a valid zip, a lying array header)."""
    with zipfile.ZipFile(io.BytesIO(raw)) as archive:
        members = {info.filename: archive.read(info) for info in archive.infolist()}
    name = sorted(members)[int(rng.integers(len(members)))]
    rows = int(rng.choice([0, 1, 50, 10**6, 10**12]))
    members[name] = re.sub(rb"'shape': \(\d+", f"'shape': ({rows}".encode(), members[name], count=1)
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        for member, data in members.items():
            archive.writestr(member, data)
    return out.getvalue(), f"{name} rows -> {rows}"


def _e57_number(raw: bytes, rng, pattern: bytes = rb'(?:recordCount|fileOffset)="(\d+)"|>(-?\d[\d.e+-]*)<'):
    """Change a number of the E57 XML in place (same length) and re-compute the page checksums.

    E57 files are 1024-byte pages of 1020 data bytes and a big-endian CRC-32C, so a plain byte flip
    only ever tests the checksum.
    """
    logical = bytearray(b"".join(raw[i:i + 1020] for i in range(0, len(raw) - len(raw) % 1024, 1024)))
    found = [m for m in re.finditer(pattern, logical)]
    if not found:
        return flip_bytes(raw, rng, "e57")
    m = found[int(rng.integers(len(found)))]
    group = 1 if m.group(1) is not None else 2
    old = m.group(group)
    digits = rng.integers(0, 10, len(old))
    new = ("".join(map(str, digits)) if rng.random() < 0.7 else "9" * len(old)).encode()
    logical[m.start(group):m.end(group)] = new
    pages = [bytes(logical[i:i + 1020]) for i in range(0, len(logical), 1020)]
    return (b"".join(p + struct.pack(">I", crc32c.crc32c(p)) for p in pages),
            f"XML number {old.decode()} -> {new.decode()}")


def json_edit(raw: bytes, rng, target: str) -> tuple[bytes, str]:
    """A structural change of a model file: a value replaced by an odd one, a key dropped, deep nesting."""
    data = json.loads(raw)
    paths = []

    def walk(node, path):
        paths.append(path)
        children = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for key, child in list(children)[:40]:  # a sample of long lists is enough
            walk(child, path + [key])

    walk(data, [])
    path = paths[int(rng.integers(len(paths)))]
    if not path:  # the whole document
        value = [None, 5, "canalsurf.model", [], [[[]]]][int(rng.integers(5))]
        return json.dumps(value).encode(), f"document = {value}"
    parent = data
    for key in path[:-1]:
        parent = parent[key]
    odd = [None, True, 0, -1, 3.7, 5, 1e308, -1e-320, "x", [], {}, [[[[1]]]], 10**25, [0.0] * 3]
    action = rng.choice(["replace", "drop", "nest"])
    if action == "drop" and isinstance(parent, dict):
        del parent[path[-1]]
        return json.dumps(data).encode(), f"drop {path}"
    if action == "nest":
        parent[path[-1]] = json.loads("[" * 50 + "1" + "]" * 50)
        return json.dumps(data).encode(), f"nest 50 deep at {path}"
    value = odd[int(rng.integers(len(odd)))]
    parent[path[-1]] = value
    text = json.dumps(data)
    if rng.random() < 0.2:  # numbers JSON cannot hold, as Python writes them
        text = text.replace("1e+308", rng.choice(["NaN", "Infinity", "1e999"]), 1)
    return text.encode(), f"{path} = {str(value)[:20]}"


MUTATIONS = (flip_bytes, truncate, duplicate_slice, change_header_number, huge_count, change_header_word)


def mutate(raw: bytes, rng, target: str) -> tuple[bytes, str]:
    """One or two mutations of ``raw``; the text says which."""
    mutations = MUTATIONS + ((json_edit, json_edit) if target == "model.json" else ())
    done = []
    for _ in range(1 if rng.random() < 0.8 else 2):
        mutation = mutations[int(rng.integers(len(mutations)))]
        try:
            raw, what = mutation(raw, rng, target)
        except Exception:  # noqa: BLE001 -- a structure (zip, JSON) the first mutation broke
            mutation = flip_bytes
            raw, what = mutation(raw, rng, target)
        done.append(f"{mutation.__name__}: {what}")
    return raw, "; ".join(done)


# --------------------------------------------------------------------------------------------------
# the child that reads


def worker() -> int:
    """Read the files named on stdin (``points|model <path>``), answer one JSON line each."""
    import gc
    import warnings

    warnings.simplefilter("error")  # a warning is a failure: the command line must print only its error
    leaks = []  # what Python could not raise: a file left open (ResourceWarning) and the like
    sys.unraisablehook = lambda info: leaks.append(f"{info.exc_type.__name__}: {info.exc_value}")
    from canalsurf.errors import InputError
    from canalsurf.io import read_points
    from canalsurf.model import load_model

    for module in ("laspy", "lazrs", "pye57", "pypcd4", "plyfile"):  # imported once, outside the timing
        __import__(module)
    gc.freeze()  # what is imported now is never garbage: the collection after each case skips it
    for line in sys.stdin:
        kind, path = line.rstrip("\n").split(" ", 1)
        try:
            if kind == "model":
                load_model(path)
            else:
                points, normals = read_points(path)
                if not (isinstance(points, np.ndarray) and points.dtype == np.float64 and points.ndim == 2
                        and points.shape[1] == 3 and (normals is None or normals.shape == points.shape)):
                    raise TypeError(f"read_points gave {type(points).__name__} {getattr(points, 'shape', '')}")
            answer = {"outcome": "ok"}
        except InputError as exc:
            one_line = "\n" not in str(exc) and str(exc).strip() == str(exc)
            answer = {"outcome": "InputError" if one_line else "other",
                      "detail": str(exc) if one_line else f"multi-line InputError: {exc!s}"}
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as exc:  # noqa: BLE001 -- every other exception is what we look for
            answer = {"outcome": "other", "detail": f"{type(exc).__name__}: {exc}"[:500]}
        gc.collect()
        if leaks:
            answer = {"outcome": "other", "detail": f"after {answer['outcome']}: {leaks[0]}"[:500]}
            leaks.clear()
        print(json.dumps(answer), flush=True)
    return 0


def _limit_memory() -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


class Reader:
    """The worker child: restarted after a crash or a timeout."""

    def __init__(self):
        self.proc = None

    def start(self) -> None:
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True, preexec_fn=_limit_memory)

    def read(self, kind: str, path: Path, timeout: float) -> dict:
        if self.proc is None or self.proc.poll() is not None:
            self.start()
        try:
            self.proc.stdin.write(f"{kind} {path}\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            return self._died()
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            self.stop()
            return {"outcome": "timeout", "detail": f"no answer within {timeout:g} s"}
        line = self.proc.stdout.readline()
        if not line:
            return self._died()
        return json.loads(line)

    def _died(self) -> dict:
        code = self.proc.wait()
        self.proc = None
        how = f"signal {-code}" if code < 0 else f"exit {code}"
        return {"outcome": "crash", "detail": f"the reading process died ({how})"}

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None


# --------------------------------------------------------------------------------------------------
# the loop and the table


def make_case(valid: dict, seed: int, case: int) -> tuple[str, bytes, str]:
    """Target, damaged bytes and description of case number ``case`` (the same for the same seed)."""
    target = list(TARGETS)[case % len(TARGETS)]
    rng = np.random.default_rng([seed, case])
    bases = valid[target]
    raw, what = mutate(bases[int(rng.integers(len(bases)))], rng, target)
    return target, raw, what


def run(minutes: float, seed: int, timeout: float, keep: Path | None,
        only: int | None = None) -> tuple[dict, list[dict], int]:
    """Fuzz for ``minutes`` (or run case ``only``); per-target counts, the failures, the number of cases."""
    counts = {name: dict.fromkeys(OUTCOMES + ("seconds",), 0) for name in TARGETS}
    failures = []
    reader = Reader()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        valid = valid_files(folder, seed)
        reader.start()
        for target, files in valid.items():  # a fuzzer whose valid files fail would measure nothing
            for i, raw in enumerate(files):
                path = folder / f"valid-{i}{TARGETS[target]}"
                path.write_bytes(raw)
                answer = reader.read("model" if target == "model.json" else "points", path, timeout)
                if answer["outcome"] != "ok":
                    raise RuntimeError(f"valid {target} file {i} is not read: {answer}")
                path.unlink()
        deadline = time.monotonic() + 60 * minutes
        case = 0 if only is None else only
        try:
            while time.monotonic() < deadline if only is None else case == only:
                target, raw, what = make_case(valid, seed, case)
                path = folder / f"case-{case}{TARGETS[target]}"
                path.write_bytes(raw)
                start = time.perf_counter()
                answer = reader.read("model" if target == "model.json" else "points", path, timeout)
                counts[target]["seconds"] += time.perf_counter() - start
                counts[target][answer["outcome"]] += 1
                if only is not None:
                    print(f"case {case} ({target}, {what}): {answer}")
                if answer["outcome"] in FAILURES:
                    failures.append({"case": case, "target": target, "mutation": what, **answer})
                    print(f"FAILURE case {case} ({target}, {what}): {answer['detail']}", flush=True)
                    if keep is not None:
                        keep.mkdir(parents=True, exist_ok=True)
                        (keep / path.name).write_bytes(raw)
                path.unlink()
                case += 1
        finally:
            reader.stop()
    return counts, failures, case if only is None else 1


def table(counts: dict) -> str:
    head = "| reader | cases | ok | InputError | other exception | crash | timeout | failures | seconds |"
    lines = [head, "|---|---|---|---|---|---|---|---|---|"]
    total = dict.fromkeys(OUTCOMES + ("seconds",), 0)
    for name, row in list(counts.items()) + [("**all**", total)]:
        if row is not total:
            for key in total:
                total[key] += row[key]
        cases = sum(row[o] for o in OUTCOMES)
        bad = sum(row[o] for o in FAILURES)
        lines.append(f"| {name} | {cases:,} | {row['ok']:,} | {row['InputError']:,} | {row['other']:,} | "
                     f"{row['crash']:,} | {row['timeout']:,} | {bad:,} | {row['seconds']:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=1.0, help="how long to fuzz (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the valid files and the mutations")
    parser.add_argument("--timeout", type=float, default=TIMEOUT, help=f"seconds per case (default {TIMEOUT:g})")
    parser.add_argument("--keep", type=Path, help="keep the file of every failing case in this folder")
    parser.add_argument("--case", type=int, help="run only this case (of --seed), e.g. to replay a failure")
    parser.add_argument("--markdown", type=Path, help="also write the table into this Markdown file")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    if args.worker:
        return worker()
    counts, failures, cases = run(args.minutes, args.seed, args.timeout, args.keep, args.case)
    text = table(counts)
    print(text)
    print(f"{cases:,} cases, {len(failures)} failures")
    if args.markdown:
        listed = "\n".join(f"- case {f['case']} ({f['target']}; {f['mutation']}): {f['outcome']}, {f['detail']}"
                           for f in failures[:50]) or "None."
        args.markdown.write_text(
            "# Reliability\n\nMade by `" + " ".join(["python", "benchmarks/fuzz.py", *argv]) + "` on the "
            f"development machine ({os.cpu_count()} cores). Each case takes a valid file of one reader's format "
            "(written from a seeded cloud by canalsurf's writers or the format's library; for `model.json`, a "
            "saved pipe, canal or closed loop), damages it -- bytes flipped, the file cut short, a slice "
            "duplicated, a header number or word (a type, an encoding) changed, a count made huge, for "
            "`model.json` also values replaced, "
            "keys dropped, nesting deepened -- and reads it with `read_points` or `load_model` in a child "
            f"process limited to {MEMORY_LIMIT >> 30} GB of address space, with a timeout of {args.timeout:g} s "
            "per case. *ok*: the file was still read; *InputError*: refused with one line; *other exception*: "
            "anything else raised (a warning or a multi-line message counts as one); *crash*: the process "
            "died; *timeout*: no answer in time. *Failures* are the last three. *Seconds* is the time spent "
            "reading, child restarts included.\n\n" + text + f"\n\n{cases:,} cases.\n\nFailures:\n\n{listed}\n",
            encoding="utf-8")
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
