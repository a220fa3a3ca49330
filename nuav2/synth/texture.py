"""Procedural BEV ground texture (colour + lidar reflectivity) drawn from the road layout.

The ground is stored as a few axis-aligned raster layers in the local frame: one fine strip
along each road (where paint needs ~5 cm pixels) and a coarse square underneath for the
grass far away. Noise is a function of world position (hashed on the world pixel grid), so
two layers that overlap show the same asphalt grain and no seam. Each layer keeps a mip
pyramid; the renderer picks the level from each pixel's ground footprint, so distant paint
is filtered instead of aliased.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numba
import numpy as np
import shapely

from nuav2.geometry import F64
from nuav2.synth.road import DASH_LEN, DASH_PERIOD, DRIVABLE_HALF, SIDEWALK_W, RoadLayout

SHIFT = 4  # cv2 sub-pixel drawing bits
GRASS = np.array([84, 110, 56], np.float32)
CONCRETE = np.array([168, 164, 156], np.float32)
ASPHALT = np.array([82, 82, 86], np.float32)
CURB = np.array([198, 198, 192], np.float32)
WHITE = np.array([236, 236, 230], np.float32)
YELLOW = np.array([226, 182, 44], np.float32)
PAINT_W = 0.15
DOUBLE_GAP = 0.12  # centre offset of each line of a double line
CROSSWALK_STRIPE = (0.6, 1.2)  # stripe width, period (metres along the crosswalk)
SIDEWALK_JOINT = (1.5, 0.04)  # joint spacing and width (metres)
_GRASS = GRASS.astype(np.float64)
STRIP_HALF_W = 16.0  # fine strips cover |lateral| <= this around each road axis
FINE_LEVELS_MIN_PX = 8


def _hash01(ix: np.ndarray, iy: np.ndarray, salt: int) -> np.ndarray:
    """Deterministic uniform [0, 1) value per integer lattice point (murmur-style finaliser)."""
    h = (ix.astype(np.int64) * 0x8DA6B343 ^ iy.astype(np.int64) * 0xD8163841 ^ salt * 0xCB1AB31F) & 0xFFFFFFFF
    h = h.astype(np.uint64)
    h ^= h >> np.uint64(16)
    h = (h * np.uint64(0x45D9F3B)) & np.uint64(0xFFFFFFFF)
    h ^= h >> np.uint64(16)
    h = (h * np.uint64(0x45D9F3B)) & np.uint64(0xFFFFFFFF)
    h ^= h >> np.uint64(16)
    return (h & np.uint64(0xFFFFFF)).astype(np.float32) / np.float32(1 << 24)


@dataclass(frozen=True)
class TextureLayer:
    """A raster over [xmin, xmin + W res] x [ymin, ymin + H res]; rows grow with +y.

    Pixel (col, row) of level 0 has its centre at (xmin + (col + .5) res, ymin + (row + .5) res);
    level l is OpenCV's pyrDown of level l-1, whose pixel i is centred on pixel 2i of level l-1,
    so a level-0 coordinate u maps to u / 2**l (measured: a line at column p peaks at p / 2).
    """

    xmin: float
    ymin: float
    res: float
    levels: tuple[np.ndarray, ...]  # uint8 (H, W, 3) RGB pyramids
    reflectivity: np.ndarray  # uint8 (H, W)

    @property
    def shape(self) -> tuple[int, int]:
        return self.reflectivity.shape

    def contains(self, xy: F64) -> np.ndarray:
        h, w = self.shape
        return ((xy[:, 0] >= self.xmin) & (xy[:, 0] < self.xmin + w * self.res)
                & (xy[:, 1] >= self.ymin) & (xy[:, 1] < self.ymin + h * self.res))

    def pixel_coords(self, xy: F64) -> tuple[np.ndarray, np.ndarray]:
        return (xy[:, 0] - self.xmin) / self.res - 0.5, (xy[:, 1] - self.ymin) / self.res - 0.5

    def sample_reflectivity(self, xy: F64) -> np.ndarray:
        u0, v0 = self.pixel_coords(xy)
        h, w = self.shape
        c = np.clip(np.round(u0).astype(np.int64), 0, w - 1)
        r = np.clip(np.round(v0).astype(np.int64), 0, h - 1)
        return self.reflectivity[r, c]


@dataclass(frozen=True)
class GroundTexture:
    """Layers in priority order; points outside all of them are plain grass."""

    layers: tuple[TextureLayer, ...]

    @cached_property
    def packed(self) -> PackedTexture:
        return PackedTexture.pack(self.layers)

    def sample_rgb(self, xy: F64, footprint_m: np.ndarray) -> np.ndarray:
        """(N, 3) float32 trilinear (mip) colour; ``footprint_m`` is each sample's ground size."""
        xy = np.ascontiguousarray(xy, np.float64)
        fp = np.ascontiguousarray(footprint_m, np.float64)
        out = np.empty((len(xy), 3), np.float32)
        _sample_many(*self.packed.arrays(), xy, fp, out)
        return out

    def sample_reflectivity(self, xy: F64) -> np.ndarray:
        out = np.full(len(xy), MATERIALS[MAT["grass"]][3], np.uint8)
        todo = np.ones(len(xy), bool)
        for layer in self.layers:
            m = np.flatnonzero(todo & layer.contains(xy))
            if len(m):
                out[m] = layer.sample_reflectivity(xy[m])
                todo[m] = False
        return out


