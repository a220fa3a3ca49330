"""Which Gaussians one view needs, placed in the scene frame: the rasterizer's input per render.

A 15 s log holds ~100k background Gaussians and dozens of moving objects, while one camera sees a
third of the background and a handful of the objects. Culling each set against the view frustum
*before* moving objects and concatenating keeps the per-step tensors (and their autograd) at the
size of what the camera sees; an object outside the view costs no differentiable ops at all.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import torch
from numba import njit

from nuav2.geometry import F64, T_inverse, rot_to_quat
from nuav2.rig import CameraSpec

if TYPE_CHECKING:  # (scene_model imports this module)
    from nuav2.splat.scene_model import ObjectModel, SplatScene


def quat_mul_torch(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a * b of (..., 4) wxyz quaternions (rotation b first, then a)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([aw * bw - ax * bx - ay * by - az * bz,
                        aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw], -1)


def _view_limits(cam: CameraSpec, scene_T_cam: F64, margin: float) -> tuple[F64, float, float]:
    """cam_T_scene and the tangents of the half fields of view, widened by ``margin``."""
    K = cam.K
    lim_x = max(K[0, 2] + 0.5, cam.width - 0.5 - K[0, 2]) / K[0, 0] * (1 + margin)
    lim_y = max(K[1, 2] + 0.5, cam.height - 0.5 - K[1, 2]) / K[1, 1] * (1 + margin)
    return T_inverse(scene_T_cam), lim_x, lim_y


def _spheres_in_view(p_cam: torch.Tensor, r: torch.Tensor, near: float, far: float, lim_x: float,
                     lim_y: float) -> torch.Tensor:
    """Whether spheres (camera-frame centres, radii) may touch the widened frustum (bool mask)."""
    z = p_cam[:, 2]
    keep = (z + r > near) & (z - r < far)
    keep &= p_cam[:, 0].abs() - r * math.sqrt(1 + lim_x**2) < z.clamp_min(0) * lim_x
    keep &= p_cam[:, 1].abs() - r * math.sqrt(1 + lim_y**2) < z.clamp_min(0) * lim_y
    return keep


@njit(cache=True)
def _cull_rows(means, log_scales, cam_T_scene, near, far, lim_x, lim_y, kx, ky, out):
    """:func:`_spheres_in_view` for each Gaussian's 3-sigma sphere, one pass (float32 rows, float64
    maths); writes the kept row numbers into ``out`` and returns how many."""
    n_kept = 0
    for i in range(means.shape[0]):
        x, y, zz = np.float64(means[i, 0]), np.float64(means[i, 1]), np.float64(means[i, 2])
        px = cam_T_scene[0, 0] * x + cam_T_scene[0, 1] * y + cam_T_scene[0, 2] * zz + cam_T_scene[0, 3]
        py = cam_T_scene[1, 0] * x + cam_T_scene[1, 1] * y + cam_T_scene[1, 2] * zz + cam_T_scene[1, 3]
        z = cam_T_scene[2, 0] * x + cam_T_scene[2, 1] * y + cam_T_scene[2, 2] * zz + cam_T_scene[2, 3]
        s = min(max(log_scales[i, 0], log_scales[i, 1], log_scales[i, 2]), np.float32(10.0))
        r = 3.0 * np.exp(np.float64(s))
        zc = max(z, 0.0)
        if (z + r > near and z - r < far and abs(px) - r * kx < zc * lim_x
                and abs(py) - r * ky < zc * lim_y):
            out[n_kept] = i
            n_kept += 1
    return n_kept


def frustum_cull(g: dict[str, torch.Tensor], cam: CameraSpec, scene_T_cam: F64, near: float, far: float,
                 margin: float = 0.3) -> torch.Tensor:
    """Indices of Gaussians (``means``, ``log_scales``) whose 3-sigma sphere may touch the view
    frustum (widened by ``margin`` of the half field of view): everything else costs projection
    time for nothing. CPU float32 sets take one numba pass; others the same test in torch."""
    with torch.no_grad():
        means, log_scales = g["means"].detach(), g["log_scales"].detach()
        if len(means) == 0:
            return torch.zeros(0, dtype=torch.long, device=means.device)
        cam_T_scene, lim_x, lim_y = _view_limits(cam, scene_T_cam, margin)
        if means.device.type == "cpu" and means.dtype == log_scales.dtype == torch.float32:
            out = np.empty(len(means), np.int64)
            n = _cull_rows(means.contiguous().numpy(), log_scales.contiguous().numpy(), cam_T_scene,
                           float(near), float(far), lim_x, lim_y, math.sqrt(1 + lim_x**2),
                           math.sqrt(1 + lim_y**2), out)
            return torch.from_numpy(out[:n])
        R = torch.as_tensor(cam_T_scene[:3, :3], dtype=means.dtype, device=means.device)
        t = torch.as_tensor(cam_T_scene[:3, 3], dtype=means.dtype, device=means.device)
        r = 3.0 * torch.exp(log_scales.clamp(max=10.0)).max(-1).values
        return torch.nonzero(_spheres_in_view(means @ R.T + t, r, near, far, lim_x, lim_y)).flatten()


def place_object(obj: ObjectModel, timestamp_ns: int) -> dict[str, torch.Tensor]:
    """The object's Gaussians in the scene frame at a time; autograd flows back to the set's
    parameters and to the track's learned pose correction."""
    T = obj.track.scene_T_box_at(timestamp_ns)
    g = obj.gaussians.tensors()
    dev = g["means"].device
    R = torch.as_tensor(T[:3, :3], dtype=torch.float32, device=dev)
    t = torch.as_tensor(T[:3, 3], dtype=torch.float32, device=dev)
    q_box = torch.as_tensor(rot_to_quat(T[:3, :3]), dtype=torch.float32, device=dev)
    means = g["means"]
    delta = obj.track.delta_at(timestamp_ns)
    if delta is not None:  # box_T_corrected = [Rz(dyaw) | dxyz], learned
        c, s = torch.cos(delta[3]), torch.sin(delta[3])
        zero, one = torch.zeros_like(c), torch.ones_like(c)
        Rd = torch.stack([torch.stack([c, -s, zero]), torch.stack([s, c, zero]),
                          torch.stack([zero, zero, one])])
        means = means @ Rd.T + delta[:3]
        half = 0.5 * delta[3]
        q_box = quat_mul_torch(q_box, torch.stack([torch.cos(half), zero, zero, torch.sin(half)]))
    return {"means": means @ R.T + t, "quats": quat_mul_torch(q_box.expand_as(g["quats"]), g["quats"]),
            "log_scales": g["log_scales"], "opacity_logits": g["opacity_logits"], "sh": g["sh"]}


