"""How well each placed camera sees the insertion site during the task, and when that
is bad enough to place it again.

During the insertion (sim/stages/task.py) the panel hangs over its slot and comes down
into it: it is a moving occluder of the very place the cameras must watch. Every step,
each placed camera's position is rated (eq. 1-4) for the **insertion site** as a target,
on the map as the task keeps it (the panel's voxels moved by ``taskcam.mapping.move_object``),
with the panel at its current believed pose as one more convex hull, exactly as the
placement search rates a candidate with other robots' bodies as extra occluders
(``taskcam.placement.search``'s ``extra_occluders``). Only the cameras' own positions are
rated, not a search, and the map's occluders are kept between calls
(:class:`SiteCache`, sim/stages/site_occluders.py): only the connected components of
the map that changed are hulled again, so a step costs a few milliseconds.

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

**The rule** (:class:`ReplacementTrigger`, sim/stages/replacement_rule.py): a camera is
re-placed when its site rating has been below ``DROP`` x its reference for ``HOLD``
steps running, and not again until it has been back above ``RECOVER`` x its reference; a
re-placement is made only if the new pose is worth the move (:func:`worth_the_move`).
Once the panel's bottom edge is below the site's plane (it is going into the slot) its
hull holds the site, which is then hidden from everywhere: ``SiteRating.open_fraction``
is 0 and no candidate can be worth a move.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from taskcam.mapping import BoxModel, OccupancyGrid, stored_log_odds
from taskcam.placement import TargetModel, distance_level, rate, tfv_at
from taskcam.placement.tfv import sphere
from taskcam.sim.config.scenario import Scenario
from taskcam.sim.stages.rating_problem import RatingProblem
from taskcam.sim.stages.replacement_rule import ReplacementTrigger
from taskcam.sim.stages.site_occluders import SiteCache

# The site rises at most this far over the slot: over the rails (3 cm) and the rest
# of the voxel their tops are mapped into when they lie on its floor (with 5 cm voxels
# the site rises to 0.08 m over the slot), not up a panel that stands in it.
MAX_LIFT_M = 0.1
# ... to this far over the top of the highest voxel it climbed, as the placement's
# sight points sit 1 mm over a target's face (taskcam.placement.target_points): clear of
# the voxel boundary, whatever the rounding of the voxels' heights.
OVER_SURFACE_M = 0.001

UP = np.array([0.0, 0.0, 1.0])
SITE = "insertion site"  # the insertion site's name as a target


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


def site_rating(grid: OccupancyGrid, scenario: Scenario, site: TargetModel,
                camera: np.ndarray, panel_pose: np.ndarray, panel: BoxModel,
                others: Sequence[np.ndarray] = (), cache: SiteCache | None = None
                ) -> SiteRating:
    """The rating (eq. 1-4) of a camera at ``camera`` (world, m) for the insertion
    ``site``, on the map ``grid`` as it is (the panel's voxels wherever the task last
    moved them) with the scenario's camera, weights and TFV settings, the panel
    (``panel`` at ``panel_pose``, its believed pose, 4x4) as one more convex hull, and
    ``others`` (point sets, m: other robots' bodies) as more: what
    ``taskcam.placement.search`` gives a candidate at ``camera`` with the panel and ``others``
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
