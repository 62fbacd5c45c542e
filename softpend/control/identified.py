"""The grey-box route: excite the rod with a designed multisine, identify it, and stop exciting as soon as the
energy swing-up + LQR designed on the estimate balances every rod the identification still allows.

Only the recorder touches the plant; the stopping check runs the controller on simulated rods drawn from the
estimate and its standard deviations, so the plant seconds of a route are the seconds of excitation.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np

from softpend.checks import in_range, positive, positive_int, set_ints
from softpend.control.swingup import EnergySwingUpController
from softpend.envs.randomised import RodUncertainty
from softpend.evaluation import HOLD_STD_RAD, evaluate
from softpend.plant import RodParams
from softpend.sysid.babble import BabbleProtocol, babble
from softpend.sysid.dataset import TrajectoryDataset
from softpend.sysid.greybox import GreyBoxConfig, GreyBoxResult, identify
from softpend.task import Task

#: First start seed of the stopping check's simulated starts (far from every training, selection and report seed).
CHECK_SEED_BASE = 500_000
#: Relative standard deviation standing for one that is not finite (a draw spans at most a factor ``e``).
WIDEST_RELATIVE_STD = 1e3
#: Standard deviation of the simulated recorder's encoder [rad] and camera [m] noise.
SENSOR_NOISE_STD = 0.002
#: Records ``seconds`` of the excitation program on the plant (from hanging) and returns the dataset.
Recorder = Callable[[float], TrajectoryDataset]


@dataclass(frozen=True)
class RouteConfig:
    """Settings of :func:`identify_until_robust`: excitation in steps of ``step_s`` up to ``max_excitation_s``
    (multisine to ``band_high_hz`` with peak ``peak_fraction`` of the torque limit), and the stopping check:
    ``check_draws`` rods drawn two standard deviations wide, each from ``check_starts`` hanging starts of
    ``check_duration_s``."""

    step_s: float = 1.0
    max_excitation_s: float = 10.0
    peak_fraction: float = 0.8
    band_high_hz: float = 6.0
    check_draws: int = 8
    check_starts: int = 2
    check_duration_s: float = 8.0

    def __post_init__(self) -> None:
        for name in ("step_s", "max_excitation_s", "band_high_hz", "check_duration_s"):
            positive(name, getattr(self, name))
        in_range("peak_fraction", self.peak_fraction, 1e-3, 1)
        set_ints(self, "check_draws check_starts", 1)
        if self.step_s > self.max_excitation_s:
            raise ValueError(f"step_s ({self.step_s}) must not exceed max_excitation_s ({self.max_excitation_s})")


@dataclass
class RouteResult:
    """What a route used and found: plant seconds of excitation, the last identification, its controller, and per
    step the seconds, the largest relative standard deviation and whether the check passed."""

    plant_s: float
    identification: GreyBoxResult
    controller: EnergySwingUpController
    robust: bool
    steps: list[dict[str, float]] = field(default_factory=list)


def design_swingup(params: RodParams, dt_s: float = 0.01) -> EnergySwingUpController:
    """The energy swing-up + LQR on the observed variables, designed on ``params``."""
    return EnergySwingUpController.for_observations(params, dt_s=dt_s)


def hanging_protocol(task: Task, seconds: float, program: str, **fields: Any) -> BabbleProtocol:
    """The babbling that identifies the rod: one trial of ``seconds`` of the torque ``program`` from hanging, no
    feedback, at ``task``'s step and sub-steps; ``fields``: the protocol's other fields."""
    timing: dict[str, Any] = dict(n_trials=1, trial_length_s=seconds, dt_s=task.dt_s, substeps=task.substeps)
    return BabbleProtocol(start="hanging", feedback_trial_fraction=0.0, program=program, **timing, **fields)


def simulated_recorder(task: Task, config: RouteConfig, seed: int, program: str = "multisine") -> Recorder:
    """A recorder of one hanging trial of the babbling ``program`` (multisine to ``band_high_hz`` with peak
    ``peak_fraction``), no feedback, on ``task``'s simulated plant with encoder and camera noise of
    :data:`SENSOR_NOISE_STD` rad and m."""

    def record(seconds: float) -> TrajectoryDataset:
        start = dict(start_angle_std_rad=0.05, start_rate_std_rad_s=0.1)
        shape = dict(multisine_peak_fraction=config.peak_fraction, torque_bandwidth_hz=config.band_high_hz)
        noise = dict(phi_noise_std_rad=SENSOR_NOISE_STD, tip_noise_std_m=SENSOR_NOISE_STD)
        protocol = hanging_protocol(task, seconds, program, **start, **shape, **noise)
        return babble(protocol, params=task.rod, seed=seed, plant=task.plant, progress=False)

    return record


def identified_uncertainty(result: GreyBoxResult, scale: float = 2.0) -> RodUncertainty:
    """The estimated rod fields' relative standard deviations (a field estimated at 0 is not drawn; one whose
    deviation is not finite is drawn over the widest range) and the draws' width ``scale`` in them."""
    relative = {}
    for name, value in result.estimates.items():
        if hasattr(result.params, name):
            ratio = result.std[name] / abs(value) if value else 0.0
            relative[name] = ratio if math.isfinite(ratio) else WIDEST_RELATIVE_STD
    return RodUncertainty(tuple(relative.items()), scale)


