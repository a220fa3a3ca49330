"""Let an unmodified nuscenes-devkit open nuAV2 map locations (``av2-<city>-<8 hex of the log id>``).

Standalone on purpose: it imports only the standard library, numpy and the devkit (and what the
devkit itself imports), so it also works in MapTR's own environment (nuscenes-devkit 1.1.x,
shapely 1.8, Python 3.7+) where ``import nuav2`` cannot. In that environment, either

* put this directory on the path: ``PYTHONPATH=<this directory> python tools/...``; the
  ``sitecustomize.py`` beside this file installs the registration at start-up, so MapTR's own
  scripts run unchanged (``nuav2 infos`` prints the directory), or
* ``import nuav2_devkit_locations`` before the devkit is used.

In nuav2's environment ``import nuav2`` installs it (``nuav2/devkit_compat.py`` loads this file).

The devkit hard-codes its four map names in three places, and its renderer predates shapely 2.
The registration patches, in memory only (the devkit on disk is untouched):

1. ``map_api.locations`` becomes a list that also *contains* any name matching
   ``LOCATION_RE``; iterating it still yields the four nuScenes names, so code looping over
   all nuScenes maps is unchanged. This admits ``NuScenesMap(dataroot, map_name=...)``.
2. ``NuScenesMapExplorer.get_map_mask`` takes an av2 location's map size from its own
   ``canvas_edge`` (the devkit's table of sizes raises "Invalid map!" for any other name).
3. ``BitMap(dataroot, location, 'semantic_prior')`` finds an av2 location's mask at
   ``maps/<md5(location)>.png`` (the devkit looks the md5 up in a fixed dict).
4. shapely 2 compatibility (a no-op in effect on shapely 1.8), which the devkit also needs for
   its own maps: ``descartes``' polygon path and ``mask_for_lines`` on multi-part lines.
5. The prediction rasterizer's ``static_layers.load_all_maps`` loads the four nuScenes maps by
   name; on a dataroot whose ``log`` table names nuAV2 locations it returns a mapping that opens
   a location's map when the rasterizer first asks for it (a few most recent kept open: a full
   conversion has one location per log); iterating it opens each in turn. The prediction metric
   ``OffRoadRate``, which renders every location's drivable mask when it is built, makes a nuAV2
   location's mask when a prediction first needs it.
6. ``PredictHelper``'s past / future stops at 2 annotations a second, nuScenes' keyframe rate; in a
   nuAV2 scene keyed faster (every 10 Hz sweep by default) the cap follows the scene's sample rate.

Importing the devkit costs seconds, so nothing is imported eagerly: a post-import hook applies
each patch when its module (``nuscenes.map_expansion.map_api``, ``bitmap``, ``descartes.patch``,
``nuscenes.prediction.helper``, ``nuscenes.eval.prediction.metrics``, ...) is first imported, or at
once if it already is. Installing twice is harmless.
"""

import collections
import os
import re
import sys

LOCATION_RE = re.compile(r"^av2-[a-z]{3}-[0-9a-f]{8}$")  # = nuav2.nuscenes_db.map_frame.LOCATION_RE
_PATCHED = "_nuav2_patched"


def is_av2_location(name):
    return isinstance(name, str) and LOCATION_RE.match(name) is not None


def semantic_prior_filename(location):
    """Dataroot-relative mask PNG of a location (= nuav2.nuscenes_db.map_mask.semantic_prior_filename)."""
    import hashlib  # here, not at start-up (the .pth hook loads this file in every interpreter)

    return "maps/" + hashlib.md5(location.encode()).hexdigest() + ".png"


class LocationList(list):
    """The devkit's location list, which also contains every nuAV2 location name."""

    def __contains__(self, name):
        return list.__contains__(self, name) or is_av2_location(name)


def _patch_map_api(map_api):
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
        import numpy as np

        # The devkit's steps, with the map size read from canvas_edge ([width, height]).
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


