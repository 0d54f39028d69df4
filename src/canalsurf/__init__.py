"""canalsurf: pipe and canal surfaces from unorganized point clouds.

Pipeline stages, in order (one module each):

1. :mod:`canalsurf.normals` -- regression-plane normals, oriented outward;
2. :mod:`canalsurf.shrink` -- shrinking, Algorithm 1 (pipe) / Algorithm 2 (canal);
3. :mod:`canalsurf.thin` -- moving least-squares thinning;
4. :mod:`canalsurf.skeleton`, :mod:`canalsurf.spine` -- the thin set as branches between junctions, and
   a B-spline spine per branch;
5. :mod:`canalsurf.radius`, :mod:`canalsurf.refine` -- radius (Eq. 6 / r(t)) and the fit of each branch
   to its points;
6. :mod:`canalsurf.network` -- branches and junctions as one result, point labels, the united mesh
   (:mod:`canalsurf.surface` meshes one tube).

:func:`reconstruct` runs them all and returns a :class:`Network` (a single tube is a network of one
branch); :func:`read_points` reads point files; :mod:`canalsurf.synth` makes the paper's test surfaces
and networks of tubes with their ground truth.
"""

import importlib
from typing import TYPE_CHECKING

from .errors import CanalsurfError, InputError, ReconstructionError

if TYPE_CHECKING:
    from .io import read_points
    from .model import CanalModel, load_model
    from .network import Junction, Network, network_mesh
    from .pipeline import reconstruct
    from .surface import surface_mesh
    from .synth import NETWORKS, SURFACES, make_network, make_tube

__version__ = "0.1.0"

#: Public names -> the module defining them, imported on first use (PEP 562, as SciPy and
#: scikit-image do): ``import canalsurf`` stays instant, so the command line can take over Ctrl-C
#: before SciPy loads (:mod:`canalsurf.__main__`).
_LAZY = {"CanalModel": "model", "load_model": "model", "reconstruct": "pipeline", "Network": "network",
         "Junction": "network", "surface_mesh": "surface", "network_mesh": "network", "SURFACES": "synth",
         "make_tube": "synth", "NETWORKS": "synth", "make_network": "synth", "read_points": "io"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value  # once only
        return value
    if not name.startswith("_"):  # a submodule (``canalsurf.io``), as when everything was imported
        try:
            return importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))


__all__ = ["reconstruct", "Network", "Junction", "CanalModel", "load_model", "read_points", "surface_mesh",
           "network_mesh", "make_tube", "SURFACES", "make_network", "NETWORKS", "CanalsurfError", "InputError",
           "ReconstructionError", "__version__"]
