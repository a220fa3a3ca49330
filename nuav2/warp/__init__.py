"""Warp mode: target-rig camera images from the log's own images via depth proxies, no reconstruction.

``WarpRenderer(scene)`` is the writer's render function; ``warp_image_source(scene)`` wraps it as
an ImageSource. See docs/modes.md for when to use it instead of render (splat) mode.
"""

from nuav2.warp.backward_warp import BlendConfig, SourceView, WarpResult, fill_uncovered, warp_from_sources
from nuav2.warp.depth_proxy import DepthProxy, GroundSurface, ProxyConfig, ProxyGeometry, render_depth_proxy
from nuav2.warp.lidar_cloud import CloudConfig, LidarCloud
from nuav2.warp.provider import WarpConfig, WarpOutput, WarpRenderer, warp_image_source
from nuav2.warp.rotation_baseline import RotationSource, closest_source_camera, rotate_into_target
from nuav2.warp.tracks import BoxesAt, BoxTracks

__all__ = ["BlendConfig", "BoxTracks", "BoxesAt", "CloudConfig", "DepthProxy", "GroundSurface", "LidarCloud",
           "ProxyConfig", "ProxyGeometry", "RotationSource", "SourceView", "WarpConfig", "WarpOutput",
           "WarpRenderer", "WarpResult",
           "closest_source_camera", "fill_uncovered", "render_depth_proxy", "rotate_into_target",
           "warp_from_sources", "warp_image_source"]
