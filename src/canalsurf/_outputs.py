"""Writing the set of files of one result into a folder, as one unit.

:func:`write_files` is what the command line writes through:

* every file is first written into a hidden staging folder inside the target, and only once all of
  them have succeeded are they moved into place (``os.replace``); a failure or an interrupt leaves
  the earlier files untouched and removes the staging folder and any folder made for the write;
* the folder is locked while it is written (``.canalsurf.lock``, ``flock`` on POSIX, ``msvcrt`` on
  Windows), so two runs into the same folder cannot mix their files: the second waits for the first;
* the names written are kept in ``.canalsurf-manifest.json``; the next write into the folder removes
  the files of that list it does not write again (a report.html left from a run with ``--report``),
  unless they have been changed since -- files canalsurf did not write are never touched.

Moving the files into place, removing the stale ones and updating the manifest happen with signals
held back (:func:`canalsurf._interrupt.deferred`), so an interrupt cannot cut the set in two.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import stat
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from . import _interrupt
from .errors import InputError

__all__ = ["write_files", "make_dirs", "remove_dirs", "check_output_folder", "output_lock",
           "LOCK_NAME", "MANIFEST_NAME", "STAGING_PREFIX"]

#: Lock file of a folder being written (removed again when the write is done).
LOCK_NAME = ".canalsurf.lock"
#: The names (and sizes and modification times) of the files the last write put into the folder.
MANIFEST_NAME = ".canalsurf-manifest.json"
#: Prefix of the staging folders (``tempfile.mkdtemp`` adds a random part).
STAGING_PREFIX = ".canalsurf-"
#: Seconds a run waits for another run writing into the same folder.  A write takes seconds (the
#: files are computed before the lock is taken), so a lock held this long belongs to a stuck run.
LOCK_TIMEOUT = 300.0
#: Seconds between two attempts to take the lock.
LOCK_POLL = 0.05

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None
try:
    import msvcrt
except ImportError:  # POSIX
    msvcrt = None


def make_dirs(folder: Path, created: list[Path] | None = None) -> list[Path]:
    """Create ``folder`` and its missing parents; return those created (outermost first).

    Each folder is appended to ``created`` (when given) as soon as it exists, so an interrupt
    cannot lose track of one.

    Raises
    ------
    InputError
        A path component exists but is not a folder.
    OSError
        The folder cannot be created (permissions, ...); whatever was created is removed again.
    """
    missing = []
    probe = folder
    while not probe.exists() and probe != probe.parent:
        missing.append(probe)
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"{folder}: cannot create this folder, {probe} is a file — "
                         "choose another output folder")
    made: list[Path] = []
    try:
        for path in reversed(missing):
            with _interrupt.deferred():
                try:
                    path.mkdir()
                except FileExistsError:
                    if path.is_dir():  # another run made it meanwhile
                        continue
                    raise
                made.append(path)
                if created is not None:
                    created.append(path)
    except BaseException:
        remove_dirs(made)
        raise
    return made


def remove_dirs(created: list[Path]) -> None:
    """Remove folders made by :func:`make_dirs`, innermost first, if they are empty."""
    for path in reversed(created):
        with contextlib.suppress(OSError):
            path.rmdir()


def check_output_folder(folder: Path) -> None:
    """Fail before any work if ``folder`` can never be created (a file stands in the way)."""
    probe = folder
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"{folder}: cannot create this folder, {probe} is a file — "
                         "choose another output folder")


def _check_inside(folder: Path, base: Path) -> None:
    """``folder`` must be ``base`` or lie inside it once links and ``..`` are resolved."""
    real, root = folder.resolve(), base.resolve()
    if real != root and not real.is_relative_to(root):
        raise InputError(f"{folder}: leads outside {base} (to {real}) — remove the link or choose "
                         "another output folder")


def write_files(folder: Path, files: dict[str, Callable[[Path], None]], *,
                inside: Path | None = None) -> list[Path]:
    """Write ``files`` (name -> ``write(path)``) into ``folder``, all or nothing, under its lock.

    ``inside``: the folder must lie inside this one (after resolving links).  The folder (and
    missing parents) is created only now; on failure the staging folder and any folder created here
    are removed, and earlier files of the same names are left untouched.  Returns the paths written.
    """
    if inside is not None:
        _check_inside(folder, inside)
    for name in files:
        if (folder / name).is_dir():
            raise InputError(f"{folder / name}: is a folder — remove it or choose another output folder")
    created: list[Path] = []
    staging: list[Path] = []

    def clean_up() -> None:
        for path in staging:
            shutil.rmtree(path, ignore_errors=True)
        remove_dirs(created)

    with _interrupt.on_interrupt(clean_up):
        try:
            with output_lock(folder, created):
                with _interrupt.deferred():
                    staging.append(Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=folder)))
                for name, write in files.items():
                    write(staging[0] / name)
                with _interrupt.deferred():
                    _commit(folder, staging[0], list(files))
                    staging[0].rmdir()
                    staging.clear()
        except BaseException:
            clean_up()
            raise
    return [folder / name for name in files]


def _commit(folder: Path, staging: Path, names: list[str]) -> None:
    """Move the staged files into place, remove the previous write's files that are not written
    again, and record the new set in the manifest."""
    previous = _read_manifest(folder)
    for name in names:
        os.replace(staging / name, folder / name)
    now = {name: _stamp(folder / name) for name in names}
    for name, stamp in previous.items():
        if name not in now and _stamp(folder / name) == stamp:  # still the file written then
            with contextlib.suppress(FileNotFoundError):
                (folder / name).unlink()
    manifest = staging / MANIFEST_NAME
    manifest.write_text(json.dumps({"files": now}, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    os.replace(manifest, folder / MANIFEST_NAME)


def _stamp(path: Path) -> dict[str, int] | None:
    """Size and modification time of a regular file (not a link), else None."""
    try:
        st = path.lstat()
    except OSError:
        return None
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns} if stat.S_ISREG(st.st_mode) else None


def _read_manifest(folder: Path) -> dict[str, dict]:
    """The files the previous write recorded; nothing if the manifest is missing or unreadable.

    Only plain names of files in the folder itself are taken, never canalsurf's own hidden files.
    """
    try:
        data = json.loads((folder / MANIFEST_NAME).read_text(encoding="utf-8"))
        files = data["files"]
        items = list(files.items())
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}
    return {name: stamp for name, stamp in items
            if isinstance(name, str) and name == Path(name).name and name not in ("", ".", "..")
            and not name.startswith(".canalsurf") and isinstance(stamp, dict)}


@contextlib.contextmanager
def output_lock(folder: Path, created: list[Path] | None = None, *,
                timeout: float | None = None) -> Iterator[None]:
    """Create ``folder`` if needed and hold its lock for the block.

    A run that finds the folder locked waits (up to ``timeout`` seconds, default
    :data:`LOCK_TIMEOUT`), then fails with an :class:`InputError`.  The lock file is removed when
    the block ends: a waiting run notices that the file it waited on is gone and takes a new one.
    Folders made here are appended to ``created``.
    """
    if fcntl is None and msvcrt is None:  # no file locking on this system
        make_dirs(folder, created)
        yield
        return
    timeout = LOCK_TIMEOUT if timeout is None else timeout
    deadline = time.monotonic() + timeout
    path = folder / LOCK_NAME
    with contextlib.ExitStack() as stack:
        while True:
            make_dirs(folder, created)
            with _interrupt.deferred():  # a lock file made here is removed again on an interrupt
                fd = _try_lock(path)
                if fd is not None:
                    stack.callback(_release, fd, path)
                    stack.enter_context(_interrupt.on_interrupt(lambda: _release(fd, path)))
                    break
            if time.monotonic() >= deadline:
                raise InputError(f"{folder}: another canalsurf run has been writing into this folder for "
                                 f"{timeout:g} s — wait for it to finish, or remove {path} if no run is "
                                 "going on")
            time.sleep(LOCK_POLL)
        yield


def _try_lock(path: Path) -> int | None:
    """Open and lock ``path`` without waiting; the descriptor, or None if another run holds it."""
    flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags, 0o644)
    except FileNotFoundError:  # the folder was removed meanwhile (a failed run cleaned up)
        return None
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        else:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
    except OSError:
        os.close(fd)
        return None
    # The run that held the lock removes the file before it lets go: a lock on a removed file is
    # worth nothing, try again with the file now at ``path``.
    try:
        same = os.path.samestat(os.fstat(fd), os.stat(path, follow_symlinks=False))
    except OSError:
        same = False
    if not same:
        os.close(fd)
        return None
    return fd


def _release(fd: int, path: Path) -> None:
    """Remove the lock file (while still holding it, so no run can be using it) and let go."""
    with contextlib.suppress(OSError):  # Windows cannot remove an open file: it stays
        os.unlink(path)
    with contextlib.suppress(OSError):
        os.close(fd)
