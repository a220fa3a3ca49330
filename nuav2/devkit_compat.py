"""Make the unmodified nuscenes-devkit accept nuAV2 map locations (``av2-<city>-<log id prefix>``).

The registration itself lives in ``nuav2/devkit_hook/nuav2_devkit_locations.py``, a standalone
file that imports nothing from nuav2, so that MapTR's older environment (nuscenes-devkit 1.1.x,
shapely 1.8), where nuav2 cannot be installed, uses the very same code through
``PYTHONPATH=nuav2/devkit_hook``. ``import nuav2`` loads that file under its own module name
(so an explicit ``import nuav2_devkit_locations`` finds the same module) and installs it: the
patches are applied lazily, when the devkit is imported (see that file for what they do).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

HOOK_DIR = Path(__file__).resolve().parent / "devkit_hook"
MODULE_NAME = "nuav2_devkit_locations"


def _load():
    module = sys.modules.get(MODULE_NAME)
    if module is None:
        spec = importlib.util.spec_from_file_location(MODULE_NAME, HOOK_DIR / f"{MODULE_NAME}.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[MODULE_NAME] = module
        spec.loader.exec_module(module)  # installs the hook
    return module


_registration = _load()
is_av2_location = _registration.is_av2_location
LocationList = _registration.LocationList
install = _registration.install
install()
