"""Live tip measurements: a camera (real, recorded or the twin's synthetic one) plus the tracker, frame by frame,
each measurement stamped with its capture time on the host clock (:func:`open_tip_source` for ``--camera``)."""

from __future__ import annotations

import collections
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence

import cv2
import numpy as np

from softpend.checks import in_unit_interval, non_negative
from softpend.io.reading import check_capture_path
from softpend.vision.calibration import AffineCalibration, calibrate_from_markers, tip_angle_rad
from softpend.vision.camera import DEFAULT_MARKERS_M, CameraEffects, CameraModel, SyntheticCamera, _hide_dot, check_fps
from softpend.vision.tracker import Detection, TipTracker


@dataclass(frozen=True)
class TipMeasurement:
    """One tracked frame: the tip relative to the hub [m] (NaN when ``lost``), the host time at the middle of
    the exposure and when the answer was ready [s], and the frame's index in its source."""

    x_m: float
    y_m: float
    lost: bool
    capture_time_s: float = math.nan
    frame: int = -1
    delivered_time_s: float = math.nan

    @property
    def theta_rad(self) -> float:
        """Tip angle from upright (NaN when lost) [rad]."""
        return float(tip_angle_rad(self.x_m, self.y_m)) if not self.lost else math.nan


class FrameTracker:
    """A :class:`TipTracker` and a pixel -> metre calibration (unless given, fitted on the first frame)."""

    def __init__(
        self,
        tracker: Optional[TipTracker] = None,
        calibration: Optional[AffineCalibration] = None,
        markers_m: Optional[Sequence[Sequence[float]]] = None,
    ) -> None:
        self.tracker = tracker if tracker is not None else TipTracker()
        self.calibration = calibration
        self.markers_m = markers_m if markers_m is not None else DEFAULT_MARKERS_M

    def __call__(self, frame_bgr: np.ndarray) -> tuple[float, float, Detection]:
        """``(x_m, y_m, detection)`` of one BGR frame (NaN positions when lost)."""
        if self.calibration is None:
            self.calibration = calibrate_from_markers(frame_bgr, self.markers_m)
        detection = self.tracker.track(frame_bgr)
        if detection.lost:
            return math.nan, math.nan, detection
        x_m, y_m = self.calibration.to_metres(np.array([detection.x_px, detection.y_px]))
        return float(x_m), float(y_m), detection


FrameHook = Callable[[int, np.ndarray, Detection, "TipMeasurement"], None]


