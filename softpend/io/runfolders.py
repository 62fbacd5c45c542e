"""Run folders named by their settings, ``<algo>-<hash>-seed<k>`` (the hash of the saved config without the
seed): a changed setting is a new folder, and a folder is reused only to resume the same run."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Mapping, Optional


def _canonical_json(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=True)


def run_folder_name(algo: str, data: Mapping[str, Any], seed: int) -> str:
    """``<algo>-<hash>-seed<seed>``: the first 8 hex digits of the SHA-256 of ``data`` as canonical JSON."""
    return f"{algo}-{hashlib.sha256(_canonical_json(data).encode()).hexdigest()[:8]}-seed{int(seed)}"


def _setting_differences(saved: Any, wanted: Any, prefix: str = "") -> list[str]:
    """The dotted names of the settings in which ``saved`` and ``wanted`` (JSON data) differ."""
    if isinstance(saved, Mapping) and isinstance(wanted, Mapping):
        names = []
        for key in sorted(set(saved) | set(wanted), key=str):
            name = f"{prefix}{key}"
            if key not in saved or key not in wanted:
                names.append(name)
            else:
                names += _setting_differences(saved[key], wanted[key], name + ".")
        return names
    same = _canonical_json(saved) == _canonical_json(wanted)  # tuples as lists, NaN equal to NaN
    return [] if same else [prefix.rstrip(".") or "(the whole config)"]


def check_run_folder(
    folder: str | Path,
    saved: Optional[Mapping[str, Any]],
    wanted: Mapping[str, Any],
    saved_seed: Optional[int],
    seed: int,
    resume: bool,
    can_resume: bool = True,
) -> None:
    """Refuse (``ValueError`` naming ``folder``), before any work, to train run ``(wanted, seed)`` into
    ``folder`` holding a run with the saved config ``saved`` (None: unreadable) and ``saved_seed`` (None: no
    log yet): another run, or this run unless ``resume`` (``can_resume`` false: the method cannot resume)."""
    if saved is None:
        raise ValueError(
            f"run folder {folder} holds a run whose config this version cannot read; refusing to train "
            "into it (choose another folder)"
        )
    differences = _setting_differences(saved, wanted)
    if saved_seed is not None and int(saved_seed) != int(seed):
        differences.insert(0, f"seed ({saved_seed}, not {seed})")
    if differences:
        shown = ", ".join(differences[:5]) + (f" and {len(differences) - 5} more" if len(differences) > 5 else "")
        raise ValueError(
            f"run folder {folder} holds another run (it differs in {shown}); a run folder is reused "
            "only for the same settings and seed: choose another folder"
        )
    if not resume:
        advice = "resume it (softpend train --resume) or " if can_resume else ""
        raise ValueError(
            f"run folder {folder} already holds this run (same settings, seed {seed}); {advice}choose another "
            "folder: a run folder is never trained over"
        )
