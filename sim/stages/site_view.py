"""How well each placed camera sees the insertion site during the task, and when that
is bad enough to place it again.

During the insertion (sim/stages/task.py) the panel hangs over its slot and comes down
into it: it is a moving occluder of the very place the cameras must watch. Every step,
each placed camera's position is rated (eq. 1-4) for the **insertion site** as a target,
on the map as the task keeps it (the panel's voxels moved by ``mapping.move_object``),
with the panel at its current believed pose as one more convex hull, exactly as the
placement search rates a candidate with other robots' bodies as extra occluders
(``placement.search``'s ``extra_occluders``). Only the cameras' own positions are
rated, not a search, and the map's occluders are kept between calls
(:class:`SiteCache`): only the connected components of the map that changed are
hulled again, so a step costs a few milliseconds.

**The site** (:func:`site_target`): the slot (site ``workpiece/slot``), facing up, a
slot-shaped target (placement's ``TargetModel`` with a half length): the panel's
half-length (0.1 m) either side along the slot and the slot's half-width (7 mm) across,
the part of the slot that the panel's 200 mm bottom edge goes into (the rails beyond it,
the slot being 240 mm long, do not matter). Occluders are expanded by that rectangle:
with the panel hanging over the slot, it is seen from across the slot, under the
panel's bottom edge, and not from above or along it. (A disc of the panel's
half-length, as before, was hidden by the hanging panel from every direction.) The site
is lifted over the map's voxels that hold the work-piece's surface at the slot: the
rails' tops (3 cm over the slot's floor) are mapped into the voxel above
them when they lie on a voxel boundary, and would otherwise be an occluder on the
site itself.

**The rule** (:class:`ReplacementTrigger`): a camera is re-placed when its site rating
has been below ``DROP`` x its reference for ``HOLD`` steps running, and not again until
it has been back above ``RECOVER`` x its reference; a re-placement is made only if the
new pose is worth the move (:func:`worth_the_move`). Once the panel's bottom edge is
below the site's plane (it is going into the slot) its hull holds the site, which is
then hidden from everywhere: ``SiteRating.open_fraction`` is 0 and no candidate can be
worth a move.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from mapping import BoxModel, OccupancyGrid, stored_log_odds
from placement import (
    Hull,
    SearchSettings,
    TargetModel,
    above_plane,
    distance_level,
    expand,
    grid_occluders,
    rate,
    target_outline,
    tfv_at,
)
from placement.tfv import PackedHulls, sphere
from sim.config.scenario import Scenario
from sim.stages.rating_problem import RatingProblem

# --- the re-placement rule ------------------------------------------------------------
# A placed camera does not move during the task, so its distance to the site and angle
# to it (DOF, Res, TAV) stay as they were: its site rating changes only by TFV (and the
# 1 - P of its own voxel). TFV is the angular clearance around the sight line / pi;
# the default run's placed cameras had TFV 0.07 and 0.23 (12 and 42 deg of clearance).
# Halving it means the nearest occlusion has come twice as close, to a few degrees,
# which the cameras' pose errors (about 1 deg, 1-2 cm) and the panel's believed pose
# (up to the 3 cm carry error) use up: the view is about to be lost.
DROP = 0.5
# Re-armed only once back above this fraction of the reference: a band of 0.3 of the
# reference between firing and re-arming, wider than the step-to-step jitter of the
# rating (the panel's believed pose moves by its step, up to 3 cm, and its voxels in
# the 5 cm map jump a voxel at a time), so a rating wavering around DROP fires once.
RECOVER = 0.8
# Steps running below DROP before firing: the task's own patience with a camera that
# loses the panel (TaskConfig.lost_limit, 3). One step's dip (a failed fit leaving the
# believed pose a step off, a voxel flip) does not fire; the panel moves at most 3 cm
# (max_step_m) a step, so a dip lasting 3 steps is the panel staying in the way.
HOLD = 3
# The gain a new pose must promise over staying. Cost of a move: in the default
# scenario a placement's move took 5.0 to 5.4 s of simulated time (the task's steps
# are 1 s apart; its task took 26 steps), during which this camera measures nothing,
# and a correction after it (16 s of computing each). Over the ~20 steps left, moving
# pays only if new x (20 - 5) > current x 20, i.e. new > 1.33 x current; the ratings
# are themselves uncertain by about 10-15 % (candidates on 5 cm voxels change Res by
# 3-6 % at 0.8-1.5 m; TFV is sampled on directions 1.6 deg apart, 0.01 of TFV). Hence
# a required gain of 0.33 and some: 50 %.
MOVE_GAIN = 0.5
# The site rises at most this far over the slot: over the rails (3 cm) and the rest
# of the voxel their tops are mapped into when they lie on its floor (with 5 cm voxels
# the site rises to 0.08 m over the slot), not up a panel that stands in it.
MAX_LIFT_M = 0.1
# ... to this far over the top of the highest voxel it climbed, as the placement's
# sight points sit 1 mm over a target's face (placement.target_points): clear of
# the voxel boundary, whatever the rounding of the voxels' heights.
OVER_SURFACE_M = 0.001

UP = np.array([0.0, 0.0, 1.0])
SITE = "insertion site"  # the insertion site's name as a target
NEIGHBOURS = np.array([[i, j, k] for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])


def site_target(grid: OccupancyGrid, scenario: Scenario, slot: np.ndarray,
                panel: BoxModel, along: np.ndarray, half_width: float) -> TargetModel:
    """The insertion site as a target: a slot at ``slot`` (world, m), facing up, the
    panel's half-length either side along ``along`` (the slot's length, world) and
    ``half_width`` (m) across, lifted over the solid voxels (occupied, or unknown if they
    occlude) stacked on the slot's voxel in the slot's column and its 8 neighbours, at
    most MAX_LIFT_M, to OVER_SURFACE_M over their top. Compute it once, before the
    task moves the panel's voxels (with the panel over the slot it would climb it)."""
    slot = np.asarray(slot, dtype=float)
    i, j, k = (int(v) for v in grid.index(slot[None])[0])
    solid = grid.log_odds > stored_log_odds(0.5)
    if scenario.rating.unknown_occludes:
        solid |= grid.log_odds == 0
    column = solid[max(i - 1, 0):i + 2, max(j - 1, 0):j + 2]
    top = k

    def over(layer: int) -> float:  # the site's height over the top of ``layer``
        return float(grid.origin[2] + (layer + 1) * grid.resolution + OVER_SURFACE_M)

    while (top + 1 < grid.shape[2] and over(top + 1) - slot[2] <= MAX_LIFT_M
           and column[:, :, top + 1].any()):
        top += 1
    z = slot[2] if top == k else over(top)
    return TargetModel(SITE, np.array([slot[0], slot[1], max(z, slot[2])]), UP,
                       half_width, half_length=panel.size / 2,
                       axis=np.asarray(along, float))


