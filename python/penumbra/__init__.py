"""penumbra: environment lighting with soft shadows for fully dynamic scenes.

The heavy lifting is done by libpenumbra (OpenCL kernels behind a C API);
this package binds it (:mod:`penumbra.core`), reads and writes files
(:mod:`penumbra.imageio`, :mod:`penumbra.meshio`), makes procedural content
(:mod:`penumbra.procedural`), finds the test data (:mod:`penumbra.data`),
loads scene files (:mod:`penumbra.scenefile`) and renders them
(:mod:`penumbra.render`, the ``penumbra`` command); the shading methods and
their metadata are in :mod:`penumbra.methods`.

The classes of the library's objects and the errors are exported here, with
the modules a script uses next to them (``penumbra.procedural.sky()``,
``penumbra.imageio.write_png(...)``, ``penumbra.data.path(...)``).
"""

from ._native import BACKGROUND, version
from .core import Camera, Context, EnvMap, GBuffer, Image, Material, Mesh, Renderer, Scene
from .errors import InputError, PenumbraError
from .methods.fiv import FivField, FivOptions
from . import data, imageio, meshio, methods, procedural, scenefile  # noqa: E402  (modules, after the classes they use)

#: The library's version string (pn_version), e.g. "0.1.0".
__version__ = version()

__all__ = ["BACKGROUND", "Camera", "Context", "EnvMap", "FivField", "FivOptions", "GBuffer", "Image", "InputError",
           "Material", "Mesh", "PenumbraError", "Renderer", "Scene", "__version__", "data", "imageio", "meshio",
           "methods", "procedural", "scenefile"]
