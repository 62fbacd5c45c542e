"""``softpend train --algo pilco``: run the PILCO loop and save the result to ``--out``."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from softpend.io.outputs import check_output_folder, json_text
from softpend.pilco.loop import PilcoConfig, run_pilco
from softpend.study.head_to_head import refuse_other_pilco_run
from softpend.study.presets import load_hparams


def config_from_args(args: argparse.Namespace) -> PilcoConfig:
    """A :class:`PilcoConfig` from the parsed ``softpend train`` options: ``--seed``, ``--episodes``,
    ``--torque-limit-nm`` and ``--n-links`` first, then the ``--set`` overrides (``args.overrides``,
    ``NAME -> parsed value``; unknown names raise ``ValueError``)."""
    overrides: dict[str, Any] = {"seed": int(args.seed)}
    if getattr(args, "episodes", None) is not None:
        overrides["n_policy_trials"] = int(args.episodes)
    for name in ("torque_limit_nm", "n_links"):
        if getattr(args, name, None) is not None:
            overrides[f"task.rod.{name}"] = getattr(args, name)
    overrides.update(getattr(args, "overrides", None) or {})
    return load_hparams("pilco", overrides=overrides)


def train_pilco_from_args(args: argparse.Namespace) -> int:
    """Entry point of ``softpend train --algo pilco`` (see the module docstring); prints a JSON summary."""
    import torch

    if getattr(args, "resume", False):
        raise ValueError("--resume is not supported for pilco (runs are short; start a new run)")
    torch.set_num_threads(1)
    config = config_from_args(args)
    # before the work: a new or empty folder; one that holds a PILCO run (of any settings) is never trained over
    check_output_folder(args.out, what="run folder", owned=lambda folder: (folder / "pilco.json").is_file())
    refuse_other_pilco_run(args.out, config)
    result = run_pilco(config, progress=not getattr(args, "no_progress", False))
    out = result.save(Path(args.out))
    balance = result.real_seconds_to_balance
    summary = {
        "out": str(out),
        "trials": len(result.records),
        "plant_seconds_total": result.plant_seconds_total,
        "real_seconds_to_balance": balance if math.isfinite(balance) else None,
        "train_wall_s": result.train_wall_s,
        "final_eval_upright_std_rad": result.records[-1].eval_upright_std_rad,
    }
    print(json_text(summary, indent=2))
    return 0
