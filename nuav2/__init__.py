"""nuav2: Argoverse 2 sensor logs as nuScenes databases, re-rendered into any camera rig (MapGS)."""

__version__ = "0.1.0"
