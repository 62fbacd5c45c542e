"""The claims ledger: each claim of the report beside what the book's notebooks and run folders measured, with a
verdict; nothing here trains."""

from __future__ import annotations

import ast
import math
import re
from functools import partial
from pathlib import Path
from typing import Any, Callable, Mapping, NamedTuple, Optional, Sequence

import numpy as np

from softpend.rl.curves import run_to_asymptote
from softpend.study.fresh_starts import BALANCED_FRACTION, _refuse_selection_starts, held_starts
from softpend.study.rl_runs import METHOD_NAMES, load_runs

NOT_COMPUTED = "not computed in this build"
VERDICTS = ("reproduced", "differs", "not comparable", NOT_COMPUTED)
#: A number of the report counts as reproduced within this factor (either way) [-].
FACTOR = 1.5
#: Upright standard deviation the report quotes after swing-up [rad].
REPORT_HOLD_STD_RAD = 0.2
#: Largest difference of the held shares of two methods that counts as "near-identical" [-].
SAME_SHARE = 0.1


class LedgerRow(NamedTuple):
    """One claim (glued as ``verdict_<key>``): the report's words and figure, ours, the verdict and its chapter."""

    key: str
    claim: str
    report: str
    ours: str
    verdict: str
    chapter: str


# ----------------------------------------------------------------------------- reading the evidence
_NUMPY_SCALAR = re.compile(r"^np\.(?:float|int|bool_?)\w*\((.*)\)$")


def _parse_glued(text: str) -> Any:
    """The Python value of a glued ``text/plain`` repr; the text itself when it is not a literal."""
    text = text.strip()
    if match := _NUMPY_SCALAR.match(text):
        text = match.group(1)
    if text in ("inf", "-inf", "nan"):
        return float(text)
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError, MemoryError, RecursionError):
        return text


def glued_values(notebook_path: Path | str) -> dict[str, Any]:
    """The values glued as text in an executed notebook (``{name: value}``); empty when the file is missing."""
    import nbformat

    cells = nbformat.read(str(notebook_path), as_version=4).cells if Path(notebook_path).is_file() else []
    outputs = [(o, o.get("metadata", {}).get("scrapbook") or {}) for cell in cells for o in cell.get("outputs", [])]
    texts = [
        (s["name"], o.get("data", {}).get(f"{s.get('mime_prefix', '')}text/plain")) for o, s in outputs if "name" in s
    ]
    return {name: _parse_glued(text) for name, text in texts if text is not None}


def rl_run_logs(runs_root: Path | str, seeds: Sequence[int], plant: str = "prb") -> dict[str, list[Any]]:
    """``{method name: [TrainingLog of each seed whose run folder holds one]}`` of the RL runs of Figures 4-6."""
    from softpend.rl.training_log import TrainingLog

    load = lambda folder, seed: TrainingLog.load(folder / "log.json")  # noqa: E731
    return {method: load_runs(runs_root, plant, algo, seeds, load) for algo, method in METHOD_NAMES.items()}


def rl_fresh_start_summaries(
    runs_root: Path | str,
    seeds: Sequence[int],
    report_seeds: Sequence[int],
    duration_s: float = 10.0,
    plant: str = "prb",
    which: str = "best",
) -> dict[str, list[Any]]:
    """``{method name: [EvaluationSummary per seed]}`` of each run's agent (``which``) on the fresh starts
    ``report_seeds``; ``ValueError`` if a report seed selected a run's agents."""
    from softpend.rl.dqn import evaluate_agent, load_agent

    summaries: dict[str, list[Any]] = {}
    starts, load = tuple(int(s) for s in report_seeds), lambda folder, seed: (seed, *load_agent(folder, which))
    for algo, method in METHOD_NAMES.items():
        summaries[method] = []
        for seed, model, config in load_runs(runs_root, plant, algo, seeds, load):
            _refuse_selection_starts(report_seeds, config.selection_seeds, f"the agents of {algo} seed {seed}")
            name = f"{method} seed {seed}"
            summaries[method].append(evaluate_agent(model, config, seeds=starts, duration_s=duration_s, name=name))
    return summaries


