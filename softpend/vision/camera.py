"""The synthetic camera: simulated rod trajectories rendered to video frames with known ground truth.

:class:`SyntheticCamera` looks at the rod's plane through an affine camera (:class:`CameraModel`) and
draws, per frame, a background (plain or cluttered), the green reference markers, the rod through its
joint positions, the hub, and the blue tip dot (anti-aliased, sub-pixel placed).  Options reproduce what
a real camera adds: sensor noise, motion blur (the frame is the average of sub-frames over the exposure),
and lighting changes (a slowly varying global gain and a gradient).  The ground truth of a frame is the
tip's pixel position averaged over the exposure (what a blurred dot's centroid should be).

:func:`render_video` writes frames with ``cv2.VideoWriter`` plus a sidecar JSON (frame timestamps on the
camera clock, marker layout, truth) that ``softpend track`` and the time synchronisation read.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Iterator, Optional, Sequence

import cv2
import numpy as np

from softpend.checks import int_at_least, non_negative, positive
from softpend.vision.calibration import AffineCalibration, points_array, read_json_file

__all__ = [
    "DEFAULT_MARKERS_M",
    "MAX_FPS",
    "CameraEffects",
    "CameraModel",
    "RenderedClip",
    "SyntheticCamera",
    "render_video",
    "read_sidecar",
    "check_fps",
    "check_sidecar",
]

#: Highest frame rate accepted [1/s] (beyond any camera; a larger value is a typo or garbage).
MAX_FPS = 1e6
#: Largest sidecar file read [bytes] (about two hours of 100 frames/s).
MAX_SIDECAR_BYTES = 64 << 20


def check_fps(name: str, value) -> float:
    """``value`` as a frame rate in (0, :data:`MAX_FPS`] [1/s], else ``ValueError`` naming ``name``."""
    fps = positive(name, value)
    if fps > MAX_FPS:
        raise ValueError(f"{name} must be at most {MAX_FPS:g} frames/s, got {value!r}")
    return fps


#: Reference-marker layout in the rod plane [m] (asymmetric, so the marker correspondence is unique).
DEFAULT_MARKERS_M: tuple[tuple[float, float], ...] = ((-0.42, 0.31), (0.42, 0.31), (0.40, -0.30), (-0.22, -0.33))

_TIP_BGR = (200, 70, 20)  # the blue dot
_MARKER_BGR = (40, 170, 30)  # green markers
_ROD_BGR = (70, 70, 70)
_HUB_MARKER_BGR = (180, 0, 220)  # magenta
_HUB_BGR = (20, 20, 20)


@dataclass(frozen=True)
class CameraModel:
    """Affine camera on the rod's plane: metres (hub at the origin, y up) to pixels (y down).

    ``pixel = centre + s * R(roll) @ diag(1, aspect) @ [[1, shear], [0, 1]] @ [x, -y]``.
    """

    width_px: int = 640
    height_px: int = 480
    px_per_m: float = 640.0
    centre_px: tuple[float, float] = (320.0, 238.0)
    roll_rad: float = 0.03
    aspect: float = 1.0
    shear: float = 0.0

    def __post_init__(self) -> None:
        if self.width_px < 16 or self.height_px < 16:
            raise ValueError(f"width_px and height_px must be >= 16, got {self.width_px}x{self.height_px}")
        if not (math.isfinite(self.px_per_m) and self.px_per_m > 0):
            raise ValueError(f"px_per_m must be positive, got {self.px_per_m!r}")
        if not (math.isfinite(self.aspect) and self.aspect > 0):
            raise ValueError(f"aspect must be positive, got {self.aspect!r}")

    def metre_to_pixel(self) -> np.ndarray:
        """The 2x3 matrix ``pixel = M @ [x_m, y_m, 1]``."""
        c, s = math.cos(self.roll_rad), math.sin(self.roll_rad)
        rot = np.array([[c, -s], [s, c]])
        linear = self.px_per_m * rot @ np.diag([1.0, self.aspect]) @ np.array([[1.0, self.shear], [0.0, 1.0]])
        linear = linear @ np.diag([1.0, -1.0])
        return np.column_stack([linear, np.asarray(self.centre_px, dtype=float)])

    def to_pixels(self, points_m: np.ndarray) -> np.ndarray:
        m = self.metre_to_pixel()
        return np.asarray(points_m, dtype=float) @ m[:, :2].T + m[:, 2]

    def calibration(self) -> AffineCalibration:
        """The exact pixel -> metre map of this camera (ground truth for calibration tests)."""
        m = self.metre_to_pixel()
        linear = np.linalg.inv(m[:, :2])
        return AffineCalibration(np.column_stack([linear, -linear @ m[:, 2]]))


@dataclass(frozen=True)
class CameraEffects:
    """Imperfections of the synthetic camera (all off by default: a clean camera).

    Parameters
    ----------
    noise_std_dn : float
        Gaussian sensor noise, standard deviation in 8-bit digital numbers.
    exposure_s : float
        Exposure time [s]; > 0 gives motion blur (``blur_subframes`` renders averaged over it).
    blur_subframes : int
        Sub-frames averaged over the exposure.
    lighting_amplitude : float
        Relative amplitude of a slow global gain change, ``1 + a sin(2 pi f t)``.
    lighting_frequency_hz : float
        Frequency of the gain change [Hz].
    gradient : float
        Relative brightness difference across the image (uneven lighting).
    clutter : bool
        Draw background clutter (coloured shapes and lines; a few tiny blue specks below the tracker's
        minimum area).
    """

    noise_std_dn: float = 0.0
    exposure_s: float = 0.0
    blur_subframes: int = 5
    lighting_amplitude: float = 0.0
    lighting_frequency_hz: float = 0.3
    gradient: float = 0.0
    clutter: bool = False

    def __post_init__(self) -> None:
        for name in ("noise_std_dn", "exposure_s", "lighting_amplitude", "gradient"):
            non_negative(name, getattr(self, name))
        if self.lighting_amplitude >= 1:
            raise ValueError(f"lighting_amplitude must be < 1, got {self.lighting_amplitude!r}")
        int_at_least("blur_subframes", self.blur_subframes, 1)

    @classmethod
    def noisy(cls) -> "CameraEffects":
        """The "noisy" condition of the benchmark: noise, blur, lighting changes and clutter."""
        return cls(
            noise_std_dn=6.0,
            exposure_s=0.008,
            blur_subframes=5,
            lighting_amplitude=0.25,
            lighting_frequency_hz=0.5,
            gradient=0.3,
            clutter=True,
        )

    @classmethod
    def rig(cls) -> "CameraEffects":
        """The nominal rig camera of the digital twin: mild sensor noise, 4 ms exposure blur, a slow
        lighting drift and a gradient (the default of :func:`softpend.hardware.twin.run_twin_session`)."""
        return cls(noise_std_dn=3.0, exposure_s=0.004, blur_subframes=3, lighting_amplitude=0.1, gradient=0.1)


@dataclass
class RenderedClip:
    """Frames (optional), their camera-clock timestamps and the true tip pixel positions."""

    timestamps_s: np.ndarray
    tip_px: np.ndarray
    frames: Optional[list[np.ndarray]] = None


class SyntheticCamera:
    """Render the rod to BGR frames.

    Parameters
    ----------
    model : CameraModel
        Geometry.
    effects : CameraEffects
        Imperfections.
    markers_m : sequence of (x, y)
        Reference markers in the rod plane [m].
    dot_radius_m : float
        Radius of the blue tip dot [m].
    rod_width_m : float
        Drawn rod width [m].
    hub_marker_radius_m : float or None
        Distance of the magenta hub marker (on the rod clamp, turning with the hub) from the hub axis
        [m]; None draws no marker.
    seed : int
        Seed for clutter and noise.
    """

    def __init__(
        self,
        model: Optional[CameraModel] = None,
        effects: Optional[CameraEffects] = None,
        markers_m: Sequence[Sequence[float]] = DEFAULT_MARKERS_M,
        dot_radius_m: float = 0.011,
        rod_width_m: float = 0.01,
        hub_marker_radius_m: Optional[float] = 0.035,
        seed: int = 0,
    ) -> None:
        self.model = model if model is not None else CameraModel()
        self.effects = effects if effects is not None else CameraEffects()
        self.markers_m = np.asarray(markers_m, dtype=float)
        if not (dot_radius_m > 0):
            raise ValueError(f"dot_radius_m must be positive, got {dot_radius_m!r}")
        self.dot_radius_m = float(dot_radius_m)
        self.rod_width_m = float(rod_width_m)
        self.hub_marker_radius_m = hub_marker_radius_m
        self.seed = int(seed)
        self._rng = np.random.default_rng(seed)
        self._background = self._make_background()
        m = self.model
        yy, xx = np.mgrid[0 : m.height_px, 0 : m.width_px].astype(np.float32)
        gradient = (1.0 + self.effects.gradient * ((xx / m.width_px) - 0.5)).astype(np.float32)
        self._gradient3 = cv2.merge([gradient, gradient, gradient])
        # sensor noise: per frame a random crop of one larger noise field (fast, and distinct per frame)
        self._noise_margin = 97
        self._noise_field = (
            self._rng.standard_normal(
                (m.height_px + self._noise_margin, m.width_px + self._noise_margin, 3), dtype=np.float32
            )
            * np.float32(self.effects.noise_std_dn)
            if self.effects.noise_std_dn > 0
            else None
        )

    # ------------------------------------------------------------------ scene
    def _make_background(self) -> np.ndarray:
        m = self.model
        image = np.full((m.height_px, m.width_px, 3), (205, 210, 215), dtype=np.uint8)
        if self.effects.clutter:
            rng = np.random.default_rng(self.seed + 7919)
            palette = [
                (60, 60, 200),
                (40, 140, 220),
                (30, 200, 230),
                (150, 150, 150),
                (100, 90, 120),
                (180, 200, 230),
                (80, 110, 140),
            ]  # reds, oranges, yellows, greys, browns: no blue, green or magenta
            for _ in range(25):
                colour = palette[rng.integers(len(palette))]
                kind = rng.integers(3)
                x, y = int(rng.integers(0, m.width_px)), int(rng.integers(0, m.height_px))
                if kind == 0:
                    cv2.rectangle(
                        image, (x, y), (x + int(rng.integers(10, 90)), y + int(rng.integers(10, 60))), colour, -1
                    )
                elif kind == 1:
                    cv2.circle(image, (x, y), int(rng.integers(5, 30)), colour, -1, cv2.LINE_AA)
                else:
                    cv2.line(
                        image,
                        (x, y),
                        (int(rng.integers(0, m.width_px)), int(rng.integers(0, m.height_px))),
                        colour,
                        int(rng.integers(1, 4)),
                        cv2.LINE_AA,
                    )
            for _ in range(6):  # tiny blue specks (below any sensible min_area_px)
                x, y = int(rng.integers(0, m.width_px)), int(rng.integers(0, m.height_px))
                cv2.circle(image, (x, y), 1, _TIP_BGR, -1)
        for centre in self.model.to_pixels(self.markers_m):
            _circle(image, centre, 7.0, _MARKER_BGR)
        return image

    def draw(self, link_points_m: np.ndarray, hub_angle_rad: Optional[float] = None) -> tuple[np.ndarray, np.ndarray]:
        """One sharp, noise-free frame of the rod at ``link_points_m`` ``(n + 1, 2)`` (hub first) [m]
        with the hub at ``hub_angle_rad`` (default: the first link's direction); returns the frame and the
        tip's pixel position."""
        points = np.asarray(link_points_m, dtype=float)
        if points.ndim != 2 or points.shape[1] != 2 or len(points) < 2:
            raise ValueError(f"link_points_m must have shape (n + 1, 2), got {points.shape}")
        image = self._background.copy()
        pixels = self.model.to_pixels(points)
        width = max(1, int(round(self.rod_width_m * self.model.px_per_m)))
        shift = 4
        fixed = np.round(pixels * (1 << shift)).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(image, [fixed], False, _ROD_BGR, width, cv2.LINE_AA, shift)
        hub = pixels[0]
        half = 0.6 * width + 3
        cv2.rectangle(
            image, (int(hub[0] - half), int(hub[1] - half)), (int(hub[0] + half), int(hub[1] + half)), _HUB_BGR, -1
        )
        if self.hub_marker_radius_m:
            if hub_angle_rad is None:
                d = points[1] - points[0]
                hub_angle_rad = math.atan2(-d[0], d[1])
            r = self.hub_marker_radius_m
            marker = self.model.to_pixels(points[0] + r * np.array([-math.sin(hub_angle_rad), math.cos(hub_angle_rad)]))
            _circle(image, marker, 0.45 * width + 1.5, _HUB_MARKER_BGR)
        _circle(image, pixels[-1], self.dot_radius_m * self.model.px_per_m, _TIP_BGR)
        return image, pixels[-1]

    def render(self, sample_points_m, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        """A frame exposed over ``[time_s - exposure_s, time_s]``.

        Parameters
        ----------
        sample_points_m : callable
            ``sample_points_m(t) -> (points, hub_angle_rad)``: link points ``(n + 1, 2)`` [m] and the hub
            angle [rad] (or None) at time ``t``.
        time_s : float
            End of the exposure (the frame's timestamp on the scene clock) [s].

        Returns
        -------
        frame : ndarray (H, W, 3) uint8
        tip_px : ndarray (2,)
            True tip pixel position averaged over the exposure.
        """
        fx = self.effects
        if fx.exposure_s > 0 and fx.blur_subframes > 1:
            times = time_s - fx.exposure_s * (1 - (np.arange(fx.blur_subframes) + 0.5) / fx.blur_subframes)
        else:
            times = np.array([time_s])
        tips = []
        frames = []
        for t in times:
            frame, tip = self.draw(*sample_points_m(float(t)))
            tips.append(tip)
            frames.append(frame)
        tip = np.mean(tips, axis=0)
        gain = 1.0 + fx.lighting_amplitude * math.sin(2 * math.pi * fx.lighting_frequency_hz * time_s)
        if len(frames) == 1 and gain == 1.0 and not fx.gradient and self._noise_field is None:
            return frames[0], tip
        image: np.ndarray = np.zeros(frames[0].shape, np.float32)
        for frame in frames:
            cv2.accumulate(frame, image)
        scale = np.float32(gain / len(frames))
        if fx.gradient:
            image = cv2.multiply(image, self._gradient3, scale=float(scale))
        else:
            image *= scale
        if self._noise_field is not None:
            dy, dx = self._rng.integers(0, self._noise_margin, size=2)
            h, w = image.shape[:2]
            crop = self._noise_field[dy : dy + h, dx : dx + w]
            image = cv2.add(image, crop) if self._rng.integers(0, 2) else cv2.subtract(image, crop)
        image += np.float32(0.5)
        np.clip(image, 0, 255, out=image)
        return image.astype(np.uint8), tip

    def frames(
        self,
        times_s: np.ndarray,
        link_points_m: np.ndarray,
        frame_times_s: np.ndarray,
        hub_angles_rad: Optional[np.ndarray] = None,
    ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Frames for a sampled trajectory.

        Parameters
        ----------
        times_s : ndarray (T,)
            Trajectory sample times [s] (increasing).
        link_points_m : ndarray (T, n + 1, 2)
            Link points at those times [m]; linearly interpolated in between.
        frame_times_s : ndarray (F,)
            Exposure end times of the frames on the same clock [s].
        hub_angles_rad : ndarray (T,), optional
            Hub angle at the sample times [rad] (unwrapped; default: from the first link).
        """
        times_s = np.asarray(times_s, dtype=float)
        link_points_m = np.asarray(link_points_m, dtype=float)
        if link_points_m.ndim != 3 or link_points_m.shape[0] != len(times_s) or link_points_m.shape[2] != 2:
            raise ValueError(f"link_points_m must have shape (len(times_s), n + 1, 2), got {link_points_m.shape}")
        if len(times_s) < 2 or np.any(np.diff(times_s) <= 0):
            raise ValueError("times_s must be increasing with at least 2 samples")
        flat = link_points_m.reshape(len(times_s), -1)
        if hub_angles_rad is not None:
            hub_angles_rad = np.asarray(hub_angles_rad, dtype=float)
            if hub_angles_rad.shape != times_s.shape:
                raise ValueError(f"hub_angles_rad must have shape {times_s.shape}, got {hub_angles_rad.shape}")

        def sample(t: float) -> tuple[np.ndarray, Optional[float]]:
            i = int(np.clip(np.searchsorted(times_s, t) - 1, 0, len(times_s) - 2))
            w = (t - times_s[i]) / (times_s[i + 1] - times_s[i])
            w = min(max(w, 0.0), 1.0)
            hub = None if hub_angles_rad is None else (1 - w) * hub_angles_rad[i] + w * hub_angles_rad[i + 1]
            return ((1 - w) * flat[i] + w * flat[i + 1]).reshape(-1, 2), hub

        for t in np.asarray(frame_times_s, dtype=float):
            yield self.render(sample, float(t))


def _circle(image: np.ndarray, centre_px: np.ndarray, radius_px: float, colour: tuple[int, int, int]) -> None:
    shift = 4
    scale = 1 << shift
    cv2.circle(
        image,
        (int(round(centre_px[0] * scale)), int(round(centre_px[1] * scale))),
        int(round(radius_px * scale)),
        colour,
        -1,
        cv2.LINE_AA,
        shift,
    )


def render_video(
    path: str | Path,
    camera: SyntheticCamera,
    times_s: np.ndarray,
    link_points_m: np.ndarray,
    hub_angles_rad: Optional[np.ndarray] = None,
    fps: float = 100.0,
    clock_offset_s: float = 0.0,
    timestamp_jitter_s: float = 0.0,
    start_s: Optional[float] = None,
    duration_s: Optional[float] = None,
    drop_dot_frames: Sequence[int] = (),
    fourcc: str = "MJPG",
    keep_frames: bool = False,
    progress: bool = False,
) -> RenderedClip:
    """Render a trajectory to a video file and a sidecar ``<path>.json``.

    The camera runs on its own clock: a frame exposed until scene time ``t`` is stamped
    ``t + clock_offset_s`` (+ Gaussian jitter of ``timestamp_jitter_s``), like a Raspberry Pi camera
    whose clock is not the motor controller's.

    Parameters
    ----------
    path : path
        Output video (``.avi`` for MJPG, ``.mp4`` for ``mp4v``).
    camera : SyntheticCamera
        The renderer.
    times_s, link_points_m : ndarray
        The trajectory (see :meth:`SyntheticCamera.frames`), on the scene (= motor) clock [s, m].
    hub_angles_rad : ndarray, optional
        Hub angle at ``times_s`` [rad] (for the hub marker).
    fps : float
        Frame rate [1/s].
    clock_offset_s : float
        Camera clock minus motor clock [s].
    timestamp_jitter_s : float
        Standard deviation of the timestamp noise [s].
    start_s, duration_s : float, optional
        Part of the trajectory to film (default: all of it).
    drop_dot_frames : sequence of int
        Frames in which the dot is hidden (occlusion: the tracker must report them lost).
    fourcc : str
        Codec four-character code.
    keep_frames : bool
        Also return the frames in memory.
    progress : bool
        Show a progress bar.
    """
    path = Path(path)
    check_fps("fps", fps)
    times_s = np.asarray(times_s, dtype=float)
    start = times_s[0] + camera.effects.exposure_s if start_s is None else float(start_s)
    end = times_s[-1] if duration_s is None else start + float(duration_s)
    frame_times = np.arange(start, end + 1e-9, 1.0 / fps)
    rng = np.random.default_rng(camera.seed + 104729)
    stamps = frame_times + clock_offset_s + timestamp_jitter_s * rng.standard_normal(len(frame_times))
    model = camera.model
    writer = cv2.VideoWriter(
        str(path),
        cv2.VideoWriter_fourcc(*fourcc),  # type: ignore[attr-defined]  # not in the stubs
        fps,
        (model.width_px, model.height_px),
    )
    if not writer.isOpened():
        raise ValueError(f"fourcc {fourcc!r}: cannot open a video writer for {path}")
    hidden = set(int(i) for i in drop_dot_frames)
    tips = np.empty((len(frame_times), 2))
    kept: Optional[list[np.ndarray]] = [] if keep_frames else None
    iterator = camera.frames(times_s, link_points_m, frame_times, hub_angles_rad)
    if progress:
        from tqdm.auto import tqdm

        iterator = tqdm(iterator, total=len(frame_times), desc="rendering", unit="frame", mininterval=1.0)
    try:
        for i, (frame, tip) in enumerate(iterator):
            if i in hidden:
                frame = _hide_dot(frame, tip, camera)
                tip = np.array([np.nan, np.nan])
            tips[i] = tip
            writer.write(frame)
            if kept is not None:
                kept.append(frame)
    finally:
        writer.release()
    sidecar = {
        "fps": fps,
        "timestamps_s": stamps.tolist(),
        "scene_times_s": frame_times.tolist(),
        "tip_px": [[None if not np.isfinite(v) else float(v) for v in row] for row in tips],
        "markers_m": camera.markers_m.tolist(),
        "hub_marker_radius_m": camera.hub_marker_radius_m,
        "clock_offset_s": clock_offset_s,
        "camera_model": asdict(camera.model),
        "effects": asdict(camera.effects),
    }
    from softpend.io.outputs import atomic_write

    with atomic_write(str(path) + ".json", "w") as handle:
        handle.write(json.dumps(sidecar))
    return RenderedClip(stamps, tips, kept)


def _hide_dot(frame: np.ndarray, tip_px: np.ndarray, camera: SyntheticCamera) -> np.ndarray:
    """Paint over the dot with the rod colour (an occlusion)."""
    frame = frame.copy()
    radius = camera.dot_radius_m * camera.model.px_per_m + 3
    cv2.circle(frame, (int(round(tip_px[0])), int(round(tip_px[1]))), int(math.ceil(radius)), _ROD_BGR, -1)
    return frame


def read_sidecar(video_path: str | Path) -> dict:
    """The JSON written next to a video by :func:`render_video`, checked by :func:`check_sidecar`.

    Raises
    ------
    FileNotFoundError
        If there is no sidecar.
    ValueError
        If it is not valid JSON, too large, or a field has the wrong type or shape (the message names it).
    """
    path = Path(str(video_path) + ".json")
    if not path.exists():
        raise FileNotFoundError(f"no camera sidecar {path} (pass --markers and --fps instead)")
    data = read_json_file("sidecar", path, MAX_SIDECAR_BYTES)
    try:
        return check_sidecar(data)
    except ValueError as exc:
        raise ValueError(f"sidecar {path}: {exc}") from None


def check_sidecar(data) -> dict:
    """Check the fields a tracker reads from a sidecar: ``fps`` (in (0, :data:`MAX_FPS`]),
    ``timestamps_s`` (a list of finite numbers [s]) and ``markers_m`` (3 to 6 finite (x, y) pairs [m]),
    each optional; returns a copy with those converted (floats, lists), ``ValueError`` naming a bad field."""
    if not isinstance(data, dict):
        raise ValueError(f"must be a JSON object, got {type(data).__name__}")
    out = dict(data)
    if out.get("fps") is not None:
        out["fps"] = check_fps("fps", out["fps"])
    if out.get("timestamps_s") is not None:
        stamps = out["timestamps_s"]
        ok = isinstance(stamps, list) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in stamps
        )
        if not ok:
            raise ValueError("timestamps_s must be a list of finite numbers [s]")
        out["timestamps_s"] = [float(v) for v in stamps]
    if out.get("markers_m") is not None:
        out["markers_m"] = points_array("markers_m", out["markers_m"], 3, 6).tolist()
    return out
