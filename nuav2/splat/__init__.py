"""Gaussian splatting: the differentiable rasterizer (CPU numba kernels, gsplat on CUDA).

OpenMP threads that spin between parallel regions (libgomp's default) make the CPU kernels
3-4x slower whenever the cores are shared (measured in docs/rasterizer.md), so unless the
user chose otherwise the wait policy defaults to PASSIVE. libgomp reads it once, when first
loaded (by torch or numba), so this only takes effect if nuav2 is imported before torch.
"""

import os
import sys

if "OMP_WAIT_POLICY" in os.environ:
    OMP_WAIT_POLICY = f"{os.environ['OMP_WAIT_POLICY']} (set by the user)"
elif "torch" in sys.modules:
    OMP_WAIT_POLICY = "libgomp default (torch was imported before nuav2.splat; too late to change)"
else:
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    OMP_WAIT_POLICY = "PASSIVE (set by nuav2.splat before torch loaded libgomp)"

from nuav2.splat.rasterize import BACKENDS, RasterOutput, rasterize  # noqa: E402

__all__ = ["BACKENDS", "RasterOutput", "rasterize"]