def pilco_run_results(runs_root: Path | str, seeds: Sequence[int], plant: str = "prb") -> list[Any]:
    """The PILCO runs of Figure 10 that exist, as ``PilcoResult`` objects."""
    from softpend.pilco.loop import PilcoResult

    return load_runs(runs_root, plant, "pilco", seeds, lambda folder, seed: PilcoResult.load(folder))


# ----------------------------------------------------------------------------- figures over seeds
def _number(value: float, digits: int = 2) -> str:
    if math.isinf(value):
        return "never" if value > 0 else "-inf"
    return f"{value:.{digits}g}" if abs(value) < 10**digits else f"{value:.0f}"


def _seconds(value: float, unit: str = "s", scale: float = 1.0) -> str:
    return "never" if math.isinf(value) else f"{_number(value / scale)} {unit}"


def over_seeds(values: Sequence[float], unit: str = "", fmt: Callable[[float], str] = _number) -> str:
    """``"median M (95 % interval L-H over n seeds)"``, one value with ``"(1 seed)"``, none: :data:`NOT_COMPUTED`;
    ``inf`` (never got there) counts as the largest value."""
    from softpend.stats import aggregate_interval

    values = [float(v) for v in values if not math.isnan(float(v))]
    text = lambda v: f"{fmt(v)} {unit}" if unit and not math.isinf(v) else fmt(v)  # noqa: E731 -- "never": no unit
    if not values:
        return NOT_COMPUTED
    if len(values) == 1:
        return f"{text(values[0])} (1 seed)"
    interval = aggregate_interval(values, "median")
    return (
        f"median {text(interval.value)} (95 % interval {fmt(interval.low)}-{text(interval.high)} "
        f"over {len(values)} seeds)"
    )


def _median(values: Sequence[float]) -> float:
    return float(np.median(values)) if len(values) else math.nan


def _per_method_median(fresh: Mapping[str, Sequence[Any]], figure: Callable[[Any], float]) -> Optional[dict]:
    """``{algo: median over a method's runs of figure(run)}`` for both RL methods; None if one has no runs."""
    if not all(fresh.get(method) for method in METHOD_NAMES.values()):
        return None
    return {algo: _median([figure(s) for s in fresh[method]]) for algo, method in METHOD_NAMES.items()}


def _to_asymptote(logs: Sequence[Any]) -> tuple[list[float], list[float], int]:
    """Episodes and plant seconds to the asymptote of each run, and how many runs stopped balanced."""
    pairs = [run_to_asymptote(log) for log in logs]
    return [p[0] for p in pairs], [p[1] for p in pairs], sum(log.stop_reason is not None for log in logs)


# ----------------------------------------------------------------------------- the claims
# Each claim's figures: None without evidence, else ``(ours, verdict)`` (a bool verdict: reproduced or differs).
Found = Optional[tuple[str, Any]]


class _Evidence(NamedTuple):
    glued: Mapping[str, Mapping[str, Any]]
    logs: Mapping[str, Sequence[Any]]
    fresh: Mapping[str, Sequence[Any]]
    pilco: Sequence[Any]


def _sysid(e: _Evidence) -> Found:
    # reproduced: our held-out one-step MSE within FACTOR of the report's 3e-9
    fig03 = e.glued.get("fig03_sysid", {})
    full, limited, trials = (fig03.get(k) for k in ("one_step_mse_full", "one_step_mse_limited", "n_test_trials"))
    if not isinstance(full, (int, float)):
        return None
    ours = f"{full:.2g} (full information), " + (f"{limited:.2g} (limited)" if isinstance(limited, float | int) else "")
    ours += f"; 1 seed, {trials} held-out trials" if trials is not None else "; 1 seed"
    return ours, 3e-9 / FACTOR <= full <= 3e-9 * FACTOR


