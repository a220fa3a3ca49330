"""Per-image exposure and white balance, per-camera vignetting, solved from images that see shared points.

Real cameras disagree: auto-exposure drifts over time, each camera has its own white balance,
lenses darken towards the corners. Blending such images (warp mode) shows seams; training on
them (render mode) bakes the differences into the Gaussians and the target rig flickers. As
panorama stitchers do, the differences are solved from overlaps: static 3D points seen by
several images (across cameras and over time) must have one colour. Per observation of point
p in image v, channel k, at normalised radius rho (pixel distance from the principal point
over the half diagonal):

    log c[v,p,k] = log g[v,k] + a1[cam(v)] rho^2 + a2[cam(v)] rho^4 + log r[p,k]

solved by least squares (point colours eliminated exactly) with a ridge prior pulling log g to 0,
re-weighted a few times so that observations whose
residual is beyond ``outlier_sigma`` robust standard deviations dropped (moving things,
occlusion mistakes, specular spots), and the gauge fixed so the mean log gain over all images
is 0: the reference exposure is the log's geometric mean, one for the whole log, so target-rig
images rendered or warped at it match each other and stay steady over time. The synthetic
world's exposure model is never looked at: only image colours and geometry are.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import cv2
import numpy as np
from numba import njit

from nuav2.zbuffer import nearest_surface

F64 = np.ndarray


@njit(cache=True, nogil=True)
def _divide_u8(image, falloff, gain, out):  # pragma: no cover - compiled
    """``out = uint8(clip(image / (falloff * gain) + 0.5))`` in float32, one pass (numpy's four passes and
    temporaries cost warp mode a millisecond per source image)."""
    h, w, nc = image.shape
    half, top = np.float32(0.5), np.float32(255.0)
    for r in range(h):
        for c in range(w):
            fo = falloff[r, c]
            for k in range(nc):
                v = np.float32(image[r, c, k]) / (fo * gain[k]) + half
                out[r, c, k] = np.uint8(min(max(v, np.float32(0.0)), top))


@dataclass(frozen=True)
class ExposureConfig:
    """Knobs of the solve (colours in [0, 1])."""

    iterations: int = 4
    prior_weight: float = 2.0  # ridge weight (in observations) pulling each log gain to 0
    vignetting: bool = True  # also solve a radial fall-off shared by the cameras (AV2's ring: one model) ...
    camera_vignetting_prior: float | None = 0.1  # ... + each camera's deviation (ridge x its observations)
    outlier_sigma: float = 2.5
    min_value: float = 0.04  # darker or ...
    max_value: float = 0.96  # ... brighter channels are not observations (noise floor, clipping)
    max_observations_per_image: int = 4000
    # A point seen by every image of a 15 s log (2,100 images) ties them as well through a random dozen:
    # the solve's cost grows with the square of the images per point, its accuracy hardly at all.
    max_observations_per_point: int = 16
    # Warp mode observes this many images per camera and second and interpolates the others' log gains
    # in time (auto-exposure is smooth over a few frames; 0: every image). At AV2's 20 Hz, 2.5 Hz reads
    # an eighth of the images (15 s `hard` log: 55 -> 5 CPU s, 0.65 -> 0.8 % rms gain error,
    # `nuav2 bench exposure`).
    observe_hz: float = 2.5
    min_observed_per_camera: int = 12  # ... but at least this many images per camera (short logs)
    cell_px: int = 2  # z-buffer cell of the visibility test
    depth_rel_tol: float = 0.03
    depth_abs_tol_m: float = 0.2
    near_m: float = 0.5


@dataclass
class Observations:
    """Colours of points in images: which image, which point, RGB in [0, 1], rho^2."""

    image: list[np.ndarray] = field(default_factory=list)
    point: list[np.ndarray] = field(default_factory=list)
    rgb: list[np.ndarray] = field(default_factory=list)
    rho2: list[np.ndarray] = field(default_factory=list)

    def add(self, image_index: int, point: np.ndarray, rgb: np.ndarray, rho2: np.ndarray) -> None:
        self.image.append(np.full(len(point), int(image_index), np.int64))
        self.point.append(np.asarray(point, np.int64))
        self.rgb.append(np.asarray(rgb, np.float64).reshape(-1, 3))
        self.rho2.append(np.asarray(rho2, np.float64))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if not self.image:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0)
        return (np.concatenate(self.image), np.concatenate(self.point), np.concatenate(self.rgb),
                np.concatenate(self.rho2))


def radius2(u: F64, v: F64, K: F64, width: int, height: int) -> F64:
    """Squared pixel distance from the principal point over the squared half diagonal."""
    half_diag2 = 0.25 * (width**2 + height**2)
    return ((u - K[0, 2]) ** 2 + (v - K[1, 2]) ** 2) / half_diag2


@functools.lru_cache(maxsize=16)
def _radius2_map(cx: float, cy: float, width: int, height: int) -> np.ndarray:
    """(H, W) float32 :func:`radius2` of every pixel of a camera (cached: one per camera and size)."""
    K = np.array([[1.0, 0.0, cx], [0.0, 1.0, cy], [0.0, 0.0, 1.0]])
    uu, vv = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    out = radius2(uu, vv, K, width, height).astype(np.float32)
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=16)
def _falloff_map(a1: float, a2: float, cx: float, cy: float, width: int, height: int) -> np.ndarray:
    """(H, W) float32 radial fall-off ``exp(a1 rho^2 + a2 rho^4)`` of one camera (cached)."""
    r2 = _radius2_map(cx, cy, width, height)
    out = np.exp(a1 * r2 + a2 * r2 * r2).astype(np.float32)
    out.flags.writeable = False
    return out


def sample_bilinear(image: np.ndarray, u: F64, v: F64) -> F64:
    """(N, 3) colours in [0, 1] of a uint8 or float image at pixel centres (u, v) (centre of u is u)."""
    if len(u) == 0:  # an image that sees none of the points (cv2.remap refuses empty maps)
        return np.zeros((0, 3))
    img = image.astype(np.float32) / 255.0 if image.dtype == np.uint8 else image.astype(np.float32)
    m = cv2.remap(img, np.asarray(u, np.float32).reshape(1, -1), np.asarray(v, np.float32).reshape(1, -1),
                  cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return m.reshape(-1, 3).astype(np.float64)


def local_points(points: F64) -> tuple[np.ndarray, F64]:
    """(float32 points about their mean, that mean): for :func:`observe` with ``cam_T_points @
    translation(mean)``; city coordinates reach kilometres, the points of one log span a few hundred m."""
    centre = np.asarray(points, np.float64).mean(0) if len(points) else np.zeros(3)
    return (np.asarray(points, np.float64) - centre).astype(np.float32), centre


def observe(points: F64, K: F64, width: int, height: int, cam_T_points: F64, image: np.ndarray,
            valid: np.ndarray | None, cfg: ExposureConfig, rng: np.random.Generator | None = None
            ) -> tuple[np.ndarray, F64, F64]:
    """(point indices, RGB, rho^2) of the ``points`` an image sees (nearest surface, inside the image,
    on valid pixels), at most ``cfg.max_observations_per_image``. ``K``/``width``/``height`` describe
    ``image`` (scale them together when reading images reduced). Float32 ``points`` (recentred near the
    cameras: :func:`local_points`) are projected in float32, twice as fast."""
    idx, u, v = visible_points(points, K, width, height, cam_T_points, valid, cfg)
    return sample_observations(idx, u, v, image, K, width, height, cfg, rng)


def visible_points(points: F64, K: F64, width: int, height: int, cam_T_points: F64,
                   valid: np.ndarray | None, cfg: ExposureConfig) -> tuple[np.ndarray, F64, F64]:
    """(point indices, u, v) of the ``points`` an image sees: the half of :func:`observe` that needs no
    random state, so callers may run it for many images at once."""
    dt = points.dtype if points.dtype == np.float32 else np.float64
    R, t = cam_T_points[:3, :3].astype(dt), cam_T_points[:3, 3].astype(dt)
    front = np.flatnonzero(points @ R[2] > cfg.near_m - t[2])  # depth first: about half are behind
    p = points[front] @ R.T + t
    u = K[0, 0] * p[:, 0] / p[:, 2] + K[0, 1] * p[:, 1] / p[:, 2] + K[0, 2]
    v = K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]
    inside = (u > 0) & (u < width - 1) & (v > 0) & (v < height - 1)
    idx, u, v, z = front[inside], u[inside], v[inside], p[inside, 2]
    vis = nearest_surface(u, v, z, width, height, cfg.cell_px, cfg.depth_rel_tol, cfg.depth_abs_tol_m, valid)
    return idx[vis], u[vis], v[vis]


def sample_observations(idx: np.ndarray, u: F64, v: F64, image: np.ndarray, K: F64, width: int, height: int,
                        cfg: ExposureConfig, rng: np.random.Generator | None = None
                        ) -> tuple[np.ndarray, F64, F64]:
    """At most ``cfg.max_observations_per_image`` of the visible points (a random subset, drawn from
    ``rng`` in call order), with their RGB and rho^2: the other half of :func:`observe`."""
    if len(idx) > cfg.max_observations_per_image:
        rng = rng or np.random.default_rng(0)
        pick = np.sort(rng.choice(len(idx), cfg.max_observations_per_image, replace=False))
        idx, u, v = idx[pick], u[pick], v[pick]
    return idx, sample_bilinear(image, u, v), radius2(u, v, K, width, height)


@dataclass(frozen=True)
class ExposureModel:
    """Solved corrections: ``log_gain`` per image and channel, the cameras' radial ``vignetting``."""

    log_gain: np.ndarray  # (V, 3)
    vignetting: np.ndarray  # (C, 2): a1, a2 of each camera's radial fall-off
    camera_of_image: np.ndarray  # (V,) int
    observations: int = 0
    inliers: int = 0

    @staticmethod
    def identity(camera_of_image: np.ndarray) -> ExposureModel:
        cams = np.asarray(camera_of_image, np.int64)
        return ExposureModel(np.zeros((len(cams), 3)), np.zeros((int(cams.max(initial=-1)) + 1, 2)), cams)

    def gain(self, image_index: int) -> np.ndarray:
        return np.exp(self.log_gain[int(image_index)])

    def falloff(self, image_index: int, K: F64, width: int, height: int) -> np.ndarray:
        """(H, W) float32 radial fall-off of the image's camera (cached per camera)."""
        a1, a2 = self.vignetting[int(self.camera_of_image[int(image_index)])]
        return _falloff_map(float(a1), float(a2), float(K[0][2]), float(K[1][2]), int(width), int(height))

    def factor(self, image_index: int, K: F64, width: int, height: int) -> np.ndarray:
        """(H, W, 3) float32: the observed image is the reference-exposure image times this."""
        return (self.falloff(image_index, K, width, height)[..., None]
                * np.exp(self.log_gain[int(image_index)]).astype(np.float32))

    def correct(self, image: np.ndarray, image_index: int, K: F64) -> np.ndarray:
        """The image at the reference exposure (same dtype; uint8 rounds and clips)."""
        h, w = image.shape[:2]
        if image.dtype == np.uint8 and image.ndim == 3:
            out = np.empty_like(image)
            _divide_u8(np.ascontiguousarray(image), self.falloff(image_index, K, w, h),
                       np.exp(self.log_gain[int(image_index)]).astype(np.float32), out)
            return out
        f = self.factor(image_index, K, w, h)
        if image.dtype == np.uint8:
            return np.clip(image.astype(np.float32) / f + 0.5, 0, 255).astype(np.uint8)
        return (image / f).astype(image.dtype)

    def to_dict(self) -> dict:
        return {"log_gain": self.log_gain.round(5).tolist(), "vignetting": self.vignetting.round(5).tolist(),
                "camera_of_image": self.camera_of_image.tolist(), "observations": self.observations,
                "inliers": self.inliers}


