"""The grey-box route: its plant seconds are the seconds it excited, and the controller it designs balances the rod
it identified (its uncertainty draws are tested in tests/test_commission.py)."""

import math

import numpy as np
import pytest

from softpend.control.identified import (
    RouteConfig,
    identify_until_robust,
    simulated_recorder,
)
from softpend.evaluation import evaluate
from softpend.plant import RodParams
from softpend.task import Task


def test_the_route_counts_the_seconds_its_plant_was_driven_and_its_controller_balances():
    task = Task()
    config = RouteConfig(step_s=0.5, max_excitation_s=1.0, check_draws=1, check_starts=1, check_duration_s=5.0)
    recorder = simulated_recorder(task, config, seed=1)
    driven: list[float] = []

    def record(seconds):
        data = recorder(seconds)
        driven.append(data.n_trials * data.n_samples * data.dt_s)  # one plant step per stored sample
        return data

    route = identify_until_robust(
        record, RodParams(hub_friction_nms_per_rad=0.5 * RodParams().hub_friction_nms_per_rad), config, seed=1
    )
    assert route.plant_s == pytest.approx(driven[-1], abs=1e-9)
    assert route.plant_s == len(route.steps) * 0.5 and len(route.steps) == len(driven)
    assert [s["plant_s"] for s in route.steps] == [0.5 * (k + 1) for k in range(len(route.steps))]
    summary = evaluate(route.controller, task, seeds=(20_000,), duration_s=6.0)
    assert math.isfinite(summary.results[0].swing_up_time_s) and summary.results[0].upright_std_rad < 0.1


@pytest.mark.parametrize("program", ["noise", "multisine"])
def test_the_recorder_drives_the_program_it_is_given_within_the_torque_limit(program):
    task = Task()
    data = simulated_recorder(task, RouteConfig(), seed=3, program=program)(2.0)
    torques = data.torques_nm[0]
    assert 0.2 * task.torque_limit_nm < np.max(np.abs(torques)) <= task.torque_limit_nm
    spectrum = np.abs(np.fft.rfft(torques - torques.mean()))
    frequencies = np.fft.rfftfreq(len(torques), data.dt_s)
    in_band = spectrum[(frequencies > 0) & (frequencies <= RouteConfig().band_high_hz)] ** 2
    power_in_band = in_band.sum() / (spectrum[frequencies > 0] ** 2).sum()  # a fraction of the torque's power
    # the multisine puts its power in its band (but for the leakage of a 2 s record); random torque spreads it wider
    assert power_in_band > 0.9 if program == "multisine" else power_in_band < 0.7


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(step_s=0.0), "step_s"),
        (dict(step_s=2.0, max_excitation_s=1.0), "step_s"),
        (dict(peak_fraction=1.5), "peak_fraction"),
        (dict(check_draws=0), "check_draws"),
    ],
)
def test_route_settings_are_checked_by_name(kwargs, name):
    with pytest.raises(ValueError, match=name):
        RouteConfig(**kwargs)
