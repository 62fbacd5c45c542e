"""Files from elsewhere run no code, outputs are checked before the work and never lose a file, and training
that goes non-finite stops with a named error instead of saving NaN weights."""

from __future__ import annotations

import base64
import io
import json
import math
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from support import one_line_error

from softpend.checks import NonFiniteError
from softpend.cli import main
from softpend.io.outputs import Outputs, atomic_write, json_text
from softpend.rl.agent_files import AgentFileError, load_agent_file, load_replay_buffer, save_replay_buffer
from softpend.rl.config import MBPOConfig
from softpend.rl.dqn import agent_class, load_agent, train_dqn
from softpend.rl.training_env import make_training_env
from softpend.study.presets import load_hparams

TINY = dict(episode_s=0.5, eval_every_episodes=2, checkpoint_every_episodes=2, eval_seeds=(0,), eval_duration_s=0.5)
CONFIG = load_hparams("dqn", overrides=dict(learning_starts=10, **TINY))  # what `softpend train` builds from TRAIN_ARGS
TRAIN_ARGS = [
    "--set",
    "episode_s=0.5",
    "--set",
    "eval_seeds=[0]",
    "--set",
    "eval_duration_s=0.5",
    "--set",
    "learning_starts=10",
    "--set",
    "eval_every_episodes=2",
    "--set",
    "checkpoint_every_episodes=2",
]


class Payload:
    """Unpickling this creates ``path`` (the marker of code run from a file)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)

    def __reduce__(self):
        return (Path.touch, (self.path,))


def payload_bytes(marker: Path) -> bytes:
    return pickle.dumps(Payload(marker))


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A tiny finished DQN run (2 episodes, checkpoint at the end)."""
    folder = tmp_path_factory.mktemp("run") / "dqn"
    train_dqn(CONFIG, seed=0, episodes=2, run_dir=folder, progress=False)
    return folder


def copy_run(run: Path, tmp_path: Path) -> Path:
    target = tmp_path / "run"
    shutil.copytree(run, target)
    return target


def rewrite_zip(path: Path, change) -> None:
    """Rewrite the zip at ``path`` with ``change(name, data) -> data`` applied to every member."""
    with zipfile.ZipFile(path) as archive:
        members = [(info.filename, archive.read(info)) for info in archive.infolist()]
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members:
            archive.writestr(name, change(name, data))


# ------------------------------------------------------------------------------------------------ security
def test_agent_with_an_unknown_pickled_entry_is_refused_and_runs_nothing(run, tmp_path, capsys):
    folder = copy_run(run, tmp_path)
    marker = tmp_path / "pwned"

    def inject(name, data):
        if name != "data":
            return data
        content = json.loads(data)
        content["evil"] = {
            ":type:": "<class 'object'>",
            ":serialized:": base64.b64encode(payload_bytes(marker)).decode(),
        }
        return json.dumps(content).encode()

    for agent in ("agent.zip", "best_agent.zip"):
        rewrite_zip(folder / agent, inject)
    with pytest.raises(AgentFileError, match="evil.*pickled"):
        load_agent(folder, which="final")
    assert main(["evaluate", str(folder), "--seeds", "0", "--duration-s", "0.5"]) == 2
    one_line_error(capsys, "AgentFileError", "evil")
    assert not marker.exists()


def test_a_payload_in_a_rebuilt_entry_is_never_unpickled(run, tmp_path):
    """Every pickled entry of a genuine agent is rebuilt from config.json: a payload put there is ignored and the
    agent acts as the genuine one."""
    folder = copy_run(run, tmp_path)
    marker = tmp_path / "pwned"
    encoded = base64.b64encode(payload_bytes(marker)).decode()

    def inject(name, data):
        if name != "data":
            return data
        content = json.loads(data)
        for key in ("exploration_schedule", "policy_class", "observation_space", "_last_obs"):
            content[key] = {":type:": "x", ":serialized:": encoded}
        return json.dumps(content).encode()

    rewrite_zip(folder / "agent.zip", inject)
    agent, _ = load_agent(folder, which="final")
    genuine, _ = load_agent(run, which="final")
    assert not marker.exists()
    observations = np.random.default_rng(0).uniform(-1, 1, size=(20, 11)).astype(np.float32)
    np.testing.assert_array_equal(
        agent.predict(observations, deterministic=True)[0], genuine.predict(observations, deterministic=True)[0]
    )


