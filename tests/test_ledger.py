"""The claims ledger (softpend.study.ledger): glued values read back, rows that say when evidence is missing,
verdicts from evidence, and the Markdown table."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import nbformat
import numpy as np

from softpend.evaluation import EvaluationSummary
from softpend.study.ledger import (
    NOT_COMPUTED,
    VERDICTS,
    LedgerRow,
    claims_ledger,
    glued_values,
    ledger_markdown,
    over_seeds,
    verdict_counts,
)


def glue_output(name: str, text: str) -> dict:
    return nbformat.v4.new_output(
        "display_data",
        data={"application/papermill.record/text/plain": text},
        metadata={"scrapbook": {"name": name, "mime_prefix": "application/papermill.record/"}},
    )


def test_glued_values_reads_numbers_strings_and_numpy_scalars_back(tmp_path):
    nb = nbformat.v4.new_notebook()
    cell = nbformat.v4.new_code_cell("glue(...)")
    cell.outputs = [
        glue_output("mse", "3.1e-09"),
        glue_output("text", "'100% of 10 starts'"),
        glue_output("flag", "True"),
        glue_output("numpy", "np.float64(0.25)"),
        glue_output("never", "inf"),
        nbformat.v4.new_output("stream", text="not glued"),
    ]
    nb.cells = [cell]
    path = tmp_path / "x.ipynb"
    nbformat.write(nb, str(path))
    assert glued_values(path) == {
        "mse": 3.1e-9,
        "text": "100% of 10 starts",
        "flag": True,
        "numpy": 0.25,
        "never": math.inf,
    }
    assert glued_values(tmp_path / "missing.ipynb") == {}


def test_without_evidence_every_row_says_not_computed():
    rows = claims_ledger({}, {}, {}, [])
    assert len(rows) >= 11 and len({row.key for row in rows}) == len(rows)
    assert all(row.verdict == NOT_COMPUTED and row.ours.startswith(NOT_COMPUTED) for row in rows), rows
    assert verdict_counts(rows)[NOT_COMPUTED] == len(rows)
    assert set(verdict_counts(rows)) == set(VERDICTS)


@dataclass
class Start:
    swing_up_time_s: float
    upright_std_rad: float
    diverged: Optional[str] = None


def summary(times, stds) -> EvaluationSummary:
    return EvaluationSummary("agent", [Start(t, s) for t, s in zip(times, stds)])


def fig07(**runs) -> dict:
    """Glued values of Figure 7: key -> (rate, low, high)."""
    values = {
        "near_tilt_rad": 0.2,
        "far_tilt_rad": 0.8,
        "pid_scales_failing": "0.5",
        "pid_scales_tried": "0.5, 1, 2",
        "pid_sensitive_near_one": False,
    }
    for key, (rate, low, high) in runs.items():
        values.update(
            {
                f"{key}_rate": rate,
                f"{key}_low": low,
                f"{key}_high": high,
                f"{key}_starts": 20,
                f"{key}_time_s": 0.1,
                f"{key}_text": f"{rate:.0%} of 20 starts",
            }
        )
    return values


def test_verdicts_follow_the_evidence():
    glued = {
        "fig03_sysid": {"one_step_mse_full": 3.5e-9, "one_step_mse_limited": 1e-8, "n_test_trials": 12},
        "fig07_classical": fig07(
            lqr_near=(1.0, 0.84, 1.0),
            lqr_far=(0.0, 0.0, 0.16),
            lqr_hanging=(0.0, 0.0, 0.16),
            lqr_learned_near=(0.9, 0.7, 0.97),
            pid_true_near=(1.0, 0.84, 1.0),
            pid_learned_near=(0.0, 0.0, 0.16),
            pid_true_nolimit_far=(1.0, 0.84, 1.0),
        ),
    }
    held = [summary([2.0, 3.0, 2.5], [0.05, 0.1, 0.15])] * 2  # every start held within 0.2 rad
    slower = [summary([4.0, 5.0, 4.5], [0.05, 0.1, 0.15])] * 2
    fresh = {"model-free DQN": held, "DQN-MBPO": slower}
    rows = {row.key: row for row in claims_ledger(glued, {}, fresh, [])}
    assert rows["sysid_mse"].verdict == "reproduced" and "3.5e-09" in rows["sysid_mse"].ours
    assert rows["mf_holds"].verdict == rows["mb_holds"].verdict == "reproduced"
    assert rows["mb_matches_mf"].verdict == "reproduced"
    assert rows["mf_faster"].verdict == "reproduced" and rows["mf_steady"].verdict == "reproduced"
    assert rows["lqr_far"].verdict == "reproduced"
    assert rows["lqr_model"].verdict == "differs"  # the learned-model LQR is not clearly worse
    assert rows["pid_learned"].verdict == "differs" and rows["pid_fast"].verdict == "not comparable"
    assert rows["pid_sensitive"].verdict == "differs"
    # a machine figure, measured by `softpend bench`, never by the book (its numbers repeat on every build)
    assert rows["tracker_real_time"].verdict == NOT_COMPUTED and "softpend bench" in rows["tracker_real_time"].ours
    assert rows["mf_asymptote"].verdict == NOT_COMPUTED  # no training logs given

    # a method that does not hold: the rows that need it differ
    fresh = {"model-free DQN": held, "DQN-MBPO": [summary([math.inf] * 3, [2.0] * 3)] * 2}
    rows = {row.key: row for row in claims_ledger(glued, {}, fresh, [])}
    assert rows["mb_holds"].verdict == "differs" and rows["mb_matches_mf"].verdict == "differs"
    assert "median 0 %" in rows["mb_holds"].ours and "over 2 seeds" in rows["mb_holds"].ours


def test_over_seeds_and_markdown():
    assert over_seeds([], "s") == NOT_COMPUTED
    assert over_seeds([3.0], "s") == "3 s (1 seed)"
    assert over_seeds([math.inf], "s") == "never (1 seed)"
    text = over_seeds([1.0, 2.0, 3.0, 4.0], "h")
    assert text.startswith("median 2.5 h (95 % interval") and text.endswith("over 4 seeds)")
    row = LedgerRow("k", "a | b", "c", "d", "reproduced", "fig03-sysid")
    table = ledger_markdown([row], {"fig03-sysid": "Figure 3"})
    assert "a \\| b" in table and "{ref}`Figure 3 <fig03-sysid>`" in table and "**reproduced**" in table


def training_log(algo: str, seed: int, returns, stop_reason: Optional[str] = None, episode_s: float = 20.0):
    from softpend.rl.training_log import TrainingLog

    episodes = [
        {"episode": k + 1, "return": float(r), "plant_s": episode_s * (k + 1), "model_steps": 0}
        for k, r in enumerate(returns)
    ]
    return TrainingLog(algo=algo, seed=seed, episodes=episodes, stop_reason=stop_reason)


def test_a_run_that_stopped_balanced_reaches_its_asymptote_at_the_stop():
    from softpend.study.ledger import run_to_asymptote

    # a short run cut by the stop rule as its return rises (DQN-MBPO stops after a few episodes): its curve has no
    # tail to read an asymptote from, and the curve reading alone says it never gets there
    rising = [-50.0, -50.0, -40.0, -50.0, -30.0, 100.0, 300.0, 400.0]
    stopped = training_log("mbpo", 0, rising, stop_reason="balanced in an evaluation (upright std <= 0.1 rad ...)")
    assert run_to_asymptote(stopped) == (8.0, 8 * 20.0)
    # the same curve at the end of its budget (no stop): still rising, so its asymptote is not reached
    assert run_to_asymptote(training_log("mbpo", 0, rising)) == (math.inf, math.inf)
    # a run that levelled off before its budget ended: the curve reading
    plateau = np.concatenate([np.linspace(-50.0, 400.0, 100), np.full(100, 400.0)])
    episodes, plant_s = run_to_asymptote(training_log("dqn", 0, plateau))
    assert 80 <= episodes <= 110 and plant_s == episodes * 20.0

    # ten DQN-MBPO runs that all stopped balanced after 8 to 12 episodes: the ledger says when, not "never"
    logs = {
        "DQN-MBPO": [
            training_log("mbpo", seed, rising + [400.0] * (seed % 5), stop_reason="balanced") for seed in range(10)
        ],
        "model-free DQN": [training_log("dqn", seed, plateau, episode_s=100.0) for seed in range(10)],
    }
    rows = {row.key: row for row in claims_ledger({}, logs, {}, [])}
    mb = rows["mb_asymptote"]
    assert "never" not in mb.ours, mb.ours
    assert mb.ours.startswith("median 10 episodes") and "10 of 10 runs stopped balanced" in mb.ours, mb.ours
    assert mb.verdict == "differs"  # 10 episodes against the report's 100
    fewer = rows["mb_fewer"]
    assert fewer.verdict == "reproduced" and "never" not in fewer.ours, fewer.ours


def test_the_closer_to_pilco_row_compares_the_grey_box_route_with_pilco():
    def glued(greybox_s, balanced):
        values = {"median_pilco": 20.0, "seeds_balanced_pilco": 10, "seeds_pilco": 10}
        values.update({"median_mbpo": 130.0, "seeds_balanced_mbpo": 10, "seeds_mbpo": 10})
        values.update({"median_greybox": greybox_s, "seeds_balanced_greybox": balanced, "seeds_greybox": 10})
        return {"data_efficiency": values}

    row = {r.key: r for r in claims_ledger(glued(1.0, 10), {}, {}, [])}["closer_to_pilco"]
    assert row.verdict == "reproduced" and "grey-box route 1" in row.ours and "10 of 10 seeds" in row.ours
    assert {r.key: r for r in claims_ledger(glued(40.0, 10), {}, {}, [])}["closer_to_pilco"].verdict == "differs"
    assert {r.key: r for r in claims_ledger(glued(1.0, 8), {}, {}, [])}["closer_to_pilco"].verdict == "differs"
