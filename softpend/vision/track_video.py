"""Track a video file (or camera) into a time-stamped, crash-safe CSV (``softpend track``)."""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path
from typing import Callable, Optional, Sequence

import cv2
import numpy as np

from softpend.io.samplelog import SampleLog
from softpend.vision.calibration import AffineCalibration, calibrate_from_markers, tip_angle_rad
from softpend.vision.camera import MAX_FPS, check_fps, read_sidecar
from softpend.vision.tracker import MAGENTA_HSV, Detection, TipTracker

__all__ = ["TRACK_COLUMNS", "hub_marker_tracker", "track_frames", "track_live", "track_video"]


def hub_marker_tracker(
    calibration: AffineCalibration, frame_shape: tuple[int, ...], radius_m: float = 0.06
) -> TipTracker:
    """A tracker for the magenta hub marker that searches only within ``radius_m`` of the hub axis."""
    centre = calibration.to_pixels(np.zeros(2))
    r = radius_m / calibration.metres_per_pixel
    h, w = frame_shape[:2]
    region = (
        max(int(centre[0] - r), 0),
        max(int(centre[1] - r), 0),
        min(int(centre[0] + r) + 1, w),
        min(int(centre[1] + r) + 1, h),
    )
    return TipTracker(MAGENTA_HSV, min_area_px=6.0, region_px=region)


#: Columns of the tracking CSV.
TRACK_COLUMNS: tuple[str, ...] = (
    "frame",
    "camera_time_s",
    "x_px",
    "y_px",
    "area_px",
    "x_m",
    "y_m",
    "theta_rad",
    "lost",
    "hub_angle_rad",
    "hub_lost",
)


def track_frames(
    frames,
    timestamps_s: Sequence[float] | Callable[[int], float],
    tracker: TipTracker,
    calibration: AffineCalibration,
    log: Optional[SampleLog] = None,
    on_detection: Optional[Callable[[int, np.ndarray, Detection], None]] = None,
    hub_tracker: Optional[TipTracker] = None,
) -> np.ndarray:
    """Track an iterable of BGR frames; returns an ``(F, len(TRACK_COLUMNS))`` array (NaN where lost).

    Parameters
    ----------
    frames : iterable of ndarray
        BGR frames.
    timestamps_s : sequence or callable
        Camera-clock time of each frame [s] (or ``index -> time``).
    tracker : TipTracker
        The tracker.
    calibration : AffineCalibration
        Pixel -> metre map (hub axis at the origin).
    log : SampleLog, optional
        Also append each row to this log (columns :data:`TRACK_COLUMNS`) as it is produced.
    on_detection : callable, optional
        Called with ``(index, frame, detection)`` (e.g. to keep a frame for a figure).
    hub_tracker : TipTracker, optional
        Tracker of the hub marker (:func:`hub_marker_tracker`); gives ``hub_angle_rad`` (else NaN).
    """
    stamp = timestamps_s if callable(timestamps_s) else (lambda i: float(timestamps_s[i]))
    rows = []
    for i, frame in enumerate(frames):
        detection = tracker.track(frame)
        if detection.lost:
            x_m = y_m = theta = math.nan
        else:
            x_m, y_m = calibration.to_metres(np.array([detection.x_px, detection.y_px]))
            theta = float(tip_angle_rad(x_m, y_m))
        hub_angle, hub_lost = math.nan, 1
        if hub_tracker is not None:
            hub = hub_tracker.track(frame)
            if not hub.lost:
                hx, hy = calibration.to_metres(np.array([hub.x_px, hub.y_px]))
                hub_angle, hub_lost = float(tip_angle_rad(hx, hy)), 0
        row = [
            i,
            stamp(i),
            detection.x_px,
            detection.y_px,
            detection.area_px,
            float(x_m),
            float(y_m),
            theta,
            int(detection.lost),
            hub_angle,
            hub_lost,
        ]
        if log is not None:
            log.append(row)
        if on_detection is not None:
            on_detection(i, frame, detection)
        rows.append(row)
    return np.array(rows, dtype=float).reshape(-1, len(TRACK_COLUMNS))


def _video_frames(capture: cv2.VideoCapture):
    while True:
        ok, frame = capture.read()
        if not ok:
            return
        yield frame


