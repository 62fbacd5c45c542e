"""Plotting helpers used by the book's notebooks."""

from softpend.plotting.rod import draw_rod, render_rod_rgb

__all__ = ["draw_rod", "render_rod_rgb"]
