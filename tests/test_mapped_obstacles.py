"""The clutter as the robots mapped it, in the planner's world: distance fields of the
camera map and the bases' floor plan (mapping/obstacle_field.py, mapping/floor_map.py),
the laser scanner (sim/world/base_scanner.py), robots as spheres and the planner that
keeps them off what the maps hold (sim/world/mapped_obstacles.py)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from test_planning import CLEARANCE_M, GOAL, WALL_HALF_Y, scene_with

from taskcam.mapping import FloorMap, ObstacleField
from taskcam.mapping.floor_map import FREE, OCCUPIED, UNSCANNED
from taskcam.sim.stages.world import new_floor, new_grid
from taskcam.sim.world.arm import scene_arm
from taskcam.sim.world.base_scanner import SCAN_HEIGHT_M, scan_into
from taskcam.sim.world.mapped_obstacles import covering_spheres, inside_geom
from taskcam.sim.world.planning import ArmPlanner


@pytest.mark.parametrize("dims", [2, 3])
def test_the_field_never_overestimates_the_distance_to_the_nearest_cell(dims):
    """Against brute force: each sphere's distance to the union of the obstacle cells
    (cubes or squares), measured exactly, is at least the field's bound, and the bound
    gives away at most the cell's diagonal."""
    rng = np.random.default_rng(7)
    res, shape = 0.05, (20,) * dims
    obstacle = rng.random(shape) < 0.02
    origin = rng.uniform(-1, 1, dims)
    field = ObstacleField.from_mask(obstacle, origin, res)
    centres = origin + rng.uniform(0, 20 * res, (300, dims))
    radii = rng.uniform(0, 0.05, 300)
    bound = field.clearance(centres, radii)
    lo = origin + np.argwhere(obstacle) * res  # each cell's min corner
    outside = np.maximum(np.maximum(lo[None] - centres[:, None], centres[:, None] - lo[None] - res),
                         0.0)
    exact = np.linalg.norm(outside, axis=2).min(axis=1) - radii
    assert np.all(bound <= exact + 1e-9)
    assert np.all(bound >= exact - res * math.sqrt(dims) - 1e-9)
    assert field.least(centres, radii) == pytest.approx(bound.min())  # the compiled least
    # outside the grid the field says nothing
    assert field.clearance(origin[None] - 1.0, np.zeros(1))[0] == np.inf


@pytest.mark.parametrize("dims", [2, 3])
def test_the_field_measures_exactly_where_a_query_needs_it(dims):
    """Against brute force: asked with ``exact_below``, the least clearance is the exact
    distance to the obstacle cells (cubes or squares) whenever that is below the
    threshold, and otherwise at least the threshold; never more than the exact one.
    Looked up in two fields' bounds one after the other, each sphere reads its own."""
    rng = np.random.default_rng(11)
    res, shape = 0.05, (16,) * dims
    masks = [rng.random(shape) < 0.03, rng.random(shape) < 0.01]
    origin = rng.uniform(-1, 1, dims)
    fields = [ObstacleField.from_mask(m, origin, res) for m in masks]
    both = np.concatenate([f.bounds for f in fields])

    def exact(mask: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
        lo = origin + np.argwhere(mask) * res
        outside = np.maximum(np.maximum(lo[None] - centres[:, None],
                                        centres[:, None] - lo[None] - res), 0.0)
        return np.linalg.norm(outside, axis=2).min(axis=1) - radii

    hits = 0
    for threshold in (0.02, 0.05, 0.1):
        for _ in range(200):
            centres = origin + rng.uniform(0, 16 * res, (3, dims))
            radii = rng.uniform(0, 0.05, 3)
            first = int(rng.integers(0, 4))  # these read the second field
            truth = np.concatenate([exact(masks[1], centres[:first], radii[:first]),
                                    exact(masks[0], centres[first:], radii[first:])]).min()
            got = fields[0].least(centres, radii, both, first, len(fields[0].bounds),
                                  exact_below=threshold)
            assert got <= truth + 1e-9
            if truth < threshold:
                hits += 1
                assert got == pytest.approx(truth, abs=1e-9)
            else:
                assert got >= threshold - 1e-9
    assert hits > 100  # the exact branch was exercised


def test_covering_spheres_hold_every_point_of_each_geom():
    """Points drawn inside a capsule, a cylinder or a sphere of the robot's scene, and on
    a box's faces, all lie within one of the spheres covering that geom (a box's inside
    is reached through its faces); and a box's spheres bulge at most 4.5 cm past it."""
    scene = scene_with([{"shape": "box", "position": [-1.3, 0.5, 0.3], "size": [0.05, 0.4, 0.3]},
                        {"shape": "cylinder", "position": [-1.0, -0.8, 0.4], "size": [0.08, 0.4]}])
    m, d = scene.model, scene.make_data()
    rng = np.random.default_rng(1)
    kinds = {int(k) for k in (mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CAPSULE,
                              mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_SPHERE)}
    geoms = [g for g in range(m.ngeom) if int(m.geom_type[g]) in kinds]
    assert {int(m.geom_type[g]) for g in geoms} >= kinds - {int(mujoco.mjtGeom.mjGEOM_SPHERE)}
    for g in geoms:
        spheres = covering_spheres(m, [g])
        centre, half = m.geom_aabb[g, :3], m.geom_aabb[g, 3:]  # in the geom's frame
        unit = rng.uniform(-1, 1, (2000, 3))
        box = int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_BOX)
        if box:  # onto a face
            unit[np.arange(2000), rng.integers(0, 3, 2000)] = rng.choice([-1.0, 1.0], 2000)
        local = centre + unit * half
        points = d.geom_xpos[g] + local @ d.geom_xmat[g].reshape(3, 3).T
        points = points[inside_geom(m, d, g, points, 0.0)]
        assert len(points) > 20
        gap = np.linalg.norm(points[:, None] - spheres.centres(d)[None], axis=2) - spheres.radii
        assert np.all(gap.min(axis=1) <= 1e-9), m.geom(g).name
        if box:  # the farthest any sphere reaches past the box: at most a cubic
            # piece's bulge, 0.05 m half-wide, and a little for uneven pieces
            reach = np.abs(spheres.local) + spheres.radii[:, None] - m.geom_size[g]
            assert reach.max() <= 0.045, m.geom(g).name


