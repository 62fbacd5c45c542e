"""The tip tracker (Algorithm 1) on rendered frames with known truth, the calibration, and `softpend track`."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from softpend.plant import RodParams, make_plant
from softpend.vision.calibration import calibrate_from_markers, fit_affine
from softpend.vision.camera import DEFAULT_MARKERS_M, CameraEffects, CameraModel, SyntheticCamera, render_video
from softpend.vision.track_video import TRACK_COLUMNS
from softpend.vision.tracker import TipTracker


@pytest.fixture(scope="module")
def swing():
    """0.6 s of a swinging rod: times [s], link points (T, n + 1, 2) [m], hub angles [rad]."""
    plant = make_plant("prb", params=RodParams())
    q, qd = plant.hanging_state()
    q[0] = 2.0
    plant.reset(q, qd)
    times, points, hub = [], [], []
    for k in range(60):
        times.append(k * 0.01)
        points.append(plant.link_points_m())
        hub.append(plant.joint_state()[0][0])
        plant.step(0.06 * math.sin(0.3 * k))
    return np.array(times), np.array(points), np.array(hub)


def _rmse_px(camera: SyntheticCamera, swing, frames_at: np.ndarray) -> tuple[float, int]:
    times, points, hub = swing
    tracker = TipTracker()
    errors, lost = [], 0
    for frame, truth in camera.frames(times, points, frames_at, hub):
        d = tracker.track(frame)
        lost += d.lost
        errors.append([d.x_px - truth[0], d.y_px - truth[1]])
    return float(np.sqrt(np.nanmean(np.sum(np.square(errors), axis=1)))), lost


def test_tracker_is_subpixel_on_clean_frames(swing):
    rmse, lost = _rmse_px(SyntheticCamera(seed=0), swing, swing[0][1:40:2])
    assert lost == 0 and rmse < 0.5


def test_tracker_with_noise_blur_lighting_and_clutter(swing):
    rmse, lost = _rmse_px(SyntheticCamera(effects=CameraEffects.noisy(), seed=1), swing, swing[0][2:40:2])
    assert lost == 0 and rmse < 1.5


def test_no_dot_or_too_small_dot_is_lost_not_guessed(swing):
    times, points, _ = swing
    camera = SyntheticCamera(effects=CameraEffects(clutter=True), seed=2)
    frame, tip = camera.draw(points[10])
    hidden = frame.copy()
    cv2.circle(hidden, (int(round(tip[0])), int(round(tip[1]))), 12, (70, 70, 70), -1)
    d = TipTracker().track(hidden)  # the clutter has tiny blue specks: they must not be taken for the dot
    assert d.lost and math.isnan(d.x_px) and math.isnan(d.y_px)
    assert not TipTracker().track(frame).lost
    assert TipTracker(min_area_px=10_000).track(frame).lost  # the dot is below this minimum area
    with pytest.raises(ValueError, match="frame_bgr"):
        TipTracker().track(np.zeros((10, 10), np.uint8))
    with pytest.raises(ValueError, match="min_area_px"):
        TipTracker(min_area_px=-1)


def test_search_window_tracking_matches_full_frame(swing):
    times, points, hub = swing
    camera = SyntheticCamera(seed=0)
    full, windowed = TipTracker(search_radius_px=None), TipTracker(search_radius_px=40)
    for frame, _ in camera.frames(times, points, times[1:20], hub):
        a, b = full.track(frame), windowed.track(frame)
        assert (a.x_px, a.y_px) == pytest.approx((b.x_px, b.y_px), abs=1e-9)


def test_calibration_recovers_a_skewed_camera():
    model = CameraModel(px_per_m=610.0, centre_px=(331.0, 229.5), roll_rad=-0.07)
    camera = SyntheticCamera(model=model, effects=CameraEffects(noise_std_dn=2.0), seed=3)
    frame, tip_px = camera.draw(np.array([[0.0, 0.0], [0.1, -0.1], [0.21, -0.2]]))
    calibration = calibrate_from_markers(frame, DEFAULT_MARKERS_M)
    truth = np.linalg.inv((model.to_pixels(np.eye(2)) - model.centre_px).T)  # the camera's exact pixel -> metre map
    np.testing.assert_allclose(calibration.pixel_to_metre[:, :2], truth, rtol=0.01, atol=2e-6)
    # a tip position maps back to metres within half a millimetre
    np.testing.assert_allclose(calibration.to_metres(tip_px), [0.21, -0.2], atol=5e-4)
    np.testing.assert_allclose(calibration.to_pixels(calibration.to_metres(tip_px)), tip_px, atol=1e-9)
    assert calibration.residual_rms_m < 1e-3
    with pytest.raises(ValueError, match="only 4 are visible"):
        calibrate_from_markers(frame, list(DEFAULT_MARKERS_M) + [(0.0, 0.33)])
    with pytest.raises(ValueError, match="collinear"):
        fit_affine(np.array([[0, 0], [1, 1], [2, 2]]), np.array([[0, 0], [1, 1], [2, 2]]))


def test_softpend_track_writes_a_timestamped_csv(tmp_path, swing, capsys):
    from softpend.cli import main
    from softpend.io.samplelog import read_sample_log

    times, points, hub = swing
    video = tmp_path / "clip.avi"
    stamps, tips = render_video(
        video, SyntheticCamera(seed=4), times, points, hub, fps=100.0, clock_offset_s=12.5, drop_dot_frames=[7]
    )
    assert video.exists() and len(stamps) > 40
    out = tmp_path / "track.csv"
    assert main(["track", str(video), "--out", str(out)]) == 0
    assert "1 lost" in capsys.readouterr().out
    data = read_sample_log(out)
    assert data.columns == list(TRACK_COLUMNS) and len(data) == len(stamps)
    np.testing.assert_allclose(data["camera_time_s"], stamps)
    lost = data["lost"] > 0.5
    assert lost.tolist().index(True) == 7 and lost.sum() == 1 and np.isnan(data["x_m"][7])
    # through the MJPG codec the tip is still within a pixel of the truth
    err = np.hypot(data["x_px"] - tips[:, 0], data["y_px"] - tips[:, 1])[~lost]
    assert np.sqrt(np.mean(err**2)) < 1.0
    # the camera's view of the hub angle matches the simulated hub
    hub_cam = data["hub_angle_rad"]
    hub_true = (np.interp(np.asarray(stamps) - 12.5, times, hub) + np.pi) % (2 * np.pi) - np.pi
    assert np.max(np.abs(np.angle(np.exp(1j * (hub_cam - hub_true))))) < 0.06
    assert main(["track", str(tmp_path / "missing.avi"), "--out", str(out)]) == 2
