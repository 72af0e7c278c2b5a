"""The world in the recording: every drawn geom as rerun geometry under its
body, the moving bodies' poses over time, and the layout it opens on, read back from
the ``.rrd`` file."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader

from taskcam.sim.stages.record import Recorder

SCENE = """
<mujoco>
  <asset>
    <material name="red" rgba="0.9 0.1 0.1 1"/>
    <texture name="chequer" type="2d" builtin="checker" rgb1="1 0 0" rgb2="0 0 1"
             width="8" height="8"/>
    <material name="chequered" texture="chequer"/>
    <mesh name="tetra" vertex="0 0 0  0.1 0 0  0 0.1 0  0 0 0.1"/>
  </asset>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 0.1"/>
    <body name="table" pos="0.5 0 0.4">
      <geom name="top" type="box" size="0.3 0.2 0.02" material="red"/>
      <geom name="proxy" type="box" size="0.3 0.2 0.1" group="3"/>
      <geom name="ghost" type="sphere" size="0.05" rgba="1 1 1 0"/>
      <geom name="leg" type="box" pos="0 0 -0.2" size="0.02 0.02 0.2" material="chequered"/>
    </body>
    <body name="arm/link 1" pos="0 0 0.2">
      <joint name="hinge" type="hinge" axis="0 0 1"/>
      <geom name="upper" type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
      <body name="hand" pos="0.3 0 0">
        <geom name="wrist" type="cylinder" size="0.02 0.04"/>
        <geom name="tip" type="sphere" pos="0.05 0 0" size="0.015"/>
        <geom name="blob" type="ellipsoid" size="0.01 0.02 0.03"/>
        <geom name="shard" type="mesh" mesh="tetra"/>
      </body>
    </body>
    <body name="carried" mocap="true" pos="0 0.5 0.3">
      <geom name="panel" type="box" size="0.1 0.005 0.05" rgba="0.9 0.8 0.1 1"/>
    </body>
  </worldbody>
</mujoco>
"""

DRAWN = {  # entity path under world/scene -> the shape component expected there
    "world/floor": "Boxes3D:half_sizes", "table/top": "Boxes3D:half_sizes",
    "table/leg": "Boxes3D:half_sizes",
    "arm_link_1/upper": "Capsules3D:radii", "hand/wrist": "Cylinders3D:radii",
    "hand/tip": "Ellipsoids3D:half_sizes", "hand/blob": "Ellipsoids3D:half_sizes",
    "hand/shard": "Mesh3D:vertex_positions", "carried/panel": "Boxes3D:half_sizes",
}


def _record(path: Path) -> tuple[mujoco.MjModel, list[tuple[float, dict[str, np.ndarray]]]]:
    """Record the scene, then the arm turning and the panel carried over 5 samples;
    returns the model and, per sample, its time (s) and the moving bodies' positions."""
    model = mujoco.MjModel.from_xml_string(SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    recorder = Recorder(path, "scene-test")
    recorder.step(0)
    recorder.scene(model, data, ["r1"], task=True)
    samples = []
    for k in range(5):
        data.qpos[0] = 0.3 * k
        data.mocap_pos[0] = [0.05 * k, 0.5, 0.3 - 0.02 * k]
        mujoco.mj_forward(model, data)
        recorder.motion("r1", 0.5 * k, data, np.eye(4))
        samples.append((0.5 * k, {b: data.body(b).xpos.copy()
                                  for b in ("arm/link 1", "hand", "carried")}))
    recorder.close()
    return model, samples


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory
             ) -> tuple[mujoco.MjModel, list, dict[str, list[pa.RecordBatch]], RrdReader]:
    path = tmp_path_factory.mktemp("rec") / "run.rrd"
    model, samples = _record(path)
    reader = RrdReader(path)
    chunks: dict[str, list[pa.RecordBatch]] = {}
    for chunk in reader.store().stream():
        chunks.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    return model, samples, chunks, reader


def _column(batches: list[pa.RecordBatch], name: str) -> list:
    return [v for b in batches if name in b.schema.names for v in b.column(name).to_pylist()]


def _rgb(packed: int) -> tuple[int, int, int]:
    """Red, green, blue (0-255) of rerun's packed 0xRRGGBBAA colour."""
    return (packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255


def test_every_drawn_geom_is_recorded_with_its_shape_and_nothing_else(recorded):
    _, _, chunks, _ = recorded
    for path, component in DRAWN.items():
        assert _column(chunks.get(f"/world/scene/{path}", []), component), path
    geoms = {p for p in chunks if p.startswith("/world/scene/") and p.count("/") == 4}
    assert geoms == {f"/world/scene/{p}" for p in DRAWN}  # no proxy, no invisible geom
    # sizes as MuJoCo has them: the box's half sizes, the capsule's length and radius
    assert _column(chunks["/world/scene/table/top"], "Boxes3D:half_sizes") == [
        [pytest.approx([0.3, 0.2, 0.02])]]
    upper = chunks["/world/scene/arm_link_1/upper"]
    assert _column(upper, "Capsules3D:lengths") == [[pytest.approx(0.3)]]
    assert _column(upper, "Capsules3D:radii") == [[pytest.approx(0.03)]]
    # the material's colour where the geom keeps the default grey (0xRRGGBBAA)
    colour = _column(chunks["/world/scene/table/top"], "Boxes3D:colors")[0][0]
    assert _rgb(colour) == pytest.approx((0.9 * 255, 0.1 * 255, 0.1 * 255), abs=1)
    # a textured material's in one colour: the texture's mean (half red, half blue)
    leg = _column(chunks["/world/scene/table/leg"], "Boxes3D:colors")[0][0]
    assert _rgb(leg) == pytest.approx((127.5, 0, 127.5), abs=1)


def test_the_moving_bodies_poses_replay_the_motion(recorded):
    _, samples, chunks, _ = recorded
    for body, path in (("arm/link 1", "arm_link_1"), ("hand", "hand"), ("carried", "carried")):
        batches = [b for b in chunks[f"/world/scene/{path}"] if "sim_time" in b.schema.names]
        times = [t for b in batches for t in b.column("sim_time").cast(pa.int64()).to_pylist()]
        where = _column(batches, "Transform3D:translation")
        logged = dict(zip(times, where, strict=True))
        for t, positions in samples:
            assert np.allclose(logged[round(t * 1e9)], positions[body], atol=1e-6), body
    # the hand really moved (the arm turned): the recording is not of one pose
    hand = [p["hand"] for _, p in samples]
    assert np.linalg.norm(hand[-1] - hand[0]) > 0.2
    # the table is welded to the world: one static pose, on no timeline
    table = chunks["/world/scene/table"]
    assert all("sim_time" not in b.schema.names for b in table)
    assert _column(table, "Transform3D:translation") == [[pytest.approx([0.5, 0, 0.4])]]


def test_the_recording_opens_on_a_layout(recorded):
    *_, reader = recorded
    assert reader.blueprints(), "no blueprint in the recording"
