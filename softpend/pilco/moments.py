"""Exact moment matching of Gaussian inputs through the pieces of PILCO (Deisenroth & Rasmussen, 2011)."""

from __future__ import annotations

import functools

import torch


def _solve(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``torch.linalg.solve(a, b)`` without its singularity check (which keeps a compiled graph out of the caches)."""
    return torch.linalg.solve_ex(a, b)[0]


def _inv(a: torch.Tensor) -> torch.Tensor:
    """``torch.linalg.inv(a)`` without its singularity check (see :func:`_solve`)."""
    return torch.linalg.inv_ex(a)[0]


@functools.lru_cache(maxsize=None)
def _pair_tables(n_outputs: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The output pairs ``i <= j`` (rows, cols, in :func:`torch.triu_indices` order), the positions of the pairs
    ``i = j`` among them, and the (E, E) table of the pair index of every ``(i, j)``."""
    rows, cols = torch.triu_indices(n_outputs, n_outputs, device=device)
    diag = torch.nonzero(rows == cols).squeeze(1)
    table = torch.empty(n_outputs, n_outputs, dtype=torch.long, device=device)
    table[rows, cols] = torch.arange(len(rows), device=device)
    table[cols, rows] = torch.arange(len(rows), device=device)
    return rows, cols, diag, table


def pair_weights(beta: torch.Tensor, inv_kernel: torch.Tensor | None = None) -> torch.Tensor:
    """The weights ``W_ij = beta_i beta_j'`` (minus ``(K_i + sn2 I)^{-1}`` when ``i = j`` and ``inv_kernel`` is
    given) of the second moments ``sum(W_ij * L_ij)`` in :func:`gp_moments`, for the output pairs ``i <= j``
    in :func:`torch.triu_indices` order: (P, N, N), ``P = E (E + 1) / 2``."""
    rows, cols, diag, _ = _pair_tables(beta.shape[0], beta.device)
    weights = beta[rows].unsqueeze(2) * beta[cols].unsqueeze(1)
    if inv_kernel is not None:
        weights = weights.index_add(0, diag, -inv_kernel)
    return weights


class _WeightedExpSum(torch.autograd.Function):
    """``sum_{n,m} W[p, n, m] exp(X[p, n] . Y[p, m])`` per ``p``, with its gradient in ``X`` and ``Y`` written out."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, y: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        terms = torch.bmm(x, y.transpose(1, 2))
        terms.exp_()
        terms.mul_(weights)
        ctx.save_for_backward(x, y, terms)
        return terms.sum(dim=(1, 2))

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        x, y, terms = ctx.saved_tensors
        scale = grad.reshape(-1, 1, 1)
        grad_x = torch.bmm(terms, y) * scale if ctx.needs_input_grad[0] else None
        grad_y = torch.bmm(terms.transpose(1, 2), x) * scale if ctx.needs_input_grad[1] else None
        return grad_x, grad_y, None


def _weighted_exp_sum(x: torch.Tensor, y: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    if weights.requires_grad:  # weights that depend on parameters: plain autograd
        return torch.sum(torch.exp(x @ y.transpose(1, 2)) * weights, dim=(1, 2))
    return _WeightedExpSum.apply(x, y, weights)


def gp_moments(
    mean: torch.Tensor,
    cov: torch.Tensor,
    inputs: torch.Tensor,
    beta: torch.Tensor,
    log_lengthscales: torch.Tensor,
    log_signal_var: torch.Tensor,
    inv_kernel: torch.Tensor | None = None,
    weights: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Moments of GP predictions at a Gaussian input (squared-exponential ARD kernel, zero prior mean)."""
    dim = log_lengthscales.shape[1]
    eye = torch.eye(dim, dtype=mean.dtype, device=mean.device)
    inp = inputs - mean  # (N, D)
    inv_ell = torch.exp(-log_lengthscales)  # (E, D)
    scaled = inp.unsqueeze(0) * inv_ell.unsqueeze(1)  # (E, N, D)
    b_mat = inv_ell.unsqueeze(2) * cov.unsqueeze(0) * inv_ell.unsqueeze(1) + eye  # (E, D, D)
    t = _solve(b_mat, scaled.transpose(1, 2)).transpose(1, 2)  # (E, N, D) = scaled @ B^-1
    lb = torch.exp(-0.5 * torch.sum(scaled * t, dim=2)) * beta  # (E, N)
    signal_var = torch.exp(log_signal_var)
    c = signal_var / torch.sqrt(torch.linalg.det(b_mat))  # (E,)
    mean_out = torch.sum(lb, dim=1) * c
    io_cov = torch.einsum("end,en->de", t * inv_ell.unsqueeze(1), lb) * c  # (D, E)
    # the (E, E) second moments E[f_i f_j], computed once per output pair i <= j
    log_k = log_signal_var.unsqueeze(1) - 0.5 * torch.sum(scaled * scaled, dim=2)  # (E, N)
    rows, cols, diag, table = _pair_tables(log_lengthscales.shape[0], inp.device)
    inv_ell2 = torch.exp(-2.0 * log_lengthscales)  # (E, D)
    r_mat = cov.unsqueeze(0) * (inv_ell2[rows] + inv_ell2[cols]).unsqueeze(1) + eye  # (P, D, D)
    t_pair = 1.0 / torch.sqrt(torch.linalg.det(r_mat))  # (P,)
    q_mat = 0.5 * _solve(r_mat, cov.expand_as(r_mat))  # (P, D, D), symmetric
    ii = inp.unsqueeze(0) * inv_ell2[rows].unsqueeze(1)  # (P, N, D)
    ij = inp.unsqueeze(0) * inv_ell2[cols].unsqueeze(1)
    ii_q, ij_q = ii @ q_mat, ij @ q_mat
    half_i = (log_k[rows] + torch.sum(ii_q * ii, dim=2)).unsqueeze(2)  # (P, N, 1)
    half_j = (log_k[cols] + torch.sum(ij_q * ij, dim=2)).unsqueeze(2)
    # L_ij[n, m] = exp(half_i[n] + half_j[m] + 2 ii_q[n] . ij[m]) = exp(X[n] . Y[m]) with the two halves as extra
    # columns; second_ij = sum(W_ij * L_ij) with W_ij = beta_i beta_j' (- K_i^{-1} on the diagonal pairs)
    ones = torch.ones_like(half_i)
    x_aug = torch.cat([2.0 * ii_q, half_i, ones], dim=2)  # (P, N, D + 2)
    y_aug = torch.cat([ij, ones, half_j], dim=2)
    weights = pair_weights(beta, inv_kernel) if weights is None else weights
    second = _weighted_exp_sum(x_aug, y_aug, weights) * t_pair
    if inv_kernel is not None:
        # model uncertainty on the diagonal pairs: sf2_i - tr(K_i^{-1} L_ii) (the trace is in the weights)
        second = second.index_add(0, diag, signal_var)
    second = second[table]  # symmetric: both halves read the same pair
    return mean_out, second - torch.outer(mean_out, mean_out), io_cov


def rbf_network_moments(
    mean: torch.Tensor, cov: torch.Tensor, centers: torch.Tensor, beta: torch.Tensor, log_lengthscales: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Moments of one RBF network ``f(x) = sum_n beta_n exp(-|x - c_n|^2_Lambda / 2)`` at a Gaussian input."""
    dim = mean.shape[0]
    eye = torch.eye(dim, dtype=mean.dtype, device=mean.device)
    inp = centers - mean  # (N, D)
    inv_ell = torch.exp(-log_lengthscales)  # (D,)
    scaled = inp * inv_ell
    b_mat = inv_ell.unsqueeze(1) * cov * inv_ell.unsqueeze(0) + eye
    t = _solve(b_mat, scaled.T).T  # scaled @ B^-1
    lb = torch.exp(-0.5 * torch.sum(scaled * t, dim=1)) * beta
    c = 1.0 / torch.sqrt(torch.linalg.det(b_mat))
    mean_out = torch.sum(lb) * c
    io_cov = ((t * inv_ell).T @ lb) * c  # (D,)
    inv_ell2 = torch.exp(-2.0 * log_lengthscales)
    r_mat = cov * (2.0 * inv_ell2) + eye
    q_mat = 0.5 * _solve(r_mat, cov)
    ii = inp * inv_ell2
    ii_q = ii @ q_mat
    half = -0.5 * torch.sum(scaled * scaled, dim=1) + torch.sum(ii_q * ii, dim=1)  # (N,)
    big_l = torch.exp(half.unsqueeze(1) + half.unsqueeze(0) + 2.0 * ii_q @ ii.T)
    second = (beta @ big_l @ beta) / torch.sqrt(torch.linalg.det(r_mat))
    return mean_out, second - mean_out * mean_out, io_cov


def trig_moments(mean: torch.Tensor, cov: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Moments of ``(sin a_1, cos a_1, sin a_2, cos a_2, ...)`` for Gaussian angles ``a ~ N(mean, cov)``."""
    n = mean.shape[0]
    var = torch.diagonal(cov)
    decay = torch.exp(-0.5 * var)
    e_sin = decay * torch.sin(mean)
    e_cos = decay * torch.cos(mean)
    if n == 1:  # one angle (the propagation's case, twice per step): the formulas below with fewer operations
        plus = 1.0 - decay * decay
        minus = (decay * decay - 1.0) * decay * decay
        sin2, cos2 = torch.sin(2.0 * mean), torch.cos(2.0 * mean)
        ss, cc, sc = 0.5 * (plus - minus * cos2), 0.5 * (plus + minus * cos2), 0.5 * minus * sin2
        s_out = torch.stack([torch.cat([ss, sc]), torch.cat([sc, cc])])
        return torch.cat([e_sin, e_cos]), s_out, torch.stack([e_cos, -e_sin], dim=1)
    lq = -0.5 * (var.unsqueeze(1) + var.unsqueeze(0))
    q = torch.exp(lq)
    plus = torch.exp(lq + cov) - q
    minus = torch.exp(lq - cov) - q
    diff = mean.unsqueeze(1) - mean.unsqueeze(0)
    summ = mean.unsqueeze(1) + mean.unsqueeze(0)
    u1 = plus * torch.sin(diff)
    u2 = minus * torch.sin(summ)
    u3 = plus * torch.cos(diff)
    u4 = minus * torch.cos(summ)
    ss = 0.5 * (u3 - u4)
    cc = 0.5 * (u3 + u4)
    sc = 0.5 * (u1 + u2)  # cov(sin a_i, cos a_j)
    s_out = torch.stack([torch.stack([ss, sc], dim=2), torch.stack([sc.T, cc], dim=2)], dim=1)  # (A, 2, A, 2)
    s_out = s_out.reshape(2 * n, 2 * n)
    m_out = torch.stack([e_sin, e_cos], dim=1).reshape(2 * n)
    eye = torch.eye(n, dtype=mean.dtype, device=mean.device)
    c_out = torch.stack([eye * e_cos, -eye * e_sin], dim=2).reshape(n, 2 * n)
    return m_out, s_out, c_out


def sin_saturation_moments(
    mean: torch.Tensor, var: torch.Tensor, limit: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Moments of the smooth saturation ``u = limit (9 sin x + sin 3x) / 8`` of a scalar ``x ~ N(mean, var)``."""
    e = lambda k: torch.exp(-0.5 * k * k * var)  # noqa: E731  (E[cos kx] = e(k) cos(k m))
    a = limit / 8.0
    m_u = a * (9.0 * e(1.0) * torch.sin(mean) + e(3.0) * torch.sin(3.0 * mean))
    cos2 = e(2.0) * torch.cos(2.0 * mean)
    cos4 = e(4.0) * torch.cos(4.0 * mean)
    cos6 = e(6.0) * torch.cos(6.0 * mean)
    second = a * a * (40.5 * (1.0 - cos2) + 9.0 * (cos2 - cos4) + 0.5 * (1.0 - cos6))
    s_u = torch.clamp(second - m_u * m_u, min=0.0)
    c_u = a * (9.0 * e(1.0) * torch.cos(mean) + 3.0 * e(3.0) * torch.cos(3.0 * mean))
    return m_u, s_u, c_u


def saturating_cost_moments(
    mean: torch.Tensor, cov: torch.Tensor, target: torch.Tensor, width: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and variance of the saturating cost ``1 - exp(-|z - target|^2 / (2 width^2))``, ``z ~ N(mean, cov)``."""
    k = mean.shape[0]
    eye = torch.eye(k, dtype=mean.dtype, device=mean.device)
    w = eye / width**2
    delta = mean - target
    sw = cov @ w + eye
    s1 = w @ _inv(sw)
    e_exp = torch.exp(-0.5 * delta @ s1 @ delta) / torch.sqrt(torch.linalg.det(sw))
    s2w = 2.0 * cov @ w + eye
    s2 = w @ _inv(s2w)
    e2 = torch.exp(-delta @ s2 @ delta) / torch.sqrt(torch.linalg.det(s2w))
    return 1.0 - e_exp, torch.clamp(e2 - e_exp * e_exp, min=0.0)
