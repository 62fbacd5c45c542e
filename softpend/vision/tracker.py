"""The tip tracker: the report's Algorithm 1 with OpenCV.

1. convert the frame to HSV and keep the pixels inside a colour range (a binary image);
2. apply a 3x3 Gaussian blur;
3. extract the external contours;
4. take the contour with the largest area as the tracked object (if it reaches ``min_area_px`` and
   covers at most ``max_area_fraction`` of the frame -- a colour that fills the view is not a dot;
   otherwise the frame is *lost*: no position is guessed);
5. its centre (the centroid of the blurred mask inside the contour) is the tip position in pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import cv2
import numpy as np

from softpend.checks import non_negative

__all__ = [
    "BLUE_HSV",
    "GREEN_HSV",
    "MAGENTA_HSV",
    "MIN_FRAME_SIDE_PX",
    "ColourRange",
    "Detection",
    "TipTracker",
    "find_blobs",
]

#: Smallest frame height and width the tracker accepts [px].
MIN_FRAME_SIDE_PX = 8


@dataclass(frozen=True)
class ColourRange:
    """An HSV box in OpenCV units (H in [0, 180), S and V in [0, 255])."""

    lower_hsv: tuple[int, int, int]
    upper_hsv: tuple[int, int, int]

    def __post_init__(self) -> None:
        for name in ("lower_hsv", "upper_hsv"):
            value = getattr(self, name)
            ok = (
                isinstance(value, (tuple, list))
                and len(value) == 3
                and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and 0 <= v <= 255 for v in value)
            )
            if not ok:
                raise ValueError(f"{name} must be three integers in [0, 255], got {value!r}")
        if any(lo > hi for lo, hi in zip(self.lower_hsv, self.upper_hsv)):
            raise ValueError(f"lower_hsv {self.lower_hsv} must not exceed upper_hsv {self.upper_hsv}")

    def mask(self, frame_bgr: np.ndarray) -> np.ndarray:
        """Binary (0/255) mask of the pixels in range."""
        hsv = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2HSV)
        return cv2.inRange(hsv, np.array(self.lower_hsv, np.uint8), np.array(self.upper_hsv, np.uint8))


#: The blue tip dot.
BLUE_HSV = ColourRange((100, 120, 50), (130, 255, 255))
#: The green reference markers used for calibration.
GREEN_HSV = ColourRange((45, 120, 50), (75, 255, 255))
#: The magenta hub marker on the rod clamp (gives the hub angle to the camera, for clock synchronisation).
MAGENTA_HSV = ColourRange((145, 150, 50), (170, 255, 255))


@dataclass(frozen=True)
class Detection:
    """The tracker's answer for one frame (pixel coordinates: x right, y down; NaN when lost)."""

    x_px: float
    y_px: float
    area_px: float
    lost: bool
    contour: Optional[np.ndarray] = None


def _validate_frame(frame_bgr: np.ndarray) -> None:
    if (
        not isinstance(frame_bgr, np.ndarray)
        or frame_bgr.ndim != 3
        or frame_bgr.shape[2] != 3
        or frame_bgr.dtype != np.uint8
    ):
        shape = getattr(frame_bgr, "shape", None)
        dtype = getattr(frame_bgr, "dtype", type(frame_bgr).__name__)
        raise ValueError(f"frame_bgr must be an (H, W, 3) uint8 BGR image, got shape {shape} of {dtype}")
    if min(frame_bgr.shape[:2]) < MIN_FRAME_SIDE_PX:
        raise ValueError(
            f"frame_bgr must be at least {MIN_FRAME_SIDE_PX}x{MIN_FRAME_SIDE_PX} pixels, "
            f"got {frame_bgr.shape[1]}x{frame_bgr.shape[0]}"
        )


def _blobs(blurred: np.ndarray, min_area_px: float) -> list[tuple[float, np.ndarray]]:
    _, binary = cv2.threshold(blurred, 127, 255, cv2.THRESH_BINARY)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = []
    for contour in contours:
        area = cv2.contourArea(contour)
        if area >= min_area_px:
            out.append((area, contour))
    out.sort(key=lambda item: -item[0])
    return out