class LazyMaps(dict):
    """{location: value} that makes a location's value (its NuScenesMap, its drivable mask) on first
    use and keeps the ``keep`` latest; iterating it walks every location, making each in turn."""

    def __init__(self, names, make, keep=8):
        super().__init__()
        self.names, self._make, self.keep = list(names), make, keep
        self._order = collections.deque()

    def __missing__(self, name):
        if name not in self.names:
            raise KeyError(name)
        while len(self._order) >= self.keep:
            dict.pop(self, self._order.popleft(), None)
        value = self._make(name)
        self[name] = value
        self._order.append(name)
        return value

    def __contains__(self, name):
        return name in self.names

    def __iter__(self):
        return iter(self.names)

    def __len__(self):
        return len(self.names)

    def keys(self):
        return list(self.names)

    def values(self):
        return (self[name] for name in self.names)

    def items(self):
        return ((name, self[name]) for name in self.names)

    def get(self, name, default=None):
        return self[name] if name in self.names else default


def _patch_static_layers(static_layers):
    devkit_load_all_maps = static_layers.load_all_maps
    if getattr(devkit_load_all_maps, _PATCHED, False):
        return

    def load_all_maps(helper, verbose=False):
        names = sorted(set(log["location"] for log in helper.data.log))
        if not any(is_av2_location(n) for n in names):
            return devkit_load_all_maps(helper, verbose)
        dataroot = helper.data.dataroot
        return LazyMaps(names, lambda name: static_layers.NuScenesMap(dataroot, map_name=name))

    setattr(load_all_maps, _PATCHED, True)
    static_layers.load_all_maps = load_all_maps


def _patch_prediction_metrics(metrics):
    """OffRoadRate renders every location's whole drivable mask (10 px/m) when it is built: 4 masks
    for nuScenes, one per log for nuAV2; for nuAV2 each mask is made when a prediction first asks."""
    cls = metrics.OffRoadRate
    devkit_load = cls.load_drivable_area_masks
    if getattr(devkit_load, _PATCHED, False):
        return

    def load_drivable_area_masks(helper):
        # the module's own load_all_maps, patched (metrics holds the devkit's if it was imported first)
        maps = sys.modules["nuscenes.prediction.input_representation.static_layers"].load_all_maps(helper)
        if not isinstance(maps, LazyMaps):
            return devkit_load(helper)

        def drivable_mask(name):
            return maps[name].get_map_mask(patch_box=None, patch_angle=0, layer_names=["drivable_area"],
                                           canvas_size=None)[0]

        return LazyMaps(maps.names, drivable_mask, keep=maps.keep)

    setattr(load_drivable_area_masks, _PATCHED, True)
    cls.load_drivable_area_masks = staticmethod(load_drivable_area_masks)


def _patch_bitmap(bitmap):
    cls = bitmap.BitMap
    if getattr(cls.load_bitmap, _PATCHED, False):
        return
    devkit_load_bitmap = cls.load_bitmap

    def load_bitmap(self):
        if self.layer_name != "semantic_prior" or not is_av2_location(self.map_name):
            return devkit_load_bitmap(self)
        import numpy as np

        path = os.path.join(self.dataroot, semantic_prior_filename(self.map_name))
        if not os.path.exists(path):
            raise Exception(f"Error: Cannot find semantic_prior {path}! Was the nuAV2 map written?")
        image = np.array(bitmap.Image.open(path))
        return image.max() - image  # the devkit shows the prior inverted

    setattr(load_bitmap, _PATCHED, True)
    cls.load_bitmap = load_bitmap


def _patch_descartes(patch_module):
    devkit_polygon_path = patch_module.PolygonPath
    if getattr(devkit_polygon_path, _PATCHED, False):
        return

    def polygon_path(polygon):
        geom_type = getattr(polygon, "geom_type", None)
        if geom_type not in ("Polygon", "MultiPolygon"):
            return devkit_polygon_path(polygon)  # GeoJSON-like input: the original code works
        import numpy as np
        from matplotlib.path import Path as MplPath

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


def _keyframe_rate(helper, sample_token):
    """Samples per second of a nuAV2 sample's scene (None for a nuScenes scene, or one sample)."""
    cache = helper.__dict__.setdefault("_nuav2_keyframe_rates", {})
    scene_token = helper.data.get("sample", sample_token)["scene_token"]
    if scene_token not in cache:
        scene = helper.data.get("scene", scene_token)
        rate = None
        location = helper.data.get("log", scene["log_token"])["location"]
        if is_av2_location(location) and scene["nbr_samples"] > 1:
            first = helper.data.get("sample", scene["first_sample_token"])["timestamp"]
            last = helper.data.get("sample", scene["last_sample_token"])["timestamp"]
            if last > first:
                rate = (scene["nbr_samples"] - 1) / ((last - first) / 1e6)
        cache[scene_token] = rate
    return cache[scene_token]


