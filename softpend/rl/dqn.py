"""Model-free DQN (stable-baselines3) that swings the soft rod up and balances it, with plant-time bookkeeping."""

from __future__ import annotations

import math
import shutil
import time
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import Logger
from tqdm import tqdm

from softpend.checks import check_work_size, int_at_least, one_of, positive, positive_int
from softpend.evaluation import evaluate_controller, metrics_from_trajectory
from softpend.io.outputs import check_output_folder
from softpend.io.reading import read_json_object
from softpend.plant import OBSERVATION_NAMES
from softpend.rl.agent_files import (
    AgentFileError,
    check_finite_weights,
    load_agent_file,
    load_replay_buffer,
    save_agent_file,
    save_replay_buffer,
)
from softpend.rl.config import SB3_FIELDS, DQNConfig, load_config, save_config, saved_config_data
from softpend.rl.training_env import greedy_predictor, make_training_env, policy_controller
from softpend.rl.training_log import TrainingLog

_THETA = OBSERVATION_NAMES.index("theta_rad")
_PHI_DOT = OBSERVATION_NAMES.index("phi_dot_rad_s")


class TargetDQN(DQN):
    """:class:`stable_baselines3.DQN` whose gradient steps clamp the TD targets to ``q_target_bounds``."""

    def __init__(self, *args, q_target_bounds: Optional[tuple[float, float]] = None, **kwargs) -> None:
        if q_target_bounds is not None:
            low, high = (float(v) for v in q_target_bounds)
            if not (math.isfinite(low) and math.isfinite(high) and low < high):
                raise ValueError(f"q_target_bounds must be finite (low, high) with low < high, got {q_target_bounds!r}")
            q_target_bounds = (low, high)
        self.q_target_bounds = q_target_bounds
        super().__init__(*args, **kwargs)

    def td_targets(
        self,
        rewards: torch.Tensor,
        dones: torch.Tensor,
        discounts: torch.Tensor | float,
        next_observations: torch.Tensor,
    ) -> torch.Tensor:
        """TD targets of a batch (no gradient)."""
        with torch.no_grad():
            next_q_target = self.q_net_target(next_observations)
            target = rewards + (1 - dones) * discounts * next_q_target.max(dim=1, keepdim=True)[0]
            bounds = getattr(self, "q_target_bounds", None)  # an agent saved without the attribute has none
            if bounds is not None:
                target = target.clamp(bounds[0], bounds[1])
        return target

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:  # noqa: D102 (SB3 API)
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        losses = []
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            discounts = data.discounts if data.discounts is not None else self.gamma
            target = self.td_targets(data.rewards, data.dones, discounts, data.next_observations)
            current = torch.gather(self.q_net(data.observations), dim=1, index=data.actions.long())
            loss = F.smooth_l1_loss(current, target)
            losses.append(loss.item())
            self.policy.optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", float(np.mean(losses)) if losses else float("nan"))


def agent_class(config: DQNConfig) -> type[DQN]:
    """:class:`TargetDQN` if ``config.learner.clip_q_targets``, else stable-baselines3's ``DQN``."""
    return TargetDQN if config.learner.clip_q_targets else DQN


def build_dqn(config: DQNConfig, env: Any, seed: int, episodes: int, **kwargs: Any) -> DQN:
    """A stable-baselines3 DQN with the config's hyperparameters (``kwargs`` go to ``DQN``)."""
    cls = agent_class(config)
    if issubclass(cls, TargetDQN):
        kwargs["q_target_bounds"] = config.q_target_bounds
    hyper = {name: getattr(config.learner, name) for name in SB3_FIELDS} | {"learning_starts": config.learning_starts}
    net = {"net_arch": list(config.learner.net_arch)}
    return cls("MlpPolicy", env, tau=1.0, policy_kwargs=net, seed=int(seed), device="cpu", verbose=0, **hyper | kwargs)


