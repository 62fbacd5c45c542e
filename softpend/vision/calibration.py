"""Affine pixel-to-metre calibration, fitted by least squares to reference markers at known positions in the
rod's plane (metres, hub axis at the origin, y up)."""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from softpend.checks import non_negative
from softpend.io.reading import read_json_checked
from softpend.vision.tracker import GREEN_HSV, find_blobs

#: Largest calibration or marker file read [bytes].
MAX_CALIBRATION_BYTES = 1 << 20


def points_array(name: str, value, n_min: int = 3, n_max: int = 6) -> np.ndarray:
    """``value`` as a finite ``(n, 2)`` float array, ``n_min <= n <= n_max`` (``ValueError`` naming ``name``)."""
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be a list of (x, y) number pairs, got {_short(value)}") from None
    if array.ndim != 2 or array.shape[1] != 2 or not n_min <= len(array) <= n_max:
        raise ValueError(f"{name} must be {n_min} to {n_max} (x, y) pairs, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must hold finite numbers, got {_short(value)}")
    return array


def read_json_file(name: str, path: str | Path, max_bytes: int):
    """The JSON document in the regular file at ``path`` (``ValueError`` naming ``name`` and the file)."""
    return read_json_checked(path, f"{name} file", max_bytes)


def read_markers(name: str, text: Optional[str]) -> Optional[list]:
    """A ``--markers`` argument, a JSON list ``[[x, y], ...]`` or a file holding one, as 3 to 6 marker
    positions [m] (None for None or an empty argument)."""
    if not text:
        return None
    if text.lstrip().startswith("["):
        try:
            markers = json.loads(text)
        except (ValueError, RecursionError) as exc:
            raise ValueError(f"{name} is not a valid JSON list: {exc}") from None
    else:
        markers = read_json_file(name, text, MAX_CALIBRATION_BYTES)
    return points_array(name, markers).tolist()


def _short(value) -> str:
    return text if len(text := repr(value)) <= 120 else text[:120] + "..."


def fit_affine(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Least-squares 2x3 affine ``A`` with ``target ~ A @ [source, 1]`` (needs >= 3 non-collinear points)."""
    source, target = np.asarray(source, dtype=float), np.asarray(target, dtype=float)
    design = np.column_stack([source, np.ones(len(source))])
    if np.linalg.matrix_rank(design) < 3:
        raise ValueError("source points are collinear: the affine map is not determined")
    solution, *_ = np.linalg.lstsq(design, target, rcond=None)
    return solution.T


def tip_angle_rad(x_m: np.ndarray | float, y_m: np.ndarray | float) -> np.ndarray | float:
    """Tip angle from upright, counter-clockwise positive, of a tip at ``(x, y)`` from the hub [rad]."""
    return np.arctan2(-np.asarray(x_m, dtype=float), np.asarray(y_m, dtype=float))


@dataclass(frozen=True)
class AffineCalibration:
    """The map ``[x_m, y_m] = pixel_to_metre @ [x_px, y_px, 1]`` and the markers' RMS residual of the fit [m]."""

    pixel_to_metre: np.ndarray
    residual_rms_m: float = 0.0

    def __post_init__(self) -> None:
        try:
            a = np.array(self.pixel_to_metre, dtype=float)
        except (TypeError, ValueError, OverflowError):
            a = np.full(0, math.nan)
        if a.shape != (2, 3) or not np.all(np.isfinite(a)):
            raise ValueError(f"pixel_to_metre must be a finite (2, 3) matrix, got {_short(self.pixel_to_metre)}")
        if abs(np.linalg.det(a[:, :2])) < 1e-15:
            raise ValueError("pixel_to_metre is singular")
        object.__setattr__(self, "pixel_to_metre", a)
        object.__setattr__(self, "residual_rms_m", non_negative("residual_rms_m", self.residual_rms_m))

    def to_metres(self, points_px: np.ndarray) -> np.ndarray:
        """Map ``(..., 2)`` pixel coordinates to metres (NaN stays NaN)."""
        return np.asarray(points_px, dtype=float) @ self.pixel_to_metre[:, :2].T + self.pixel_to_metre[:, 2]

    def to_pixels(self, points_m: np.ndarray) -> np.ndarray:
        """Map ``(..., 2)`` metre coordinates to pixels."""
        linear = np.linalg.inv(self.pixel_to_metre[:, :2])
        return np.asarray(points_m, dtype=float) @ linear.T + -linear @ self.pixel_to_metre[:, 2]

    @property
    def metres_per_pixel(self) -> float:
        """Mean scale [m/px] (square root of the area scale)."""
        return math.sqrt(abs(np.linalg.det(self.pixel_to_metre[:, :2])))

    def to_json(self) -> str:
        return json.dumps({"pixel_to_metre": self.pixel_to_metre.tolist(), "residual_rms_m": self.residual_rms_m})

    @classmethod
    def from_data(cls, data) -> "AffineCalibration":
        """The calibration of parsed :meth:`to_json` output; anything else raises ``ValueError`` saying why."""
        if not isinstance(data, dict) or "pixel_to_metre" not in data:
            raise ValueError(
                f"calibration must be a JSON object with a 'pixel_to_metre' 2x3 matrix, got {_short(data)}"
            )
        if unknown := sorted(set(data) - {"pixel_to_metre", "residual_rms_m"}):
            raise ValueError(f"calibration has unknown keys {unknown}")
        return cls(data["pixel_to_metre"], data.get("residual_rms_m", 0.0))

    @classmethod
    def load(cls, path: str | Path) -> "AffineCalibration":
        """Read a file holding :meth:`to_json` output (``ValueError`` naming the file if it is not one)."""
        data = read_json_file("calibration", path, MAX_CALIBRATION_BYTES)
        try:
            return cls.from_data(data)
        except ValueError as exc:
            raise ValueError(f"calibration file {path}: {exc}") from None


def calibrate_from_markers(frame_bgr: np.ndarray, marker_positions_m: Sequence[Sequence[float]]) -> AffineCalibration:
    """Find the 3 to 6 green markers at ``marker_positions_m`` [m] in ``frame_bgr`` and fit the pixel -> metre
    map: the handedness-preserving marker correspondence of smallest residual."""
    known = points_array("marker_positions_m", marker_positions_m)
    blobs = find_blobs(frame_bgr, GREEN_HSV, 10.0)[: len(known)]
    if len(blobs) < len(known):
        raise ValueError(f"marker_positions_m lists {len(known)} markers but only {len(blobs)} are visible")
    pixels = np.array([[b.x_px, b.y_px] for b in blobs])
    best = None
    for order in itertools.permutations(range(len(known))):
        target = known[list(order)]
        try:
            a = fit_affine(pixels, target)
        except ValueError:
            continue
        rms = float(np.sqrt(np.mean(np.sum((target - (pixels @ a[:, :2].T + a[:, 2])) ** 2, axis=1))))
        if np.linalg.det(a[:, :2]) < 0 and (best is None or rms < best[0]):  # >= 0: a mirror image (y up/down)
            best = (rms, a)
    if best is None:
        raise ValueError("marker_positions_m: no marker correspondence gives a valid affine map")
    return AffineCalibration(best[1], best[0])