# Materials of the ground: colour, noise amplitude, lidar reflectivity (uint8 intensity scale).
MATERIALS = (
    ("grass", GRASS, 0.25, 18),
    ("concrete", CONCRETE, 0.08, 34),
    ("joint", CONCRETE * 0.8, 0.05, 30),
    ("asphalt", ASPHALT, 0.18, 9),
    ("curb", CURB, 0.05, 40),
    ("white_paint", WHITE, 0.04, 96),
    ("yellow_paint", YELLOW, 0.04, 80),
)
MAT = {name: i for i, (name, *_) in enumerate(MATERIALS)}
assert all(float(c.max()) * (1 + a) < 255 for _, c, a, _ in MATERIALS), "a material could overflow uint8"


@dataclass(frozen=True, eq=False)
class PackedTexture:
    """All pyramid levels of all layers in one flat buffer, for the numba samplers."""

    data: np.ndarray  # uint8 (total,)
    layer_box: np.ndarray  # (L, 5) float64: xmin, ymin, res, xmax, ymax
    n_levels: np.ndarray  # (L,) int64
    level_meta: np.ndarray  # (L, max levels, 3) int64: offset, height, width

    @staticmethod
    def pack(layers: tuple[TextureLayer, ...]) -> PackedTexture:
        n_max = max(len(layer.levels) for layer in layers)
        meta = np.zeros((len(layers), n_max, 3), np.int64)
        box = np.zeros((len(layers), 5))
        chunks, offset = [], 0
        for i, layer in enumerate(layers):
            h, w = layer.shape
            box[i] = (layer.xmin, layer.ymin, layer.res, layer.xmin + w * layer.res,
                      layer.ymin + h * layer.res)
            for lv, img in enumerate(layer.levels):
                meta[i, lv] = (offset, img.shape[0], img.shape[1])
                chunks.append(np.ascontiguousarray(img).reshape(-1))
                offset += img.size
        n_levels = np.array([len(x.levels) for x in layers], np.int64)
        return PackedTexture(np.concatenate(chunks), box, n_levels, meta)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return self.data, self.layer_box, self.n_levels, self.level_meta