def evaluate_agent(
    model: Any,
    config: DQNConfig,
    seeds: Optional[tuple[int, ...]] = None,
    duration_s: Optional[float] = None,
    name: str = "agent",
    stop_at_first_failure: bool = False,
):
    """Shared evaluation (:func:`softpend.evaluation.evaluate_controller`) of a trained agent on ``config.task``."""
    seeds, duration_s = _seeds_and_duration(config, seeds, duration_s)
    options: dict[str, Any] = dict(seeds=seeds, duration_s=duration_s, stop_at_first_failure=stop_at_first_failure)
    return evaluate_controller(policy_controller(model, config), config.task, name=name, **options)


def _seeds_and_duration(config: DQNConfig, seeds: Any, duration_s: Any) -> tuple[tuple[int, ...], float]:
    seeds = tuple(int_at_least("seeds", s, 0) for s in (seeds if seeds is not None else config.eval_seeds))
    return seeds, positive("duration_s", duration_s if duration_s is not None else config.eval_duration_s)


def evaluate_agents_batched(
    models: Sequence[Any],
    config: DQNConfig,
    seeds: Optional[tuple[int, ...]] = None,
    duration_s: Optional[float] = None,
    name: str = "agent",
    **options: Any,
) -> list:
    """:func:`evaluate_agent` of several agents at once on the batched chain (agent ``i`` drives rod block ``i``)."""
    from softpend.evaluation import BatchPolicy, EvaluationSummary, evaluate

    models = list(models)
    if not models:
        raise ValueError("models must not be empty")
    seeds, duration_s = _seeds_and_duration(config, seeds, duration_s)
    predictors = [greedy_predictor(model) for model in models]
    n = len(seeds)

    def predict(vectors: np.ndarray) -> np.ndarray:
        return np.concatenate([np.asarray(p(vectors[i * n : (i + 1) * n])) for i, p in enumerate(predictors)])

    policy = BatchPolicy(predict, config.action_repeat, config.n_torque_levels)
    summary = evaluate(
        policy, config.task, engine="batched", seeds=seeds * len(models), duration_s=duration_s, **options
    )
    return [EvaluationSummary(name=name, results=summary.results[i * n : (i + 1) * n]) for i in range(len(models))]


class EpisodeRecorder(BaseCallback):
    """Each agent step's plant observations, torques and reward; at an episode end one :class:`TrainingLog` row
    (return, plant seconds, upright std and swing-up time, model steps of ``part``, clocks).  ``ended`` holds that
    episode's plant observations and torques for the callbacks after this one in the list, ``None`` between episode
    ends."""

    model: DQN

    def __init__(self, config: DQNConfig, log: TrainingLog, part: Any = None) -> None:
        super().__init__()
        self.config, self.log, self.part = config, log, part
        last = log.episodes[-1] if log.episodes else {"wall_s": 0.0, "cpu_s": 0.0}  # a resumed run's clocks go on
        self._wall_from = float(last["wall_s"]) - time.perf_counter()
        self._cpu_from = float(last.get("cpu_s", math.nan)) - time.process_time()
        self._return, self._observations, self._torques = 0.0, list[np.ndarray](), list[float]()
        self.ended: Optional[tuple[np.ndarray, np.ndarray]] = None

    def model_steps(self) -> int:
        return int(self.part.model_steps) if self.part is not None else 0

    def clocks(self) -> dict[str, float]:
        """Wall and CPU seconds of training so far, over resumed sessions."""
        return dict(wall_s=self._wall_from + time.perf_counter(), cpu_s=self._cpu_from + time.process_time())

    def _on_step(self) -> bool:
        info = self.locals["infos"][0]
        plant = info["plant_observations"]
        self._observations.append(plant if not self._observations else plant[1:])
        self._torques.extend([info["torque_nm"]] * int(info["plant_steps"]))
        self._return += float(self.locals["rewards"][0])
        self.ended = self._end_episode() if self.locals["dones"][0] else None
        return True

    def _end_episode(self) -> tuple[np.ndarray, np.ndarray]:
        """Append the episode's row to the log; its plant observations and torques."""
        observations, torques = np.concatenate(self._observations), np.asarray(self._torques, float)
        plant_steps, dt = len(observations) - 1, self.config.dt_s
        std, swing_up = math.pi, math.inf
        if plant_steps >= 2:
            times = np.arange(plant_steps + 1) * dt
            theta, phi_dot = observations[:, _THETA], observations[:, _PHI_DOT]
            metrics = metrics_from_trajectory(times, theta, np.append(torques, 0.0), phi_dot)
            std, swing_up = metrics["upright_std_rad"], metrics["swing_up_time_s"]
        row: dict[str, Any] = {"episode": self.log.n_episodes + 1, "return": self._return}
        row |= dict(plant_s=self.log.plant_s + plant_steps * dt, upright_std_rad=std, swing_up_time_s=swing_up)
        row |= dict(model_steps=self.model_steps(), **self.clocks())
        self.log.episodes.append(row)
        self._return, self._observations, self._torques = 0.0, [], []
        check_finite_weights(
            self.model, f"{self.log.algo} seed {self.log.seed}, after training episode {row['episode']}"
        )
        return observations, torques


