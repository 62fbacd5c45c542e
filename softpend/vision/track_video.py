"""Track a video file or a live camera into a time-stamped, crash-safe CSV (``softpend track``)."""

from __future__ import annotations

import contextlib
import itertools
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Iterator, Optional, Sequence

import cv2
import numpy as np

from softpend.io.reading import check_regular_file
from softpend.io.samplelog import SampleLog
from softpend.vision.calibration import AffineCalibration, calibrate_from_markers, tip_angle_rad
from softpend.vision.camera import MAX_FPS, check_fps, read_sidecar
from softpend.vision.tip_source import FrameTracker
from softpend.vision.tracker import MAGENTA_HSV, TipTracker

#: Columns of the tracking CSV.
TRACK_COLUMNS: tuple[str, ...] = tuple(
    "frame camera_time_s x_px y_px area_px x_m y_m theta_rad lost hub_angle_rad hub_lost".split()
)


def hub_marker_tracker(calibration: AffineCalibration, frame_shape: tuple[int, ...]) -> TipTracker:
    """A tracker of the magenta hub marker that searches only within 6 cm of the hub axis."""
    centre = calibration.to_pixels(np.zeros(2))
    r = 0.06 / calibration.metres_per_pixel
    x0, y0 = (max(int(c - r), 0) for c in centre)
    x1, y1 = (min(int(c + r) + 1, n) for c, n in zip(centre, (frame_shape[1], frame_shape[0])))
    return TipTracker(MAGENTA_HSV, min_area_px=6.0, region_px=(x0, y0, x1, y1))


def _row(index, time_s, x_m, y_m, detection, hub_tracker, calibration, frame) -> list:
    """One row of :data:`TRACK_COLUMNS` (the hub angle NaN and lost without a tracker or a marker)."""
    theta = math.nan if detection.lost else float(tip_angle_rad(x_m, y_m))
    row = [index, time_s, detection.x_px, detection.y_px, detection.area_px, x_m, y_m, theta, int(detection.lost)]
    hub = hub_tracker.track(frame) if hub_tracker is not None else None
    if hub is None or hub.lost:
        return row + [math.nan, 1]
    return row + [float(tip_angle_rad(*calibration.to_metres(np.array([hub.x_px, hub.y_px])))), 0]


def _progress(iterator=None, total: Optional[int] = None, progress: bool = True):
    from tqdm.auto import tqdm

    return tqdm(iterator, total=total, desc="tracking", unit="frame", mininterval=1.0, disable=not progress)


def track_video(
    video: str | Path,
    out_csv: str | Path,
    marker_positions_m: Optional[Sequence[Sequence[float]]] = None,
    fps: Optional[float] = None,
    tracker: Optional[TipTracker] = None,
    calibration: Optional[AffineCalibration] = None,
    track_hub: bool = True,
    progress: bool = False,
) -> np.ndarray:
    """Track every frame of a video file (and the hub marker if ``track_hub``) into ``out_csv``, replaced only
    once the whole video is tracked; timestamps, and a missing frame rate and markers, come from its sidecar."""
    video, out_csv = Path(video), Path(out_csv)
    fps = None if fps is None else check_fps("fps", fps)
    _check_output_path(out_csv, video)
    check_regular_file(video, "video")
    sidecar = read_sidecar(video)
    marker_positions_m = sidecar.get("markers_m") if marker_positions_m is None else marker_positions_m
    stamps = sidecar.get("timestamps_s")  # checked finite by read_sidecar
    capture = cv2.VideoCapture(str(video))
    if not capture.isOpened():
        raise ValueError(f"video {video} cannot be opened by OpenCV")
    try:
        fps = sidecar.get("fps") if fps is None else fps
        if fps is None:
            container_fps = float(capture.get(cv2.CAP_PROP_FPS) or 0)
            fps = container_fps if math.isfinite(container_fps) and 0 < container_fps <= MAX_FPS else None
        if stamps is None and fps is None:
            raise ValueError("fps: the video has no usable frame rate; pass fps or timestamps")
        frames = (frame for _, frame in itertools.takewhile(lambda read: read[0], iter(capture.read, None)))
        first = next(frames, None)
        if first is None:
            raise ValueError(f"video {video} has no frames")
        if calibration is None:
            if marker_positions_m is None:
                raise ValueError("marker_positions_m: needed to calibrate (no calibration and no sidecar)")
            calibration = calibrate_from_markers(first, marker_positions_m)

        def stamp(i: int) -> float:
            if stamps is None:
                return i / fps  # type: ignore[operator]  # checked above: timestamps or a frame rate
            if i >= len(stamps):
                raise ValueError(f"timestamps_s has {len(stamps)} entries but the video has more frames")
            return float(stamps[i])

        total = int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0) or None
        iterator = _progress(itertools.chain([first], frames), total, progress)
        hub = hub_marker_tracker(calibration, first.shape) if track_hub else None
        metadata = {"video": str(video), "calibration": calibration.to_json()}
        frame_tracker = FrameTracker(tracker, calibration)
        rows = []
        with _replacing(out_csv, metadata) as log:
            for i, frame in enumerate(iterator):
                x_m, y_m, detection = frame_tracker(frame)
                rows.append(_row(i, stamp(i), x_m, y_m, detection, hub, calibration, frame))
                log.append(rows[-1])
        return np.array(rows, dtype=float).reshape(-1, len(TRACK_COLUMNS))
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


