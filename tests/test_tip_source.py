"""Live tip sources: the twin's synthetic camera filming a live scene in simulated time (time stamps, accuracy,
faults), ``cv2.VideoCapture`` on a file as a camera, and ``softpend track --camera``."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from softpend.cli import main
from softpend.hardware.emulator import RigConfig, SimRig
from softpend.io.samplelog import read_sample_log
from softpend.task import Task
from softpend.vision.accuracy import babbling_trajectory
from softpend.vision.camera import CameraEffects, CameraModel, SyntheticCamera, render_video
from softpend.vision.tip_source import (
    CameraFaults,
    CaptureTipSource,
    SyntheticLiveCamera,
    TipMeasurement,
    open_tip_source,
)

#: A quarter-size camera: the same optics at 320x240 (cheaper to render).
SMALL = CameraModel(width_px=320, height_px=240, px_per_m=320.0, centre_px=(160.0, 119.0))


def _film(rig: SimRig, camera: SyntheticLiveCamera, seconds: float) -> list[TipMeasurement]:
    camera.start()
    rig.clock.sleep_until(seconds)
    return camera.poll()


def test_synthetic_live_camera_stamps_frames_with_their_capture_time():
    rig = SimRig(RigConfig(task=Task(start_noise_rad=0.0), initial_tilt_rad=2.0))  # the rod falls: a fast tip
    camera = SyntheticLiveCamera(
        rig.poses,
        rig.clock,
        fps=60,
        latency_s=0.02,
        model=SMALL,
        effects=CameraEffects.rig(),
        faults=CameraFaults(occlusions_s=((0.4, 0.6),)),
    )
    measurements = _film(rig, camera, 1.2)
    exposure = camera.camera.effects.exposure_s
    # every frame whose delivery time has come, and no other: t_k + latency <= 1.2 s
    assert len(measurements) == math.floor((1.2 - exposure - 0.02) * 60) + 1
    captures = np.array([m.capture_time_s for m in measurements])
    np.testing.assert_allclose(np.diff(captures), 1 / 60, rtol=1e-9)
    np.testing.assert_allclose(
        [m.delivered_time_s - m.capture_time_s for m in measurements], 0.02 + exposure / 2, rtol=1e-9
    )
    seen = [m for m in measurements if not m.lost]
    errors = [np.hypot(*(rig.poses.pose_at(m.capture_time_s)[0][-1] - (m.x_m, m.y_m))) for m in seen]
    # the tip moves up to ~2 m/s: a stamp 10 ms off would show as ~2 cm; blur and noise leave ~1 mm
    assert np.median(errors) < 0.002 and max(errors) < 0.006
    # simulated time on the rig's clock since the first frame (not the wall clock): the occlusion's 0.4-0.6 s
    since_first_s = captures + exposure / 2 - camera.first_frame_time_s
    lost = np.array([m.lost for m in measurements])
    inside = (since_first_s > 0.41) & (since_first_s < 0.59)
    assert inside.any() and lost[inside].all()
    assert not lost[(since_first_s < 0.39) | (since_first_s > 0.61)].any()
    assert camera.stats()["frames_occluded"] == lost.sum()


def test_synthetic_live_camera_stall_stops_delivery_and_drops_are_counted():
    rig = SimRig(RigConfig())
    camera = SyntheticLiveCamera(
        rig.poses,
        rig.clock,
        fps=30,
        latency_s=0.0,
        model=SMALL,
        faults=CameraFaults(stall_after_s=0.3, drop_probability=0.3, seed=1),
    )
    measurements = _film(rig, camera, 0.9)
    # capture times on the simulated clock: nothing captured after the stall at 0.3 s
    since_first_s = np.array([m.capture_time_s for m in measurements]) - camera.first_frame_time_s
    assert len(measurements) >= 2 and np.all(since_first_s < 0.3)
    stats = camera.stats()
    assert stats["frames_stalled"] >= 15 and stats["frames_dropped"] >= 1
    assert stats["frames_tracked"] + stats["frames_dropped"] == 9  # frames at 0, 1/30, ... 8/30 s; then the stall
    camera.close()
    rig.clock.sleep_until(1.5)
    assert camera.poll() == []  # a closed camera films no more


def test_camera_faults_reject_bad_values():
    with pytest.raises(ValueError, match="drop_probability"):
        CameraFaults(drop_probability=1.5)
    with pytest.raises(ValueError, match="occlusions_s"):
        CameraFaults(occlusions_s=((0.5, 0.2),))
    with pytest.raises(ValueError, match="stall_after_s"):
        CameraFaults(stall_after_s=-1.0)
    rig = SimRig(RigConfig())
    with pytest.raises(ValueError, match="fps"):
        SyntheticLiveCamera(rig.poses, rig.clock, fps=0.0)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    path = tmp_path_factory.mktemp("clip") / "clip.avi"
    times, points, hub = babbling_trajectory(100)
    stamps, _ = render_video(path, SyntheticCamera(), times, points, hub, fps=50.0)
    return path, stamps


def test_a_capture_source_on_a_video_file_agrees_with_the_offline_tracker(clip, tmp_path):
    path, stamps = clip
    assert main(["track", str(path), "--out", str(tmp_path / "offline.csv")]) == 0
    offline = read_sample_log(tmp_path / "offline.csv")
    capture = open_tip_source(str(path))
    assert isinstance(capture, CaptureTipSource)
    captured = []
    capture.start()
    try:
        while not capture.finished:
            captured += capture.poll()
            time.sleep(0.005)
    finally:
        capture.close()
    assert len(captured) == len(offline) == len(stamps)
    np.testing.assert_allclose([m.x_m for m in captured], offline["x_m"], atol=1e-12)
    np.testing.assert_allclose([m.y_m for m in captured], offline["y_m"], atol=1e-12)
    assert [m.frame for m in captured] == list(range(len(captured)))


def test_track_command_on_a_live_camera(clip, tmp_path):
    path, stamps = clip
    out = tmp_path / "live.csv"
    assert main(["track", "--camera", str(path), "--out", str(out)]) == 0
    live = read_sample_log(out)
    assert len(live) == len(stamps) and not live["lost"].any()
    assert np.all(np.diff(live["camera_time_s"]) >= 0)
    assert np.isfinite(live["hub_angle_rad"]).mean() > 0.9  # the hub marker is tracked too
    assert main(["track", "--out", str(tmp_path / "x.csv")]) == 2  # neither a video nor a camera
    assert main(["track", str(path), "--camera", "0", "--out", str(tmp_path / "x.csv")]) == 2  # both
    assert main(["track", "--camera", str(tmp_path / "missing.avi"), "--out", str(tmp_path / "x.csv")]) == 2
    assert not (tmp_path / "x.csv").exists()


def test_open_tip_source_rejects_empty_names():
    with pytest.raises(ValueError, match="camera"):
        open_tip_source("  ")
    assert math.isnan(TipMeasurement(math.nan, math.nan, True).theta_rad)