def _centroid(blurred: np.ndarray, contour: np.ndarray) -> tuple[float, float]:
    """Weighted centroid of the blurred mask over the contour's bounding box (sub-pixel)."""
    x, y, w, h = cv2.boundingRect(contour)
    x0, y0 = max(x - 1, 0), max(y - 1, 0)
    roi = blurred[y0 : y + h + 1, x0 : x + w + 1]
    m = cv2.moments(roi, binaryImage=False)
    if m["m00"] <= 0:
        m = cv2.moments(contour)
        if m["m00"] <= 0:  # a degenerate (zero-area) contour: the centre of its bounding box
            return x + (w - 1) / 2.0, y + (h - 1) / 2.0
        return m["m10"] / m["m00"], m["m01"] / m["m00"]
    return x0 + m["m10"] / m["m00"], y0 + m["m01"] / m["m00"]


def find_blobs(frame_bgr: np.ndarray, colour: ColourRange, min_area_px: float = 10.0) -> list[Detection]:
    """Every blob of ``colour`` with at least ``min_area_px`` (Algorithm 1 without the final 'largest'
    step), largest first; used to find calibration markers."""
    _validate_frame(frame_bgr)
    blurred = cv2.GaussianBlur(colour.mask(frame_bgr), (3, 3), 0)
    detections = []
    for area, contour in _blobs(blurred, min_area_px):
        x, y = _centroid(blurred, contour)
        detections.append(Detection(x, y, area, False, contour))
    return detections


