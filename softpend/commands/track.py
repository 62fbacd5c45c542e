"""``softpend track``: track the blue tip dot in a video into a time-stamped CSV (Algorithm 1)."""

from __future__ import annotations

import argparse
import json


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("track", help="track the tip dot in a video file into a time-stamped CSV")
    parser.add_argument("video", help="video file (the synthetic camera's sidecar VIDEO.json is used if present)")
    parser.add_argument("--out", required=True, metavar="CSV",
                        help="output CSV (crash-safe sample log; replaced only once the whole video is tracked)")
    parser.add_argument("--markers", metavar="JSON",
                        help='marker positions in the rod plane [m], JSON list [[x, y], ...] or file (hub axis at 0, y up)')
    parser.add_argument("--calibration", metavar="JSON", help="a saved AffineCalibration instead of markers")
    parser.add_argument("--fps", type=float, help="frame rate for timestamps when the video has no sidecar")
    parser.add_argument("--min-area", type=float, default=20.0, help="smallest dot area [px^2] (default 20)")
    parser.add_argument("--no-hub", action="store_true", help="do not track the magenta hub marker")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from softpend.vision.calibration import MAX_CALIBRATION_BYTES, AffineCalibration, points_array, read_json_file
    from softpend.vision.track_video import track_video
    from softpend.vision.tracker import TipTracker

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
    rows = track_video(args.video, args.out, marker_positions_m=markers, fps=args.fps,
                       tracker=TipTracker(min_area_px=args.min_area), calibration=calibration,
                       track_hub=not args.no_hub, progress=True)
    lost = int(np.sum(rows[:, 8] > 0.5)) if len(rows) else 0
    print(f"tracked {len(rows)} frames ({lost} lost) -> {args.out}")
    return 0
