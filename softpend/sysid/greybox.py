"""Grey-box identification: the PRB rod's physical parameters (and rig calibrations) from a babbling dataset.

Multiple shooting over short windows on the Exudyn plant: each window's initial joint state is a free variable,
the parameters are shared, and Levenberg-Marquardt eliminates the window states (Schur complement) at every step.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from softpend.checks import int_at_least, positive, positive_int
from softpend.plant import PRBPlant, RodParams, SimulationDiverged
from softpend.plant.base import PlantBase
from softpend.sysid.dataset import TrajectoryDataset

#: Rod parameters estimated by default.
GREYBOX_PARAMETERS: tuple[str, ...] = tuple(
    "hub_inertia_kgm2 hub_friction_nms_per_rad youngs_modulus_pa joint_damping_nms_per_rad tip_mass_kg".split()
)
#: Rod fields that may be estimated (``youngs_modulus_pa`` and ``stiffness_scale`` act alike: pick one).
ESTIMABLE_ROD_FIELDS: tuple[str, ...] = GREYBOX_PARAMETERS + ("stiffness_scale", "mass_kg")
#: Rig calibrations that may be estimated besides the rod fields, and their values when not estimated.
_CALIBRATIONS = {"torque_gain": 1.0, "encoder_offset_rad": 0.0, "torque_delay_s": 0.0, "camera_delay_s": 0.0}
CALIBRATION_PARAMETERS: tuple[str, ...] = tuple(_CALIBRATIONS)
#: Calibrations that are delays within one sample either way (decision variable: the fraction of ``dt``).
_DELAYS = ("torque_delay_s", "camera_delay_s")
#: Scale of the encoder-offset decision variable [rad].
_OFFSET_SCALE_RAD = 0.01
#: Bounds of the log-scaled parameters (a factor e^5 either side of the initial guess).
_LOG_BOUND = 5.0
#: Numerical rank tolerance of the normalised parameter information matrix.
IDENTIFIABILITY_TOLERANCE = 1e-9
IDENTIFICATION_SCHEMA = "softpend.sysid.greybox"
#: Length of the warm-up windows [s], relative forward-difference step and convergence tolerance of the fit.
WARMUP_WINDOW_S = 0.1
DIFF_STEP = 1e-6
TOLERANCE = 1e-6


class NotIdentifiable(ValueError):
    """The dataset does not determine ``parameter`` (the message says why)."""

    def __init__(self, parameter: str, message: str) -> None:
        super().__init__(message)
        self.parameter = parameter


@dataclass(frozen=True)
class GreyBoxConfig:
    """Settings of :func:`identify`: what to estimate (:data:`ESTIMABLE_ROD_FIELDS`, :data:`CALIBRATION_PARAMETERS`),
    the window length and count, the seed of the window draw and the iteration limit (of each stage).  Windows
    longer than :data:`WARMUP_WINDOW_S` are first fitted cut to that length (nearly linear in the parameters and
    states, so a poor guess converges), then whole."""

    parameters: tuple[str, ...] = GREYBOX_PARAMETERS
    window_s: float = 0.3
    max_windows: int = 120
    seed: int = 0
    max_iterations: int = 25

    def __post_init__(self) -> None:
        names, allowed = tuple(self.parameters), ESTIMABLE_ROD_FIELDS + CALIBRATION_PARAMETERS
        if not names or len(set(names)) < len(names) or not set(names) <= set(allowed):
            raise ValueError(f"parameters must be one or more distinct names from {allowed}, got {names}")
        if {"youngs_modulus_pa", "stiffness_scale"} <= set(names):
            raise ValueError("parameters: youngs_modulus_pa and stiffness_scale both scale E I; estimate one")
        object.__setattr__(self, "parameters", names)
        positive("window_s", self.window_s)
        object.__setattr__(self, "seed", int_at_least("seed", self.seed, 0))
        for name in ("max_windows", "max_iterations"):
            object.__setattr__(self, name, positive_int(name, getattr(self, name)))


#: The fit's figures that :meth:`GreyBoxResult.to_dict` writes under ``fit``.
_FIT_FIELDS = (
    "residual_rms_rad",
    "n_windows",
    "window_steps",
    "n_residuals",
    "n_variables",
    "identify_s",
    "nfev",
    "njev",
    "status",
    "message",
)


@dataclass
class GreyBoxResult:
    """What :func:`identify` found: the rod with the estimated fields replaced, every estimate and its standard
    deviation in its own unit, how the fit went, and the estimates that ended on a bound of the search (not
    determined by the data); the calibrations are properties (1, 0, 0, 0 when not estimated)."""

    params: RodParams
    initial_params: RodParams
    estimates: dict[str, float]
    std: dict[str, float]
    residual_rms_rad: float
    n_windows: int
    window_steps: int
    n_residuals: int
    n_variables: int
    identify_s: float
    nfev: int
    njev: int
    status: int
    message: str
    at_bounds: tuple[str, ...] = ()

    def _calibration(self, name: str) -> float:
        return self.estimates.get(name, _CALIBRATIONS[name])

    @property
    def torque_gain(self) -> float:
        return self._calibration("torque_gain")

    @property
    def encoder_offset_rad(self) -> float:
        return self._calibration("encoder_offset_rad")

    @property
    def torque_delay_s(self) -> float:
        return self._calibration("torque_delay_s")

    @property
    def camera_delay_s(self) -> float:
        return self._calibration("camera_delay_s")

    def relative_errors(self, truth: RodParams) -> dict[str, float]:
        """``|estimate / truth - 1|`` of every estimated rod field and of the torque gain (against 1)."""
        rated = [n for n in self.estimates if n in ESTIMABLE_ROD_FIELDS + ("torque_gain",)]  # the rest: truth zero
        truths = {n: 1.0 if n == "torque_gain" else getattr(truth, n) for n in rated}
        return {n: abs(self.estimates[n] / t - 1.0) if t != 0 else abs(self.estimates[n]) for n, t in truths.items()}

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict; its ``rod_params`` is what :meth:`RodParams.from_json` reads."""
        method = "multiple shooting, Levenberg-Marquardt with the window states eliminated (Schur complement)"
        fit = {"method": method} | {name: getattr(self, name) for name in _FIT_FIELDS}
        fit |= {"at_bounds": list(self.at_bounds), "initial_params": self.initial_params.to_dict()}
        out = {"schema": IDENTIFICATION_SCHEMA, "rod_params": self.params.to_dict(), "estimates": dict(self.estimates)}
        calibration = {name: getattr(self, name) for name in CALIBRATION_PARAMETERS}
        return out | {"std": dict(self.std), "calibration": calibration, "fit": fit}


