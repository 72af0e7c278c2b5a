"""The insertion site's rating during the task, and when to place a camera again
(sim/stages/site_view.py): against the placement search, by hand, and on a map where
the panel hides one camera's view of the slot."""

from __future__ import annotations

import numpy as np
import pytest

from taskcam.mapping import BoxModel, OccupancyGrid, SensorModel, move_object
from taskcam.placement import Region, TargetModel, clearance_map, expanded_hulls, search, tfv_at
from taskcam.placement.occluders import grid_occluders
from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.stages.panel_model import panel_model
from taskcam.sim.stages.rating_problem import RatingProblem
from taskcam.sim.stages.replacement_rule import (
    DROP,
    HOLD,
    MOVE_GAIN,
    RECOVER,
    ReplacementTrigger,
    required_rating,
    worth_the_move,
)
from taskcam.sim.stages.site_occluders import SiteCache
from taskcam.sim.stages.site_view import MAX_LIFT_M, box_corners, site_rating, site_target
from taskcam.sim.world.scene import build_scene

S = load_scenario()
ALONG = np.array([0.0, 1.0, 0.0])  # the slot's length (the work-piece's y axis)
HALF_WIDTH = 0.007  # between the rails' inner faces: 14 mm


@pytest.fixture(scope="module")
def workpiece() -> tuple[BoxModel, np.ndarray]:
    """The panel's CAD model and the slot (world, m), from the default scene."""
    scene = build_scene(S)
    return panel_model(scene.model), scene.make_data().site("workpiece/slot").xpos.copy()


def occupy(g: OccupancyGrid, lo, hi, p: float = 0.999) -> None:
    """Voxels whose centres lie in the box [lo, hi] (m) get probability ``p``."""
    c = g.centers()
    g.set_probability(p, np.all((c >= np.array(lo)) & (c <= np.array(hi)), axis=-1))


def mapped(slot: np.ndarray, rails: bool = True) -> OccupancyGrid:
    """A mapped scene around the slot, all of it seen (5 cm voxels, the slot in a
    voxel's middle): the table and plate up to the slot's voxel; the rails' tops, on a
    voxel boundary, in the voxel above it; a post 0.5 m from the slot on the +x side."""
    g = OccupancyGrid.from_bounds(slot - [0.975, 1.025, slot[2]], slot + [1.025, 0.975, 0.9],
                                  0.05, SensorModel(*S.sensor()))  # as the episode's map
    g.set_probability(g.model.clamp_min)
    occupy(g, slot - [0.4, 0.3, 1.0], slot + [0.4, 0.3, 0.03])
    if rails:
        occupy(g, slot + [-0.1, -0.1, 0.03], slot + [0.1, 0.1, 0.08])
    occupy(g, slot + [0.25, 0.2, 0.13], slot + [0.35, 0.3, 0.7])
    return g


def at(position) -> np.ndarray:
    """The panel's pose (its bottom edge's centre at ``position``, upright)."""
    T = np.eye(4)
    T[:3, 3] = position
    return T


# cameras 0.69 m from the site at 37 deg elevation, on either side of it (x)
A = np.array([-0.55, 0.0, 0.5])
B = np.array([0.55, 0.0, 0.5])
AWAY = np.array([0.6, -0.8, -0.52])  # the panel on the floor, beside the table


def hiding_a(site: TargetModel, slot: np.ndarray) -> np.ndarray:
    """Where the panel's bottom edge goes to stand across A's sight line to the site,
    a third of the way from the site (its face toward A)."""
    on_line = site.position + 0.35 * (slot + A - site.position)
    return on_line - [0.0, 0.0, 0.075]


def test_the_site_is_the_slot_facing_up_as_long_as_the_panel(workpiece):
    panel, slot = workpiece
    site = site_target(mapped(slot), S, slot, panel, ALONG, HALF_WIDTH)
    assert site.half_length == pytest.approx(0.1)  # 200 mm panel
    assert site.radius == HALF_WIDTH and np.allclose(site.axis, ALONG)  # 14 mm across
    assert np.allclose(site.normal, [0, 0, 1])
    assert np.allclose(site.position[:2], slot[:2])
    # lifted over the voxel the rails' tops were mapped into: [0.55, 0.60] m, + 1 mm
    assert site.position[2] == pytest.approx(0.601)
    bare = site_target(mapped(slot, rails=False), S, slot, panel, ALONG, HALF_WIDTH)
    assert bare.position[2] == slot[2]
    # a panel standing in the slot is not climbed: at most MAX_LIFT_M
    g = mapped(slot)
    occupy(g, slot + [-0.05, -0.1, 0.0], slot + [0.05, 0.1, 0.3])
    assert site_target(g, S, slot, panel, ALONG, HALF_WIDTH).position[2] <= slot[2] + MAX_LIFT_M


