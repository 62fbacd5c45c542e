"""The study's defaults and budgets, read by the notebooks, commands and benchmarks; the methods' tuned settings
are data (``book/hparams/<method>.yml``, :func:`load_hparams`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Optional

from softpend.io.overrides import Overrides, apply_overrides
from softpend.io.reading import read_yaml_checked
from softpend.pilco.loop import PilcoConfig
from softpend.rl.config import DQNConfig, MBPOConfig
from softpend.task import Task

#: The task of every figure: the default rod on the PRB plant, hanging starts.
TASK = Task()

#: The folder of the tuned settings, one YAML file per method (``<method>.yml``).
HPARAMS_DIR = Path(__file__).resolve().parents[2] / "book" / "hparams"

#: The config class of each method of :func:`load_hparams` (the planner's file is read by
#: :func:`softpend.study.data_efficiency.planner_config`: the figures that read these presets do not use its code).
CONFIG_CLASSES: dict[str, type] = {"dqn": DQNConfig, "mbpo": MBPOConfig, "pilco": PilcoConfig}


def load_hparams(
    method: str,
    task: Optional[Task] = None,
    overrides: Optional[Overrides] = None,
    path: Optional[Path | str] = None,
) -> Any:
    """The config the book trains ``method`` with: :func:`load_settings` of its class from the settings file
    ``path`` (default ``<HPARAMS_DIR>/<method>.yml``)."""
    if (cls := CONFIG_CLASSES.get(method)) is None:
        raise ValueError(f"unknown method {method!r}; known: {sorted(CONFIG_CLASSES)}")
    return load_settings(cls, path if path is not None else HPARAMS_DIR / f"{method}.yml", task, overrides)


def load_settings(
    cls: type, path: Path | str, task: Optional[Task] = None, overrides: Optional[Overrides] = None
) -> Any:
    """``cls``'s defaults, then the settings file ``path``, ``task`` (default :data:`TASK`) and ``overrides``;
    ``ValueError`` naming the file for an unknown field or a non-mapping."""
    path = Path(path)
    try:
        data = read_yaml_checked(path, "settings file") or {}
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the settings ({' '.join(str(exc).split())})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping of {cls.__name__} fields, got {type(data).__name__}")
    if unknown := [name for name in data if name not in {f.name for f in dataclasses.fields(cls)} - {"task"}]:
        raise ValueError(f"{path}: {unknown[0]!r} is not a {cls.__name__} setting")
    try:
        config = apply_overrides(cls(task=task if task is not None else TASK), data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    return apply_overrides(config, overrides or {})


#: The published RL runs of Figures 4-6 and 10: episodes per seed, seeds, and the run folders.
RL_BOOK = SimpleNamespace(episodes_dqn=250, episodes_mbpo=80, seeds=tuple(range(10)), runs_root="runs/rl-book")

#: Training episodes of each RL method: the ``softpend train`` default, the book and the benchmark runs.
RL_EPISODES = {"dqn": RL_BOOK.episodes_dqn, "mbpo": RL_BOOK.episodes_mbpo}


#: The settings of the book's runs: DQN and DQN-MBPO (Figures 4-6), PILCO (Figure 10).
DQN = load_hparams("dqn")
MBPO = load_hparams("mbpo")
PILCO = load_hparams("pilco")


#: The published PILCO runs of Figure 10: one per seed, in ``runs_root``.
PILCO_BOOK = SimpleNamespace(seeds=tuple(range(10)), runs_root="runs/pilco-book")


#: Start seeds that training and model selection see (the configs' ``selection_seeds`` and ``eval_seeds``).
SELECTION_SEEDS = tuple(sorted(set(DQN.selection_seeds) | set(MBPO.selection_seeds) | set(PILCO.eval_seeds)))

#: Fresh start seeds of every reported success rate and upright error (disjoint from the seeds above).
REPORT_SEEDS = tuple(range(20_000, 20_020))
