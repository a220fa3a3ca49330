"""The expansion's geometric layers (node, line, polygon) with deterministic tokens.

Nodes are shared by coordinate (on the 0.1 mm grid), as in nuScenes, so adjacent lanes share
their edge nodes and the devkit's ``get_next_roads`` finds successors by node identity.
Tokens are hyphenated UUID-style md5 hashes of (location, layer, key): re-running a
conversion writes byte-identical JSON.
"""

from __future__ import annotations

import hashlib

import numpy as np
from shapely.geometry import Polygon

DECIMALS = 4  # node grid, matches map_polygons.GRID_M


def map_token(location: str, layer: str, key: str) -> str:
    """Deterministic UUID-formatted token for a record of ``layer`` identified by ``key``."""
    h = hashlib.md5(f"{location}/{layer}/{key}".encode()).hexdigest()
    return f"{h[:8]}-{h[8:12]}-{h[12:16]}-{h[16:20]}-{h[20:]}"


def _coord(v: float) -> float:
    r = round(float(v), DECIMALS)
    return 0.0 if r == 0 else r  # no "-0.0"


class GeometryTables:
    """Accumulates node/line/polygon records for one location."""

    def __init__(self, location: str) -> None:
        self.location = location
        self.node: list[dict] = []
        self.line: list[dict] = []
        self.polygon: list[dict] = []
        self._node_by_xy: dict[tuple[float, float], str] = {}
        self._keys: set[tuple[str, str]] = set()

    def _new_token(self, layer: str, key: str) -> str:
        if (layer, key) in self._keys:
            raise ValueError(f"{self.location}: duplicate {layer} key {key!r}")
        self._keys.add((layer, key))
        return map_token(self.location, layer, key)

    def node_token(self, x: float, y: float) -> str:
        xy = (_coord(x), _coord(y))
        tok = self._node_by_xy.get(xy)
        if tok is None:
            tok = self._new_token("node", f"{xy[0]!r},{xy[1]!r}")
            self._node_by_xy[xy] = tok
            self.node.append({"token": tok, "x": xy[0], "y": xy[1]})
        return tok

    def node_tokens(self, xy: np.ndarray, drop_repeats: bool = True) -> list[str]:
        toks = [self.node_token(x, y) for x, y in np.asarray(xy, dtype=np.float64)[:, :2].tolist()]
        if drop_repeats:
            toks = [t for k, t in enumerate(toks) if k == 0 or t != toks[k - 1]]
        return toks

    def add_line(self, key: str, node_tokens: list[str]) -> str:
        """A line over already-created nodes (see ``node_tokens``)."""
        tok = self._new_token("line", key)
        self.line.append({"token": tok, "node_tokens": list(node_tokens)})
        return tok

    def _ring(self, coords) -> list[str]:
        toks = self.node_tokens(np.asarray(coords)[:-1])  # shapely rings repeat the first vertex
        while len(toks) > 1 and toks[-1] == toks[0]:
            toks.pop()
        return toks

    def add_polygon(self, key: str, poly: Polygon) -> str:
        tok = self._new_token("polygon", key)
        self.polygon.append({
            "token": tok,
            "exterior_node_tokens": self._ring(poly.exterior.coords),
            "holes": [{"node_tokens": self._ring(r.coords)} for r in poly.interiors],
        })
        return tok
