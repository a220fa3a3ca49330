"""Evaluation: MapTR chamfer AP for vectorised maps, and image metrics (PSNR, SSIM).

The protocol's defaults live here so that the CLI can show them without importing numba.
"""

MAP_CLASSES = ("divider", "ped_crossing", "boundary", "centerline")
MAP_THRESHOLDS_M = (0.5, 1.0, 1.5)
