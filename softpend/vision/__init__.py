"""Vision: the tip tracker (Algorithm 1), affine calibration, the synthetic camera, video tracking into CSV logs."""

from softpend.vision.camera import DEFAULT_MARKERS_M, CameraEffects, SyntheticCamera
from softpend.vision.tracker import TipTracker

__all__ = ["CameraEffects", "DEFAULT_MARKERS_M", "SyntheticCamera", "TipTracker"]
