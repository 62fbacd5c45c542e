"""Motor babbling, numerical differentiation and the dataset file format."""

from __future__ import annotations

import hashlib
import io
import json
import zipfile

import numpy as np
import pytest

from softpend.plant import OBSERVATION_NAMES, RodParams
from softpend.sysid import (
    BabbleProtocol,
    TrajectoryDataset,
    babble,
    backward_difference,
    band_limited_noise,
    load_dataset,
    save_dataset,
)

TINY = BabbleProtocol(n_trials=3, trial_length_s=1.0, feedback_trial_fraction=1.0)


@pytest.fixture(scope="module")
def tiny() -> TrajectoryDataset:
    return babble(TINY, seed=3, progress=False)


# ------------------------------------------------------------------ differentiation
def test_backward_difference_matches_the_derivative_of_a_known_signal():
    dt = 0.01
    t = np.arange(0, 2, dt)
    x = np.sin(3 * t)[:, None]
    v = backward_difference(x, dt, np.array([False]))[:, 0]
    # a backward difference is the exact derivative at the midpoint to second order ...
    midpoint = 3 * np.cos(3 * (t[1:] - dt / 2))
    assert np.max(np.abs(v - midpoint)) < 3**3 * dt**2 / 24 * 1.01
    # ... and first order at the sample itself: error ~ x'' dt / 2
    at_sample = 3 * np.cos(3 * t[1:])
    err = np.max(np.abs(v - at_sample))
    assert 0.5 * 9 * dt / 2 < err < 1.01 * 9 * dt / 2


def test_backward_difference_unwraps_angles():
    dt = 0.01
    t = np.arange(0, 3, dt)
    angle = 5.0 * t  # rad, crosses the +-pi seam several times
    wrapped = (angle + np.pi) % (2 * np.pi) - np.pi
    v = backward_difference(np.stack([wrapped, wrapped], axis=1), dt, np.array([True, False]))
    np.testing.assert_allclose(v[:, 0], 5.0, rtol=1e-9)  # unwrapped: constant rate
    assert np.max(np.abs(v[:, 1])) > 100  # the same column treated as a length jumps by 2 pi / dt


def test_band_limited_noise_has_the_requested_spread_and_bandwidth():
    rng = np.random.default_rng(0)
    u = band_limited_noise(rng, 200_000, std=0.03, bandwidth_hz=2.0, dt_s=0.01)
    assert abs(u.std() - 0.03) < 0.003
    a = np.exp(-2 * np.pi * 2.0 * 0.01)
    lag1 = np.corrcoef(u[1:], u[:-1])[0, 1]
    assert abs(lag1 - a) < 0.01  # first-order low-pass: lag-1 correlation exp(-2 pi fc dt)


# ------------------------------------------------------------------ babbling
def test_babble_shapes_limits_and_upright_region(tiny):
    n = TINY.n_samples
    assert tiny.positions.shape == (3, n, 5) and tiny.torques_nm.shape == (3, n - 1)
    assert tiny.true_observations.shape == (3, n, len(OBSERVATION_NAMES))
    limit = tiny.params.torque_limit_nm
    assert np.abs(tiny.torques_nm).max() <= limit + 1e-12
    assert np.abs(tiny.torques_nm).max() > 0.5 * limit  # the torque process actually excites the rod
    # with the stabilising feedback the rod stays in the upright region for the whole trial
    assert np.abs(tiny.column("theta_rad")).max() < 1.0
    # noise-free data: observed positions are the simulator's, differenced velocities approximate the true ones
    np.testing.assert_allclose(tiny.positions, tiny.true_observations[..., :5], atol=1e-12)
    v_obs, v_true = tiny.velocities[..., 2:4], tiny.true_observations[..., 7:9]  # ex_dot, ey_dot
    assert np.sqrt(np.mean((v_obs - v_true) ** 2)) < 0.3 * np.sqrt(np.mean(v_true**2))
    # the stored velocity is exactly the backward difference of the stored positions
    np.testing.assert_allclose(
        tiny.velocities[:, 1:, 2], np.diff(tiny.positions[..., 2], axis=1) / TINY.dt_s, atol=1e-9
    )