def follows_scene_rate(rate):
    """Whether a scene sampled at ``rate`` Hz (None: not nuAV2, or one sample) needs the rate-following
    walk: halfway between 2 Hz and 2.5 Hz, so that 2 Hz with jitter keeps the devkit's code and 2.5 Hz,
    which measures 2.49994 or 2.50008 by its sweeps' timing, never does."""
    return rate is not None and rate >= 2.25


def _patch_prediction_helper(helper_module):
    """PredictHelper caps a past / future at 2 annotations a second (nuScenes' keyframe rate), so on a
    nuAV2 database keyed at every 10 Hz sweep ``seconds=1`` gave 0.2 s; here the cap follows the scene's
    own sample rate (nuScenes scenes, and nuAV2 ones at 2 Hz or less, keep the devkit's code)."""
    cls = helper_module.PredictHelper
    devkit_iterate = cls._iterate
    if getattr(devkit_iterate, _PATCHED, False):
        return

    def _iterate(self, starting_annotation, seconds, direction):
        rate = _keyframe_rate(self, starting_annotation["sample_token"]) if seconds > 0 else None
        if not follows_scene_rate(rate):
            return devkit_iterate(self, starting_annotation, seconds, direction)
        # The devkit's tolerance (BUFFER, 0.15 s) is under half its 0.5 s sample period, and its count cap
        # keeps the sample after ``seconds`` out; at the scene's rate half a period does both.
        limit = seconds + min(helper_module.BUFFER, 0.5 / rate)
        start_us = self._timestamp_for_sample(starting_annotation["sample_token"])
        found, record = [], starting_annotation
        while record[direction]:
            record = self.data.get("sample_annotation", record[direction])
            t_us = self._timestamp_for_sample(record["sample_token"])
            if self._absolute_time_diff(t_us, start_us) >= limit:
                break
            found.append(record)
        return found

    setattr(_iterate, _PATCHED, True)
    cls._iterate = _iterate


PATCHERS = {
    "nuscenes.map_expansion.map_api": _patch_map_api,
    "nuscenes.map_expansion.bitmap": _patch_bitmap,
    "descartes.patch": _patch_descartes,
    "nuscenes.prediction.input_representation.static_layers": _patch_static_layers,
    "nuscenes.prediction.helper": _patch_prediction_helper,
    "nuscenes.eval.prediction.metrics": _patch_prediction_metrics,
}


class _PatchingLoader:
    """Delegates to the real loader, then applies the module's patch (a plain class, as the import
    system only calls ``create_module`` / ``exec_module``: importing ``importlib.abc`` cost ~20 ms
    at every interpreter start-up where the .pth hook is installed)."""

    def __init__(self, inner, patcher):
        self._inner, self._patcher = inner, patcher

    def create_module(self, spec):
        return self._inner.create_module(spec)

    def exec_module(self, module):
        module.__loader__ = self._inner
        module.__spec__.loader = self._inner
        self._inner.exec_module(module)
        self._patcher(module)


class PostImportHook:
    """Finds the devkit modules through the other finders and wraps their loader (a meta path finder
    needs only ``find_spec``)."""

    _nuav2_hook = True  # marks every copy of this hook, however this file was loaded

    def find_spec(self, fullname, path, target=None):
        patcher = PATCHERS.get(fullname)
        if patcher is None:
            return None
        for finder in sys.meta_path:
            if getattr(finder, "_nuav2_hook", False) or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(fullname, path, target)
            if spec is not None:
                if spec.loader is not None and hasattr(spec.loader, "exec_module"):
                    spec.loader = _PatchingLoader(spec.loader, patcher)
                return spec
        return None


def install():
    """Patch already-imported devkit modules now and the others when they are imported (idempotent)."""
    if not any(getattr(f, "_nuav2_hook", False) for f in sys.meta_path):
        sys.meta_path.insert(0, PostImportHook())
    for name, patcher in PATCHERS.items():
        module = sys.modules.get(name)
        if module is not None:
            patcher(module)


install()