class ThreadedTipSource:
    """A daemon thread runs :meth:`_run`, which calls :meth:`_deliver` per frame; :meth:`poll` drains the queue and
    re-raises an error of the thread; ``on_frame(index, frame, detection, measurement)`` runs after each frame."""

    name = "camera"

    def __init__(self, frame_tracker: Optional[FrameTracker] = None, on_frame: Optional[FrameHook] = None) -> None:
        self.frame_tracker, self.on_frame = frame_tracker if frame_tracker is not None else FrameTracker(), on_frame
        self._queue: collections.deque[TipMeasurement] = collections.deque(maxlen=10000)
        self._lock, self._stop = threading.Lock(), threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._error: Optional[BaseException] = None
        self.counts = dict.fromkeys(("frames_tracked", "frames_lost", "frames_dropped"), 0)
        self._ages_s: list[float] = []

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._guarded_run, name=f"softpend-{self.name}", daemon=True)
            self._thread.start()

    def _guarded_run(self) -> None:
        try:
            self._run()
        except BaseException as exc:  # surfaced by poll() in the consumer's thread
            self._error = exc
        finally:
            self._release()

    def close(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    @property
    def finished(self) -> bool:
        """The source has ended and everything was polled."""
        return self._thread is not None and not self._thread.is_alive() and not self._queue

    def poll(self) -> list[TipMeasurement]:
        with self._lock:
            out = list(self._queue)
            self._queue.clear()
        if not out and self._error is not None:
            error, self._error = self._error, None
            raise error
        return out

    def stats(self) -> dict[str, float]:
        ages = np.asarray(self._ages_s) * 1e3
        median, p95 = (float(np.median(ages)), float(np.percentile(ages, 95))) if ages.size else (math.nan, math.nan)
        return {
            **{k: float(v) for k, v in self.counts.items()},
            "delivery_latency_ms_median": median,
            "delivery_latency_ms_p95": p95,
        }

    def _run(self) -> None:
        raise NotImplementedError

    def _release(self) -> None:
        """Free the camera (on the thread, when :meth:`_run` ends)."""

    def _deliver(
        self, index: int, frame: np.ndarray, capture_time_s: float, delivered_time_s: Optional[float] = None
    ) -> TipMeasurement:
        """Track ``frame`` and queue its measurement (delivered now on the host clock, unless given)."""
        x_m, y_m, detection = self.frame_tracker(frame)
        delivered = time.monotonic() if delivered_time_s is None else delivered_time_s
        measurement = TipMeasurement(x_m, y_m, bool(detection.lost), float(capture_time_s), int(index), delivered)
        self.counts["frames_tracked"] += 1
        self.counts["frames_lost"] += int(measurement.lost)
        self._ages_s.append(delivered - measurement.capture_time_s)
        if self.on_frame is not None:
            self.on_frame(index, frame, detection, measurement)
        with self._lock:
            self._queue.append(measurement)
        return measurement


class PoseHistory:
    """The last 2 s of joint positions of a PRB rod on the host clock; ``link_points(q)`` gives the rod's points [m]."""

    keep_s = 2.0

    def __init__(self, link_points: Callable[[np.ndarray], np.ndarray]) -> None:
        self.link_points = link_points
        self._times: collections.deque[float] = collections.deque()
        self._q: collections.deque[np.ndarray] = collections.deque()

    def add(self, time_s: float, q: np.ndarray) -> None:
        if self._times and time_s <= self._times[-1]:
            return  # out of order or repeated: the newest pose wins
        self._times.append(float(time_s))
        self._q.append(np.asarray(q, dtype=float))
        while self._times and self._times[0] < time_s - self.keep_s:
            self._times.popleft()
            self._q.popleft()

    def pose_at(self, time_s: float) -> tuple[np.ndarray, Optional[float]]:
        """Link points ``(n + 1, 2)`` [m] and hub angle [rad] at ``time_s``, linear between samples, clamped."""
        times = self._times
        if times[0] < time_s < times[-1]:
            i = int(np.searchsorted(np.fromiter(times, float, len(times)), time_s)) - 1
            w = (time_s - times[i]) / (times[i + 1] - times[i])
            q = (1.0 - w) * self._q[i] + w * self._q[i + 1]
        else:
            q = self._q[0] if time_s <= times[0] else self._q[-1]
        return self.link_points(q), float(q[0])


@dataclass(frozen=True)
class CameraFaults:
    """Faults of the synthetic live camera: the probability that a frame never arrives (drawn with ``seed``),
    windows ``(start, end)`` [s since the first frame] with the dot hidden, and a stall after a time [s]."""

    drop_probability: float = 0.0
    occlusions_s: tuple[tuple[float, float], ...] = ()
    stall_after_s: Optional[float] = None
    seed: int = 0

    def __post_init__(self) -> None:
        in_unit_interval("drop_probability", self.drop_probability)
        try:
            windows = tuple((float(start), float(end)) for start, end in self.occlusions_s)
        except (TypeError, ValueError):
            windows = ((math.nan, math.nan),)
        if not all(0 <= start < end < math.inf for start, end in windows):
            raise ValueError(
                f"occlusions_s must be (start, end) pairs [s], 0 <= start < end, got {self.occlusions_s!r}"
            )
        object.__setattr__(self, "occlusions_s", windows)
        if self.stall_after_s is not None:
            non_negative("stall_after_s", self.stall_after_s)


class SyntheticLiveCamera(ThreadedTipSource):
    """The twin's camera on its simulated ``clock``: frame ``k``, exposed until ``t_k = t_first + k / fps``, is
    tracked at ``t_k + latency_s`` and stamped ``t_k - exposure_s / 2``; ``effects`` default to the rig's."""

    name = "synthetic-camera"

    def __init__(
        self,
        scene: PoseHistory,
        clock,
        fps: float = 60.0,
        latency_s: float = 0.02,
        effects: Optional[CameraEffects] = None,
        model: Optional[CameraModel] = None,
        faults: Optional[CameraFaults] = None,
        seed: int = 0,
        on_frame: Optional[FrameHook] = None,
    ) -> None:
        super().__init__(None, on_frame)
        self.scene, self.clock = scene, clock
        self.fps = check_fps("fps", fps)
        self.latency_s = non_negative("latency_s", latency_s)
        effects = effects if effects is not None else CameraEffects.rig()
        self.camera = SyntheticCamera(model=model, effects=effects, seed=seed)
        self.faults = faults if faults is not None else CameraFaults()
        self._rng = np.random.default_rng(self.faults.seed)
        self.counts.update(frames_stalled=0, frames_occluded=0)
        self.first_frame_time_s: Optional[float] = None
        self._closed = False

    def start(self) -> None:
        if self.first_frame_time_s is None:
            self.first_frame_time_s = self.clock.now_s() + self.camera.effects.exposure_s
            self.clock.call_at(self.first_frame_time_s + self.latency_s, lambda: self._frame(0))

    def close(self, timeout_s: float = 0.0) -> None:
        self._closed = True

    def _frame(self, k: int) -> None:
        """Frame ``k``, ready now; the next one scheduled."""
        first, faults = self.first_frame_time_s, self.faults
        assert first is not None  # set by start()
        if self._closed:
            return
        self.clock.call_at(first + (k + 1) / self.fps + self.latency_s, lambda: self._frame(k + 1))
        t_k = first + k / self.fps
        elapsed = t_k - first
        if faults.stall_after_s is not None and elapsed >= faults.stall_after_s:
            self.counts["frames_stalled"] += 1
            return
        if faults.drop_probability and self._rng.random() < faults.drop_probability:
            self.counts["frames_dropped"] += 1
            return
        frame, tip_px = self.camera.render(self.scene.pose_at, t_k)
        if any(start <= elapsed < end for start, end in faults.occlusions_s):
            frame = _hide_dot(frame, tip_px, self.camera)
            self.counts["frames_occluded"] += 1
        self._deliver(k, frame, t_k - self.camera.effects.exposure_s / 2, self.clock.now_s())


class CaptureTipSource(ThreadedTipSource):
    """``cv2.VideoCapture`` on a device index, stream URL or video file.  A frame's capture time is the host
    time of its read minus the camera's ``latency_s``; no frame for :attr:`timeout_s` [s] ends the source."""

    name = "capture"
    timeout_s = 2.0

    def __init__(self, device: int | str, latency_s: float = 0.0, frame_tracker: Optional[FrameTracker] = None) -> None:
        super().__init__(frame_tracker)
        self.device, self.latency_s = device, non_negative("latency_s", latency_s)
        self._capture = cv2.VideoCapture(device)
        if not self._capture.isOpened():
            raise ValueError(f"camera {device!r} cannot be opened by OpenCV (no such device or stream)")

    def _run(self) -> None:
        index, last_frame = 0, time.monotonic()
        while not self._stop.is_set():
            ok, frame = self._capture.read()
            now = time.monotonic()
            if not ok:
                if now - last_frame > self.timeout_s or not self._capture.isOpened():
                    return
                self._stop.wait(0.005)
                if isinstance(self.device, str) and Path(self.device).is_file():
                    return  # the end of a file
                continue
            last_frame = now
            self._deliver(index, frame, now - self.latency_s)
            index += 1

    def _release(self) -> None:
        self._capture.release()


#: Largest camera device index a ``--camera`` argument may name (OpenCV takes a C int).
MAX_DEVICE_INDEX = 10_000


def open_tip_source(
    camera: str, latency_s: float = 0.0, frame_tracker: Optional[FrameTracker] = None
) -> CaptureTipSource:
    """The :class:`CaptureTipSource` of a ``--camera`` argument: a device index (digits), stream URL or file."""
    if not isinstance(camera, str) or not camera.strip():
        raise ValueError(f"camera must be a device index or a URL, got {camera!r}")
    check_capture_path("camera", camera)  # a FIFO or folder would block the capture
    device: int | str = int(camera) if camera.strip().isdigit() else camera
    if isinstance(device, int) and device > MAX_DEVICE_INDEX:
        raise ValueError(f"camera index must lie in [0, {MAX_DEVICE_INDEX}], got {camera!r}")
    return CaptureTipSource(device, latency_s=latency_s, frame_tracker=frame_tracker)
