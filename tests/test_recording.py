"""The recording opens clean, read back from its ``.rrd`` file with rerun's reader: every
2-D entity a 3-D view of its layout shows has a pinhole above it (rerun's viewer cannot
place it otherwise, and says so with an error badge), and each robot's image view has
the image of the stage that is running: a mapping view's depth, the last frame of its
pose correction, the look, the task's images."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from taskcam.mapping import Pinhole
from taskcam.sim.stages.record import Recorder
from taskcam.sim.stages.record_layout import image_share

# rerun's 2-D archetypes: a 3-D view draws them only through a pinhole above them
TWO_D = {"Image", "DepthImage", "SegmentationImage", "EncodedImage", "EncodedDepthImage",
         "Points2D", "LineStrips2D", "Boxes2D", "Arrows2D", "VideoFrameReference", "VideoStream"}
IMAGES = {"Image", "DepthImage"}


@dataclass
class Read:
    """A recording as read back: each entity's archetypes and the ``step`` values they
    were logged at, and its layout's views (class, origin, contents' query)."""

    archetypes: dict[str, set[str]] = field(default_factory=lambda: defaultdict(set))
    steps: dict[tuple[str, str], set[int]] = field(default_factory=lambda: defaultdict(set))
    views: list[tuple[str, str, list[str]]] = field(default_factory=list)


def read(path: Path) -> Read:
    reader = RrdReader(path)
    out = Read()
    for chunk in reader.store().stream():
        batch = chunk.to_record_batch()
        entity = str(chunk.entity_path)
        kinds = {n.split(":")[0] for n in batch.schema.names if ":" in n}
        out.archetypes[entity] |= kinds
        if "step" in batch.schema.names:
            steps = batch.column("step").cast(pa.int64()).to_pylist()
            for kind in kinds:
                column = next(n for n in batch.schema.names if n.startswith(f"{kind}:"))
                logged = batch.column(column).to_pylist()
                out.steps[entity, kind] |= {s for s, v in zip(steps, logged, strict=True)
                                            if v is not None}
    blueprints = reader.blueprints()
    assert blueprints, "no layout in the recording"
    views: dict[str, dict[str, object]] = defaultdict(dict)
    for chunk in reader.store(store=blueprints[-1]).stream():
        batch = chunk.to_record_batch()
        view = str(chunk.entity_path)
        for name in (n for n in batch.schema.names if ":" in n):  # components only
            values = [v for v in batch.column(name).to_pylist() if v is not None]
            if values and view.startswith("/view/"):
                views[view][name] = values[-1][0] if name != "ViewContents:query" else values[-1]
    for key, parts in views.items():
        if "ViewBlueprint:class_identifier" in parts:
            query = views.get(f"{key}/ViewContents", {}).get("ViewContents:query", ["$origin/**"])
            out.views.append((str(parts["ViewBlueprint:class_identifier"]),
                              "/" + str(parts["ViewBlueprint:space_origin"]).strip("/"),
                              list(query)))  # type: ignore[call-overload]
    return out


def shown(entity: str, origin: str, query: list[str]) -> bool:
    """Whether a view's contents ``query`` takes ``entity`` in: of the rules that match
    it, the most specific decides (an exact path before a subtree, a longer before a
    shorter), as rerun's entity path filter does."""
    best: tuple[int, int, bool] | None = None
    for rule in query:
        rule = rule.strip()
        include = not rule.startswith("-")
        pattern = rule.lstrip("+-").strip().replace("$origin", origin.strip("/"))
        pattern = "/" + pattern.strip("/")
        subtree = pattern.endswith("/**")
        base = pattern[:-3].rstrip("/") if subtree else pattern
        if subtree and not (base == "" or entity == base or entity.startswith(base + "/")):
            continue
        if not subtree and entity != base:
            continue
        rank = (len(base), 0 if subtree else 1, include)
        if best is None or rank[:2] >= best[:2]:
            best = rank
    return best is not None and best[2]


