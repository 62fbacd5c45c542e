"""Figure 7's comparison (softpend.study.classical): every run from fresh starts, with Wilson intervals."""

from __future__ import annotations

import numpy as np
import pytest

from softpend.control.pid import PIDGains
from softpend.study.classical import classical_comparison, near_upright_starts, pid_gain_sensitivity
from softpend.study.presets import REPORT_SEEDS
from softpend.task import Task

STARTS = REPORT_SEEDS[:10]
GAINS = PIDGains(0.18, 0.0076, 0.0145)


def test_near_upright_starts_are_seeded_tilts_within_the_start_noise():
    task = Task()
    first = near_upright_starts(task, 0.3, STARTS)
    again = near_upright_starts(task, 0.3, STARTS)
    assert len(first) == len(STARTS)
    for (q, qd), (q2, qd2) in zip(first, again):
        assert np.array_equal(q, q2) and np.array_equal(qd, qd2) and not np.any(qd)
    hub = [q[0] for q, _ in first]
    reference = task.tilt_state(0.3)[0][0]
    assert len(set(hub)) == len(STARTS)  # a different start per seed
    assert all(abs(h - reference) <= task.start_noise_rad + 1e-12 for h in hub)


def test_every_run_is_evaluated_from_every_start_with_an_interval():
    comparison = classical_comparison(
        Task(), tilts_rad=(0.2,), duration_s=2.0, starts=STARTS, swingup_duration_s=3.0, pid_gains=GAINS
    )
    assert comparison.pid_gains == {"given": GAINS}
    labels = {row["controller"] for row in comparison.rows}
    assert {
        "LQR (true model)",
        "PID (tuned on given)",
        "PID (tuned on given), no limit",
        "energy swing-up + LQR",
    } <= labels
    for row in comparison.rows:
        assert row["seeds"] == len(STARTS)
        assert 0.0 <= row["success_low"] <= row["success_rate"] <= row["success_high"] + 1e-12 <= 1.0 + 1e-12
    assert [r.seed for r in comparison.near_upright["LQR (true model)"][0].results] == list(STARTS)
    assert comparison.row("LQR (true model)", "tilt 0.2 rad")["success_rate"] == 1.0
    assert comparison.row("LQR (true model)", "hanging")["success_rate"] == 0.0  # a local controller
    with pytest.raises(KeyError):
        comparison.row("LQR (true model)", "tilt 9 rad")
    with pytest.raises(ValueError, match="starts"):
        classical_comparison(Task(), starts=(), pid_gains=GAINS)


def test_pid_gain_sensitivity_scales_every_gain():
    rows = pid_gain_sensitivity(Task(), GAINS, scales=(0.01, 1.0), tilt_rad=0.2, starts=STARTS, duration_s=2.0)
    assert [row["gain_scale"] for row in rows] == [0.01, 1.0]
    assert rows[0]["success_rate"] < rows[1]["success_rate"]  # a hundredth of the gains cannot hold the rod
    with pytest.raises(ValueError, match="scales"):
        pid_gain_sensitivity(Task(), GAINS, scales=(0.0,), starts=STARTS)
