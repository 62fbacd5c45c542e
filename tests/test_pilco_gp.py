"""PILCO's GP dynamics model: fit on a known function, subsampling, input checks."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from softpend.pilco.gp import MultiOutputGP, select_subset

torch.set_num_threads(1)


def _data(n: int, noise_std: float, seed: int):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-3, 3, (n, 3))  # the third input is irrelevant
    y = np.stack([np.sin(x[:, 0]) + 0.5 * np.cos(2 * x[:, 1]), 0.3 * x[:, 0] * x[:, 1]], 1)
    return x, y, y + noise_std * rng.normal(size=y.shape)


def test_gp_fit_recovers_a_known_function():
    x, _, y_noisy = _data(120, 0.05, seed=0)
    gp = MultiOutputGP(x, y_noisy)
    gp.fit(80)
    x_test, y_true, _ = _data(300, 0.0, seed=1)
    mean, var = gp.predict(x_test)
    rmse = np.sqrt(np.mean((mean - y_true) ** 2, axis=0))
    assert np.all(rmse < 0.1), rmse  # signal std is about 0.8 and 0.9
    # calibrated: the errors are of the size of the predicted standard deviation
    z = (mean - y_true) / np.sqrt(var)
    assert 0.2 < np.sqrt(np.mean(z**2)) < 3.0
    noise = np.exp(gp.hyperparameters.log_noise_std)
    assert np.all((noise > 0.025) & (noise < 0.1)), noise
    ell = np.exp(gp.hyperparameters.log_lengthscales)
    assert ell[0, 2] > 5 * ell[0, 0]  # automatic relevance determination switches the irrelevant input off


def test_fit_beats_the_initial_guess_and_noise_free_data_stays_well_posed():
    x, y, _ = _data(80, 0.0, seed=2)
    gp = MultiOutputGP(x, y)
    x_test, y_true, _ = _data(200, 0.0, seed=3)
    before = np.sqrt(np.mean((gp.predict(x_test)[0] - y_true) ** 2))
    gp.fit(80)
    after = np.sqrt(np.mean((gp.predict(x_test)[0] - y_true) ** 2))
    assert after < 0.5 * before
    # the signal-to-noise penalty keeps sf/sn at most about 500 even without noise in the data
    h = gp.hyperparameters
    assert np.all(h.log_signal_std - h.log_noise_std < np.log(500) * 1.1)
    assert np.all(np.isfinite(gp.beta.numpy()))


def test_select_subset_keeps_the_latest_points_and_is_seeded():
    idx = select_subset(1000, 100, recent=30, seed=0)
    assert len(idx) == 100 and len(set(idx.tolist())) == 100
    assert set(range(970, 1000)) <= set(idx.tolist())
    np.testing.assert_array_equal(idx, select_subset(1000, 100, recent=30, seed=0))
    assert not np.array_equal(idx, select_subset(1000, 100, recent=30, seed=1))
    np.testing.assert_array_equal(select_subset(50, 100, recent=30, seed=0), np.arange(50))
    with pytest.raises(ValueError, match="max_points"):
        select_subset(10, 0, recent=0, seed=0)


def test_bad_inputs_raise_value_errors():
    with pytest.raises(ValueError, match="inputs"):
        MultiOutputGP(np.zeros((5, 2)), np.zeros((4, 1)))
    with pytest.raises(ValueError, match="finite"):
        MultiOutputGP(np.full((5, 2), np.nan), np.zeros((5, 1)))
    gp = MultiOutputGP(np.random.default_rng(0).normal(size=(5, 2)), np.zeros((5, 1)))
    with pytest.raises(ValueError, match="columns"):
        gp.predict(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="max_iterations"):
        gp.fit(0)
