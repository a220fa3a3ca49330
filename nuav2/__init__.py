"""nuav2: Argoverse 2 sensor logs as nuScenes databases, re-rendered into any camera rig (MapGS)."""

import os as _os

__version__ = "0.1.0"

# torch and numba share one libgomp that reads this once, at torch's import: spin-waiting
# OpenMP threads made the splat kernels 3-4x slower on a loaded 2-core machine.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from nuav2.numba_cache import fallback_cache_dir as _fallback_cache_dir  # noqa: E402

_cache_dir = _fallback_cache_dir(_os.path.dirname(__file__), _os.environ)
if _cache_dir is not None:  # before numba is imported: it reads the variable once
    _os.environ["NUMBA_CACHE_DIR"] = _cache_dir

# Lets the unmodified devkit's NuScenesMap open our per-log "av2-xxx-xxxxxxxx" locations;
# patches are applied lazily, when the devkit is imported (see devkit_compat).
from nuav2 import devkit_compat  # noqa: E402,F401
