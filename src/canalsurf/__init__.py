"""canalsurf: pipe and canal surfaces from unorganized point clouds.

Pipeline stages, in order (one module each):

1. :mod:`canalsurf.normals` -- regression-plane normals, oriented outward;
2. :mod:`canalsurf.shrink` -- shrinking, Algorithm 1 (pipe) / Algorithm 2 (canal);
3. :mod:`canalsurf.thin` -- moving least-squares thinning;
4. :mod:`canalsurf.order`, :mod:`canalsurf.spine` -- ordering and the B-spline spine;
5. :mod:`canalsurf.radius`, :mod:`canalsurf.refine` -- radius (Eq. 6 / r(t)) and the fit with all points;
6. :mod:`canalsurf.surface` -- the pipe / canal-envelope mesh.

:func:`reconstruct` runs them all; :mod:`canalsurf.synth` makes the paper's test surfaces.
"""

from .errors import CanalsurfError, InputError, ReconstructionError
from .model import CanalModel, load_model
from .pipeline import reconstruct
from .surface import surface_mesh
from .synth import SURFACES, make_tube

__version__ = "0.1.0"

__all__ = ["reconstruct", "CanalModel", "load_model", "surface_mesh", "make_tube", "SURFACES",
           "CanalsurfError", "InputError", "ReconstructionError", "__version__"]
