"""The synthetic camera: rod trajectories rendered to frames with known ground truth, and to video files
with a sidecar JSON (timestamps on the camera clock, markers, truth)."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Iterator, Optional, Sequence

import cv2
import numpy as np

from softpend.checks import finite, in_unit_interval, int_at_least, non_negative, positive
from softpend.io.outputs import atomic_write
from softpend.vision.calibration import points_array, read_json_file

#: Highest frame rate accepted [1/s].
MAX_FPS = 1e6
MAX_SIDECAR_BYTES = 64 << 20


def check_fps(name: str, value) -> float:
    """``value`` as a frame rate in (0, :data:`MAX_FPS`], else ``ValueError`` naming ``name``."""
    fps = positive(name, value)
    if fps > MAX_FPS:
        raise ValueError(f"{name} must be at most {MAX_FPS:g} frames/s, got {value!r}")
    return fps


#: Reference-marker layout in the rod plane [m] (asymmetric, so the marker correspondence is unique).
DEFAULT_MARKERS_M: tuple[tuple[float, float], ...] = ((-0.42, 0.31), (0.42, 0.31), (0.40, -0.30), (-0.22, -0.33))

_TIP_BGR = (200, 70, 20)
_MARKER_BGR = (40, 170, 30)
_ROD_BGR = (70, 70, 70)
_HUB_MARKER_BGR = (180, 0, 220)
_HUB_BGR = (20, 20, 20)


@dataclass(frozen=True)
class CameraModel:
    """Camera on the rod's plane, metres (hub at the origin, y up) to pixels (y down):
    ``pixel = centre + s * R(roll) @ [x, -y]``."""

    width_px: int = 640
    height_px: int = 480
    px_per_m: float = 640.0
    centre_px: tuple[float, float] = (320.0, 238.0)
    roll_rad: float = 0.03

    def __post_init__(self) -> None:
        if self.width_px < 16 or self.height_px < 16:
            raise ValueError(f"width_px and height_px must be >= 16, got {self.width_px}x{self.height_px}")
        positive("px_per_m", self.px_per_m)

    def to_pixels(self, points_m: np.ndarray) -> np.ndarray:
        c, s = math.cos(self.roll_rad), math.sin(self.roll_rad)
        linear = self.px_per_m * np.array([[c, s], [s, -c]])  # R(roll) @ diag(1, -1)
        return np.asarray(points_m, dtype=float) @ linear.T + np.asarray(self.centre_px, dtype=float)


@dataclass(frozen=True)
class CameraEffects:
    """Imperfections of the synthetic camera (all off by default): sensor noise [DN], exposure blur [s], a gain
    ``1 + a sin(2 pi f t)``, a brightness gradient, and background clutter."""

    noise_std_dn: float = 0.0
    exposure_s: float = 0.0
    blur_subframes: int = 5
    lighting_amplitude: float = 0.0
    lighting_frequency_hz: float = 0.3
    gradient: float = 0.0
    clutter: bool = False

    def __post_init__(self) -> None:
        for name in ("noise_std_dn", "exposure_s", "gradient"):
            non_negative(name, getattr(self, name))
        in_unit_interval("lighting_amplitude", self.lighting_amplitude, include_one=False)
        int_at_least("blur_subframes", self.blur_subframes, 1)

    @classmethod
    def noisy(cls) -> "CameraEffects":
        """The benchmark's "noisy" condition: noise, blur, lighting changes and clutter."""
        return cls(6.0, 0.008, 5, 0.25, 0.5, 0.3, True)

    @classmethod
    def rig(cls) -> "CameraEffects":
        """The nominal rig camera of the digital twin."""
        return cls(noise_std_dn=3.0, exposure_s=0.004, blur_subframes=3, lighting_amplitude=0.1, gradient=0.1)