def _asymptote(algo: str, episodes: float, hours: float, e: _Evidence) -> Found:
    # reproduced: the median episodes and plant time to the asymptote within FACTOR of the report's
    if not (runs := list(e.logs.get(METHOD_NAMES[algo], []))):
        return None
    to_asymptote, plant_s, stopped = _to_asymptote(runs)
    plant_h = [value / 3600.0 for value in plant_s]
    ours = (
        f"{over_seeds(to_asymptote, 'episodes')}; {over_seeds(plant_h, 'h of plant time')}; "
        f"{stopped} of {len(runs)} runs stopped balanced"
        + (" (a stopped run reaches its asymptote at the stop episode)" if stopped else "")
        + f", median {_median([log.n_episodes for log in runs]):.0f} episodes trained"
    )
    ok = episodes / FACTOR <= _median(to_asymptote) <= episodes * FACTOR
    return ours, ok and hours / FACTOR <= _median(plant_h) <= hours * FACTOR


def _fewer_episodes(e: _Evidence) -> Found:
    # reproduced: DQN-MBPO's median plant time to the asymptote below model-free DQN's
    if not all(e.logs.get(method) for method in METHOD_NAMES.values()):
        return None
    (mb_episodes, mb_s), (mf_episodes, mf_s) = (
        map(_median, _to_asymptote(list(e.logs[METHOD_NAMES[algo]]))[:2]) for algo in ("mbpo", "dqn")
    )
    hours = partial(_seconds, unit="h", scale=3600.0)
    ours = (
        f"plant time to the asymptote (median over seeds): DQN-MBPO {hours(mb_s)} ({_number(mb_episodes)} episodes), "
        f"DQN {hours(mf_s)} ({_number(mf_episodes)} episodes)"
    )
    return ours, mb_s < mf_s


def _holds(algo: str, e: _Evidence) -> Found:
    # reproduced: the median over runs of the share of fresh starts held within std_rad is at least BALANCED_FRACTION
    from softpend.stats import wilson_interval

    if not (summaries := list(e.fresh.get(METHOD_NAMES[algo], []))):
        return None
    held = [held_starts(s, REPORT_HOLD_STD_RAD) for s in summaries]
    shares = [float(np.mean(h)) for h in held]
    if len(held) == 1:
        k, n = int(sum(held[0])), len(held[0])
        low, high = wilson_interval(k, n)
        share = f"{k} of {n} starts ({100 * low:.0f}-{100 * high:.0f} %)"
        ours = f"{METHOD_NAMES[algo]}: held {share} within {REPORT_HOLD_STD_RAD:g} rad (1 seed)"
    else:
        ours = (
            f"{METHOD_NAMES[algo]}: share of {len(held[0])} fresh starts held within {REPORT_HOLD_STD_RAD:g} rad, "
            + over_seeds(shares, fmt=lambda v: f"{100 * v:.0f} %")
        )
    return ours, _median(shares) >= BALANCED_FRACTION


def _steady(e: _Evidence) -> Found:
    # reproduced: model-free DQN's median swing-up time on fresh starts (median over runs) at most 10 s
    if not (summaries := list(e.fresh.get(METHOD_NAMES["dqn"], []))):
        return None
    times = [s.median("swing_up_time_s") for s in summaries]
    return f"model-free DQN, swing-up time on fresh starts: {over_seeds(times, 's')}", _median(times) <= 10.0


def _same_final(e: _Evidence) -> Found:
    # reproduced: both methods hold (as in _holds) and their median shares differ by at most SAME_SHARE
    if (shares := _per_method_median(e.fresh, lambda s: float(np.mean(held_starts(s, REPORT_HOLD_STD_RAD))))) is None:
        return None
    ours = (
        f"share of fresh starts held within {REPORT_HOLD_STD_RAD:g} rad (median over seeds): "
        f"DQN-MBPO {100 * shares['mbpo']:.0f} %, DQN {100 * shares['dqn']:.0f} %"
    )
    return ours, min(shares.values()) >= BALANCED_FRACTION and abs(shares["mbpo"] - shares["dqn"]) <= SAME_SHARE


