"""PILCO's controller: a radial-basis-function network squashed by a sine saturation."""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from softpend.pilco.moments import rbf_network_moments, sin_saturation_moments

DTYPE = torch.float64


def saturated_rbf_moments(
    mean: torch.Tensor,
    cov: torch.Tensor,
    centers: torch.Tensor,
    beta: torch.Tensor,
    log_lengthscales: torch.Tensor,
    torque_limit_nm: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Mean, variance and ``cov^{-1} cov(x, u)`` (D,) of the torque ``u`` [N m] of an RBF network with weights
    ``beta`` squashed by the sine saturation at ``torque_limit_nm``, at a Gaussian input ``x ~ N(mean, cov)``."""
    m_z, s_z, c_z = rbf_network_moments(mean, cov, centers, beta, log_lengthscales)
    m_u, s_u, c_u = sin_saturation_moments(m_z, s_z, torque_limit_nm)
    return m_u, s_u, c_z * c_u


def sin_saturation(z: torch.Tensor, torque_limit_nm: float) -> torch.Tensor:
    """The torque ``u_max (9 sin z + sin 3z) / 8`` [N m] of pre-saturation outputs ``z`` (PILCO's ``gSat``)."""
    return torque_limit_nm * (9.0 * torch.sin(z) + torch.sin(3.0 * z)) / 8.0


def saturated_linear_moments(
    mean: torch.Tensor, cov: torch.Tensor, weights: torch.Tensor, torque_limit_nm: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Mean, variance and ``cov^{-1} cov(x, u)`` (D,) of the torque ``u`` [N m] of the linear map ``weights . x``
    squashed by the sine saturation at ``torque_limit_nm``, at a Gaussian input ``x ~ N(mean, cov)``."""
    m_u, s_u, c_u = sin_saturation_moments(weights @ mean, weights @ cov @ weights, torque_limit_nm)
    return m_u, s_u, weights * c_u


class _Policy:
    """What both policies share: parameters as named tensors (:data:`_PARAMS`), as one vector and as a state dict,
    and the saturated torque of :meth:`pre_saturation`."""

    _PARAMS: tuple[str, ...] = ()
    torque_limit_nm: float

    def parameters(self) -> list[torch.Tensor]:
        return [getattr(self, name) for name in self._PARAMS]

    def get_vector(self) -> np.ndarray:
        """All parameters flattened, in :data:`_PARAMS` order."""
        return torch.cat([p.reshape(-1) for p in self.parameters()]).detach().numpy().copy()

    def set_vector(self, vector: np.ndarray | torch.Tensor, requires_grad: bool = False) -> None:
        """Inverse of :meth:`get_vector`; with ``requires_grad`` the parameters become views of the tensor given."""
        v, start = torch.as_tensor(vector, dtype=DTYPE), 0
        for name, p in zip(self._PARAMS, self.parameters()):
            part = v[start : start + p.numel()].reshape(p.shape)
            setattr(self, name, part if requires_grad else part.detach().clone())
            start += p.numel()

    def pre_saturation(self, x: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def torque_nm(self, x: np.ndarray) -> np.ndarray:
        """Saturated torque [N m] at deterministic inputs ``x`` (M, D) or (D,)."""
        xt = torch.as_tensor(np.atleast_2d(np.asarray(x, dtype=float)), dtype=DTYPE)
        with torch.no_grad():
            torque = sin_saturation(self.pre_saturation(xt), self.torque_limit_nm).numpy()
        return torque if np.ndim(x) == 2 else torque[:1].reshape(())

    def moment_function(self) -> tuple[Callable[..., tuple[torch.Tensor, torch.Tensor, torch.Tensor]], tuple]:
        """Mean, variance and ``cov^{-1} cov(x, u)`` (D,) of the saturated torque at a Gaussian input: a pure function
        and its arguments after ``(mean, cov)``."""
        raise NotImplementedError

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {name: p.detach().clone() for name, p in zip(self._PARAMS, self.parameters())}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        wrong = sorted(set(self._PARAMS) ^ set(state))
        if wrong:
            raise ValueError(f"policy state dict must hold {list(self._PARAMS)}, got {sorted(state)} ({wrong} differ)")
        for name, p in zip(self._PARAMS, self.parameters()):
            value = state[name].to(DTYPE)
            if value.shape != p.shape:
                raise ValueError(f"policy {name} must have shape {tuple(p.shape)}, got {tuple(value.shape)}")
            setattr(self, name, value.clone())


class LinearPolicy(_Policy):
    """Saturated linear policy ``u = u_max (9 sin z + sin 3z) / 8`` with ``z = w . x`` on ``D`` inputs (PILCO's
    ``conlin`` with ``gSat``)."""

    _PARAMS = ("weights",)

    def __init__(self, n_inputs: int, torque_limit_nm: float, weights: np.ndarray | None = None) -> None:
        self.torque_limit_nm = float(torque_limit_nm)
        self.weights = torch.tensor(np.zeros(n_inputs) if weights is None else np.asarray(weights, float), dtype=DTYPE)

    def pre_saturation(self, x: torch.Tensor) -> torch.Tensor:
        return x @ self.weights

    def moment_function(self) -> tuple[Callable[..., tuple[torch.Tensor, torch.Tensor, torch.Tensor]], tuple]:
        """:meth:`moments` as a pure function and its arguments after ``(mean, cov)``."""
        return saturated_linear_moments, (self.weights, self.torque_limit_nm)


class RBFPolicy(_Policy):
    """Saturated RBF-network policy on ``D`` inputs with one scalar output (the base torque)."""

    _PARAMS = ("centers", "targets", "log_lengthscales")

    def __init__(
        self,
        centers: np.ndarray,
        lengthscales: np.ndarray,
        torque_limit_nm: float,
        seed: int = 0,
        target_std: float = 0.1,
    ) -> None:
        self.torque_limit_nm, self.noise_var = float(torque_limit_nm), 0.01**2  # the pseudo-targets' noise std 0.01
        generator = torch.Generator().manual_seed(int(seed))
        self.centers = torch.tensor(np.asarray(centers, dtype=float), dtype=DTYPE)
        self.targets = float(target_std) * torch.randn(len(self.centers), generator=generator, dtype=DTYPE)
        self.log_lengthscales = torch.log(torch.tensor(np.asarray(lengthscales, dtype=float), dtype=DTYPE))
        self._beta_cache: tuple | None = None

    def _beta(self) -> torch.Tensor:
        """``(K_cc + sn^2 I)^{-1} t``, computed once per set of parameters (and grad mode)."""
        params = self.parameters()
        key, cache = (torch.is_grad_enabled(), tuple(p._version for p in params)), self._beta_cache
        if cache is not None and cache[0] == key and all(a is b for a, b in zip(cache[1], params)):
            return cache[2]
        beta = self._compute_beta()
        self._beta_cache = (key, tuple(params), beta)
        return beta

    def _compute_beta(self) -> torch.Tensor:
        d = (self.centers.unsqueeze(1) - self.centers.unsqueeze(0)) / torch.exp(self.log_lengthscales)
        k = torch.exp(-0.5 * torch.sum(d * d, dim=2)) + self.noise_var * torch.eye(len(self.centers), dtype=DTYPE)
        return torch.linalg.solve(k, self.targets)

    def pre_saturation(self, x: torch.Tensor) -> torch.Tensor:
        """``pi~(x)`` for inputs ``x`` (M, D)."""
        d = (x.unsqueeze(1) - self.centers.unsqueeze(0)) / torch.exp(self.log_lengthscales)
        return torch.exp(-0.5 * torch.sum(d * d, dim=2)) @ self._beta()

    def moment_function(self) -> tuple[Callable[..., tuple[torch.Tensor, torch.Tensor, torch.Tensor]], tuple]:
        """:meth:`moments` as a pure function and its arguments after ``(mean, cov)`` (for a compiled propagation,
        whose graph then holds no reference to this object)."""
        return saturated_rbf_moments, (self.centers, self._beta(), self.log_lengthscales, self.torque_limit_nm)
