"""Buildings of a synthetic street: facades along both sides of every road, their styling, and
solids set onto sloped terrain."""

from __future__ import annotations

import numpy as np
from shapely.geometry import Polygon

from nuav2.geometry import F64
from nuav2.synth import polyline as pl
from nuav2.synth.boxes import KIND_BUILDING, BoxSet
from nuav2.synth.layouts import SIDEWALK_W, StreetPlan
from nuav2.synth.legacy import FACADE_COLORS
from nuav2.synth.materials import MAT_FACADE, REFLECTIVITY
from nuav2.synth.road import RoadLayout
from nuav2.synth.shapes import rot_z
from nuav2.synth.terrain import Terrain


def footprint(c: F64, yaw: float, lx: float, ly: float) -> Polygon:
    """The ground rectangle of a box (centre xy, yaw, length, width)."""
    R = rot_z(yaw)[:2, :2]
    corners = np.array([[-lx, -ly], [lx, -ly], [lx, ly], [-lx, ly]]) / 2 @ R.T + c
    return Polygon(corners)


def place_buildings(plan: StreetPlan, layout: RoadLayout, rng: np.random.Generator) -> BoxSet:
    """Facades along both sides of every road, off the roads and sidewalks, not overlapping."""
    keep_out = layout.drivable_union().buffer(SIDEWALK_W + 0.8)
    centers, yaws, sizes, colors = [], [], [], []
    taken: list[Polygon] = []
    for road in plan.roads:
        L = road.length
        for side, half in ((1.0, road.left_half), (-1.0, road.right_half)):
            s = rng.uniform(3.0, 6.0)
            while s < L - 4.0:
                length, depth = rng.uniform(8.0, 20.0), rng.uniform(8.0, 14.0)
                height = rng.uniform(5.0, 22.0)
                near = half + SIDEWALK_W + 1.0 + rng.uniform(0.0, 2.0)
                color = FACADE_COLORS[rng.integers(len(FACADE_COLORS))] * rng.uniform(0.85, 1.1)
                gap = rng.uniform() < 0.12
                s_mid = s + length / 2
                s += length + rng.uniform(1.0, 5.0)
                if gap or s_mid > L:
                    continue
                p = pl.at(road.centre, np.array([s_mid]))[0]
                yaw = float(pl.heading_at(road.centre, np.array([s_mid]))[0])
                n = np.array([-np.sin(yaw), np.cos(yaw)])
                c = p + side * (near + depth / 2) * n
                foot = footprint(c, yaw, length, depth)
                if foot.intersects(keep_out) or any(foot.intersects(t) for t in taken):
                    continue
                taken.append(foot.buffer(0.5))
                centers.append([c[0], c[1], height / 2])
                yaws.append(yaw)
                sizes.append([length, depth, height])
                colors.append(np.clip(color, 0, 255))
    n = len(centers)
    return BoxSet(
        np.array(centers).reshape(n, 3),
        np.array(yaws),
        np.array(sizes).reshape(n, 3),
        np.array(colors, np.float32).reshape(n, 3),
        np.full(n, KIND_BUILDING, np.int8),
        np.full(n, REFLECTIVITY[KIND_BUILDING], np.uint8),
    )


def style_facades(buildings: BoxSet, rng: np.random.Generator) -> BoxSet:
    """Facades that vary: floor height, window pitch and width, storefronts, tint, roof shade."""
    n = len(buildings)
    params = np.column_stack(
        [
            rng.uniform(2.9, 4.2, n),
            rng.uniform(1.8, 4.0, n),
            rng.uniform(0.35, 0.8, n),
            rng.uniform(0.8, 1.15, n),
        ]
    )
    tint = rng.uniform(0.85, 1.12, (n, 3)).astype(np.float32)
    color = np.clip(buildings.color * tint, 0, 255).astype(np.float32)
    return BoxSet(
        buildings.center,
        buildings.yaw,
        buildings.size,
        color,
        np.full(n, MAT_FACADE, np.int8),
        buildings.reflectivity,
        buildings.rot,
        buildings.quad,
        buildings.owner,
        params,
    )


def settle(solids: BoxSet, terrain: Terrain, sink_m: float) -> BoxSet:
    """Solids standing on z = 0 moved onto the terrain: lifted by the lowest ground under their
    footprint and, with ``sink_m``, extended that far down so no gap shows on a slope."""
    if terrain.flat or len(solids) == 0:
        return solids
    corners = solids.corners()[:, :, :2]
    h = terrain.height(corners.reshape(-1, 2)).reshape(-1, 8).min(1)
    center, size = solids.center.copy(), solids.size.copy()
    if sink_m > 0:
        center[:, 2] += h - sink_m / 2
        size[:, 2] += sink_m
    else:
        center[:, 2] += h
    return BoxSet(
        center,
        solids.yaw,
        size,
        solids.color,
        solids.kind,
        solids.reflectivity,
        solids.rot,
        solids.quad,
        solids.owner,
        solids.params,
    )
