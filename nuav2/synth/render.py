"""Ground-truth camera images of the synthetic world, for any pinhole camera at any pose.

Independent of the splatting code on purpose: it is the yardstick reconstructions are
measured against. Per pixel: the ray meets the ground (the terrain surface, textured by the
BEV texture mip-filtered by the pixel's ground footprint), the nearest solid, or the sky.
Solids are z-buffered exact ray tests, pre-culled to their projected screen rectangles; where
a painter's algorithm sorts whole boxes (and can misorder a long building against a car),
this resolves every pixel to its nearest surface. A solid crossing the near plane is tested on
every pixel and a ray counts only hits beyond ``NEAR_Z``, so near-plane clipping is exact.
Pixels under the camera's ego-mask polygons show the ego body, as on the real AV2 rig.
Light (light.py): Lambert shading by the sun and, with the ``shadows`` factor, cast shadows on
ground and solids and a sky with sun glow and clouds. The render is the clean world: unit
exposure, neutral white balance, no vignetting, noise or JPEG (camera_effects.py adds those to
the log's own images only).

Depth is the camera z-depth in metres (float32): inf for sky, 0 under the ego mask. Labels
(uint8, ``LABEL_*``) say what each pixel shows, so image quality can be scored per region.
"""

from __future__ import annotations

from functools import lru_cache

import numba
import numpy as np

from nuav2.geometry import F64, T_inverse
from nuav2.rig import CameraSpec
from nuav2.synth.boxes import FACE_QUADRIC, BoxSet, intersect_rays
from nuav2.synth.light import AMBIENT, DIRECT, LEGACY_SUN, in_shadow, shadow_grid, sky_color
from nuav2.synth.materials import material_color
from nuav2.synth.terrain import ray_terrain, surface
from nuav2.synth.texture import sample_texture_point
from nuav2.synth.world import SyntheticWorld

NEAR_Z = 0.05
# Region labels of render_view(with_labels=True): what a pixel shows.
LABEL_SKY, LABEL_GROUND, LABEL_OBJECT, LABEL_STATIC, LABEL_EGO = 0, 1, 2, 3, 4
REGION_LABELS = {"sky": LABEL_SKY, "ground": LABEL_GROUND, "objects": LABEL_OBJECT, "static": LABEL_STATIC,
                 "ego": LABEL_EGO}
