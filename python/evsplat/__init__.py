"""evsplat: 4D reconstruction of fast dynamic scenes from a single event camera.

Deformable 3D Gaussian splatting trained on an event stream and known camera poses
(FastEventDGS). The hot loops (event binning, patches, the wgpu rasterizer) live in the
native module ``evsplat._core``; models, losses and the CLI are in Python.
"""

from evsplat.errors import EvsplatError
from evsplat.raster import rasterize

__version__ = "0.1.0"
__all__ = ["EvsplatError", "__version__", "rasterize"]