def uncertainty_draws(result: GreyBoxResult, n: int, seed: int, scale: float = 2.0) -> list[RodParams]:
    """``n`` rods drawn from :func:`identified_uncertainty` around the estimate (log scale, as the
    identification's)."""
    rng = np.random.default_rng(seed)
    uncertainty = identified_uncertainty(result, scale)
    return [uncertainty.draw(result.params, rng) for _ in range(positive_int("n", n))]


def _balances_every_draw(
    controller: EnergySwingUpController, draws: list[RodParams], config: RouteConfig, seed: int
) -> bool:
    for i, rod in enumerate(draws):
        seeds = [CHECK_SEED_BASE + seed * 1000 + i * config.check_starts + j for j in range(config.check_starts)]
        task, duration_s = Task(rod=rod), config.check_duration_s
        summary = evaluate(controller, task, seeds=seeds, duration_s=duration_s, stop_at_first_failure=True)
        if not all(math.isfinite(r.swing_up_time_s) and r.upright_std_rad <= HOLD_STD_RAD for r in summary.results):
            return False
    return True


def identify_until_robust(
    record: Recorder, guess: RodParams, config: Optional[RouteConfig] = None, seed: int = 0
) -> RouteResult:
    """Excite for ``step_s``, ``2 step_s``, ... seconds, identify from ``guess`` each time, and stop at the first
    length whose controller balances every uncertainty draw (or at ``max_excitation_s``).

    ``seed`` seeds the identification's window draw (:class:`GreyBoxConfig`'s defaults otherwise), the uncertainty
    draws and the check's starts (hanging starts of the simulator, never the plant's).
    """
    config, identification = config if config is not None else RouteConfig(), GreyBoxConfig(seed=seed)
    steps: list[dict[str, float]] = []
    n_steps = max(int(math.floor(config.max_excitation_s / config.step_s + 1e-9)), 1)
    for k in range(1, n_steps + 1):
        seconds = k * config.step_s
        started = time.perf_counter()
        result = identify(record(seconds), identification, initial_params=guess)
        identified = time.perf_counter()
        controller = design_swingup(result.params)
        draws = uncertainty_draws(result, config.check_draws, seed + k)
        robust = _balances_every_draw(controller, [result.params] + draws, config, seed + k)
        relative = max(result.std[n] / abs(v) for n, v in result.estimates.items() if v)
        walls = {"identify_wall_s": identified - started, "check_wall_s": time.perf_counter() - identified}
        steps.append({"plant_s": seconds, "max_relative_std": float(relative), "robust": float(robust), **walls})
        if robust or k == n_steps:
            return RouteResult(seconds, result, controller, robust, steps)
    raise AssertionError("unreachable")
