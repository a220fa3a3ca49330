"""Training augmentation: photometric jitter per camera, random rotation and mirroring of the BEV frame.

The rotation (``random_rotation``) picks, per sample, one of the angles whose GT the training
tensors carry (:mod:`nuav2.mapping.rotations`) or none.

The BEV mirror (as in BEVDet's BEV-space augmentation) flips the LIDAR_TOP frame's x and / or y
axis: ``lidar2img`` becomes ``lidar2img @ F`` with ``F = diag(sx, sy, 1, 1)``, so every pixel's
ray lands on the mirrored 3-D points (same pixel, same depth), and the GT polylines and the BEV
target are mirrored with it; the images, their perspective-view and depth targets are unchanged.
The patch is symmetric, so nothing leaves it. Four mirror images of every keyframe keep a small
training set from being memorised as a map prior. One mirrored axis reverses a ring's direction, so
rings are re-reversed: MapTR's GT rings are clockwise and their targets only cyclic shifts.
"""

from __future__ import annotations

import torch

from nuav2.maptr.fixed_points import PAD_VALUE


def photometric(img: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """Per-camera brightness / contrast / colour jitter (MapTR trains with photometric distortion)."""
    B, N = img.shape[:2]
    x = img.float()
    gain = 1.0 + 0.25 * (torch.rand(B, N, 1, 1, 1, generator=gen) - 0.5) * 2
    colour = 1.0 + 0.08 * (torch.rand(B, N, 3, 1, 1, generator=gen) - 0.5) * 2
    bias = 20.0 * (torch.rand(B, N, 1, 1, 1, generator=gen) - 0.5) * 2
    mean = x.mean(dim=(2, 3, 4), keepdim=True)
    contrast = 1.0 + 0.25 * (torch.rand(B, N, 1, 1, 1, generator=gen) - 0.5) * 2
    x = (x - mean) * contrast + mean
    return (x * gain * colour + bias).clamp(0, 255)


def mirror(batch: dict, signs: torch.Tensor) -> dict:
    """The batch with sample b's BEV frame mirrored by ``signs[b] = (sx, sy)`` (each +-1)."""
    out = dict(batch)
    B = len(signs)
    F = torch.eye(4).repeat(B, 1, 1)
    F[:, 0, 0], F[:, 1, 1] = signs[:, 0], signs[:, 1]
    out["lidar2img"] = batch["lidar2img"] @ F[:, None]
    shifts = []
    for b, s in enumerate(batch["gt_shifts"]):
        real = s > PAD_VALUE / 2
        m = torch.where(real, s * signs[b].to(s.dtype), s)
        if signs[b, 0] * signs[b, 1] < 0 and len(m):
            m = _rings_clockwise_again(m, real)
        shifts.append(m)
    out["gt_shifts"] = shifts
    bev = batch["bev_target"].clone()
    for b in range(B):
        dims = [d for d, sign in ((-1, signs[b, 0]), (-2, signs[b, 1])) if sign < 0]
        if dims:
            bev[b] = bev[b].flip(dims)
    out["bev_target"] = bev
    return out


def _rings_clockwise_again(shifts: torch.Tensor, real: torch.Tensor) -> torch.Tensor:
    """One mirrored axis turns every ring anticlockwise, while the GT's rings (crossings, closed
    boundaries) are clockwise and their ordering variants only cyclic shifts: reverse the rings'
    points so the same shape keeps the same targets (open lines carry both directions already,
    centerlines keep their driving order)."""
    first, last = shifts[:, 0, 0], shifts[:, 0, -1]
    ring = real[:, 0, 0].all(-1) & ((first - last).abs().amax(-1) <= 1e-4)
    out = shifts.clone()
    out[ring] = shifts[ring].flip(-2)
    return out


def bev_flip(batch: dict, gen: torch.Generator) -> dict:
    """``mirror`` with signs drawn at random (each axis flipped with probability 1/2)."""
    signs = torch.where(torch.rand(len(batch["gt_shifts"]), 2, generator=gen) < 0.5, -1.0, 1.0)
    return mirror(batch, signs)


def random_rotation(batch: dict, data, index: list[int], gen: torch.Generator) -> dict:
    """Each sample in its frame rotated by one of ``data.meta["rotations_deg"]`` or unrotated, uniformly
    (``index``: the samples' positions in ``data``)."""
    from nuav2.mapping.rotations import rotate_batch

    angles = data.meta["rotations_deg"]
    pick = torch.randint(0, len(angles) + 1, (len(index),), generator=gen).tolist()  # 0: unrotated
    rotated = [data.rotated[i][k - 1] if k else None for i, k in zip(index, pick)]
    return rotate_batch(batch, rotated, [angles[k - 1] if k else 0.0 for k in pick])
