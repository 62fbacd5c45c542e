"""The rig's geometry from the rod's parameters: a printed beam of the rod's flexural rigidity (thickness
``(12 EI / (E_print W)) ** (1/3)``), hub mount, steel tip disc, calibration markers and a square-on camera."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from softpend.checks import instance_of, positive
from softpend.plant.params import RodParams
from softpend.vision.camera import DEFAULT_MARKERS_M, CameraModel

STEEL_DENSITY_KG_M3 = 7850.0
#: Radius of the calibration markers and of the tip dot's disc [m].
MARKER_RADIUS_M = 0.011
#: Young's modulus of printed TPU filaments, Shore 85A to 98A [Pa].
TPU_MODULUS_RANGE_PA = (10.0e6, 100.0e6)
#: Thinnest beam a printer lays down [m].
PRINTABLE_THICKNESS_M = 1.0e-4


@dataclass(frozen=True)
class MotorCartridge:
    """A gear cartridge of the VEX V5 Smart Motor (published figures at 12 V, at the output)."""

    name: str
    free_speed_rad_s: float
    stall_torque_nm: float
    encoder_ticks_per_rev: int

    def available_torque_nm(self, speed_rad_s: float) -> float:
        """Torque at ``speed_rad_s`` on the full supply (the DC motor line), 0 beyond the free speed [N m]."""
        return self.stall_torque_nm * max(0.0, 1.0 - abs(float(speed_rad_s)) / self.free_speed_rad_s)


_RPM = 2.0 * math.pi / 60.0
#: The three V5 Smart Motor cartridges, coarse to fine speed.
V5_CARTRIDGES: tuple[MotorCartridge, ...] = (
    MotorCartridge("red 36:1", 100.0 * _RPM, 4.2, 1800),
    MotorCartridge("green 18:1", 200.0 * _RPM, 2.1, 900),
    MotorCartridge("blue 6:1", 600.0 * _RPM, 0.7, 300),
)


@dataclass(frozen=True)
class CameraSpec:
    """The camera filming the rod's plane: image size and horizontal field of view [deg] of the video mode."""

    width_px: int = 640
    height_px: int = 480
    horizontal_fov_deg: float = 62.2


@dataclass(frozen=True)
class HubSpec:
    """The printed hub mount, hub marker flag and clearances around the rod [m]."""

    shaft_side_m: float = 0.125 * 0.0254
    clamp_radius_m: float = 0.012
    pocket_start_m: float = 0.004
    mount_thickness_m: float = 0.012
    hub_marker_radius_m: float = 0.035
    hub_marker_dot_radius_m: float = 0.007
    flag_gap_m: float = 0.003
    marker_clearance_m: float = 0.05
    keep_out_margin_m: float = 0.10


@dataclass(frozen=True)
class RigDesign:
    """Dimensions of the rig for one rod (:func:`rig_design`) [SI; beam thickness in plane; markers: hub at 0, y up]."""

    params: RodParams
    print_modulus_pa: float
    beam_length_m: float
    beam_width_m: float
    beam_thickness_m: float
    beam_mass_kg: float
    out_of_plane_stiffness_ratio: float
    tip_disc_thickness_m: float
    dot_radius_m: float
    swing_radius_m: float
    keep_out_radius_m: float
    flag_length_m: float
    markers_m: np.ndarray = field(repr=False)
    camera_model: CameraModel
    camera_distance_m: float
    hub: HubSpec
    camera: CameraSpec

    @property
    def pixel_size_m(self) -> float:
        """Side of one pixel in the rod's plane [m]."""
        return 1.0 / self.camera_model.px_per_m

    @property
    def field_of_view_m(self) -> tuple[float, float]:
        """Width and height of the rod's plane the image covers [m]."""
        return self.camera.width_px * self.pixel_size_m, self.camera.height_px * self.pixel_size_m

    def depth_error_m(self, offset_m: float = 0.001) -> float:
        """Tip position error of the affine map when the dot lies ``offset_m`` in front of the markers' plane [m]."""
        return abs(offset_m) / self.camera_distance_m * self.swing_radius_m

    @property
    def min_marker_gap_m(self) -> float:
        """Least gap between a marker's edge and the swing circle [m]."""
        return float(np.min(np.hypot(*self.markers_m.T))) - MARKER_RADIUS_M - self.swing_radius_m

    def _in_view(self, centres_m: np.ndarray, radius_m: float) -> bool:
        """Whether the circles of ``radius_m`` around ``centres_m`` lie wholly inside the image."""
        px = self.camera_model.to_pixels(centres_m).reshape(-1, 2)
        r = radius_m * self.camera_model.px_per_m
        return bool(np.all(px - r >= 0) and np.all(px + r <= (self.camera.width_px, self.camera.height_px)))

    def markers_in_view(self) -> bool:
        return self._in_view(self.markers_m, MARKER_RADIUS_M)

    def swing_in_view(self) -> bool:
        return self._in_view(np.zeros(2), self.swing_radius_m)

    def to_dict(self) -> dict:
        """The design's figures as JSON numbers (millimetres where the key says ``_mm``)."""
        mm = {name: getattr(self, name + "_m") for name in _MM_FIELDS}
        mm.update(mount_boss_radius=self.hub.clamp_radius_m, mount_bore=self.hub.shaft_side_m)
        mm.update(hub_marker_radius=self.hub.hub_marker_radius_m, marker_diameter=2 * MARKER_RADIUS_M)
        mm.update(rod_length=self.params.length_m, tip_disc_diameter=2 * self.dot_radius_m)
        return {
            **{f"{name}_mm": 1e3 * value for name, value in mm.items()},
            "bending_stiffness_nm2": self.params.bending_stiffness_nm2,
            "print_modulus_mpa": self.print_modulus_pa / 1e6,
            "beam_mass_g": 1e3 * self.beam_mass_kg,
            "out_of_plane_stiffness_ratio": self.out_of_plane_stiffness_ratio,
            "tip_mass_g": 1e3 * self.params.tip_mass_kg,
            "markers_m": [[float(x), float(y)] for x, y in self.markers_m],
            "camera_px_per_m": self.camera_model.px_per_m,
            "field_of_view_mm": [1e3 * side for side in self.field_of_view_m],
            "dot_area_px": math.pi * (self.dot_radius_m / self.pixel_size_m) ** 2,
            "markers_in_view": self.markers_in_view(),
            "swing_in_view": self.swing_in_view(),
        }