class EpisodeEvents(BaseCallback):
    """After the recorder, at each episode end: the progress bar and, when due, the greedy evaluation (keeping
    ``best_agent.zip``), :func:`reset_q_network` and a checkpoint (plus ``part.save(folder)``), at the next rollout
    end or after the last episode; with the stop rule the evaluation runs at once and the rule follows it.  Training
    stops at the episode budget."""

    model: DQN

    def __init__(
        self,
        config: DQNConfig,
        recorder: EpisodeRecorder,
        episodes: int,
        run_dir: Path,
        progress: bool = True,
        part: Any = None,
    ) -> None:
        super().__init__()
        self.config, self.recorder, self.log, self.episodes, self.part = config, recorder, recorder.log, episodes, part
        self.run_dir, self.progress = Path(run_dir), progress
        self.stop_rule = bool(config.stop.after_balanced_evaluations)
        self.pending = dict.fromkeys(("evaluate", "reset_network", "checkpoint"), False)
        self.best_score = min((_score(row) for row in self.log.evaluations), default=None)
        self.bar: Optional[tqdm] = None

    def _on_training_start(self) -> None:
        shown: dict[str, Any] = dict(desc=f"{self.log.algo} seed {self.log.seed}", unit="episode", leave=False)
        self.bar = tqdm(total=self.episodes, initial=self.log.n_episodes, disable=not self.progress, **shown)

    def _on_step(self) -> bool:
        if self.recorder.ended is None:
            return True
        go_on = not (self.log.n_episodes >= self.episodes and self.num_timesteps < self.model._total_timesteps)
        return self._events() and go_on

    def _check_weights(self, when: str) -> None:
        check_finite_weights(self.model, f"{self.log.algo} seed {self.log.seed}, {when}")

    def _events(self) -> bool:
        log, c, last = self.log, self.config, self.episodes
        if self.bar is not None:
            last_eval = log.evaluations[-1]["max_upright_std_rad"] if log.evaluations else math.nan
            self.bar.update(1)
            self.bar.set_postfix(
                ret=f"{log.episodes[-1]['return']:.0f}", plant_s=f"{log.plant_s:.0f}", eval_std=f"{last_eval:.2f}"
            )
        n, go_on = log.n_episodes, True
        due = {
            "evaluate": n % c.eval_every_episodes == 0 or n >= last,
            "reset_network": bool(c.reset_every_episodes) and n % c.reset_every_episodes == 0 and n < last,
            "checkpoint": n % c.checkpoint_every_episodes == 0,
        }
        for task, now in due.items():
            self.pending[task] = self.pending[task] or now
            if n >= last:
                self.flush(task)
            elif task == "evaluate" and self.stop_rule and self.pending[task]:
                self.pending[task] = False
                self.evaluate()
                go_on = not self.stop()
        return go_on

    def _on_rollout_end(self) -> None:
        for task in self.pending:
            self.flush(task)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def flush(self, task: str) -> None:
        if self.pending[task]:
            self.pending[task] = False
            getattr(self, task)()

    def reset_network(self) -> None:
        reset_q_network(self.model, seed=(self.log.seed, self.log.n_episodes))

    def evaluate(self) -> dict[str, Any]:
        """Evaluate the greedy policy on the true plant and append an evaluation row."""
        summary = evaluate_agent(self.model, self.config, stop_at_first_failure=self.config.eval_until_first_failure)
        results, seeds, nan = summary.results, self.config.eval_seeds, math.nan
        complete, stds = len(results) == len(seeds), [r.upright_std_rad for r in results]
        swing_up, median_std = (summary.median("swing_up_time_s"), float(np.median(stds))) if complete else (nan, nan)
        row: dict[str, Any] = dict(episode=self.log.n_episodes, plant_s=self.log.plant_s)
        row |= dict(model_steps=self.recorder.model_steps(), starts_evaluated=len(results))
        row |= dict(median_upright_std_rad=median_std)
        row |= dict(max_upright_std_rad=max(stds), median_swing_up_time_s=swing_up)
        row |= dict(all_swung_up=complete and all(math.isfinite(r.swing_up_time_s) for r in results))
        row |= dict(success_rate=summary.successes / len(seeds), **self.recorder.clocks())
        self.log.evaluations.append(row)
        if self.best_score is None or _score(row) <= self.best_score:
            self.best_score = _score(row)
            self._check_weights(f"episode {row['episode']}")
            save_agent_file(self.model, self.run_dir / "best_agent.zip")
        return row

    def stop(self) -> bool:
        """The stop rule after an evaluation (see :class:`~softpend.rl.config.StopRule`); writes ``log.stop_reason``."""
        rule, k = self.config.stop, self.config.stop.after_balanced_evaluations
        balanced = lambda swung_up, std: bool(swung_up) and std <= rule.upright_std_rad  # noqa: E731
        rows = self.log.evaluations[-k:]
        if len(rows) < k or not all(balanced(r["all_swung_up"], r["max_upright_std_rad"]) for r in rows):
            return False
        if rule.confirm_seeds:
            failures = 0
            for seed in rule.confirm_seeds:
                (result,) = evaluate_agent(self.model, self.config, seeds=(seed,)).results
                failures += not balanced(math.isfinite(result.swing_up_time_s), result.upright_std_rad)
                if failures > rule.confirm_max_failures:
                    break
            rows[-1].update(confirmed=failures <= rule.confirm_max_failures, confirm_failures=failures)
            if not rows[-1]["confirmed"]:
                return False
        n = len(rule.confirm_seeds)
        held = n - rows[-1].get("confirm_failures", 0)
        confirmation = "" if not n else f" and from {'the' if held == n else f'{held} of the'} {n} confirmation starts"
        self.log.stop_reason = (
            "balanced in an evaluation " if k == 1 else f"balanced in {k} consecutive evaluations "
        ) + f"(upright std <= {rule.upright_std_rad:g} rad from every evaluation start){confirmation}"
        return True

    def checkpoint(self) -> Path:
        """Write agent, replay buffer (plain arrays), log (and extra files) to ``run_dir/checkpoint`` atomically."""
        self._check_weights(f"checkpoint at episode {self.log.n_episodes}")
        final, tmp, old = (self.run_dir / name for name in ("checkpoint", "checkpoint.tmp", "checkpoint.old"))
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        self.model.save(tmp / "agent.zip")
        assert self.model.replay_buffer is not None  # an off-policy agent's, set up by _setup_model
        save_replay_buffer(self.model.replay_buffer, tmp / "replay_buffer.npz")
        self.log.save(tmp / "log.json")
        if self.part is not None:
            self.part.save(tmp)
        shutil.rmtree(old, ignore_errors=True)
        if final.exists():
            final.rename(old)
        tmp.rename(final)
        shutil.rmtree(old, ignore_errors=True)
        return final