def test_the_scanner_sees_free_floor_up_to_an_obstacle_and_not_behind_it():
    """A box between the robot and the work-piece, in the scan's plane: the floor plan
    is free from the robot to its face, occupied at its face, never scanned behind it."""
    scene = scene_with([{"shape": "box", "position": [-1.3, 0.0, 0.4], "size": [0.1, 0.3, 0.4]}])
    data = scene.make_data()
    floor = new_floor(scene.scenario, scene, scene_arm(scene).reach_m)
    scan_into(floor, scene.model, data, data, scene.robots, scene.robot_geoms())

    def at(x: float, y: float) -> int:
        return int(floor.state[tuple(floor.index(np.array([[x, y]]))[0])])

    assert at(-1.7, 0.0) == FREE and at(-1.5, 0.0) == FREE
    assert at(-1.39, 0.0) == OCCUPIED  # just inside its face, 0.1 m before its centre
    assert at(-1.0, 0.0) == UNSCANNED  # in its shadow
    assert at(-1.0, 1.0) == FREE  # beside it, seen
    assert SCAN_HEIGHT_M < 0.8  # the box stands in the scan's plane


def mapped(scene, occupied_boxes: list[tuple[np.ndarray, np.ndarray]],
           scanned_from: tuple[tuple[float, float], ...] = ()):
    """A camera map that saw everything: free, but for the voxels within the boxes
    (centre, half extents; m); and the floor plan the robot's scanner makes in
    ``scene`` where it stands and from the places ``scanned_from`` (x, y; m)."""
    grid = new_grid(scene.scenario)
    grid.set_probability(0.1)
    centres = grid.centers()
    for c, h in occupied_boxes:
        inside = np.all(np.abs(centres - c) <= h + grid.resolution / 2, axis=-1)
        grid.set_probability(0.9, inside)
    data = scene.make_data()
    floor = new_floor(scene.scenario, scene, scene_arm(scene).reach_m)
    robot = scene.robots[0]
    for xy in ((None, None), *scanned_from):
        if xy[0] is not None:
            data.qpos[robot.qpos_adr[:2]] = xy
            mujoco.mj_kinematics(scene.model, data)
        scan_into(floor, scene.model, data, data, scene.robots, scene.robot_geoms())
    return grid, floor


def map_planner(scene, grid, floor: FloorMap) -> ArmPlanner:
    return ArmPlanner(scene, scene.make_data(), CLEARANCE_M, CLEARANCE_M + 0.02, drive_m=4.0,
                      rng=np.random.default_rng(3), grid=grid, floor=floor)


def test_the_planner_knows_the_clutter_as_the_robots_mapped_it():
    """The wall lies inside the map: the planner knows it only from the maps. Mapped as
    it is (the floor behind it scanned from round its end), the base drives round it;
    mapped as free (the maps of a room without it), the planner goes straight through
    where it stands, as it believes. Unscanned, the floor behind it is no place to
    stand (nor is there a goal from where the base may stand)."""
    # the wall across the way, inside the map, with room behind it for the base
    wall = (np.array([-1.44, 0.0, 0.8]), np.array([0.05, WALL_HALF_Y, 0.8]))
    scene = scene_with([{"shape": "box", "position": wall[0].tolist(),
                         "size": wall[1].tolist()}])
    robot = scene.robots[0]
    grid, floor = mapped(scene, [wall])
    unseen = map_planner(scene, grid, floor).plan(robot, scene.primary.position, GOAL)
    assert unseen.reason in ("no place to stand", "no goal configuration")
    grid, floor = mapped(scene, [wall], scanned_from=((-1.44, 1.4), (-1.44, -1.4)))
    p = map_planner(scene, grid, floor)
    assert p.unmapped  # the wall's geom: left to the maps
    around = p.plan(robot, scene.primary.position, GOAL)
    assert around.reason is None, around.summary()
    assert np.abs(around.path[:, 1]).max() > WALL_HALF_Y

    empty = scene_with([])
    grid, floor = mapped(empty, [])
    straight = map_planner(scene, grid, floor).plan(robot, scene.primary.position, GOAL)
    assert straight.reason is None and np.abs(straight.path[:, 1]).max() < WALL_HALF_Y


def test_what_the_cameras_never_saw_the_arm_does_not_enter():
    """A camera map with nothing observed: the robot may stand where it is, but its arm
    may reach nowhere beyond the room its own body needed."""
    scene = scene_with([])
    grid, floor = mapped(scene, [])
    grid.set_probability(0.5)  # never observed
    plan = map_planner(scene, grid, floor).plan(scene.robots[0], scene.primary.position, GOAL)
    assert plan.reason in ("no place to stand", "no goal configuration",
                           "no path within the budget")
    start = scene.start_qpos[scene.robots[0].qpos_adr]
    assert map_planner(scene, grid, floor)._valid(scene.robots[0], start, CLEARANCE_M)