def test_agent_weights_that_are_a_pickle_payload_are_refused(run, tmp_path, capsys):
    folder = copy_run(run, tmp_path)
    marker = tmp_path / "pwned"
    buffer = io.BytesIO()
    torch.save({"q_net.q_net.0.weight": Payload(marker)}, buffer)
    rewrite_zip(folder / "agent.zip", lambda name, data: buffer.getvalue() if name == "policy.pth" else data)
    with pytest.raises(AgentFileError):
        load_agent(folder, which="final")
    assert main(["evaluate", str(folder / "agent.zip"), "--seeds", "0", "--duration-s", "0.5"]) == 2
    one_line_error(capsys, "AgentFileError")
    assert not marker.exists()


def test_resume_refuses_a_pickled_replay_buffer(run, tmp_path, capsys):
    folder = copy_run(run, tmp_path)
    marker = tmp_path / "pwned"
    (folder / "checkpoint" / "replay_buffer.npz").unlink()
    (folder / "checkpoint" / "replay_buffer.pkl").write_bytes(payload_bytes(marker))
    with pytest.raises(AgentFileError, match="pickled replay buffer"):
        train_dqn(CONFIG, seed=0, episodes=3, run_dir=folder, resume=True, progress=False)
    args = ["train", "--algo", "dqn", "--episodes", "3", "--out", str(folder), "--resume", "--no-progress", *TRAIN_ARGS]
    assert main(args) == 2
    one_line_error(capsys, "AgentFileError")
    assert not marker.exists()


def test_replay_buffer_file_holding_objects_is_refused(run, tmp_path):
    folder = copy_run(run, tmp_path)
    marker = tmp_path / "pwned"
    path = folder / "checkpoint" / "replay_buffer.npz"
    with np.load(path) as archive:
        arrays = {name: archive[name] for name in archive.files}
    arrays["observations"] = np.array([Payload(marker)], dtype=object)
    np.savez(path, **arrays)  # an object array: a pickle inside the npz
    with pytest.raises(AgentFileError):
        train_dqn(CONFIG, seed=0, episodes=3, run_dir=folder, resume=True, progress=False)
    assert not marker.exists()


def test_safe_loading_equals_stable_baselines3_loading(run, tmp_path):
    """The agent and buffer read without unpickling equal what SB3's pickle route gives, and keep training
    bit for bit the same (the bookkeeping of a resumed run is unchanged)."""
    from stable_baselines3 import DQN
    from stable_baselines3.common.logger import Logger

    checkpoint = run / "checkpoint"
    reference_buffer = tmp_path / "buffer.pkl"  # a pickle this test wrote itself
    sb3 = DQN.load(checkpoint / "agent.zip", env=make_training_env(CONFIG), device="cpu")
    load_replay_buffer(sb3.replay_buffer, checkpoint / "replay_buffer.npz")
    sb3.save_replay_buffer(reference_buffer)

    def continued(model) -> list[torch.Tensor]:
        model.set_logger(Logger(folder=None, output_formats=[]))  # as training does: no SB3-<date> temp folder
        model.learn(total_timesteps=40, reset_num_timesteps=False)
        return [p.detach().clone() for p in model.q_net.parameters()]

    safe = load_agent_file(agent_class(CONFIG), checkpoint / "agent.zip", CONFIG, env=make_training_env(CONFIG))
    load_replay_buffer(safe.replay_buffer, checkpoint / "replay_buffer.npz")
    for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts"):
        np.testing.assert_array_equal(getattr(safe.replay_buffer, name), getattr(sb3.replay_buffer, name))
    assert (safe.replay_buffer.pos, safe.replay_buffer.full) == (sb3.replay_buffer.pos, sb3.replay_buffer.full)
    for key in ("num_timesteps", "exploration_rate", "_n_calls", "_n_updates", "learning_rate", "seed"):
        assert getattr(safe, key) == getattr(sb3, key), key
    weights_safe = continued(safe)
    reference = DQN.load(checkpoint / "agent.zip", env=make_training_env(CONFIG), device="cpu")
    reference.load_replay_buffer(reference_buffer)
    weights_reference = continued(reference)
    assert all(torch.equal(a, b) for a, b in zip(weights_safe, weights_reference))


