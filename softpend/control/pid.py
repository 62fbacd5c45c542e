"""PID on the tip angle (filtered derivative of the measured angle, back-calculation anti-windup) and its tuning
by Nelder-Mead on closed-loop rollouts of any one-step model."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from softpend.checks import non_negative, positive
from softpend.plant import Observation, RodParams, wrap_angle_rad
from softpend.task import Task

#: Time constant ``T_f`` [s] of the PID's derivative filter.
DERIVATIVE_FILTER_S = 0.02


@dataclass(frozen=True)
class PIDGains:
    """PID gains on the tip angle."""

    kp_nm_per_rad: float
    ki_nm_per_rad_s: float
    kd_nms_per_rad: float

    def __post_init__(self) -> None:
        for name in ("kp_nm_per_rad", "ki_nm_per_rad_s", "kd_nms_per_rad"):
            non_negative(name, getattr(self, name))

    def as_array(self) -> np.ndarray:
        return np.array([self.kp_nm_per_rad, self.ki_nm_per_rad_s, self.kd_nms_per_rad])


class PIDController:
    """Discrete PID on the tip angle, setpoint upright: ``D[k] = (T_f D[k-1] + e[k] - e[k-1]) / (T_f + dt)``,
    ``u[k] = K_p e[k] + I[k] + K_d D[k]``, ``tau[k] = -sat(u[k])``, ``I[k+1] = I[k] + dt (K_i e[k] + (sat(u[k]) -
    u[k]) / T_t)`` with ``T_f =`` :data:`DERIVATIVE_FILTER_S`, ``T_t = sqrt(T_i T_d)`` (``10 dt`` when a gain is
    zero)."""

    def __init__(self, gains: PIDGains, dt_s: float = 0.01, torque_limit_nm: float = RodParams.torque_limit_nm) -> None:
        if not isinstance(gains, PIDGains):
            raise ValueError(f"gains must be a PIDGains, got {type(gains).__name__}")
        self.dt_s = positive("dt_s", dt_s)
        self.torque_limit_nm = positive("torque_limit_nm", torque_limit_nm)
        kp, ki, kd = gains.as_array()
        self.tracking_time_s = math.sqrt((kp / ki) * (kd / kp)) if kp > 0 and ki > 0 and kd > 0 else 10 * self.dt_s
        self.gains, self.name = gains, "PID"
        self.reset()

    def reset(self) -> None:
        self.integral_nm, self.derivative_rad_s = 0.0, 0.0
        self._last_error_rad: Optional[float] = None

    def update(self, theta_rad: float) -> float:
        """One step with the measured tip angle; the torque [N m]."""
        if not math.isfinite(theta_rad):
            raise ValueError(f"theta_rad must be finite, got {theta_rad!r}")
        kp, ki, kd = self.gains.as_array()
        error = float(wrap_angle_rad(theta_rad))
        increment = 0.0 if self._last_error_rad is None else float(wrap_angle_rad(error - self._last_error_rad))
        self._last_error_rad = error
        tf, dt = DERIVATIVE_FILTER_S, self.dt_s
        self.derivative_rad_s = (tf * self.derivative_rad_s + increment) / (tf + dt)
        effort = kp * error + self.integral_nm + kd * self.derivative_rad_s
        saturated = min(max(effort, -self.torque_limit_nm), self.torque_limit_nm)
        self.integral_nm += dt * (ki * error + (saturated - effort) / self.tracking_time_s)
        return -saturated

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        return self.update(observation.theta_rad)


@dataclass
class PIDTuningResult:
    """Outcome of :func:`tune_pid`."""

    gains: PIDGains
    cost: float
    initial_cost: float
    n_evaluations: int


#: ``simulate(controller, tilt_rad, duration_s) -> (theta_rad[T], torque_nm[T])`` on some model.
Simulator = Callable[[PIDController, float, float], tuple[np.ndarray, np.ndarray]]


#: Weight of the mean squared torque fraction beside the mean squared tip angle in :func:`tune_pid`'s cost.
TORQUE_WEIGHT = 0.1


def tune_pid(
    simulate: Simulator,
    initial_gains: PIDGains = PIDGains(0.5, 0.5, 0.05),
    torque_limit_nm: float = RodParams.torque_limit_nm,
    tilts_rad: Sequence[float] = (0.1, -0.2),
    duration_s: float = 3.0,
    max_evaluations: int = 120,
) -> PIDTuningResult:
    """Gains minimising the mean over ``tilts_rad`` starts of ``mean(theta^2) + TORQUE_WEIGHT * mean((tau /
    tau_max)^2)`` (10 for a rollout that leaves 1 rad or is not finite) on ``simulate``, by Nelder-Mead on their
    logarithms from ``initial_gains`` (positive), in at most ``max_evaluations`` costs."""
    import scipy.optimize

    if np.any(initial_gains.as_array() <= 0):
        raise ValueError("initial_gains must all be positive (the search is on their logarithms)")
    if int(max_evaluations) < 1:
        raise ValueError(f"max_evaluations must be >= 1, got {max_evaluations!r}")

    def cost(log_gains: np.ndarray) -> float:
        controller = PIDController(PIDGains(*np.exp(np.clip(log_gains, -12, 6))), torque_limit_nm=torque_limit_nm)
        total = 0.0
        for tilt in tilts_rad:
            controller.reset()
            theta, torque = (np.asarray(a, float) for a in simulate(controller, float(tilt), duration_s))
            if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(torque))) or np.any(np.abs(theta) > 1.0):
                total += 10.0
                continue
            total += float(np.mean(theta**2) + TORQUE_WEIGHT * np.mean((torque / torque_limit_nm) ** 2))
        return total / len(tilts_rad)

    x0 = np.log(initial_gains.as_array())
    initial_cost, simplex = cost(x0), np.vstack([np.zeros(3), np.eye(3)])
    options = {"maxfev": int(max_evaluations), "xatol": 1e-3, "fatol": 1e-7, "initial_simplex": x0 + simplex}
    result = scipy.optimize.minimize(cost, x0, method="Nelder-Mead", options=options)
    best = result.x if result.fun <= initial_cost else x0
    gains = PIDGains(*np.exp(np.clip(best, -12, 6)))
    return PIDTuningResult(gains, float(min(result.fun, initial_cost)), initial_cost, int(result.nfev) + 1)


def plant_simulator(task: Optional[Task] = None) -> Simulator:
    """Closed-loop simulator on the plant of ``task``, from the straight rod at rest at the given tilt."""
    from softpend.evaluation import evaluate_controller

    base = (task if task is not None else Task()).replace(start="upright")

    def simulate(controller: PIDController, tilt_rad: float, duration_s: float) -> tuple[np.ndarray, np.ndarray]:
        run_task = base.replace(torque_limit_nm=controller.torque_limit_nm)
        result = evaluate_controller(
            controller, run_task, seeds=(0,), duration_s=duration_s, initial_state=run_task.tilt_state(tilt_rad)
        ).results[0]
        theta = result.theta_rad if result.diverged is None else np.append(result.theta_rad, np.nan)
        return theta, result.torque_nm

    return simulate