@contextlib.contextmanager
def _replacing(out_csv: Path, metadata: dict) -> Iterator[SampleLog]:
    """A :class:`SampleLog` in a temporary file that replaces ``out_csv`` on a clean exit, removed on an error."""
    fd, name = tempfile.mkstemp(prefix=f".{out_csv.name}.", suffix=".partial", dir=out_csv.parent)
    os.close(fd)
    partial = Path(name)
    try:
        os.chmod(partial, 0o644)
        with SampleLog(partial, TRACK_COLUMNS, metadata=metadata, fsync_every_s=1.0) as log:
            yield log
        os.replace(partial, out_csv)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise


def track_live(
    source, out_csv: str | Path, duration_s: Optional[float] = None, track_hub: bool = True, progress: bool = False
) -> np.ndarray:
    """Track a live camera (not yet started) into ``out_csv`` (host capture times), replaced when ``duration_s``
    has passed, the source ends or on Ctrl-C; on an error ``out_csv`` is left as it was."""
    out_csv = Path(out_csv)
    _check_output_path(out_csv, None)
    rows: list[list[float]] = []
    hub: list[Optional[TipTracker]] = [None]
    frame_tracker = source.frame_tracker
    previous_hook = source.on_frame

    def on_frame(index, frame, detection, measurement) -> None:
        calibration = frame_tracker.calibration
        assert calibration is not None  # set by the frame's tracking, before this hook
        if track_hub and hub[0] is None:
            hub[0] = hub_marker_tracker(calibration, frame.shape)
        x_m, y_m = measurement.x_m, measurement.y_m
        rows.append(_row(index, measurement.capture_time_s, x_m, y_m, detection, hub[0], calibration, frame))
        if previous_hook is not None:
            previous_hook(index, frame, detection, measurement)

    source.on_frame = on_frame
    with _progress(progress=progress) as bar, _replacing(out_csv, {"camera": getattr(source, "name", "camera")}) as log:

        def flush() -> None:
            for row in rows[log.rows_written :]:  # a snapshot: the camera thread appends meanwhile
                log.append(row)

        start = time.monotonic()
        source.start()
        try:
            while duration_s is None or time.monotonic() - start < duration_s:
                source.poll()  # raises the camera thread's error
                flush()
                bar.update(log.rows_written - bar.n)
                if source.finished:
                    break
                time.sleep(0.01)
        except KeyboardInterrupt:
            pass
        finally:
            source.close()
        flush()
        if log.rows_written == 0:
            raise ValueError("the camera delivered no frame")
    return np.array(rows, dtype=float).reshape(-1, len(TRACK_COLUMNS))
