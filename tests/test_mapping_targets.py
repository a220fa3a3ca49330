"""Dense auxiliary targets: BEV masks lie in the cells under the polylines; perspective-view masks
cover the feature pixels where an independent pinhole projection of the ground line falls."""

from __future__ import annotations

import numpy as np

from nuav2.geometry import T_inverse
from nuav2.mapping.backbone import STRIDE
from nuav2.mapping.config import MapModelConfig
from nuav2.mapping.targets import bev_targets, pv_targets
from nuav2.rig import load_rig

CFG = MapModelConfig()


def test_bev_target_is_the_cells_under_the_line():
    rows, cols = CFG.bev_shape
    mask = bev_targets([("boundary", np.array([[-4.75, -20.0], [-4.75, 20.0]]))], CFG)
    k = CFG.classes.index("boundary")
    col = int((-4.75 + 15.0) / CFG.bev_cell_m)  # 20: the line runs through the centres of column 20
    assert mask[k, :, col].sum() >= (40.0 / CFG.bev_cell_m) - 1
    assert mask[k].sum() == mask[k, :, col].sum()
    on = np.flatnonzero(mask[k, :, col])
    assert on.min() >= int((-20 + 30) / CFG.bev_cell_m) - 1 and on.max() <= int((20 + 30) / CFG.bev_cell_m)
    assert mask[[i for i in range(len(CFG.classes)) if i != k]].sum() == 0


def test_pv_target_follows_the_projected_ground_line():
    scale = 0.08
    rig = load_rig("nuscenes", scale)
    ego_T_lidar = rig.lidar("LIDAR_TOP").ego_T_lidar
    chans = ("CAM_FRONT", "CAM_BACK")
    l2i = []
    for ch in chans:
        cam = rig.camera(ch)
        K4 = np.eye(4)
        K4[:3, :3] = cam.K
        l2i.append(K4 @ T_inverse(cam.ego_T_cam) @ ego_T_lidar)
    H, W = 72, 128
    feat_hw = (-(-H // STRIDE), -(-W // STRIDE))
    line = np.array([[1.0, 6.0], [1.0, 28.0]])  # lidar xy: 1 m right, ahead of the car, on the ground
    mask = pv_targets([("divider", line)], np.stack(l2i), ego_T_lidar, feat_hw, CFG)
    assert mask.shape == (2, len(CFG.classes), *feat_hw)
    k = CFG.classes.index("divider")
    assert mask[1].sum() == 0  # behind the rear camera
    front = mask[0, k]
    assert front.sum() > 0
    # independent projection: ground points in the ego frame -> camera -> pixel -> feature pixel
    ys = np.linspace(6.0, 28.0, 200)
    xyz_lidar = np.column_stack([np.full_like(ys, 1.0), ys, np.zeros_like(ys)])
    xyz_ego = xyz_lidar @ ego_T_lidar[:3, :3].T + ego_T_lidar[:3, 3]
    xyz_ego[:, 2] = 0.0  # on the ground (ego origin at ground level)
    cam = rig.camera("CAM_FRONT")
    cam_T_ego = T_inverse(cam.ego_T_cam)
    pc = xyz_ego @ cam_T_ego[:3, :3].T + cam_T_ego[:3, 3]
    u = cam.K[0, 0] * pc[:, 0] / pc[:, 2] + cam.K[0, 2]
    v = cam.K[1, 1] * pc[:, 1] / pc[:, 2] + cam.K[1, 2]
    fu = np.round((u - (STRIDE - 1) / 2) / STRIDE).astype(int)
    fv = np.round((v - (STRIDE - 1) / 2) / STRIDE).astype(int)
    inside = (fu >= 0) & (fu < feat_hw[1]) & (fv >= 0) & (fv < feat_hw[0])
    assert inside.sum() > 20
    hits = front[fv[inside], fu[inside]]
    assert hits.mean() > 0.9
    # and nothing far from the line is set
    near = np.zeros_like(front, dtype=bool)
    for a, b in zip(fv[inside], fu[inside]):
        near[max(0, a - 1) : a + 2, max(0, b - 1) : b + 2] = True
    assert front[~near].sum() == 0


def test_depth_target_is_the_nearest_lidar_return_per_feature_pixel():
    from nuav2.mapping.targets import depth_targets

    K = np.array([[50.0, 0, 31.5], [0, 50.0, 15.5], [0, 0, 1]])
    cam_T_lidar = np.eye(4)
    cam_T_lidar[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # camera looks along lidar y (forward)
    K4 = np.eye(4)
    K4[:3, :3] = K
    l2i = (K4 @ cam_T_lidar)[None]
    step = (CFG.depth_max_m - CFG.depth_min_m) / CFG.depth_bins

    def lidar_point(u: float, v: float, depth: float) -> list[float]:
        x, y = (u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth
        return [x, depth, -y]  # camera (x, y, z) -> lidar (x, z, -y)

    pts = np.array([
        lidar_point(11.0, 4.0, 10.2),  # feature pixel (0, 1)
        lidar_point(13.0, 6.0, 20.0),  # same feature pixel, farther: ignored
        lidar_point(40.0, 20.0, 5.1),  # feature pixel (2, 5)
        lidar_point(40.0, 20.0, 60.0),  # beyond the depth range
        lidar_point(70.0, 20.0, 8.0),  # right of the 64 px image
    ])
    out = depth_targets(pts, l2i, np.array([[32, 64]]), (4, 8), CFG)
    assert out.shape == (1, 4, 8)
    assert out[0, 0, 1] == int((10.2 - CFG.depth_min_m) // step)
    assert out[0, 2, 5] == int((5.1 - CFG.depth_min_m) // step)
    assert (out >= 0).sum() == 2
