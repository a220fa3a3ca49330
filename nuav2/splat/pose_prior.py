"""The prior on a moving track's learned box-pose corrections (label-noise refinement).

AV2 boxes are a few centimetres and a fraction of a degree off, and the error jitters from frame
to frame; the reconstruction learns a small per-frame correction of each moving track's pose, and
this prior keeps the corrections small and the corrected path smooth (as Street Gaussians does).
"""

from __future__ import annotations

import numpy as np
import torch

from nuav2.splat.scene_model import TrackPoses


def pose_prior(track: TrackPoses, lambda_size: float, lambda_smooth: float,
               base: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
    """Prior of a track's learned box-pose corrections: small (``lambda_size`` x mean squared correction)
    and a smooth corrected path (``lambda_smooth`` x mean squared second difference of the corrected
    centres and headings between annotated frames): labels jitter from frame to frame, actors do not.
    ``base``: the track's (poses, unwrapped headings) as tensors, when the caller keeps them."""
    d = track.pose_delta
    T, yaw0 = base if base is not None else track_tensors(track)
    centre = T[:, :3, 3] + torch.einsum("nij,nj->ni", T[:, :3, :3], d[:, :3])
    total = lambda_size * d.pow(2).sum(-1).mean()
    if len(d) >= 3:
        path = torch.cat([centre, (yaw0 + d[:, 3])[:, None]], 1)
        total = total + lambda_smooth * (path[2:] - 2 * path[1:-1] + path[:-2]).pow(2).sum(-1).mean()
    return total


def track_tensors(track: TrackPoses) -> tuple[torch.Tensor, torch.Tensor]:
    """(scene_T_box (T, 4, 4), unwrapped heading (T,)) of a track as float32 tensors, on the device
    of its learned corrections."""
    dev = track.pose_delta.device if track.pose_delta is not None else torch.device("cpu")
    yaw = np.unwrap(np.arctan2(track.scene_T_box[:, 1, 0], track.scene_T_box[:, 0, 0]))
    T = torch.as_tensor(track.scene_T_box, dtype=torch.float32, device=dev)
    return T, torch.as_tensor(yaw, dtype=torch.float32, device=dev)
