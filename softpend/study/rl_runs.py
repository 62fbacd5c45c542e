"""The book's multi-seed RL runs, cached in run folders ``<root>/<algo>-<hash>-seed<k>``: a finished run is reused,
a shorter one resumed."""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

from softpend.evaluation import SUCCESS_STD_RAD
from softpend.io.overrides import apply_overrides
from softpend.io.runfolders import run_folder_name
from softpend.plant import check_plant_name
from softpend.rl.config import DQNConfig, load_config, saved_config_data
from softpend.rl.curves import run_to_asymptote
from softpend.rl.training_log import TrainingLog
from softpend.study.presets import TASK, load_hparams
from softpend.study.sweep import run_jobs
from softpend.task import Task


def train_seeds(
    algo: str,
    config: DQNConfig,
    seeds: Sequence[int],
    episodes: int,
    root: Path | str = "runs/rl",
    progress: bool = True,
    workers: Optional[int] = None,
    backend: Optional[str] = None,
) -> list[TrainingLog]:
    """Train (or reuse) one run per seed, ``workers`` at a time; returns their logs in seed order."""
    return _train_runs([(algo, config, seeds, episodes)], root, progress, workers, backend)[0]


def _train_runs(
    specs: Sequence[tuple[str, DQNConfig, Sequence[int], int]],
    root: Path | str,
    progress: bool,
    workers: Optional[int],
    backend: Optional[str] = None,
) -> list[list[TrainingLog]]:
    """Train what ``specs`` need in one pool; logs per spec."""
    jobs = rl_jobs(specs, root)
    run_jobs(train_run, [args for _, args in jobs], [name for name, _ in jobs], workers, progress, "RL runs", backend)
    return [
        [TrainingLog.load(run_folder(root, algo, int(seed), config) / "log.json") for seed in seeds]
        for algo, config, seeds, _ in specs
    ]


def rl_jobs(
    specs: Sequence[tuple[str, DQNConfig, Sequence[int], int]], root: Path | str
) -> list[tuple[str, tuple[Any, ...]]]:
    """The runs ``specs`` (``(algo, config, seeds, episodes)`` each) still need under ``root`` as ``(name, arguments
    of train_run)``, DQN-MBPO's first."""
    jobs: dict[str, tuple[Any, ...]] = {}
    for algo, config, seeds, episodes in specs:
        for seed in seeds:
            run_dir = run_folder(root, algo, int(seed), config)
            if run_dir.name in jobs:
                continue  # a seed listed twice is trained once (two workers must not share a folder)
            log_path = run_dir / "log.json"
            if log_path.exists() and (run_dir / "config.json").exists() and _saved_config(run_dir) == config:
                done = TrainingLog.load(log_path)
                if done.n_episodes == episodes or done.stop_reason is not None:
                    continue
                resume = done.n_episodes < episodes
            else:  # an unfinished run resumes; a folder holding another run is refused by the training
                resume = (run_dir / "config.json").exists()
            jobs[run_dir.name] = (algo, config, int(seed), int(episodes), run_dir, resume)
    return sorted(jobs.items(), key=lambda job: job[1][0] != "mbpo")  # stable: in order within each algorithm


def _saved_config(run_dir: Path) -> DQNConfig | None:
    """The config saved in a run folder, or None if this version cannot read it."""
    try:
        return load_config(run_dir / "config.json")
    except ValueError:
        return None


def train_run(
    algo: str, config: DQNConfig, seed: int, episodes: int, run_dir: Path, resume: bool, progress: bool = True
) -> None:
    """Train one run into ``run_dir`` (a job of :func:`softpend.study.sweep.run_jobs`)."""
    from softpend.rl.dqn import train_dqn
    from softpend.rl.mbpo import train_mbpo

    train: Callable[..., Any] = train_dqn if algo == "dqn" else train_mbpo
    train(config, seed=seed, episodes=episodes, run_dir=run_dir, resume=resume, progress=progress)


def summary_table(logs_by_method: dict[str, Sequence[TrainingLog]]) -> list[dict[str, Any]]:
    """One row per method and seed: episodes and plant seconds to balance (within :data:`SUCCESS_STD_RAD`) and to the
    asymptote, final std."""
    rows = []
    for method, logs in logs_by_method.items():
        for log in logs:
            last = log.evaluations[-1] if log.evaluations else {}
            row = {"method": method, "seed": log.seed, "episodes": log.n_episodes, "plant_s": log.plant_s}
            row |= dict(zip(("episodes_to_asymptote", "plant_s_to_asymptote"), run_to_asymptote(log)))
            row |= {"episodes_to_balance": log.episodes_to_balance(SUCCESS_STD_RAD)}
            row["plant_s_to_balance"] = log.real_s_to_balance(SUCCESS_STD_RAD)
            row["final_max_upright_std_rad"] = last.get("max_upright_std_rad", math.nan)
            row["final_swing_up_time_s"] = last.get("median_swing_up_time_s", math.nan)
            rows.append(row | {"model_steps": log.model_steps})
    return rows


