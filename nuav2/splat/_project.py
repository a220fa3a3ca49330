"""Numba EWA projection of 3D Gaussians into pinhole cameras, forward and exact backward.

Always float64 inside (city-scale coordinates and huge or tiny scales stay finite) whatever
the array dtype: every input is widened when read and outputs are rounded once when stored,
so float32 callers get the float64 result without conversion copies. Scalar code only (no
small temporary arrays), one prange over Gaussians with the cameras looped inside, so the backward accumulates
per-Gaussian gradients without races. The 2D covariance is built from its factor
A = J W R diag(s) (cov2d = A A^T + 0.3 I), so the backward never forms 3D covariances.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from nuav2.splat.constants import (
    ALPHA_MIN,
    EPS2D,
    EXTEND_MAX,
    FOV_CLAMP,
    LOG_SCALE_MAX,
    LOG_SCALE_MIN,
    QUAT_EPS,
)

# Gaussians whose projected centre lies further than this from the image (pixels) are culled:
# float32 pixel offsets beyond it would square past the float32 range in the compositor.
MEAN2D_LIMIT = 1e6
RADIUS_MAX = 2.0**31 - 1          # int32 pixel radii are clamped here (huge off-screen splats only)


@njit(cache=True)
def _rotation_scales(quats, log_scales, g):
    """Unit quaternion q/max(|q|,eps) (a zero one gives the identity), |q|, its rotation rows,
    and the clamped scales."""
    f64 = np.float64
    qw, qx, qy, qz = f64(quats[g, 0]), f64(quats[g, 1]), f64(quats[g, 2]), f64(quats[g, 3])
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    d = max(n, QUAT_EPS)
    w, x, y, z = qw / d, qx / d, qy / d, qz / d
    r = (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
         2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
         2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))
    s = (math.exp(min(max(f64(log_scales[g, 0]), LOG_SCALE_MIN), LOG_SCALE_MAX)),
         math.exp(min(max(f64(log_scales[g, 1]), LOG_SCALE_MIN), LOG_SCALE_MAX)),
         math.exp(min(max(f64(log_scales[g, 2]), LOG_SCALE_MIN), LOG_SCALE_MAX)))
    return (w, x, y, z), n, d, r, s


@njit(cache=True)
def _cam_factor(W, r, s):
    """B = W R diag(s) (rows), the camera-frame factor with covariance B B^T."""
    m = (r[0] * s[0], r[1] * s[1], r[2] * s[2], r[3] * s[0], r[4] * s[1], r[5] * s[2],
         r[6] * s[0], r[7] * s[1], r[8] * s[2])
    return (W[0] * m[0] + W[1] * m[3] + W[2] * m[6], W[0] * m[1] + W[1] * m[4] + W[2] * m[7],
            W[0] * m[2] + W[1] * m[5] + W[2] * m[8], W[3] * m[0] + W[4] * m[3] + W[5] * m[6],
            W[3] * m[1] + W[4] * m[4] + W[5] * m[7], W[3] * m[2] + W[4] * m[5] + W[5] * m[8],
            W[6] * m[0] + W[7] * m[3] + W[8] * m[6], W[6] * m[1] + W[7] * m[4] + W[8] * m[7],
            W[6] * m[2] + W[7] * m[5] + W[8] * m[8])


@njit(cache=True)
def _screen_factor(B, j00, j02, j11, j12):
    """A = J B (2x3 rows) for J = [[j00, 0, j02], [0, j11, j12]]."""
    return ((j00 * B[0] + j02 * B[6], j00 * B[1] + j02 * B[7], j00 * B[2] + j02 * B[8]),
            (j11 * B[3] + j12 * B[6], j11 * B[4] + j12 * B[7], j11 * B[5] + j12 * B[8]))


@njit(cache=True)
def _cov2d(A0, A1):
    """cov2d = A A^T + 0.3 I as (a, b, c) and its determinant.

    The determinant comes from Cauchy-Binet (sum of squared 2x2 minors of A, plus the blur
    terms) instead of a*c - b*b, which cancels catastrophically for needle-like splats whose
    long axis is 1e10 times the short one; this form stays accurate for any anisotropy.
    """
    a0 = A0[0] * A0[0] + A0[1] * A0[1] + A0[2] * A0[2]
    c0 = A1[0] * A1[0] + A1[1] * A1[1] + A1[2] * A1[2]
    b = A0[0] * A1[0] + A0[1] * A1[1] + A0[2] * A1[2]
    m01 = A0[0] * A1[1] - A0[1] * A1[0]
    m02 = A0[0] * A1[2] - A0[2] * A1[0]
    m12 = A0[1] * A1[2] - A0[2] * A1[1]
    det = m01 * m01 + m02 * m02 + m12 * m12 + EPS2D * (a0 + c0) + EPS2D * EPS2D
    return a0 + EPS2D, b, c0 + EPS2D, det, (m01, m02, m12)


@njit(cache=True)
def _conic_backward(ga, gb, gc, a, b, c, det, m01, m02, m12, A0, A1):
    """dL/dA given dL/d(conic) for conic = (c, -b, a) / det, det from Cauchy-Binet.

    Differentiates that explicit formula rather than using d(S^-1) = -S^-1 dS S^-1: the
    identity is exact but loses everything to rounding for needle-like splats (their long
    axis's tiny inverse eigenvalue times a huge factor), while this form stays accurate.
    """
    inv_det = 1.0 / det
    g_a = gc * inv_det
    g_c = ga * inv_det
    g_b = -gb * inv_det
    g_det = -(ga * c - gb * b + gc * a) * inv_det * inv_det
    k0 = 2.0 * (g_a + EPS2D * g_det)
    k1 = 2.0 * (g_c + EPS2D * g_det)
    t = 2.0 * g_det
    gA0 = (k0 * A0[0] + g_b * A1[0] + t * (m01 * A1[1] + m02 * A1[2]),
           k0 * A0[1] + g_b * A1[1] + t * (-m01 * A1[0] + m12 * A1[2]),
           k0 * A0[2] + g_b * A1[2] + t * (-m02 * A1[0] - m12 * A1[1]))
    gA1 = (k1 * A1[0] + g_b * A0[0] + t * (-m01 * A0[1] - m02 * A0[2]),
           k1 * A1[1] + g_b * A0[1] + t * (m01 * A0[0] - m12 * A0[2]),
           k1 * A1[2] + g_b * A0[2] + t * (m02 * A0[0] + m12 * A0[1]))
    return gA0, gA1


@njit(cache=True)
def _camera(cam_T_world, Ks, c):
    V = cam_T_world[c]
    W = (V[0, 0], V[0, 1], V[0, 2], V[1, 0], V[1, 1], V[1, 2], V[2, 0], V[2, 1], V[2, 2])
    return V, W, Ks[c, 0, 0], Ks[c, 1, 1], Ks[c, 0, 2], Ks[c, 1, 2]


@njit(cache=True)
def _to_camera(V, means, g):
    mx, my, mz = np.float64(means[g, 0]), np.float64(means[g, 1]), np.float64(means[g, 2])
    return (V[0, 0] * mx + V[0, 1] * my + V[0, 2] * mz + V[0, 3],
            V[1, 0] * mx + V[1, 1] * my + V[1, 2] * mz + V[1, 3],
            V[2, 0] * mx + V[2, 1] * my + V[2, 2] * mz + V[2, 3])


@njit(cache=True)
def _fov_limits(size, f, centre):
    """gsplat's 1.3x FoV clamp of x/z (or y/z) inside the Jacobian."""
    tan_fov = 0.5 * size / f
    return -(centre / f + FOV_CLAMP * tan_fov), (size - centre) / f + FOV_CLAMP * tan_fov


@njit(parallel=True, cache=True, nogil=True)
def project_forward(means, quats, log_scales, opacities, cam_T_world, Ks, width, height,
                    near, far, radius_clip, means2d, conics, depths, radii):
    """Fill means2d (C,N,2), conics (C,N,3), depths (C,N) and radii (C,N,2); radii 0 = culled."""
    n_cams = cam_T_world.shape[0]
    for g in prange(means.shape[0]):
        _q, _n, _d, r, s = _rotation_scales(quats, log_scales, g)
        o = np.float64(opacities[g])
        for c in range(n_cams):
            radii[c, g, 0] = 0
            radii[c, g, 1] = 0
            V, W, fx, fy, cx, cy = _camera(cam_T_world, Ks, c)
            x, y, z = _to_camera(V, means, g)
            if not (z >= near and z <= far) or not (o >= ALPHA_MIN):
                continue
            rz = 1.0 / z
            lo_x, hi_x = _fov_limits(width, fx, cx)
            lo_y, hi_y = _fov_limits(height, fy, cy)
            tx = z * min(hi_x, max(lo_x, x * rz))
            ty = z * min(hi_y, max(lo_y, y * rz))
            A0, A1 = _screen_factor(_cam_factor(W, r, s), fx * rz, -fx * tx * rz * rz, fy * rz,
                                    -fy * ty * rz * rz)
            a, b, cc, det, _m = _cov2d(A0, A1)
            if not (det > 0.0):
                continue
            u = fx * x * rz + cx
            v = fy * y * rz + cy
            extend = min(EXTEND_MAX, math.sqrt(2.0 * math.log(o / ALPHA_MIN)))
            rx = math.ceil(extend * math.sqrt(a))
            ry = math.ceil(extend * math.sqrt(cc))
            if rx <= radius_clip and ry <= radius_clip:
                continue
            if u + rx <= 0.0 or u - rx >= width or v + ry <= 0.0 or v - ry >= height:
                continue
            if not (abs(u) <= MEAN2D_LIMIT and abs(v) <= MEAN2D_LIMIT):
                continue
            ia, ib, ic = cc / det, -b / det, a / det
            if not (math.isfinite(ia) and math.isfinite(ib) and math.isfinite(ic)
                    and math.isfinite(rx) and math.isfinite(ry)):
                continue
            means2d[c, g, 0] = u
            means2d[c, g, 1] = v
            conics[c, g, 0] = ia
            conics[c, g, 1] = ib
            conics[c, g, 2] = ic
            depths[c, g] = z
            radii[c, g, 0] = int(min(rx, RADIUS_MAX))
            radii[c, g, 1] = int(min(ry, RADIUS_MAX))


@njit(cache=True, inline="always")
def _has_gradient(radii, g_means2d, g_conics, g_depths, c, g):
    """Whether Gaussian g is visible in camera c and receives a nonzero upstream gradient there."""
    if radii[c, g, 0] <= 0 and radii[c, g, 1] <= 0:
        return False
    return not (g_means2d[c, g, 0] == 0.0 and g_means2d[c, g, 1] == 0.0 and g_conics[c, g, 0] == 0.0
                and g_conics[c, g, 1] == 0.0 and g_conics[c, g, 2] == 0.0 and g_depths[c, g] == 0.0)


@njit(parallel=True, cache=True, nogil=True)
def project_backward(means, quats, log_scales, cam_T_world, Ks, width, height, radii,
                     g_means2d, g_conics, g_depths, g_means, g_quats, g_log_scales):
    """Exact vector-Jacobian product of project_forward; sums over cameras per Gaussian."""
    n_cams = cam_T_world.shape[0]
    for g in prange(means.shape[0]):
        seen = False
        for c in range(n_cams):
            seen = seen or _has_gradient(radii, g_means2d, g_conics, g_depths, c, g)
        if not seen:              # culled everywhere, or occluded: the VJP is linear, so exactly zero
            for k in range(3):
                g_means[g, k] = 0.0
                g_log_scales[g, k] = 0.0
            for k in range(4):
                g_quats[g, k] = 0.0
            continue
        q, qn, qd, r, s = _rotation_scales(quats, log_scales, g)
        gM = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)     # dL/d(R diag(s)), row-major
        gm0 = 0.0
        gm1 = 0.0
        gm2 = 0.0
        for c in range(n_cams):
            if not _has_gradient(radii, g_means2d, g_conics, g_depths, c, g):
                continue
            V, W, fx, fy, cx, cy = _camera(cam_T_world, Ks, c)
            x, y, z = _to_camera(V, means, g)
            rz = 1.0 / z
            lo_x, hi_x = _fov_limits(width, fx, cx)
            lo_y, hi_y = _fov_limits(height, fy, cy)
            xz = x * rz
            yz = y * rz
            tx = z * min(hi_x, max(lo_x, xz))
            ty = z * min(hi_y, max(lo_y, yz))
            j00 = fx * rz
            j02 = -fx * tx * rz * rz
            j11 = fy * rz
            j12 = -fy * ty * rz * rz
            B = _cam_factor(W, r, s)
            A0, A1 = _screen_factor(B, j00, j02, j11, j12)
            a, b, cc, det, (m01, m02, m12) = _cov2d(A0, A1)
            gA0, gA1 = _conic_backward(np.float64(g_conics[c, g, 0]), np.float64(g_conics[c, g, 1]),
                                       np.float64(g_conics[c, g, 2]),
                                       a, b, cc, det, m01, m02, m12, A0, A1)
            # A0 = j00 B0 + j02 B2, A1 = j11 B1 + j12 B2 (B rows)
            GJ00 = gA0[0] * B[0] + gA0[1] * B[1] + gA0[2] * B[2]
            GJ02 = gA0[0] * B[6] + gA0[1] * B[7] + gA0[2] * B[8]
            GJ11 = gA1[0] * B[3] + gA1[1] * B[4] + gA1[2] * B[5]
            GJ12 = gA1[0] * B[6] + gA1[1] * B[7] + gA1[2] * B[8]
            gB = (j00 * gA0[0], j00 * gA0[1], j00 * gA0[2], j11 * gA1[0], j11 * gA1[1], j11 * gA1[2],
                  j02 * gA0[0] + j12 * gA1[0], j02 * gA0[1] + j12 * gA1[1], j02 * gA0[2] + j12 * gA1[2])
            # B = W M: dL/dM += W^T dL/dB
            gM = (gM[0] + W[0] * gB[0] + W[3] * gB[3] + W[6] * gB[6],
                  gM[1] + W[0] * gB[1] + W[3] * gB[4] + W[6] * gB[7],
                  gM[2] + W[0] * gB[2] + W[3] * gB[5] + W[6] * gB[8],
                  gM[3] + W[1] * gB[0] + W[4] * gB[3] + W[7] * gB[6],
                  gM[4] + W[1] * gB[1] + W[4] * gB[4] + W[7] * gB[7],
                  gM[5] + W[1] * gB[2] + W[4] * gB[5] + W[7] * gB[8],
                  gM[6] + W[2] * gB[0] + W[5] * gB[3] + W[8] * gB[6],
                  gM[7] + W[2] * gB[1] + W[5] * gB[4] + W[8] * gB[7],
                  gM[8] + W[2] * gB[2] + W[5] * gB[5] + W[8] * gB[8])
            # camera-frame mean gradient: projection, depth, then J's dependence on (x, y, z)
            gu = np.float64(g_means2d[c, g, 0])
            gv = np.float64(g_means2d[c, g, 1])
            rz2 = rz * rz
            gx = gu * fx * rz
            gy = gv * fy * rz
            gz = -(gu * fx * x + gv * fy * y) * rz2 + np.float64(g_depths[c, g])
            gz += -GJ00 * fx * rz2 - GJ11 * fy * rz2
            if xz >= lo_x and xz <= hi_x:
                gx += -GJ02 * fx * rz2
                gz += GJ02 * 2.0 * fx * x * rz2 * rz
            else:
                gz += GJ02 * fx * (tx * rz) * rz2
            if yz >= lo_y and yz <= hi_y:
                gy += -GJ12 * fy * rz2
                gz += GJ12 * 2.0 * fy * y * rz2 * rz
            else:
                gz += GJ12 * fy * (ty * rz) * rz2
            gm0 += W[0] * gx + W[3] * gy + W[6] * gz
            gm1 += W[1] * gx + W[4] * gy + W[7] * gz
            gm2 += W[2] * gx + W[5] * gy + W[8] * gz
        g_means[g, 0] = gm0
        g_means[g, 1] = gm1
        g_means[g, 2] = gm2
        # M = R diag(s): dL/dR_kj = dL/dM_kj s_j, dL/ds_j = sum_k dL/dM_kj R_kj
        gR = (gM[0] * s[0], gM[1] * s[1], gM[2] * s[2], gM[3] * s[0], gM[4] * s[1], gM[5] * s[2],
              gM[6] * s[0], gM[7] * s[1], gM[8] * s[2])
        ds0 = gM[0] * r[0] + gM[3] * r[3] + gM[6] * r[6]
        ds1 = gM[1] * r[1] + gM[4] * r[4] + gM[7] * r[7]
        ds2 = gM[2] * r[2] + gM[5] * r[5] + gM[8] * r[8]
        for j, ds in enumerate((ds0, ds1, ds2)):
            ls = np.float64(log_scales[g, j])
            g_log_scales[g, j] = ds * s[j] if (ls >= LOG_SCALE_MIN and ls <= LOG_SCALE_MAX) else 0.0
        w, x, y, z = q
        gw = 2.0 * (-z * gR[1] + y * gR[2] + z * gR[3] - x * gR[5] - y * gR[6] + x * gR[7])
        gx = 2.0 * (y * gR[1] + z * gR[2] + y * gR[3] - 2.0 * x * gR[4] - w * gR[5] + z * gR[6] + w * gR[7]
                    - 2.0 * x * gR[8])
        gy = 2.0 * (-2.0 * y * gR[0] + x * gR[1] + w * gR[2] + x * gR[3] + z * gR[5] - w * gR[6] + z * gR[7]
                    - 2.0 * y * gR[8])
        gz = 2.0 * (-2.0 * z * gR[0] - w * gR[1] + x * gR[2] + w * gR[3] - 2.0 * z * gR[4] + y * gR[5]
                    + x * gR[6] + y * gR[7])
        # through q / max(|q|, eps): project out the radial part while |q| >= eps
        dot = (gw * w + gx * x + gy * y + gz * z) if qn >= QUAT_EPS else 0.0
        g_quats[g, 0] = (gw - dot * w) / qd
        g_quats[g, 1] = (gx - dot * x) / qd
        g_quats[g, 2] = (gy - dot * y) / qd
        g_quats[g, 3] = (gz - dot * z) / qd


def empty_projection(n_cams: int, n: int, dtype) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Output buffers for project_forward: means2d, conics, depths in the image dtype (zeros where
    culled), int32 radii."""
    return (np.zeros((n_cams, n, 2), dtype), np.zeros((n_cams, n, 3), dtype), np.zeros((n_cams, n), dtype),
            np.zeros((n_cams, n, 2), np.int32))