def _faster(e: _Evidence) -> Found:
    # reproduced: model-free DQN's median swing-up time (median over runs) below DQN-MBPO's
    if (times := _per_method_median(e.fresh, lambda s: s.median("swing_up_time_s"))) is None:
        return None
    ours = f"median swing-up time on fresh starts: DQN {_seconds(times['dqn'])}, DQN-MBPO {_seconds(times['mbpo'])}"
    return ours, times["dqn"] < times["mbpo"]


def _fig07(e: _Evidence, *keys: str) -> tuple[Mapping[str, Any], list[Optional[dict[str, Any]]]]:
    """Figure 7's glued values and each run ``keys`` names: ``{rate, low, high, starts, time_s, text}`` or None."""
    values = e.glued.get("fig07_classical", {})
    runs: list[Optional[dict[str, Any]]] = []
    for key in keys:
        found = {name: values.get(f"{key}_{name}") for name in ("rate", "low", "high", "starts", "time_s")}
        ok = all(isinstance(value, (int, float)) for value in found.values())
        runs.append(found | {"text": values.get(f"{key}_text")} if ok else None)
    return values, runs


def _lqr_far(e: _Evidence) -> Found:
    # reproduced: >= 90 % of near-upright starts balance, <= 10 % from hanging
    values, (near, far, hanging) = _fig07(e, "lqr_near", "lqr_far", "lqr_hanging")
    if near is None or hanging is None:
        return None
    near_tilt, far_tilt = values.get("near_tilt_rad"), values.get("far_tilt_rad")
    ours = f"LQR (true model) balances {near['text']} from {near_tilt:g} rad"
    if far is not None and far_tilt != near_tilt:
        ours += f", {far['text']} from {far_tilt:g} rad"
    ours += f" and {hanging['text']} from hanging"
    return ours, near["rate"] >= BALANCED_FRACTION and hanging["rate"] <= 1 - BALANCED_FRACTION


def _lqr_model(e: _Evidence) -> Found:
    # reproduced: the learned-model LQR balances fewer near-upright starts (the Wilson intervals do not overlap)
    values, (near, learned) = _fig07(e, "lqr_near", "lqr_learned_near")
    if near is None or learned is None:
        text = values.get("lqr_learned_near_text")
        return None if text is None else (f"LQR on the learned model: {text}", NOT_COMPUTED)
    ours = f"from {values.get('near_tilt_rad'):g} rad: LQR on the true model {near['text']}, on the learned model "
    return ours + learned["text"], learned["high"] < near["low"]


def _pid_learned(e: _Evidence) -> Found:
    # reproduced: PID tuned on the learned model balances >= 50 % of the near-upright starts with the limit
    values, (learned, true) = _fig07(e, "pid_learned_near", "pid_true_near")
    if learned is None or true is None:
        return None
    ours = (
        f"from {values.get('near_tilt_rad'):g} rad with the torque limit: tuned on the learned model "
        f"{learned['text']}, tuned on the true plant {true['text']}"
    )
    return ours, learned["rate"] >= 0.5


def _pid_fast(e: _Evidence) -> Found:
    # not comparable: the starts differ (near upright against hanging)
    values, (fast,) = _fig07(e, "pid_true_nolimit_far")
    if fast is None:
        return None
    ours = (
        f"PID (true-plant gains) without a torque limit from {values.get('far_tilt_rad'):g} rad: {fast['text']}, "
        f"median time to upright {_seconds(fast['time_s'])}; the RL agents start from hanging"
    )
    return ours, "not comparable"


def _pid_sensitive(e: _Evidence) -> Found:
    # reproduced: scaling the gains within 0.8-1.25 leaves the success interval below one half
    values = e.glued.get("fig07_classical", {})
    failing, tried = values.get("pid_scales_failing"), values.get("pid_scales_tried")
    if failing is None or tried is None or not isinstance(sensitive := values.get("pid_sensitive_near_one"), bool):
        return None
    return f"gains scaled by {tried}: fails (success interval below one half) at the factors {failing}", sensitive


