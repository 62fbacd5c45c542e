"""Vision: the report's tip tracker (Algorithm 1), affine calibration, the synthetic camera, and tracking
video files into time-stamped CSV logs."""

from softpend.vision.calibration import AffineCalibration, calibrate_from_markers, fit_affine, tip_angle_rad
from softpend.vision.camera import DEFAULT_MARKERS_M, CameraEffects, CameraModel, SyntheticCamera, render_video
from softpend.vision.tracker import BLUE_HSV, GREEN_HSV, ColourRange, Detection, TipTracker, find_blobs

__all__ = ["AffineCalibration", "BLUE_HSV", "CameraEffects", "CameraModel", "ColourRange", "DEFAULT_MARKERS_M"]
__all__ += ["Detection", "GREEN_HSV", "SyntheticCamera", "TipTracker", "calibrate_from_markers", "find_blobs"]
__all__ += ["fit_affine", "render_video", "tip_angle_rad"]