def without_pinhole(recording: Read) -> list[str]:
    """The 2-D entities that a 3-D view shows with no pinhole at or above them, below
    its origin: what rerun's viewer reports as an error."""
    pinholes = {e for e, kinds in recording.archetypes.items() if "Pinhole" in kinds}
    found = []
    for view, origin, query in recording.views:
        if view != "3D":
            continue
        for entity, kinds in recording.archetypes.items():
            if not kinds & TWO_D or not shown(entity, origin, query):
                continue
            parts = entity.strip("/").split("/")
            above = {"/" + "/".join(parts[:k]) for k in range(1, len(parts) + 1)}
            if not any(p in pinholes and (p + "/").startswith(origin.rstrip("/") + "/")
                       for p in above):
                found.append(entity)
    return sorted(found)


def image_steps(recording: Read, origin: str) -> dict[str, set[int]]:
    """The steps at which an image (by archetype) was logged at or under ``origin``."""
    out: dict[str, set[int]] = defaultdict(set)
    for (entity, kind), steps in recording.steps.items():
        if kind in IMAGES and (entity == origin or entity.startswith(origin + "/")):
            out[kind] |= steps
    return out


SCENE = """
<mujoco><worldbody><geom name="floor" type="plane" size="1 1 0.1"/>
<body name="box" pos="0 0 0.2"><geom type="box" size="0.1 0.1 0.1"/></body>
</worldbody></mujoco>
"""


