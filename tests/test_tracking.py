"""The fiducial tracker's parts: stereo disparities by correlation along the
row against shifts made by hand, and the predicted overlap that decides when a frame is
taken against geometry worked out by hand."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from taskcam.calibration.ekf import StereoCamera
from taskcam.calibration.flow import flow_disparities, nearest_disparity
from taskcam.calibration.pose import invert
from taskcam.calibration.stereo_features import (
    FeatureFinder,
    StereoFeatures,
    row_disparities,
    spread,
)
from taskcam.calibration.tracker_settings import TrackerSettings
from taskcam.calibration.tracking import (
    SCALE,
    SCALE_KEPT,
    TURN_DEG,
    TURN_KEPT,
    FiducialTracker,
    predicted_overlap,
)

CAMERA = StereoCamera(400.0, 400.0, 320.0, 240.0, 0.12)
SIZE = (640, 480)


def _texture(seed: int, shape: tuple[int, int] = (480, 640)) -> np.ndarray:
    """Smooth random texture, 8-bit: noise blurred to blobs a few pixels across."""
    noise = np.random.default_rng(seed).uniform(0, 255, shape).astype(np.float32)
    return cv2.normalize(cv2.GaussianBlur(noise, (0, 0), 2.0), None, 0, 255,
                         cv2.NORM_MINMAX).astype(np.uint8)


def _shifted(image: np.ndarray, disparity: float) -> np.ndarray:
    """The image as a right camera sees a plane ``disparity`` px away: moved left."""
    shift = np.float32([[1, 0, -disparity], [0, 1, 0]])
    return cv2.warpAffine(image, shift, image.shape[::-1], flags=cv2.INTER_CUBIC,
                          borderMode=cv2.BORDER_REFLECT)


@pytest.mark.parametrize("disparity", [12.0, 37.3, 80.55])
def test_row_disparities_recover_a_sub_pixel_shift(disparity):
    left = _texture(1)
    right = _shifted(left, disparity)
    pts = np.random.default_rng(2).uniform([100, 40], [600, 440], (200, 2))
    d = row_disparities(left, right, pts, TrackerSettings())
    found = np.isfinite(d)
    assert found.mean() > 0.9
    assert np.median(np.abs(d[found] - disparity)) < 0.05
    assert np.max(np.abs(d[found] - disparity)) < 0.3


def test_row_disparities_refuse_a_flat_patch_and_a_shift_beyond_the_range():
    left = _texture(3)
    left[200:280, 300:380] = 128  # no texture: the correlation has no peak
    right = _shifted(left, 20.0)
    d = row_disparities(left, right, np.array([[340.0, 240.0]]), TrackerSettings())
    assert np.isnan(d[0])
    far = _shifted(_texture(4), 200.0)  # beyond max_disparity_px (160)
    d = row_disparities(_texture(4), far, np.array([[400.0, 240.0]]), TrackerSettings())
    assert not np.isfinite(d[0]) or abs(d[0] - 200.0) > 1.0


@pytest.mark.parametrize("disparity, guess", [(12.0, 40.0), (37.3, 0.0), (80.55, 60.0)])
def test_flow_disparities_recover_a_sub_pixel_shift_from_a_guess_far_off(disparity, guess):
    left = _texture(1)
    right = _shifted(left, disparity)
    pts = np.random.default_rng(2).uniform([100, 40], [600, 440], (200, 2))
    expected = np.array([[320.0, 240.0, guess]])  # one known fiducial's disparity, for all
    guess = nearest_disparity(pts, expected, 0.0)
    d = flow_disparities(left, right, pts, guess, row_px=1.0, most_px=160.0)
    found = np.isfinite(d)
    assert found.mean() > 0.9
    assert np.median(np.abs(d[found] - disparity)) < 0.05
    assert np.max(np.abs(d[found] - disparity)) < 0.2


def test_flow_disparities_refuse_what_the_right_image_does_not_show():
    left = _texture(3)
    right = _shifted(left, 20.0)
    right[150:330, 200:420] = _texture(9)[150:330, 200:420]  # something else stands there
    pts = np.array([[330.0, 240.0], [500.0, 240.0]])  # behind it, and clear of it
    d = flow_disparities(left, right, pts, np.full(2, 40.0), row_px=1.0, most_px=160.0)
    assert np.isnan(d[0])
    assert abs(d[1] - 20.0) < 0.05
    beyond = flow_disparities(left, _shifted(left, 20.0), pts, np.full(2, 10.0), 1.0, 15.0)
    assert np.all(np.isnan(beyond))  # a disparity over the range is refused


@pytest.mark.parametrize("stereo, within_px", [("correlation", 0.05), ("descriptors", 0.2),
                                               ("flow", 0.05)])
def test_stereo_features_pair_the_left_keypoints_with_their_disparity(stereo, within_px):
    left = cv2.cvtColor(_texture(5), cv2.COLOR_GRAY2RGB)
    right = cv2.cvtColor(_shifted(_texture(5), 25.0), cv2.COLOR_GRAY2RGB)
    ignore = np.zeros((480, 640), bool)
    ignore[:, :320] = True  # the left half is the robot's own body
    found = FeatureFinder(TrackerSettings(stereo=stereo)).stereo(left, right, ignore)
    assert len(found) > 50
    assert np.all(found.z[:, 0] > 320)
    assert np.median(np.abs(found.z[:, 2] - 25.0)) < within_px
    assert found.descriptors.shape == (len(found), 128)


def test_stereo_features_are_the_same_with_the_right_image_on_a_second_thread():
    """OpenCV on one thread (a sweep's worker) finds the right image's keypoints after
    the left's; on more, meanwhile on a second thread: the features must not differ."""
    left = cv2.cvtColor(_texture(7), cv2.COLOR_GRAY2RGB)
    right = cv2.cvtColor(_shifted(_texture(7), 31.4), cv2.COLOR_GRAY2RGB)
    expected = np.array([[200.0, 200.0, 31.0], [500.0, 300.0, 30.0]])
    before = cv2.getNumThreads()
    found = {}
    try:
        for threads in (1, 2):
            cv2.setNumThreads(threads)
            finder = FeatureFinder(TrackerSettings())
            found[threads] = finder.stereo(left, right, None, expected)
            assert (finder._pool is not None) == (threads > 1)
    finally:
        cv2.setNumThreads(before)
    assert len(found[1]) > 100
    assert np.array_equal(found[1].z, found[2].z)
    assert np.array_equal(found[1].descriptors, found[2].descriptors)


def test_keypoints_described_after_the_spread_are_those_of_describing_every_one():
    """Only the spread keypoints are described (SIFT's pyramid built again for them):
    the same pixels and descriptors as describing all of them in one pass and keeping
    the spread ones, masked and with fiducials expected."""
    image = _texture(8)
    mask = np.full(image.shape, 255, np.uint8)
    mask[:, :200] = 0
    expected = np.array([[300.0, 100.0], [600.0, 400.0], [610.0, 420.0]])
    finder = FeatureFinder(TrackerSettings())
    pts, descriptors = finder.keypoints(image, mask, expected)
    every, described = finder.detector.detectAndCompute(image, mask)
    keep = spread(np.array([k.response for k in every]), np.array([k.pt for k in every]),
                  SIZE, finder.settings.features, expected)
    assert len(every) > 2 * len(keep) and len(keep) == 800
    assert np.array_equal(pts, np.array([every[i].pt for i in keep], np.float32).astype(float))
    assert descriptors is not None and np.array_equal(descriptors, described[keep])


def test_keypoints_sit_where_their_blob_is_not_a_quarter_pixel_off():
    """A keypoint of the image mirrored left-right, mapped back (u -> w - 1 - u), lands
    where the image's own keypoint is only if both are unbiased: OpenCV's default SIFT
    puts them a quarter pixel right and down, so the two differ by half a pixel."""
    image = _texture(6)
    finder = FeatureFinder(TrackerSettings(features=2000))
    every = np.ones(image.shape, np.uint8) * 255
    pts, _ = finder.keypoints(image, every)
    for flipped, back in [(image[:, ::-1], lambda p: np.column_stack([639 - p[:, 0], p[:, 1]])),
                          (image[::-1], lambda p: np.column_stack([p[:, 0], 479 - p[:, 1]]))]:
        mirrored = back(finder.keypoints(np.ascontiguousarray(flipped), every)[0])
        gap = np.linalg.norm(pts[:, None] - mirrored[None], axis=2)
        pair = gap.argmin(axis=1)
        close = gap[np.arange(len(pts)), pair] < 0.5
        assert close.sum() > 200
        offset = np.median(pts[close] - mirrored[pair[close]], axis=0)
        assert np.all(np.abs(offset) < 0.05), offset


def test_spread_gives_every_cell_an_equal_share_of_half_and_the_rest_to_the_strongest():
    rng = np.random.default_rng(7)
    size, grid = (640, 480), (4, 2)
    pixels = rng.uniform([0, 0], size, (400, 2))
    responses = rng.uniform(0, 1, 400)
    responses[pixels[:, 0] < 160] += 10.0  # one strip of cells far more contrasted
    dull = (pixels[:, 0] >= 480) & (pixels[:, 1] >= 240)  # a cell with three keypoints
    keep_dull = np.flatnonzero(dull)[:3]
    gone = np.flatnonzero(dull)[3:]
    pixels, responses = np.delete(pixels, gone, 0), np.delete(responses, gone)
    keep_dull = keep_dull - np.searchsorted(gone, keep_dull)
    n = 80
    kept = spread(responses, pixels, size, n, grid=grid)
    assert len(kept) == n and len(set(kept.tolist())) == n
    cells = (pixels[:, 1] * 2 // 480).astype(int) * 4 + (pixels[:, 0] * 4 // 640).astype(int)
    share = n // 16  # half of n over the 8 cells
    for c in range(8):  # by hand: each cell's strongest up to the share
        mine = np.flatnonzero(cells == c)
        strongest = mine[np.argsort(-responses[mine])][:share]
        assert set(strongest.tolist()) <= set(kept.tolist())
    assert set(keep_dull.tolist()) <= set(kept.tolist())  # a dull cell keeps what it has
    # what it could not use went to the strongest left anywhere: the contrasted strip
    extra = [k for k in kept if np.sum(responses[cells == cells[k]] > responses[k]) >= share]
    assert len(extra) == n - 7 * share - 3
    assert all(pixels[k, 0] < 160 for k in extra)
    assert np.array_equal(spread(responses, pixels, size, 1000, grid=grid), np.arange(len(pixels)))


def test_spread_gives_the_cells_where_fiducials_are_expected_more_of_the_shared_half():
    rng = np.random.default_rng(8)
    size, grid, n = (640, 480), (4, 2), 160
    pixels = rng.uniform([0, 0], size, (2000, 2))
    responses = rng.uniform(0, 1, 2000)
    responses[pixels[:, 0] < 160] += 10.0  # the strongest all in the left strip
    expected = rng.uniform([480, 240], [640, 480], (30, 2))  # all in the last cell
    kept = spread(responses, pixels, size, n, expected, grid=grid)
    cells = (pixels[:, 1] * 2 // 480).astype(int) * 4 + (pixels[:, 0] * 4 // 640).astype(int)
    # by hand: n / 4 / 8 = 5 a cell, and the expected cell n / 4 = 40 more
    counts = np.bincount(cells[kept], minlength=8)
    assert counts[7] == 45
    assert all(counts[c] == 5 for c in (1, 2, 3, 5, 6))
    assert counts[0] + counts[4] == n - 45 - 25  # the strongest half: the left strip
    assert len(kept) == n


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """g01 (world to camera, OpenCV axes: z forward, y down) of a camera at ``eye``
    looking at ``target``, its x axis level."""
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.column_stack([x, y, z]), eye
    return invert(T)


def _wall(n: int = 21) -> np.ndarray:
    """Points on a 1 m x 0.6 m patch of the plane x = 0, centred on (0, 0, 1)."""
    ys, zs = np.meshgrid(np.linspace(-0.5, 0.5, n), np.linspace(0.7, 1.3, n))
    return np.column_stack([np.zeros(ys.size), ys.ravel(), zs.ravel()])


def test_overlap_of_an_unchanged_view_is_whole_and_of_a_view_turned_away_none():
    points = _wall()
    here = _look_at(np.array([-1.5, 0.0, 1.0]), np.array([0.0, 0.0, 1.0]))
    assert predicted_overlap(CAMERA, SIZE, here, here, points) == pytest.approx(1.0)
    away = _look_at(np.array([-1.5, 0.0, 1.0]), np.array([-3.0, 0.0, 1.0]))
    assert predicted_overlap(CAMERA, SIZE, here, away, points) == 0.0


def test_overlap_of_a_view_panned_halfway_off_the_wall():
    """Panning about the camera's centre changes no point's viewing direction or
    distance: the overlap is the share still inside the image, counted by hand."""
    points = _wall()
    eye = np.array([-1.5, 0.0, 1.0])
    here = _look_at(eye, np.array([0.0, 0.0, 1.0]))
    panned = _look_at(eye, np.array([0.0, 1.5, 1.0]))
    uv = (points - eye) @ invert(panned)[:3, :3]  # camera-frame directions
    u = CAMERA.fx * uv[:, 0] / uv[:, 2] + CAMERA.cx
    v = CAMERA.fy * uv[:, 1] / uv[:, 2] + CAMERA.cy
    inside = (u >= 8) & (u <= SIZE[0] - 8) & (v >= 8) & (v <= SIZE[1] - 8)
    assert 0.2 < inside.mean() < 0.9
    assert predicted_overlap(CAMERA, SIZE, here, panned, points) == pytest.approx(inside.mean())


def test_overlap_falls_with_the_turn_and_the_distance_as_measured():
    """One point straight ahead, seen again from a camera swung about it by a known
    angle, or moved toward it by a known ratio: the overlap is the measured share
    left (TURN_KEPT, SCALE_KEPT) at that angle and ratio."""
    point = np.array([[0.0, 0.0, 1.0]])
    here = _look_at(np.array([-1.0, 0.0, 1.0]), point[0])
    for angle in (2.0, 7.0, 20.0, 40.0):
        a = math.radians(angle)
        eye = point[0] + np.array([-math.cos(a), math.sin(a), 0.0])
        expected = float(np.interp(angle, TURN_DEG, TURN_KEPT))
        assert predicted_overlap(CAMERA, SIZE, here, _look_at(eye, point[0]), point) \
            == pytest.approx(expected, abs=1e-6)
    for ratio in (1.1, 1.5, 2.5):
        eye = point[0] + np.array([-1.0 / ratio, 0.0, 0.0])
        expected = float(np.interp(ratio, SCALE, SCALE_KEPT))
        assert predicted_overlap(CAMERA, SIZE, here, _look_at(eye, point[0]), point) \
            == pytest.approx(expected, abs=1e-6)


def _seen(g01: np.ndarray, points: np.ndarray, descriptors: np.ndarray,
          rng: np.random.Generator) -> StereoFeatures:
    """What a camera at g01 finds of ``points``: their pixels and disparities (0.1 px of
    noise) and their descriptors."""
    c = points @ g01[:3, :3].T + g01[:3, 3]
    z = np.column_stack([CAMERA.fx * c[:, 0] / c[:, 2] + CAMERA.cx,
                         CAMERA.fy * c[:, 1] / c[:, 2] + CAMERA.cy,
                         CAMERA.fx * CAMERA.baseline / c[:, 2]])
    return StereoFeatures(z + rng.normal(0.0, 0.1, z.shape), descriptors)


def test_a_frame_located_from_a_few_fiducials_carries_the_track_to_a_new_view():
    """The camera leaves the first view's fiducials: a middle frame finds only 10 of them
    (and 100 new ones); the last frame sees only those new ones. The middle frame seeds
    them, so the last one is located; the bundle puts it where it was, within the
    uncertainty it reports (10 fiducials on a patch of a wall locate the middle frame only
    loosely)."""
    rng = np.random.default_rng(3)
    first = np.column_stack([np.zeros(100), rng.uniform(-0.6, -0.2, 100),
                             rng.uniform(0.7, 1.3, 100)])
    second = first + [0.0, 0.8, 0.0]  # the wall further on
    descriptors = rng.normal(size=(200, 128)).astype(np.float32)
    descriptors *= 512 / np.linalg.norm(descriptors, axis=1, keepdims=True)
    poses = [_look_at(np.array([-1.5, y, 1.0]), np.array([0.0, y, 1.0]))
             for y in (-0.2, 0.0, 0.2)]
    tracker = FiducialTracker(CAMERA, TrackerSettings())
    tracker.start(_seen(poses[0], first, descriptors[:100], rng), poses[0])
    few = np.r_[np.arange(10), 100 + np.arange(100)]
    both = np.vstack([first, second])
    middle = tracker.add(_seen(poses[1], both[few], descriptors[few], rng), poses[1])
    assert middle.located and len(middle.observations) == 110
    last = tracker.add(_seen(poses[2], second[:30], descriptors[100:130], rng), poses[2])
    assert last.located and len(last.observations) == 30
    bundle, frames, _ = tracker.solve()
    assert len(frames) == 3
    # the pose's parameters (rotation vector, translation of g01) against the truth's,
    # by the bundle's covariance: under chi-square's 99.9th percentile for 6 (22.5)
    params = [np.r_[Rotation.from_matrix(g[:3, :3]).as_rotvec(), g[:3, 3]]
              for g in (bundle.poses[-1], poses[2])]
    error = params[0] - params[1]
    assert error @ np.linalg.solve(bundle.pose_cov[-1], error) < 22.5, error
