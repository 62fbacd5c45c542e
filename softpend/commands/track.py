"""``softpend track``: track the blue tip dot in a video file or live from ``--camera`` into a time-stamped CSV."""

from __future__ import annotations

import argparse

from softpend.commands.options import MAX_SESSION_S, Option, add_command, camera_source

OPTIONS: tuple[Option, ...] = (
    ("video", None, dict(nargs="?", help="video file (its sidecar VIDEO.json is used if present)")),
    ("--camera", None, dict(help="track live instead: a camera index (0), a stream URL or a video file")),
    ("--duration", (1e-3, MAX_SESSION_S), dict(type=float, help="with --camera: stop after this many seconds")),
    ("--camera-latency-ms", (0.0, 1000.0), dict(type=float, default=0.0, help="with --camera: its latency [ms] (0)")),
    ("--out", None, dict(required=True, metavar="CSV", help="output CSV, replaced once the video is tracked")),
    ("--markers", None, dict(metavar="JSON", help="marker positions [m]: a JSON list [[x, y], ...] or file")),
    ("--calibration", None, dict(metavar="JSON", help="a saved AffineCalibration instead of markers")),
    ("--fps", (1e-3, 1e6), dict(type=float, help="frame rate of a video without a sidecar (timestamps)")),
    ("--min-area", (0.0, 1e8), dict(type=float, default=20.0, help="smallest dot area [px^2] (default 20)")),
    ("--no-hub", None, dict(action="store_true", help="do not track the magenta hub marker")),
)


def register(subparsers: argparse._SubParsersAction) -> None:
    add_command(subparsers, "track", "track the tip dot in a video file into a time-stamped CSV", OPTIONS, run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from softpend.io.outputs import Outputs
    from softpend.vision.calibration import AffineCalibration, read_markers
    from softpend.vision.track_video import track_live, track_video
    from softpend.vision.tracker import TipTracker

    outputs = Outputs()  # before the work: a CSV this command wrote may be replaced, no other file
    outputs.file(args.out, what="--out")
    markers = read_markers("--markers", args.markers)
    calibration = AffineCalibration.load(args.calibration) if args.calibration else None
    if (args.video is None) == (args.camera is None):
        raise ValueError("give either a VIDEO file or --camera CAMERA")
    tracker, hub = TipTracker(min_area_px=args.min_area), not args.no_hub
    if args.camera is not None:
        if args.fps is not None:
            raise ValueError("--fps is for video files; a live camera stamps each frame when it arrives")
        source = camera_source(args, tracker)
        try:
            rows = track_live(source, args.out, duration_s=args.duration, track_hub=hub, progress=True)
        finally:
            outputs.done(args.out)  # written atomically by track_live (also on Ctrl-C)
    else:
        video = dict(marker_positions_m=markers, fps=args.fps, tracker=tracker, calibration=calibration)
        rows = track_video(args.video, args.out, **video, track_hub=hub, progress=True)
        outputs.done(args.out)  # written atomically by track_video
    source_text = f"from camera {args.camera} " if args.camera is not None else ""
    lost = int(np.sum(rows[:, 8] > 0.5)) if len(rows) else 0
    print(f"tracked {len(rows)} frames ({lost} lost) {source_text}-> {args.out}")
    return 0