_MM_FIELDS = (
    "beam_length beam_width beam_thickness tip_disc_thickness flag_length swing_radius keep_out_radius min_marker_gap "
    "camera_distance pixel_size"
).split()


def rig_design(params: Optional[RodParams] = None, print_modulus_pa: Optional[float] = None) -> RigDesign:
    """The rig's dimensions for the rod ``params``, its beam printed at ``print_modulus_pa`` (default the rod's
    modulus); ``ValueError`` for a rod without bending stiffness or shorter than the clamp, or an unprintable beam."""
    params = params if params is not None else RodParams()
    instance_of("params", params, RodParams)
    camera, hub = CameraSpec(), HubSpec()
    modulus = positive("print_modulus_pa", params.youngs_modulus_pa if print_modulus_pa is None else print_modulus_pa)
    ei = params.bending_stiffness_nm2
    if not ei > 0:
        raise ValueError("params: the rod has no bending stiffness (youngs_modulus_pa or stiffness_scale is 0)")
    if params.length_m <= 2 * hub.clamp_radius_m:
        raise ValueError(
            f"params.length_m must exceed twice the clamp radius {hub.clamp_radius_m} m, got {params.length_m!r}"
        )
    width = params.width_m
    thickness = (12.0 * ei / (modulus * width)) ** (1.0 / 3.0)
    if not PRINTABLE_THICKNESS_M <= thickness <= params.length_m:  # also NaN
        raise ValueError(
            f"print_modulus_pa {modulus:g} Pa gives a beam {thickness * 1e3:.3g} mm thick for the rod's "
            f"bending stiffness; a printable beam is {PRINTABLE_THICKNESS_M * 1e3:g} mm to the rod's "
            f"length ({params.length_m * 1e3:g} mm) thick"
        )
    density = params.mass_kg / (params.width_m * params.depth_m * params.length_m)
    dot_radius = MARKER_RADIUS_M
    swing = params.length_m + dot_radius
    default_markers = np.array(DEFAULT_MARKERS_M, dtype=float)
    needed = swing + hub.marker_clearance_m + MARKER_RADIUS_M
    scale = max(1.0, needed / float(np.min(np.hypot(*default_markers.T))))
    base = CameraModel()
    w, h = camera.width_px, camera.height_px
    centre = (base.centre_px[0] * w / base.width_px, base.centre_px[1] * h / base.height_px)
    model = CameraModel(width_px=w, height_px=h, px_per_m=base.px_per_m / scale, centre_px=centre, roll_rad=0.0)
    fov_width = w / model.px_per_m
    return RigDesign(
        params=params,
        print_modulus_pa=modulus,
        beam_length_m=params.length_m - hub.pocket_start_m,
        beam_width_m=width,
        beam_thickness_m=thickness,
        beam_mass_kg=density * width * thickness * params.length_m,
        out_of_plane_stiffness_ratio=(width / thickness) ** 2,
        tip_disc_thickness_m=params.tip_mass_kg / (STEEL_DENSITY_KG_M3 * math.pi * dot_radius**2),
        dot_radius_m=dot_radius,
        swing_radius_m=swing,
        keep_out_radius_m=swing + hub.keep_out_margin_m,
        flag_length_m=hub.hub_marker_radius_m + hub.hub_marker_dot_radius_m + 0.003,
        markers_m=default_markers * scale,
        camera_model=model,
        camera_distance_m=fov_width / (2.0 * math.tan(math.radians(camera.horizontal_fov_deg) / 2.0)),
        hub=hub,
        camera=camera,
    )