def _small_recording(path: Path, stray: bool) -> None:
    """A camera with its depth and image and what was found in it, and with ``stray``,
    an image logged in the world with no pinhole above it."""
    model = mujoco.MjModel.from_xml_string(SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    pinhole = Pinhole.from_fovy(np.radians(45), 64, 48)
    recorder = Recorder(path, "recording-test")
    recorder.step(0)
    recorder.scene(model, data, ["r1"], task=True, size_m=2.0, image=(64, 48))
    recorder.tick()
    recorder.camera("r1", np.eye(4), pinhole, depth=np.ones((48, 64)))
    recorder.tick()
    recorder.camera("r1", np.eye(4), pinhole, rgb=np.zeros((48, 64, 3), np.uint8))
    assert recorder.rec is not None
    recorder.rec.log("world/r1/camera/rgb/found/panel", rr.Points2D([[3.0, 4.0]]))
    if stray:
        recorder.rec.log("world/r1/task/left", rr.Image(np.zeros((48, 64, 3), np.uint8)))
        recorder.rec.log("world/r1/task/left/edges", rr.Points2D([[1.0, 2.0]]))
    recorder.close()


@pytest.mark.parametrize("stray", [False, True])
def test_a_2d_entity_without_a_pinhole_in_the_world_is_found(tmp_path, stray):
    path = tmp_path / "run.rrd"
    _small_recording(path, stray)
    recording = read(path)
    assert ("3D", "/world", ["+ $origin/**", "- world/r1/camera/depth"]) in recording.views
    assert "/world/r1/camera/rgb/found/panel" in recording.archetypes  # under the pinhole
    expected = ["/world/r1/task/left", "/world/r1/task/left/edges"] if stray else []
    assert without_pinhole(recording) == expected
    # the camera's view follows it: its depth, then its image
    steps = image_steps(recording, "/world/r1/camera")
    assert steps == {"DepthImage": {1}, "Image": {2}}


def test_the_view_contents_rules_as_rerun_reads_them():
    query = ["+ $origin/**", "- world/r1/camera/depth"]
    assert shown("/world/r1/camera/rgb", "/world", query)
    assert not shown("/world/r1/camera/depth", "/world", query)
    assert shown("/world/r1/camera/depth/x", "/world", query)  # only the entity is left out
    assert not shown("/mapping/gain", "/world", query)
    assert not shown("/world/a", "/world", ["+ $origin/**", "- $origin/**"])


def test_images_fill_their_panels():
    """The image column's share of the width holds images of the camera's aspect at the
    height their rows leave them (the viewer's proportions assumed)."""
    for robots in (1, 2, 3, 4):
        share = image_share(robots, 4 / 3)
        assert 0.1 < share <= 0.5, robots
    assert image_share(2, 4 / 3) > image_share(2, 1.0)  # wider images, a wider column


@pytest.mark.slow
def test_the_default_runs_recording_opens_clean_and_follows_the_stages(default_run):
    out, summary = default_run
    recording = read(out / "run.rrd")
    assert any(view == "3D" and origin == "/world" for view, origin, _ in recording.views)
    assert without_pinhole(recording) == []
    two_d = [v for v in recording.views if v[0] == "2D"]
    names = [r["name"] for r in summary["robots"]]
    assert sorted(origin for _, origin, _ in two_d) == [f"/world/{n}/camera" for n in names]
    # the stages' steps, from the recording's own plots and choices
    mapping = recording.steps["/mapping/region_entropy_bits", "Scalars"]
    task = recording.steps["/task/displacement_m", "Scalars"]
    chosen = {n: recording.steps.get((f"/world/{n}/chosen", "Arrows3D")) for n in names}
    placed = {n: min(steps) for n, steps in chosen.items() if steps}
    assert placed, "no robot was placed"
    look = max(placed.values()) + 1  # the look is the step after the last placement
    assert max(mapping) < min(placed.values()) and look < min(task)
    for robot in summary["robots"]:
        name = robot["name"]
        steps = image_steps(recording, f"/world/{name}/camera")
        if summary["mapping"]["views"][name]:
            assert steps["DepthImage"] & mapping, name  # a mapping view's depth
        if name in placed:
            assert placed[name] in steps["Image"], name  # its correction's final frame
        assert look in steps["Image"], name
        assert len(steps["Image"] & task) >= len(task) // 2, name  # the task's images


def _components(path: Path, entity: str) -> dict[str, list]:
    out: dict[str, list] = defaultdict(list)
    for chunk in RrdReader(path).store().stream():
        if str(chunk.entity_path) == entity:
            batch = chunk.to_record_batch()
            for name in (n for n in batch.schema.names if ":" in n):
                out[name] += [v for v in batch.column(name).to_pylist() if v is not None]
    return out


def test_candidates_are_coloured_by_rating_with_a_legend_and_labels_stand_apart(tmp_path):
    path = tmp_path / "run.rrd"
    model = mujoco.MjModel.from_xml_string(SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    recorder = Recorder(path, "legend-test")
    recorder.step(0)
    recorder.scene(model, data, ["r1"], task=False, size_m=2.5, image=(64, 48))
    recorder.targets(["a", "b", "c"], np.array([[0.0, 0, 0.5], [0.02, 0, 0.5], [0.04, 0, 0.51]]),
                     [0.01] * 3)
    positions = np.column_stack([np.linspace(0, 1, 6), np.zeros(6), np.full(6, 0.8)])
    recorder.candidates("r1", positions, np.array([0.0, 1.0, 2.0, 4.0, 8.0, 0.0]))
    recorder.chosen("r1", np.array([1.0, 0, 1]), np.array([0.0, 0, 0.5]), "a")
    recorder.close()
    candidates = _components(path, "/world/r1/candidates")
    colours = candidates["Points3D:colors"][0]
    grey = (110 << 24) | (110 << 16) | (110 << 8) | 255
    assert colours[0] == colours[5] == grey  # rated 0
    assert len({colours[k] for k in range(1, 5)}) == 4  # each rated one its own colour
    legend = _components(path, "/world/r1/candidates/legend")
    labels = [t for t in legend["Points3D:labels"][0] if t]
    assert labels == ["r1: RF 1 (grey: 0)", "best RF 8 (median 3)"]
    assert legend["Points3D:colors"][0][-1] == colours[4]  # the best's colour tops the bar
    # the targets' labels stand apart, one above the other, the chosen view's at its camera
    lifted = np.array(_components(path, "/world/targets/labels")["Points3D:positions"][0])
    assert np.all(np.diff(np.sort(lifted[:, 2])) >= 0.08 * 2.5 - 1e-6)
    chosen = _components(path, "/world/r1/chosen/label")
    assert chosen["Points3D:labels"] == [["r1 -> a"]]
    assert chosen["Points3D:positions"][0][0] == pytest.approx([1.0, 0, 1])