def reset_q_network(model: DQN, seed: tuple[int, int]) -> None:
    """Re-initialise ``model``'s Q-network (PyTorch's default, seeded by ``seed``) and its target and clear the
    optimiser's moments."""
    generator = torch.Generator().manual_seed(int(np.random.SeedSequence([int(s) for s in seed]).generate_state(1)[0]))
    with torch.no_grad():
        for layer in model.q_net.modules():
            if isinstance(layer, torch.nn.Linear):
                torch.nn.init.kaiming_uniform_(layer.weight, a=math.sqrt(5), generator=generator)
                if layer.bias is not None:
                    bound = 1 / math.sqrt(layer.in_features)
                    torch.nn.init.uniform_(layer.bias, -bound, bound, generator=generator)
        model.q_net_target.load_state_dict(model.q_net.state_dict())
    model.policy.optimizer.state.clear()


def _score(evaluation: dict[str, Any]) -> tuple[bool, float]:
    """Order of evaluations for keeping the best agent: all seeds swung up first, then the worst std."""
    return (not evaluation["all_swung_up"], float(evaluation["max_upright_std_rad"]))


def is_run_folder(path: Path) -> bool:
    """Whether ``path`` is a run folder of :func:`run_training` (its ``config.json`` names a config class)."""
    data = read_json_object(Path(path) / "config.json", 10**7)
    return data is not None and data.get("class") in ("DQNConfig", "MBPOConfig")


