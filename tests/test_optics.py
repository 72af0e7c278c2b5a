"""Depth of field in the image: the circle of confusion by hand, and a blurred feature
measuring worse than a sharp one."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from taskcam.calibration import detect_holes
from taskcam.sim.world.optics import Lens, defocus

LENS = Lens(near_m=0.35, far_m=1.5, coc_px=1.5)


def test_circle_of_confusion_by_hand():
    s = 2 / (1 / 0.35 + 1 / 1.5)
    assert LENS.focus_m == pytest.approx(s)
    blur = LENS.blur_px(np.array([0.35, 1.5, s, 3.0, np.inf]))
    assert blur[:3] == pytest.approx([1.5, 1.5, 0.0])
    assert blur[3] == pytest.approx(1.5 * abs(1 / 3.0 - 1 / s) / abs(1 / 0.35 - 1 / s))
    assert blur[4] == 0.0  # no depth (sky): left sharp


def test_in_focus_is_untouched_and_far_out_of_focus_is_smoothed():
    rng = np.random.default_rng(0)
    noise = cv2.GaussianBlur(rng.uniform(0, 255, (60, 80, 3)).astype(np.float32), (0, 0), 2.0)
    image = np.clip((noise - noise.mean()) * 4 + 128, 0, 255).astype(np.uint8)
    focused = defocus(image, np.full((60, 80), LENS.focus_m), LENS)
    assert np.array_equal(focused, image)
    near = defocus(image, np.full((60, 80), 0.12), LENS)  # well inside the near limit
    sigma = LENS.blur_px(np.array([0.12]))[0] / (2 * math.sqrt(2))
    assert 2.0 < sigma < 4.0  # between two blur levels
    expected = cv2.GaussianBlur(image.astype(np.float32), (0, 0), float(sigma))
    # the mix of the two levels is close to the Gaussian of the disk's own spread
    assert np.abs(near.astype(float) - expected)[10:-10, 10:-10].mean() < 0.1 * image.std()
    assert near.std() < 0.7 * image.std()


def test_each_pixel_mixes_its_two_blur_levels_by_hand():
    """At a depth whose spread lies between the 2 and 4 px levels, every pixel is the
    linear mix of those two Gaussian blurs, rounded; nearer pixels mix 4 and 8 px."""
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (50, 70, 3), dtype=np.uint8)
    depth = np.full((50, 70), 0.12)
    depth[:, 35:] = 0.07
    seen = defocus(image, depth, LENS).astype(float)
    as_float = image.astype(np.float32)
    for z, (low, high), part in ((0.12, (2.0, 4.0), np.s_[:, :35]),
                                 (0.07, (4.0, 8.0), np.s_[:, 35:])):
        sigma = LENS.blur_px(np.array([z]))[0] / (2 * math.sqrt(2))
        assert low < sigma < high
        w = (sigma - low) / (high - low)
        mixed = ((1 - w) * cv2.GaussianBlur(as_float, (0, 0), low)
                 + w * cv2.GaussianBlur(as_float, (0, 0), high))
        assert np.abs(seen[part] - mixed[part]).max() <= 0.5 + 1e-3


def test_a_blurred_hole_measures_worse_than_a_sharp_one():
    """The same dark disk, with sensor noise, seen in focus and at 0.15 m (nearer than
    the depth of field): its centre scatters more when it is blurred."""
    errors = {}
    for depth in (LENS.focus_m, 0.15):
        found = []
        for seed in range(40):
            rng = np.random.default_rng(seed)
            u, v = 40 + rng.uniform(0, 1), 30 + rng.uniform(0, 1)
            img = np.full((60, 80), 190, np.uint8)
            cv2.circle(img, (round(u * 256), round(v * 256)), 6 * 256, 15, -1,
                       lineType=cv2.LINE_AA, shift=8)
            rgb = np.repeat(img[..., None], 3, axis=2)
            seen = defocus(rgb, np.full((60, 80), depth), LENS).astype(float)
            seen = np.clip(seen + rng.normal(0, 12.0, seen.shape), 0, 255).astype(np.uint8)
            holes = detect_holes(seen, 6.0)
            assert holes, f"no hole at {depth} m"
            found.append(math.hypot(holes[0].u - u, holes[0].v - v))
        errors[depth] = float(np.sqrt(np.mean(np.square(found))))
    sharp, blurred = errors[LENS.focus_m], errors[0.15]
    assert blurred > 1.3 * sharp, errors
