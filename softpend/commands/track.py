"""``softpend track``: track the blue tip dot in a video file, or live from a camera (``--camera``: a device
index, a stream URL or a video file read as a stream), into a time-stamped CSV."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("track", help="track the tip dot in a video file into a time-stamped CSV")
    parser.add_argument("video", nargs="?", help="video file (its sidecar VIDEO.json is used if present)")
    parser.add_argument("--camera", help="track live instead: a camera index (0), a stream URL or a video file")
    parser.add_argument("--duration", type=float, help="with --camera: stop after this many seconds")
    parser.add_argument(
        "--camera-latency-ms", type=float, default=0.0, help="with --camera: exposure-to-host latency [ms] (default 0)"
    )
    parser.add_argument("--out", required=True, metavar="CSV", help="output CSV, replaced once the video is tracked")
    parser.add_argument("--markers", metavar="JSON", help="marker positions [m]: a JSON list [[x, y], ...] or file")
    parser.add_argument("--calibration", metavar="JSON", help="a saved AffineCalibration instead of markers")
    parser.add_argument("--fps", type=float, help="frame rate for timestamps when the video has no sidecar")
    parser.add_argument("--min-area", type=float, default=20.0, help="smallest dot area [px^2] (default 20)")
    parser.add_argument("--no-hub", action="store_true", help="do not track the magenta hub marker")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from softpend.commands.options import MAX_SESSION_S, check_numbers
    from softpend.io.outputs import Outputs
    from softpend.vision.calibration import AffineCalibration, read_markers
    from softpend.vision.camera import MAX_FPS
    from softpend.vision.tip_source import FrameTracker, open_tip_source
    from softpend.vision.track_video import track_live, track_video
    from softpend.vision.tracker import TipTracker

    outputs = Outputs()  # before the work: a CSV this command wrote may be replaced, no other file
    outputs.file(args.out, what="--out")
    limits = {"--duration": (1e-3, MAX_SESSION_S), "--camera-latency-ms": (0.0, 1000.0), "--min-area": (0.0, 1e8)}
    check_numbers(args, {**limits, "--fps": (1e-3, MAX_FPS)})
    markers = read_markers("--markers", args.markers)
    calibration = AffineCalibration.load(args.calibration) if args.calibration else None
    if (args.video is None) == (args.camera is None):
        raise ValueError("give either a VIDEO file or --camera CAMERA")
    tracker = TipTracker(min_area_px=args.min_area)
    if args.camera is not None:
        if args.fps is not None:
            raise ValueError("--fps is for video files; a live camera stamps each frame when it arrives")
        frame_tracker = FrameTracker(tracker, calibration, markers)
        source = open_tip_source(args.camera, latency_s=args.camera_latency_ms / 1000.0, frame_tracker=frame_tracker)
        try:
            rows = track_live(source, args.out, duration_s=args.duration, track_hub=not args.no_hub, progress=True)
        finally:
            outputs.done(args.out)  # written atomically by track_live (also on Ctrl-C)
        source_text = f"from camera {args.camera} "
    else:
        rows = track_video(
            args.video,
            args.out,
            marker_positions_m=markers,
            fps=args.fps,
            tracker=tracker,
            calibration=calibration,
            track_hub=not args.no_hub,
            progress=True,
        )
        outputs.done(args.out)  # written atomically by track_video
        source_text = ""
    lost = int(np.sum(rows[:, 8] > 0.5)) if len(rows) else 0
    print(f"tracked {len(rows)} frames ({lost} lost) {source_text}-> {args.out}")
    return 0