def check_run_size(config: DQNConfig, observation_dim: int) -> None:
    """``ValueError`` if a run's arrays (buffers, networks, records) would exceed :data:`softpend.checks.MAX_WORK_BYTES`."""
    from softpend.rl.config import MBPOConfig

    row = 2 * observation_dim * 4 + 8 + 3 * 4  # obs and next obs (float32), action (int64), reward/done/timeout
    buffers = config.learner.buffer_size * row
    if isinstance(config, MBPOConfig):
        buffers += config.learner.buffer_size * 8 * len(OBSERVATION_NAMES) + config.rollout.buffer_size * row
    widths = [observation_dim, *config.learner.net_arch, config.n_torque_levels]
    n_weights = sum((a + 1) * b for a, b in zip(widths[:-1], widths[1:]))
    networks = 4 * 4 * n_weights + 2 * 4 * config.learner.batch_size * sum(widths)  # nets, Adam moments; a batch
    plant_steps = config.episode_agent_steps * config.action_repeat + 1
    eval_steps = len(config.eval_seeds) * (config.eval_duration_s / config.dt_s + 1)
    records = 8 * (len(OBSERVATION_NAMES) + 2) * 2 * (plant_steps + eval_steps)
    sizes = [f"replay buffers {buffers / 2**20:.3g} MiB", f"networks {networks / 2**20:.3g} MiB"]
    sizes.append(f"episode and evaluation records {records / 2**20:.3g} MiB")
    check_work_size("this training run", buffers + networks + records, ", ".join(sizes))


def _saved_run_seed(run_dir: Path) -> Optional[int]:
    """The seed recorded in a run folder's log (the final one, else the checkpoint's), or None (no log yet)."""
    for path in (run_dir / "log.json", run_dir / "checkpoint" / "log.json"):
        data = read_json_object(path, 10**9)
        if data is not None and isinstance(data.get("seed"), int):
            return int(data["seed"])
    return None


def _check_run_args(episodes: int, run_dir: Path | str, config: DQNConfig, seed: int, resume: bool) -> Path:
    """The run folder, checked before any work: new, empty, or holding this run (same config and seed)."""
    from softpend.io.runfolders import check_run_folder

    positive_int("episodes", episodes)
    run_dir = check_output_folder(run_dir, what="run folder", owned=is_run_folder)
    if is_run_folder(run_dir):
        saved = read_json_object(run_dir / "config.json", 10**7)
        check_run_folder(run_dir, saved, saved_config_data(config), _saved_run_seed(run_dir), seed, resume)
    return run_dir


def training_callbacks(
    config: DQNConfig, log: TrainingLog, episodes: int, run_dir: Path, progress: bool, part: Any = None
) -> CallbackList:
    """The training's callbacks in their order: ``part``'s before the recorder (MBPO's model rollouts), the
    :class:`EpisodeRecorder`, ``part``'s after it (MBPO's refit), the :class:`EpisodeEvents` last."""
    recorder = EpisodeRecorder(config, log, part)
    before, after = part.callbacks(recorder) if part is not None else ([], [])
    return CallbackList([*before, recorder, *after, EpisodeEvents(config, recorder, episodes, run_dir, progress, part)])


