"""Agent and replay-buffer files read without running code from them."""

from __future__ import annotations

import io
import json
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import ReplayBuffer

from softpend.checks import NonFiniteError
from softpend.io.arrays import read_npz
from softpend.io.outputs import atomic_write
from softpend.io.reading import check_zip_members, read_bytes_checked, read_zip_member
from softpend.io.torchfiles import refused
from softpend.rl.config import SB3_FIELDS, DQNConfig
from softpend.rl.training_env import make_base_env

#: The pickled (``":serialized:"``) attributes of a softpend DQN agent file, each rebuilt from the config.
#: Those reset by ``DQN.learn`` before any use (a loaded agent starts a fresh rollout), unused by ``predict``.
_RESET_ATTRIBUTES = ("_last_obs", "_last_original_obs", "_last_episode_starts", "ep_info_buffer", "ep_success_buffer")
_BUILT = ("policy_class", "observation_space", "action_space", "replay_buffer_class", "train_freq", "lr_schedule")
REBUILT_ATTRIBUTES: frozenset[str] = frozenset({*_BUILT, "exploration_schedule", *_RESET_ATTRIBUTES})

#: Hyperparameters stored as plain JSON in an agent file that must equal the run's config.
_CONFIG_ATTRIBUTES = [name for name in SB3_FIELDS if name != "train_freq"]

_BUFFER_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


class AgentFileError(ValueError):
    """An agent or replay-buffer file that softpend will not load (pickled content, corrupt, or not matching
    the run's config); the message names the file and the reason."""


#: Largest ``data`` member (the JSON of the agent's plain attributes) of an agent file [bytes].
MAX_AGENT_DATA_BYTES = 16 * 2**20


#: What a corrupt or foreign agent file raises while its ``data`` member is read (JSON and UTF-8 errors included).
_CORRUPT = (zipfile.BadZipFile, zipfile.LargeZipFile, KeyError, ValueError, EOFError, NotImplementedError, OSError)


def _read_data(path: Path, raw: bytes, max_member_bytes: int = MAX_AGENT_DATA_BYTES) -> dict[str, Any]:
    try:
        with zipfile.ZipFile(io.BytesIO(raw)) as archive:
            check_zip_members(archive, path, "agent file", max_member_bytes, error=AgentFileError)
            member = read_zip_member(archive, "data", path, "agent file", MAX_AGENT_DATA_BYTES, AgentFileError)
        data = json.loads(member.decode("utf-8"))
    except AgentFileError:
        raise
    except (*_CORRUPT, RecursionError, zlib.error) as exc:
        raise AgentFileError(f"{path}: not a stable-baselines3 agent file ({type(exc).__name__}: {exc})") from None
    if not isinstance(data, dict):
        raise AgentFileError(f"{path}: its 'data' member is not a JSON object")
    return data


def _rebuilt(cls: type[DQN], config: DQNConfig, replay_buffer_class: type[ReplayBuffer]) -> dict[str, Any]:
    """``custom_objects`` for ``DQN.load``: every attribute of :data:`REBUILT_ATTRIBUTES` from ``config``."""
    from stable_baselines3.common.type_aliases import TrainFreq, TrainFrequencyUnit
    from stable_baselines3.common.utils import FloatSchedule, LinearSchedule

    spaces_env = make_base_env(config)  # its own space objects: DQN.load seeds the action space it is given
    return {
        "policy_class": cls.policy_aliases["MlpPolicy"],
        "observation_space": spaces_env.observation_space,
        "action_space": spaces_env.action_space,
        "replay_buffer_class": replay_buffer_class,
        "train_freq": TrainFreq(int(config.learner.train_freq), TrainFrequencyUnit.STEP),
        "lr_schedule": FloatSchedule(float(config.learner.learning_rate)),
        "exploration_schedule": LinearSchedule(
            config.learner.exploration_initial_eps,
            config.learner.exploration_final_eps,
            config.learner.exploration_fraction,
        ),
        **dict.fromkeys(_RESET_ATTRIBUTES),
    }


def _check_matches(path: Path, data: dict[str, Any], config: DQNConfig) -> None:
    """The plain-JSON facts of the file agree with the config (a clear message instead of a shape error)."""
    kwargs = data.get("policy_kwargs")
    saved_arch = kwargs.get("net_arch") if isinstance(kwargs, dict) else None
    if saved_arch != list(config.learner.net_arch):
        raise AgentFileError(
            f"{path}: its network {saved_arch!r} is not the config's learner.net_arch {list(config.learner.net_arch)}"
        )
    action = data.get("action_space")
    if isinstance(action, dict) and "n" in action and str(action["n"]) != str(config.n_torque_levels):
        raise AgentFileError(f"{path}: it has {action['n']} actions, the config {config.n_torque_levels} torque levels")
    for name in _CONFIG_ATTRIBUTES:
        if name in data and data[name] != getattr(config.learner, name):
            raise AgentFileError(
                f"{path}: its {name} {data[name]!r} is not the config's learner.{name} {getattr(config.learner, name)!r}"
            )
    if data.get("n_steps", 1) != 1 or data.get("tau", 1.0) != 1.0:
        raise AgentFileError(
            f"{path}: n_steps {data.get('n_steps')!r} and tau {data.get('tau')!r} must be 1 (softpend's DQN)"
        )


def check_finite_weights(model: DQN, where: str) -> None:
    """``NonFiniteError`` if any Q-network weight of ``model`` is NaN or infinite (``where`` says when/which)."""
    for name, tensor in model.policy.state_dict().items():
        if torch.is_floating_point(tensor) and not bool(torch.isfinite(tensor).all()):
            bad = int((~torch.isfinite(tensor)).sum())
            raise NonFiniteError(
                f"{where}: {bad} of {tensor.numel()} values of the network's {name} are not finite "
                "(training diverged: lower learning_rate)"
            )