def _observed(dataset: TrajectoryDataset) -> tuple[list[str], np.ndarray]:
    """The residual variables (``phi, ex, ey`` and ``er`` if recorded) and their columns ``(T, N, k)``."""
    names = ["phi_rad", "ex_m", "ey_m"] + (["er_rad"] if "er_rad" in dataset.position_names else [])
    return names, np.stack([dataset.column(n) for n in names], axis=-1)


def reconstruct_joint_states(
    phi_rad: np.ndarray,
    ex_m: np.ndarray,
    ey_m: np.ndarray,
    er_rad: Optional[np.ndarray],
    params: RodParams,
    iterations: int = 20,
    initial_springs_rad: Optional[np.ndarray] = None,
) -> np.ndarray:
    """Joint angles ``(..., n + 1)`` of a PRB rod that put its tip at the observed position (and tip angle ``er``
    when given), the spring angles as small as possible (a ridge on them); vectorised Gauss-Newton from the straight
    rod (or from ``initial_springs_rad (..., n)``)."""
    ridge = 1e-4
    phi, has_er = np.asarray(phi_rad, float), er_rad is not None
    n, length, scale = params.n_links, params.link_length_m, params.length_m
    b = np.zeros(phi.shape + (n,)) if initial_springs_rad is None else np.array(initial_springs_rad, float)
    observed = [np.asarray(ex_m, float) / scale, np.asarray(ey_m, float) / scale]
    target = np.stack(observed + [np.asarray(er_rad, float)] * has_er, axis=-1)
    for _ in range(iterations):
        a = phi[..., None] + np.cumsum(b, axis=-1)
        sin, cos = np.sin(a), np.cos(a)
        r = np.stack([-length * sin.sum(-1) / scale, length * cos.sum(-1) / scale] + [a[..., -1]] * has_er, -1) - target
        if has_er:
            r[..., 2] = wrap_diff(a[..., -1], target[..., 2])
        tail_cos, tail_sin = (np.cumsum(x[..., ::-1], axis=-1)[..., ::-1] for x in (cos, sin))
        jac = np.stack([-length * tail_cos / scale, -length * tail_sin / scale] + [np.ones_like(b)] * has_er, axis=-2)
        jtj = np.einsum("...ki,...kj->...ij", jac, jac) + ridge * np.eye(n)
        rhs = np.einsum("...ki,...k->...i", jac, r) + ridge * b
        b = b - np.linalg.solve(jtj, rhs[..., None])[..., 0]
    return np.concatenate([phi[..., None], b], axis=-1)


