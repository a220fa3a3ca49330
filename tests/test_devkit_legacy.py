"""MapTR's older stack (nuscenes-devkit 1.1.11, shapely 1.8) opens a converted database through
``nuav2/devkit_hook`` alone: no ``import nuav2`` there, and MapTR's scripts unchanged.

Needs the small venv that ``.ci/devkit_legacy_venv`` builds (CI builds it before the suite); without it the
test skips and says so. ``NUAV2_LEGACY_PYTHON`` points at another interpreter with that stack.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

pytest_plugins = ["test_writer_support"]  # native_db: the real fixture log converted in native mode

REPO = Path(__file__).resolve().parent.parent
HOOK_DIR = REPO / "nuav2" / "devkit_hook"
VERSION = "v1.0-nuav2"

# Runs in the legacy interpreter with PYTHONPATH=nuav2/devkit_hook (sitecustomize installs the hook).
SCRIPT = r"""
import importlib.util, json, sys
import matplotlib
matplotlib.use("Agg")
from importlib.metadata import version as dist_version
import shapely
assert importlib.util.find_spec("nuav2") is None, "nuav2 must not be importable in the legacy stack"
assert "nuav2_devkit_locations" in sys.modules, "sitecustomize did not install the registration"
from nuscenes.nuscenes import NuScenes
from nuscenes.map_expansion.map_api import NuScenesMap, NuScenesMapExplorer
from nuscenes.map_expansion.bitmap import BitMap

dataroot, version = sys.argv[1], sys.argv[2]
nusc = NuScenes(version=version, dataroot=dataroot, verbose=False)
sample = nusc.sample[0]
log = nusc.get("log", nusc.get("scene", sample["scene_token"])["log_token"])
nmap = NuScenesMap(dataroot=dataroot, map_name=log["location"])
pose = nusc.get("ego_pose", nusc.get("sample_data", sample["data"]["LIDAR_TOP"])["ego_pose_token"])
x, y = pose["translation"][:2]
explorer = NuScenesMapExplorer(nmap)
patch_box, angle = (x, y, 60.0, 30.0), 0.0
# What MapTR's GT extraction calls.
dividers = explorer._get_layer_line(patch_box, angle, "lane_divider")
crossings = explorer._get_layer_polygon(patch_box, angle, "ped_crossing")
roads = explorer._get_layer_polygon(patch_box, angle, "road_segment")
lanes = nmap.get_records_in_patch((x - 30, y - 30, x + 30, y + 30), ["lane", "lane_connector"])
centerlines = nmap.discretize_lanes(lanes["lane"] + lanes["lane_connector"], 0.5)
mask = nmap.get_map_mask(None, 0.0, ["drivable_area"], canvas_size=(200, 200))
prior = BitMap(dataroot, log["location"], "semantic_prior").image
print(json.dumps({
    "devkit": dist_version("nuscenes-devkit"), "shapely": shapely.__version__,
    "location": log["location"], "on_road": nmap.layers_on_point(x, y)["drivable_area"] != "",
    "dividers": len(dividers), "crossings": len(crossings), "roads": len(roads),
    "centerlines": len(centerlines), "mask_px": int(mask.sum()), "prior_shape": list(prior.shape),
}))
"""


def legacy_python() -> Path:
    given = os.environ.get("NUAV2_LEGACY_PYTHON")
    path = Path(given) if given else REPO / ".venv-devkit-1.1.11" / "bin" / "python"
    if not path.exists():
        if given:
            pytest.fail(f"NUAV2_LEGACY_PYTHON={given} does not exist")
        pytest.skip(f"{path} not built: run .ci/devkit_legacy_venv (CI does, before the suite)")
    return path


def test_legacy_devkit_opens_nuav2_maps_through_the_hook_alone(native_db: Path):
    python = legacy_python()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PYTHONPATH"] = str(HOOK_DIR)
    run = subprocess.run([str(python), "-c", SCRIPT, str(native_db), VERSION], env=env, cwd=native_db,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["devkit"] == "1.1.11" and out["shapely"].startswith("1.8"), out
    assert out["location"].startswith("av2-pit-") and out["on_road"]
    assert out["dividers"] > 0 and out["crossings"] > 0 and out["roads"] > 0 and out["centerlines"] > 0
    assert out["mask_px"] > 0 and len(out["prior_shape"]) == 2 and min(out["prior_shape"]) > 100


def test_without_the_hook_the_legacy_devkit_rejects_the_location(native_db: Path):
    """The control: the same stack without the hook fails as the issue reports ("Unknown map name")."""
    python = legacy_python()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    code = ("import matplotlib; matplotlib.use('Agg')\n"
            "from nuscenes.map_expansion.map_api import NuScenesMap\n"
            f"NuScenesMap(dataroot={str(native_db)!r}, map_name='av2-pit-adcf7d18')\n")
    run = subprocess.run([str(python), "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode != 0 and "Unknown map name" in run.stderr