def test_babble_is_reproducible_to_the_byte(tmp_path):
    protocol = TINY.replace(n_trials=2, feedback_trial_fraction=0.5)
    a = babble(protocol, seed=11, path=tmp_path / "a.npz", progress=False)
    babble(protocol, seed=11, path=tmp_path / "b.npz", progress=False)
    c = babble(protocol, seed=12, path=tmp_path / "c.npz", progress=False)
    digest = lambda p: hashlib.sha256(p.read_bytes()).hexdigest()  # noqa: E731
    assert digest(tmp_path / "a.npz") == digest(tmp_path / "b.npz")
    assert digest(tmp_path / "a.npz") != digest(tmp_path / "c.npz")
    assert not np.allclose(a.torques_nm, c.torques_nm)


def test_babble_sensor_noise_and_camera_delay():
    protocol = TINY.replace(n_trials=1, tip_noise_std_m=0.002, camera_delay_steps=3)
    data = babble(protocol, seed=5, progress=False)
    true = data.true_observations[0]
    ex = data.column("ex_m")[0]
    # the camera sample i shows the true tip position of 3 samples earlier, plus noise
    residual = ex[3:] - true[:-3, OBSERVATION_NAMES.index("ex_m")]
    assert 0.0015 < residual.std() < 0.0025 and abs(residual.mean()) < 0.001
    # the encoder angle is neither delayed nor noisy
    np.testing.assert_allclose(data.column("phi_rad")[0], true[:, 0], atol=1e-12)


def test_babble_protocol_rejects_bad_input():
    with pytest.raises(ValueError, match="start"):
        BabbleProtocol(start="sideways")
    with pytest.raises(ValueError, match="n_trials"):
        BabbleProtocol(n_trials=0)
    with pytest.raises(ValueError, match="feedback_trial_fraction"):
        BabbleProtocol(feedback_trial_fraction=1.5)
    with pytest.raises(ValueError, match="seed"):
        babble(TINY, seed=-1, progress=False)


# ------------------------------------------------------------------ dataset files
def _rig_arrays(n_trials=2, n_samples=6):
    rng = np.random.default_rng(0)
    positions = np.stack(
        [
            rng.uniform(-0.5, 0.5, (n_trials, n_samples)),
            rng.uniform(-0.1, 0.1, (n_trials, n_samples)),
            0.3 + rng.uniform(-0.01, 0.01, (n_trials, n_samples)),
        ],
        axis=-1,
    )
    velocities = rng.normal(size=positions.shape)
    torques = rng.uniform(-0.05, 0.05, (n_trials, n_samples - 1))
    return positions, velocities, torques


def test_dataset_round_trip(tmp_path, tiny):
    from softpend.sysid import write_dataset

    path = write_dataset(tmp_path / "tiny", tiny)
    assert path.suffix == ".npz"
    back = load_dataset(path, expected_dt_s=0.01)
    for name, array in tiny.arrays().items():
        np.testing.assert_array_equal(getattr(back, name), array)
    assert back.metadata == tiny.metadata
    assert back.metadata["seed"] == 3 and back.metadata["plant_params"] == RodParams().to_dict()
    # a rig file: only the limited variables, no simulator arrays
    positions, velocities, torques = _rig_arrays()
    rig = save_dataset(
        tmp_path / "rig.npz", positions, velocities, torques, dt_s=0.02, position_names=("phi_rad", "ex_m", "ey_m")
    )
    back = load_dataset(tmp_path / "rig.npz")
    np.testing.assert_array_equal(back.positions, positions)
    assert back.true_observations is None and back.velocity_names == ("phi_dot_rad_s", "ex_dot_m_s", "ey_dot_m_s")
    assert rig.metadata == back.metadata