def wrap_diff(a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
    """``a - b`` wrapped to ``[-pi, pi)`` [rad]."""
    return (np.asarray(a) - b + np.pi) % (2 * np.pi) - np.pi


def dataset_substeps(dataset: TrajectoryDataset) -> int:
    """The dataset's protocol's solver sub-steps, else 2."""
    return int(dataset.metadata.get("protocol", {}).get("substeps", 2))


def free_plant(params: RodParams, dataset: TrajectoryDataset) -> PRBPlant:
    """A PRB plant at the dataset's step and sub-steps whose torque is not clipped (the recorded one already was)."""
    return PRBPlant(params.replace(torque_limit_nm=1e6), dt_s=dataset.dt_s, substeps=dataset_substeps(dataset))


def simulate_windows(
    plant: PlantBase, states: np.ndarray, torques_nm: np.ndarray, has_er: bool = True, diverged_nan: bool = False
) -> np.ndarray:
    """Open-loop simulations from joint states ``(B, 2 (n + 1))`` under torques ``(B, W)``: ``phi, ex, ey`` (and
    ``er``) at every sample, ``(B, W + 1, 3 or 4)``.  A diverging simulation keeps its last state to the end of its
    window (``diverged_nan``: the whole window is NaN)."""
    n_q = plant.n_coordinates
    torques = np.asarray(torques_nm, float)
    out = np.full((len(states), torques.shape[1] + 1, 4 if has_er else 3), np.nan)
    for w, row in enumerate(out):
        path = [plant.reset(states[w, :n_q], states[w, n_q:])]
        try:
            for tau in torques[w]:
                path.append(plant.step(tau))
        except SimulationDiverged:
            if diverged_nan:
                continue
            path += path[-1:] * (len(row) - len(path))
        row[:] = [(o.phi_rad, o.ex_m, o.ey_m, o.er_rad)[: row.shape[1]] for o in path]
    return out


def _shifted(x: np.ndarray, fraction: float, before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """``x`` along axis 1 delayed by ``fraction`` of a sample (advanced if negative), linearly interpolated; ``before``
    and ``after`` are the samples beyond either end."""
    if fraction > 0.0:
        return (1.0 - fraction) * x + fraction * np.concatenate([before, x[:, :-1]], axis=1)
    if fraction < 0.0:
        return (1.0 + fraction) * x - fraction * np.concatenate([x[:, 1:], after], axis=1)
    return x


def _normal_blocks(dense: np.ndarray, block: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``J_p^T J_p``, the windows' ``J_s^T J_s`` and ``J_p^T J_s``."""
    a = np.einsum("wrp,wrq->pq", dense, dense)
    d = np.einsum("wri,wrj->wij", block, block)
    b = np.einsum("wrp,wri->wpi", dense, block)
    return a, d, b


def _decode(names: Sequence[str], theta: np.ndarray, guess: RodParams) -> dict[str, float]:
    """Each parameter's value of the decision variables: rod fields and the torque gain scaled by ``e^theta``, the
    encoder offset by :data:`_OFFSET_SCALE_RAD`, the delays as fractions of ``dt``; the calibrations not estimated
    at their defaults."""
    out = dict(_CALIBRATIONS)
    for name, value in zip(names, theta):
        if name in _DELAYS:
            out[name] = float(value)
        elif name == "encoder_offset_rad":
            out[name] = value * _OFFSET_SCALE_RAD
        else:
            out[name] = (getattr(guess, name) if name != "torque_gain" else 1.0) * math.exp(value)
    return out


class _Problem:
    """The multiple-shooting least-squares problem (decision vector: scaled parameters, then window states)."""

    def __init__(
        self,
        dataset: TrajectoryDataset,
        guess: RodParams,
        names: Sequence[str],
        starts: np.ndarray,
        steps: int,
        diverged_nan: bool = False,
    ) -> None:
        self.dataset, self.guess, self.names, self.diverged_nan = dataset, guess, tuple(names), diverged_nan
        observed, columns = _observed(dataset)
        self.has_er = "er_rad" in observed
        index = starts[:, 1:2] + np.arange(steps + 1)[None, :]
        self.measured = columns[starts[:, :1], index]
        self.torques = dataset.torques_nm[starts[:, :1], index[:, :-1]]
        self.previous_torques = dataset.torques_nm[starts[:, :1], np.maximum(starts[:, 1:] - 1, 0)]
        self.next_torques = dataset.torques_nm[starts[:, :1], np.minimum(starts[:, 1:] + steps, dataset.n_samples - 2)]
        self.n_windows = int(starts.shape[0])
        self.n_q = guess.n_links + 1
        self.n_p = len(self.names)
        self.weights = np.array([1.0, 1.0 / guess.length_m, 1.0 / guess.length_m, 1.0][: len(observed)])
        self._plants: dict[bytes, PRBPlant] = {}
        self._cache: tuple[bytes, np.ndarray] | None = None

    def unpack(self, theta: np.ndarray) -> tuple[RodParams, dict[str, float]]:
        """The rod and every parameter's value (:func:`_decode`) of scaled parameters."""
        values = _decode(self.names, theta, self.guess)
        return self.guess.replace(**{n: v for n, v in values.items() if n in ESTIMABLE_ROD_FIELDS}), values

    def simulate(self, z: np.ndarray) -> np.ndarray:
        theta = z[: self.n_p]
        states = z[self.n_p :].reshape(self.n_windows, 2 * self.n_q)
        key = np.asarray(theta, float).tobytes()
        rod, values = self.unpack(theta)
        if key not in self._plants:
            if len(self._plants) > 4:
                self._plants.clear()
            self._plants[key] = free_plant(rod, self.dataset)
        torques = _shifted(self.torques, values["torque_delay_s"], self.previous_torques, self.next_torques)
        sim = simulate_windows(
            self._plants[key], states, torques * values["torque_gain"], self.has_er, self.diverged_nan
        )
        sim[..., 0] += values["encoder_offset_rad"]
        if values["camera_delay_s"]:  # the camera sees the tip of (k - b) dt at sample k
            c = sim[:, :, 1:]
            sim[:, :, 1:] = _shifted(c, values["camera_delay_s"], 2 * c[:, :1] - c[:, 1:2], 2 * c[:, -1:] - c[:, -2:-1])
        return sim

    def residual_blocks(self, z: np.ndarray) -> np.ndarray:
        """Residuals ``(B, W + 1, k)``, angles wrapped, tip coordinates over the rod length."""
        r = self.simulate(z) - self.measured
        r[..., ::3] = wrap_diff(r[..., ::3], 0.0)  # phi and er, the angles
        return r * self.weights

    def residuals(self, z: np.ndarray) -> np.ndarray:
        key = z.tobytes()
        if self._cache is None or self._cache[0] != key:
            self._cache = (key, self.residual_blocks(z).reshape(-1))
        return self._cache[1]

    def jacobian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Forward differences, every window's state component moved at once (backward ones for a window whose
        forward move diverges, zero if both do): ``(J_p, J_s)`` of shapes ``(B, R, P)`` and ``(B, R, S)`` (each
        window's own state; the rest is zero)."""
        z = np.asarray(z, float)
        base = self.residuals(z).reshape(self.n_windows, -1)

        def difference(move: np.ndarray) -> np.ndarray:
            """``(r(z + move) - r(z - move)`` where that is finite, else one side) over the move, per window."""
            ahead = self.residual_blocks(z + move).reshape(self.n_windows, -1) - base
            bad = ~np.isfinite(ahead).all(axis=1)
            if bad.any():
                ahead[bad] = (base - self.residual_blocks(z - move).reshape(self.n_windows, -1))[bad]
                ahead[~np.isfinite(ahead).all(axis=1)] = 0.0
            return ahead

        def column(index: np.ndarray) -> np.ndarray:
            """The derivative along the entries ``index`` of ``z``, moved together (one per window at most)."""
            move = np.zeros_like(z)
            move[index] = DIFF_STEP * np.maximum(1.0, np.abs(z[index]))
            return difference(move) / move[index][:, None]

        n_s = 2 * self.n_q
        windows = self.n_p + n_s * np.arange(self.n_windows)
        jac = np.stack([column(np.array([j])) for j in range(self.n_p)] + [column(windows + c) for c in range(n_s)], -1)
        return jac[..., : self.n_p], jac[..., self.n_p :]

    def parameter_information(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(A, S)`` at ``z``: ``J_p^T J_p`` and its Schur complement after eliminating the window states."""
        a, d, b = _normal_blocks(*self.jacobian(z))
        s = a - np.einsum("wpi,wij,wqj->pq", b, np.linalg.pinv(d, rcond=1e-12, hermitian=True), b)
        return a, 0.5 * (s + s.T)


def _levenberg_marquardt(
    problem: _Problem, z0: np.ndarray, bound: np.ndarray, max_iterations: int, tolerance: float
) -> tuple[np.ndarray, dict[str, Any]]:
    """Levenberg-Marquardt with Marquardt's scaling, each step solved exactly with the window states eliminated,
    the variables kept within ``[-bound, bound]``; stops on a small step or cost reduction, or the limit."""
    n_p = problem.n_p
    z = z0.copy()
    r = problem.residuals(z)
    cost = 0.5 * float(r @ r)
    mu = 1e-3
    nfev, njev, status, message = 1, 0, 0, "the iteration limit was reached"
    for _ in range(max_iterations):
        dense, block = problem.jacobian(z)
        njev += 1
        rb = r.reshape(problem.n_windows, -1)
        g_p = np.einsum("wrp,wr->p", dense, rb)
        g_s = np.einsum("wri,wr->wi", block, rb)
        a, d, b = _normal_blocks(dense, block)
        diag_a = np.maximum(np.diag(a), 1e-30)
        diag_d = np.maximum(np.diagonal(d, axis1=1, axis2=2), 1e-30)
        tries = 0
        while mu < 1e12:
            tries += 1
            d_mu = d + mu * (np.eye(d.shape[1])[None] * diag_d[:, None, :])
            a_mu = a + mu * np.diag(diag_a)
            solved = np.linalg.solve(d_mu, np.concatenate([np.transpose(b, (0, 2, 1)), g_s[:, :, None]], axis=2))
            inv_bt, inv_g = solved[:, :, :n_p], solved[:, :, n_p]
            schur = a_mu - np.einsum("wpi,wiq->pq", b, inv_bt)
            rhs = -g_p + np.einsum("wpi,wi->p", b, inv_g)
            dp = np.linalg.solve(schur, rhs) if n_p else np.zeros(0)
            ds = -inv_g - np.einsum("wip,p->wi", inv_bt, dp)
            trial = np.clip(z + np.concatenate([dp, ds.reshape(-1)]), -bound, bound)
            r_new = problem.residuals(trial)
            nfev += 1
            cost_new = 0.5 * float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new < cost:
                break
            mu *= 4.0
        else:
            status, message = 2, "no step lowers the cost (converged to the numerical precision)"
            break
        if n_p:
            step = float(np.max(np.abs(trial[:n_p] - z[:n_p])))
        else:
            step = float(np.max(np.abs(trial - z) / np.maximum(1.0, np.abs(z)), initial=0.0))
        reduction = (cost - cost_new) / max(cost, 1e-300)
        z, r, cost = trial, r_new, cost_new
        mu = max(mu / 10.0, 1e-12)
        # a step shrunk by raising the damping is small because larger ones failed, not because it converged
        if (step < tolerance and tries == 1) or reduction < tolerance**2 or cost < 1e-30:
            status, message = 1, "the parameter step or the cost reduction fell below the tolerance"
            break
    return z, {"nfev": nfev, "njev": njev, "status": status, "message": message}


def _check_identifiable(names: tuple[str, ...], a: np.ndarray, s: np.ndarray, where: str) -> None:
    """:class:`NotIdentifiable` naming a parameter the data do not determine (no effect, or a mix of others)."""
    diag = np.diag(a)
    scale = float(diag.max(initial=0.0))
    for name, value in zip(names, diag):
        if not value > IDENTIFIABILITY_TOLERANCE * max(scale, 1e-300) or scale == 0.0:
            raise NotIdentifiable(name, f"the dataset cannot identify {name} ({where}: nothing observed depends on it)")
    norm = 1.0 / np.sqrt(diag)
    values, vectors = np.linalg.eigh(s * norm[:, None] * norm[None, :])
    if values[0] < IDENTIFIABILITY_TOLERANCE:
        worst = names[int(np.argmax(np.abs(vectors[:, 0])))]
        partners = [n for n, v in zip(names, vectors[:, 0]) if abs(v) > 0.2 and n != worst]
        mixed = ", ".join(partners) or "the window initial states"
        raise NotIdentifiable(worst, f"the dataset cannot identify {worst} ({where}: its effect is that of {mixed})")


def _window_starts(dataset: TrajectoryDataset, steps: int, max_windows: int, seed: int) -> np.ndarray:
    """``(B, 2)`` rows ``(trial, first sample)`` of non-overlapping windows from sample 1, at most ``max_windows``
    drawn."""
    n = dataset.n_samples
    firsts = np.arange(1, n - steps, steps)
    if firsts.size == 0:
        raise ValueError(f"window_s covers {steps} samples; trials of {n} samples are too short for one window")
    grid = np.array([(t, s) for t in range(dataset.n_trials) for s in firsts], dtype=np.int64)
    if len(grid) > max_windows:
        grid = grid[np.sort(np.random.default_rng(seed).choice(len(grid), size=max_windows, replace=False))]
    return grid


def _initial_states(dataset: TrajectoryDataset, starts: np.ndarray, guess: RodParams) -> np.ndarray:
    """Window start states: the reconstructed bent rod, rates by central differences of the reconstructions."""
    names, columns = _observed(dataset)
    shifted = (columns[starts[:, 0], starts[:, 1] + shift] for shift in (-1, 0, 1))
    er = len(names) > 3
    q = [reconstruct_joint_states(c[:, 0], c[:, 1], c[:, 2], c[:, 3] if er else None, guess) for c in shifted]
    return np.concatenate([q[1], wrap_diff(q[2], q[0]) / (2 * dataset.dt_s)], axis=1)


def identify(
    dataset: TrajectoryDataset, config: Optional[GreyBoxConfig] = None, initial_params: Optional[RodParams] = None
) -> GreyBoxResult:
    """Estimate PRB rod parameters (and rig calibrations) from a dataset by multiple shooting.

    ``initial_params`` is the initial guess and holds the fields not estimated (default: the dataset's
    ``plant_params``, else ``RodParams()``).  Raises ``ValueError`` on bad arguments, a dataset too short for one
    window, or a parameter the dataset cannot identify (named).
    """
    started = time.perf_counter()
    config = config if config is not None else GreyBoxConfig()
    guess = initial_params if initial_params is not None else (dataset.params or RodParams())
    for name in config.parameters:
        if name in ESTIMABLE_ROD_FIELDS and not getattr(guess, name) > 0:
            raise ValueError(f"initial_params.{name} must be positive to be estimated, got {getattr(guess, name)!r}")
        if name in ("torque_gain", "torque_delay_s") and not np.any(dataset.torques_nm != 0):
            raise NotIdentifiable(name, f"the dataset cannot identify {name}: its torques_nm are all zero")
    steps = int(round(config.window_s / dataset.dt_s))
    if steps < 2:
        raise ValueError(f"window_s must cover at least 2 samples of dt_s = {dataset.dt_s} s, got {config.window_s!r}")
    starts = _window_starts(dataset, steps, config.max_windows, config.seed)
    warmup = int(round(WARMUP_WINDOW_S / dataset.dt_s))
    names, n_p = config.parameters, len(config.parameters)
    upper = np.array([1.0 if n in _DELAYS else np.inf if n == "encoder_offset_rad" else _LOG_BOUND for n in names])
    z = np.concatenate([np.zeros(n_p), _initial_states(dataset, starts, guess).reshape(-1)])
    fit: dict[str, Any] = {"nfev": 0, "njev": 0}
    for stage, stage_steps in enumerate(sorted({min(max(warmup, 2), steps), steps})):
        probe = _Problem(dataset, guess, names, starts, stage_steps, True)
        finite = np.isfinite(probe.residual_blocks(z)).all(axis=(1, 2))
        if not finite.any():
            raise ValueError(f"the simulation diverges in every window of {stage_steps} samples; give a closer guess")
        starts = starts[finite]  # a window whose simulation diverges has no derivative: left out
        z = np.concatenate([z[:n_p], z[n_p:].reshape(finite.size, -1)[finite].reshape(-1)])
        problem = probe if finite.all() else _Problem(dataset, guess, names, starts, stage_steps, True)
        if stage == 0:
            _check_identifiable(names, *problem.parameter_information(z), "at the initial guess")
        bound = np.concatenate([upper, np.full(z.size - n_p, np.inf)])
        z, stage_fit = _levenberg_marquardt(problem, z, bound, config.max_iterations, TOLERANCE)
        fit = {**stage_fit, "nfev": fit["nfev"] + stage_fit["nfev"], "njev": fit["njev"] + stage_fit["njev"]}
    a, s = problem.parameter_information(z)
    _check_identifiable(names, a, s, "at the optimum")
    r = problem.residuals(z)
    sigma2 = float(r @ r) / max(r.size - z.size, 1)
    sd = np.sqrt(np.clip(np.diag(sigma2 * np.linalg.inv(s)), 0.0, None))
    values = _decode(names, z[:n_p], guess)  # the delays' units are dt, their derivative too; log scale: the value
    unit = {n: dataset.dt_s if n in _DELAYS else 1.0 for n in names}
    slope = {
        n: _OFFSET_SCALE_RAD if n == "encoder_offset_rad" else unit[n] if n in _DELAYS else values[n] for n in names
    }
    record: dict[str, Any] = {k: int(fit[k]) for k in ("nfev", "njev", "status")} | {"message": str(fit["message"])}
    record |= dict(n_windows=problem.n_windows, window_steps=steps, n_residuals=r.size, n_variables=z.size)
    return GreyBoxResult(
        params=problem.unpack(z[:n_p])[0],
        initial_params=guess,
        estimates={n: values[n] * unit[n] for n in names},
        std={n: float(slope[n] * sd[j]) for j, n in enumerate(names)},
        residual_rms_rad=float(np.sqrt(np.mean(r**2))),
        identify_s=time.perf_counter() - started,
        at_bounds=tuple(n for n, hit in zip(names, np.abs(z[:n_p]) >= upper * (1 - 1e-9)) if hit),
        **record,
    )


def estimate_joint_states(
    params: RodParams,
    dataset: TrajectoryDataset,
    samples: np.ndarray,
    lookback_s: float = 0.1,
) -> np.ndarray:
    """Causal PRB joint states ``(B, 2 (n + 1))`` at rows ``(trial, sample)``: the state ``lookback_s`` earlier is
    fitted to the observations up to ``sample`` (parameters held), then run forward under the recorded torques."""
    samples = np.asarray(samples, dtype=np.int64).reshape(-1, 2)
    steps = int(round(positive("lookback_s", lookback_s) / dataset.dt_s))
    if steps < 2:
        raise ValueError(f"lookback_s must cover at least 2 samples of dt_s = {dataset.dt_s} s, got {lookback_s!r}")
    starts = samples - np.array([0, steps])
    if samples.size == 0 or starts[:, 1].min() < 1 or samples[:, 1].max() >= dataset.n_samples:
        raise ValueError(f"samples must lie in [{steps + 1}, {dataset.n_samples}) to look {lookback_s} s back")
    problem = _Problem(dataset, params, (), starts, steps)
    x0 = _initial_states(dataset, starts, params).reshape(-1)
    z, _ = _levenberg_marquardt(problem, x0, np.full(x0.size, np.inf), 15, 1e-8)
    fitted = z.reshape(problem.n_windows, -1)
    plant = free_plant(params, dataset)
    n_q = plant.n_coordinates
    out = np.empty_like(fitted)
    for w in range(problem.n_windows):
        plant.reset(fitted[w, :n_q], fitted[w, n_q:])
        try:
            for tau in problem.torques[w]:
                plant.step(tau)
        except SimulationDiverged:
            pass
        out[w] = np.concatenate(plant.joint_state())
    return out