def _pilco(e: _Evidence) -> Found:
    # not comparable: the report quotes PILCO on the cart double pendulum, not on its rod
    if not e.pilco:
        return None
    seconds = [r.real_seconds_to_balance for r in e.pilco]
    balanced = sum(math.isfinite(s) for s in seconds)
    ours = f"PILCO on our rod, plant seconds to balance: {over_seeds(seconds, 's')}; {balanced} of {len(seconds)} runs balanced"
    return ours, "not comparable"


def _closer_to_pilco(e: _Evidence) -> Found:
    # reproduced when a route of this project needs at most PILCO's median plant seconds on >= 9 of 10 seeds
    values = e.glued.get("data_efficiency", {})
    needed = [f"{kind}_{key}" for key in ("greybox", "pilco", "mbpo") for kind in ("median", "seeds_balanced", "seeds")]
    if any(not isinstance(values.get(name), (int, float)) for name in needed):
        return None
    median = {key: float(values[f"median_{key}"]) for key in ("greybox", "pilco", "mbpo")}
    share = {key: (int(values[f"seeds_balanced_{key}"]), int(values[f"seeds_{key}"])) for key in median}
    ours = "median plant seconds to balance: " + ", ".join(
        f"{name} {_seconds(median[key])} ({share[key][0]} of {share[key][1]} seeds)"
        for key, name in (("greybox", "grey-box route"), ("pilco", "PILCO"), ("mbpo", "DQN-MBPO"))
    )
    balanced, seeds = share["greybox"]
    return ours, seeds > 0 and balanced >= 0.9 * seeds and median["greybox"] <= median["pilco"]


def _tracker(e: _Evidence) -> Found:
    # the tracker's speed is a machine figure, measured by `softpend bench --only hardware`, not by the book
    return f"{NOT_COMPUTED}: a property of the machine, measured by `softpend bench --only hardware`", NOT_COMPUTED


#: The report's claims in its order: key -> (its figure, the label of the chapter that explains it, what measures ours).
CLAIMS: dict[str, tuple[str, str, Callable[[_Evidence], Found]]] = {
    "sysid_mse": ("≈ 3e-9", "fig03-sysid", _sysid),
    "mf_asymptote": ("≈ 150 episodes, ≈ 4 h", "fig-learning-curves", partial(_asymptote, "dqn", 150, 4.0)),
    "mb_asymptote": ("≈ 100 episodes, 2 h 45 min", "fig-learning-curves", partial(_asymptote, "mbpo", 100, 2.75)),
    "mf_holds": ("std 0.2 rad", "fig-upright-error", partial(_holds, "dqn")),
    "mb_holds": ("std 0.2 rad", "fig-upright-error", partial(_holds, "mbpo")),
    "mf_steady": ("≈ 10 s", "fig-swingup", _steady),
    "mb_matches_mf": ("near-identical", "fig-upright-error", _same_final),
    "mf_faster": ("model-free slightly faster", "fig-upright-error", _faster),
    "lqr_far": ("a start near upright (Figure 7)", "fig07-classical", _lqr_far),
    "lqr_model": ("no figure", "fig07-classical", _lqr_model),
    "pid_learned": ("some success (Figure 7)", "fig07-classical", _pid_learned),
    "pid_fast": ("quicker than RL (Figure 7)", "fig07-classical", _pid_fast),
    "pid_sensitive": ("no figure", "fig07-classical", _pid_sensitive),
    "mb_fewer": ("≈ 100 against ≈ 150 episodes", "fig-learning-curves", _fewer_episodes),
    "pilco_90s": ("< 90 s (literature, cart double pendulum)", "fig-pilco", _pilco),
    "closer_to_pilco": ("a hope (no figure)", "data-efficiency", _closer_to_pilco),
    "tracker_real_time": ("real time (no figure)", "fig09-rig", _tracker),
}
#: The report's words of each claim.
WORDS = {
    "sysid_mse": "By minimizing the mean squared error (MSE) between the predicted next state and the actual next state the network achieved an error of ≈ 3e-9.",
    "mf_asymptote": "The model-free controller proved to successfully balance the pole reaching the asymptotic reward in approximately 150 episodes of training, equivalent to around 4 hours of simulated time.",
    "mb_asymptote": "The agent reached asymptotic performance in approximately 100 episodes of training as seen by the orange line in Figure 4 (2 hours 45 minutes of simulated time).",
    "mf_holds": "After swinging up the rod remained within a standard deviation of 0.2 radians from the upright position for an arbitrary time.",
    "mb_holds": "The final performance is near-identical to the performance of the model-free controller, reaching a standard deviation of 0.2 radians from the upright position.",
    "mf_steady": "Typically the pendulum will reach steady state oscillatory behavior after 10 seconds.",
    "mb_matches_mf": "As seen in Figure 6, the final performance is near-identical to the performance of the model-free controller.",
    "mf_faster": "Time-averaging smooths rapid changes in error, thereby masking small differences in the swingup velocity, where the model free-controller shows a slight advantage.",
    "lqr_far": "For this method, the pendulum starts closer to the final position as convergance becomes more difficult as the distance from the target increases for a nonlinear system.",
    "lqr_model": "It requires a full state-space model of the system (matrices A, B, C, D) so it will not perform simply with observed data of motor babbling with a physical system.",
    "pid_learned": "PID parameters could be optimized for the model obtained from system identification and then applied to the real system. This enabled testing on the actual system to be avoided, whilst still yielding reasonable results, albeit to a limited degree.",
    "pid_fast": "A very high torque limit was given to the controller meaning it naturally moved the pendulum upright much quicker than the reinforcement-based methods.",
    "pid_sensitive": "Adding more links to the system increases the overall complexity making PID control hypersensitive to its parameters.",
    "mb_fewer": "The model-based approach successfully converged its performance in fewer episodes than model-free RL.",
    "pilco_90s": "PILCO took less than 90 seconds of real experience to learn to stabilize the double pendulum cart model, with computation time between trials.",
    "closer_to_pilco": "While our method requires more time on the system, there is potential to reach values closer to this.",
    "tracker_real_time": "This was implemented on a raspberry pi module to remove possible sources of lag.",
}