def test_save_dataset_rejects_bad_arrays(tmp_path):
    positions, velocities, torques = _rig_arrays()
    names = ("phi_rad", "ex_m", "ey_m")
    with pytest.raises(ValueError, match="velocities must have shape"):
        save_dataset(tmp_path / "x", positions, velocities[:, :-1], torques, dt_s=0.01, position_names=names)
    with pytest.raises(ValueError, match="torques_nm must have shape"):
        save_dataset(tmp_path / "x", positions, velocities, torques[:, :-1], dt_s=0.01, position_names=names)
    bad = positions.copy()
    bad[1, 2, 1] = np.nan
    with pytest.raises(ValueError, match="positions has non-finite"):
        save_dataset(tmp_path / "x", bad, velocities, torques, dt_s=0.01, position_names=names)
    with pytest.raises(ValueError, match="position_names must include"):
        save_dataset(
            tmp_path / "x", positions, velocities, torques, dt_s=0.01, position_names=("phi_rad", "theta_rad", "ey_m")
        )
    with pytest.raises(ValueError, match="dt_s"):
        save_dataset(tmp_path / "x", positions, velocities, torques, dt_s=0.0, position_names=names)
    with pytest.raises(ValueError, match="wrapped"):
        save_dataset(
            tmp_path / "x", positions + np.array([4.0, 0, 0]), velocities, torques, dt_s=0.01, position_names=names
        )
    with pytest.raises(ValueError, match="torque limit"):
        save_dataset(
            tmp_path / "x",
            positions,
            velocities,
            torques * 10,
            dt_s=0.01,
            position_names=names,
            plant_params=RodParams(),
        )
    assert not list(tmp_path.iterdir())  # nothing written on error


def _rewrite(path, replace):
    """Copy a dataset zip, changing members with replace(name, bytes) -> bytes or None (drop)."""
    src = zipfile.ZipFile(path)
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            data = replace(info.filename, src.read(info.filename))
            if data is not None:
                dst.writestr(info.filename, data)
    path.write_bytes(out.getvalue())


def _npy(array):
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, array, allow_pickle=True)
    return buffer.getvalue()


def test_load_dataset_errors(tmp_path, tiny):
    from softpend.sysid import write_dataset

    good = write_dataset(tmp_path / "good.npz", tiny)
    with pytest.raises(FileNotFoundError):
        load_dataset(tmp_path / "missing.npz")
    # corrupt: truncated archive and garbage bytes
    (tmp_path / "cut.npz").write_bytes(good.read_bytes()[:500])
    with pytest.raises(ValueError, match="not a readable dataset"):
        load_dataset(tmp_path / "cut.npz")
    (tmp_path / "junk.npz").write_bytes(b"this is not a zip file" * 10)
    with pytest.raises(ValueError, match="not a readable dataset"):
        load_dataset(tmp_path / "junk.npz")
    # mismatched metadata (claims more trials than the arrays hold)
    meta = dict(tiny.metadata, n_trials=7)
    path = tmp_path / "meta.npz"
    path.write_bytes(good.read_bytes())
    _rewrite(path, lambda n, b: _npy(np.array(json.dumps(meta))) if n == "metadata.npy" else b)
    with pytest.raises(ValueError, match=r"positions must have shape \(7,"):
        load_dataset(path)
    # wrong shape, NaN, wrong dtype, pickled object array, missing member
    cases = {
        "velocities.npy": (_npy(tiny.velocities[:, :, :2]), "velocities must have shape"),
        "positions.npy": (_npy(np.where(tiny.positions > 0.2, np.nan, tiny.positions)), "positions has non-finite"),
        "torques_nm.npy": (_npy(tiny.torques_nm.astype(np.float32)), "dtype float64"),
    }
    for member, (payload, message) in cases.items():
        path = tmp_path / f"bad_{member}.npz"
        path.write_bytes(good.read_bytes())
        _rewrite(path, lambda n, b: payload if n == member else b)
        with pytest.raises(ValueError, match=message):
            load_dataset(path)
    path = tmp_path / "pickle.npz"
    path.write_bytes(good.read_bytes())
    _rewrite(path, lambda n, b: _npy(np.array([{"evil": 1}], dtype=object)) if n == "torques_nm.npy" else b)
    with pytest.raises(ValueError, match="not a readable dataset"):
        load_dataset(path)
    path = tmp_path / "nomember.npz"
    path.write_bytes(good.read_bytes())
    _rewrite(path, lambda n, b: None if n == "torques_nm.npy" else b)
    with pytest.raises(ValueError, match="missing arrays"):
        load_dataset(path)
    # expectations of the caller
    with pytest.raises(ValueError, match="dt_s"):
        load_dataset(good, expected_dt_s=0.02)