def test_tfv_at_is_what_the_clearance_map_reads(workpiece):
    panel, slot = workpiece
    g = mapped(slot)
    site = site_target(g, S, slot, panel, ALONG, HALF_WIDTH)
    hulls = expanded_hulls(grid_occluders(g, site) + [box_corners(panel, at(slot + A / 3))],
                           site)
    cmap = clearance_map(site.position, hulls, 0.35, 1.5)
    rng = np.random.default_rng(0)
    u = rng.normal(size=(2000, 3))
    u[:, 2] = np.abs(u[:, 2])
    offsets = u / np.linalg.norm(u, axis=1, keepdims=True) * rng.uniform(0.3, 1.6, (2000, 1))
    ours = tfv_at(site.position, cmap.depth, offsets, 0.35, 1.5, cmap.hulls)
    theirs = cmap.tfv(offsets)
    assert 0.1 < np.mean(theirs == 0) < 0.9  # both occluded and clear cameras
    assert np.array_equal(ours, theirs)


def test_the_site_rating_is_the_searchs_rating_with_the_panel_as_one_more_hull(workpiece):
    panel, slot = workpiece
    g = mapped(slot)
    site = site_target(g, S, slot, panel, ALONG, HALF_WIDTH)
    pose = at(hiding_a(site, slot))
    move_object(g, panel, None, pose)  # the map follows the panel
    p = RatingProblem(g, S)
    field = search(g, [site], p.camera, p.weights, p.free_threshold, Region(), p.settings,
                   extra_occluders=[box_corners(panel, pose)])
    r = field.ratings
    rng = np.random.default_rng(1)
    pick = np.r_[rng.choice(np.flatnonzero(r.total > 0), 25, replace=False),
                 rng.choice(np.flatnonzero(r.total == 0), 5, replace=False)]
    cache = SiteCache()
    for i in pick:
        ours = site_rating(g, S, site, r.positions[i], pose, panel, cache=cache)
        assert ours.terms == pytest.approx(r.terms(int(i)), rel=1e-9, abs=1e-12)


def test_the_cache_follows_the_map_as_the_panel_moves(workpiece):
    panel, slot = workpiece
    g = mapped(slot)
    site = site_target(g, S, slot, panel, ALONG, HALF_WIDTH)
    cache = SiteCache()
    last = at(slot + AWAY)
    site_rating(g, S, site, slot + A, last, panel, cache=cache)
    assert cache.rehulled == 1  # the post: the map's one occluder over the site
    path = [hiding_a(site, slot) + [0.0, 0.03 * k, 0.0] for k in range(4)] + [slot + [0, 0, 0.1]]
    for position in path:
        pose = at(position)
        move_object(g, panel, last, pose)
        last = pose
        for camera in (A, B):
            kept = site_rating(g, S, site, slot + camera, pose, panel, cache=cache)
            assert cache.rehulled <= 2  # only the panel's part of the map is hulled again
            assert kept == site_rating(g, S, site, slot + camera, pose, panel)  # from scratch


def test_the_trigger_fires_when_the_panel_hides_a_cameras_view(workpiece):
    """A camera that sees the site keeps a good rating while the panel is away; with the
    panel standing across its sight line (and the map following it) its TFV falls to 0
    and the trigger fires after HOLD steps, not before; the camera on the other side is
    unaffected. Once the panel has gone the camera is rearmed, and fires again the next
    time."""
    panel, slot = workpiece
    g = mapped(slot)
    site = site_target(g, S, slot, panel, ALONG, HALF_WIDTH)
    cache = SiteCache()
    away, hide = at(slot + AWAY), at(hiding_a(site, slot))

    def rated(pose: np.ndarray) -> tuple[dict[str, float], dict[str, float]]:
        return (site_rating(g, S, site, slot + A, pose, panel, cache=cache).terms,
                site_rating(g, S, site, slot + B, pose, panel, cache=cache).terms)

    a0, b0 = rated(away)
    assert a0["tfv"] > 0.3 and a0["total"] > 0  # A sees the site, far from the post
    assert 0 < b0["tfv"] < 0.2  # B sees it too; its clearance ends at the post
    trigger = ReplacementTrigger()
    trigger.start("A", a0["total"])
    trigger.start("B", b0["total"])

    move_object(g, panel, away, hide)
    reasons: dict[str, list[str | None]] = {"A": [], "B": []}
    for _ in range(HOLD):
        a, b = rated(hide)
        assert a["tfv"] == 0 and a["total"] == 0  # hidden by the panel
        assert {k: a[k] for k in ("dof", "resolution", "tav", "free")} == \
            {k: a0[k] for k in ("dof", "resolution", "tav", "free")}  # the camera did not move
        assert b == pytest.approx(b0)  # the other side is unaffected
        reasons["A"].append(trigger.should_replace("A", a["total"]))
        reasons["B"].append(trigger.should_replace("B", b["total"]))
    assert reasons["A"][:-1] == [None] * (HOLD - 1)
    assert reasons["A"][-1] == (f"site rating 0 below {DROP:g} x {a0['total']:.3g} (its "
                                f"reference) for {HOLD} steps running")
    assert reasons["B"] == [None] * HOLD
    assert trigger.should_replace("A", rated(hide)[0]["total"]) is None  # fired: once

    move_object(g, panel, hide, away)  # the panel goes: A sees the site as before
    a, _ = rated(away)
    assert a == pytest.approx(a0)
    assert trigger.should_replace("A", a["total"]) is None  # rearmed
    move_object(g, panel, away, hide)
    again = [trigger.should_replace("A", rated(hide)[0]["total"]) for _ in range(HOLD)]
    assert again[:-1] == [None] * (HOLD - 1) and again[-1] is not None


