"""Make the unmodified nuscenes-devkit accept nuAV2 map locations (``av2-<city>-<log id prefix>``).

The devkit hard-codes its four map names in three places, and its renderer predates shapely 2.
Importing ``nuav2`` installs these patches, in memory only (the devkit on disk is untouched):

1. ``map_api.locations`` becomes a list that also *contains* any name matching
   ``map_frame.LOCATION_RE``; iterating it still yields the four nuScenes names only, so code
   looping over all nuScenes maps is unchanged. This admits ``NuScenesMap(dataroot, map_name=...)``.
2. ``NuScenesMapExplorer.get_map_mask`` takes an av2 location's map size from its own
   ``canvas_edge`` (the devkit's table of sizes raises "Invalid map!" for any other name).
3. ``BitMap(dataroot, location, 'semantic_prior')`` finds an av2 location's mask at
   ``map_mask.semantic_prior_filename(location)`` (the devkit looks the md5 up in a fixed dict).
4. shapely 2 compatibility, which the devkit also needs for its own maps: ``descartes``' polygon
   path (behind every polygon rendering) and ``mask_for_lines`` on multi-part lines.

Importing the devkit costs ~2.5 s, so nothing is imported eagerly: the patches are applied by a
post-import hook the moment ``nuscenes.map_expansion.map_api`` / ``bitmap`` or ``descartes.patch``
is first imported, or immediately if it already is.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import os
import sys
from collections.abc import Callable

import numpy as np

from nuav2.nuscenes_db.map_frame import LOCATION_RE
from nuav2.nuscenes_db.map_mask import semantic_prior_filename

_PATCHED = "_nuav2_patched"


def is_av2_location(name: object) -> bool:
    return isinstance(name, str) and LOCATION_RE.match(name) is not None


class LocationList(list):
    """The devkit's location list, which also contains every nuAV2 location name."""

    def __contains__(self, name: object) -> bool:
        return list.__contains__(self, name) or is_av2_location(name)


def _patch_map_api(map_api) -> None:
    if not isinstance(map_api.locations, LocationList):
        map_api.locations = LocationList(map_api.locations)
    static_layers = sys.modules.get("nuscenes.prediction.input_representation.static_layers")
    if static_layers is not None:
        static_layers.locations = map_api.locations

    explorer = map_api.NuScenesMapExplorer
    if getattr(explorer.get_map_mask, _PATCHED, False):
        return
    devkit_get_map_mask = explorer.get_map_mask

    def get_map_mask(self, patch_box, patch_angle, layer_names=None, canvas_size=(100, 100)):
        if not is_av2_location(self.map_api.map_name):
            return devkit_get_map_mask(self, patch_box, patch_angle, layer_names, canvas_size)
        # Same steps as the devkit's, with the map size read from canvas_edge.
        width, height = self.map_api.canvas_edge
        if patch_box is None:
            patch_box = [width / 2, height / 2, height, width]
        if layer_names is None:
            layer_names = self.map_api.non_geometric_layers
        if canvas_size is None:
            canvas_size = tuple(np.round(np.array((patch_box[2], patch_box[3])) * 10).astype(np.int32))
        map_geom = self.get_map_geom(patch_box, patch_angle, layer_names)
        local_box = (0.0, 0.0, patch_box[2], patch_box[3])
        return self.map_geom_to_mask(map_geom, local_box, canvas_size)

    setattr(get_map_mask, _PATCHED, True)
    explorer.get_map_mask = get_map_mask

    devkit_mask_for_lines = explorer.mask_for_lines

    def mask_for_lines(lines, mask):
        if lines.geom_type in ("MultiLineString", "GeometryCollection"):
            for part in lines.geoms:
                if part.geom_type == "LineString" and not part.is_empty:
                    mask = devkit_mask_for_lines(part, mask)
            return mask
        return devkit_mask_for_lines(lines, mask)

    explorer.mask_for_lines = staticmethod(mask_for_lines)


def _patch_bitmap(bitmap) -> None:
    cls = bitmap.BitMap
    if getattr(cls.load_bitmap, _PATCHED, False):
        return
    devkit_load_bitmap = cls.load_bitmap

    def load_bitmap(self) -> np.ndarray:
        if self.layer_name != "semantic_prior" or not is_av2_location(self.map_name):
            return devkit_load_bitmap(self)
        path = os.path.join(self.dataroot, semantic_prior_filename(self.map_name))
        if not os.path.exists(path):
            raise Exception(f"Error: Cannot find semantic_prior {path}! Was the nuAV2 map written?")
        image = np.array(bitmap.Image.open(path))
        return image.max() - image  # the devkit shows the prior inverted

    setattr(load_bitmap, _PATCHED, True)
    cls.load_bitmap = load_bitmap


def _patch_descartes(patch_module) -> None:
    devkit_polygon_path = patch_module.PolygonPath
    if getattr(devkit_polygon_path, _PATCHED, False):
        return
    from matplotlib.path import Path as MplPath

    def polygon_path(polygon):
        geom_type = getattr(polygon, "geom_type", None)
        if geom_type not in ("Polygon", "MultiPolygon"):
            return devkit_polygon_path(polygon)  # GeoJSON-like input: the original code works
        parts = [polygon] if geom_type == "Polygon" else list(polygon.geoms)
        vertices, codes = [], []
        for part in parts:
            for ring in [part.exterior, *part.interiors]:
                xy = np.asarray(ring.coords, dtype=np.float64)[:, :2]
                if len(xy) == 0:
                    continue
                c = np.full(len(xy), MplPath.LINETO, dtype=MplPath.code_type)
                c[0] = MplPath.MOVETO
                vertices.append(xy)
                codes.append(c)
        if not vertices:
            return MplPath(np.zeros((0, 2)))
        return MplPath(np.concatenate(vertices), np.concatenate(codes))

    setattr(polygon_path, _PATCHED, True)
    patch_module.PolygonPath = polygon_path


_PATCHERS: dict[str, Callable] = {
    "nuscenes.map_expansion.map_api": _patch_map_api,
    "nuscenes.map_expansion.bitmap": _patch_bitmap,
    "descartes.patch": _patch_descartes,
}


class _PatchingLoader(importlib.abc.Loader):
    """Delegates to the real loader, then applies the module's patch."""

    def __init__(self, inner, patcher: Callable) -> None:
        self._inner, self._patcher = inner, patcher

    def create_module(self, spec):
        return self._inner.create_module(spec)

    def exec_module(self, module) -> None:
        module.__loader__ = self._inner
        module.__spec__.loader = self._inner
        self._inner.exec_module(module)
        self._patcher(module)


class _PostImportHook(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path, target=None):
        patcher = _PATCHERS.get(fullname)
        if patcher is None:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(fullname, path, target)
            if spec is not None:
                if spec.loader is not None and hasattr(spec.loader, "exec_module"):
                    spec.loader = _PatchingLoader(spec.loader, patcher)
                return spec
        return None


def install() -> None:
    """Patch already-imported devkit modules now and the others when they are imported (idempotent)."""
    if not any(isinstance(f, _PostImportHook) for f in sys.meta_path):
        sys.meta_path.insert(0, _PostImportHook())
    for name, patcher in _PATCHERS.items():
        module = sys.modules.get(name)
        if module is not None:
            patcher(module)


install()
