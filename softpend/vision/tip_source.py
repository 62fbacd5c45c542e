"""Live tip measurements: a camera (real, recorded or synthetic) plus the Algorithm 1 tracker, frame by frame.

A :class:`TipSource` delivers :class:`TipMeasurement` objects -- the tip position relative to the hub in
metres, or ``lost`` -- each stamped with its *capture time* on the host clock (``time.monotonic()`` on a rig,
the simulated clock on the twin; the middle of the exposure), so that a state estimator can place a
measurement that arrives late at the instant it describes.  The real and recorded cameras grab and track frames
on a background thread as they arrive; :meth:`TipSource.poll` returns what has been tracked since the previous
call, oldest first.

Two sources share the tracking (:class:`FrameTracker`: the tracker of :mod:`softpend.vision.tracker`
and an affine calibration, fitted from the reference markers on the first frame unless one is given):

* :class:`SyntheticLiveCamera` -- the digital twin's camera, in simulated time: renders frames of a *live*
  :class:`Scene` (the twin's poses, :attr:`softpend.hardware.emulator.SimRig.poses`) at a frame rate (30, 60,
  120 frames/s ...) with the exposure and imperfections of :class:`~softpend.vision.camera.CameraEffects`;
  each frame reaches the tracker ``latency_s`` after the end of its exposure (sensor read-out and transfer),
  and :class:`CameraFaults` injects stalls, dropped frames and occlusions of the dot.
* :class:`CaptureTipSource` -- ``cv2.VideoCapture`` on a device index (``0``), a stream URL or a video file; the
  capture time is the host time at which the frame was read minus the camera's known ``latency_s``.

:func:`open_tip_source` builds it from a ``--camera`` argument.  No physical camera was available
when this module was written: :class:`CaptureTipSource` is exercised with video files (which
``cv2.VideoCapture`` opens the same way), and the loop with the synthetic live camera.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Protocol, Sequence

import numpy as np

from softpend.checks import in_unit_interval, non_negative, positive
from softpend.vision.calibration import AffineCalibration, calibrate_from_markers, tip_angle_rad
from softpend.vision.camera import DEFAULT_MARKERS_M, CameraEffects, CameraModel, SyntheticCamera, _hide_dot, check_fps
from softpend.vision.tracker import Detection, TipTracker

__all__ = [
    "CameraFaults",
    "CaptureTipSource",
    "FrameTracker",
    "PoseHistory",
    "Scene",
    "SyntheticLiveCamera",
    "ThreadedTipSource",
    "TipMeasurement",
    "TipSource",
    "open_tip_source",
]


@dataclass(frozen=True)
class TipMeasurement:
    """One tracked frame: the tip position relative to the hub [m] (NaN and ``lost=True`` when no blob
    qualified).

    Attributes
    ----------
    x_m, y_m : float
        Tip position in the rod plane, hub axis at the origin, y up [m].
    lost : bool
        The tracker found no dot in this frame.
    capture_time_s : float
        Host clock (``time.monotonic()``) at the middle of the frame's exposure [s] (NaN if unknown).
    frame : int
        Index of the frame in its source (-1 if unknown).
    delivered_time_s : float
        Host clock when the tracker's answer was ready [s] (NaN if unknown).
    """

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

    @property
    def age_s(self) -> float:
        """Delivery minus capture time [s]: the latency the measurement reached its user with."""
        return self.delivered_time_s - self.capture_time_s


class TipSource(Protocol):
    """A camera with a tracker behind it (see the module docstring)."""

    def start(self) -> None:
        """Begin grabbing and tracking frames (on a background thread)."""

    def poll(self) -> list[TipMeasurement]:
        """The measurements tracked since the previous call, oldest first (re-raises an error of the
        background thread)."""

    def close(self) -> None:
        """Stop grabbing and release the camera."""

    def stats(self) -> dict[str, float]:
        """Counters: frames tracked, lost, dropped, and the delivery latency."""


# ---------------------------------------------------------------------- tracking
class FrameTracker:
    """Algorithm 1 on a frame, mapped to metres: a :class:`TipTracker` plus an affine calibration.

    Parameters
    ----------
    tracker : TipTracker, optional
        The tracker (default ``TipTracker()``).
    calibration : AffineCalibration, optional
        Pixel -> metre map; without it, it is fitted on the first frame from ``markers_m``.
    markers_m : sequence of (x, y)
        Reference-marker layout in the rod plane [m] (used only without ``calibration``).
    """

    def __init__(
        self,
        tracker: Optional[TipTracker] = None,
        calibration: Optional[AffineCalibration] = None,
        markers_m: Sequence[Sequence[float]] = DEFAULT_MARKERS_M,
    ) -> None:
        if tracker is not None and not isinstance(tracker, TipTracker):
            raise ValueError(f"tracker must be a TipTracker, got {type(tracker).__name__}")
        if calibration is not None and not isinstance(calibration, AffineCalibration):
            raise ValueError(f"calibration must be an AffineCalibration, got {type(calibration).__name__}")
        self.tracker = tracker if tracker is not None else TipTracker()
        self.calibration = calibration
        self.markers_m = markers_m

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
    """Shared machinery of the sources: a daemon thread runs :meth:`_run`, which calls :meth:`_deliver` for
    each tracked frame; :meth:`poll` drains the queue.  An exception on the thread ends it and is raised by
    the next :meth:`poll`.  Use as a context manager (``start`` on enter, ``close`` on exit).

    Parameters
    ----------
    frame_tracker : FrameTracker, optional
        Tracking and calibration (default ``FrameTracker()``).
    on_frame : callable, optional
        ``on_frame(index, frame, detection, measurement)`` after each tracked frame (on the thread), e.g.
        to keep frames for a figure.
    max_queue : int
        Measurements kept when nobody polls (the oldest are dropped first).
    """

    name = "camera"

    def __init__(
        self, frame_tracker: Optional[FrameTracker] = None, on_frame: Optional[FrameHook] = None, max_queue: int = 10000
    ) -> None:
        self.frame_tracker = frame_tracker if frame_tracker is not None else FrameTracker()
        self.on_frame = on_frame
        self._queue: collections.deque[TipMeasurement] = collections.deque(maxlen=int(max_queue))
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._error: Optional[BaseException] = None
        self.frames_tracked = 0
        self.frames_lost = 0
        self.frames_dropped = 0
        self._ages_s: list[float] = []

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        if self._thread is not None:
            return
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
        """The source has ended (end of a video, camera closed, or an error) and everything was polled."""
        return self._thread is not None and not self._thread.is_alive() and not self._queue

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ consumer side
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
        return {
            "frames_tracked": float(self.frames_tracked),
            "frames_lost": float(self.frames_lost),
            "frames_dropped": float(self.frames_dropped),
            "delivery_latency_ms_median": float(np.median(ages)) if ages.size else math.nan,
            "delivery_latency_ms_p95": float(np.percentile(ages, 95)) if ages.size else math.nan,
        }

    # ------------------------------------------------------------------ producer side
    def _run(self) -> None:
        raise NotImplementedError

    def _release(self) -> None:
        """Free the camera (called on the thread when :meth:`_run` ends)."""

    def _deliver(
        self, index: int, frame: np.ndarray, capture_time_s: float, delivered_time_s: Optional[float] = None
    ) -> TipMeasurement:
        """Track ``frame`` now and queue its measurement (delivered now on the host clock, unless given)."""
        x_m, y_m, detection = self.frame_tracker(frame)
        delivered = time.monotonic() if delivered_time_s is None else delivered_time_s
        measurement = TipMeasurement(x_m, y_m, bool(detection.lost), float(capture_time_s), int(index), delivered)
        self.frames_tracked += 1
        self.frames_lost += int(measurement.lost)
        self._ages_s.append(measurement.age_s)
        if self.on_frame is not None:
            self.on_frame(index, frame, detection, measurement)
        with self._lock:
            self._queue.append(measurement)
        return measurement


# ---------------------------------------------------------------------- scenes
class Scene(Protocol):
    """What the synthetic live camera films: the rod's pose as a function of the (host's) time."""

    def pose_at(self, time_s: float) -> tuple[np.ndarray, Optional[float]]:
        """Link points ``(n + 1, 2)`` (hub first) [m] and the hub angle [rad] at time ``time_s``."""


class PoseHistory:
    """Recent joint positions of a PRB rod on the host clock, interpolated to any time in between.

    Parameters
    ----------
    link_points : callable
        ``link_points(q) -> (n + 1, 2)`` points along the rod [m] (e.g. ``plant.link_points_m``).
    keep_s : float
        How much history is kept [s].
    """

    def __init__(self, link_points: Callable[[np.ndarray], np.ndarray], keep_s: float = 2.0) -> None:
        self.link_points = link_points
        self.keep_s = positive("keep_s", keep_s)
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

    def q_at(self, time_s: float) -> np.ndarray:
        """Joint positions at ``time_s``, linear between the stored samples (clamped at both ends)."""
        if not self._times:
            raise ValueError("PoseHistory is empty")
        times = self._times
        if time_s <= times[0]:
            return self._q[0]
        if time_s >= times[-1]:
            return self._q[-1]
        i = int(np.searchsorted(np.fromiter(times, float, len(times)), time_s)) - 1
        t0, t1 = times[i], times[i + 1]
        w = (time_s - t0) / (t1 - t0)
        return (1.0 - w) * self._q[i] + w * self._q[i + 1]

    def pose_at(self, time_s: float) -> tuple[np.ndarray, Optional[float]]:
        q = self.q_at(time_s)
        return self.link_points(q), float(q[0])


# ---------------------------------------------------------------------- the synthetic live camera
@dataclass(frozen=True)
class CameraFaults:
    """Faults of the synthetic live camera (none by default).

    Parameters
    ----------
    drop_probability : float
        Probability that a frame never reaches the host.
    occlusions_s : sequence of (start, end)
        Windows of time since the first frame [s] in which the dot is hidden (the tracker reports lost).
    stall_after_s : float, optional
        The camera delivers nothing after this much time since its first frame [s] (a frozen driver).
    seed : int
        Seed of the drop draws.
    """

    drop_probability: float = 0.0
    occlusions_s: tuple[tuple[float, float], ...] = ()
    stall_after_s: Optional[float] = None
    seed: int = 0

    def __post_init__(self) -> None:
        in_unit_interval("drop_probability", self.drop_probability)
        windows = []
        for window in self.occlusions_s:
            try:
                start, end = (float(v) for v in window)
            except (TypeError, ValueError):
                raise ValueError(f"occlusions_s must be (start, end) pairs [s], got {self.occlusions_s!r}") from None
            if not (math.isfinite(start) and math.isfinite(end) and 0 <= start < end):
                raise ValueError(f"occlusions_s must be (start, end) pairs with 0 <= start < end, got {window!r}")
            windows.append((start, end))
        object.__setattr__(self, "occlusions_s", tuple(windows))
        if self.stall_after_s is not None:
            non_negative("stall_after_s", self.stall_after_s)

    def occluded(self, elapsed_s: float) -> bool:
        return any(start <= elapsed_s < end for start, end in self.occlusions_s)


class SyntheticLiveCamera(ThreadedTipSource):
    """The twin's camera: film a live :class:`Scene` on a simulated clock and track every frame.

    Frame ``k`` is exposed over ``[t_k - exposure_s, t_k]`` with ``t_k = t_first + k / fps`` (``t_first``: the
    clock's time at :meth:`start` plus the exposure); it is rendered and tracked when the clock reaches
    ``t_k + latency_s``, its delivery time, and stamped with its capture time ``t_k - exposure_s / 2``.  The
    clock (:class:`~softpend.hardware.clock.SimClock`) runs the frames as events, so rendering and tracking cost
    computer time but no simulated time, and the same seeds give the same measurements.

    Parameters
    ----------
    scene : Scene
        What is filmed (the twin's :attr:`~softpend.hardware.emulator.SimRig.poses`).
    clock : SimClock
        The twin's clock.
    fps : float
        Frame rate [1/s].
    latency_s : float
        End of exposure to the frame's arrival at the tracker [s].
    effects : CameraEffects, optional
        Exposure blur, noise and lighting (default :meth:`CameraEffects.rig`).
    model : CameraModel, optional
        Camera geometry (default :class:`CameraModel`, 640x480).
    faults : CameraFaults, optional
        Injected stalls, drops and occlusions.
    seed : int
        Seed of the image noise.
    frame_tracker, on_frame :
        See :class:`ThreadedTipSource`.
    """

    name = "synthetic-camera"

    def __init__(
        self,
        scene: Scene,
        clock,
        fps: float = 60.0,
        latency_s: float = 0.02,
        effects: Optional[CameraEffects] = None,
        model: Optional[CameraModel] = None,
        faults: Optional[CameraFaults] = None,
        seed: int = 0,
        frame_tracker: Optional[FrameTracker] = None,
        on_frame: Optional[FrameHook] = None,
    ) -> None:
        super().__init__(frame_tracker, on_frame)
        self.scene = scene
        self.clock = clock
        self.fps = check_fps("fps", fps)
        self.latency_s = non_negative("latency_s", latency_s)
        self.camera = SyntheticCamera(
            model=model, effects=effects if effects is not None else CameraEffects.rig(), seed=seed
        )
        self.faults = faults if faults is not None else CameraFaults()
        self._rng = np.random.default_rng(self.faults.seed)
        self.frames_stalled = 0
        self.frames_occluded = 0
        self.first_frame_time_s: Optional[float] = None
        self._closed = False

    def start(self) -> None:
        if self.first_frame_time_s is None:
            self.first_frame_time_s = self.clock.now_s() + self.camera.effects.exposure_s
            self._schedule(0)

    def close(self, timeout_s: float = 0.0) -> None:
        self._closed = True

    def _schedule(self, k: int) -> None:
        assert self.first_frame_time_s is not None  # set by start()
        self.clock.call_at(self.first_frame_time_s + k / self.fps + self.latency_s, lambda: self._frame(k))

    def _frame(self, k: int) -> None:
        if self._closed:
            return
        self._schedule(k + 1)
        assert self.first_frame_time_s is not None  # set by start()
        t_k = self.first_frame_time_s + k / self.fps
        elapsed = t_k - self.first_frame_time_s
        if self.faults.stall_after_s is not None and elapsed >= self.faults.stall_after_s:
            self.frames_stalled += 1
            return
        if self.faults.drop_probability and self._rng.random() < self.faults.drop_probability:
            self.frames_dropped += 1
            return
        frame, tip_px = self.camera.render(self.scene.pose_at, t_k)
        if self.faults.occluded(elapsed):
            frame = _hide_dot(frame, tip_px, self.camera)
            self.frames_occluded += 1
        self._deliver(k, frame, t_k - self.camera.effects.exposure_s / 2, self.clock.now_s())

    def stats(self) -> dict[str, float]:
        out = super().stats()
        out["frames_stalled"] = float(self.frames_stalled)
        out["frames_occluded"] = float(self.frames_occluded)
        return out


# ---------------------------------------------------------------------- recorded and real cameras
class CaptureTipSource(ThreadedTipSource):
    """A live camera through ``cv2.VideoCapture``: a device index (``0``) or a stream URL.

    Each frame is tracked as soon as it is read; its capture time is the host time of the read minus
    ``latency_s``, the camera's exposure-to-host latency, which must be measured for the camera at hand
    (e.g. by filming the host's own clock).  A device that delivers no frame for ``timeout_s`` ends the
    source (the consumer sees no more measurements and decides what that means).

    Parameters
    ----------
    device : int or str
        Device index or URL (any source ``cv2.VideoCapture`` opens, video files included).
    latency_s : float
        Exposure-to-host latency subtracted from the read time [s].
    fps : float, optional
        Frame rate to request from the device.
    timeout_s : float
        Longest wait for a frame [s].
    frame_tracker, on_frame :
        See :class:`ThreadedTipSource`.
    """

    name = "capture"

    def __init__(
        self,
        device: int | str,
        latency_s: float = 0.0,
        fps: Optional[float] = None,
        timeout_s: float = 2.0,
        frame_tracker: Optional[FrameTracker] = None,
        on_frame: Optional[FrameHook] = None,
    ) -> None:
        import cv2

        if isinstance(device, bool) or not isinstance(device, (int, str)) or device == "":
            raise ValueError(f"device must be a camera index or a URL, got {device!r}")
        super().__init__(frame_tracker, on_frame)
        self.device = device
        self.latency_s = non_negative("latency_s", latency_s)
        self.timeout_s = positive("timeout_s", timeout_s)
        self._capture = cv2.VideoCapture(device)
        if not self._capture.isOpened():
            raise ValueError(f"camera {device!r} cannot be opened by OpenCV (no such device or stream)")
        if fps is not None:
            self._capture.set(cv2.CAP_PROP_FPS, check_fps("fps", fps))

    def _run(self) -> None:
        index = 0
        last_frame = time.monotonic()
        while not self._stop.is_set():
            ok, frame = self._capture.read()
            now = time.monotonic()
            if not ok:
                if now - last_frame > self.timeout_s or not self._capture.isOpened():
                    return
                self._stop.wait(0.005)
                if isinstance(self.device, str) and Path(self.device).is_file():
                    return  # the end of a file: no more frames will come
                continue
            last_frame = now
            self._deliver(index, frame, now - self.latency_s)
            index += 1

    def _release(self) -> None:
        self._capture.release()


#: Largest camera device index a ``--camera`` argument may name.
MAX_DEVICE_INDEX = 10_000


def open_tip_source(
    camera: str,
    latency_s: float = 0.0,
    fps: Optional[float] = None,
    frame_tracker: Optional[FrameTracker] = None,
    on_frame: Optional[FrameHook] = None,
) -> CaptureTipSource:
    """The :class:`CaptureTipSource` of a ``--camera`` argument: digits are a device index, anything else a
    stream URL or a file that ``cv2.VideoCapture`` opens."""
    if not isinstance(camera, str) or not camera.strip():
        raise ValueError(f"camera must be a device index or a URL, got {camera!r}")
    from softpend.io.reading import check_capture_path

    check_capture_path("camera", camera)  # a FIFO or folder would block the capture
    device: int | str = int(camera) if camera.strip().isdigit() else camera
    if isinstance(device, int) and device > MAX_DEVICE_INDEX:  # OpenCV takes a C int (and reads it as a pattern)
        raise ValueError(f"camera index must lie in [0, {MAX_DEVICE_INDEX}], got {camera!r}")
    return CaptureTipSource(device, latency_s=latency_s, fps=fps, frame_tracker=frame_tracker, on_frame=on_frame)