def load_agent_file(
    cls: type[DQN],
    path: str | Path,
    config: DQNConfig,
    env: Any = None,
    replay_buffer_class: type[ReplayBuffer] = ReplayBuffer,
) -> DQN:
    """Load a DQN agent file written by softpend without unpickling anything (see the module docstring)."""
    path = Path(path)
    # the most bytes one member (networks, Adam's moments, metadata) and all members of such an agent file unpack to
    widths = [int(np.prod(make_base_env(config).observation_space.shape or (1,))), *config.learner.net_arch]
    widths.append(config.n_torque_levels)
    max_member = MAX_AGENT_DATA_BYTES + 16 * sum((a + 1) * b for a, b in zip(widths[:-1], widths[1:]))
    # read once (what is checked is what is loaded), a regular file of the size such an agent can have
    raw = read_bytes_checked(path, "agent file", 4 * max_member, AgentFileError)
    data = _read_data(path, raw, max_member)
    pickled = sorted(k for k, v in data.items() if isinstance(v, dict) and ":serialized:" in v)
    pickled = [k for k in pickled if k not in REBUILT_ATTRIBUTES]
    if pickled:
        raise AgentFileError(
            f"{path}: refusing to load it: its entries {pickled} are pickled Python objects, and unpickling can run "
            f"arbitrary code (softpend rebuilds only {sorted(REBUILT_ATTRIBUTES)} from the run's config)"
        )
    _check_matches(path, data, config)
    custom = _rebuilt(cls, config, replay_buffer_class)
    if replay_buffer_class is ReplayBuffer:
        custom["replay_buffer_kwargs"] = {}
    with refused(f"{path}: cannot load the agent", AgentFileError):
        model = cls.load(io.BytesIO(raw), env=env, device="cpu", custom_objects=custom)
    check_finite_weights(model, str(path))
    return model


def save_agent_file(model: DQN, path: str | Path) -> Path:
    """``model.save`` written through :func:`softpend.io.outputs.atomic_write` (an interrupted save leaves the
    previous file)."""
    buffer = io.BytesIO()
    model.save(buffer)
    with atomic_write(path) as handle:
        handle.write(buffer.getvalue())
    return Path(path)


def _parts(buffer: ReplayBuffer) -> dict[str, tuple[ReplayBuffer, tuple[str, ...]]]:
    """The SB3 buffers inside ``buffer`` by key prefix (an MBPO buffer carries a model buffer and the real plant
    observations), each with the names of its arrays."""
    plant = isinstance(getattr(buffer, "plant_observations", None), np.ndarray)
    parts = {"": (buffer, _BUFFER_ARRAYS + ("plant_observations",) * plant)}
    model_buffer = getattr(buffer, "model_buffer", None)
    if isinstance(model_buffer, ReplayBuffer):
        parts["model/"] = (model_buffer, _BUFFER_ARRAYS)
    return parts


def _filled(buffer: ReplayBuffer) -> int:
    return buffer.buffer_size if buffer.full else buffer.pos


def save_replay_buffer(buffer: ReplayBuffer, path: str | Path) -> Path:
    """Write the filled rows of ``buffer`` (and of an MBPO buffer's model part and real plant observations),
    its position and fill flag as an uncompressed ``.npz`` (plain arrays, no pickle)."""
    arrays: dict[str, np.ndarray] = {}
    for prefix, (part, names) in _parts(buffer).items():
        arrays |= {prefix + name: getattr(part, name)[: _filled(part)] for name in names}
        arrays[prefix + "pos"], arrays[prefix + "full"] = np.array(part.pos, dtype=np.int64), np.array(bool(part.full))
    with atomic_write(path) as handle:
        np.savez(handle, **arrays)  # type: ignore[arg-type]  # numpy's stub: no key is allow_pickle
    return Path(path)


def load_replay_buffer(buffer: ReplayBuffer, path: str | Path) -> None:
    """Fill ``buffer`` (freshly allocated, with the run's sizes) from a file of :func:`save_replay_buffer`."""
    path, parts = Path(path), _parts(buffer)
    # the file can hold no more than the buffer it fills (its arrays, and the zip's and headers' overhead)
    max_bytes = 2**20 + sum(int(getattr(part, name).nbytes) for part, names in parts.values() for name in names)
    saved = read_npz(path, "replay buffer file", AgentFileError, max_bytes=max_bytes)
    expected = {prefix + name for prefix, (_, names) in parts.items() for name in names + ("pos", "full")}
    if set(saved) != expected:
        raise AgentFileError(f"{path}: holds {sorted(saved)}, expected {sorted(expected)}")
    for prefix, (part, names) in parts.items():
        pos, full = saved[prefix + "pos"], saved[prefix + "full"]
        if pos.shape != () or pos.dtype.kind not in "iu" or full.shape != () or full.dtype != np.bool_:
            raise AgentFileError(f"{path}: {prefix}pos and {prefix}full must be an integer and a bool")
        if not 0 <= int(pos) < part.buffer_size:
            raise AgentFileError(f"{path}: {prefix}pos {int(pos)} outside [0, {part.buffer_size})")
        part.pos, part.full = int(pos), bool(full)
        for name in names:
            _restore(path, prefix + name, getattr(part, name), saved[prefix + name], _filled(part))


def _restore(path: Path, name: str, target: np.ndarray, value: np.ndarray, n: int) -> None:
    if value.dtype != target.dtype or value.shape != (n,) + target.shape[1:]:
        raise AgentFileError(
            f"{path}: {name} has shape {value.shape} and dtype {value.dtype}, expected "
            f"{(n,) + target.shape[1:]} and {target.dtype}"
        )
    target[...] = 0
    target[:n] = value
