"""Solids that make up the world's content: vehicles whose shape is not their cuboid, walking
pedestrians, cyclists, and street furniture (poles, signs, traffic lights, trees).

Each maker returns solids in the *box frame* of its annotation cuboid (origin at the cuboid's
centre, x forward, z up), all inside the cuboid: a rounded body (box cut by an ellipsoid), a
narrower glass cabin, wheels (box cut by a cylinder); pedestrians swing legs and arms with the
distance walked, cyclists pedal, so they are not rigid inside their box.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nuav2.geometry import F64
from nuav2.synth.boxes import BoxSet
from nuav2.synth.materials import (
    MAT_BARK,
    MAT_BUS,
    MAT_CABIN,
    MAT_CARGO,
    MAT_CLOTH,
    MAT_FOLIAGE,
    MAT_METAL,
    MAT_PAINT,
    MAT_SIGN,
    MAT_SIGNAL,
    MAT_SKIN,
    MAT_TYRE,
    METAL,
    REFLECTIVITY,
    TROUSERS,
)

# AV2 category and size ranges (length, width, height in metres) of each vehicle class.
VEHICLE_CLASSES = {
    "car": ("REGULAR_VEHICLE", (4.2, 4.9), (1.78, 1.95), (1.42, 1.58)),
    "suv": ("REGULAR_VEHICLE", (4.6, 5.1), (1.9, 2.05), (1.7, 1.9)),
    "bus": ("BUS", (11.0, 12.5), (2.5, 2.6), (3.0, 3.3)),
    "truck": ("BOX_TRUCK", (7.0, 8.8), (2.35, 2.5), (3.1, 3.6)),
}
PEDESTRIAN_SIZE = ((0.7, 0.8), (0.55, 0.65), (1.6, 1.9))
CYCLIST_SIZE = (1.78, 0.66, 1.76)
SWING_RAD = 0.3  # leg swing amplitude of a walking pedestrian
STRIDE_M = 1.5  # distance walked per full gait cycle


@dataclass
class SolidList:
    """Solids being assembled (box frame)."""

    center: list
    rot: list
    half: list
    quad: list
    color: list
    kind: list
    params: list

    @staticmethod
    def new() -> SolidList:
        return SolidList([], [], [], [], [], [], [])

    def add(self, center, half, kind: int, color, *, radii=None, rot: F64 | None = None, params=(0, 0, 0, 0)):
        """One solid; ``radii`` (3,) of the cutting quadric in its own frame (inf: unbounded)."""
        self.center.append(np.asarray(center, np.float64))
        self.rot.append(np.eye(3) if rot is None else np.asarray(rot, np.float64))
        self.half.append(np.asarray(half, np.float64))
        q = (
            np.zeros(3)
            if radii is None
            else np.where(np.isinf(radii), 0.0, 1.0 / np.square(np.asarray(radii, float)))
        )
        self.quad.append(q)
        self.color.append(np.asarray(color, np.float32))
        self.kind.append(kind)
        self.params.append(np.asarray(params, np.float64))

    def boxset(self, local_T_box: F64, owner: int) -> BoxSet:
        """The solids in the local frame of a box pose."""
        n = len(self.center)
        if n == 0:
            return BoxSet.empty()
        R = local_T_box[:3, :3]
        centers = np.array(self.center) @ R.T + local_T_box[:3, 3]
        rots = R[None] @ np.array(self.rot)
        kinds = np.array(self.kind, np.int8)
        return BoxSet(
            centers,
            np.arctan2(rots[:, 1, 0], rots[:, 0, 0]),
            2 * np.array(self.half),
            np.array(self.color, np.float32),
            kinds,
            np.array([REFLECTIVITY[int(k)] for k in kinds], np.uint8),
            rots,
            np.array(self.quad),
            np.full(n, owner, np.int64),
            np.array(self.params),
        )


def rot_y(a: float) -> F64:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_x(a: float) -> F64:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_z(a: float) -> F64:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _wheels(out: SolidList, xs: list[float], half_w: float, bottom: float, r: float, width: float = 0.24):
    inf = np.inf
    for x in xs:
        for side in (-1.0, 1.0):
            out.add(
                [x, side * (half_w - width / 2 - 0.01), bottom + r],
                [r, width / 2, r],
                MAT_TYRE,
                (28, 28, 30),
                radii=[r, inf, r],
            )


def vehicle(cls: str, size: F64, color: F64) -> SolidList:
    """A vehicle of class ``cls`` (VEHICLE_CLASSES) filling a cuboid of ``size`` (l, w, h)."""
    L, W, H = size
    b = -H / 2  # box bottom
    out = SolidList.new()
    inf = np.inf
    if cls in ("car", "suv"):
        r = 0.33 if cls == "car" else 0.37
        top = (0.56 if cls == "car" else 0.6) * H
        zb = 0.2 if cls == "car" else 0.25
        hz = (top - zb) / 2
        out.add(
            [0, 0, b + zb + hz], [L / 2, W / 2, hz], MAT_PAINT, color, radii=[0.6 * L, 0.72 * W, 2.4 * hz]
        )
        cab_l = (0.26 if cls == "car" else 0.34) * L
        cz = (H - top + 0.04) / 2
        out.add(
            [-0.06 * L if cls == "car" else -0.04 * L, 0, b + top - 0.04 + cz],
            [cab_l, W / 2 - 0.12, cz],
            MAT_CABIN,
            color,
            radii=[1.3 * cab_l, 1.7 * (W / 2 - 0.12), 2.0 * cz],
        )
        _wheels(out, [-0.31 * L, 0.3 * L], W / 2, b, r)
    elif cls == "bus":
        out.add(
            [0, 0, b + 0.35 + (H - 0.35) / 2],
            [L / 2, W / 2, (H - 0.35) / 2],
            MAT_BUS,
            color,
            radii=[0.52 * L, 0.75 * W, inf],
        )
        _wheels(out, [-0.3 * L, 0.32 * L], W / 2, b, 0.5, 0.3)
    else:  # box truck: cab + cargo box
        cab = 0.26 * L
        out.add(
            [L / 2 - cab / 2, 0, b + 0.4 + 0.25 * H / 2],
            [cab / 2, W / 2 - 0.05, 0.25 * H / 2],
            MAT_PAINT,
            color,
            radii=[0.62 * cab, 0.7 * W, inf],
        )
        out.add(
            [L / 2 - cab / 2 - 0.05, 0, b + 0.4 + 0.25 * H + 0.2 * H],
            [cab / 2 - 0.05, W / 2 - 0.08, 0.2 * H],
            MAT_CABIN,
            color,
            radii=[0.62 * cab, 0.68 * W, 1.6 * 0.2 * H],
        )
        box_l = L - cab - 0.15
        out.add(
            [-L / 2 + box_l / 2, 0, b + 0.45 + (H - 0.45) / 2],
            [box_l / 2, W / 2, (H - 0.45) / 2],
            MAT_CARGO,
            (226, 226, 220),
        )
        _wheels(out, [-L / 2 + 0.18 * L, L / 2 - 0.16 * L], W / 2, b, 0.45, 0.3)
    return out


def pedestrian(size: F64, shirt: F64, walked_m: float, phase: float) -> SolidList:
    """A person walking (``walked_m``: distance so far; 0 with no motion: standing still)."""
    L, W, H = size
    b = -H / 2
    out = SolidList.new()
    inf = np.inf
    swing = SWING_RAD * np.sin(2 * np.pi * walked_m / STRIDE_M + phase)
    hip, shoulder = b + 0.5 * H, b + 0.81 * H
    leg = 0.5 * H - 0.02
    for side, sgn in ((-1.0, 1.0), (1.0, -1.0)):
        R = rot_y(sgn * swing)
        c = np.array([0.0, side * 0.085, hip]) + R @ [0.0, 0.0, -leg / 2]
        out.add(c, [0.075, 0.07, leg / 2], MAT_CLOTH, TROUSERS, radii=[0.075, 0.07, inf], rot=R)
        Ra = rot_y(-sgn * 0.7 * swing)
        arm = 0.34 * H
        ca = np.array([0.0, side * (W / 2 - 0.07), shoulder - 0.02]) + Ra @ [0.0, 0.0, -arm / 2]
        out.add(ca, [0.05, 0.045, arm / 2], MAT_CLOTH, shirt, radii=[0.05, 0.045, inf], rot=Ra)
    tz = (shoulder - hip) / 2 + 0.03
    out.add([0, 0, hip + tz - 0.03], [0.12, W / 2 - 0.11, tz], MAT_CLOTH, shirt, radii=[0.15, 0.26, 1.8 * tz])
    out.add(
        [0, 0, b + H - 0.115], [0.105, 0.095, 0.115], MAT_SKIN, (205, 170, 140), radii=[0.105, 0.095, 0.115]
    )
    return out


def cyclist(size: F64, shirt: F64, frame: F64, ridden_m: float) -> SolidList:
    """A rider on a bicycle; the legs turn with the cranks (``ridden_m``: distance so far)."""
    L, W, H = size
    b = -H / 2
    out = SolidList.new()
    inf = np.inf
    r = 0.34
    for x in (-0.53, 0.53):
        out.add([x, 0, b + r], [r, 0.025, r], MAT_TYRE, (30, 30, 32), radii=[r, inf, r])
    out.add([0.0, 0, b + 0.62], [0.42, 0.02, 0.025], MAT_METAL, frame, rot=rot_y(0.18))
    out.add([-0.18, 0, b + 0.7], [0.02, 0.02, 0.22], MAT_METAL, frame, rot=rot_y(-0.3))
    out.add([0.42, 0, b + 0.75], [0.02, 0.02, 0.25], MAT_METAL, frame, rot=rot_y(0.3))
    out.add([0.47, 0, b + 1.02], [0.02, 0.24, 0.02], MAT_METAL, METAL)
    crank = 2 * np.pi * ridden_m / (2 * np.pi * r * 2.6)
    seat = np.array([-0.22, 0.0, b + 0.98])
    for side, ph in ((-1.0, 0.0), (1.0, np.pi)):
        pedal = np.array([0.05 + 0.17 * np.cos(crank + ph), side * 0.1, b + 0.3 + 0.17 * np.sin(crank + ph)])
        hip = seat + [0.0, side * 0.1, 0.05]
        d = pedal - hip
        ang = np.arctan2(d[0], d[2])  # rot_y(ang) turns +z onto d
        leg = float(np.linalg.norm(d))
        out.add(
            (hip + pedal) / 2,
            [0.065, 0.06, leg / 2],
            MAT_CLOTH,
            TROUSERS,
            radii=[0.065, 0.06, inf],
            rot=rot_y(ang),
        )
    lean = 0.6
    torso = 0.3
    tc = seat + [0.0, 0.0, 0.06] + rot_y(lean) @ [0.0, 0.0, torso]
    out.add(tc, [0.11, 0.17, torso], MAT_CLOTH, shirt, radii=[0.14, 0.22, 1.6 * torso], rot=rot_y(lean))
    head = seat + [0.0, 0.0, 0.06] + rot_y(lean) @ [0.0, 0.0, 2 * torso + 0.13]
    head[2] = min(head[2], b + H - 0.12)
    out.add(head, [0.11, 0.1, 0.12], MAT_SKIN, (205, 170, 140), radii=[0.11, 0.1, 0.12])
    for side in (-1.0, 1.0):
        sh = seat + [0.0, side * 0.18, 0.06] + rot_y(lean) @ [0.0, 0.0, 2 * torso - 0.08]
        hand = np.array([0.47, side * 0.2, b + 1.02])
        d = hand - sh
        out.add(
            (sh + hand) / 2,
            [0.045, 0.045, np.linalg.norm(d) / 2],
            MAT_CLOTH,
            shirt,
            radii=[0.045, 0.045, inf],
            rot=rot_y(np.arctan2(d[0], d[2])),
        )
    return out


def street_light(height: float) -> SolidList:
    """A lamp post at the origin (ground level), its arm reaching +x."""
    out = SolidList.new()
    inf = np.inf
    out.add([0, 0, height / 2], [0.09, 0.09, height / 2], MAT_METAL, METAL, radii=[0.09, 0.09, inf])
    out.add([0.9, 0, height - 0.1], [0.9, 0.04, 0.04], MAT_METAL, METAL)
    out.add([1.7, 0, height - 0.2], [0.3, 0.14, 0.07], MAT_METAL, (90, 92, 96))
    return out


def sign(height: float, color: F64, round_: bool) -> SolidList:
    """A sign post; the plate faces +x."""
    out = SolidList.new()
    inf = np.inf
    out.add([0, 0, height / 2], [0.035, 0.035, height / 2], MAT_METAL, METAL, radii=[0.035, 0.035, inf])
    plate = [0.015, 0.32, 0.32]
    if round_:
        out.add([0.05, 0, height + 0.2], plate, MAT_SIGN, color, radii=[inf, 0.32, 0.32])
    else:
        out.add(
            [0.05, 0, height + 0.2], plate, MAT_SIGN, color, rot=rot_x(np.pi / 4) if color[2] < 100 else None
        )
    return out


def traffic_light(reach: float, lamp: int) -> SolidList:
    """A signal pole with a mast arm reaching -y by ``reach``; the lamp housing faces +x."""
    out = SolidList.new()
    inf = np.inf
    h = 5.8
    out.add([0, 0, h / 2], [0.13, 0.13, h / 2], MAT_METAL, METAL, radii=[0.13, 0.13, inf])
    out.add([0, -reach / 2, h - 0.15], [0.08, reach / 2, 0.08], MAT_METAL, METAL)
    out.add(
        [0.0, -reach + 0.3, h - 0.85], [0.17, 0.17, 0.5], MAT_SIGNAL, (40, 40, 36), params=(lamp, 0, 0, 0)
    )
    out.add(
        [0.0, -reach * 0.45, h - 0.85], [0.17, 0.17, 0.5], MAT_SIGNAL, (40, 40, 36), params=(lamp, 0, 0, 0)
    )
    return out


def tree(trunk_h: float, trunk_r: float, crown: F64, leaf: F64) -> SolidList:
    out = SolidList.new()
    inf = np.inf
    out.add(
        [0, 0, trunk_h / 2],
        [trunk_r, trunk_r, trunk_h / 2],
        MAT_BARK,
        (92, 70, 52),
        radii=[trunk_r, trunk_r, inf],
    )
    rx, ry, rz = crown
    out.add([0, 0, trunk_h + 0.75 * rz], [rx, ry, rz], MAT_FOLIAGE, leaf, radii=[rx, ry, rz])
    return out
