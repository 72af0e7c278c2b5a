"""Edges that merge with a neighbouring step: how far the search's found step
lies from its true place when another step is near, against images rendered another way,
and what that bias does to the edge fit's covariance, by hand."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from taskcam.calibration.edge_fit import edge_covariance
from taskcam.calibration.edge_search import (
    MERGE_CONTRASTS,
    MERGE_PHASES,
    merge_bias_px,
    pixel_steps,
    search_edges,
)

UP = 8  # rendered at this many times the resolution, then averaged down (pixel area)


def _two_steps(distance_px: float, contrast: float, blur_px: float, phase: float) -> np.ndarray:
    """A 64 x 16 image (RGB float): a step of 100 at column 32 + phase (pixel edges at
    integers), another of ``contrast`` x 100 ``distance_px`` to its right, blurred by a
    Gaussian of ``blur_px`` sd before the pixels average it."""
    x = (np.arange(64 * UP) + 0.5) / UP
    edge = 32 + phase
    row = 100.0 * ((x > edge) + contrast * (x > edge + distance_px))
    fine = np.repeat(row[None, :], 16 * UP, axis=0).astype(np.float32)
    if blur_px > 0:
        fine = cv2.GaussianBlur(fine, (0, 0), blur_px * UP)
    small = cv2.resize(fine, (64, 16), interpolation=cv2.INTER_AREA)
    return np.repeat(small[:, :, None], 3, axis=2)


def _rms_shift(distance_px: float, blur_px: float, isolated: bool = False) -> float:
    """The search's RMS offset over the neighbour's contrast (either sign) and the edge's
    sub-pixel phase (the table's), searched at most halfway to the neighbour."""
    shifts = []
    for contrast in MERGE_CONTRASTS:
        for phase in MERGE_PHASES:
            image = _two_steps(distance_px, 0.0 if isolated else contrast, blur_px, phase)
            limit = np.array([distance_px / 2])
            found = search_edges(image, np.array([[32 + phase - 0.5, 8.0]]),
                                 np.array([[1.0, 0.0]]), 3, limit)[0]
            shifts.append(found if np.isfinite(found) else min(distance_px / 2, 3.0))
    return float(np.sqrt(np.mean(np.square(shifts))))


@pytest.mark.parametrize("blur_px", [0.0, 0.53, 1.0])
def test_merged_steps_bias_the_search_as_images_rendered_another_way_show(blur_px):
    """The tabulated bias (an isolated step's own error taken out) against images
    blurred and averaged down by OpenCV: within 0.1 px from 0.5 px apart to 7 px apart,
    and zero where the neighbour lies beyond the search and the blur."""
    for distance in (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 7.0):
        brute = _rms_shift(distance, blur_px)
        own = _rms_shift(distance, blur_px, isolated=True)
        excess = np.sqrt(max(brute ** 2 - own ** 2, 0.0))
        assert merge_bias_px(np.array([distance]), blur_px)[0] == pytest.approx(
            excess, abs=0.1), distance
    assert merge_bias_px(np.array([np.inf, 20.0]), blur_px).tolist() == [0.0, 0.0]
    # two steps under a pixel apart in a sharp image are found up to halfway between
    assert 0.1 < merge_bias_px(np.array([1.0]), blur_px)[0] <= 0.6


def test_a_merged_edge_widens_the_covariance_by_its_own_pull_by_hand():
    """Eight edges of 10 points each, edge k pulling motion axis k mod 6 by 1 px a unit,
    residuals +-0.1 px alternating (no edge is biased, so the shared bias is 0): the
    covariance is H^-1 (noise W J^T J W + prior) H^-1. Giving edge 2 a merge bias of
    0.5 px adds exactly H^-1 (0.25 p p^T) H^-1, p its summed pull (10 w along axis 2)."""
    edges = np.repeat(np.arange(8), 10)
    J = np.zeros((80, 6))
    J[np.arange(80), edges % 6] = 1.0
    r = np.tile([0.1, -0.1], 40)
    scale = 0.5
    w = np.full(80, 1.0 / scale ** 2)  # every point an inlier, Tukey's weight 1
    prior = np.eye(6) * 1e-6
    plain, _ = edge_covariance(J, r, w, scale, edges, np.zeros(80), prior)
    merge = np.where(edges == 2, 0.5, 0.0)
    merged, _ = edge_covariance(J, r, w, scale, edges, merge, prior)
    H = J.T @ (w[:, None] * J) + prior
    pull = np.zeros(6)
    pull[2] = 10 * w[0]
    inverse = np.linalg.inv(H)
    assert np.allclose(merged - plain, inverse @ np.outer(pull, pull) @ inverse * 0.25)
    # noise: 0.1 px squared over 80 - 8 degrees of freedom, each point counted once
    noise = 80 * 0.01 / 72
    expected = inverse @ (noise * J.T @ ((w ** 2)[:, None] * J) + prior) @ inverse
    assert np.allclose(plain, expected)


@pytest.mark.parametrize("blur_px", [0.0, 0.4, 1.7])
def test_blurred_steps_averaged_over_pixels_match_fine_sampling(blur_px):
    """The closed-form pixel means of a blurred step against a step sampled 400 times a
    pixel, blurred by a sampled Gaussian and averaged over each pixel."""
    edges = np.array([10.0, 10.3, 17.77])
    sub = 400
    x = (np.arange(32 * sub) + 0.5) / sub
    sharp = (x[None, :] > edges[:, None]).astype(float)
    if blur_px > 0:
        half = round(6 * blur_px * sub)
        kernel = np.exp(-0.5 * (np.arange(-half, half + 1) / sub / blur_px) ** 2)
        padded = np.pad(sharp, ((0, 0), (half, half)), mode="edge")  # the steps go on
        sharp = np.array([np.convolve(row, kernel / kernel.sum(), mode="valid")
                          for row in padded])
    brute = sharp.reshape(len(edges), 32, sub).mean(axis=2)
    exact = pixel_steps(edges, 32, blur_px)
    assert exact.shape == (3, 32)
    np.testing.assert_allclose(exact, brute, atol=2e-3)
    np.testing.assert_allclose(exact[:, -1], 1.0, atol=1e-9)  # the step's far side
