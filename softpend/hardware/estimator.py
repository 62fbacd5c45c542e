"""Rig state estimation: an extended Kalman filter on the PRB model, fed by the encoder every STATE frame and by
late camera frames at their capture time (the history corrected there and replayed to now)."""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from softpend.checks import int_at_least, non_negative, positive
from softpend.plant import Observation, SimulationDiverged


@dataclass(frozen=True)
class EstimatorConfig:
    """Noise levels and limits of :class:`RigStateEstimator` (SI units; ``history_s`` how far back a late frame may
    reach; ``lead_steps`` of prediction ahead)."""

    counts_per_rev: int = 4096
    hub_rate_std_rad_s: float = 0.02
    tip_std_m: float = 0.002
    torque_std_nm: float = 0.003
    accel_std_rad_s2: float = 0.5
    initial_bend_std_rad: float = 0.03
    initial_rate_std_rad_s: float = 0.5
    max_blind_s: float = 0.3
    history_s: float = 0.3
    gate_sigma: float = 6.0
    lead_steps: int = 1

    def __post_init__(self) -> None:
        int_at_least("counts_per_rev", self.counts_per_rev, 4)
        for name in ("hub_rate_std_rad_s", "tip_std_m", "max_blind_s", "history_s", "gate_sigma"):
            positive(name, getattr(self, name))
        for name in ("torque_std_nm", "accel_std_rad_s2", "initial_bend_std_rad", "initial_rate_std_rad_s"):
            non_negative(name, getattr(self, name))
        int_at_least("lead_steps", self.lead_steps, 0)


@dataclass(frozen=True)
class Estimate:
    """What the estimator hands a controller: the state at ``time_s`` (last encoder sample plus the lead)."""

    time_s: float
    q: np.ndarray
    q_dot: np.ndarray
    observation: Observation
    tip_std_m: float


@dataclass
class _Step:
    time_s: float
    x: np.ndarray
    p: np.ndarray
    torque_nm: float  # applied from time_s on
    phi_rad: float
    phi_dot_rad_s: float
    tips: list = field(default_factory=list)  # (capture_time_s, x_m, y_m) applied at this step


class DeviceClock:
    """Host to device time: the smallest ``host - device`` of the last ``window`` STATE frames, less the latency."""

    def __init__(self, one_way_latency_s: float = 0.0, window: int = 500) -> None:
        self.one_way_latency_s = one_way_latency_s
        self._delays: collections.deque[float] = collections.deque(maxlen=window)

    def observe(self, host_time_s: float, device_time_s: float) -> None:
        self._delays.append(host_time_s - device_time_s)

    @property
    def offset_s(self) -> float:
        """Host minus device clock [s] (NaN before the first frame)."""
        return min(self._delays) - self.one_way_latency_s if self._delays else math.nan

    def to_device(self, host_time_s: float) -> float:
        return host_time_s - self.offset_s


