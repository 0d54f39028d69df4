"""Ctrl-C and SIGTERM for the ``canalsurf`` command: clean up, one line, exit 130 / 143.

:func:`install` (called first thing by the console script, :mod:`canalsurf.__main__`) replaces
Python's ``KeyboardInterrupt`` by a handler that ends the process at once:

1. the clean-up callbacks registered with :func:`on_interrupt` run, newest first (the writers register
   their staging folder, the folders they created and their lock file);
2. ``canalsurf: error: interrupted — nothing more was written`` goes to stderr;
3. the process ends with ``os._exit(128 + signal)``: 130 for SIGINT, 143 for SIGTERM.

Why not raise ``KeyboardInterrupt`` and let it unwind?  SciPy's KD-tree queries with ``workers=-1``
run in threads that the main thread joins; an interrupt in that join unwinds the main thread while
the workers still search the tree, and the tree -- often a temporary, ``cKDTree(x).query(...)`` --
is freed under them: the process then dies of a segmentation fault (and an interpreter shutting down
under running daemon threads can crash the same way).  Exiting from the handler frees nothing and
tears nothing down, so the workers just stop with the process.

Steps that must not be cut in half -- moving a set of finished files into place -- run inside
:func:`deferred`: a signal arriving there is acted on when the step is complete.

Only light modules are imported here, so the handlers are in place before NumPy and SciPy load.
Nothing changes for a program that calls :func:`canalsurf.cli.main` itself: there the signals keep
Python's behaviour and ``main`` reports a ``KeyboardInterrupt`` itself.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import sys
import tempfile
from collections.abc import Callable, Iterator
from typing import NoReturn

__all__ = ["INTERRUPTED", "install", "finish", "on_interrupt", "deferred", "exit_interrupted", "private_caches"]

#: The one line an interrupted run prints (after ``canalsurf: error:``).
INTERRUPTED = "interrupted — nothing more was written"
#: The signals handled, each ending the process with 128 + its number (the shells' convention).
SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM") if hasattr(signal, name))

#: Where ezdxf keeps its font list under ``XDG_CACHE_HOME``, and an empty one in its format (version
#: 2 of ``ezdxf.fonts.font_manager``; a list of another version is rebuilt by ezdxf, as if absent).
EZDXF_FONT_CACHE = (os.path.join("ezdxf", "font_manager_cache.json"), '{"version": 2, "font-faces": []}')

_callbacks: list[Callable[[], None]] = []
_depth = 0  # nesting of deferred() blocks
_pending: int | None = None  # a signal that arrived inside a deferred() block


def install() -> None:
    """Handle SIGINT and SIGTERM as described above (main thread only; a signal that was ignored
    when the process started, as for a background job, stays ignored)."""
    for signum in SIGNALS:
        if signal.getsignal(signum) is not signal.SIG_IGN:
            signal.signal(signum, _handle)


def finish() -> None:
    """The run is over: ignore the signals from now on.

    Python's shutdown would otherwise put the default handlers back, and a SIGTERM arriving then
    would kill the process (exit -15) after everything was written.
    """
    for signum in SIGNALS:
        with contextlib.suppress(ValueError, OSError):
            signal.signal(signum, signal.SIG_IGN)


def _handle(signum: int, frame) -> None:
    global _pending
    if _depth:
        _pending = signum
        return
    exit_interrupted(signum)


@contextlib.contextmanager
def on_interrupt(callback: Callable[[], None]) -> Iterator[None]:
    """Run ``callback()`` if the process is interrupted inside this block."""
    _callbacks.append(callback)
    try:
        yield
    finally:
        with contextlib.suppress(ValueError):
            _callbacks.remove(callback)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Hold a signal that arrives inside this block until the block is done (blocks may nest)."""
    global _depth
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if not _depth and _pending is not None:
            exit_interrupted(_pending)


def exit_interrupted(signum: int) -> NoReturn:
    """Clean up, print the one line and end the process with ``128 + signum`` (never returns)."""
    finish()  # a second Ctrl-C must not cut the clean-up short
    for callback in reversed(_callbacks):
        try:
            callback()
        except Exception:  # noqa: BLE001 -- clean up as much as possible, then exit all the same
            pass
    with contextlib.suppress(Exception):
        sys.stdout.flush()  # the summaries of inputs that were finished
    # Straight to the file descriptor: the main thread may have been stopped inside a write to
    # sys.stderr, which a second write through the same buffer would refuse (reentrant call).
    line = f"canalsurf: error: {INTERRUPTED}\n"
    with contextlib.suppress(Exception):
        if os.isatty(2):
            line = "\r\x1b[K" + line  # over a progress bar being drawn on the terminal
    with contextlib.suppress(OSError):
        os.write(2, line.encode("utf-8", "replace"))
    os._exit(128 + signum)


@contextlib.contextmanager
def private_caches() -> Iterator[None]:
    """Send third-party caches into a temporary folder for the duration of the block.

    matplotlib (the report's figures) writes ``~/.config/matplotlib`` and ``~/.cache/matplotlib``,
    and ezdxf (spine.dxf) builds ``~/.cache/ezdxf`` when first imported, unless told otherwise; a
    command should not leave files in the user's home.  ``MPLCONFIGDIR`` and ``XDG_CACHE_HOME`` are
    pointed into a temporary folder when they are not set (a value the user set is respected), and
    the folder is removed afterwards.  Must be entered before matplotlib or ezdxf are imported.

    ezdxf would fill its empty cache by reading every font file of the system at import, on every
    run and the longer the more fonts are installed, for text that spine.dxf never holds; the private
    cache starts with an empty font list instead (:data:`EZDXF_FONT_CACHE`).
    matplotlib still rebuilds its font list for each report.
    """
    names = [name for name in ("MPLCONFIGDIR", "XDG_CACHE_HOME") if not os.environ.get(name)]
    if not names:
        yield
        return
    with contextlib.ExitStack() as stack:
        with deferred():  # no interrupt between making the folder and registering its removal
            folder = tempfile.mkdtemp(prefix="canalsurf-cache-")
            stack.callback(shutil.rmtree, folder, ignore_errors=True)
            stack.enter_context(on_interrupt(lambda: shutil.rmtree(folder, ignore_errors=True)))
        for name in names:
            stack.callback(os.environ.pop, name, None)
            os.environ[name] = os.path.join(folder, "matplotlib" if name == "MPLCONFIGDIR" else "cache")
        if "XDG_CACHE_HOME" in names:
            name, text = EZDXF_FONT_CACHE
            path = os.path.join(os.environ["XDG_CACHE_HOME"], name)
            with contextlib.suppress(OSError):  # then ezdxf reads the fonts, as without this
                os.makedirs(os.path.dirname(path))
                with open(path, "w", encoding="utf-8") as file:
                    file.write(text)
        yield
