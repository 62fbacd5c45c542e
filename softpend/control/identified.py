"""The grey-box route: excite the rod with a designed multisine, identify it, and stop exciting as soon as the
energy swing-up + LQR designed on the estimate balances every rod the identification still allows.

Only the recorder touches the plant; the stopping check runs the controller on simulated rods drawn from the
estimate and its standard deviations, so the plant seconds of a route are the seconds of excitation.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from softpend.checks import positive, positive_int
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
#: Records ``seconds`` of the excitation program on the plant (from hanging) and returns the dataset.
Recorder = Callable[[float], TrajectoryDataset]


@dataclass(frozen=True)
class RouteConfig:
    """Settings of :func:`identify_until_robust`: excitation in steps of ``step_s`` up to ``max_excitation_s``
    (multisine to ``band_high_hz`` with peak ``peak_fraction`` of the torque limit), and the stopping check:
    ``check_draws`` rods drawn ``uncertainty_scale`` standard deviations wide, each from ``check_starts``
    hanging starts of ``check_duration_s``."""

    step_s: float = 1.0
    max_excitation_s: float = 10.0
    peak_fraction: float = 0.8
    band_high_hz: float = 6.0
    check_draws: int = 8
    check_starts: int = 2
    check_duration_s: float = 8.0
    uncertainty_scale: float = 2.0

    def __post_init__(self) -> None:
        for name in ("step_s", "max_excitation_s", "peak_fraction", "band_high_hz", "check_duration_s"):
            positive(name, getattr(self, name))
        positive("uncertainty_scale", self.uncertainty_scale)
        for name in ("check_draws", "check_starts"):
            object.__setattr__(self, name, positive_int(name, getattr(self, name)))
        if self.peak_fraction > 1:
            raise ValueError(f"peak_fraction must be at most 1 (of the torque limit), got {self.peak_fraction!r}")
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


def excitation_protocol(
    seconds: float,
    dt_s: float,
    config: RouteConfig,
    phi_noise_std_rad: float = 0.0,
    tip_noise_std_m: float = 0.0,
    program: str = "multisine",
) -> BabbleProtocol:
    """One hanging trial of the multisine (or another babbling ``program``), ``seconds`` long, no feedback, with
    encoder and camera noise."""
    return BabbleProtocol(
        n_trials=1,
        trial_length_s=seconds,
        dt_s=dt_s,
        start="hanging",
        start_angle_std_rad=0.05,
        start_rate_std_rad_s=0.1,
        feedback_trial_fraction=0.0,
        program=program,
        multisine_peak_fraction=config.peak_fraction,
        torque_bandwidth_hz=config.band_high_hz,
        phi_noise_std_rad=phi_noise_std_rad,
        tip_noise_std_m=tip_noise_std_m,
    )


def simulated_recorder(
    task: Task,
    config: RouteConfig,
    seed: int,
    phi_noise_std_rad: float = 0.002,
    tip_noise_std_m: float = 0.002,
    program: str = "multisine",
) -> Recorder:
    """A recorder of the babbling ``program`` on ``task``'s simulated plant with encoder and camera noise (the rod is
    ``task.rod``)."""

    def record(seconds: float) -> TrajectoryDataset:
        protocol = excitation_protocol(seconds, task.dt_s, config, phi_noise_std_rad, tip_noise_std_m, program).replace(
            substeps=task.substeps
        )
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
        summary = evaluate(
            controller,
            Task(rod=rod),
            seeds=[CHECK_SEED_BASE + seed * 1000 + i * config.check_starts + j for j in range(config.check_starts)],
            duration_s=config.check_duration_s,
            stop_at_first_failure=True,
        )
        if not all(math.isfinite(r.swing_up_time_s) and r.upright_std_rad <= HOLD_STD_RAD for r in summary.results):
            return False
    return True


def identify_until_robust(
    record: Recorder,
    guess: RodParams,
    config: Optional[RouteConfig] = None,
    seed: int = 0,
    dt_s: float = 0.01,
    identification: Optional[GreyBoxConfig] = None,
) -> RouteResult:
    """Excite for ``step_s``, ``2 step_s``, ... seconds, identify from ``guess`` each time, and stop at the first
    length whose controller balances every uncertainty draw (or at ``max_excitation_s``).

    ``seed`` seeds the identification's window draw, the uncertainty draws and the check's starts (hanging
    starts of the simulator, never the plant's).
    """
    config = config if config is not None else RouteConfig()
    identification = identification if identification is not None else GreyBoxConfig(seed=seed)
    steps: list[dict[str, float]] = []
    n_steps = max(int(math.floor(config.max_excitation_s / config.step_s + 1e-9)), 1)
    for k in range(1, n_steps + 1):
        seconds = k * config.step_s
        started = time.perf_counter()
        result = identify(record(seconds), identification, initial_params=guess)
        identified = time.perf_counter()
        controller = design_swingup(result.params, dt_s)
        draws = uncertainty_draws(result, config.check_draws, seed + k, config.uncertainty_scale)
        robust = _balances_every_draw(controller, [result.params] + draws, config, seed + k)
        relative = [result.std[n] / abs(v) for n, v in result.estimates.items() if v]
        steps.append(
            {
                "plant_s": seconds,
                "max_relative_std": float(max(relative)),
                "robust": float(robust),
                "identify_wall_s": identified - started,
                "check_wall_s": time.perf_counter() - identified,
            }
        )
        if robust or k == n_steps:
            return RouteResult(seconds, result, controller, robust, steps)
    raise AssertionError("unreachable")
