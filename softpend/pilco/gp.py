"""Gaussian-process regression for PILCO's dynamics model: one GP per output, squared-exponential ARD kernel."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
import scipy.optimize
import torch

from softpend.pilco.moments import gp_moments, pair_weights

DTYPE = torch.float64


@dataclass
class GPHyperparameters:
    """Hyperparameters of ``E`` independent GPs on ``D`` inputs (natural logs)."""

    log_lengthscales: np.ndarray  # (E, D)
    log_signal_std: np.ndarray  # (E,)
    log_noise_std: np.ndarray  # (E,)

    def to_dict(self) -> dict[str, list]:
        return {k: np.asarray(v).tolist() for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, data: dict) -> "GPHyperparameters":
        return cls(**{k: np.asarray(v, dtype=float) for k, v in data.items()})


def select_subset(n_points: int, max_points: int, recent: int, seed: int) -> np.ndarray:
    """Indices of at most ``max_points`` of ``n_points`` data points: the last ``recent`` always, the rest at random."""
    if n_points <= max_points:
        return np.arange(n_points)
    recent = min(max(int(recent), 0), max_points)
    newest = np.arange(n_points - recent, n_points)
    older = np.random.default_rng(seed).choice(n_points - recent, size=max_points - recent, replace=False)
    return np.sort(np.concatenate([np.sort(older), newest]))


def _data(inputs: np.ndarray, targets: np.ndarray, d: object = "D", e: object = "E") -> tuple[np.ndarray, np.ndarray]:
    """``inputs`` (N, d) and ``targets`` (N, e) as finite float arrays, else ``ValueError`` (``"D"``: any width)."""
    x, y = np.asarray(inputs, dtype=float), np.asarray(targets, dtype=float)
    if not (x.ndim == y.ndim == 2 and len(x) == len(y) and d in ("D", x.shape[1]) and e in ("E", y.shape[1])):
        raise ValueError(f"inputs must be (N, {d}) and targets (N, {e}) with the same N, got {x.shape} and {y.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("inputs and targets must be finite")
    return x, y


class MultiOutputGP:
    """``E`` independent GP regressors sharing the training inputs (SE-ARD kernel, zero prior mean)."""

    def __init__(self, inputs: np.ndarray, targets: np.ndarray, hyperparameters: Optional[GPHyperparameters] = None):
        inputs, targets = _data(inputs, targets)
        if len(inputs) < 2:
            raise ValueError(f"inputs must hold at least 2 points, got {len(inputs)}")
        self.inputs_np, self.targets_np = inputs, targets
        self.n_inputs, self.n_outputs = inputs.shape[1], targets.shape[1]
        self.input_std = np.maximum(inputs.std(axis=0), 1e-6)
        if hyperparameters is None:
            target_std = np.maximum(targets.std(axis=0), 1e-6)
            hyperparameters = GPHyperparameters(
                log_lengthscales=np.tile(np.log(self.input_std), (self.n_outputs, 1)),
                log_signal_std=np.log(target_std),
                log_noise_std=np.log(target_std / 10.0),
            )
        self.hyperparameters = hyperparameters
        self.conditioning: Optional[tuple[np.ndarray, np.ndarray]] = None
        self._update_cache()

    def condition_on(self, inputs: np.ndarray, targets: np.ndarray) -> None:
        """Condition the predictor on ``inputs`` (N, D) and ``targets`` (N, E), usually a superset of the training
        data, through FITC with the training inputs as the inducing inputs; the hyperparameters stay as they are."""
        self.conditioning = _data(inputs, targets, self.n_inputs, self.n_outputs)
        self._update_cache()

    @staticmethod
    def _neg_log_likelihood(
        params: torch.Tensor, x: torch.Tensor, y: torch.Tensor, log_input_std: torch.Tensor
    ) -> torch.Tensor:
        """Negative log marginal likelihood, penalised (PILCO) beyond 100 input spreads and a 500 signal-to-noise."""
        d = x.shape[1]
        log_ell, log_sf, log_sn = params[:d], params[d], params[d + 1]
        scaled = x / torch.exp(log_ell)
        sq = torch.sum(scaled**2, dim=1)
        dist2 = torch.clamp(sq.unsqueeze(1) + sq.unsqueeze(0) - 2.0 * scaled @ scaled.T, min=0.0)
        n = x.shape[0]
        k = torch.exp(2 * log_sf - 0.5 * dist2) + (torch.exp(2 * log_sn) + 1e-10) * torch.eye(n, dtype=x.dtype)
        chol = torch.linalg.cholesky(k)
        alpha = torch.cholesky_solve(y.unsqueeze(1), chol).squeeze(1)
        nll = 0.5 * y @ alpha + torch.sum(torch.log(torch.diagonal(chol))) + 0.5 * n * math.log(2 * math.pi)
        p = 30
        penalty = torch.sum(((log_ell - log_input_std) / math.log(100.0)) ** p)
        penalty = penalty + ((log_sf - log_sn) / math.log(500.0)) ** p
        return nll + penalty

    def fit(self, max_iterations: int = 100) -> list[float]:
        """Maximise each output's penalised log marginal likelihood (L-BFGS-B); returns the final objectives."""
        x = torch.as_tensor(self.inputs_np, dtype=DTYPE)
        log_input_std = torch.as_tensor(np.log(self.input_std), dtype=DTYPE)
        h = self.hyperparameters
        objectives = []
        for a in range(self.n_outputs):
            y = torch.as_tensor(self.targets_np[:, a], dtype=DTYPE)
            start = np.concatenate([h.log_lengthscales[a], [h.log_signal_std[a], h.log_noise_std[a]]])

            def objective(theta: np.ndarray) -> tuple[float, np.ndarray]:
                params = torch.tensor(theta, dtype=DTYPE, requires_grad=True)
                try:
                    value = self._neg_log_likelihood(params, x, y, log_input_std)
                except torch.linalg.LinAlgError:
                    return 1e10, np.zeros_like(theta)
                (grad,) = torch.autograd.grad(value, params)
                return float(value.detach()), grad.numpy().astype(float)

            result = scipy.optimize.minimize(
                objective, start, jac=True, method="L-BFGS-B", options={"maxiter": int(max_iterations)}
            )
            d = self.n_inputs
            h.log_lengthscales[a], h.log_signal_std[a], h.log_noise_std[a] = result.x[:d], result.x[d], result.x[d + 1]
            objectives.append(float(result.fun))
        self._update_cache()
        return objectives

    def _update_cache(self) -> None:
        """Precompute ``beta = (K + sn^2 I)^{-1} y``, ``(K + sn^2 I)^{-1}`` per output and the pair weights of the
        second moments (:func:`~softpend.pilco.moments.pair_weights`): constants for the policy search."""
        h = self.hyperparameters
        x = torch.as_tensor(self.inputs_np, dtype=DTYPE)
        y = torch.as_tensor(self.targets_np, dtype=DTYPE)
        n = x.shape[0]
        self.inputs = x
        self.log_lengthscales = torch.as_tensor(h.log_lengthscales, dtype=DTYPE).clone()
        self.log_signal_var = 2.0 * torch.as_tensor(h.log_signal_std, dtype=DTYPE)
        betas, inv_ks = [], []
        eye = torch.eye(n, dtype=DTYPE)
        for a in range(self.n_outputs):
            noise_var = math.exp(2 * h.log_noise_std[a]) + 1e-10
            if self.conditioning is None:
                inv_k = torch.cholesky_inverse(torch.linalg.cholesky(self._kernel(x, x, a) + noise_var * eye))
                beta = inv_k @ y[:, a]
            else:
                beta, inv_k = self._fitc(a, noise_var)
            inv_ks.append(inv_k)
            betas.append(beta)
        self.beta = torch.stack(betas)  # (E, N)
        self.inv_kernel = torch.stack(inv_ks)  # (E, N, N)
        self.pair_weights = pair_weights(self.beta, self.inv_kernel)  # (E (E + 1) / 2, N, N)

    def _fitc(self, a: int, noise_var: float) -> tuple[torch.Tensor, torch.Tensor]:
        """``beta`` (M,) and ``K_mm^-1 - A^-1`` (M, M) of output ``a`` under FITC (see :meth:`condition_on`), through
        ``K_mm + jitter = L L'`` and ``B = I + V Lambda^-1 V'`` with ``V = L^-1 K_mn``, in float64."""
        z = self.inputs
        assert self.conditioning is not None  # called only after condition_on
        x_all = torch.as_tensor(self.conditioning[0], dtype=DTYPE)
        y_all = torch.as_tensor(self.conditioning[1][:, a], dtype=DTYPE)
        m = z.shape[0]
        eye = torch.eye(m, dtype=DTYPE)
        signal_var = float(torch.exp(self.log_signal_var[a]))
        chol_m = torch.linalg.cholesky(self._kernel(z, z, a) + 1e-8 * signal_var * eye)
        v = torch.linalg.solve_triangular(chol_m, self._kernel(z, x_all, a), upper=False)  # (M, N)
        lam = torch.clamp(signal_var - torch.sum(v * v, dim=0), min=0.0) + noise_var  # (N,)
        v_scaled = v / torch.sqrt(lam)
        chol_b = torch.linalg.cholesky(eye + v_scaled @ v_scaled.T)
        # A^-1 = L^-T B^-1 L^-1, so K_mm^-1 - A^-1 = L^-T (I - B^-1) L^-1 and beta = L^-T B^-1 V Lambda^-1 y
        inv_b = torch.cholesky_inverse(chol_b)
        inv_chol_m = torch.linalg.solve_triangular(chol_m, eye, upper=False)
        inv_k = inv_chol_m.T @ (eye - inv_b) @ inv_chol_m
        inv_k = 0.5 * (inv_k + inv_k.T)
        beta = inv_chol_m.T @ (inv_b @ (v @ (y_all / lam)))
        return beta, inv_k

    def _kernel(self, x1: torch.Tensor, x2: torch.Tensor, a: int) -> torch.Tensor:
        ell = torch.exp(self.log_lengthscales[a])
        d = (x1.unsqueeze(1) - x2.unsqueeze(0)) / ell
        return torch.exp(self.log_signal_var[a] - 0.5 * torch.sum(d * d, dim=2))

    def moment_function(self) -> tuple[Callable[..., tuple[torch.Tensor, torch.Tensor, torch.Tensor]], tuple]:
        """Exact moment matching at a Gaussian input, with model uncertainty, as a pure function and its arguments
        after ``(mean, cov)`` (see :func:`~softpend.pilco.moments.gp_moments`)."""
        kernel = (self.log_lengthscales, self.log_signal_var, self.inv_kernel, self.pair_weights)
        return gp_moments, (self.inputs, self.beta, *kernel)