def track_video(
    video: str | Path,
    out_csv: str | Path,
    marker_positions_m: Optional[Sequence[Sequence[float]]] = None,
    timestamps_s: Optional[Sequence[float]] = None,
    fps: Optional[float] = None,
    tracker: Optional[TipTracker] = None,
    calibration: Optional[AffineCalibration] = None,
    track_hub: bool = True,
    progress: bool = False,
) -> np.ndarray:
    """Track every frame of a video file into ``out_csv`` (crash-safe :class:`SampleLog`).

    Missing settings come from the synthetic camera's sidecar ``<video>.json`` when present: the frame
    timestamps (camera clock) and the marker layout.  The calibration is fitted on the first frame from
    the markers unless ``calibration`` is given.  With ``track_hub`` the magenta hub marker is tracked
    too (near the hub axis), giving the camera's view of the hub angle for clock synchronisation.

    Every input is checked before ``out_csv`` is touched.  The rows go to a temporary file next to it
    (``.<name>.*.partial``, crash-safe like any :class:`SampleLog`), which replaces ``out_csv`` only when
    the whole video is tracked; on an error it is removed and ``out_csv`` is left as it was.

    Raises
    ------
    FileNotFoundError
        If the video does not exist.
    ValueError
        If ``fps`` is not in (0, 1e6], ``out_csv`` cannot be written, the sidecar is malformed, the video
        cannot be decoded, or neither markers nor a calibration are available.
    """
    video = Path(video)
    out_csv = Path(out_csv)
    if fps is not None:
        fps = check_fps("fps", fps)
    _check_output_path(out_csv, video)
    if not video.exists():
        raise FileNotFoundError(f"video not found: {video}")
    if not video.is_file():
        raise ValueError(f"video {video} is not a file")
    sidecar = read_sidecar(video) if Path(str(video) + ".json").exists() else None
    if marker_positions_m is None and sidecar is not None:
        marker_positions_m = sidecar.get("markers_m")
    if timestamps_s is None and sidecar is not None:
        timestamps_s = sidecar.get("timestamps_s")
    if timestamps_s is not None:
        stamps_array = np.asarray(timestamps_s, dtype=float)
        if stamps_array.ndim != 1 or not np.all(np.isfinite(stamps_array)):
            raise ValueError("timestamps_s must be a 1-D sequence of finite times [s]")
    capture = cv2.VideoCapture(str(video))
    if not capture.isOpened():
        raise ValueError(f"video {video} cannot be opened by OpenCV")
    try:
        if fps is None:
            if sidecar is not None and sidecar.get("fps") is not None:
                fps = sidecar["fps"]
            else:
                container_fps = float(capture.get(cv2.CAP_PROP_FPS) or 0)
                fps = container_fps if math.isfinite(container_fps) and 0 < container_fps <= MAX_FPS else None
        if timestamps_s is None and fps is None:
            raise ValueError("fps: the video has no usable frame rate; pass fps or timestamps")
        frames = _video_frames(capture)
        first = next(frames, None)
        if first is None:
            raise ValueError(f"video {video} has no frames")
        if calibration is None:
            if marker_positions_m is None:
                raise ValueError("marker_positions_m: needed to calibrate (no calibration and no sidecar)")
            calibration = calibrate_from_markers(first, marker_positions_m)
        if timestamps_s is not None:
            stamps = list(timestamps_s)

            def stamp(i: int) -> float:
                if i >= len(stamps):
                    raise ValueError(f"timestamps_s has {len(stamps)} entries but the video has more frames")
                return float(stamps[i])
        else:
            assert fps is not None  # checked above: timestamps or a frame rate
            stamp = lambda i: i / fps  # noqa: E731

        def all_frames():
            yield first
            yield from frames

        iterator = all_frames()
        if progress:
            from tqdm.auto import tqdm

            total = int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0) or None
            iterator = tqdm(iterator, total=total, desc="tracking", unit="frame", mininterval=1.0)
        hub = hub_marker_tracker(calibration, first.shape) if track_hub else None
        partial = _partial_path(out_csv)
        try:
            with SampleLog(
                partial,
                TRACK_COLUMNS,
                metadata={"video": str(video), "calibration": calibration.to_json()},
                fsync_every_s=1.0,
            ) as log:
                rows = track_frames(iterator, stamp, tracker or TipTracker(), calibration, log, hub_tracker=hub)
            os.replace(partial, out_csv)
        except BaseException:
            partial.unlink(missing_ok=True)
            raise
        return rows
    finally:
        capture.release()


