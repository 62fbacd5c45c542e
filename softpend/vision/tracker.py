"""The tip tracker, the report's Algorithm 1 with OpenCV: HSV colour range, 3x3 Gaussian blur, external contours,
the largest blob (within area bounds, else the frame is lost) and its centroid in pixels."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

import cv2
import numpy as np

from softpend.checks import instance_of, int_at_least, non_negative, optional_positive

#: Smallest frame height and width the tracker accepts [px].
MIN_FRAME_SIDE_PX = 8
#: Largest share of the frame a blob may cover and still be the tip dot.
MAX_AREA_FRACTION = 0.05


@dataclass(frozen=True)
class ColourRange:
    """An HSV box in OpenCV units (H in [0, 180), S and V in [0, 255]; lower <= upper)."""

    lower_hsv: tuple[int, int, int]
    upper_hsv: tuple[int, int, int]

    def mask(self, frame_bgr: np.ndarray) -> np.ndarray:
        """Binary (0/255) mask of the pixels in range."""
        hsv = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2HSV)
        return cv2.inRange(hsv, np.array(self.lower_hsv, np.uint8), np.array(self.upper_hsv, np.uint8))


#: The blue tip dot.
BLUE_HSV = ColourRange((100, 120, 50), (130, 255, 255))
#: The green reference markers.
GREEN_HSV = ColourRange((45, 120, 50), (75, 255, 255))
#: The magenta hub marker on the rod clamp.
MAGENTA_HSV = ColourRange((145, 150, 50), (170, 255, 255))


@dataclass(frozen=True)
class Detection:
    """The tracker's answer for one frame (pixels: x right, y down; NaN when lost)."""

    x_px: float
    y_px: float
    area_px: float
    lost: bool
    contour: Optional[np.ndarray] = None


_LOST = Detection(math.nan, math.nan, 0.0, True, None)


def _validate_frame(frame_bgr: np.ndarray) -> None:
    shape: Any = getattr(frame_bgr, "shape", None)
    if not isinstance(frame_bgr, np.ndarray) or frame_bgr.ndim != 3 or shape[2] != 3 or frame_bgr.dtype != np.uint8:
        dtype = getattr(frame_bgr, "dtype", type(frame_bgr).__name__)
        raise ValueError(f"frame_bgr must be an (H, W, 3) uint8 BGR image, got shape {shape} of {dtype}")
    if min(shape[:2]) < (side := MIN_FRAME_SIDE_PX):
        raise ValueError(f"frame_bgr must be at least {side}x{side} pixels, got {shape[1]}x{shape[0]}")


def _blobs(blurred: np.ndarray, min_area_px: float) -> list[tuple[float, np.ndarray]]:
    _, binary = cv2.threshold(blurred, 127, 255, cv2.THRESH_BINARY)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    found = [(area, contour) for contour in contours if (area := cv2.contourArea(contour)) >= min_area_px]
    return sorted(found, key=lambda item: -item[0])


def _centroid(blurred: np.ndarray, contour: np.ndarray) -> tuple[float, float]:
    """Weighted centroid of the blurred mask over the contour's bounding box (sub-pixel)."""
    x, y, w, h = cv2.boundingRect(contour)
    x0, y0 = max(x - 1, 0), max(y - 1, 0)
    m = cv2.moments(blurred[y0 : y + h + 1, x0 : x + w + 1], binaryImage=False)
    if m["m00"] <= 0:
        m = cv2.moments(contour)
        if m["m00"] <= 0:  # a degenerate contour: the centre of its bounding box
            return x + (w - 1) / 2.0, y + (h - 1) / 2.0
        return m["m10"] / m["m00"], m["m01"] / m["m00"]
    return x0 + m["m10"] / m["m00"], y0 + m["m01"] / m["m00"]


def find_blobs(frame_bgr: np.ndarray, colour: ColourRange, min_area_px: float = 10.0) -> list[Detection]:
    """Every blob of ``colour`` of at least ``min_area_px``, largest first (for calibration markers)."""
    _validate_frame(frame_bgr)
    blurred = cv2.GaussianBlur(colour.mask(frame_bgr), (3, 3), 0)
    return [
        Detection(*_centroid(blurred, contour), area, False, contour) for area, contour in _blobs(blurred, min_area_px)
    ]


