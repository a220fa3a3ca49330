"""Lidar sweeps ray-cast against the synthetic world (terrain + solids).

Two 32-beam spinning lidars (AV2's up_lidar and down_lidar, 180 degrees apart in phase)
with VLP-32C elevation angles; the down lidar is mounted upside down (rig extrinsics), so in
the ego frame the two patterns differ and stack. Every ray is cast from the ego pose at the
sweep timestamp against the actors at that timestamp, i.e. the sweep is *perfectly* motion
compensated and moving objects do not smear (real AV2 sweeps smear them, av2-api#204).
``offset_ns`` still encodes when in the 100 ms revolution each ray fired. Nothing returns from
the sky or beyond range. Without the ``lidar_noise`` factor ranges are exact (the only error is
the float16 storage of the ego-frame coordinates); with it, ranges get a few centimetres of
Gaussian noise and returns drop out at grazing incidence and on dark, distant surfaces, drawn
from a stream seeded by the world's seed and the sweep's timestamp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nuav2.geometry import F64, T_inverse, transform_points
from nuav2.synth.boxes import face_normals_local, intersect_rays
from nuav2.synth.world import LIDARS, SyntheticWorld

RANGE_NOISE_M = 0.02
GRAZING_COS = 0.12  # below this incidence cosine returns start to drop out
DARK_REFLECTIVITY = 12.0  # returns from surfaces darker than this (x incidence) fade with range
DARK_FADE_M = (10.0, 50.0)

# VLP-32C elevation angles (degrees), sorted ascending; laser_number = index (+32 for down_lidar).
VLP32C_ELEVATION_DEG = np.array([
    -25.0, -15.639, -11.31, -8.843, -7.254, -6.148, -5.333, -4.667, -4.0, -3.667, -3.333, -3.0, -2.667,
    -2.333, -2.0, -1.667, -1.333, -1.0, -0.667, -0.333, 0.0, 0.333, 0.667, 1.0, 1.333, 1.667, 2.333,
    3.333, 4.667, 7.0, 10.333, 15.0])
SWEEP_NS = 100_000_000
MIN_RANGE_M = 0.5


@dataclass(frozen=True, eq=False)
class LidarReturns:
    """One merged sweep, rows sorted by ``offset_ns``; ``box`` indexes ``world.boxes_at`` (-1: ground);
    the owner of a solid (``world.boxes_at(t).owner``) is the actor it belongs to."""

    xyz_ego: F64  # (N, 3) float64 before float16 storage
    intensity: np.ndarray  # (N,) uint8
    laser_number: np.ndarray  # (N,) uint8
    offset_ns: np.ndarray  # (N,) int32
    box: np.ndarray  # (N,) int64


def beam_directions(azimuth_steps: int) -> tuple[F64, F64]:
    """Unit ray directions (32 * steps, 3) in the sensor frame and their azimuths (rad, [0, 2pi))."""
    el = np.deg2rad(VLP32C_ELEVATION_DEG)
    az = np.arange(azimuth_steps) * (2 * np.pi / azimuth_steps)
    el_g, az_g = np.meshgrid(el, az, indexing="ij")
    dirs = np.stack([np.cos(el_g) * np.cos(az_g), np.cos(el_g) * np.sin(az_g), np.sin(el_g)], -1)
    return dirs.reshape(-1, 3), az_g.reshape(-1)


def _dropouts(rng: np.random.Generator, cos_inc: F64, refl: F64, rng_m: F64) -> np.ndarray:
    """Which returns survive: grazing incidence and dark surfaces far away return too little light."""
    p_graze = np.clip((GRAZING_COS - cos_inc) / GRAZING_COS, 0.0, 1.0)
    fade = np.clip((rng_m - DARK_FADE_M[0]) / (DARK_FADE_M[1] - DARK_FADE_M[0]), 0.0, 1.0)
    p_dark = 0.6 * np.clip((DARK_REFLECTIVITY - refl * cos_inc) / DARK_REFLECTIVITY, 0.0, 1.0) * fade
    return rng.uniform(size=len(cos_inc)) >= np.maximum(p_graze, p_dark)


def cast_sweep(world: SyntheticWorld, timestamp_ns: int) -> LidarReturns:
    """Ray-cast both lidars at ``timestamp_ns``; points come back in the ego frame at that time."""
    cfg = world.config
    local_T_ego = world.local_T_ego_at(int(timestamp_ns))
    ego_T_local = T_inverse(local_T_ego)
    boxes = world.boxes_at(int(timestamp_ns))
    dirs_s, az = beam_directions(cfg.lidar_azimuth_steps)
    n_beams = len(VLP32C_ELEVATION_DEG)
    noise = None
    if cfg.lidar_noise:
        noise = np.random.default_rng([world.seed, 100, int(timestamp_ns) % (1 << 62)])
    parts = []
    for li, name in enumerate(LIDARS):
        local_T_lidar = local_T_ego @ world.rig.lidar(name).ego_T_lidar
        origin = local_T_lidar[:3, 3]
        dirs = dirs_s @ local_T_lidar[:3, :3].T
        hits = intersect_rays(origin, dirs, boxes, t_min=MIN_RANGE_M, t_max=cfg.lidar_max_range_m)
        if world.terrain.flat:
            with np.errstate(divide="ignore", invalid="ignore"):
                t_ground = np.where(dirs[:, 2] < -1e-12, -origin[2] / dirs[:, 2], np.inf)
        else:
            t_ground = world.terrain.intersect(origin, dirs, MIN_RANGE_M, cfg.lidar_max_range_m)
        t_ground = np.where((t_ground >= MIN_RANGE_M) & (t_ground <= cfg.lidar_max_range_m), t_ground, np.inf)
        on_box = hits.t < t_ground
        t = np.where(on_box, hits.t, t_ground)
        keep = np.isfinite(t)
        t, on_box, d = t[keep], on_box[keep], dirs[keep]
        box = np.where(on_box, hits.box[keep], -1)
        p_local = origin + t[:, None] * d
        bi = np.flatnonzero(on_box)
        if world.terrain.flat:
            normal = np.tile([0.0, 0.0, 1.0], (len(t), 1))
        else:
            normal = world.terrain.normal(p_local[:, :2])
        normal[bi] = face_normals_local(boxes, box[bi], hits.face[keep][bi], p_local[bi])
        refl = world.texture.sample_reflectivity(p_local[:, :2]).astype(np.float64)
        refl[bi] = boxes.reflectivity[box[bi]]
        cos_inc = np.abs(np.einsum("ij,ij->i", d, normal))
        beam = np.repeat(np.arange(n_beams), cfg.lidar_azimuth_steps)[keep]
        phase = (az[keep] + np.pi * li) % (2 * np.pi)
        if noise is not None:
            ok = _dropouts(noise, cos_inc, refl, t)
            t_noisy = t + noise.normal(0.0, RANGE_NOISE_M, len(t))
            p_local = (origin + t_noisy[:, None] * d)[ok]
            t, box, refl, cos_inc, beam, phase = t[ok], box[ok], refl[ok], cos_inc[ok], beam[ok], phase[ok]
            refl = refl + noise.normal(0.0, 2.0, len(refl))
        intensity = np.clip(np.round(refl * (0.4 + 0.6 * cos_inc)), 0, 255).astype(np.uint8)
        offset = np.floor(phase / (2 * np.pi) * SWEEP_NS).astype(np.int32)
        parts.append((transform_points(ego_T_local, p_local), intensity, (beam + 32 * li).astype(np.uint8),
                      offset, box))
    xyz, inten, laser, offset, box = (np.concatenate(c) for c in zip(*parts))
    order = np.argsort(offset, kind="stable")
    return LidarReturns(xyz[order], inten[order], laser[order], offset[order], box[order])
