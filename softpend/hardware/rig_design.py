"""The rig's geometry and parts, computed from the rod's parameters.

:func:`rig_design` turns a :class:`~softpend.plant.params.RodParams` into the dimensions of what is printed,
bought and placed: the TPU beam, the hub mount on the motor shaft, the tip mass with its blue dot, the green
calibration markers and the camera.  Every figure follows from the parameters and a few stated parts
(:class:`MotorCartridge`, :class:`CameraSpec`, :class:`HubSpec`), so a change of the rod changes the rig.

The beam section
----------------
The PRB model needs only the beam's flexural rigidity ``EI = E W D**3 / 12 * stiffness_scale``
(:attr:`RodParams.bending_stiffness_nm2`); the joint springs are ``k = EI/(L/n)``.  A beam printed from a
material of modulus ``E_print`` and width ``W`` (out of the camera plane) has that rigidity when its
thickness in the bending direction (in the camera plane) is::

    D_print = (12 EI / (E_print W)) ** (1/3)

With ``E_print`` equal to the parameters' modulus this is the parameters' own depth ``D``.  The beam bends
in the camera plane because the out-of-plane rigidity ``E D W**3 / 12`` is ``(W/D)**2`` times larger.  The
print's mass is ``rho W D_print L`` with the density ``rho = m / (W D L)`` the parameters imply.

The camera
----------
The camera looks square-on at the rod's plane, its optical axis through the hub axis, so the plane maps to
the image by an affine map (:mod:`softpend.vision.calibration`).  The scene of the synthetic camera
(:class:`~softpend.vision.camera.CameraModel`, :data:`~softpend.vision.camera.DEFAULT_MARKERS_M`) is the
design for the default rod; a longer rod scales the marker layout and the field of view by the same factor,
so that every marker stays outside the swing circle by :attr:`HubSpec.marker_clearance_m`.  A lens of
horizontal field of view ``alpha`` covers the field width ``F`` from the distance ``F / (2 tan(alpha/2))``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from softpend.checks import int_at_least, positive
from softpend.plant.params import RodParams
from softpend.vision.camera import DEFAULT_MARKERS_M, CameraModel

__all__ = [
    "MARKER_RADIUS_M",
    "STEEL_DENSITY_KG_M3",
    "TPU_MODULUS_RANGE_PA",
    "V5_CARTRIDGES",
    "CameraSpec",
    "HubSpec",
    "MotorCartridge",
    "RigDesign",
    "rig_design",
]

#: Density of the steel tip mass [kg/m^3].
STEEL_DENSITY_KG_M3 = 7850.0
#: Radius of the printed green calibration markers and of the blue tip dot's disc [m] (the synthetic camera's
#: 11 mm dot; its markers are drawn 7 px wide at 640 px/m, the same size).
MARKER_RADIUS_M = 0.011
#: Young's modulus of printed TPU filaments, Shore 85A to 98A, from the range of manufacturers' data sheets
#: [Pa].  The modulus of a print also depends on infill, layer orientation and temperature: the static sag
#: test of the assembled rod (:attr:`RigDesign.rows`) measures it.
TPU_MODULUS_RANGE_PA = (10.0e6, 100.0e6)
#: Thinnest beam a printer lays down (two layers of 0.05 mm) [m].
PRINTABLE_THICKNESS_M = 1.0e-4


@dataclass(frozen=True)
class MotorCartridge:
    """A gear cartridge of the VEX V5 Smart Motor (published figures at 12 V).

    Parameters
    ----------
    name : str
        Label (colour and ratio).
    free_speed_rad_s : float
        Output speed without load [rad/s].
    stall_torque_nm : float
        Output torque at stall [N m].
    encoder_ticks_per_rev : int
        Encoder ticks per output revolution.
    """

    name: str
    free_speed_rad_s: float
    stall_torque_nm: float
    encoder_ticks_per_rev: int

    def __post_init__(self) -> None:
        positive("free_speed_rad_s", self.free_speed_rad_s)
        positive("stall_torque_nm", self.stall_torque_nm)
        int_at_least("encoder_ticks_per_rev", self.encoder_ticks_per_rev, 4)

    def available_torque_nm(self, speed_rad_s: float) -> float:
        """Torque the motor can give at ``speed_rad_s`` on the full supply, ``stall (1 - |w|/w_free)`` (the DC motor
        line of the device program's model), 0 beyond the free speed [N m]."""
        return self.stall_torque_nm * max(0.0, 1.0 - abs(float(speed_rad_s)) / self.free_speed_rad_s)

    @property
    def encoder_resolution_rad(self) -> float:
        """Hub angle of one encoder tick [rad]."""
        return 2.0 * math.pi / self.encoder_ticks_per_rev


_RPM = 2.0 * math.pi / 60.0
#: The three V5 Smart Motor cartridges (red, green, blue), coarse to fine speed.
V5_CARTRIDGES: tuple[MotorCartridge, ...] = (
    MotorCartridge("red 36:1", 100.0 * _RPM, 4.2, 1800),
    MotorCartridge("green 18:1", 200.0 * _RPM, 2.1, 900),
    MotorCartridge("blue 6:1", 600.0 * _RPM, 0.7, 300),
)


@dataclass(frozen=True)
class CameraSpec:
    """The camera filming the rod's plane.

    Parameters
    ----------
    width_px, height_px : int
        Image size of the video mode used.
    horizontal_fov_deg : float
        Horizontal field of view of the lens in that mode [deg] (62.2 for the Raspberry Pi Camera Module 2 at
        its full field).
    """

    width_px: int = 640
    height_px: int = 480
    horizontal_fov_deg: float = 62.2

    def __post_init__(self) -> None:
        int_at_least("width_px", self.width_px, 16)
        int_at_least("height_px", self.height_px, 16)
        fov = positive("horizontal_fov_deg", self.horizontal_fov_deg)
        if fov >= 180:
            raise ValueError(f"horizontal_fov_deg must be below 180, got {self.horizontal_fov_deg!r}")


@dataclass(frozen=True)
class HubSpec:
    """The printed hub mount and the clearances around the rod.

    Parameters
    ----------
    shaft_side_m : float
        Side of the motor's square drive shaft (the V5 1/8 inch shaft) [m]; the mount's bore.
    clamp_radius_m : float
        Radius of the mount's round boss around the shaft: the beam leaves the mount at this distance from the
        hub axis [m].
    pocket_start_m : float
        Distance from the hub axis to the inner end of the beam's pocket in the mount [m].
    mount_thickness_m : float
        Thickness of the mount along the shaft [m].
    hub_marker_radius_m : float
        Distance of the magenta hub marker from the axis along the rod [m] (the synthetic camera's 35 mm).  The
        marker sits on a rigid flag of the mount that runs along the rod ``flag_gap_m`` in front of the beam
        (towards the camera), so that it turns with the hub while the beam bends freely behind it.
    hub_marker_dot_radius_m : float
        Radius of the hub marker dot [m].
    flag_gap_m : float
        Gap between the marker flag and the beam's front face [m].
    marker_clearance_m : float
        Least gap between a calibration marker's edge and the swing circle [m].
    keep_out_margin_m : float
        Margin beyond the swing circle that must stay clear of hands and objects while the motor is on [m].
    """

    shaft_side_m: float = 0.125 * 0.0254
    clamp_radius_m: float = 0.012
    pocket_start_m: float = 0.004
    mount_thickness_m: float = 0.012
    hub_marker_radius_m: float = 0.035
    hub_marker_dot_radius_m: float = 0.007
    flag_gap_m: float = 0.003
    marker_clearance_m: float = 0.05
    keep_out_margin_m: float = 0.10

    def __post_init__(self) -> None:
        for name in (
            "shaft_side_m",
            "clamp_radius_m",
            "pocket_start_m",
            "mount_thickness_m",
            "hub_marker_radius_m",
            "hub_marker_dot_radius_m",
            "flag_gap_m",
            "marker_clearance_m",
            "keep_out_margin_m",
        ):
            positive(name, getattr(self, name))
        if not self.pocket_start_m < self.clamp_radius_m:
            raise ValueError(f"pocket_start_m must be below clamp_radius_m, got {self.pocket_start_m!r}")
        if self.pocket_start_m < self.shaft_side_m * math.sqrt(0.5):
            raise ValueError(
                f"pocket_start_m must clear the shaft's bore (half-diagonal "
                f"{self.shaft_side_m * math.sqrt(0.5):.4g} m), got {self.pocket_start_m!r}"
            )


@dataclass(frozen=True)
class RigDesign:
    """Dimensions of the rig for one rod (see :func:`rig_design`; SI units).

    Attributes
    ----------
    params : RodParams
        The rod.
    print_modulus_pa : float
        Modulus of the material the beam is printed from [Pa].
    beam_length_m, beam_width_m, beam_thickness_m : float
        The printed beam: from the pocket's inner end to the tip, out of plane, in plane (bending) [m].
    beam_mass_kg : float
        Mass of the printed beam at the density the parameters imply [kg].
    out_of_plane_stiffness_ratio : float
        Out-of-plane over in-plane flexural rigidity, ``(W / D_print)**2``.
    tip_disc_thickness_m : float
        Thickness of a steel disc of the dot's diameter that has the tip mass [m].
    dot_radius_m : float
        Radius of the blue dot on the tip disc [m].
    swing_radius_m : float
        Radius of the circle the straight rod's dot sweeps, ``L`` plus the dot radius [m].
    keep_out_radius_m : float
        Radius that must stay clear while the motor is on [m].
    flag_length_m : float
        Length of the mount's marker flag from the hub axis (it carries the hub marker) [m].
    markers_m : ndarray, shape (4, 2)
        Calibration marker centres in the rod's plane [m] (hub axis at the origin, y up).
    marker_scale : float
        Factor applied to :data:`DEFAULT_MARKERS_M` (1 for the default rod).
    camera_model : CameraModel
        The affine camera of the design (no roll, hub at the image centre used by the synthetic camera).
    camera_distance_m : float
        Lens to rod plane [m].
    hub : HubSpec, camera : CameraSpec
        The parts assumed.
    """

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
    marker_scale: float
    camera_model: CameraModel
    camera_distance_m: float
    hub: HubSpec
    camera: CameraSpec

    # ------------------------------------------------------------------ camera figures
    @property
    def pixel_size_m(self) -> float:
        """Side of one pixel in the rod's plane [m]."""
        return 1.0 / self.camera_model.px_per_m

    @property
    def field_of_view_m(self) -> tuple[float, float]:
        """Width and height of the rod's plane the image covers [m]."""
        return self.camera.width_px * self.pixel_size_m, self.camera.height_px * self.pixel_size_m

    @property
    def dot_area_px(self) -> float:
        """Area of the blue dot in the image [px^2] (the tracker needs at least its ``min_area_px``)."""
        return math.pi * (self.dot_radius_m / self.pixel_size_m) ** 2

    def depth_error_m(self, offset_m: float = 0.001) -> float:
        """Tip position error of the affine map when the dot lies ``offset_m`` in front of the markers' plane:
        the scale error ``offset / distance`` times the swing radius [m]."""
        return abs(offset_m) / self.camera_distance_m * self.swing_radius_m

    @property
    def min_marker_gap_m(self) -> float:
        """Least gap between a marker's edge and the swing circle [m]."""
        return float(np.min(np.hypot(*self.markers_m.T))) - MARKER_RADIUS_M - self.swing_radius_m

    def markers_in_view(self) -> bool:
        """Whether every marker lies wholly inside the image."""
        px = self.camera_model.to_pixels(self.markers_m)
        r = MARKER_RADIUS_M * self.camera_model.px_per_m
        return bool(
            np.all(px - r >= 0)
            and np.all(px[:, 0] + r <= self.camera.width_px)
            and np.all(px[:, 1] + r <= self.camera.height_px)
        )

    def swing_in_view(self) -> bool:
        """Whether the whole swing circle lies inside the image."""
        centre = self.camera_model.to_pixels(np.zeros(2))
        r = self.swing_radius_m * self.camera_model.px_per_m
        return bool(
            centre[0] - r >= 0
            and centre[1] - r >= 0
            and centre[0] + r <= self.camera.width_px
            and centre[1] + r <= self.camera.height_px
        )

    def to_dict(self) -> dict:
        """The design's figures as plain numbers (JSON), lengths in millimetres where the key says ``_mm``."""
        fov_w, fov_h = self.field_of_view_m
        return {
            "rod_length_mm": 1e3 * self.params.length_m,
            "bending_stiffness_nm2": self.params.bending_stiffness_nm2,
            "print_modulus_mpa": self.print_modulus_pa / 1e6,
            "beam_length_mm": 1e3 * self.beam_length_m,
            "beam_width_mm": 1e3 * self.beam_width_m,
            "beam_thickness_mm": 1e3 * self.beam_thickness_m,
            "beam_mass_g": 1e3 * self.beam_mass_kg,
            "out_of_plane_stiffness_ratio": self.out_of_plane_stiffness_ratio,
            "tip_mass_g": 1e3 * self.params.tip_mass_kg,
            "tip_disc_diameter_mm": 2e3 * self.dot_radius_m,
            "tip_disc_thickness_mm": 1e3 * self.tip_disc_thickness_m,
            "mount_boss_radius_mm": 1e3 * self.hub.clamp_radius_m,
            "flag_length_mm": 1e3 * self.flag_length_m,
            "mount_bore_mm": 1e3 * self.hub.shaft_side_m,
            "hub_marker_radius_mm": 1e3 * self.hub.hub_marker_radius_m,
            "swing_radius_mm": 1e3 * self.swing_radius_m,
            "keep_out_radius_mm": 1e3 * self.keep_out_radius_m,
            "markers_m": [[float(x), float(y)] for x, y in self.markers_m],
            "marker_diameter_mm": 2e3 * MARKER_RADIUS_M,
            "min_marker_gap_mm": 1e3 * self.min_marker_gap_m,
            "camera_distance_mm": 1e3 * self.camera_distance_m,
            "camera_px_per_m": self.camera_model.px_per_m,
            "pixel_size_mm": 1e3 * self.pixel_size_m,
            "field_of_view_mm": [1e3 * fov_w, 1e3 * fov_h],
            "dot_area_px": self.dot_area_px,
            "markers_in_view": self.markers_in_view(),
            "swing_in_view": self.swing_in_view(),
        }


def rig_design(
    params: Optional[RodParams] = None,
    print_modulus_pa: Optional[float] = None,
    camera: Optional[CameraSpec] = None,
    hub: Optional[HubSpec] = None,
) -> RigDesign:
    """The rig's dimensions for the rod ``params`` (module docstring for the formulas).

    Parameters
    ----------
    params : RodParams, optional
        The rod (default: the project's default rod).
    print_modulus_pa : float, optional
        Modulus of the beam's material [Pa] (default ``params.youngs_modulus_pa``: the parameters' own section).
    camera : CameraSpec, optional
        The camera (default :class:`CameraSpec`).
    hub : HubSpec, optional
        Mount and clearances (default :class:`HubSpec`).

    Raises
    ------
    ValueError
        If ``params`` is not a RodParams, the rod has no bending stiffness (a hinged chain cannot be printed as
        a beam), or the rod is shorter than the mount's clamp.
    """
    params = params if params is not None else RodParams()
    if not isinstance(params, RodParams):
        raise ValueError(f"params must be a RodParams, got {type(params).__name__}")
    camera = camera if camera is not None else CameraSpec()
    hub = hub if hub is not None else HubSpec()
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
    if not PRINTABLE_THICKNESS_M <= thickness <= params.length_m:  # also NaN; a drawing of it would never end
        raise ValueError(
            f"print_modulus_pa {modulus:g} Pa gives a beam {thickness * 1e3:.3g} mm thick for the rod's "
            f"bending stiffness; a printable beam is {PRINTABLE_THICKNESS_M * 1e3:g} mm to the rod's "
            f"length ({params.length_m * 1e3:g} mm) thick"
        )
    density = params.mass_kg / (params.width_m * params.depth_m * params.length_m)
    beam_length = params.length_m - hub.pocket_start_m
    dot_radius = MARKER_RADIUS_M
    tip_disc = params.tip_mass_kg / (STEEL_DENSITY_KG_M3 * math.pi * dot_radius**2)
    swing = params.length_m + dot_radius
    default_markers = np.array(DEFAULT_MARKERS_M, dtype=float)
    needed = swing + hub.marker_clearance_m + MARKER_RADIUS_M
    scale = max(1.0, needed / float(np.min(np.hypot(*default_markers.T))))
    base = CameraModel()
    model = CameraModel(
        width_px=camera.width_px,
        height_px=camera.height_px,
        px_per_m=base.px_per_m / scale,
        centre_px=(
            base.centre_px[0] * camera.width_px / base.width_px,
            base.centre_px[1] * camera.height_px / base.height_px,
        ),
        roll_rad=0.0,
    )
    fov_width = camera.width_px / model.px_per_m
    distance = fov_width / (2.0 * math.tan(math.radians(camera.horizontal_fov_deg) / 2.0))
    flag_length = hub.hub_marker_radius_m + hub.hub_marker_dot_radius_m + 0.003
    return RigDesign(
        params=params,
        print_modulus_pa=modulus,
        beam_length_m=beam_length,
        beam_width_m=width,
        beam_thickness_m=thickness,
        beam_mass_kg=density * width * thickness * params.length_m,
        out_of_plane_stiffness_ratio=(width / thickness) ** 2,
        tip_disc_thickness_m=tip_disc,
        dot_radius_m=dot_radius,
        swing_radius_m=swing,
        keep_out_radius_m=swing + hub.keep_out_margin_m,
        flag_length_m=flag_length,
        markers_m=default_markers * scale,
        marker_scale=scale,
        camera_model=model,
        camera_distance_m=distance,
        hub=hub,
        camera=camera,
    )