def frames_to_observe(timestamps_ns: np.ndarray, hz: float, min_frames: int = 0) -> np.ndarray:
    """Indices of one camera's frames (sorted timestamps) at most ``hz`` apart in rate, faster where that
    gives fewer than ``min_frames`` (a short log needs its images to tie the cameras together), first and
    last always (so every other frame lies between two observed ones); every frame when ``hz`` <= 0."""
    t = np.asarray(timestamps_ns, np.int64)
    if hz <= 0 or len(t) <= 2:
        return np.arange(len(t))
    span_s = (int(t[-1]) - int(t[0])) * 1e-9
    if min_frames > 1 and span_s > 0:
        hz = max(hz, (min_frames - 1) / span_s)
    step_ns = int(round(1e9 / hz))
    picked, last = [0], int(t[0])
    for j in range(1, len(t) - 1):
        if int(t[j]) - last >= step_ns - step_ns // 10:  # 10 % slack for timestamp jitter
            picked.append(j)
            last = int(t[j])
    picked.append(len(t) - 1)
    return np.array(picked, np.int64)


def interpolate_log_gains(model: ExposureModel, observed: np.ndarray, timestamps_ns: np.ndarray,
                          camera_of_image: np.ndarray) -> ExposureModel:
    """The model over every image: ``model`` solved on the images ``observed`` (its rows, in order),
    the other images' log gains linear in time between their camera's observed neighbours."""
    cams = np.asarray(camera_of_image, np.int64)
    t = np.asarray(timestamps_ns, np.float64)
    observed = np.asarray(observed, np.int64)
    log_gain = np.zeros((len(cams), 3))
    for c in np.unique(cams):
        mine = np.flatnonzero(cams == c)
        rows = np.flatnonzero(cams[observed] == c)
        if len(rows) == 0:
            continue
        order = np.argsort(t[observed[rows]])
        rows = rows[order]
        for k in range(3):
            log_gain[mine, k] = np.interp(t[mine], t[observed[rows]], model.log_gain[rows, k])
    return ExposureModel(log_gain, model.vignetting, cams, model.observations, model.inliers)