SUN_DIR = LEGACY_SUN  # the sun of worlds without the shadows factor
EGO_BODY = np.array([52.0, 56.0, 64.0])
SHADOW_EPS_M = 0.01
# The 12 edges of a box as corner-index pairs (BoxSet.corners order: x-major sign bits).
_EDGES = np.array([(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1])


@lru_cache(maxsize=64)
def _pixel_rays(fx: float, fy: float, cx: float, cy: float, width: int, height: int) -> F64:
    """(H*W, 3) camera-frame rays through pixel centres (OpenCV: pixel (u, v) is centred at (u, v)), z = 1."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], -1).reshape(-1, 3)
    rays.setflags(write=False)
    return rays


def _screen_rects(cam_T_local: F64, K: F64, width: int, height: int, boxes: BoxSet) -> tuple[np.ndarray, F64]:
    """(N, 4) pixel rectangles (r0, r1, c0, c1; empty when r1 < r0) bounding each box's part in
    front of the near plane, and a lower bound of the z-depth of any of its pixels.

    The visible part of a box is the convex hull of its corners in front of the near plane and
    of its edges' crossings of that plane, so projecting those points bounds it exactly."""
    corners = boxes.corners() @ cam_T_local[:3, :3].T + cam_T_local[:3, 3]  # (N, 8, 3)
    z = corners[..., 2]
    a, b = corners[:, _EDGES[:, 0]], corners[:, _EDGES[:, 1]]  # (N, 12, 3)
    za, zb = a[..., 2], b[..., 2]
    crosses = (za > NEAR_Z) != (zb > NEAR_Z)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(crosses, (NEAR_Z - za) / np.where(crosses, zb - za, 1.0), 0.0)
    cut = a + f[..., None] * (b - a)  # (N, 12, 3), on the near plane where ``crosses``
    pts = np.concatenate([corners, cut], axis=1)  # (N, 20, 3)
    use = np.concatenate([z > NEAR_Z, crosses], axis=1)
    pz = np.where(use, pts[..., 2], 1.0)
    u = np.where(use, (K[0, 0] * pts[..., 0] + K[0, 1] * pts[..., 1]) / pz + K[0, 2], np.nan)
    v = np.where(use, K[1, 1] * pts[..., 1] / pz + K[1, 2], np.nan)
    rects = np.zeros((len(boxes), 4), np.int64)
    rects[:, 1] = -1  # empty by default
    vis = use.any(axis=1)
    if np.any(vis):
        uv_, vv_ = u[vis], v[vis]
        c0 = np.maximum(0, np.floor(np.nanmin(uv_, 1)) - 1)
        c1 = np.minimum(width - 1, np.ceil(np.nanmax(uv_, 1)) + 1)
        r0 = np.maximum(0, np.floor(np.nanmin(vv_, 1)) - 1)
        r1 = np.minimum(height - 1, np.ceil(np.nanmax(vv_, 1)) + 1)
        ok = (c0 <= c1) & (r0 <= r1)
        rects[vis] = np.where(ok[:, None], np.column_stack([r0, r1, c0, c1]), [0, -1, 0, -1])
    z_low = np.where(vis, np.maximum(z.min(axis=1), NEAR_Z), np.inf)
    return rects, z_low


@numba.njit(cache=True, parallel=True)
def _shade_kernel(origin, dirs, hit_t, hit_box, hit_face, centers, rots, halves, quads, colors, kinds, params,
                  owners, tex_data, tex_box, tex_levels, tex_meta, focal, tmeta, tH, tSD, sky, gmeta, gstart,
                  gitems, rgb, depth, labels, owner_px):
    """Per pixel: the nearest of solid hit / ground hit / sky, its colour, its z-depth and the actor it shows
    (``owner_px``: the actor index, -1 for static solids, ground and sky)."""
    sun = sky[:3]
    shadows = sky[3] > 0.5
    flat = tmeta[12] > 0.5
    for j in numba.prange(dirs.shape[0]):
        dx, dy, dz = dirs[j, 0], dirs[j, 1], dirs[j, 2]
        t_box = hit_t[j]
        t_ground = ray_terrain(tmeta, tH, tSD, origin[0], origin[1], origin[2], dx, dy, dz, NEAR_Z, t_box)
        if t_box < t_ground:
            i, face = hit_box[j], hit_face[j]
            R = rots[i]
            px = origin[0] + t_box * dx - centers[i, 0]
            py = origin[1] + t_box * dy - centers[i, 1]
            pz = origin[2] + t_box * dz - centers[i, 2]
            bx = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
            by = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
            bz = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
            if face == FACE_QUADRIC:
                nbx, nby, nbz = quads[i, 0] * bx, quads[i, 1] * by, quads[i, 2] * bz
                nn = np.sqrt(nbx * nbx + nby * nby + nbz * nbz)
                nbx, nby, nbz = nbx / nn, nby / nn, nbz / nn
                axis = 0 if abs(nbx) >= max(abs(nby), abs(nbz)) else (1 if abs(nby) >= abs(nbz) else 2)
                n_dot_sun = (nbx * (R[0, 0] * sun[0] + R[1, 0] * sun[1] + R[2, 0] * sun[2])
                             + nby * (R[0, 1] * sun[0] + R[1, 1] * sun[1] + R[2, 1] * sun[2])
                             + nbz * (R[0, 2] * sun[0] + R[1, 2] * sun[1] + R[2, 2] * sun[2]))
            else:
                axis = face // 2
                sign = 1.0 if face % 2 == 1 else -1.0
                nbx = sign if axis == 0 else 0.0
                nby = sign if axis == 1 else 0.0
                nbz = sign if axis == 2 else 0.0
                n_dot_sun = sign * (R[0, axis] * sun[0] + R[1, axis] * sun[1] + R[2, axis] * sun[2])
            u = by if axis == 0 else bx
            half_u = halves[i, 1] if axis == 0 else halves[i, 0]
            wx, wy, wz = origin[0] + t_box * dx, origin[1] + t_box * dy, origin[2] + t_box * dz
            r, g, b, emissive = material_color(kinds[i], colors[i], params[i], axis, u, half_u,
                                               bz + halves[i, 2], 2 * halves[i, 2], bx, by, bz, halves[i],
                                               nbz, wx, wy, wz)
            lit = 1.0
            if shadows and n_dot_sun > 0.0:
                nx = R[0, 0] * nbx + R[0, 1] * nby + R[0, 2] * nbz
                ny = R[1, 0] * nbx + R[1, 1] * nby + R[1, 2] * nbz
                nz = R[2, 0] * nbx + R[2, 1] * nby + R[2, 2] * nbz
                if in_shadow(gmeta, gstart, gitems, centers, rots, halves, quads, sun, wx + SHADOW_EPS_M * nx,
                             wy + SHADOW_EPS_M * ny, wz + SHADOW_EPS_M * nz):
                    lit = 0.0
            shade = 1.0 if emissive else AMBIENT + DIRECT * max(n_dot_sun, 0.0) * lit
            rgb[j, 0], rgb[j, 1], rgb[j, 2] = r * shade, g * shade, b * shade
            depth[j] = t_box
            labels[j] = LABEL_OBJECT if owners[i] >= 0 else LABEL_STATIC
            owner_px[j] = owners[i]
        elif t_ground < np.inf:
            norm = np.sqrt(dx * dx + dy * dy + dz * dz)
            gx_, gy_ = origin[0] + t_ground * dx, origin[1] + t_ground * dy
            if flat:
                footprint = t_ground / focal / np.sqrt(max(abs(dz) / norm, 1e-6))
                nx, ny, nz = 0.0, 0.0, 1.0
            else:
                _, sgx, sgy, _ = surface(tmeta, tH, tSD, gx_, gy_)
                nn = np.sqrt(sgx * sgx + sgy * sgy + 1.0)
                nx, ny, nz = -sgx / nn, -sgy / nn, 1.0 / nn
                footprint = t_ground / focal / np.sqrt(max(abs(dx * nx + dy * ny + dz * nz) / norm, 1e-6))
            sample_texture_point(tex_data, tex_box, tex_levels, tex_meta, gx_, gy_, footprint, rgb, j)
            if shadows:
                n_dot_sun = nx * sun[0] + ny * sun[1] + nz * sun[2]
                lit = 1.0
                if n_dot_sun > 0.0 and in_shadow(gmeta, gstart, gitems, centers, rots, halves, quads, sun,
                                                 gx_ + SHADOW_EPS_M * nx, gy_ + SHADOW_EPS_M * ny,
                                                 origin[2] + t_ground * dz + SHADOW_EPS_M * nz):
                    lit = 0.0
                k = (AMBIENT + DIRECT * max(n_dot_sun, 0.0) * lit) / (AMBIENT + DIRECT * sun[2])
                for c in range(3):
                    rgb[j, c] *= k
            depth[j] = t_ground
            labels[j] = LABEL_GROUND
            owner_px[j] = -1
        else:
            sky_color(sky, dx, dy, dz, rgb, j)
            depth[j] = np.inf
            labels[j] = LABEL_SKY
            owner_px[j] = -1


def render_view(world: SyntheticWorld, cam: CameraSpec, city_T_cam: F64, timestamp_ns: int, *,
                with_depth: bool = False, with_labels: bool = False, with_owners: bool = False):
    """RGB uint8 (H, W, 3) of ``world`` seen by ``cam`` at ``city_T_cam`` (actors at ``timestamp_ns``);
    with ``with_depth`` also the float32 (H, W) camera z-depth (inf: sky, 0: ego body), with
    ``with_labels`` also the uint8 (H, W) region labels (``LABEL_*``), with ``with_owners`` also the int32
    (H, W) actor index per pixel (``world.actors``; -1: not an actor). Returns the image alone, or a tuple
    of it and the asked-for arrays in that order (``(img, depth)``, ``(img, labels)``, ...)."""
    city_T_cam = np.asarray(city_T_cam, np.float64)
    if city_T_cam.shape != (4, 4) or not np.all(np.isfinite(city_T_cam)):
        raise ValueError(f"city_T_cam must be a finite 4x4 matrix, got shape {city_T_cam.shape}")
    w, h, K = cam.width, cam.height, cam.K
    local_T_cam = world.local_T_city @ city_T_cam
    cam_T_local = T_inverse(local_T_cam)
    origin = np.ascontiguousarray(local_T_cam[:3, 3])
    rays_cam = _pixel_rays(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), w, h)
    dirs = rays_cam @ local_T_cam[:3, :3].T

    boxes = world.boxes_at(int(timestamp_ns))
    rects, z_near = _screen_rects(cam_T_local, K, w, h, boxes)
    hits = intersect_rays(origin, dirs, boxes, t_min=NEAR_Z, rects=rects, image_width=w, t_lower=z_near)
    rgb = np.empty((w * h, 3), np.float32)
    depth = np.empty(w * h, np.float32)
    labels = np.empty(w * h, np.uint8)
    owner_px = np.empty(w * h, np.int32)
    sky = world.sky
    grid = shadow_grid(boxes, sky.sun) if sky.structured else shadow_grid(BoxSet.empty(), sky.sun)
    _shade_kernel(origin, dirs, hits.t, hits.box, hits.face, np.ascontiguousarray(boxes.center),
                  np.ascontiguousarray(boxes.rotations), np.ascontiguousarray(boxes.size / 2),
                  np.ascontiguousarray(boxes.quad, np.float64), np.ascontiguousarray(boxes.color, np.float64),
                  np.ascontiguousarray(boxes.kind, np.int64), np.ascontiguousarray(boxes.params, np.float64),
                  np.ascontiguousarray(boxes.owner, np.int64), *world.texture.packed.arrays(),
                  float(np.sqrt(K[0, 0] * K[1, 1])), *world.terrain.arrays(), sky.packed(), *grid.arrays(),
                  rgb, depth, labels, owner_px)
    img = np.clip(rgb + 0.5, 0, 255).astype(np.uint8).reshape(h, w, 3)
    depth, labels, owner_px = depth.reshape(h, w), labels.reshape(h, w), owner_px.reshape(h, w)
    if cam.ego_mask_polygons:
        mask = cam.ego_mask()
        rows = np.arange(h, dtype=np.float64)[:, None] / max(h - 1, 1)
        body = EGO_BODY[None, None, :] * (0.8 + 0.4 * rows[..., None])
        img[mask] = np.broadcast_to(body, (h, w, 3))[mask].astype(np.uint8)
        depth[mask] = 0.0
        labels[mask] = LABEL_EGO
        owner_px[mask] = -1
    out = ((img,) + ((depth,) if with_depth else ()) + ((labels,) if with_labels else ())
           + ((owner_px,) if with_owners else ()))
    return out if len(out) > 1 else img
