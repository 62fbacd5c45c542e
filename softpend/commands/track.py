"""``softpend track``: track the blue tip dot in a video, or live from a camera, into a time-stamped CSV
(Algorithm 1).

``--camera 0`` (a device index), ``--camera rtsp://...`` (a stream URL) or ``--camera FILE`` (any video
``cv2.VideoCapture`` opens) tracks frames as they arrive, stamped with their capture time on the host clock
(the read time minus ``--camera-latency-ms``), until ``--duration``, the end of the stream, or Ctrl-C.  The
live path was tested with video files and the synthetic camera; no physical camera was available.
"""

from __future__ import annotations

import argparse
import json


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("track", help="track the tip dot in a video file into a time-stamped CSV")
    parser.add_argument(
        "video", nargs="?", help="video file (the synthetic camera's sidecar VIDEO.json is used if present)"
    )
    parser.add_argument(
        "--camera",
        metavar="CAMERA",
        help="track live instead: a camera index (0), a stream URL, or a video file read as a stream",
    )
    parser.add_argument("--duration", type=float, help="with --camera: stop after this many seconds")
    parser.add_argument(
        "--camera-latency-ms",
        type=float,
        default=0.0,
        help="with --camera: exposure-to-host latency of the camera, subtracted from the read time [ms] (default 0)",
    )
    parser.add_argument(
        "--out",
        required=True,
        metavar="CSV",
        help="output CSV (crash-safe sample log; replaced only once the whole video is tracked)",
    )
    parser.add_argument(
        "--markers",
        metavar="JSON",
        help="marker positions in the rod plane [m], JSON list [[x, y], ...] or file (hub axis at 0, y up)",
    )
    parser.add_argument("--calibration", metavar="JSON", help="a saved AffineCalibration instead of markers")
    parser.add_argument("--fps", type=float, help="frame rate for timestamps when the video has no sidecar")
    parser.add_argument("--min-area", type=float, default=20.0, help="smallest dot area [px^2] (default 20)")
    parser.add_argument("--no-hub", action="store_true", help="do not track the magenta hub marker")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from softpend.io.outputs import Outputs
    from softpend.vision.calibration import MAX_CALIBRATION_BYTES, AffineCalibration, points_array, read_json_file
    from softpend.vision.track_video import track_video
    from softpend.vision.tracker import TipTracker

    outputs = Outputs()  # before the work: a CSV this command wrote may be replaced, no other file
    outputs.file(args.out, what="--out")
    from softpend.commands.options import MAX_SESSION_S, check_numbers
    from softpend.vision.camera import MAX_FPS

    check_numbers(
        args,
        {
            "--duration": (1e-3, MAX_SESSION_S),
            "--camera-latency-ms": (0.0, 1000.0),
            "--min-area": (0.0, 1e8),
            "--fps": (1e-3, MAX_FPS),
        },
    )  # before anything starts
    markers = None
    if args.markers:
        if args.markers.lstrip().startswith("["):
            try:
                markers = json.loads(args.markers)
            except (ValueError, RecursionError) as exc:
                raise ValueError(f"--markers is not a valid JSON list: {exc}") from None
        else:
            markers = read_json_file("--markers", args.markers, MAX_CALIBRATION_BYTES)
        markers = points_array("--markers", markers, 3, 6).tolist()
    calibration = AffineCalibration.load(args.calibration) if args.calibration else None
    if (args.video is None) == (args.camera is None):
        raise ValueError("give either a VIDEO file or --camera CAMERA")
    if args.camera is not None:
        try:
            return _track_camera(args, markers, calibration)
        finally:
            outputs.done(args.out)  # written atomically by track_live (also on Ctrl-C)
    rows = track_video(
        args.video,
        args.out,
        marker_positions_m=markers,
        fps=args.fps,
        tracker=TipTracker(min_area_px=args.min_area),
        calibration=calibration,
        track_hub=not args.no_hub,
        progress=True,
    )
    outputs.done(args.out)  # written atomically by track_video
    lost = int(np.sum(rows[:, 8] > 0.5)) if len(rows) else 0
    print(f"tracked {len(rows)} frames ({lost} lost) -> {args.out}")
    return 0


def _track_camera(args: argparse.Namespace, markers, calibration) -> int:
    import math

    import numpy as np

    from softpend.vision.camera import DEFAULT_MARKERS_M
    from softpend.vision.tip_source import FrameTracker, open_tip_source
    from softpend.vision.track_video import track_live
    from softpend.vision.tracker import TipTracker

    if args.fps is not None:
        raise ValueError("--fps is for video files; a live camera stamps each frame when it arrives")
    latency_ms = args.camera_latency_ms
    if not (math.isfinite(latency_ms) and latency_ms >= 0):
        raise ValueError(f"--camera-latency-ms must be a non-negative number, got {latency_ms!r}")
    tracker = FrameTracker(
        TipTracker(min_area_px=args.min_area), calibration, markers if markers is not None else DEFAULT_MARKERS_M
    )
    source = open_tip_source(args.camera, latency_s=latency_ms / 1000.0, frame_tracker=tracker)
    rows = track_live(source, args.out, duration_s=args.duration, track_hub=not args.no_hub, progress=True)
    lost = int(np.sum(rows[:, 8] > 0.5)) if len(rows) else 0
    print(f"tracked {len(rows)} frames ({lost} lost) from camera {args.camera} -> {args.out}")
    return 0
