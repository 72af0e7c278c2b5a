"""Depth integration: taskcam against OctoMap on the same rendered depth frames.

Run from the repository root: ``python -m bench.peers.integration`` (needs the benchmark
extra: ``pip install -e .[bench]``). Frames: 640 x 480 depth images rendered in the
default scene, from both robots' start poses looking around the target. Grid: 4 m x
4 m x 2 m at 2 cm, OctoMap's default sensor model (0.7 / 0.4 / 0.12 / 0.97), 4 m range.
Prints one table and writes bench/results/integration.json.
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np

from bench.common import print_table, write_results
from taskcam.mapping import (
    OccupancyGrid,
    Pinhole,
    SensorModel,
    integrate_depth,
    opencv_pose,
)
from taskcam.mapping.integrate import share_bands
from taskcam.mapping.raycast import image_working_bytes
from taskcam.sim.config.scenario import load_scenario
from taskcam.sim.world.ik import solve_camera_pose
from taskcam.sim.world.render import Renderer, camera_pinhole, camera_pose
from taskcam.sim.world.scene import build_scene

LO, HI, RES, RANGE = np.array([-2.0, -2.0, 0.0]), np.array([2.0, 2.0, 2.0]), 0.02, 4.0


def render_frames(views: int) -> tuple[Pinhole, list[tuple[np.ndarray, np.ndarray]], float]:
    """Depth frames (z-depth, T_world_cam OpenCV) and the median render time (s)."""
    scene = build_scene(load_scenario())
    data = scene.make_data()
    frames, times = [], []
    pinhole = camera_pinhole(scene.model, scene.robots[0].camera)
    rng = np.random.default_rng(0)
    with Renderer(scene.model, pinhole.width, pinhole.height) as renderer:
        for i in range(views):
            robot = scene.robots[i % len(scene.robots)]
            look = scene.primary.position + rng.uniform([-0.6, -0.6, -0.2], [0.6, 0.6, 0.4])
            ik = solve_camera_pose(scene.model, scene.start_qpos, robot, look, move_base=False)
            scene.set_robot(data, robot, ik.qpos)
            start = time.perf_counter()
            depth = renderer.depth(data, robot.camera)
            times.append(time.perf_counter() - start)
            frames.append((depth, opencv_pose(camera_pose(data, robot.camera))))
    return pinhole, frames, statistics.median(times)


def octomap_points(depth: np.ndarray, pinhole: Pinhole, T: np.ndarray) -> np.ndarray:
    """World end points of the valid pixels; sky pixels as points far beyond the range,
    which OctoMap truncates to free-only beams, as taskcam treats them."""
    _, _, rays = pinhole.rays()
    z = np.where(np.isposinf(depth), 4 * RANGE, depth)
    ok = np.isfinite(z) & (z > 0)
    cam = rays[ok] * z[ok, None]
    return cam @ T[:3, :3].T + T[:3, 3]


def octomap_states(tree: Any, grid: OccupancyGrid) -> np.ndarray:
    """OctoMap's state per voxel of ``grid``: -1 free, 0 unknown, 1 occupied."""
    states = np.zeros(grid.shape, dtype=np.int8)
    for leaf in tree.begin_leafs():
        size = leaf.getSize()
        centre = np.asarray(leaf.getCoordinate())
        lo = np.floor((centre - size / 2 - grid.origin) / RES + 0.5).astype(int)
        n = round(size / RES)
        hi = np.minimum(lo + n, grid.shape)
        lo = np.maximum(lo, 0)
        if np.any(hi <= lo):
            continue
        states[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = 1 if tree.isNodeOccupied(leaf) else -1
    return states


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    import octomap

    model = SensorModel()  # OctoMap's defaults
    pinhole, frames, render_s = render_frames(args.views)
    valid = [int(np.sum(np.isfinite(d) & (d > 0))) for d, _ in frames]
    points = [octomap_points(d, pinhole, T) for d, T in frames]

    def ours(share: float) -> tuple[OccupancyGrid, list[float]]:
        per_frame: list[list[float]] = [[] for _ in frames]
        for _ in range(args.repeat):
            grid = OccupancyGrid.from_bounds(LO, HI, RES, model)
            for i, (depth, T) in enumerate(frames):
                start = time.perf_counter()
                integrate_depth(grid, depth, pinhole, T, RANGE, share=share)
                per_frame[i].append(time.perf_counter() - start)
        return grid, [statistics.median(t) for t in per_frame]

    def octo() -> tuple[Any, list[float]]:  # an octomap.OcTree (the module is untyped)
        per_frame: list[list[float]] = [[] for _ in frames]
        for _ in range(args.repeat):
            tree = octomap.OcTree(RES)
            tree.setProbHit(model.hit)
            tree.setProbMiss(model.miss)
            tree.setClampingThresMin(model.clamp_min)
            tree.setClampingThresMax(model.clamp_max)
            for i, ((_, T), pts) in enumerate(zip(frames, points, strict=True)):
                start = time.perf_counter()
                tree.insertPointCloud(pts, T[:3, 3].copy(), maxrange=RANGE)
                per_frame[i].append(time.perf_counter() - start)
        return tree, [statistics.median(t) for t in per_frame]

    ours(0.5)  # compile the kernels before timing
    grid, t_shared = ours(0.5)
    exact, t_exact = ours(0.0)
    tree, t_octo = octo()
    theirs = octomap_states(tree, grid)

    def agreement(states: np.ndarray) -> float:
        observed = (states != 0) | (theirs != 0)
        return float(np.mean(states[observed] == theirs[observed]))

    ms = {k: 1e3 * statistics.median(v) for k, v in
          (("shared", t_shared), ("exact", t_exact), ("octomap", t_octo))}
    pps = {k: statistics.median(n / t for n, t in zip(valid, v, strict=True)) for k, v in
           (("shared", t_shared), ("exact", t_exact), ("octomap", t_octo))}
    levels = len(share_bands(pinhole.fy, 0.5)) - 1
    transient = image_working_bytes(pinhole.height, pinhole.width, levels)
    rows = [
        {"case": "ms per frame (shared rays)", "ours": ms["shared"], "peer": ms["octomap"],
         "ratio": ms["octomap"] / ms["shared"], "unit": "ms (ratio: speed-up)"},
        {"case": "ms per frame (every ray exact)", "ours": ms["exact"], "peer": ms["octomap"],
         "ratio": ms["octomap"] / ms["exact"], "unit": "ms (ratio: speed-up)"},
        {"case": "points per second (shared rays)", "ours": pps["shared"],
         "peer": pps["octomap"], "ratio": pps["shared"] / pps["octomap"], "unit": "points/s"},
        {"case": "voxel-state agreement (shared rays)", "ours": agreement(grid.states()),
         "peer": None, "ratio": None, "unit": "fraction of voxels either observed"},
        {"case": "voxel-state agreement (every ray exact)", "ours": agreement(exact.states()),
         "peer": None, "ratio": None, "unit": "fraction of voxels either observed"},
        {"case": "memory: grid + integration", "ours": (grid.nbytes() + transient) / 2**20,
         "peer": tree.memoryUsage() / 2**20,
         "ratio": tree.memoryUsage() / (grid.nbytes() + transient), "unit": "MiB"},
        {"case": "memory per voxel: grid + integration",
         "ours": (grid.nbytes() + transient) / grid.size, "peer": None, "ratio": None,
         "unit": "bytes (grid: 3)"},
        {"case": "render one depth frame (the floor)", "ours": 1e3 * render_s, "peer": None,
         "ratio": None, "unit": "ms"},
    ]
    print(f"{len(frames)} frames of {pinhole.width}x{pinhole.height}, grid {grid.shape} at "
          f"{RES} m, median of {args.repeat} runs per frame; "
          f"{statistics.median(valid):.0f} valid pixels per frame")
    print_table(rows)
    path = write_results("integration", rows, frames=len(frames), grid_shape=list(grid.shape),
                         resolution_m=RES, repeat=args.repeat,
                         observed_voxels=int(((grid.states() != 0) | (theirs != 0)).sum()),
                         median_seconds={"shared": t_shared, "exact": t_exact,
                                         "octomap": t_octo})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