def _concat(parts: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """The parts' tensors concatenated per parameter (a single part as it is: no copy)."""
    if len(parts) == 1:
        return parts[0]
    return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}


def gather_all(splat: SplatScene, timestamp_ns: int,
               objects: bool = True) -> tuple[dict[str, torch.Tensor], dict[str, slice]]:
    """Every Gaussian in the scene frame at ``timestamp_ns`` (objects moved along their tracks),
    concatenated, with the rows of each set (``"background"`` or a track key)."""
    parts = [splat.background.tensors()]
    slices = {"background": slice(0, len(splat.background))}
    start = len(splat.background)
    for obj in splat.objects if objects else []:
        if not obj.track.present(timestamp_ns) or len(obj.gaussians) == 0:
            continue
        parts.append(place_object(obj, timestamp_ns))
        slices[obj.track.key] = slice(start, start + len(obj.gaussians))
        start += len(obj.gaussians)
    return _concat(parts), slices


def _object_spheres(objs: list[ObjectModel], timestamp_ns: int) -> tuple[F64, F64]:
    """Scene-frame centre and radius of a sphere holding each object's 3-sigma Gaussians at a time
    (the learned pose correction moves the box origin; its yaw turns about it)."""
    centres, radii = np.zeros((len(objs), 3)), np.zeros(len(objs))
    for i, obj in enumerate(objs):
        T = obj.track.scene_T_box_at(timestamp_ns)
        with torch.no_grad():
            d = obj.track.delta_at(timestamp_ns)
        offset = np.zeros(3) if d is None else d.cpu().numpy()[:3].astype(np.float64)
        centres[i] = T[:3, :3] @ offset + T[:3, 3]
        radii[i] = obj.gaussians.bounding_radius()
    return centres, radii


def gather_visible(splat: SplatScene, timestamp_ns: int, cam: CameraSpec, scene_T_cam: F64,
                   objects: bool = True, margin: float = 0.3) -> tuple[dict[str, torch.Tensor],
                                                                      dict[str, slice], torch.Tensor]:
    """The Gaussians that may touch the view, placed and concatenated, with ``slices`` (the rows of
    each set that has any, numbered as if those whole sets were concatenated) and ``index`` (which
    of those rows were kept, in order). Background Gaussians are culled one by one, objects as a
    whole by a bounding sphere; an object outside the view costs no differentiable ops (no gradient
    reaches it from this render) but keeps its slice: it is present, as the trainer needs to know."""
    near, far = splat.near, splat.far
    bg = splat.background.tensors()
    keep = frustum_cull(bg, cam, scene_T_cam, near, far, margin)
    parts, index = [{k: v.index_select(0, keep) for k, v in bg.items()}], [keep]  # (faster than v[keep])
    slices = {"background": slice(0, len(splat.background))}
    start = len(splat.background)
    present = [o for o in (splat.objects if objects else [])
               if len(o.gaussians) and o.track.present(timestamp_ns)]
    if present:
        centres, radii = _object_spheres(present, timestamp_ns)
        cam_T_scene, lim_x, lim_y = _view_limits(cam, scene_T_cam, margin)
        p_cam = torch.from_numpy(centres @ cam_T_scene[:3, :3].T + cam_T_scene[:3, 3])
        seen = _spheres_in_view(p_cam, torch.from_numpy(radii), near, far, lim_x, lim_y).tolist()
        for obj, in_view in zip(present, seen):
            n = len(obj.gaussians)
            if in_view:
                parts.append(place_object(obj, timestamp_ns))
                index.append(torch.arange(start, start + n, device=keep.device))
            slices[obj.track.key] = slice(start, start + n)
            start += n
    return _concat(parts), slices, torch.cat(index) if len(index) > 1 else index[0]
