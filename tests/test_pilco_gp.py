"""PILCO's GP dynamics model: fit on a known function, subsampling, input checks."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from support import gp_predict

from softpend.pilco.gp import MultiOutputGP, select_subset

torch.set_num_threads(1)


def _moments(gp: MultiOutputGP, mean: torch.Tensor, cov: torch.Tensor):
    function, parameters = gp.moment_function()
    return function(mean, cov, *parameters)


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
    mean, var = gp_predict(gp, x_test)
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
    before = np.sqrt(np.mean((gp_predict(gp, x_test)[0] - y_true) ** 2))
    gp.fit(80)
    after = np.sqrt(np.mean((gp_predict(gp, x_test)[0] - y_true) ** 2))
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


@pytest.mark.parametrize("noise_std", [0.05, 0.0])
def test_fitc_on_the_training_data_is_the_exact_gp(noise_std):
    """With the training inputs as inducing inputs and no other data, FITC's predictions and the moments at a
    Gaussian input are the exact GP's (the noise-free case has the worst-conditioned kernel matrix)."""
    x, _, y_noisy = _data(150, noise_std, seed=0)
    gp = MultiOutputGP(x, y_noisy)
    gp.fit(60)
    x_test = x[:30] + 0.1
    mean0, var0 = gp_predict(gp, x_test)
    mu = torch.tensor([0.3, -0.2, 0.1], dtype=torch.float64)
    moments0 = [_moments(gp, mu, scale * torch.eye(3, dtype=torch.float64)) for scale in (0.01, 0.3)]
    gp.condition_on(x, y_noisy)
    mean1, var1 = gp_predict(gp, x_test)
    np.testing.assert_allclose(mean1, mean0, atol=1e-4 * np.abs(mean0).max())
    np.testing.assert_allclose(var1, var0, rtol=0.05, atol=1e-3 * var0.max())
    for scale, (m0, s0, c0) in zip((0.01, 0.3), moments0):
        m1, s1, c1 = _moments(gp, mu, scale * torch.eye(3, dtype=torch.float64))
        np.testing.assert_allclose(m1.numpy(), m0.numpy(), atol=1e-5)
        np.testing.assert_allclose(s1.numpy(), s0.numpy(), atol=1e-5)
        np.testing.assert_allclose(c1.numpy(), c0.numpy(), atol=1e-4)


def test_fitc_on_all_data_predicts_better_than_the_subset_and_stays_calibrated():
    x, _, y_noisy = _data(600, 0.05, seed=4)
    subset = select_subset(600, 120, recent=60, seed=0)
    gp = MultiOutputGP(x[subset], y_noisy[subset])
    gp.fit(60)
    x_test, y_true, _ = _data(400, 0.0, seed=5)
    mean_subset, var_subset = gp_predict(gp, x_test)
    gp.condition_on(x, y_noisy)
    mean_all, var_all = gp_predict(gp, x_test)
    rmse_subset = np.sqrt(np.mean((mean_subset - y_true) ** 2, axis=0))
    rmse_all = np.sqrt(np.mean((mean_all - y_true) ** 2, axis=0))
    assert np.all(rmse_all < 0.8 * rmse_subset), (rmse_all, rmse_subset)
    assert np.all(var_all.mean(axis=0) < var_subset.mean(axis=0))  # five times the data: less model uncertainty
    z = (mean_all - y_true) / np.sqrt(var_all)
    assert 0.2 < np.sqrt(np.mean(z**2)) < 3.0
    assert gp.beta.shape == (2, 120) and gp.inv_kernel.shape == (2, 120, 120)  # the cost of the subset


def test_bad_inputs_raise_value_errors():
    with pytest.raises(ValueError, match="inputs"):
        MultiOutputGP(np.zeros((5, 2)), np.zeros((4, 1)))
    with pytest.raises(ValueError, match="finite"):
        MultiOutputGP(np.full((5, 2), np.nan), np.zeros((5, 1)))
    gp = MultiOutputGP(np.random.default_rng(0).normal(size=(5, 2)), np.zeros((5, 1)))
    with pytest.raises(ValueError, match="inputs must be"):
        gp.condition_on(np.zeros((8, 3)), np.zeros((8, 1)))
    with pytest.raises(ValueError, match="finite"):
        gp.condition_on(np.full((8, 2), np.inf), np.zeros((8, 1)))
