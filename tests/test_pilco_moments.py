"""PILCO's moment matching against Monte Carlo sampling through the same functions."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from support import gp_predict

from softpend.pilco.gp import MultiOutputGP
from softpend.pilco.moments import (
    _WeightedExpSum,
    gp_moments,
    pair_weights,
    rbf_network_moments,
    saturating_cost_moments,
    sin_saturation_moments,
    trig_moments,
)
from softpend.pilco.policy import LinearPolicy, RBFPolicy
from softpend.pilco.propagation import Propagator, _cost, _step, silence_compiler_notes, state_spec

F64 = torch.float64
N_MC = 200_000


def _cost_of(prop: Propagator, m: torch.Tensor, s: torch.Tensor):
    """The propagator's expected saturating cost and its variance at ``x ~ N(m, s)``."""
    return _cost(prop._layout, prop._cost_terms, m, s)


def _rel(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


@pytest.fixture(scope="module")
def gp() -> MultiOutputGP:
    rng = np.random.default_rng(0)
    x = rng.uniform(-2, 2, (80, 3))
    y = np.stack([np.sin(x[:, 0]) * np.cos(x[:, 1]), 0.5 * x[:, 2] + np.sin(2 * x[:, 1])], 1)
    model = MultiOutputGP(x, y + 0.01 * rng.normal(size=y.shape))
    model.fit(60)
    return model


@pytest.fixture(scope="module")
def gaussian_input():
    rng = np.random.default_rng(1)
    a = 0.3 * rng.normal(size=(3, 3))
    m = torch.tensor([0.3, -0.2, 0.5], dtype=F64)
    s = torch.tensor(a @ a.T + 0.01 * np.eye(3), dtype=F64)
    xs = rng.multivariate_normal(m.numpy(), s.numpy(), N_MC)
    return m, s, xs


def test_gp_moments_with_model_uncertainty_match_monte_carlo(gp, gaussian_input):
    m, s, xs = gaussian_input
    function, parameters = gp.moment_function()
    mean, cov, c = function(m, s, *parameters)
    mu, var = gp_predict(gp, xs)
    f = mu + np.sqrt(var) * np.random.default_rng(2).normal(size=mu.shape)  # samples of the latent GP
    assert _rel(mean, f.mean(0)) < 0.03
    assert _rel(cov, np.cov(f.T)) < 0.03
    cross = np.cov(np.hstack([xs, f]).T)[:3, 3:]
    assert _rel(s @ c, cross) < 0.03
    # the model uncertainty is really in there: the mean-function-only variance is smaller
    _, cov_mean_only, _ = gp_moments(m, s, gp.inputs, gp.beta, gp.log_lengthscales, gp.log_signal_var)
    assert np.all(np.diag(cov_mean_only.numpy()) < np.diag(cov.numpy()))
    assert _rel(cov_mean_only, np.cov(mu.T)) < 0.03


def test_trig_moments_match_monte_carlo(gaussian_input):
    m, s, xs = gaussian_input
    mean, cov, c = trig_moments(m[:2], s[:2, :2])
    a = xs[:, :2]
    trig = np.stack([np.sin(a[:, 0]), np.cos(a[:, 0]), np.sin(a[:, 1]), np.cos(a[:, 1])], 1)
    assert np.max(np.abs(mean.numpy() - trig.mean(0))) < 0.005
    assert _rel(cov, np.cov(trig.T)) < 0.02
    assert _rel(s[:2, :2] @ c, np.cov(np.hstack([a, trig]).T)[:2, 2:]) < 0.02


@pytest.mark.parametrize("mean,var", [(0.4, 0.5), (-1.2, 0.05), (3.0, 2.0)])
def test_sin_saturation_moments_match_monte_carlo(mean, var):
    limit = 0.06
    m_u, s_u, c_u = sin_saturation_moments(torch.tensor(mean, dtype=F64), torch.tensor(var, dtype=F64), limit)
    x = np.random.default_rng(3).normal(mean, np.sqrt(var), N_MC)
    u = limit * (9 * np.sin(x) + np.sin(3 * x)) / 8
    assert abs(float(m_u) - u.mean()) < 0.01 * limit
    assert float(s_u) == pytest.approx(u.var(), rel=0.02)
    assert float(c_u) * var == pytest.approx(np.cov(x, u)[0, 1], rel=0.03, abs=1e-4 * limit)
    assert np.max(np.abs(u)) <= limit * (1 + 1e-12)


def test_saturating_cost_moments_match_monte_carlo():
    m = torch.tensor([0.05, 0.25], dtype=F64)
    s = torch.tensor([[0.004, 0.001], [0.001, 0.002]], dtype=F64)
    target = torch.tensor([0.0, 0.3], dtype=F64)
    e, v = saturating_cost_moments(m, s, target, 0.1)
    z = np.random.default_rng(4).multivariate_normal(m.numpy(), s.numpy(), N_MC)
    cost = 1 - np.exp(-0.5 * np.sum((z - target.numpy()) ** 2, 1) / 0.1**2)
    assert float(e) == pytest.approx(cost.mean(), rel=0.01)
    assert float(v) == pytest.approx(cost.var(), rel=0.03)


def test_one_step_propagation_close_to_monte_carlo():
    """State -> sin/cos -> policy -> GP -> next state, against sampling states through the same maps."""
    spec = state_spec("tip")
    rng = np.random.default_rng(5)
    states = np.column_stack([rng.uniform(-6, 6, 150), rng.uniform(-np.pi, np.pi, 150)])
    u = rng.uniform(-0.06, 0.06, 150)
    x = np.hstack([spec.model_inputs(states), u[:, None]])
    # a smooth pendulum-like map of state differences
    dy = np.column_stack([0.05 * (9.81 / 0.3 * np.sin(states[:, 1]) + 300 * u), 0.05 * states[:, 0]])
    gp = MultiOutputGP(x, dy + 1e-3 * rng.normal(size=dy.shape))
    gp.fit(60)
    policy = RBFPolicy(spec.model_inputs(states[:10]), np.array([3.0, 0.7, 0.7]), 0.06, seed=0)
    policy.targets = torch.tensor(rng.normal(size=10), dtype=F64)
    prop = Propagator(spec, gp, policy, 0.3, 0.1)
    m0 = torch.tensor([0.5, 2.5], dtype=F64)
    s0 = torch.diag(torch.tensor([0.05**2, 0.05**2], dtype=F64))
    m1, s1 = _step(prop._layout, policy.moment_function(), gp.moment_function(), m0, s0)
    xs = rng.multivariate_normal(m0.numpy(), s0.numpy(), 50_000)
    us = policy.torque_nm(spec.model_inputs(xs))
    mu, var = gp_predict(gp, np.hstack([spec.model_inputs(xs), us[:, None]]))
    nxt = xs + mu + np.sqrt(var) * rng.normal(size=mu.shape)
    assert np.max(np.abs(m1.numpy() - nxt.mean(0)) / np.sqrt(np.diag(np.cov(nxt.T)))) < 0.05
    assert np.diag(s1.numpy()) == pytest.approx(np.diag(np.cov(nxt.T)), rel=0.05)
    # expected cost of the predicted state against sampling it
    e, _ = _cost_of(prop, m1, s1)
    d2 = 2 * 0.3**2 * (1 - np.cos(nxt[:, 1]))
    assert float(e) == pytest.approx(np.mean(1 - np.exp(-0.5 * d2 / 0.1**2)), abs=0.01)


@pytest.mark.parametrize("exploration", [0.0, -0.3])
def test_rollout_gradient_matches_finite_differences(exploration):
    spec = state_spec("tip")
    rng = np.random.default_rng(6)
    states = np.column_stack([rng.uniform(-6, 6, 60), rng.uniform(-np.pi, np.pi, 60)])
    u = rng.uniform(-0.06, 0.06, 60)
    x = np.hstack([spec.model_inputs(states), u[:, None]])
    dy = np.column_stack([0.05 * (30 * np.sin(states[:, 1]) + 300 * u), 0.05 * states[:, 0]])
    gp = MultiOutputGP(x, dy)
    policy = RBFPolicy(spec.model_inputs(states[:5]), np.array([3.0, 0.7, 0.7]), 0.06, seed=1)
    prop = Propagator(spec, gp, policy, 0.3, 0.1, exploration=exploration)
    m0 = torch.tensor([0.0, np.pi], dtype=F64)
    s0 = 0.01 * torch.eye(2, dtype=F64)
    vector = policy.get_vector()
    leaf = torch.tensor(vector, requires_grad=True)
    policy.set_vector(leaf, requires_grad=True)
    total = prop.rollout(m0, s0, 5)[3]
    (grad,) = torch.autograd.grad(total, leaf)

    def value(v):
        policy.set_vector(v)
        return float(prop.rollout(m0, s0, 5)[3])

    eps = 1e-6
    for i in rng.choice(len(vector), 5, replace=False):
        step = np.zeros_like(vector)
        step[i] = eps
        fd = (value(vector + step) - value(vector - step)) / (2 * eps)
        assert float(grad[i]) == pytest.approx(fd, rel=1e-4, abs=1e-7)


@pytest.mark.parametrize("spec_name", ["tip", "tip_bend"])
def test_cost_with_a_tip_rate_width_against_monte_carlo(spec_name):
    """The expected cost with the tip-rate factor against sampling the (correlated) state; off, it is the position cost."""
    spec = state_spec(spec_name)
    rng = np.random.default_rng(8)
    d = spec.dim
    a = 0.15 * rng.normal(size=(d, d))
    s = torch.tensor(a @ a.T + 0.01 * np.eye(d), dtype=F64)
    m = torch.zeros(d, dtype=F64)
    m[spec.tip_angle_index] = 0.3
    m[spec.tip_rate_index] = -0.8
    prop = Propagator(spec, None, None, 0.3, 0.15, cost_rate_width_rad_s=1.5)
    e, _ = _cost_of(prop, m, s)
    xs = rng.multivariate_normal(m.numpy(), s.numpy(), N_MC)
    theta, rate = xs[:, spec.tip_angle_index], xs[:, spec.tip_rate_index]
    d2 = 2 * 0.3**2 * (1 - np.cos(theta))
    sampled = 1 - np.exp(-0.5 * d2 / 0.15**2 - 0.5 * (rate / 1.5) ** 2)
    assert float(e) == pytest.approx(sampled.mean(), abs=0.01)
    position_only = float(_cost_of(Propagator(spec, None, None, 0.3, 0.15), m, s)[0])
    assert position_only == pytest.approx(np.mean(1 - np.exp(-0.5 * d2 / 0.15**2)), abs=0.01)
    assert float(e) > position_only + 0.05  # the rate is really in there


def test_exploration_adds_the_weighted_cost_spread_which_is_larger_where_the_model_has_no_data():
    """The search objective with exploration weight b is sum E[c_t] + b sum sqrt(Var[c_t]); a policy that drives
    the rod out of the region the GP was trained on earns a larger bonus than one that leaves it hanging."""
    spec = state_spec("tip")
    rng = np.random.default_rng(11)
    states = np.column_stack([rng.uniform(-1, 1, 120), np.pi + rng.uniform(-0.3, 0.3, 120)])  # hanging only
    u = rng.uniform(-0.06, 0.06, 120)
    x = np.hstack([spec.model_inputs(states), u[:, None]])
    dy = np.column_stack([0.05 * (30 * np.sin(states[:, 1]) + 300 * u), 0.05 * states[:, 0]])
    gp = MultiOutputGP(x, dy + 1e-3 * rng.normal(size=dy.shape))
    gp.fit(60)
    m0 = torch.tensor([0.0, np.pi], dtype=F64)
    s0 = 0.01**2 * torch.eye(2, dtype=F64)
    bonus = {}
    for name, target in (("still", 0.0), ("push", 3.0)):
        policy = RBFPolicy(spec.model_inputs(states[:5]), np.array([3.0, 0.7, 0.7]), 0.06, seed=1)
        policy.targets = torch.full((5,), target, dtype=F64)
        _, _, costs, plain = Propagator(spec, gp, policy, 0.3, 0.3).rollout(m0, s0, 30)
        means, covs, costs_b, explored = Propagator(spec, gp, policy, 0.3, 0.3, exploration=-0.5).rollout(m0, s0, 30)
        assert float(plain) == pytest.approx(float(costs.sum()), rel=1e-12)
        assert torch.allclose(costs, costs_b)
        spread = sum(
            float(torch.sqrt(_cost_of(Propagator(spec, None, None, 0.3, 0.3), m, s)[1]))
            for m, s in zip(means[1:], covs[1:])
        )
        assert float(explored) == pytest.approx(float(costs.sum()) - 0.5 * spread, abs=1e-5)  # sqrt(var) >= 1e-6
        bonus[name] = float(plain - explored)
    assert bonus["push"] > 100 * bonus["still"]  # 0.26 against 0.0006


def test_rbf_network_moments_equal_the_one_output_gp_moments_with_their_gradients(gaussian_input):
    m, s, _ = gaussian_input
    rng = np.random.default_rng(5)
    centres = torch.tensor(rng.normal(size=(12, 3)), dtype=F64)
    beta = torch.tensor(rng.normal(size=12), dtype=F64, requires_grad=True)
    log_ell = torch.tensor(rng.normal(scale=0.3, size=3), dtype=F64, requires_grad=True)
    fast = rbf_network_moments(m, s, centres, beta, log_ell)
    general = gp_moments(m, s, centres, beta.unsqueeze(0), log_ell.unsqueeze(0), torch.zeros(1, dtype=F64))
    general = (general[0][0], general[1][0, 0], general[2][:, 0])
    for a, b in zip(fast, general):
        np.testing.assert_allclose(a.detach().numpy(), b.detach().numpy(), rtol=1e-10, atol=1e-14)
    grads = [torch.autograd.grad(sum(x.sum() for x in out), (beta, log_ell)) for out in (fast, general)]
    for a, b in zip(*grads):
        np.testing.assert_allclose(a.numpy(), b.numpy(), rtol=1e-9, atol=1e-13)


def test_one_angle_trig_moments_equal_the_blocks_of_two_independent_angles():
    m = torch.tensor([2.9, -0.4], dtype=F64)
    s = torch.diag(torch.tensor([0.3, 0.05], dtype=F64))
    mean2, cov2, c2 = trig_moments(m, s)  # the general formulas
    for k in range(2):
        mean1, cov1, c1 = trig_moments(m[k : k + 1], s[k : k + 1, k : k + 1])  # the one-angle formulas
        block = slice(2 * k, 2 * k + 2)
        np.testing.assert_allclose(mean1.numpy(), mean2[block].numpy(), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(cov1.numpy(), cov2[block, block].numpy(), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(c1.numpy(), c2[k : k + 1, block].numpy(), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(cov2[0:2, 2:4].numpy(), 0.0, atol=1e-15)  # independent angles


def test_weighted_exp_sum_gradient_matches_finite_differences_and_weights_hold_the_pairs():
    rng = np.random.default_rng(6)
    x = torch.tensor(rng.normal(scale=0.4, size=(3, 7, 4)), dtype=F64, requires_grad=True)
    y = torch.tensor(rng.normal(scale=0.4, size=(3, 5, 4)), dtype=F64, requires_grad=True)
    w = torch.tensor(rng.normal(size=(3, 7, 5)), dtype=F64)
    assert torch.autograd.gradcheck(lambda a, b: _WeightedExpSum.apply(a, b, w), (x, y))
    plain = torch.sum(torch.exp(x @ y.transpose(1, 2)) * w, dim=(1, 2))
    np.testing.assert_allclose(_WeightedExpSum.apply(x, y, w).detach().numpy(), plain.detach().numpy(), rtol=1e-13)
    beta = torch.tensor(rng.normal(size=(2, 4)), dtype=F64)
    inv_k = torch.tensor(rng.normal(size=(2, 4, 4)), dtype=F64)
    weights = pair_weights(beta, inv_k)  # pairs (0, 0), (0, 1), (1, 1)
    np.testing.assert_allclose(weights[1].numpy(), np.outer(beta[0], beta[1]))
    np.testing.assert_allclose(weights[2].numpy(), np.outer(beta[1], beta[1]) - inv_k[1].numpy())


def test_policy_reuses_its_beta_until_a_parameter_changes():
    rng = np.random.default_rng(7)
    policy = RBFPolicy(rng.normal(size=(6, 3)), np.ones(3), 0.06, seed=1)
    first = policy._beta()
    assert policy._beta() is first
    policy.targets[0] += 1.0  # in place
    changed = policy._beta()
    assert changed is not first
    np.testing.assert_allclose(changed.numpy(), policy._compute_beta().numpy())
    policy.set_vector(policy.get_vector() * 1.1)
    np.testing.assert_allclose(policy._beta().numpy(), policy._compute_beta().numpy())
    assert not np.allclose(policy._beta().numpy(), changed.numpy())


def test_the_compiled_rollout_equals_the_eager_one_and_goes_through_torchs_disk_caches():
    """``compiled=True`` gives the eager objective and gradient (to rounding) with the book's state, the tip-rate
    cost and exploration, also when a later search changes the cost width and a restart brings new parameters;
    without gradients it runs eagerly, and it refuses models it cannot compile.  Torch runs two threads here: the
    compiled loops must stay serial (with parallel ones the backward pass corrupted the heap).

    Compiling the step (for a GP size no other test uses, so it is compiled here) neither bypasses the FX graph
    cache nor the AOT autograd cache, and it is saved to or read from them (a later process then reads it instead
    of compiling it again): the step has no side effect (``torch.linalg.solve``'s singularity check had one) and
    its custom autograd function is admitted to the AOT autograd cache."""
    from torch._dynamo.utils import counters

    keys = (
        ("aot_autograd", "autograd_cache_bypass"),
        ("inductor", "fxgraph_cache_bypass"),
        ("aot_autograd", "autograd_cache_saved"),
        ("aot_autograd", "autograd_cache_hit"),
    )
    before = {key: counters[key[0]][key[1]] for key in keys}
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        _compare_compiled_and_eager_rollouts()
    finally:
        torch.set_num_threads(threads)
    grown = {key: counters[key[0]][key[1]] - before[key] for key in keys}
    assert grown[keys[0]] == 0 and grown[keys[1]] == 0, grown
    assert grown[keys[2]] + grown[keys[3]] >= 1, grown


def _compare_compiled_and_eager_rollouts() -> None:
    spec = state_spec("tip_bend")
    rng = np.random.default_rng(12)
    states = np.cumsum(rng.normal(0.0, 0.3, (41, 4)), axis=0) + np.array([0.0, 0.0, 0.0, np.pi])
    u = rng.uniform(-0.06, 0.06, 40)
    x = np.hstack([spec.model_inputs(states[:-1]), u[:, None]])
    gp = MultiOutputGP(x, states[1:] - states[:-1])
    gp.fit(10)
    m0 = torch.zeros(4, dtype=F64)
    m0[3] = np.pi
    s0 = 0.05**2 * torch.eye(4, dtype=F64)
    for width_m, seed in ((0.15, 0), (0.075, 1)):
        policy = RBFPolicy(
            spec.model_inputs(states[:8]), np.array([1.0, 1.0, 0.7, 0.7, 0.7]), 0.06, seed=seed, target_std=1.0
        )
        results = []
        for compiled in (False, True):
            prop = Propagator(
                spec, gp, policy, 0.3, width_m, cost_rate_width_rad_s=3.0, exploration=-0.2, compiled=compiled
            )
            leaf = torch.tensor(policy.get_vector(), requires_grad=True)
            policy.set_vector(leaf, requires_grad=True)
            means, covs, costs, total = prop.rollout(m0, s0, 12)
            (grad,) = torch.autograd.grad(total, leaf)
            results.append((float(total.detach()), grad, means.detach(), covs.detach()))
            policy.set_vector(leaf.detach())
        (eager, eager_grad, eager_means, eager_covs), (fast, fast_grad, fast_means, fast_covs) = results
        assert 5.0 < eager < 12.0 and float(eager_grad.abs().max()) > 1e-4  # a rollout with something to optimise
        assert fast == pytest.approx(eager, rel=1e-12)
        assert _rel(fast_grad, eager_grad) < 1e-9
        assert _rel(fast_means, eager_means) < 1e-12 and _rel(fast_covs, eager_covs) < 1e-10
    with torch.no_grad():  # no gradient: the eager rollout, the same numbers
        assert float(prop.rollout(m0, s0, 12)[3]) == pytest.approx(eager, rel=1e-12)


def test_without_a_working_compiler_the_rollout_warns_once_and_runs_eagerly(monkeypatch):
    """A machine without a C++ compiler: the compiled rollout falls back to the eager one (same numbers) with one
    warning; an error of the computation itself is not taken for a compiler failure."""
    from torch._inductor.exc import CppCompileError

    import softpend.pilco.propagation as propagation

    calls = []

    def broken_compile(function, **options):
        def run(*args):
            calls.append(1)
            raise CppCompileError(["g++"], "g++: not found")

        return run

    monkeypatch.setattr(propagation, "_COMPILED", [])
    monkeypatch.setattr(torch, "compile", broken_compile)
    spec = state_spec("tip")
    rng = np.random.default_rng(6)
    states = np.column_stack([rng.uniform(-6, 6, 30), rng.uniform(-np.pi, np.pi, 30)])
    u = rng.uniform(-0.06, 0.06, 30)
    gp = MultiOutputGP(np.hstack([spec.model_inputs(states), u[:, None]]), np.column_stack([0.05 * states[:, 0], u]))
    policy = RBFPolicy(spec.model_inputs(states[:5]), np.array([3.0, 0.7, 0.7]), 0.06, seed=1)
    m0, s0 = torch.tensor([0.0, np.pi], dtype=F64), 0.01 * torch.eye(2, dtype=F64)
    eager = float(Propagator(spec, gp, policy, 0.3, 0.1).rollout(m0, s0, 4)[3])
    prop = Propagator(spec, gp, policy, 0.3, 0.1, compiled=True)
    with pytest.warns(RuntimeWarning, match="torch.compile is unavailable"):
        assert float(prop.rollout(m0, s0, 4)[3].detach()) == eager
    assert float(prop.rollout(m0, s0, 4)[3].detach()) == eager and len(calls) == 1  # no second attempt

    def failing(*args):
        raise torch.linalg.LinAlgError("singular")

    monkeypatch.setattr(propagation, "_COMPILED", [])
    monkeypatch.setattr(torch, "compile", lambda function, **options: failing)
    with pytest.raises(torch.linalg.LinAlgError):
        prop.rollout(m0, s0, 4)


def test_the_compilers_notes_are_silenced_and_other_warnings_are_not():
    """What torch's compiler prints while it compiles the rollout (a deprecation notice of its own lowering code,
    its note on a cached helper) is hidden; the same text from another module, a FutureWarning of any other
    module, or another torch warning, is not."""
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        silence_compiler_notes()
        warnings.warn_explicit(
            "`torch._prims_common.check` is deprecated",
            FutureWarning,
            "lowering.py",
            1,
            module="torch._inductor.lowering",
        )
        warnings.warn_explicit(
            "Dynamo detected a call to a `functools.lru_cache`-wrapped function",
            UserWarning,
            "functions.py",
            1,
            module="torch._dynamo.variables.functions",
        )
        warnings.warn_explicit("a later default", FutureWarning, "model.py", 1, module="softpend.pilco.loop")
        warnings.warn_explicit("a torch note", UserWarning, "lowering.py", 1, module="torch._inductor.lowering")
        warnings.warn_explicit(
            "`torch._prims_common.check` is deprecated", FutureWarning, "ours.py", 1, module="softpend.ours"
        )
    assert [str(w.message) for w in seen] == [
        "a later default",
        "a torch note",
        "`torch._prims_common.check` is deprecated",
    ]


def test_linear_policy_moments_match_monte_carlo(gaussian_input):
    m, s, xs = gaussian_input
    policy = LinearPolicy(3, 0.06, weights=np.array([1.5, -0.8, 2.0]))
    function, params = policy.moment_function()
    m_u, s_u, c_u = function(m, s, *params)
    u = policy.torque_nm(xs)
    assert abs(float(m_u) - u.mean()) < 0.01 * 0.06
    assert float(s_u) == pytest.approx(u.var(), rel=0.02)
    np.testing.assert_allclose((s @ c_u).numpy(), np.cov(np.hstack([xs, u[:, None]]).T)[:3, 3], rtol=0.03, atol=1e-5)