def test_mbpo_replay_buffer_round_trip_is_exact(tmp_path):
    from softpend.rl.mbpo import MBPOReplayBuffer

    env = make_training_env(MBPOConfig(**TINY))
    buffer = MBPOReplayBuffer(50, env.observation_space, env.action_space, model_buffer_size=30, real_ratio=0.5)
    rng = np.random.default_rng(1)
    for _ in range(70):  # wraps around: full
        obs = rng.normal(size=(1, 11)).astype(np.float32)
        buffer.add(
            obs,
            obs + 1,
            np.array([[rng.integers(5)]]),
            np.array([rng.normal()]),
            np.array([0.0]),
            [{"plant_observations": rng.normal(size=(2, 10))}],
        )
    buffer.add_model_transitions(
        rng.normal(size=(7, 11)), rng.normal(size=(7, 11)), rng.integers(0, 5, 7), rng.normal(size=7)
    )
    save_replay_buffer(buffer, tmp_path / "b.npz")
    restored = MBPOReplayBuffer(50, env.observation_space, env.action_space, model_buffer_size=30, real_ratio=0.5)
    load_replay_buffer(restored, tmp_path / "b.npz")
    for a, b in ((buffer, restored), (buffer.model_buffer, restored.model_buffer)):
        assert (a.pos, a.full) == (b.pos, b.full)
        for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(buffer.plant_observations, restored.plant_observations)
    small = MBPOReplayBuffer(40, env.observation_space, env.action_space, model_buffer_size=30)
    with pytest.raises(AgentFileError):
        load_replay_buffer(small, tmp_path / "b.npz")  # a buffer of another size


def test_torch_load_refusals_are_named_errors(tmp_path):
    from softpend.pilco.loop import PilcoConfig, PilcoResult
    from softpend.sysid import load_model
    from softpend.sysid.layout import StateLayout
    from softpend.sysid.model import DynamicsModel, save_model

    marker = tmp_path / "pwned"
    evil = io.BytesIO()
    torch.save({"weight": Payload(marker)}, evil)
    model = DynamicsModel(StateLayout("full"), 0.01, 0.06)
    weights, _ = save_model(tmp_path / "m", model)
    weights.write_bytes(evil.getvalue())
    with pytest.raises(ValueError, match="not weights written by softpend.*UnpicklingError"):
        load_model(tmp_path / "m")
    pilco = tmp_path / "pilco"
    pilco.mkdir()
    (pilco / "pilco.json").write_text(
        json.dumps({"config": PilcoConfig().to_dict(), "records": [], "gp_hyperparameters": None})
    )
    (pilco / "policy.pt").write_bytes(evil.getvalue())
    with pytest.raises(ValueError, match="not a PILCO policy.*UnpicklingError"):
        PilcoResult.load(pilco)
    assert not marker.exists()


# ------------------------------------------------------------------------------------------------ no lost work
def _bad_outputs(tmp_path: Path) -> dict[str, Path]:
    precious = tmp_path / "precious.npz"
    precious.write_bytes(b"someone else's data")
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    return {
        "exists, not ours": precious,
        "parent is a file": a_file / "out.npz",
        "unwritable": Path("/proc/softpend-test/out.npz"),
    }


@pytest.mark.parametrize("case", ["exists, not ours", "parent is a file", "unwritable"])
def test_babble_checks_its_output_before_the_work(tmp_path, monkeypatch, capsys, case):
    import softpend.sysid

    def never(*args, **kwargs):
        raise AssertionError("babbling started before the output was checked")

    monkeypatch.setattr(softpend.sysid, "babble", never)
    out = _bad_outputs(tmp_path)[case]
    assert main(["babble", str(out), "--no-progress"]) == 2
    one_line_error(capsys, "dataset")
    assert (tmp_path / "precious.npz").read_bytes() == b"someone else's data"