def figure_configs(
    plant: str = TASK.plant,
    task_overrides: Optional[Mapping[str, Any]] = None,
    rl_overrides: Optional[Mapping[str, Any]] = None,
) -> dict[str, DQNConfig]:
    """``{"dqn": ..., "mbpo": ...}``: the tuned settings on ``Task(plant=plant)`` with ``task_overrides``, then
    ``rl_overrides`` (each applied to the configs that have the field)."""
    task = apply_overrides(Task(plant=plant), task_overrides or {})
    overrides = dict(rl_overrides or {})
    configs = {algo: load_hparams(algo, task) for algo in ("dqn", "mbpo")}
    names = {algo: {f.name for f in dataclasses.fields(config)} for algo, config in configs.items()}
    if unknown := sorted(k for k in overrides if k.partition(".")[0] not in names["mbpo"]):
        raise ValueError(f"rl_overrides: {unknown[0]!r} is not a DQNConfig or MBPOConfig field")
    return {
        algo: apply_overrides(config, {k: v for k, v in overrides.items() if k.partition(".")[0] in names[algo]})
        for algo, config in configs.items()
    }


def plant_runs_root(runs_root: Path | str, plant: str) -> Path:
    """``runs_root`` for the PRB rod, ``<runs_root>-<plant>`` for any other plant."""
    check_plant_name(plant)
    root = Path(runs_root)
    return root if plant == "prb" else root.with_name(f"{root.name}-{plant}")


def load_runs(runs_root: Path | str, plant: str, algo: str, seeds: Sequence[int], load: Callable) -> list:
    """``load(folder, seed)`` of each seed's run folder under :func:`plant_runs_root`, skipping unreadable runs."""
    root, loaded = plant_runs_root(runs_root, plant), []
    for seed in seeds:
        try:
            loaded.append(load(run_folder(root, algo, int(seed)), int(seed)))
        except (FileNotFoundError, ValueError, KeyError, TypeError):
            continue
    return loaded


#: Method names used in the figures, by algorithm.
METHOD_NAMES = {"dqn": "model-free DQN", "mbpo": "DQN-MBPO"}


def figure_runs(
    episodes_dqn: int,
    episodes_mbpo: int,
    seeds: Sequence[int],
    runs_root: Path | str = "runs/rl-book",
    progress: bool = True,
    plant: str = TASK.plant,
    **config_kwargs: Any,
) -> dict[str, list[TrainingLog]]:
    """Train (or reuse) the runs of Figures 4-6 (both methods in one pool); returns ``{method name: logs}``."""
    configs = figure_configs(plant=plant, **config_kwargs)
    specs = [("dqn", configs["dqn"], seeds, episodes_dqn), ("mbpo", configs["mbpo"], seeds, episodes_mbpo)]
    logs = _train_runs(specs, plant_runs_root(runs_root, plant), progress, None)
    return {METHOD_NAMES[spec[0]]: spec_logs for spec, spec_logs in zip(specs, logs)}


def run_folder(runs_root: Path | str, algo: str, seed: int, config: Any = None) -> Path:
    """Folder of one run: with ``config``, ``<algo>-<hash>-seed<seed>``; without, the one folder of ``algo`` and
    ``seed`` (``ValueError`` if there are several), else ``<algo>-seed<seed>``; the hash: of the settings as JSON data
    (PILCO's with the seed set to 0)."""
    root = Path(runs_root)
    if config is not None and algo == "pilco":
        data = json.loads(json.dumps(dataclasses.replace(config, seed=0).to_dict(), default=float))
        return root / run_folder_name(algo, data, seed)
    if config is not None:
        return root / run_folder_name(algo, saved_config_data(config), seed)
    pattern = re.compile(rf"{re.escape(algo)}-[0-9a-f]{{8}}-seed{int(seed)}")
    found = sorted(p for p in root.glob(f"{algo}-*-seed{int(seed)}") if pattern.fullmatch(p.name) and p.is_dir())
    if len(found) > 1:
        raise ValueError(
            f"{root} holds runs of {algo} seed {seed} with {len(found)} different settings "
            f"({', '.join(p.name for p in found)}); pass the run's config to pick one"
        )
    return found[0] if found else root / f"{algo}-seed{int(seed)}"
