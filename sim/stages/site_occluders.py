"""The insertion site's occluders on one map, kept from one step of the task to the next
(:class:`SiteCache`): only the connected components of the map that changed are hulled
again, and each hull keeps, per camera distance, the directions from which it hides the
site.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy import ndimage

from taskcam.mapping import OccupancyGrid, stored_log_odds
from taskcam.placement import (
    Hull,
    SearchSettings,
    TargetModel,
    above_plane,
    expand,
    grid_occluders,
    target_outline,
)
from taskcam.placement.tfv import PackedHulls

NEIGHBOURS = np.array([[i, j, k] for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])


class _Occluder:
    """One expanded hull, and per camera distance level (m) the sphere directions
    (indices) from which it hides the site at that distance."""

    def __init__(self, hull: Hull) -> None:
        self.hull = hull
        self._packed = PackedHulls.of([hull])  # packed once, for every level
        self.hides: dict[float, np.ndarray] = {}

    def at(self, level: float, site: TargetModel, settings: SearchSettings) -> np.ndarray:
        if level not in self.hides:
            self.hides[level] = self._packed.hidden_directions(
                site.position, level, settings.directions, settings.cone)
        return self.hides[level]


def _key(points: np.ndarray) -> bytes:
    """Points named by their place to a nanometre: the same piece of the map, whichever
    sub-grid it was cut from."""
    return np.round(points, 9).tobytes()


class SiteCache:
    """The site's occluders on one map, kept between calls to :func:`site_rating`.

    Each call compares the map's occluding voxels (occupied, or unknown if they
    occlude, above the site's plane) with the last call's. A connected component the
    change did not reach (26-neighbourhood: it has no voxel in or next to a changed
    one) is the same component as before and keeps its pieces; the others are cut into
    pieces again (``taskcam.placement.grid_occluders`` on a sub-grid holding that component
    alone, aligned to the hull blocks, so the pieces are the ones the whole map gives),
    and only pieces not seen before are hulled. Each hull (the map's pieces, the
    panel, other robots) keeps, per camera distance level, the directions from which it
    hides the site (``PackedHulls.occluded``: exact, as the search's check near the
    boundary; the search's depth per direction, found by bisection, differs from it
    only within 1e-7 m of a level). A different site, map geometry or setting starts
    afresh."""

    def __init__(self) -> None:
        self._key: tuple[object, ...] | None = None
        self._reset()

    def _reset(self) -> None:
        self._above = np.zeros(0, dtype=bool)
        self._solid: np.ndarray | None = None
        self._components: dict[tuple[object, ...], list[bytes]] = {}
        self._pieces: dict[bytes, _Occluder] = {}  # the map's, by their points
        self._hidden: dict[float, np.ndarray] = {}  # the map's, per level (bool)
        self._extras: dict[bytes, _Occluder | None] = {}
        self.rehulled = 0  # map components cut into pieces by the last call
        self.new_pieces = 0  # of their pieces, hulled by the last call

    def hidden(self, grid: OccupancyGrid, site: TargetModel, settings: SearchSettings,
               level: float, extras: Sequence[np.ndarray]
               ) -> tuple[np.ndarray, Callable[[], PackedHulls]]:
        """Per sphere direction around the site, whether the map's occluders or the
        ``extras`` (point sets, m, each hulled after expansion by the site) hide the
        site from ``level`` (m) away along it; and a function giving those hulls packed
        (for the exact check near the occlusion boundary)."""
        key = (grid.origin.tobytes(), grid.shape, grid.resolution, site.position.tobytes(),
               np.asarray(site.normal, float).tobytes(), site.shape(),
               settings.unknown_occludes, settings.block, settings.directions, settings.cone)
        if key != self._key:
            self._reset()
            self._key = key
            self._above = above_plane(grid, site)
        solid = grid.log_odds > stored_log_odds(0.5)
        if settings.unknown_occludes:
            solid |= grid.log_odds == 0
        solid &= self._above
        self.rehulled = self.new_pieces = 0
        if self._solid is None or not np.array_equal(solid, self._solid):
            self._update(grid, solid, site, settings)
        if level not in self._hidden:
            hidden = np.zeros(settings.directions, dtype=bool)
            for piece in self._pieces.values():
                hidden[piece.at(level, site, settings)] = True
            self._hidden[level] = hidden
        extra = [self._extra(points, site) for points in extras]
        self._extras = {k: v for k, v in self._extras.items()
                        if any(v is e for e in extra)}  # the panel's old poses go
        hidden = self._hidden[level].copy()
        for e in extra:
            if e is not None:
                hidden[e.at(level, site, settings)] = True
        hulls = [p.hull for p in self._pieces.values()]
        hulls += [e.hull for e in extra if e is not None]
        return hidden, lambda: PackedHulls.of(hulls)

    def _extra(self, points: np.ndarray, site: TargetModel) -> _Occluder | None:
        points = np.ascontiguousarray(points, dtype=float)
        k = points.tobytes()
        if k not in self._extras:
            hull = expand(points, site)
            self._extras[k] = None if hull is None else _Occluder(hull)
        return self._extras[k]

    def _update(self, grid: OccupancyGrid, solid: np.ndarray, site: TargetModel,
                settings: SearchSettings) -> None:
        labels, count = ndimage.label(solid, structure=np.ones((3, 3, 3), dtype=bool))
        if self._solid is None:
            touched = set(range(1, count + 1))
        else:
            changed = np.argwhere(solid != self._solid)
            near = (changed[:, None, :] + NEIGHBOURS[None]).reshape(-1, 3)
            near = near[np.all((near >= 0) & (near < np.array(grid.shape)), axis=1)]
            touched = set(np.unique(labels[tuple(near.T)]).tolist()) - {0}
        outline = target_outline(site)
        components: dict[tuple[object, ...], list[bytes]] = {}
        pieces: dict[bytes, _Occluder] = {}
        for label, box in enumerate(ndimage.find_objects(labels), start=1):
            assert box is not None  # labels run 1..count
            mine = labels[box] == label
            # its box and first voxel name a component: distinct components are disjoint
            name = (tuple((s.start, s.stop) for s in box), int(np.argmax(mine)))
            if label not in touched and name in self._components:
                components[name] = self._components[name]
            else:
                self.rehulled += 1
                components[name] = []
                for points in _component_pieces(grid, box, mine, site, settings):
                    k = _key(points)
                    if k not in self._pieces and k not in pieces:
                        hull = expand(points, site, outline=outline)
                        if hull is None:
                            continue
                        self.new_pieces += 1
                        pieces[k] = _Occluder(hull)
                    components[name].append(k)
            for k in components[name]:
                pieces[k] = pieces.get(k) or self._pieces[k]
        self._components, self._pieces, self._solid = components, pieces, solid
        self._hidden = {}


def _component_pieces(grid: OccupancyGrid, box: tuple[slice, ...], mine: np.ndarray,
                      site: TargetModel, settings: SearchSettings) -> list[np.ndarray]:
    """``grid_occluders``' pieces of one component (the voxels ``mine`` of ``box``):
    the same call on a sub-grid holding only it, its origin on the hull blocks' grid."""
    lo = np.array([s.start for s in box])
    lo -= lo % settings.block
    hi = np.array([s.stop for s in box])
    sub = OccupancyGrid(grid.origin + lo * grid.resolution, grid.resolution,
                        (int(hi[0] - lo[0]), int(hi[1] - lo[1]), int(hi[2] - lo[2])),
                        grid.model)
    sub.log_odds[...] = -1  # free
    inner = tuple(slice(s.start - a, s.stop - a) for s, a in zip(box, lo, strict=True))
    sub.log_odds[inner][mine] = grid.log_odds[box][mine]
    return grid_occluders(sub, site, unknown_occludes=settings.unknown_occludes,
                          block=settings.block)