def _check_output_path(out_csv: Path, video: Optional[Path]) -> None:
    """Refuse an ``out_csv`` that cannot be written (a folder, in a missing or read-only folder, the input)."""
    if out_csv.is_dir():
        raise ValueError(f"out_csv {out_csv} is a folder")
    parent = out_csv.parent
    if not parent.is_dir():
        raise ValueError(f"out_csv {out_csv}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"out_csv {out_csv}: folder {parent} is not writable")
    for name, path in () if video is None else (("video", video), ("the video's sidecar", Path(str(video) + ".json"))):
        if path.exists() and out_csv.exists() and os.path.samefile(path, out_csv):
            raise ValueError(f"out_csv {out_csv} is {name}; choose another output")


def _partial_path(out_csv: Path) -> Path:
    """A new, empty file next to ``out_csv`` to write into before the final rename."""
    fd, name = tempfile.mkstemp(prefix=f".{out_csv.name}.", suffix=".partial", dir=out_csv.parent)
    try:
        os.fchmod(fd, 0o644)
    finally:
        os.close(fd)
    return Path(name)


def track_live(
    source,
    out_csv: str | Path,
    duration_s: Optional[float] = None,
    track_hub: bool = True,
    progress: bool = False,
) -> np.ndarray:
    """Track a live camera (a :class:`~softpend.vision.tip_source.ThreadedTipSource`, not yet started) into
    ``out_csv`` until ``duration_s`` of host time has passed, the source ends, or Ctrl-C.

    ``camera_time_s`` is each frame's capture time on the host clock (``time.monotonic()``).  The rows go to
    a temporary file next to ``out_csv`` (crash-safe), which replaces ``out_csv`` when tracking ends -- also
    on Ctrl-C, with the frames tracked so far; on an error it is removed and ``out_csv`` is left as it was.
    With ``track_hub`` the magenta hub marker is tracked too (near the hub axis).

    Raises
    ------
    ValueError
        If ``duration_s`` is not positive or ``out_csv`` cannot be written; the camera's own errors.
    """
    import time

    from softpend.vision.tip_source import ThreadedTipSource

    if not isinstance(source, ThreadedTipSource):
        raise ValueError(f"source must be a ThreadedTipSource, got {type(source).__name__}")
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s must be a positive number of seconds, got {duration_s!r}")
    out_csv = Path(out_csv)
    _check_output_path(out_csv, None)
    rows: list[list[float]] = []
    hub: list[Optional[TipTracker]] = [None]
    frame_tracker = source.frame_tracker
    previous_hook = source.on_frame

    def on_frame(index, frame, detection, measurement) -> None:
        hub_angle, hub_lost = math.nan, 1
        if track_hub:
            assert frame_tracker.calibration is not None  # set by the frame's tracking, before this hook
            hub_tracker = hub[0]
            if hub_tracker is None:
                hub_tracker = hub[0] = hub_marker_tracker(frame_tracker.calibration, frame.shape)
            found = hub_tracker.track(frame)
            if not found.lost:
                hx, hy = frame_tracker.calibration.to_metres(np.array([found.x_px, found.y_px]))
                hub_angle, hub_lost = float(tip_angle_rad(hx, hy)), 0
        theta = measurement.theta_rad
        rows.append(
            [
                index,
                measurement.capture_time_s,
                detection.x_px,
                detection.y_px,
                detection.area_px,
                measurement.x_m,
                measurement.y_m,
                theta,
                int(measurement.lost),
                hub_angle,
                hub_lost,
            ]
        )
        if previous_hook is not None:
            previous_hook(index, frame, detection, measurement)

    source.on_frame = on_frame
    partial = _partial_path(out_csv)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(desc="tracking", unit="frame", mininterval=1.0)
    written = 0
    try:
        with SampleLog(
            partial, TRACK_COLUMNS, metadata={"camera": getattr(source, "name", "camera")}, fsync_every_s=1.0
        ) as log:
            start = time.monotonic()
            source.start()
            try:
                while duration_s is None or time.monotonic() - start < duration_s:
                    source.poll()  # raises the camera thread's error
                    while written < len(rows):
                        log.append(rows[written])
                        written += 1
                    if bar is not None:
                        bar.update(written - bar.n)
                    if source.finished:
                        break
                    time.sleep(0.01)
            except KeyboardInterrupt:
                pass
            finally:
                source.close()
            while written < len(rows):
                log.append(rows[written])
                written += 1
            if log.rows_written == 0:
                raise ValueError("the camera delivered no frame")
        os.replace(partial, out_csv)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    finally:
        if bar is not None:
            bar.close()
    return np.array(rows, dtype=float).reshape(-1, len(TRACK_COLUMNS))