def claims_ledger(
    glued: Mapping[str, Mapping[str, Any]],
    rl_logs: Mapping[str, Sequence[Any]],
    rl_fresh: Mapping[str, Sequence[Any]],
    pilco: Sequence[Any],
) -> list[LedgerRow]:
    """One row per claim of :data:`CLAIMS`, from ``{notebook: glued_values(...)}``, :func:`rl_run_logs`,
    :func:`rl_fresh_start_summaries` and :func:`pilco_run_results`."""
    evidence = _Evidence(glued, rl_logs, rl_fresh, pilco)
    rows = []
    for key, (report, chapter, measure) in CLAIMS.items():
        ours, verdict = measure(evidence) or (NOT_COMPUTED, NOT_COMPUTED)
        verdict = verdict if isinstance(verdict, str) else ("reproduced" if verdict else "differs")
        rows.append(LedgerRow(key, WORDS[key], report, ours, verdict, chapter))
    return rows


def verdict_counts(rows: Sequence[LedgerRow]) -> dict[str, int]:
    """How many rows have each verdict of :data:`VERDICTS`."""
    return {verdict: sum(row.verdict == verdict for row in rows) for verdict in VERDICTS}


def ledger_markdown(rows: Sequence[LedgerRow], chapter_titles: Optional[Mapping[str, str]] = None) -> str:
    """The ledger as a MyST Markdown table, chapters linked with ``{ref}`` (``chapter_titles``: link texts)."""
    cell = lambda text: str(text).replace("|", "\\|").replace("\n", " ")  # noqa: E731
    lines = ["| claim (the report's words) | the report | ours | verdict | chapter |", "|---|---|---|---|---|"]
    for row in rows:
        link = f"{{ref}}`{cell((chapter_titles or {}).get(row.chapter, row.chapter))} <{row.chapter}>`"
        lines.append(f"| {cell(row.claim)} | {cell(row.report)} | {cell(row.ours)} | **{row.verdict}** | {link} |")
    return "\n".join(lines)