def test_the_panel_over_the_slot_hides_it_from_above_and_end_on_not_from_the_side(
        workpiece):
    """The panel hanging 0.15 m over the slot (its approach), on the map and as a hull:
    a camera straight above it (0.8 m) or looking along the slot (0.5 m along, 0.5 m up)
    sees the 14 mm slot only past the panel, which covers it; cameras across the slot
    (A, B: 37 deg up; and 15 deg up, 0.93 m away) see under the panel's bottom edge."""
    panel, slot = workpiece
    g = mapped(slot)
    site = site_target(g, S, slot, panel, ALONG, HALF_WIDTH)
    over = at(slot + [0.0, 0.0, 0.15])
    move_object(g, panel, None, over)
    for camera in (np.array([0.0, 0.0, 0.8]), np.array([0.0, 0.5, 0.5])):
        assert site_rating(g, S, site, slot + camera, over, panel).total == 0
    for camera in (A, B, np.array([-0.9, 0.0, 0.25])):
        rating = site_rating(g, S, site, slot + camera, over, panel)
        assert rating.terms["tfv"] > 0.05 and rating.total > 0


def test_the_panel_in_the_slot_hides_the_site_from_everywhere(workpiece):
    """Its hull holds the site: every camera rates 0, none could do better, so no
    candidate is worth a move."""
    panel, slot = workpiece
    g = mapped(slot)
    site = site_target(g, S, slot, panel, ALONG, HALF_WIDTH)
    inserted = at(slot)
    move_object(g, panel, None, inserted)
    for camera in (A, B, np.array([0.0, 0.4, 0.9])):
        r = site_rating(g, S, site, slot + camera, inserted, panel)
        assert r.total == 0 and r.open_fraction == 0
    assert not worth_the_move(0.0, 0.0, 100.0)


def test_hysteresis_by_hand():
    """Reference 0.40: fires below DROP x 0.40 = 0.20 for HOLD = 3 steps running;
    rearmed only at RECOVER x 0.40 = 0.32 or more (0.33 here: 0.8 x 0.4 rounds up)."""
    assert (DROP, RECOVER, HOLD) == (0.5, 0.8, 3)
    t = ReplacementTrigger()
    assert t.should_replace("r1", 0.40) is None  # the first rating is the reference
    assert t.reference("r1") == 0.40
    steps = [0.30, 0.19, 0.21,  # a dip of one step, then above 0.20: count restarts
             0.19, 0.10, 0.20,  # 0.20 is not below 0.20
             0.19, 0.15, 0.05,  # three running: fires at the third
             0.01, 0.01, 0.01, 0.31,  # fired: silent until recovered (0.31 < 0.32)
             0.19, 0.19, 0.19,  # still silent
             0.33,  # recovered: rearmed
             0.19, 0.19, 0.19]  # fires again
    fired = [i for i, r in enumerate(steps) if t.should_replace("r1", r) is not None]
    assert fired == [8, 19]
    assert t.should_replace("r2", 0.0) is None
    assert all(t.should_replace("r2", 0.0) is None for _ in range(10))  # never saw it
    t.start("r1", 0.1)  # placed again: a new reference, counted afresh
    assert [t.should_replace("r1", 0.04) for _ in range(3)][-1] == (
        "site rating 0.04 below 0.5 x 0.1 (its reference) for 3 steps running")
    with pytest.raises(ValueError, match="drop"):
        ReplacementTrigger(drop=0.9, recover=0.8)


def test_worth_the_move_by_hand():
    """A new pose must rate at least (1 + MOVE_GAIN) = 1.5 x the current one, and at
    least RECOVER x the reference (0.8 x 0.40 = 0.32)."""
    assert MOVE_GAIN == 0.5
    assert required_rating(0.10, 0.40) == pytest.approx(0.32)  # the recovery floor rules
    assert not worth_the_move(0.10, 0.31, 0.40)  # 3 x better, still a lost view
    assert worth_the_move(0.10, 0.33, 0.40)
    assert required_rating(0.30, 0.40) == pytest.approx(0.45)  # the gain rules
    assert not worth_the_move(0.30, 0.44, 0.40)  # not worth the move's time
    assert worth_the_move(0.30, 0.45, 0.40)
    assert worth_the_move(0.0, 0.33, 0.40) and not worth_the_move(0.0, 0.0, 0.0)
    t = ReplacementTrigger()
    t.start("r1", 0.40)
    assert t.worth_the_move("r1", 0.10, 0.33) and not t.worth_the_move("r1", 0.10, 0.31)