class TipTracker:
    """Track the blue tip dot (Algorithm 1): a blob of ``min_area_px`` [px^2] to :data:`MAX_AREA_FRACTION` of the frame,
    searched first within ``search_radius_px`` of the last dot, only ever inside ``region_px`` if given."""

    def __init__(
        self,
        colour: ColourRange = BLUE_HSV,
        min_area_px: float = 20.0,
        search_radius_px: Optional[float] = 48.0,
        region_px: Optional[tuple[int, int, int, int]] = None,
    ) -> None:
        self.colour = instance_of("colour", colour, ColourRange)
        self.min_area_px = non_negative("min_area_px", min_area_px)
        self.search_radius_px = optional_positive("search_radius_px", search_radius_px)
        if region_px is not None:
            try:
                x0, y0, x1, y1 = (int_at_least("region_px", v, 0) for v in region_px)
            except (TypeError, ValueError):
                raise ValueError(f"region_px must be four integers (x0, y0, x1, y1) >= 0, got {region_px!r}") from None
            if x1 <= x0 or y1 <= y0:
                raise ValueError(f"region_px must be (x0, y0, x1, y1) with x0 < x1, y0 < y1, got {region_px!r}")
            region_px = (x0, y0, x1, y1)
        self.region_px = region_px
        self._last: Optional[tuple[float, float]] = None

    def track(self, frame_bgr: np.ndarray) -> Detection:
        """Locate the dot in one BGR frame; ``lost=True`` (NaN position) when no blob qualifies."""
        _validate_frame(frame_bgr)
        h, w = frame_bgr.shape[:2]
        max_area = MAX_AREA_FRACTION * h * w
        if self.region_px is not None:
            if self.region_px[0] >= w or self.region_px[1] >= h:
                raise ValueError(f"region_px {self.region_px} lies outside the {w}x{h} frame")
            return self._track_window(frame_bgr, *self.region_px, max_area)
        detection = _LOST
        if self.search_radius_px is not None and self._last is not None:
            r = int(math.ceil(min(self.search_radius_px, max(h, w))))
            cx, cy = int(round(self._last[0])), int(round(self._last[1]))
            x0, y0 = max(cx - r, 0), max(cy - r, 0)
            if x0 < w and y0 < h:  # else the last position lies outside this (smaller) frame
                detection = self._track_window(frame_bgr, x0, y0, cx + r + 1, cy + r + 1, max_area)
        if detection.lost:  # nothing in the window, or a blob cut by it
            detection = self._track_window(frame_bgr, 0, 0, w, h, max_area)
        self._last = None if detection.lost else (detection.x_px, detection.y_px)
        return detection

    def _track_window(self, frame: np.ndarray, x0: int, y0: int, x1: int, y1: int, max_area_px: float) -> Detection:
        """The dot in ``frame[y0:y1, x0:x1]`` in frame pixels (lost, its centre unknown, if cut by the window)."""
        window = frame[y0:y1, x0:x1]
        blurred = cv2.GaussianBlur(self.colour.mask(window), (3, 3), 0)
        if not (blobs := _blobs(blurred, self.min_area_px)):
            return _LOST
        area, contour = blobs[0]
        if area > max_area_px:  # too big to be the dot
            return Detection(math.nan, math.nan, area, True, contour)
        bx, by, bw, bh = cv2.boundingRect(contour)
        (win_h, win_w), (frame_h, frame_w) = window.shape[:2], frame.shape[:2]
        if (
            (bx <= 0 < x0)
            or (by <= 0 < y0)
            or (bx + bw >= win_w and x0 + win_w < frame_w)
            or (by + bh >= win_h and y0 + win_h < frame_h)
        ):
            return Detection(math.nan, math.nan, area, True, None)
        x, y = _centroid(blurred, contour)
        return Detection(x + x0, y + y0, area, False, contour + np.array([[x0, y0]], dtype=contour.dtype))
