"""penumbra: environment lighting with soft shadows for fully dynamic scenes.

The heavy lifting is done by libpenumbra (OpenCL kernels behind a C API);
this package binds it (:mod:`penumbra.core`), reads and writes files
(:mod:`penumbra.imageio`, :mod:`penumbra.meshio`), makes procedural content
(:mod:`penumbra.procedural`), loads scene files (:mod:`penumbra.scenefile`) and
renders them (:mod:`penumbra.render`, the ``penumbra`` command).
"""

from ._native import BACKGROUND, version
from .core import Camera, Context, EnvMap, GBuffer, Image, Material, Mesh, Renderer, Scene
from .errors import InputError, PenumbraError
from .methods.fiv import FivField, FivOptions

__version__ = version()

__all__ = ["BACKGROUND", "Camera", "Context", "EnvMap", "FivField", "FivOptions", "GBuffer", "Image", "InputError", "Material", "Mesh",
           "PenumbraError", "Renderer", "Scene", "__version__"]
