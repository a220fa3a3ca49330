"""2-D polyline helpers for road centre lines, lane boundaries and paths (arc-length based).

:func:`smooth` is what moves along a path: a polyline's direction is piecewise constant, so a vehicle
following its vertices would yaw in steps; the polyline averaged by a triangle kernel in arc length is
twice continuously differentiable (continuous heading and curvature) and unchanged where it is straight.
"""

from __future__ import annotations

import numpy as np

from nuav2.geometry import F64


def arclength(xy: F64) -> F64:
    """(N,) cumulative length along ``xy`` (N, 2)."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])


def at(xy: F64, s: F64) -> F64:
    """Points at arc lengths ``s`` (clamped to the ends)."""
    c = arclength(xy)
    s = np.clip(np.asarray(s, np.float64), 0.0, c[-1])
    return np.stack([np.interp(s, c, xy[:, 0]), np.interp(s, c, xy[:, 1])], axis=-1)


def tangents(xy: F64) -> F64:
    """(N, 2) unit tangents (central differences; one-sided at the ends)."""
    d = np.gradient(xy, axis=0)
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def heading_at(xy: F64, s: F64) -> F64:
    """Heading (rad) at arc lengths ``s``, interpolated between vertex tangents (continuous)."""
    c = arclength(xy)
    t = tangents(xy)
    ang = np.unwrap(np.arctan2(t[:, 1], t[:, 0]))
    return np.interp(np.clip(s, 0.0, c[-1]), c, ang)


def offset(xy: F64, d: float) -> F64:
    """The polyline moved ``d`` metres to its left (negative: right), along vertex normals."""
    t = tangents(xy)
    return xy + d * np.column_stack([-t[:, 1], t[:, 0]])


def sub(xy: F64, s0: float, s1: float) -> F64:
    """The piece between arc lengths s0 < s1 (interpolated end points)."""
    c = arclength(xy)
    inner = (c > s0 + 1e-9) & (c < s1 - 1e-9)
    return np.vstack([at(xy, s0)[None], xy[inner], at(xy, s1)[None]])


def resample(xy: F64, n: int) -> F64:
    """``n`` points evenly spaced in arc length."""
    c = arclength(xy)
    return at(xy, np.linspace(0.0, c[-1], n))


def concat(parts: list[F64]) -> F64:
    """Join polylines end to start, dropping repeated joint points."""
    out = [parts[0]]
    for p in parts[1:]:
        out.append(p[1:] if np.linalg.norm(p[0] - out[-1][-1]) < 1e-6 else p)
    return np.vstack(out)


def bezier(p0: F64, d0: F64, p1: F64, d1: F64, k: float, step: float = 1.0) -> F64:
    """Cubic from p0 (leaving along unit d0) to p1 (arriving along unit d1), control arms ``k`` long."""
    c0, c1 = p0 + k * d0, p1 - k * d1
    n = max(3, int(np.ceil(np.linalg.norm(p1 - p0) * 1.3 / step)) + 1)
    u = np.linspace(0.0, 1.0, n)[:, None]
    return ((1 - u) ** 3) * p0 + 3 * ((1 - u) ** 2) * u * c0 + 3 * (1 - u) * u * u * c1 + u**3 * p1


def from_curvature(segments: list[tuple[float, float]], step: float = 0.5) -> F64:
    """Centre line from (length, curvature) segments, starting at the origin heading +x."""
    kappa = np.concatenate([np.full(max(1, int(round(L / step))), k) for L, k in segments])
    theta = np.concatenate([[0.0], np.cumsum(kappa * step)])
    mid = 0.5 * (theta[1:] + theta[:-1])
    xy = np.concatenate([[[0.0, 0.0]], np.cumsum(np.column_stack([np.cos(mid), np.sin(mid)]) * step, axis=0)])
    return xy


def smooth(xy: F64, s: F64, half_width: float) -> tuple[F64, F64, F64]:
    """``xy`` averaged by a triangle kernel of ``half_width`` in arc length, at arc lengths ``s``
    (clamped to the ends; beyond them the polyline continues straight): (M, 2) points and their first
    and second derivatives in ``s``. The result is C2 (its heading and curvature are continuous), stays
    exactly on the polyline wherever it is straight for ``half_width`` either side, and cuts a corner
    by about ``half_width**2 / 12`` times the curvature."""
    c = arclength(xy)
    s = np.clip(np.asarray(s, np.float64).reshape(-1), 0.0, c[-1])
    keep = np.concatenate([[True], np.diff(c) > 1e-9])
    xy, c = np.asarray(xy, np.float64)[keep], c[keep]
    if len(xy) < 2:
        return np.repeat(xy[:1], len(s), axis=0), np.tile([1.0, 0.0], (len(s), 1)), np.zeros((len(s), 2))
    w = float(half_width)
    q = xy - xy[0]  # small numbers: the integrals below are differenced
    u0 = (q[1] - q[0]) / (c[1] - c[0])
    u1 = (q[-1] - q[-2]) / (c[-1] - c[-2])
    ext = 2.0 * w + 1.0
    Q = np.vstack([q[0] - ext * u0, q, q[-1] + ext * u1])
    C = np.concatenate([[c[0] - ext], c, [c[-1] + ext]])
    L = np.diff(C)[:, None]
    D = np.diff(Q, axis=0) / L
    F = np.zeros_like(Q)  # integral of the polyline from C[0], at the vertices
    F[1:] = np.cumsum(0.5 * (Q[1:] + Q[:-1]) * L, axis=0)
    G = np.zeros_like(Q)  # integral of F
    G[1:] = np.cumsum(F[:-1] * L + Q[:-1] * L**2 / 2 + D * L**3 / 6, axis=0)
    x = np.concatenate([s - w, s, s + w])
    i = np.clip(np.searchsorted(C, x, side="right") - 1, 0, len(C) - 2)
    h = (x - C[i])[:, None]
    P_x = Q[i] + D[i] * h
    F_x = F[i] + Q[i] * h + D[i] * h**2 / 2
    G_x = G[i] + F[i] * h + Q[i] * h**2 / 2 + D[i] * h**3 / 6

    def second_difference(v: F64) -> F64:
        a, b, d = np.split(v, 3)
        return (a - 2.0 * b + d) / (w * w)

    return xy[0] + second_difference(G_x), second_difference(F_x), second_difference(P_x)
