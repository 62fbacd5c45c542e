"""Plotting helpers used by the book's notebooks: drawing the rod with matplotlib, or into an RGB array for
``env.render()``."""

from __future__ import annotations

import numpy as np

__all__ = ["draw_rod", "render_rod_rgb"]


def draw_rod(ax, points_m: np.ndarray, color: str = "C0", label: str | None = None):
    """Draw a rod given its ``(n + 1, 2)`` joint positions [m] (hub first) on a matplotlib axis."""
    points_m = np.asarray(points_m, dtype=float)
    (line,) = ax.plot(points_m[:, 0], points_m[:, 1], "-", color=color, lw=2.5, label=label)
    ax.plot(points_m[1:-1, 0], points_m[1:-1, 1], "o", color=color, ms=4)
    ax.plot(points_m[-1, 0], points_m[-1, 1], "o", color="tab:blue", ms=7)
    ax.plot(0, 0, "s", color="k", ms=8)
    ax.set_aspect("equal")
    return line


def render_rod_rgb(points_m: np.ndarray, length_m: float, size_px: int = 400) -> np.ndarray:
    """Render the rod into an ``(size_px, size_px, 3)`` uint8 RGB image (white background, hub centred)."""
    import cv2

    points_m = np.asarray(points_m, dtype=float)
    image = np.full((size_px, size_px, 3), 255, dtype=np.uint8)
    scale = 0.45 * size_px / float(length_m)
    centre = np.array([size_px / 2, size_px / 2])
    pixels = np.round(centre + np.column_stack([points_m[:, 0], -points_m[:, 1]]) * scale).astype(np.int32)
    cv2.polylines(image, [pixels.reshape(-1, 1, 2)], False, (60, 60, 60), 4, lineType=cv2.LINE_AA)
    cv2.circle(image, tuple(int(v) for v in pixels[-1]), 7, (0, 0, 255), -1, lineType=cv2.LINE_AA)
    cv2.rectangle(image, tuple(int(v) - 6 for v in pixels[0]), tuple(int(v) + 6 for v in pixels[0]), (0, 0, 0), -1)
    return image