def run_training(
    algo: str,
    config: DQNConfig,
    seed: int,
    episodes: int,
    run_dir: Path | str,
    resume: bool,
    progress: bool,
    part: Any = None,
) -> tuple[DQN, TrainingLog]:
    """The training loop shared by DQN and DQN-MBPO (``part``: a :class:`softpend.rl.mbpo.MBPOTrainer`, whose
    ``dqn_kwargs`` go to :func:`build_dqn`); a resumed run goes on from ``run_dir/checkpoint`` (same config)."""
    run_dir = _check_run_args(episodes, run_dir, config, seed, resume)
    torch.set_num_threads(1)
    run_dir.mkdir(parents=True, exist_ok=True)
    env = make_training_env(config)
    assert env.observation_space.shape is not None  # a Box
    check_run_size(config, int(np.prod(env.observation_space.shape)))
    kwargs, checkpoint = part.dqn_kwargs() if part is not None else {}, run_dir / "checkpoint"
    if not (resume and (checkpoint / "agent.zip").exists()):
        save_config(config, run_dir / "config.json")
        model, log = build_dqn(config, env, int(seed), episodes, **kwargs), TrainingLog(algo=algo, seed=int(seed))
    else:
        if load_config(run_dir / "config.json") != config:
            raise ValueError(f"config differs from the one saved in {run_dir / 'config.json'}; cannot resume")
        if not (checkpoint / "replay_buffer.npz").exists() and (checkpoint / "replay_buffer.pkl").exists():
            raise AgentFileError(
                f"{checkpoint} holds a pickled replay buffer (replay_buffer.pkl), which softpend does not load "
                "(unpickling can run arbitrary code); start a new run"
            )
        log = TrainingLog.load(checkpoint / "log.json")
        buffer_class = kwargs.get("replay_buffer_class", ReplayBuffer)
        model = load_agent_file(agent_class(config), checkpoint / "agent.zip", config, env, buffer_class)
        assert model.replay_buffer is not None  # an off-policy agent's, set up by _setup_model
        load_replay_buffer(model.replay_buffer, checkpoint / "replay_buffer.npz")
        if part is not None:
            part.restore(checkpoint)
    # a resumed run continues with fresh start-noise draws (one seed per episode count)
    env.reset(seed=int(seed) * 100_003 + log.n_episodes)
    remaining = 0 if log.stop_reason is not None else int(episodes) - log.n_episodes
    if remaining > 0:
        callbacks = training_callbacks(config, log, episodes, run_dir, progress, part)
        events = callbacks.callbacks[-1]
        assert isinstance(events, EpisodeEvents)
        # exactly the remaining episodes' steps; a logger without outputs (SB3's default one creates a temp folder)
        model.set_logger(Logger(folder=None, output_formats=[]))
        try:
            steps = remaining * config.episode_agent_steps
            model.learn(total_timesteps=steps, callback=callbacks, reset_num_timesteps=log.n_episodes == 0)
        finally:
            events.close()
        if not log.evaluations or log.evaluations[-1]["episode"] != log.n_episodes:
            events.evaluate()
        events.checkpoint()  # so that a longer run can resume from the end of this one
    check_finite_weights(model, f"{algo} seed {seed}, final agent")
    save_agent_file(model, run_dir / "agent.zip")
    log.save(run_dir / "log.json")
    return model, log


def train_dqn(
    config: DQNConfig, seed: int, episodes: int, run_dir: Path | str, resume: bool = False, progress: bool = True
) -> tuple[DQN, TrainingLog]:
    """Train model-free DQN for ``episodes`` training episodes (see the module docstring)."""
    return run_training("dqn", config, seed, episodes, run_dir, resume, progress)


def load_agent(run_dir: Path | str, which: str = "best") -> tuple[DQN, DQNConfig]:
    """An agent of a run folder and its config."""
    one_of("which", which, ("best", "final"))
    path = Path(run_dir)
    folder, agent = (path.parent, path) if path.suffix == ".zip" else (path, path / "agent.zip")
    if path.suffix != ".zip" and which == "best" and (path / "best_agent.zip").exists():  # else: no evaluations
        agent = path / "best_agent.zip"
    if not agent.exists():
        raise FileNotFoundError(f"no agent at {agent}")
    config = load_config(folder / "config.json")
    return load_agent_file(agent_class(config), agent, config), config
