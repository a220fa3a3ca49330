"""nuav2: Argoverse 2 sensor logs as nuScenes databases, re-rendered into any camera rig (MapGS)."""

__version__ = "0.1.0"

# Lets the unmodified devkit's NuScenesMap open our per-log "av2-xxx-xxxxxxxx" locations;
# patches are applied lazily, when the devkit is imported (see devkit_compat).
from nuav2 import devkit_compat  # noqa: E402,F401
