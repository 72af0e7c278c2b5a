"""The panel's pixels found by colour (calibration/panel.py), on images drawn and blurred
with OpenCV: a colour blend across another edge that passes through yellow does not
stretch the panel over the background."""

from __future__ import annotations

import cv2
import numpy as np

from taskcam.calibration.panel import panel_mask

GREEN, ORANGE, YELLOW = (40, 120, 40), (230, 120, 20), (210, 185, 30)  # RGB


def _scene(bar: bool) -> tuple[np.ndarray, np.ndarray]:
    """A yellow panel (rows 60-119, columns 100-139) on green; with ``bar``, an orange bar
    whose end touches the panel's lower left corner, its long edges half a pixel off the
    pixel grid: drawn four times as fine and averaged down, as a multisampled render
    does, the pixels along them are half orange, half green, which is yellow. The image
    and the panel's true pixels."""
    fine = np.zeros((800, 960, 3), np.uint8)
    fine[:] = GREEN
    if bar:
        fine[4 * 112 + 2:4 * 118 + 2, 4 * 20:4 * 100] = ORANGE
    fine[4 * 60:4 * 120, 4 * 100:4 * 140] = YELLOW
    truth = np.zeros((200, 240), bool)
    truth[60:120, 100:140] = True
    return cv2.resize(fine, (240, 200), interpolation=cv2.INTER_AREA), truth


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_a_blend_through_yellow_along_a_touching_edge_is_not_the_panel():
    img, truth = _scene(bar=True)
    hsv = cv2.cvtColor(img, cv2.COLOR_RGB2HSV)
    yellow = cv2.inRange(hsv, (20, 100, 50), (38, 255, 255)) > 0
    assert yellow[:, 20:95].any()  # the bar's edges do blend through yellow
    mask = panel_mask(img)
    assert not mask[:, :95].any()  # nothing of the bar's side is the panel
    assert _iou(mask, truth) > 0.9


def test_the_panel_alone_is_found_whole():
    img, truth = _scene(bar=False)
    mask = panel_mask(img)
    assert _iou(mask, truth) > 0.9
    assert mask.sum() <= truth.sum()  # eroded off its outline, never grown past it
