"""``softpend train --algo pilco``: run the PILCO loop and save the result to ``--out``.

Common options of :mod:`softpend.commands.train` map onto :class:`~softpend.pilco.loop.PilcoConfig`:
``--seed`` -> ``seed``, ``--episodes`` -> ``n_policy_trials``, ``--torque-limit-nm`` and ``--n-links`` ->
``params``; every other field is set with ``--set NAME=VALUE`` (e.g. ``--set horizon_s=3.0``,
``--set state=tip``, ``--set eval_seeds=1000,1001``, ``--set cost_rate_width_rad_s=none``).  ``--resume`` is not supported (a run is short).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

from softpend.plant import RodParams
from softpend.pilco.loop import PilcoConfig, run_pilco

__all__ = ["config_from_args", "train_pilco_from_args"]


def _convert(name: str, value: str, default: Any, optional: bool = False) -> Any:
    try:
        if optional and value.lower() == "none":  # optional fields (e.g. cost_rate_width_rad_s=none: off)
            return None
        if default is None:
            return float(value)
        if isinstance(default, bool):
            if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(value)
            return value.lower() in ("true", "1", "yes")
        if isinstance(default, int):
            return int(value)
        if isinstance(default, float):
            return float(value)
        if isinstance(default, tuple):
            return tuple(int(v) for v in value.split(",") if v.strip())
        return value
    except ValueError:
        raise ValueError(f"--set {name}: cannot convert {value!r} to {type(default).__name__}") from None


def config_from_args(args: argparse.Namespace) -> PilcoConfig:
    """A :class:`PilcoConfig` from the parsed ``softpend train`` options (unknown ``--set`` names raise ``ValueError``)."""
    base = PilcoConfig.__dataclass_fields__
    defaults = PilcoConfig()
    changes: dict[str, Any] = {"seed": int(args.seed)}
    params = RodParams()
    if getattr(args, "episodes", None) is not None:
        changes["n_policy_trials"] = int(args.episodes)
    if getattr(args, "torque_limit_nm", None) is not None:
        params = params.replace(torque_limit_nm=float(args.torque_limit_nm))
    if getattr(args, "n_links", None) is not None:
        params = params.replace(n_links=int(args.n_links))
    for name, value in (getattr(args, "overrides", None) or {}).items():
        if name.startswith("params."):
            field_name = name[len("params."):]
            if field_name not in RodParams.__dataclass_fields__:
                raise ValueError(f"--set {name}: RodParams has no field {field_name!r}")
            params = params.replace(**{field_name: _convert(name, value, getattr(params, field_name))})
            continue
        if name not in base or name == "params":
            known = sorted(n for n in base if n != "params")
            raise ValueError(f"--set {name}: PilcoConfig has no field {name!r}; known: {known} and params.<field>")
        changes[name] = _convert(name, value, getattr(defaults, name), optional="Optional" in str(base[name].type))
    return dataclasses.replace(defaults, params=params, **changes)


def train_pilco_from_args(args: argparse.Namespace) -> int:
    """Entry point of ``softpend train --algo pilco`` (see the module docstring); prints a JSON summary."""
    import torch

    if getattr(args, "resume", False):
        raise ValueError("--resume is not supported for pilco (runs are short; start a new run)")
    torch.set_num_threads(1)
    config = config_from_args(args)
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
    print(json.dumps(summary, indent=2))
    return 0
