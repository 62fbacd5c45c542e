"""Run folders named by their settings: a changed setting is a new folder, and a folder is never overwritten.

A training run's folder is ``<algo>-<hash>-seed<k>`` (:func:`run_folder_name`): ``<hash>`` is the first 8 hex
digits of the SHA-256 of the run's saved config as canonical JSON (:func:`config_hash`; the seed left out, so that
the seeds of one setting share it).  :func:`check_run_folder` is the check every trainer makes before any work:
an existing run folder is used again only for the same settings and seed, and only to resume it.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any, Mapping, Optional

__all__ = ["canonical_json", "check_run_folder", "config_hash", "run_folder_name", "setting_differences"]


def canonical_json(value: Any) -> str:
    """``value`` as JSON with sorted keys and no spaces (tuples as lists): equal settings, equal text."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=True)


def config_hash(data: Mapping[str, Any]) -> str:
    """The first 8 hex digits of the SHA-256 of ``data`` (a config as saved) in :func:`canonical_json`."""
    return hashlib.sha256(canonical_json(data).encode()).hexdigest()[:8]


def run_folder_name(algo: str, data: Mapping[str, Any], seed: int) -> str:
    """``<algo>-<config_hash(data)>-seed<seed>``."""
    return f"{algo}-{config_hash(data)}-seed{int(seed)}"


def setting_differences(saved: Any, wanted: Any, prefix: str = "") -> list[str]:
    """The dotted names of the settings in which ``saved`` and ``wanted`` (JSON data) differ."""
    if isinstance(saved, Mapping) and isinstance(wanted, Mapping):
        names = []
        for key in sorted(set(saved) | set(wanted), key=str):
            name = f"{prefix}{key}"
            if key not in saved or key not in wanted:
                names.append(name)
            else:
                names += setting_differences(saved[key], wanted[key], name + ".")
        return names
    same = canonical_json(_plain(saved)) == canonical_json(_plain(wanted))
    return [] if same else [prefix.rstrip(".") or "(the whole config)"]


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    if isinstance(value, list):
        return [_plain(v) for v in value]
    if isinstance(value, float) and math.isnan(value):
        return "NaN"
    return value


def check_run_folder(
    folder: str | Path,
    saved: Optional[Mapping[str, Any]],
    wanted: Mapping[str, Any],
    saved_seed: Optional[int],
    seed: int,
    resume: bool,
    can_resume: bool = True,
) -> None:
    """Refuse, before any work, to train run ``(wanted, seed)`` into ``folder`` that holds a run already.

    ``saved`` is the config saved in ``folder`` (None: unreadable), ``saved_seed`` the seed its log records
    (None: no log yet).  Raises ``ValueError`` naming the folder when the folder holds another run (other
    settings, another seed, or a config this version cannot read), and when it holds this very run but
    ``resume`` is false: a run folder is resumed only when asked, never trained over (``can_resume`` false: the
    method has no resuming, and the message says so).
    """
    if saved is None:
        raise ValueError(
            f"run folder {folder} holds a run whose config this version cannot read; refusing to train "
            "into it (choose another folder)"
        )
    differences = setting_differences(saved, wanted)
    if saved_seed is not None and int(saved_seed) != int(seed):
        differences.insert(0, f"seed ({saved_seed}, not {seed})")
    if differences:
        shown = ", ".join(differences[:5]) + (f" and {len(differences) - 5} more" if len(differences) > 5 else "")
        raise ValueError(
            f"run folder {folder} holds another run (it differs in {shown}); a run folder is reused "
            "only for the same settings and seed: choose another folder"
        )
    if not resume and not can_resume:
        raise ValueError(
            f"run folder {folder} already holds this run (same settings, seed {seed}); a run folder is "
            "never trained over: choose another folder"
        )
    if not resume:
        raise ValueError(
            f"run folder {folder} already holds this run (same settings, seed {seed}); resume it "
            "(softpend train --resume) or choose another folder: a run folder is never trained over"
        )