class TipTracker:
    """Track the blue tip dot in camera frames (Algorithm 1).

    Parameters
    ----------
    colour : ColourRange
        HSV range of the dot (default :data:`BLUE_HSV`).
    min_area_px : float
        Smallest blob area accepted as the dot [px^2]; below it the frame is reported lost.
    max_area_px : float, optional
        Largest acceptable area [px^2] (a big blue object is not the dot): larger blobs mean lost.
    max_area_fraction : float
        Largest acceptable area as a fraction of the whole frame (in (0, 1]; default 0.05, about a
        hundred times the default camera's dot): a blob covering more -- a blue object filling the view,
        a blue-lit frame -- is no dot, and the frame is reported lost.
    search_radius_px : float, optional
        After a successful frame the next one is searched only in a window of this radius around the
        last position (about ten times faster at 640x480); the whole frame is searched on the first
        frame and whenever the window holds no qualifying blob.  The default 48 px covers a tip moving at
        7 m/s at 100 frames/s on the default camera.  None searches every frame whole.
    region_px : (x0, y0, x1, y1), optional
        Only ever search this rectangle of the frame (e.g. around the hub for the hub marker).
    """

    def __init__(
        self,
        colour: ColourRange = BLUE_HSV,
        min_area_px: float = 20.0,
        max_area_px: Optional[float] = None,
        search_radius_px: Optional[float] = 48.0,
        region_px: Optional[tuple[int, int, int, int]] = None,
        max_area_fraction: float = 0.05,
    ) -> None:
        if not isinstance(colour, ColourRange):
            raise ValueError(f"colour must be a ColourRange, got {type(colour).__name__}")
        min_area_px = non_negative("min_area_px", min_area_px)
        if max_area_px is not None:
            max_area_px = non_negative("max_area_px", max_area_px)
            if not max_area_px > min_area_px:
                raise ValueError(f"max_area_px must exceed min_area_px, got {max_area_px!r}")
        if search_radius_px is not None:
            search_radius_px = non_negative("search_radius_px", search_radius_px)
            if not search_radius_px > 0:
                raise ValueError(f"search_radius_px must be positive, got {search_radius_px!r}")
        fraction = non_negative("max_area_fraction", max_area_fraction)
        if not 0 < fraction <= 1:
            raise ValueError(f"max_area_fraction must be in (0, 1], got {max_area_fraction!r}")
        self.colour = colour
        self.min_area_px = min_area_px
        self.max_area_px = max_area_px
        self.max_area_fraction = fraction
        self.search_radius_px = search_radius_px
        if region_px is not None:
            try:
                x0, y0, x1, y1 = (_pixel_index(v) for v in region_px)
            except (TypeError, ValueError):
                raise ValueError(f"region_px must be four integers (x0, y0, x1, y1), got {region_px!r}") from None
            if x1 <= x0 or y1 <= y0 or x0 < 0 or y0 < 0:
                raise ValueError(f"region_px must be (x0, y0, x1, y1) with x0 < x1, y0 < y1, got {region_px!r}")
            region_px = (x0, y0, x1, y1)
        self.region_px = region_px
        self._last: Optional[tuple[float, float]] = None

    def reset(self) -> None:
        """Forget the last position (search the whole next frame)."""
        self._last = None

    def track(self, frame_bgr: np.ndarray) -> Detection:
        """Locate the dot in one BGR frame; ``lost=True`` (NaN position) when no blob qualifies.

        Raises
        ------
        ValueError
            If ``frame_bgr`` is not an ``(H, W, 3)`` uint8 image of at least
            :data:`MIN_FRAME_SIDE_PX` pixels a side, or ``region_px`` lies outside it.
        """
        _validate_frame(frame_bgr)
        h, w = frame_bgr.shape[:2]
        max_area = self.max_area_fraction * h * w
        if self.max_area_px is not None:
            max_area = min(max_area, self.max_area_px)
        if self.region_px is not None:
            x0, y0, x1, y1 = self.region_px
            if x0 >= w or y0 >= h:
                raise ValueError(f"region_px {self.region_px} lies outside the {w}x{h} frame")
            crop = frame_bgr[y0:y1, x0:x1]
            detection = self._track_image(crop, max_area)
            if detection.lost:
                return detection
            assert detection.contour is not None  # a found blob has its contour
            if _touches_inner_edge(detection.contour, crop.shape, (x0, y0), (h, w)):
                # the blob runs out of the region: its centre is unknown (and it is bigger than a marker)
                return Detection(math.nan, math.nan, detection.area_px, True, None)
            return Detection(
                detection.x_px + x0,
                detection.y_px + y0,
                detection.area_px,
                False,
                detection.contour + np.array([[x0, y0]], dtype=detection.contour.dtype),
            )
        x_off = y_off = 0
        image = frame_bgr
        if self.search_radius_px is not None and self._last is not None:
            r = int(math.ceil(min(self.search_radius_px, max(h, w))))
            cx, cy = int(round(self._last[0])), int(round(self._last[1]))
            x_off, y_off = max(cx - r, 0), max(cy - r, 0)
            image = frame_bgr[y_off : min(cy + r + 1, h), x_off : min(cx + r + 1, w)]
            if image.size == 0:  # the last position lies outside this (smaller) frame
                image, x_off, y_off = frame_bgr, 0, 0
        detection = self._track_image(image, max_area)
        if image is not frame_bgr and (
            detection.lost or _touches_inner_edge(detection.contour, image.shape, (x_off, y_off), (h, w))
        ):
            # nothing in the window, or a blob cut by the window's edge (it extends beyond: search it whole)
            detection = self._track_image(frame_bgr, max_area)
            x_off = y_off = 0
        if detection.lost:
            self._last = None
            return detection
        x, y = detection.x_px + x_off, detection.y_px + y_off
        self._last = (x, y)
        assert detection.contour is not None  # a found blob has its contour
        contour = detection.contour + np.array([[x_off, y_off]], dtype=detection.contour.dtype)
        return Detection(x, y, detection.area_px, False, contour)

    def _track_image(self, image: np.ndarray, max_area_px: float) -> Detection:
        mask = self.colour.mask(image)  # 1-2: colour range -> binary image
        blurred = cv2.GaussianBlur(mask, (3, 3), 0)  # 3: 3x3 Gaussian blur
        blobs = _blobs(blurred, self.min_area_px)  # 4-5: contours, sorted by area
        if not blobs:
            return Detection(math.nan, math.nan, 0.0, True, None)
        area, contour = blobs[0]
        if area > max_area_px:  # too big to be the dot: no guess
            return Detection(math.nan, math.nan, area, True, contour)
        x, y = _centroid(blurred, contour)  # 6: centre of the region
        return Detection(x, y, area, False, contour)


def _pixel_index(value) -> int:
    """``value`` as an int pixel index (integers or integral floats; not bools, NaN or infinities)."""
    if isinstance(value, (bool, np.bool_)):
        raise TypeError("a bool is not a pixel index")
    number = float(value)
    if not (math.isfinite(number) and number.is_integer()):
        raise ValueError(f"{value!r} is not an integer")
    return int(number)


def _touches_inner_edge(
    contour: Optional[np.ndarray], window_shape: tuple[int, ...], offset: tuple[int, int], frame_shape: tuple[int, int]
) -> bool:
    """True if ``contour`` (window coordinates) reaches an edge of the search window that is not an edge of
    the frame (the blob may continue outside the window)."""
    if contour is None:
        return False
    x, y, w, h = cv2.boundingRect(contour)
    win_h, win_w = window_shape[:2]
    x_off, y_off = offset
    frame_h, frame_w = frame_shape
    return (
        (x <= 0 and x_off > 0)
        or (y <= 0 and y_off > 0)
        or (x + w >= win_w and x_off + win_w < frame_w)
        or (y + h >= win_h and y_off + win_h < frame_h)
    )