class RigStateEstimator:
    """EKF on the PRB chain of ``task.rod`` with delay-compensated camera corrections; times in device time [s]."""

    def __init__(self, task, config: Optional[EstimatorConfig] = None) -> None:
        self.task = task = task.replace(plant="prb")
        self.config = cfg = config if config is not None else EstimatorConfig()
        self.model = task.make_plant()
        self.n = n = self.model.n_coordinates
        self.dt_s = float(task.dt_s)
        self._history: collections.deque[_Step] = collections.deque()
        self._last_tip_time_s = -math.inf
        self.counts = dict.fromkeys("tips_accepted tips_refused tips_too_old tips_deferred encoder_gaps".split(), 0)
        self._pending_tips: list[tuple[float, float, float]] = []
        self._h_encoder = np.eye(2 * n)[[0, n]]  # measures the hub angle and rate
        self._encoder_var = (2 * math.pi / cfg.counts_per_rev / math.sqrt(12.0)) ** 2  # quantisation noise
        self._r_encoder = np.diag([self._encoder_var, cfg.hub_rate_std_rad_s**2])
        self._r_tip, self._eye_2n = np.eye(2) * cfg.tip_std_m**2, np.eye(2 * n)
        self._accel_sigma = cfg.accel_std_rad_s2**2 * np.eye(n)
        self._a = np.zeros((2 * n, 2 * n))
        self._a[:n, n:] = np.eye(n)
        self.started = False

    def reset(self, time_s: float, phi_rad: float, phi_dot_rad_s: float, torque_nm: float = 0.0) -> None:
        """Start from the straight rod at the measured hub angle and rate, with the config's prior uncertainty."""
        cfg, n = self.config, self.n
        x = np.zeros(2 * n)
        x[0], x[n] = phi_rad, phi_dot_rad_s
        bend, rate = cfg.initial_bend_std_rad**2, cfg.initial_rate_std_rad_s**2
        variances = [self._encoder_var] + [bend] * (n - 1) + [rate] * n
        self._history.clear()
        self._pending_tips.clear()
        self._history.append(
            _Step(float(time_s), x, np.diag(variances), float(torque_nm), float(phi_rad), float(phi_dot_rad_s))
        )
        self._last_tip_time_s = float(time_s)
        self.started = True

    @property
    def blind_s(self) -> float:
        """Time from the capture of the last correcting frame to the newest encoder sample [s]."""
        self._require_started()
        return self._history[-1].time_s - self._last_tip_time_s

    @property
    def is_blind(self) -> bool:
        return self.blind_s > self.config.max_blind_s

    def _require_started(self) -> None:
        if not self.started:
            raise ValueError("estimator: call reset() with the first encoder sample first")

    def _predict(self, x: np.ndarray, p: np.ndarray, torque_nm: float) -> tuple[np.ndarray, np.ndarray]:
        n, dt, cfg, model = self.n, self.dt_s, self.config, self.model
        model.reset(x[:n], x[n:])
        mass, stiffness, damping = model.linearized_matrices()
        model.step(torque_nm)
        x_next = np.concatenate(model.joint_state())
        if not np.all(np.isfinite(x_next)):
            raise SimulationDiverged("estimator model state is not finite")
        m_inv, a, eye = np.linalg.inv(mass), self._a, self._eye_2n
        a[n:, :n], a[n:, n:] = -m_inv @ stiffness, -m_inv @ damping
        f = np.linalg.solve(eye - 0.5 * dt * a, eye + 0.5 * dt * a)
        b = m_inv[:, 0]
        sigma = self._accel_sigma + cfg.torque_std_nm**2 / dt * np.outer(b, b)
        q_noise = np.empty((2 * n, 2 * n))
        q_noise[:n, :n] = dt**3 / 3 * sigma
        q_noise[:n, n:] = q_noise[n:, :n] = dt**2 / 2 * sigma
        q_noise[n:, n:] = dt * sigma
        p_next = f @ p @ f.T + q_noise
        return x_next, 0.5 * (p_next + p_next.T)

    @staticmethod
    def _update(x, p, h, innovation, r) -> tuple[np.ndarray, np.ndarray]:
        gain = np.linalg.solve(h @ p @ h.T + r, h @ p).T
        i_kh = np.eye(len(x)) - gain @ h
        return x + gain @ innovation, i_kh @ p @ i_kh.T + gain @ r @ gain.T  # Joseph form

    def _advance(self, x, p, torque_nm: float, steps: int, phi_rad: float, phi_dot_rad_s: float):
        """Predict ``steps`` steps with ``torque_nm``, then correct with an encoder sample."""
        for _ in range(steps):
            x, p = self._predict(x, p, torque_nm)
        innovation = np.array([phi_rad, phi_dot_rad_s]) - self._h_encoder @ x
        return self._update(x, p, self._h_encoder, innovation, self._r_encoder)

    def _tip_model(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tip position [m], its velocity [m/s] and the Jacobian ``d tip / d x`` ``(2, 2n)`` at ``x``."""
        n = self.n
        angles = np.cumsum(x[:n])[1:]  # absolute angle of each link from upright
        rates = np.cumsum(x[n:])[1:]
        length = self.task.rod.link_length_m
        s, c = np.sin(angles), np.cos(angles)
        tip = np.array([-length * s.sum(), length * c.sum()])
        velocity = np.array([-length * (c * rates).sum(), -length * (s * rates).sum()])
        jac = np.zeros((2, 2 * n))
        tails = -length * np.cumsum(np.stack([c, s])[:, ::-1], axis=1)[:, ::-1]  # sums over links k >= i
        jac[:, 0], jac[:, 1:n] = tails[:, 0], tails
        return tip, velocity, jac

    def _tip_innovation(self, step: _Step, x: np.ndarray, capture_time_s: float, x_m: float, y_m: float):
        tip, velocity, jac = self._tip_model(x)
        measured = np.array([x_m, y_m]) + velocity * (step.time_s - capture_time_s)
        return measured - tip, jac

    def _replay(self, start: int) -> None:
        """Recompute the steps after index ``start`` from its (corrected) estimate."""
        history = self._history
        for i in range(start + 1, len(history)):
            previous, step = history[i - 1], history[i]
            steps = max(1, int(round((step.time_s - previous.time_s) / self.dt_s)))
            x, p = self._advance(previous.x, previous.p, previous.torque_nm, steps, step.phi_rad, step.phi_dot_rad_s)
            for capture, tip_x, tip_y in step.tips:
                innovation, jac = self._tip_innovation(step, x, capture, tip_x, tip_y)
                x, p = self._update(x, p, jac, innovation, self._r_tip)
            step.x, step.p = x, p

    def update_encoder(self, time_s: float, phi_rad: float, phi_dot_rad_s: float, torque_nm: float) -> None:
        """A STATE frame sampled at ``time_s``, and the torque the device applies from then on."""
        self._require_started()
        last = self._history[-1]
        steps = int(round((time_s - last.time_s) / self.dt_s))
        if steps < 1:
            return  # a repeated or out-of-order frame
        self.counts["encoder_gaps"] += int(steps > 1)
        x, p = self._advance(last.x, last.p, last.torque_nm, steps, phi_rad, phi_dot_rad_s)
        self._history.append(_Step(float(time_s), x, p, float(torque_nm), float(phi_rad), float(phi_dot_rad_s)))
        while len(self._history) > 2 and self._history[1].time_s < time_s - self.config.history_s:
            self._history.popleft()
        due = [tip for tip in self._pending_tips if tip[0] <= time_s + self.dt_s / 2]
        self._pending_tips = [tip for tip in self._pending_tips if tip[0] > time_s + self.dt_s / 2]
        for tip in due:
            self._apply_tip(*tip)

    def update_tip(self, capture_time_s: float, x_m: float, y_m: float) -> bool:
        """Correct the step nearest ``capture_time_s`` with a tip seen at ``(x_m, y_m)`` and replay to now (a frame
        ahead of the encoder waits); whether it was used or queued."""
        self._require_started()
        if not (math.isfinite(x_m) and math.isfinite(y_m) and math.isfinite(capture_time_s)):
            return False
        history = self._history
        if capture_time_s < history[0].time_s - self.dt_s / 2:
            self.counts["tips_too_old"] += 1
            return False
        if capture_time_s > history[-1].time_s + self.dt_s / 2:
            if capture_time_s > history[-1].time_s + self.config.history_s:
                return False  # a clock error
            self._pending_tips.append((float(capture_time_s), float(x_m), float(y_m)))
            self.counts["tips_deferred"] += 1
            return True
        return self._apply_tip(capture_time_s, x_m, y_m)

    def _apply_tip(self, capture_time_s: float, x_m: float, y_m: float) -> bool:
        history = self._history
        times = np.fromiter((s.time_s for s in history), float, len(history))
        index = int(np.argmin(np.abs(times - capture_time_s)))
        step = history[index]
        innovation, jac = self._tip_innovation(step, step.x, capture_time_s, x_m, y_m)
        distance2 = float(innovation @ np.linalg.solve(jac @ step.p @ jac.T + self._r_tip, innovation))
        if distance2 > self.config.gate_sigma**2:
            self.counts["tips_refused"] += 1
            return False
        step.x, step.p = self._update(step.x, step.p, jac, innovation, self._r_tip)
        step.tips.append((float(capture_time_s), float(x_m), float(y_m)))
        self._replay(index)
        self.counts["tips_accepted"] += 1
        self._last_tip_time_s = max(self._last_tip_time_s, float(capture_time_s))
        return True

    def estimate(self) -> Estimate:
        """The estimate at the newest encoder sample, predicted the config's ``lead_steps`` ahead."""
        self._require_started()
        lead, last, n = self.config.lead_steps, self._history[-1], self.n
        q, qd = last.x[:n].copy(), last.x[n:].copy()
        if lead:
            self.model.reset(q, qd)
            for _ in range(lead):
                self.model.step(last.torque_nm)
            q, qd = self.model.joint_state()
        _, _, jac = self._tip_model(last.x)
        tip_std = float(math.sqrt(max(np.trace(jac @ last.p @ jac.T) / 2, 0.0)))
        observation = self.model.observation_from_state(q, qd)
        return Estimate(last.time_s + lead * self.dt_s, q, qd, observation, tip_std)

    def stats(self) -> dict[str, float]:
        return {name: float(count) for name, count in self.counts.items()}