class SyntheticCamera:
    """Render the rod to BGR frames through ``model`` with ``effects``; ``seed`` draws clutter and noise."""

    dot_radius_m = 0.011
    rod_width_m = 0.01
    #: Distance of the magenta hub marker (turning with the hub) from the hub axis [m].
    hub_marker_radius_m = 0.035

    def __init__(
        self,
        model: Optional[CameraModel] = None,
        effects: Optional[CameraEffects] = None,
        markers_m: Sequence[Sequence[float]] = DEFAULT_MARKERS_M,
        seed: int = 0,
    ) -> None:
        self.model = m = model if model is not None else CameraModel()
        self.effects = effects if effects is not None else CameraEffects()
        self.markers_m, self.seed = np.asarray(markers_m, dtype=float), int(seed)
        self._rng = np.random.default_rng(seed)
        self._background = image = np.full((m.height_px, m.width_px, 3), (205, 210, 215), dtype=np.uint8)
        if self.effects.clutter:
            rng = np.random.default_rng(self.seed + 7919)
            # reds, oranges, yellows, greys, browns: no blue, green or magenta
            palette = [(60, 60, 200), (40, 140, 220), (30, 200, 230), (150, 150, 150)]
            palette += [(100, 90, 120), (180, 200, 230), (80, 110, 140)]
            for _ in range(25):
                colour, kind = palette[rng.integers(len(palette))], rng.integers(3)
                x, y = int(rng.integers(0, m.width_px)), int(rng.integers(0, m.height_px))
                if kind == 0:
                    corner = (x + int(rng.integers(10, 90)), y + int(rng.integers(10, 60)))
                    cv2.rectangle(image, (x, y), corner, colour, -1)
                elif kind == 1:
                    cv2.circle(image, (x, y), int(rng.integers(5, 30)), colour, -1, cv2.LINE_AA)
                else:
                    end = (int(rng.integers(0, m.width_px)), int(rng.integers(0, m.height_px)))
                    cv2.line(image, (x, y), end, colour, int(rng.integers(1, 4)), cv2.LINE_AA)
            for _ in range(6):
                x, y = int(rng.integers(0, m.width_px)), int(rng.integers(0, m.height_px))
                cv2.circle(image, (x, y), 1, _TIP_BGR, -1)
        for centre in self.model.to_pixels(self.markers_m):
            _circle(image, centre, 7.0, _MARKER_BGR)
        xx = np.mgrid[0 : m.height_px, 0 : m.width_px].astype(np.float32)[1]
        gradient = (1.0 + self.effects.gradient * ((xx / m.width_px) - 0.5)).astype(np.float32)
        self._gradient3 = cv2.merge([gradient, gradient, gradient])
        self._noise_margin = 97  # sensor noise: per frame a random crop of one larger noise field
        self._noise_field: Optional[np.ndarray] = None
        if self.effects.noise_std_dn > 0:
            shape = (m.height_px + self._noise_margin, m.width_px + self._noise_margin, 3)
            noise = self._rng.standard_normal(shape, dtype=np.float32)
            self._noise_field = noise * np.float32(self.effects.noise_std_dn)

    def draw(self, link_points_m: np.ndarray, hub_angle_rad: Optional[float] = None) -> tuple[np.ndarray, np.ndarray]:
        """A sharp, noise-free frame of the rod at ``link_points_m`` ``(n + 1, 2)`` (hub first) [m] and the
        tip's pixel position; ``hub_angle_rad`` defaults to the first link's direction."""
        points = np.asarray(link_points_m, dtype=float)
        image = self._background.copy()
        pixels = self.model.to_pixels(points)
        width = max(1, int(round(self.rod_width_m * self.model.px_per_m)))
        fixed = np.round(pixels * (1 << 4)).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(image, [fixed], False, _ROD_BGR, width, cv2.LINE_AA, 4)
        hub, half = pixels[0], 0.6 * width + 3
        cv2.rectangle(image, tuple(int(v - half) for v in hub), tuple(int(v + half) for v in hub), _HUB_BGR, -1)
        if hub_angle_rad is None:
            d = points[1] - points[0]
            hub_angle_rad = math.atan2(-d[0], d[1])
        r = self.hub_marker_radius_m
        marker = self.model.to_pixels(points[0] + r * np.array([-math.sin(hub_angle_rad), math.cos(hub_angle_rad)]))
        _circle(image, marker, 0.45 * width + 1.5, _HUB_MARKER_BGR)
        _circle(image, pixels[-1], self.dot_radius_m * self.model.px_per_m, _TIP_BGR)
        return image, pixels[-1]

    def render(self, sample_points_m, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        """A frame exposed over ``[time_s - exposure_s, time_s]`` and the true tip pixel position averaged over
        the exposure; ``sample_points_m(t)`` gives the link points and hub angle (or None) at time ``t``."""
        fx = self.effects
        if fx.exposure_s > 0 and fx.blur_subframes > 1:
            times = time_s - fx.exposure_s * (1 - (np.arange(fx.blur_subframes) + 0.5) / fx.blur_subframes)
        else:
            times = np.array([time_s])
        frames, tips = zip(*(self.draw(*sample_points_m(float(t))) for t in times))
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
        """Frames (and true tip pixels) at ``frame_times_s`` of a trajectory sampled at increasing ``times_s``:
        link points ``(T, n + 1, 2)`` [m] and optional hub angles ``(T,)``, linear in between."""
        times_s = np.asarray(times_s, dtype=float)
        flat = np.asarray(link_points_m, dtype=float).reshape(len(times_s), -1)
        hub_angles_rad = None if hub_angles_rad is None else np.asarray(hub_angles_rad, dtype=float)

        def sample(t: float) -> tuple[np.ndarray, Optional[float]]:
            i = int(np.clip(np.searchsorted(times_s, t) - 1, 0, len(times_s) - 2))
            w = (t - times_s[i]) / (times_s[i + 1] - times_s[i])
            w = min(max(w, 0.0), 1.0)
            hub = None if hub_angles_rad is None else (1 - w) * hub_angles_rad[i] + w * hub_angles_rad[i + 1]
            return ((1 - w) * flat[i] + w * flat[i + 1]).reshape(-1, 2), hub

        for t in np.asarray(frame_times_s, dtype=float):
            yield self.render(sample, float(t))


def _circle(image: np.ndarray, centre_px: np.ndarray, radius_px: float, colour: tuple[int, int, int]) -> None:
    centre = (int(round(centre_px[0] * 16)), int(round(centre_px[1] * 16)))
    cv2.circle(image, centre, int(round(radius_px * 16)), colour, -1, cv2.LINE_AA, 4)


def render_video(
    path: str | Path,
    camera: SyntheticCamera,
    times_s: np.ndarray,
    link_points_m: np.ndarray,
    hub_angles_rad: Optional[np.ndarray] = None,
    fps: float = 100.0,
    clock_offset_s: float = 0.0,
    timestamp_jitter_s: float = 0.0,
    drop_dot_frames: Sequence[int] = (),
    progress: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Render a trajectory (:meth:`SyntheticCamera.frames`) to an MJPG video and a sidecar ``<path>.json``; a frame
    exposed until ``t`` is stamped ``t + clock_offset_s`` (+ jitter), ``drop_dot_frames`` have the dot hidden.
    Returns the camera-clock timestamps and the true tip pixel positions (NaN: hidden)."""
    path = Path(path)
    check_fps("fps", fps)
    times_s = np.asarray(times_s, dtype=float)
    frame_times = np.arange(times_s[0] + camera.effects.exposure_s, times_s[-1] + 1e-9, 1.0 / fps)
    rng = np.random.default_rng(camera.seed + 104729)
    stamps = frame_times + clock_offset_s + timestamp_jitter_s * rng.standard_normal(len(frame_times))
    size = (camera.model.width_px, camera.model.height_px)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, size)  # type: ignore[attr-defined]
    if not writer.isOpened():
        raise ValueError(f"cannot open a video writer for {path}")
    hidden = set(int(i) for i in drop_dot_frames)
    tips = np.empty((len(frame_times), 2))
    from tqdm.auto import tqdm

    frames = camera.frames(times_s, link_points_m, frame_times, hub_angles_rad)
    iterator = tqdm(frames, total=len(frame_times), desc="rendering", unit="frame", mininterval=1, disable=not progress)
    try:
        for i, (frame, tip) in enumerate(iterator):
            if i in hidden:
                frame = _hide_dot(frame, tip, camera)
                tip = np.array([np.nan, np.nan])
            tips[i] = tip
            writer.write(frame)
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
    with atomic_write(str(path) + ".json", "w") as handle:
        handle.write(json.dumps(sidecar))
    return stamps, tips


def _hide_dot(frame: np.ndarray, tip_px: np.ndarray, camera: SyntheticCamera) -> np.ndarray:
    """Paint over the dot with the rod colour (an occlusion)."""
    frame = frame.copy()
    radius = camera.dot_radius_m * camera.model.px_per_m + 3
    cv2.circle(frame, (int(round(tip_px[0])), int(round(tip_px[1]))), int(math.ceil(radius)), _ROD_BGR, -1)
    return frame


def read_sidecar(video_path: str | Path) -> dict:
    """The sidecar JSON of a video checked by :func:`check_sidecar` (``{}`` without one)."""
    path = Path(str(video_path) + ".json")
    if not path.exists():
        return {}
    data = read_json_file("sidecar", path, MAX_SIDECAR_BYTES)
    try:
        return check_sidecar(data)
    except ValueError as exc:
        raise ValueError(f"sidecar {path}: {exc}") from None


def check_sidecar(data) -> dict:
    """A copy of a sidecar with its optional ``fps``, ``timestamps_s`` [s] and ``markers_m`` (3 to 6 pairs
    [m]) checked and converted; ``ValueError`` naming a bad field."""
    if not isinstance(data, dict):
        raise ValueError(f"must be a JSON object, got {type(data).__name__}")
    out = dict(data)
    if out.get("fps") is not None:
        out["fps"] = check_fps("fps", out["fps"])
    if out.get("timestamps_s") is not None:
        if not isinstance(out["timestamps_s"], list):
            raise ValueError("timestamps_s must be a list of finite numbers [s]")
        out["timestamps_s"] = [finite("timestamps_s", v) for v in out["timestamps_s"]]
    if out.get("markers_m") is not None:
        out["markers_m"] = points_array("markers_m", out["markers_m"]).tolist()
    return out