@numba.njit(cache=True, inline="always")
def _add_bilinear(data, off, h, w, u, v, wgt, out, j):
    """out[j] += wgt * bilinear RGB of an (h, w, 3) level at continuous pixel coords, edge-clamped."""
    u = min(max(u, 0.0), w - 1.0)
    v = min(max(v, 0.0), h - 1.0)
    x0 = min(int(u), max(w - 2, 0))
    y0 = min(int(v), max(h - 2, 0))
    x1 = min(x0 + 1, w - 1)
    y1 = min(y0 + 1, h - 1)
    fx, fy = u - x0, v - y0
    w00, w01, w10, w11 = (1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy
    i00, i01 = off + (y0 * w + x0) * 3, off + (y0 * w + x1) * 3
    i10, i11 = off + (y1 * w + x0) * 3, off + (y1 * w + x1) * 3
    for c in range(3):
        top = w00 * data[i00 + c] + w01 * data[i01 + c]
        out[j, c] += wgt * (top + w10 * data[i10 + c] + w11 * data[i11 + c])


@numba.njit(cache=True)
def sample_texture_point(data, layer_box, n_levels, level_meta, x, y, footprint, out, j):
    """Write the trilinear colour of ground point (x, y) into out[j] (grass outside every layer)."""
    for li in range(layer_box.shape[0]):
        if not (layer_box[li, 0] <= x < layer_box[li, 3] and layer_box[li, 1] <= y < layer_box[li, 4]):
            continue
        res = layer_box[li, 2]
        u0 = (x - layer_box[li, 0]) / res - 0.5
        v0 = (y - layer_box[li, 1]) / res - 0.5
        n = n_levels[li]
        lvl = min(max(np.log2(max(footprint / res, 1e-6)), 0.0), n - 1.0)
        l0 = int(lvl)
        frac = lvl - l0
        for c in range(3):
            out[j, c] = 0.0
        for k in range(2):
            lv = l0 + k
            wgt = 1.0 - frac if k == 0 else frac
            if lv >= n or wgt <= 0.0:
                continue
            scale = 0.5 ** lv
            _add_bilinear(data, level_meta[li, lv, 0], level_meta[li, lv, 1], level_meta[li, lv, 2],
                          u0 * scale, v0 * scale, wgt, out, j)
        return
    for c in range(3):
        out[j, c] = _GRASS[c]


@numba.njit(cache=True)
def _sample_many(data, layer_box, n_levels, level_meta, xy, footprint, out):
    for j in range(xy.shape[0]):
        sample_texture_point(data, layer_box, n_levels, level_meta, xy[j, 0], xy[j, 1], footprint[j], out, j)


class _Canvas:
    """A material-id raster of one layer, drawn in local-frame metres with sub-pixel cv2 calls."""

    def __init__(self, xmin: float, ymin: float, width_m: float, height_m: float, res: float):
        self.xmin, self.ymin, self.res = xmin, ymin, res
        self.w, self.h = int(round(width_m / res)), int(round(height_m / res))
        self.mat = np.full((self.h, self.w), MAT["grass"], np.uint8)
        self.ix0, self.iy0 = int(round(xmin / res)), int(round(ymin / res))

    def px(self, xy: np.ndarray) -> np.ndarray:
        p = (np.asarray(xy, np.float64)[:, :2] - (self.xmin, self.ymin)) / self.res - 0.5
        return np.round(p * (1 << SHIFT)).astype(np.int32)

    def fill(self, polys: list[np.ndarray], material: str) -> None:
        cv2.fillPoly(self.mat, [self.px(p) for p in polys], MAT[material], lineType=cv2.LINE_8, shift=SHIFT)

    def line(self, xy: np.ndarray, width_m: float, material: str) -> None:
        thick = max(1, int(round(width_m / self.res)))
        cv2.polylines(self.mat, [self.px(xy)], False, MAT[material], thickness=thick, lineType=cv2.LINE_8,
                      shift=SHIFT)

    def noise(self, salt: int) -> np.ndarray:
        """World-anchored noise in [0, 1]: half per-pixel grain, half 1 m blotches."""
        ix = self.ix0 + np.arange(self.w)
        iy = self.iy0 + np.arange(self.h)
        fine = _hash01(ix[None, :], iy[:, None], salt)
        wl, hl = int(round(self.w * self.res)), int(round(self.h * self.res))
        jx = int(np.floor(self.xmin)) + np.arange(wl)
        jy = int(np.floor(self.ymin)) + np.arange(hl)
        coarse = cv2.resize(_hash01(jx[None, :], jy[:, None], salt + 1), (self.w, self.h),
                            interpolation=cv2.INTER_LINEAR)
        return 0.5 * fine + 0.5 * coarse

    def finish(self, salt: int) -> tuple[np.ndarray, np.ndarray]:
        """(RGB uint8, reflectivity uint8) from the material ids and the noise."""
        colors = np.stack([m[1] for m in MATERIALS]).astype(np.float32)
        amps = np.array([m[2] for m in MATERIALS], np.float32)
        refl = np.array([m[3] for m in MATERIALS], np.uint8)
        amp = amps[self.mat]
        gain = (1.0 - amp) + 2.0 * amp * self.noise(salt)
        rgb = colors[self.mat] * gain[..., None] + np.float32(0.5)  # < 255.5 by MATERIALS' construction
        return rgb.astype(np.uint8), refl[self.mat]


def _polygons(geom) -> list[np.ndarray]:
    return [np.asarray(g.exterior.coords) for g in getattr(geom, "geoms", [geom]) if not g.is_empty]


def _dash_pieces(xy: np.ndarray, dash: float, period: float) -> list[np.ndarray]:
    """Split a polyline into dashes of ``dash`` metres every ``period`` metres from its start."""
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    pieces = []
    for a in np.arange(0.0, s[-1], period):
        b = min(a + dash, s[-1])
        ts = np.concatenate([[a], s[(s > a) & (s < b)], [b]])
        pieces.append(np.column_stack([np.interp(ts, s, xy[:, 0]), np.interp(ts, s, xy[:, 1])]))
    return pieces


def _normals(xy: np.ndarray) -> np.ndarray:
    d = np.gradient(xy, axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    return np.column_stack([-d[:, 1], d[:, 0]])


def mark_lines(mark_type: str, xy: np.ndarray) -> list[tuple[np.ndarray, str]]:
    """Painted (polyline, material) pieces for an AV2 lane mark type along boundary ``xy``.

    A two-word type (DOUBLE_*, DASH_SOLID_*, SOLID_DASH_*) is two lines DOUBLE_GAP either side
    of the boundary; the first word is the left line (in the boundary's direction).
    """
    if mark_type in ("NONE", "UNKNOWN"):
        return []
    paint = "yellow_paint" if "YELLOW" in mark_type else "white_paint"
    words = mark_type.replace("DASHED", "DASH").split("_")[:-1]
    if words[0] == "DOUBLE":
        words = [words[1], words[1]]
    lines = [(xy, words[0])] if len(words) == 1 else [
        (xy + DOUBLE_GAP * _normals(xy), words[0]), (xy - DOUBLE_GAP * _normals(xy), words[1])]
    out = []
    for line, style in lines:
        pieces = _dash_pieces(line, DASH_LEN, DASH_PERIOD) if style == "DASH" else [line]
        out.extend((p, paint) for p in pieces)
    return out


def _crosswalk_stripes(edge1: np.ndarray, edge2: np.ndarray) -> list[np.ndarray]:
    width, period = CROSSWALK_STRIPE
    length = float(np.linalg.norm(edge1[1] - edge1[0]))
    u = (edge1[1] - edge1[0]) / max(length, 1e-9)
    polys = []
    for a in np.arange(period / 2 - width / 2, length - width / 2, period):
        p, q = a, min(a + width, length)
        polys.append(np.array([edge1[0] + p * u, edge1[0] + q * u, edge2[0] + q * u, edge2[0] + p * u]))
    return polys


def draw_layer(layout: RoadLayout, xmin: float, ymin: float, width_m: float, height_m: float, res: float,
               salt: int, road=None, walk=None) -> TextureLayer:
    """Rasterise grass, sidewalks, asphalt, curbs, lane paint, stop bars and crosswalks (``road`` and
    ``walk``: the drivable union and its sidewalk buffer, when the caller already has them)."""
    cv = _Canvas(xmin, ymin, width_m, height_m, res)
    road = layout.drivable_union() if road is None else road
    walk_area = road.buffer(SIDEWALK_W, quad_segs=16) if walk is None else walk
    cv.fill(_polygons(walk_area), "concrete")
    walk = cv.mat == MAT["concrete"]
    jx = (cv.xmin + (np.arange(cv.w) + 0.5) * res) % SIDEWALK_JOINT[0] < SIDEWALK_JOINT[1]
    jy = (cv.ymin + (np.arange(cv.h) + 0.5) * res) % SIDEWALK_JOINT[0] < SIDEWALK_JOINT[1]
    cv.mat[(jx[None, :] | jy[:, None]) & walk] = MAT["joint"]
    cv.fill([r for _, r in layout.drivable_areas], "asphalt")
    for ring in _polygons(road):
        cv.line(np.vstack([ring, ring[:1]]), 0.2, "curb")
    drawn: set[bytes] = set()
    for lane in layout.lanes:
        for xy, mark in ((lane.left, lane.left_mark), (lane.right, lane.right_mark)):
            key = np.round(xy, 3).tobytes() + mark.encode()
            if key in drawn:  # neighbours share boundaries; draw each once
                continue
            drawn.add(key)
            for piece, paint in mark_lines(mark, xy):
                cv.line(piece, PAINT_W, paint)
    cv.fill(list(layout.stop_bars), "white_paint")
    for cw in layout.crosswalks:
        cv.fill(_crosswalk_stripes(cw.edge1, cw.edge2), "white_paint")
    rgb, refl = cv.finish(salt)
    levels = [rgb]
    while min(levels[-1].shape[:2]) >= 2 * FINE_LEVELS_MIN_PX:
        levels.append(cv2.pyrDown(levels[-1]))
    return TextureLayer(xmin, ymin, res, tuple(levels), refl)


def build_ground_texture(layout: RoadLayout, reach_m: float, res: float, salt: int) -> GroundTexture:
    """Fine strips along both roads out to ``reach_m`` and a 4x coarser square under everything."""
    reach = float(np.ceil(reach_m))
    half_w = STRIP_HALF_W
    assert half_w > DRIVABLE_HALF + SIDEWALK_W
    ew = draw_layer(layout, -reach, -half_w, 2 * reach, 2 * half_w, res, salt)
    ns = draw_layer(layout, -half_w, -reach, 2 * half_w, 2 * reach, res, salt)
    coarse_res = min(0.5, 4 * res)
    big = float(np.ceil(reach + 40.0))
    bg = draw_layer(layout, -big, -big, 2 * big, 2 * big, coarse_res, salt)
    return GroundTexture((ew, ns, bg))


TILE_M = 32.0


def build_tiled_texture(layout: RoadLayout, res: float, salt: int) -> GroundTexture:
    """Fine square tiles wherever roads and sidewalks are (any layout), a coarse layer under all.

    Noise is world-anchored and tiles share the grid, so neighbouring tiles join without a seam."""
    road = layout.drivable_union()
    walk = road.buffer(SIDEWALK_W, quad_segs=16)
    near = walk.buffer(3.0)
    x0, y0, x1, y1 = near.bounds
    layers = []
    for ty in np.arange(np.floor(y0 / TILE_M) * TILE_M, y1, TILE_M):
        for tx in np.arange(np.floor(x0 / TILE_M) * TILE_M, x1, TILE_M):
            if near.intersects(shapely.box(tx, ty, tx + TILE_M, ty + TILE_M)):
                layers.append(draw_layer(layout, float(tx), float(ty), TILE_M, TILE_M, res, salt, road, walk))
    coarse_res = min(0.5, 4 * res)
    big = float(np.ceil(max(abs(x0), abs(x1), abs(y0), abs(y1)) + 40.0))
    layers.append(draw_layer(layout, -big, -big, 2 * big, 2 * big, coarse_res, salt, road, walk))
    return GroundTexture(tuple(layers))
