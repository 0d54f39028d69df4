"""The ``canalsurf`` console script and ``python -m canalsurf``.

Before anything slow is imported, Ctrl-C and SIGTERM are taken over (:mod:`canalsurf._interrupt`)
and third-party caches are sent to a temporary folder; then :func:`canalsurf.cli.main` runs.  So an
interrupt at any moment -- even while NumPy and SciPy are still loading -- ends in one line and exit
code 130 (SIGINT) or 143 (SIGTERM), never a traceback or a crash.
"""

import signal
import sys

from . import _interrupt


def main() -> int:
    """Run the command line with ``sys.argv``; return its exit code."""
    _interrupt.install()
    try:
        with _interrupt.private_caches():
            from .cli import main as run

            return run()
    except KeyboardInterrupt:  # raised by someone else's code; the handlers never raise it
        _interrupt.exit_interrupted(signal.SIGINT)
    finally:
        _interrupt.finish()


if __name__ == "__main__":
    sys.exit(main())