def box_corners(model: BoxModel, pose: np.ndarray) -> np.ndarray:
    """World corners (8 per box, m) of ``model`` at ``pose`` (4x4 T_world_object): the
    point set whose hull, expanded by the target, is the panel as an occluder."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    local = (model.centres[:, None] + signs[None] * model.halves[:, None]).reshape(-1, 3)
    return local @ pose[:3, :3].T + pose[:3, 3]


@dataclass(frozen=True)
class SiteRating:
    """A camera position rated for the site: each term of eq. 1 and the total, as a
    placement reports them (``Ratings.terms``), and the fraction of the directions
    over the site's plane from which the site is seen at the camera's distance (0: the
    site is hidden from everywhere at that distance; no re-placement can help)."""

    terms: dict[str, float]
    open_fraction: float

    @property
    def total(self) -> float:
        return self.terms["total"]


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
    pieces again (``placement.grid_occluders`` on a sub-grid holding that component
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


def site_rating(grid: OccupancyGrid, scenario: Scenario, site: TargetModel,
                camera: np.ndarray, panel_pose: np.ndarray, panel: BoxModel,
                others: Sequence[np.ndarray] = (), cache: SiteCache | None = None
                ) -> SiteRating:
    """The rating (eq. 1-4) of a camera at ``camera`` (world, m) for the insertion
    ``site``, on the map ``grid`` as it is (the panel's voxels wherever the task last
    moved them) with the scenario's camera, weights and TFV settings, the panel
    (``panel`` at ``panel_pose``, its believed pose, 4x4) as one more convex hull, and
    ``others`` (point sets, m: other robots' bodies) as more: what
    ``placement.search`` gives a candidate at ``camera`` with the panel and ``others``
    as its extra occluders. Pass the ``cache`` kept from the last call to rate
    cheaply: only what changed since is hulled again (a few ms a step on the default
    map; from scratch about 0.5 s)."""
    problem = RatingProblem(grid, scenario)
    cam, settings = problem.camera, problem.settings
    cache = SiteCache() if cache is None else cache
    camera = np.asarray(camera, dtype=float).reshape(1, 3)
    offset = camera - site.position
    level = distance_level(float(np.linalg.norm(offset)), cam.near, cam.far, settings.levels)
    hidden, hulls = cache.hidden(grid, site, settings, level,
                                 [box_corners(panel, panel_pose), *others])
    tfv = tfv_at(site.position, np.where(hidden, 0.0, np.inf), offset, cam.near, cam.far,
                 hulls, settings.levels, settings.directions, settings.cone)
    ratings = rate(camera, site, cam, tfv, grid.probability_at(camera), problem.weights)
    dirs, _ = sphere(settings.directions)
    over = dirs @ (np.asarray(site.normal, float) / np.linalg.norm(site.normal)) > 0
    return SiteRating(ratings.terms(0), float(np.mean(~hidden[over])))


def required_rating(current: float, reference: float, gain: float = MOVE_GAIN,
                    recover: float = RECOVER) -> float:
    """The site rating a new pose must promise to be worth the move: ``1 + gain`` times
    the current one (the move's cost, see MOVE_GAIN), and at least what counts as
    recovered (``recover`` x the camera's reference: moving to a pose that would itself
    count as having lost the site buys nothing)."""
    return max((1.0 + gain) * current, recover * reference)


def worth_the_move(current: float, candidate: float, reference: float,
                   gain: float = MOVE_GAIN, recover: float = RECOVER) -> bool:
    """Whether a candidate pose rated ``candidate`` for the site is worth moving a
    camera rated ``current`` there (``reference``: the camera's reference rating)."""
    return candidate > 0.0 and candidate >= required_rating(current, reference, gain, recover)


@dataclass(frozen=True)
class ReplacementTrigger:
    """When a camera's view of the site has fallen enough to place it again: below
    ``drop`` x its reference rating for ``hold`` steps running; then not again until
    its rating is back above ``recover`` x the reference (or it gets a new reference).

    The reference is the camera's site rating when it was placed, as :meth:`start`
    gives it, or else the first rating it is asked about (the task's first step).
    A camera with reference 0 never saw the site; this rule never fires for it."""

    drop: float = DROP
    recover: float = RECOVER
    hold: int = HOLD
    _reference: dict[str, float] = field(default_factory=dict, repr=False)
    _below: dict[str, int] = field(default_factory=dict, repr=False)  # steps running
    _fired: set[str] = field(default_factory=set, repr=False)  # until recovered

    def __post_init__(self) -> None:
        if not (0.0 < self.drop < self.recover <= 1.0 and self.hold >= 1):
            raise ValueError(f"need 0 < drop < recover <= 1 and hold >= 1, got drop "
                             f"{self.drop}, recover {self.recover}, hold {self.hold}")

    def start(self, name: str, reference: float) -> None:
        """Camera ``name`` holds on to ``reference`` from now on (placed, or placed
        again): its count of steps below is cleared and it may fire again."""
        self._reference[name] = float(reference)
        self._below[name] = 0
        self._fired.discard(name)

    def reference(self, name: str) -> float | None:
        return self._reference.get(name)

    def should_replace(self, name: str, rating: float) -> str | None:
        """One step's site rating of camera ``name``; why to place it again, if now."""
        reference = self._reference.get(name)
        if reference is None:
            self.start(name, rating)
            return None
        if name in self._fired:
            if rating >= self.recover * reference:
                self._fired.discard(name)
                self._below[name] = 0
            return None
        self._below[name] = self._below[name] + 1 if rating < self.drop * reference else 0
        if self._below[name] < self.hold:
            return None
        self._fired.add(name)
        self._below[name] = 0
        return (f"site rating {rating:.3g} below {self.drop:g} x {reference:.3g} (its "
                f"reference) for {self.hold} steps running")

    def worth_the_move(self, name: str, current: float, candidate: float) -> bool:
        """:func:`worth_the_move` with camera ``name``'s reference and this ``recover``."""
        return worth_the_move(current, candidate, self._reference[name],
                              recover=self.recover)


class SiteWatch:
    """The placed cameras rated on the insertion site at every step of the task (the
    panel, where the task believes it, as one more hull), and when one should be placed
    again (:class:`ReplacementTrigger`); the site is fixed before the panel moves."""

    def __init__(self, grid: OccupancyGrid, scenario: Scenario, slot: np.ndarray,
                 panel: BoxModel, along: np.ndarray, half_width: float,
                 others: Sequence[np.ndarray] = ()) -> None:
        self.grid, self.scenario, self.panel, self.others = grid, scenario, panel, others
        self.site = site_target(grid, scenario, slot, panel, along, half_width)
        self.cache = SiteCache()
        self.trigger = ReplacementTrigger()

    def rate(self, camera: np.ndarray, panel_pose: np.ndarray) -> SiteRating:
        """A camera position's rating of the site with the panel at ``panel_pose``."""
        return site_rating(self.grid, self.scenario, self.site, camera, panel_pose, self.panel,
                           self.others, self.cache)

    def start(self, name: str, camera: np.ndarray, panel_pose: np.ndarray) -> SiteRating:
        """A camera placed (or placed again): its rating now is its reference."""
        rating = self.rate(camera, panel_pose)
        self.trigger.start(name, rating.total)
        return rating

    def check(self, name: str, rating: SiteRating) -> str | None:
        """Why camera ``name`` should be placed again after this step's ``rating``; None
        also when the site is hidden from every direction at its distance (no pose there
        can help: the panel itself covers the slot as it goes in)."""
        why = self.trigger.should_replace(name, rating.total)
        return why if why is not None and rating.open_fraction > 0 else None