def cap_per_point(point: np.ndarray, max_per_point: int, seed: int = 0) -> np.ndarray:
    """Indices of the observations kept when each point keeps at most ``max_per_point`` of its own, drawn
    at random (deterministically), in their original order."""
    n = len(point)
    if max_per_point <= 0 or n == 0:
        return np.arange(n)
    point = np.asarray(point, np.int64)
    # one int64 key: the point in the high bits, a random tie-break in the low 20 (a single argsort)
    key = (point << 20) | np.random.default_rng(seed).integers(0, 1 << 20, n, dtype=np.int64)
    order = np.argsort(key)
    sorted_pt = point[order]
    start = np.flatnonzero(np.r_[True, sorted_pt[1:] != sorted_pt[:-1]])
    rank = np.arange(n) - np.repeat(start, np.diff(np.r_[start, n]))
    return np.sort(order[rank < max_per_point])


def solve_exposure(obs: Observations, camera_of_image: np.ndarray,
                   cfg: ExposureConfig | None = None) -> ExposureModel:
    """Solve gains (and vignetting) from ``obs`` (see module doc); identity where nothing is known.

    Per channel, the point colours are eliminated exactly (each point's unknown only meets its
    own observations), leaving a small dense system in the image gains and camera vignetting;
    ``iterations`` rounds re-weight it, dropping outliers."""
    from scipy import sparse

    cfg = cfg or ExposureConfig()
    cams = np.asarray(camera_of_image, np.int64)
    n_img = len(cams)
    img, pt, rgb, rho2 = obs.arrays()
    ok = np.all((rgb >= cfg.min_value) & (rgb <= cfg.max_value), axis=1)
    img, pt, rgb, rho2 = img[ok], pt[ok], rgb[ok], rho2[ok]
    keep = cap_per_point(pt, cfg.max_observations_per_point)
    img, pt, rgb, rho2 = img[keep], pt[keep], rgb[keep], rho2[keep]
    # Only points seen by two or more images say anything about the images.
    _, pt, counts = np.unique(pt, return_inverse=True, return_counts=True)
    multi = counts[pt.reshape(-1)] >= 2
    img, pt, rgb, rho2 = img[multi], pt.reshape(-1)[multi], rgb[multi], rho2[multi]
    _, pt = np.unique(pt, return_inverse=True)
    pt = pt.reshape(-1)
    model = ExposureModel.identity(cams)
    if len(img) == 0:
        return model
    n_obs, n_pt = len(img), int(pt.max()) + 1
    n_cam = int(cams.max()) + 1
    per_cam = cfg.vignetting and cfg.camera_vignetting_prior is not None
    n = n_img + (2 if cfg.vignetting else 0) + (2 * n_cam if per_cam else 0)
    rows = np.arange(n_obs)
    cols = [img]
    vals = [np.ones(n_obs)]
    if cfg.vignetting:  # shared a1, a2, then each camera's deviation from them
        cols += [np.full(n_obs, n_img), np.full(n_obs, n_img + 1)]
        vals += [rho2, rho2 * rho2]
    if per_cam:
        cols += [n_img + 2 + 2 * cams[img], n_img + 3 + 2 * cams[img]]
        vals += [rho2, rho2 * rho2]
    A = sparse.csr_matrix((np.concatenate(vals), (np.tile(rows, len(cols)), np.concatenate(cols))),
                          shape=(n_obs, n))
    B = sparse.csr_matrix((np.ones(n_obs), (rows, pt)), shape=(n_obs, n_pt))
    prior = np.full(n, 1e-3)
    prior[:n_img] = cfg.prior_weight
    if per_cam:
        per = np.bincount(cams[img], minlength=n_cam).astype(np.float64) * cfg.camera_vignetting_prior
        prior[n_img + 2:] = np.repeat(np.maximum(per, 1e-3), 2)
    logc = np.log(rgb)
    lg = np.zeros((n_img, 3))
    vig = np.zeros((n_cam, 2))
    w = np.ones(n_obs)
    for _ in range(max(1, cfg.iterations)):
        W = sparse.diags(w)
        AtW = (A.T @ W).tocsr()
        AtWA = (AtW @ A).toarray()
        AtWB = (AtW @ B).tocsr()
        d = np.asarray(B.T @ w).reshape(-1)
        Dinv = sparse.diags(1.0 / np.maximum(d, 1e-12))
        S = AtWB @ Dinv
        N = AtWA - (S @ AtWB.T).toarray() + np.diag(prior)
        wy = w[:, None] * logc
        x = np.linalg.solve(N, AtW @ logc - S @ (B.T @ wy))  # (n, 3): one system, three channels
        fit = A @ x
        r_pt = Dinv @ (B.T @ (w[:, None] * (logc - fit)))
        resid = logc - fit - B @ r_pt
        lg = x[:n_img]
        if cfg.vignetting:  # one fall-off for all channels (the per-channel solves differ by noise only)
            vig = np.repeat(x[n_img:n_img + 2].mean(1)[None], n_cam, axis=0)
            if per_cam:
                vig += x[n_img + 2:].mean(1).reshape(n_cam, 2)
        r = np.abs(resid).max(1)
        sigma = 1.4826 * np.median(r[w > 0]) + 1e-6
        w = (r <= cfg.outlier_sigma * sigma).astype(np.float64)
    seen = np.bincount(img, minlength=n_img) > 0
    lg[seen] -= lg[seen].mean(0)  # the reference exposure: the mean over the images that were observed
    return ExposureModel(lg, vig, cams, int(n_obs), int(w.sum()))
