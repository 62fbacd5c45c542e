"""DQN and DQN-MBPO training loops on tiny budgets: they run, log plant time, checkpoint and resume, and the
MBPO buffer holds model transitions branched from real states."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from softpend.cli import main
from softpend.envs.soft_pendulum import observation_vector
from softpend.plant import OBSERVATION_NAMES
from softpend.rl.config import DQNConfig, MBPOConfig, ModelSettings, RolloutSettings, StopRule
from softpend.rl.dqn import evaluate_agent, load_agent, train_dqn
from softpend.rl.mbpo import MBPOReplayBuffer, train_mbpo
from softpend.rl.training_env import HeldActionController, make_base_env, make_training_env

TINY = dict(episode_s=1.0, eval_every_episodes=2, checkpoint_every_episodes=2, eval_seeds=(0,), eval_duration_s=1.5)


def test_action_repeat_env_reports_plant_observations():
    env = make_training_env(DQNConfig(episode_s=0.2, action_repeat=4))
    env.reset(seed=0)
    _, reward, _, _, info = env.step(4)
    assert info["plant_observations"].shape == (5, len(OBSERVATION_NAMES)) and info["plant_steps"] == 4
    steps = 1
    while True:
        *_, terminated, truncated, _ = env.step(0)
        steps += 1
        if terminated or truncated:
            break
    assert steps == 5  # 0.2 s = 20 plant steps = 5 agent steps


def test_held_action_controller_queries_every_repeat_steps():
    calls = []
    env = make_base_env(DQNConfig())
    controller = HeldActionController(lambda v: calls.append(1) or 4, env, repeat=4)
    from softpend.evaluation import evaluate_controller

    evaluate_controller(controller, seeds=(0,), duration_s=0.4)
    assert len(calls) == 10  # 40 plant steps / 4


def test_greedy_predictor_gives_the_actions_of_stable_baselines3_predict():
    from softpend.rl.dqn import build_dqn
    from softpend.rl.training_env import greedy_predictor

    config = DQNConfig()
    model = build_dqn(config, make_training_env(config), seed=3, episodes=1)
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():  # weights that make every action greedy somewhere
        for p in model.q_net.parameters():
            p.copy_(torch.randn(p.shape, generator=generator) / np.sqrt(p.shape[-1]))
    vectors = np.random.default_rng(0).normal(size=(400, model.observation_space.shape[0]))
    predict = greedy_predictor(model)
    expected = model.predict(vectors, deterministic=True)[0]
    assert np.array_equal(predict(vectors), expected) and len(set(expected.tolist())) >= 3
    singles = [predict(v) for v in vectors[:50]]
    assert all(isinstance(a, np.integer) for a in singles)
    assert [int(a) for a in singles] == [int(model.predict(v, deterministic=True)[0]) for v in vectors[:50]]
    assert [make_base_env(config).unwrapped.torque_from_action(a) for a in singles[:5]]  # the env takes them


def test_dqn_trains_checkpoints_and_resumes(tmp_path, monkeypatch):
    import tempfile

    system_tmp = tmp_path / "system-tmp"  # where SB3's default logger would create an SB3-<date> folder per learn()
    system_tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(system_tmp))
    tmp_path = tmp_path / "run"
    config = DQNConfig(learning_starts=20, **TINY)
    model, log = train_dqn(config, seed=0, episodes=3, run_dir=tmp_path, progress=False)
    assert [row["episode"] for row in log.episodes] == [1, 2, 3]
    assert log.plant_s == pytest.approx(3.0) and log.model_steps == 0
    assert [row["episode"] for row in log.evaluations] == [2, 3]
    assert (tmp_path / "agent.zip").exists() and (tmp_path / "checkpoint" / "replay_buffer.npz").exists()
    assert model.num_timesteps == 3 * config.episode_agent_steps
    weights_before = [p.detach().clone() for p in model.q_net.parameters()]
    buffer_before = model.replay_buffer.size()
    # resume: the run continues from the checkpoint (episode 3) with its replay buffer and weights
    model2, log2 = train_dqn(config, seed=0, episodes=5, run_dir=tmp_path, resume=True, progress=False)
    assert [row["episode"] for row in log2.episodes] == [1, 2, 3, 4, 5]
    assert log2.episodes[:3] == log.episodes
    assert log2.plant_s == pytest.approx(5.0)
    cpu = log2.column("cpu_s")  # CPU seconds of training accumulate over the resumed session
    assert np.all(cpu > 0) and np.all(np.diff(cpu) > 0)
    assert model2.replay_buffer.size() == buffer_before + 2 * config.episode_agent_steps
    assert any(not torch.equal(a, b) for a, b in zip(weights_before, model2.q_net.parameters()))  # it kept learning
    agent, loaded_config = load_agent(tmp_path, which="final")
    assert loaded_config == config
    assert (tmp_path / "best_agent.zip").exists()
    with pytest.raises(ValueError, match="which"):
        load_agent(tmp_path, which="latest")
    summary = evaluate_agent(agent, loaded_config, seeds=(0,), duration_s=0.5)
    assert len(summary.results) == 1 and summary.results[0].time_s[-1] == pytest.approx(0.5)
    with pytest.raises(ValueError, match="holds another run .it differs in learning_starts"):
        train_dqn(
            DQNConfig(learning_starts=21, **TINY), seed=0, episodes=6, run_dir=tmp_path, resume=True, progress=False
        )
    assert list(system_tmp.glob("SB3-*")) == []  # no logger folder outside the run folder


def _scripted_evaluations(monkeypatch, stds):
    """Make the training-time evaluations return these worst upright stds in turn (all swung up)."""
    from types import SimpleNamespace

    import softpend.rl.dqn as dqn

    queue = list(stds)
    calls = []
    queue_calls = calls

    def fake(model, config, seeds=None, duration_s=None, name="agent", stop_at_first_failure=False):
        std = queue.pop(0)
        calls.append(tuple(seeds if seeds is not None else config.eval_seeds))
        success = std <= 0.2
        results = [SimpleNamespace(upright_std_rad=std, swing_up_time_s=2.0, success=success) for _ in calls[-1]]
        if stop_at_first_failure and not success:
            results = results[:1]
        return SimpleNamespace(results=results, median=lambda key: 2.0, successes=sum(r.success for r in results))

    monkeypatch.setattr(dqn, "evaluate_agent", fake)
    _scripted_evaluations.calls = queue_calls  # the starts of each evaluation, in order
    return queue


def test_training_stops_after_consecutive_balanced_evaluations_and_stays_stopped(tmp_path, monkeypatch):
    config = DQNConfig(
        learning_starts=20,
        stop=StopRule(after_balanced_evaluations=2, upright_std_rad=0.1, confirm_seeds=()),
        **{**TINY, "eval_every_episodes": 1},
    )
    # episode 1 balanced, 2 not (streak broken), 3 and 4 balanced: the run ends after episode 4 of its 8
    queue = _scripted_evaluations(monkeypatch, [0.05, 0.3, 0.08, 0.09, 0.05, 0.05, 0.05, 0.05, 0.05])
    model, log = train_dqn(config, seed=0, episodes=8, run_dir=tmp_path, progress=False)
    assert log.n_episodes == 4 and [row["episode"] for row in log.evaluations] == [1, 2, 3, 4]
    assert log.stop_reason is not None and "2 consecutive evaluations" in log.stop_reason
    assert log.plant_s == pytest.approx(4.0)
    assert model.num_timesteps == 4 * config.episode_agent_steps  # no plant step after the last evaluation
    assert len(queue) == 5
    from softpend.rl.training_log import TrainingLog

    saved = TrainingLog.load(tmp_path / "log.json")
    assert saved.stop_reason == log.stop_reason and saved.n_episodes == 4
    # a stopped run is finished: resuming it with a larger budget trains nothing more
    _, again = train_dqn(config, seed=0, episodes=8, run_dir=tmp_path, resume=True, progress=False)
    assert again.n_episodes == 4 and len(queue) == 5
    with pytest.raises(ValueError, match="stop.after_balanced_evaluations"):
        StopRule(after_balanced_evaluations=-1)
    with pytest.raises(ValueError, match="stop.upright_std_rad"):
        StopRule(upright_std_rad=0.0)


def test_training_stops_only_once_the_confirmation_starts_balance_too(tmp_path, monkeypatch):
    config = DQNConfig(
        learning_starts=20,
        stop=StopRule(after_balanced_evaluations=2, confirm_seeds=(5, 6)),
        **{**TINY, "eval_every_episodes": 1},
    )
    assert config.selection_seeds == (0, 5, 6)
    # evaluations 1 and 2 balance but the confirmation fails at its first start (the second is not run); 3
    # balances and its confirmation holds from both starts
    queue = _scripted_evaluations(monkeypatch, [0.05, 0.05, 0.3, 0.05, 0.05, 0.05, 0.05])
    _, log = train_dqn(config, seed=0, episodes=8, run_dir=tmp_path, progress=False)
    assert log.n_episodes == 3 and len(queue) == 1
    assert _scripted_evaluations.calls == [(0,), (0,), (5,), (0,), (5,), (6,)]
    assert [row.get("confirmed") for row in log.evaluations] == [None, False, True]
    assert "confirmation starts" in log.stop_reason
    with pytest.raises(ValueError, match="stop.confirm_seeds"):
        DQNConfig(eval_seeds=(1, 2), stop=StopRule(confirm_seeds=(2, 3)))
    with pytest.raises(ValueError, match="stop.confirm_seeds"):
        StopRule(confirm_seeds=(-1,))


def test_a_confirmation_holds_with_as_many_failing_starts_as_allowed_and_stops_at_the_next(tmp_path, monkeypatch):
    config = DQNConfig(
        learning_starts=20,
        stop=StopRule(after_balanced_evaluations=1, confirm_seeds=(5, 6, 7), confirm_max_failures=1),
        **{**TINY, "eval_every_episodes": 1},
    )
    # evaluation 1 balances; its confirmation fails at starts 5 and 6 and stops there (7 is not run); evaluation 2
    # balances and its confirmation fails at start 6 only: training stops
    queue = _scripted_evaluations(monkeypatch, [0.05, 0.3, 0.3, 0.05, 0.05, 0.3, 0.05, 0.05])
    _, log = train_dqn(config, seed=0, episodes=8, run_dir=tmp_path, progress=False)
    assert _scripted_evaluations.calls == [(0,), (5,), (6,), (0,), (5,), (6,), (7,)]
    assert log.n_episodes == 2 and len(queue) == 1
    assert [(row["confirmed"], row["confirm_failures"]) for row in log.evaluations] == [(False, 2), (True, 1)]
    assert log.stop_reason.endswith("and from 2 of the 3 confirmation starts")


def test_one_balanced_evaluation_stops_training_once_its_confirmation_holds(tmp_path, monkeypatch):
    # DQN-MBPO's rule: every balanced evaluation is confirmed at once; a failed confirmation lets training go on
    config = DQNConfig(
        learning_starts=20,
        stop=StopRule(after_balanced_evaluations=1, confirm_seeds=(5, 6)),
        **{**TINY, "eval_every_episodes": 1},
    )
    queue = _scripted_evaluations(monkeypatch, [0.3, 0.05, 0.2, 0.05, 0.05, 0.05, 0.05])
    _, log = train_dqn(config, seed=0, episodes=8, run_dir=tmp_path, progress=False)
    assert _scripted_evaluations.calls == [(0,), (0,), (5,), (0,), (5,), (6,)]
    assert log.n_episodes == 3 and len(queue) == 1
    assert [row.get("confirmed") for row in log.evaluations] == [None, False, True]
    assert log.stop_reason.startswith("balanced in an evaluation (") and "confirmation starts" in log.stop_reason
    from softpend.study.presets import load_hparams

    mbpo = load_hparams("mbpo")
    assert mbpo.stop.after_balanced_evaluations == 1 and len(mbpo.stop.confirm_seeds) == 32
    assert not set(mbpo.stop.confirm_seeds) & set(mbpo.eval_seeds)
    dqn = load_hparams("dqn")  # two balanced evaluations on eight starts, then a confirmation on 24 more
    assert dqn.stop.after_balanced_evaluations == 2 and len(dqn.eval_seeds) == 8 and len(dqn.stop.confirm_seeds) == 24


def test_mbpo_buffer_holds_model_transitions_branched_from_real_states(tmp_path):
    # MBPO's own branching (every rollout from a real state, none cut short); the start-state branching and the
    # data box of the defaults are tested below
    config = MBPOConfig(
        initial_random_episodes=2,
        model=ModelSettings(refit_every_episodes=1, fit_steps=20, ensemble_size=2, hidden_widths=(16, 16)),
        rollout=RolloutSettings(
            every_steps=10, per_real_step=9, schedule=(0, 1, 1, 1), start_branch_fraction=0.0, within_data=False
        ),
        **TINY,
    )
    model, log = train_mbpo(config, seed=0, episodes=3, run_dir=tmp_path, progress=False)
    buffer = model.replay_buffer
    assert isinstance(buffer, MBPOReplayBuffer)
    assert log.plant_s == pytest.approx(3.0)  # real plant time only
    n_model = buffer.model_buffer.size()
    # model fitted after episode 2; episode 3 has 25 agent steps -> 2 rollout batches of 9 * 10, length 1
    assert n_model == 2 * 90 and log.model_steps == n_model
    real_obs = buffer.observations[: buffer.size(), 0]
    model_obs = buffer.model_buffer.observations[:n_model, 0]
    # every model transition (rollout length 1) starts from a state stored in the real buffer
    matches = (np.abs(model_obs[:, None, :] - real_obs[None, :, :]).max(axis=2) < 1e-7).any(axis=1)
    assert matches.all()
    # and is not a copy of a real transition: its next state comes from the learned model
    real_next = buffer.next_observations[: buffer.size(), 0]
    model_next = buffer.model_buffer.next_observations[:n_model, 0]
    copies = (np.abs(model_next[:, None, :] - real_next[None, :, :]).max(axis=2) < 1e-7).any(axis=1)
    assert not copies.all()
    # the real plant observation stored with each real transition reproduces its env vector
    env = make_base_env(config)
    vec = observation_vector(buffer.plant_observations[: buffer.size()], real_obs[:, -1], env)
    np.testing.assert_allclose(vec, real_obs, atol=1e-5)
    # model rewards are the report's reward of the predicted tip angle (one model step = 4 plant steps)
    assert np.all(buffer.model_buffer.rewards[:n_model, 0] <= 4 * 2.0 + 1e-6)
    assert (tmp_path / "dynamics.pt").exists() and (tmp_path / "real_data.npz").exists()
    # sampling mixes real and model data
    batch = buffer.sample(100)
    assert batch.observations.shape == (100, 11)
    # resume refits the model and continues
    model2, log2 = train_mbpo(config, seed=0, episodes=4, run_dir=tmp_path, resume=True, progress=False)
    assert log2.n_episodes == 4 and log2.model_steps > log.model_steps


def test_mbpo_rejects_a_dqn_config(tmp_path):
    with pytest.raises(ValueError, match="MBPOConfig"):
        train_mbpo(DQNConfig(), seed=0, episodes=1, run_dir=tmp_path, progress=False)


def test_command_line_train_and_evaluate(tmp_path, capsys):
    out = tmp_path / "run"
    args = [
        "train",
        "--algo",
        "dqn",
        "--episodes",
        "2",
        "--out",
        str(out),
        "--no-progress",
        "--set",
        "episode_s=0.5",
        "--set",
        "eval_seeds=[0]",
        "--set",
        "eval_duration_s=0.5",
        "--set",
        "learning_starts=10",
    ]
    assert main(args) == 0
    assert (out / "agent.zip").exists()
    assert main(["evaluate", str(out), "--seeds", "0", "--duration-s", "0.5", "--json"]) == 0
    assert '"success_rate"' in capsys.readouterr().out
    assert main(["train", "--algo", "dqn", "--out", str(out), "--set", "bogus=1"]) == 2


class _DriftingModel:
    """A stand-in dynamics model whose every step adds 5 rad/s to the hub rate (leaves the data quickly)."""

    def predict_next(self, state, torque, generator=None):
        out = state.clone()
        out[:, OBSERVATION_NAMES.index("phi_dot_rad_s")] += 5.0
        return out


def test_mbpo_rollouts_stay_within_the_real_data_and_branch_from_start_states(tmp_path):
    from softpend.rl.mbpo import MBPOTrainer

    config = MBPOConfig(
        initial_random_episodes=2,
        model=ModelSettings(refit_every_episodes=1, fit_steps=20, ensemble_size=2, hidden_widths=(16, 16)),
        rollout=RolloutSettings(every_steps=10, per_real_step=9, schedule=(0, 1, 1, 1)),
        **TINY,
    )
    model, _ = train_mbpo(config, seed=0, episodes=2, run_dir=tmp_path, progress=False)
    buffer = model.replay_buffer
    low, high = buffer.real_observation_box()
    real = buffer.observations[: buffer.size(), 0]
    assert np.all(low <= real.min(axis=0)) and np.all(high >= real.max(axis=0))
    added = {}
    for within in (False, True):
        buffer.model_buffer.reset()
        trainer = MBPOTrainer(
            dataclasses.replace(config, rollout=dataclasses.replace(config.rollout, within_data=within)),
            seed=0,
            run_dir=tmp_path,
        )
        trainer.dynamics = _DriftingModel()
        added[within] = trainer.rollouts(model, buffer, n_rollouts=50, length=6, epsilon=0.0)
        next_obs = buffer.model_buffer.next_observations[: added[within], 0]
        inside = np.all((next_obs >= low) & (next_obs <= high), axis=1)
        assert inside.all() if within else not inside.all()
    assert 0 < added[True] < added[False] == 50 * 6
    # branching from the training start distribution: the first share of the rollouts starts at fresh draws of
    # the start environment (the straight rod at rest at a random hub angle), the rest at real states
    buffer.model_buffer.reset()
    trainer = MBPOTrainer(
        dataclasses.replace(
            config,
            rollout=dataclasses.replace(config.rollout, start_branch_fraction=0.5, within_data=False),
            training_start="random",
        ),
        seed=3,
        run_dir=tmp_path,
    )
    trainer.dynamics = _DriftingModel()
    assert trainer.rollouts(model, buffer, n_rollouts=10, length=1, epsilon=0.0) == 10
    starts = make_base_env(config, "random")
    starts.reset(seed=3 * 1_000_003 + 17)
    expected = np.array([starts.reset()[0] for _ in range(5)])
    np.testing.assert_allclose(buffer.model_buffer.observations[:5, 0], expected, atol=1e-6)
    assert (
        (np.abs(buffer.model_buffer.observations[5:10, 0][:, None, :] - real[None]).max(axis=2) < 1e-7)
        .any(axis=1)
        .all()
    )


def test_q_network_reset_comes_after_the_evaluation_and_before_the_checkpoint(tmp_path, monkeypatch):
    import softpend.rl.dqn as dqn

    config = DQNConfig(learning_starts=20, reset_every_episodes=2, **{**TINY, "eval_every_episodes": 1})
    events = []
    real_reset, real_checkpoint = dqn.reset_q_network, dqn.EpisodeEvents.checkpoint

    def reset(model, seed):
        trained = [p.detach().clone() for p in model.q_net.parameters()]
        real_reset(model, seed)
        fresh = [p.detach().clone() for p in model.q_net.parameters()]
        assert all(not torch.equal(a, b) for a, b in zip(trained, fresh))
        assert all(torch.equal(a, b) for a, b in zip(fresh, model.q_net_target.parameters()))
        assert len(model.policy.optimizer.state) == 0
        events.append(("reset", seed, fresh))

    def checkpoint(self):
        events.append(("checkpoint", self.log.n_episodes, [p.detach().clone() for p in self.model.q_net.parameters()]))
        return real_checkpoint(self)

    monkeypatch.setattr(dqn, "reset_q_network", reset)
    monkeypatch.setattr(dqn.EpisodeEvents, "checkpoint", checkpoint)
    _, log = train_dqn(config, seed=3, episodes=5, run_dir=tmp_path, progress=False)
    assert [e[:2] for e in events] == [
        ("reset", (3, 2)),
        ("checkpoint", 2),
        ("reset", (3, 4)),
        ("checkpoint", 4),
        ("checkpoint", 5),
    ]  # none after the last episode
    # the checkpoint holds the reset network, so a run resumed from it goes on after the reset
    assert all(torch.equal(a, b) for a, b in zip(events[0][2], events[1][2]))
    assert [row["episode"] for row in log.evaluations] == [1, 2, 3, 4, 5]
    with pytest.raises(ValueError, match="reset_every_episodes"):
        DQNConfig(reset_every_episodes=-1)


def test_reset_q_network_draws_a_new_agents_initialisation_from_its_seed():
    from softpend.rl.dqn import build_dqn, reset_q_network

    config = DQNConfig()
    env = make_training_env(config)
    model = build_dqn(config, env, seed=1, episodes=1)
    with torch.no_grad():
        for p in model.q_net.parameters():
            p.mul_(5.0).add_(1.0)  # far from any initialisation
    reset_q_network(model, (1, 20))
    first = [p.detach().clone() for p in model.q_net.parameters()]
    reset_q_network(model, (1, 20))
    assert all(torch.equal(a, b) for a, b in zip(first, model.q_net.parameters()))  # same seed, same weights
    reset_q_network(model, (1, 40))
    assert all(not torch.equal(a, b) for a, b in zip(first, model.q_net.parameters()))
    layers = [m for m in model.q_net.modules() if isinstance(m, torch.nn.Linear)]
    assert len(layers) == 3
    for layer, weight, bias in zip(
        layers, first[0::2], first[1::2]
    ):  # PyTorch's default: uniform within 1/sqrt(fan_in)
        bound = 1 / np.sqrt(layer.in_features)
        assert float(weight.abs().max()) <= bound and float(bias.abs().max()) <= bound
        if weight.numel() >= 1000:
            assert float(weight.std()) == pytest.approx(bound / np.sqrt(3), rel=0.05)


def test_a_run_that_stops_at_a_reset_episode_keeps_the_agent_that_balanced(tmp_path, monkeypatch):
    import softpend.rl.dqn as dqn

    config = DQNConfig(
        learning_starts=20,
        reset_every_episodes=2,
        stop=StopRule(after_balanced_evaluations=1, confirm_seeds=()),
        **{**TINY, "eval_every_episodes": 1},
    )
    evaluated = []
    real_evaluate = dqn.EpisodeEvents.evaluate

    def evaluate(self):
        evaluated.append([p.detach().clone() for p in self.model.q_net.parameters()])
        return real_evaluate(self)

    monkeypatch.setattr(dqn.EpisodeEvents, "evaluate", evaluate)
    _scripted_evaluations(monkeypatch, [0.3, 0.05, 0.05])  # episode 2, a reset episode, balances: the run stops
    model, log = train_dqn(config, seed=0, episodes=6, run_dir=tmp_path, progress=False)
    assert log.n_episodes == 2 and log.stop_reason is not None
    assert all(torch.equal(a, b) for a, b in zip(evaluated[-1], model.q_net.parameters()))
    saved, _ = load_agent(tmp_path, which="final")
    assert all(torch.equal(a, b) for a, b in zip(evaluated[-1], saved.q_net.parameters()))


def test_a_training_evaluation_stops_at_its_first_failing_start(tmp_path, monkeypatch):
    # three selection starts; an evaluation with a failing start runs only the first, one that balances all three
    config = DQNConfig(
        learning_starts=20,
        stop=StopRule(after_balanced_evaluations=1, confirm_seeds=()),
        **{**TINY, "eval_every_episodes": 1, "eval_seeds": (0, 1, 2)},
    )
    _scripted_evaluations(monkeypatch, [0.5, 0.05])
    _, log = train_dqn(config, seed=0, episodes=4, run_dir=tmp_path, progress=False)
    failed, balanced = log.evaluations
    assert failed["starts_evaluated"] == 1 and failed["success_rate"] == 0.0 and not failed["all_swung_up"]
    assert math.isnan(failed["median_upright_std_rad"]) and failed["max_upright_std_rad"] == 0.5
    assert balanced["starts_evaluated"] == 3 and balanced["success_rate"] == 1.0 and balanced["all_swung_up"]
    assert log.n_episodes == 2 and log.stop_reason is not None


def test_training_is_a_list_of_callbacks_in_order(tmp_path):
    from softpend.rl import dqn
    from softpend.rl.mbpo import MBPOTrainer, ModelRefit, ModelRollouts
    from softpend.rl.training_log import TrainingLog

    config = MBPOConfig(stop=StopRule(after_balanced_evaluations=1, confirm_seeds=(5,)), **TINY)
    log = TrainingLog(algo="mbpo", seed=0)
    callbacks = dqn.training_callbacks(config, log, 4, tmp_path, progress=False, part=MBPOTrainer(config, 0, tmp_path))
    kinds = [ModelRollouts, dqn.EpisodeRecorder, ModelRefit, dqn.EpisodeEvents]
    assert [type(c) for c in callbacks.callbacks] == kinds and callbacks.callbacks[-1].stop_rule
    plain = dqn.training_callbacks(DQNConfig(**TINY), TrainingLog(algo="dqn", seed=0), 4, tmp_path, progress=False)
    recorder, events = plain.callbacks
    assert [type(c) for c in plain.callbacks] == kinds[1::2] and not events.stop_rule and recorder.model_steps() == 0
