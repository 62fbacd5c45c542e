"""Figure 9 helpers: a tracked camera frame with the detection overlaid, and rig-data plots."""

from __future__ import annotations

from typing import Optional

import numpy as np

__all__ = ["draw_tracked_frame"]


def draw_tracked_frame(ax, frame_bgr: np.ndarray, detection, zoom_px: Optional[float] = 45.0,
                       markers_px: Optional[np.ndarray] = None, truth_px: Optional[np.ndarray] = None):
    """Show a BGR camera frame on ``ax`` with the tracker's contour (green line) and centroid (red cross),
    optional calibration-marker centres (white circles) and the true tip position (yellow plus); with
    ``zoom_px`` an inset magnifies the dot.  Returns the inset axis (or None)."""
    rgb = np.ascontiguousarray(frame_bgr[..., ::-1])
    ax.imshow(rgb)
    ax.set_axis_off()

    def _overlay(a):
        if detection is not None and detection.contour is not None:
            c = detection.contour.reshape(-1, 2)
            a.plot(np.r_[c[:, 0], c[0, 0]], np.r_[c[:, 1], c[0, 1]], "-", color="lime", lw=1.2)
        if detection is not None and not detection.lost:
            a.plot(detection.x_px, detection.y_px, "+", color="red", ms=12, mew=2)
        if truth_px is not None:
            a.plot(truth_px[0], truth_px[1], "x", color="yellow", ms=8, mew=1.5)

    _overlay(ax)
    if markers_px is not None:
        ax.plot(markers_px[:, 0], markers_px[:, 1], "o", mfc="none", mec="white", ms=14, mew=1.5)
    if zoom_px and detection is not None and not detection.lost:
        inset = ax.inset_axes([0.68, 0.62, 0.3, 0.36])
        inset.imshow(rgb)
        _overlay(inset)
        inset.set_xlim(detection.x_px - zoom_px / 2, detection.x_px + zoom_px / 2)
        inset.set_ylim(detection.y_px + zoom_px / 2, detection.y_px - zoom_px / 2)
        inset.set_xticks([])
        inset.set_yticks([])
        for spine in inset.spines.values():
            spine.set_edgecolor("white")
        return inset
    return None
