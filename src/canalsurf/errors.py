"""Exceptions raised by canalsurf.

Two kinds of failure are kept apart because a user must react to them differently:

* :class:`InputError` -- the input itself is unusable (unreadable file, NaN, too few points,
  an impossible parameter).  Fix the input and run again.  The command line exits with code 2.
* :class:`ReconstructionError` -- the input is valid but the method cannot produce a model that
  can be trusted (not a tube, shrinking never stopped, ...).  The command line exits with code 1.
"""

__all__ = ["CanalsurfError", "InputError", "ReconstructionError"]


class CanalsurfError(Exception):
    """Base class of every error canalsurf raises on purpose."""


class InputError(CanalsurfError, ValueError):
    """The input (points, file or parameter) is invalid; the message says what to change."""


class ReconstructionError(CanalsurfError):
    """The input is valid but no trustworthy pipe/canal model could be reconstructed."""
