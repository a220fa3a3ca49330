"""Rasterizer constants shared by the numba kernels, the dense reference and the gsplat backend.

They follow gsplat v1.5.3 (see shared/reference/splatting_notes.md section 3) so that the CPU
kernels, the plain-torch reference and gsplat agree on which Gaussian touches which pixel.
"""

from __future__ import annotations

TILE = 16                      # tile side in pixels
EPS2D = 0.3                    # low-pass filter added to the 2D covariance diagonal (pixels^2)
FOV_CLAMP = 0.3                # Jacobian clamp: |x/z| <= edge + 0.3 * tan_fov, i.e. a 1.3x FoV
ALPHA_MIN = 1.0 / 255.0        # alpha below this is skipped; opacity below it culls the Gaussian
ALPHA_MAX = 0.999              # alpha clamp, the same forward and backward
T_STOP = 1e-4                  # a pixel stops once T * (1 - alpha) <= T_STOP (that Gaussian excluded)
EXTEND_MAX = 3.33              # radius factor cap k = min(3.33, sqrt(2 ln(255 o)))
ALPHA_FLOOR_DEPTH = 1e-10      # expected depth = D / max(alpha, 1e-10)
QUAT_EPS = 1e-12               # quaternions are divided by max(|q|, QUAT_EPS): a zero one gives identity
LOG_SCALE_MIN = -30.0          # log-scales are clamped to this range before exp (no overflow)
LOG_SCALE_MAX = 30.0
# Pixel-Gaussian pairs whose exponent exceeds ln(255 o) by this much are rejected before exp():
# such pairs have alpha < 1/255 in any precision, so the early reject never changes a result.
SIGMA_REJECT_MARGIN = 1e-2