def test_babble_replaces_a_dataset_of_its_own(tmp_path, capsys):
    out = tmp_path / "data.npz"
    args = ["babble", str(out), "--n-trials", "2", "--trial-length-s", "0.1", "--no-progress"]
    assert main(args) == 0 and main(args + ["--seed", "1"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["n_trials"] == 2
    # no temporary file left; the manifest records the dataset as this command's
    assert sorted(p.name for p in tmp_path.iterdir()) == [".softpend-outputs.json", "data.npz"]


@pytest.mark.parametrize("case", ["exists, not ours", "parent is a file", "unwritable"])
def test_fit_model_checks_its_outputs_before_fitting(tmp_path, monkeypatch, capsys, case):
    import softpend.sysid

    data = tmp_path / "data.npz"
    assert main(["babble", str(data), "--n-trials", "2", "--trial-length-s", "0.1", "--no-progress"]) == 0
    monkeypatch.setattr(softpend.sysid, "fit_dynamics_model", lambda *a, **k: pytest.fail("fitted before checking"))
    out = _bad_outputs(tmp_path)[case]
    if case == "exists, not ours":
        out = tmp_path / "precious"
        (tmp_path / "precious.json").write_text('{"mine": true}')
    capsys.readouterr()
    assert main(["fit-model", str(data), str(out.with_suffix("")), "--no-progress"]) == 2
    one_line_error(capsys, "model file")
    assert (tmp_path / "precious.npz").read_bytes() == b"someone else's data"


@pytest.mark.parametrize("algo", ["dqn", "pilco"])
def test_train_checks_its_run_folder_before_training(tmp_path, monkeypatch, capsys, algo):
    import softpend.pilco.loop
    import softpend.rl.dqn

    monkeypatch.setattr(softpend.rl.dqn, "make_training_env", lambda *a: pytest.fail("trained before checking"))
    monkeypatch.setattr(softpend.pilco.loop, "run_pilco", lambda *a, **k: pytest.fail("trained before checking"))
    foreign = tmp_path / "photos"
    foreign.mkdir()
    (foreign / "holiday.jpg").write_bytes(b"jpeg")
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for out in (foreign, a_file, a_file / "run", Path("/proc/softpend-test/run")):
        assert main(["train", "--algo", algo, "--out", str(out), "--no-progress"]) == 2
        one_line_error(capsys, "run folder")
    assert (foreign / "holiday.jpg").read_bytes() == b"jpeg" and sorted(p.name for p in foreign.iterdir()) == [
        "holiday.jpg"
    ]


def test_atomic_write_keeps_the_old_file_when_writing_fails(tmp_path):
    path = tmp_path / "out.bin"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with atomic_write(path) as handle:
            handle.write(b"half of the new")
            raise RuntimeError("disk full")
    assert path.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]
    with pytest.raises(ValueError, match="is a folder"):
        Outputs().file(tmp_path)


# ------------------------------------------------------------------------------------------------ non-finite
def test_dqn_with_a_huge_learning_rate_stops_before_saving_nan_weights(tmp_path, capsys):
    out = tmp_path / "run"
    args = [
        "train",
        "--algo",
        "dqn",
        "--episodes",
        "3",
        "--out",
        str(out),
        "--no-progress",
        *TRAIN_ARGS,
        "--set",
        "learner.learning_rate=1e30",
    ]
    assert main(args) == 2
    one_line_error(capsys, "NonFiniteError", "learning_rate")
    assert not (out / "agent.zip").exists() and not (out / "checkpoint").exists()


def test_evaluating_an_agent_with_nan_weights_is_a_named_error(run, tmp_path, capsys):
    folder = copy_run(run, tmp_path)

    def poison(name, data):
        if name != "policy.pth":
            return data
        state = torch.load(io.BytesIO(data), weights_only=True)
        state["q_net.q_net.0.weight"][0, 0] = math.nan
        buffer = io.BytesIO()
        torch.save(state, buffer)
        return buffer.getvalue()

    rewrite_zip(folder / "agent.zip", poison)
    with pytest.raises(NonFiniteError):
        load_agent(folder, which="final")
    assert main(["evaluate", str(folder), "--which", "final", "--seeds", "0", "--duration-s", "0.5"]) == 2
    one_line_error(capsys, "NonFiniteError")


def test_a_diverging_dynamics_fit_is_a_named_error(tmp_path, capsys):
    data = tmp_path / "data.npz"
    assert main(["babble", str(data), "--n-trials", "3", "--trial-length-s", "0.2", "--no-progress"]) == 0
    capsys.readouterr()
    assert (
        main(
            [
                "fit-model",
                str(data),
                str(tmp_path / "m"),
                "--learning-rate",
                "1e30",
                "--max-epochs",
                "5",
                "--no-progress",
            ]
        )
        == 2
    )
    one_line_error(capsys, "NonFiniteError", "learning_rate")
    assert not (tmp_path / "m.pt").exists()


def _strict_json(text: str):
    def refuse(constant):
        raise AssertionError(f"not JSON: {constant}")

    return json.loads(text, parse_constant=refuse)


def test_pilco_without_policy_trials_prints_valid_json(tmp_path, capsys):
    args = [
        "train",
        "--algo",
        "pilco",
        "--episodes",
        "0",
        "--out",
        str(tmp_path / "p"),
        "--no-progress",
        "--set",
        "state=tip",
        "--set",
        "horizon_s=1.0",
        "--set",
        "eval_seeds=[1000]",
        "--set",
        "eval_duration_s=1.0",
    ]
    assert main(args) == 0
    summary = _strict_json(capsys.readouterr().out)
    assert summary["trials"] == 1 and summary["final_eval_upright_std_rad"] is None


def test_json_text_writes_null_for_non_finite_numbers():
    text = json_text({"a": math.nan, "b": [math.inf, -math.inf, 1.5], "c": np.float64("nan"), "d": np.arange(2)})
    assert _strict_json(text) == {"a": None, "b": [None, None, 1.5], "c": None, "d": [0, 1]}
