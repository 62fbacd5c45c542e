"""Controllers through the whole rig stack on the digital twin (:func:`twin_start`) beside the same controllers in
the ideal simulator (:func:`simulator_starts`), from the same seeded starts, one row per start; the planner learned
in simulation, on the twin (:func:`planner_twin_figures`), each call's wall time kept (:class:`TimedController`); a
twin run's figures from its logs: the rod's true motion and the torque chatter."""

from __future__ import annotations

import itertools
import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np

from softpend.checks import instance_of, int_at_least, non_negative, positive
from softpend.evaluation import HOLD_STD_RAD, SUCCESS_STD_RAD, evaluate_controller, metrics_from_trajectory
from softpend.hardware.closed_loop import TwinCamera, run_twin_control
from softpend.hardware.driver import LinkError
from softpend.hardware.emulator import RigConfig
from softpend.hardware.estimator import EstimatorConfig
from softpend.io.samplelog import read_sample_log
from softpend.plant import OBSERVATION_NAMES, SimulationDiverged
from softpend.stats import wilson_interval
from softpend.task import Task
from softpend.vision.camera import CameraEffects
from softpend.vision.tip_source import CameraFaults

#: Condition name of the rows of :func:`simulator_starts`.
SIMULATOR = "ideal simulator"
#: Confidence of the Wilson intervals of :func:`summary_rows`.
CONFIDENCE = 0.95
#: Labels of the controllers of :func:`rig_controllers`.
OBSERVATION_SWINGUP = "swing-up + LQR (observations)"
JOINT_SWINGUP = "swing-up + LQR (joint state)"
#: Label of the planner on the rig.
PLANNER = "MPPI planner (PRB + residual)"


@dataclass(frozen=True)
class RigCondition:
    """The rig's sensors and link for a twin run: camera frame rate, latency, image effects and faults, encoder
    resolution, one-way link latency, and the estimator's longest blind bridge before the motor stops."""

    name: str
    fps: float = 60.0
    camera_latency_s: float = 0.02
    effects: CameraEffects = field(default_factory=CameraEffects.rig)
    counts_per_rev: int = 4096
    link_latency_s: float = RigConfig.latency_s
    max_blind_s: float = EstimatorConfig.max_blind_s
    faults: Optional[CameraFaults] = None

    def __post_init__(self) -> None:
        for name in ("fps", "max_blind_s", "camera_latency_s", "link_latency_s"):
            (positive if name in ("fps", "max_blind_s") else non_negative)(name, getattr(self, name))
        instance_of("effects", self.effects, CameraEffects)
        int_at_least("counts_per_rev", self.counts_per_rev, 4)
        if self.faults is not None:
            instance_of("faults", self.faults, CameraFaults)

    def rig(self, task: Task, seed: int) -> RigConfig:
        """The emulated rig of a start seeded ``seed``."""
        return RigConfig(task=task, counts_per_rev=self.counts_per_rev, latency_s=self.link_latency_s, seed=int(seed))

    def camera(self, seed: int) -> TwinCamera:
        """The twin's camera of a start seeded ``seed``."""
        return TwinCamera(
            fps=self.fps, latency_s=self.camera_latency_s, effects=self.effects, faults=self.faults, seed=int(seed)
        )

    def estimator(self) -> EstimatorConfig:
        """The estimator's settings for these sensors."""
        return EstimatorConfig(counts_per_rev=self.counts_per_rev, max_blind_s=self.max_blind_s)


def truth_trajectory(
    truth_log: str | Path, task: Task, start_time_s: float = -math.inf, end_time_s: float = math.inf
) -> dict[str, np.ndarray]:
    """``time_s`` (device), ``theta_rad``, ``torque_nm`` and ``phi_dot_rad_s`` from the emulator's truth log, within
    the device-time window."""
    log, plant = read_sample_log(truth_log), task.make_plant()
    keep = (log["device_time_s"] >= start_time_s) & (log["device_time_s"] <= end_time_s)
    q, qd = (
        np.column_stack([log[f"q{i}{s}"][keep] for i in range(plant.n_coordinates)]) for s in ("_rad", "_dot_rad_s")
    )
    observations = [plant.observation_from_state(a, b) for a, b in zip(q, qd)]
    theta, rate = (np.array([getattr(o, name) for o in observations]) for name in ("theta_rad", "phi_dot_rad_s"))
    time_s, torque = log["device_time_s"][keep], log["applied_torque_nm"][keep]
    return {"time_s": time_s, "theta_rad": theta, "torque_nm": torque, "phi_dot_rad_s": rate}


def truth_metrics(
    truth_log: str | Path,
    task: Task,
    success_std_rad: float = SUCCESS_STD_RAD,
    start_time_s: float = -math.inf,
    end_time_s: float = math.inf,
) -> dict[str, float]:
    """The evaluation's metrics of the true motion in the window; empty for fewer than 3 ticks."""
    t = truth_trajectory(truth_log, task, start_time_s, end_time_s)
    if len(t["time_s"]) < 3:
        return {}
    metrics = metrics_from_trajectory(t["time_s"], t["theta_rad"], t["torque_nm"], t["phi_dot_rad_s"], success_std_rad)
    return {key: (value if isinstance(value, bool) else float(value)) for key, value in metrics.items()}


def run_truth_metrics(
    motor_log: str | Path, truth_log: str | Path, task: Task, success_std_rad: float = SUCCESS_STD_RAD
) -> dict[str, float]:
    """:func:`truth_metrics` from the first command to the motor log's last sample; empty when it never commanded."""
    motor = read_sample_log(motor_log)
    if not (commanded := motor["commanded"] > 0).any():
        return {}
    start_s, end_s = float(motor["device_time_s"][commanded][0]), float(motor["device_time_s"][-1])
    return truth_metrics(truth_log, task, success_std_rad, start_s, end_s)


def torque_chatter_nm_per_s(motor_log: str | Path) -> float:
    """:func:`torque_total_variation_per_s` of the commanded samples of a motor log."""
    log = read_sample_log(motor_log)
    commanded = log["commanded"] > 0
    return torque_total_variation_per_s(log["time_s"][commanded], log["command_torque_nm"][commanded])


def torque_total_variation_per_s(time_s: np.ndarray, torque_nm: np.ndarray) -> float:
    """``sum |tau[k+1] - tau[k]| / (t[-1] - t[0])`` [N m/s]; NaN for fewer than 2 samples or no elapsed time."""
    time_s, torque = np.asarray(time_s, dtype=float), np.asarray(torque_nm, dtype=float)
    if len(torque) < 2 or time_s[-1] <= time_s[0]:
        return float("nan")
    return float(np.sum(np.abs(np.diff(torque))) / (time_s[-1] - time_s[0]))


def rig_controllers(task: Task) -> dict[str, Callable[[], Any]]:
    """Factories of the rig's classical controllers by label: energy swing-up + LQR on the observations and, on the
    PRB plant, on the joint state."""
    from softpend.control.swingup import EnergySwingUpController

    rod, dt = task.rod, task.dt_s
    controllers: dict[str, Callable[[], Any]] = {
        OBSERVATION_SWINGUP: lambda: EnergySwingUpController.for_observations(rod, dt_s=dt)
    }
    if task.plant == "prb":
        controllers[JOINT_SWINGUP] = lambda: EnergySwingUpController(rod, dt_s=dt)
    return controllers


def learned_controller(folder: str | Path, which: str = "final") -> tuple[Any, Task, str]:
    """``(controller, task, label)`` of a PILCO run folder (final policy) or a DQN / DQN-MBPO run folder (agent
    ``which``); ``task`` is the one the run trained on."""
    from softpend.pilco.loop import PilcoResult
    from softpend.rl.dqn import is_run_folder, load_agent
    from softpend.rl.training_env import policy_controller

    folder = Path(folder)
    if (folder / "pilco.json").is_file():
        result = PilcoResult.load(folder)
        return result.controller(), result.config.task, f"PILCO {folder}"
    if not is_run_folder(folder):
        raise ValueError(f"{folder} is not a run folder (no pilco.json, no config.json of a DQN or DQN-MBPO run)")
    model, config = load_agent(folder, which=which)
    return policy_controller(model, config), config.task, f"{type(model).__name__} {folder}"


def _row(
    condition: str, controller: str, seed: int, metrics: Mapping[str, Any], chatter: float, stop: Optional[str]
) -> dict[str, Any]:
    success = bool(metrics.get("success", False)) and stop is None
    row = {"condition": condition, "controller": controller, "seed": int(seed), "success": success}
    for key, missing in (("swing_up_time_s", math.inf), ("upright_std_rad", math.nan), ("peak_torque_nm", math.nan)):
        row[key] = float(metrics.get(key, missing))
    return row | {"torque_chatter_nm_per_s": float(chatter), "stop": stop if stop is not None else ""}


def twin_start(
    controller: Any,
    label: str,
    task: Task,
    condition: RigCondition,
    seed: int,
    duration_s: float,
    workdir: str | Path,
    success_std_rad: float = HOLD_STD_RAD,
    on_frame: Optional[Callable] = None,
    estimator_task: Optional[Task] = None,
) -> dict[str, Any]:
    """One start of ``controller`` on the twin under ``condition`` (logs in ``workdir``): the row of the rod's true
    motion while the controller was in charge and the plant seconds the twin ran; a safe stop, link error or
    diverged estimator is a failed row whose ``stop`` says why.  ``estimator_task``: the estimator's model (default:
    ``task``, the twin's true rod)."""
    positive("duration_s", duration_s)
    workdir, stop, result, plant_s = Path(workdir), None, None, 0.0
    try:
        run = run_twin_control(
            controller,
            workdir,
            duration_s,
            rig=condition.rig(task, seed),
            camera=condition.camera(seed),
            estimator_config=condition.estimator(),
            on_frame=on_frame,
            estimator_task=estimator_task,
        )
        result = run.result
        plant_s = float(run.emulator_stats.get("ticks", 0.0)) * task.dt_s
        if result.stop_reason is not None:
            stop = f"{result.status.replace('_', ' ')}: {result.stop_reason}"
    except LinkError as exc:
        stop = f"link error: {type(exc).__name__}: {exc}"
    except SimulationDiverged as exc:
        stop = f"estimator model diverged: {exc}"
    metrics: dict[str, Any] = {}
    chatter, motor_path, truth_path = math.nan, workdir / "motor_log.csv", workdir / "truth_log.csv"
    if motor_path.is_file() and truth_path.is_file():
        metrics = run_truth_metrics(motor_path, truth_path, task, success_std_rad=success_std_rad)
        chatter = torque_chatter_nm_per_s(motor_path)
    if not metrics and stop is None:
        stop = "the controller never took charge"
    stats = (
        {} if result is None else {**result.camera, "late_commands": result.late_commands, "samples": result.samples}
    )
    counts = {key: int(stats.get(key, 0)) for key in ("late_commands", "samples", "frames_tracked", "frames_lost")}
    return _row(condition.name, label, seed, metrics, chatter, stop) | counts | {"plant_s": plant_s}


def simulator_starts(
    controller: Any,
    label: str,
    task: Task,
    seeds: Sequence[int],
    duration_s: float,
    success_std_rad: float = HOLD_STD_RAD,
) -> list[dict[str, Any]]:
    """The starts ``seeds`` of ``controller`` in the ideal simulator of ``task``, one row each (a diverged
    simulation is a failed row)."""
    summary = evaluate_controller(controller, task, name=label, seeds=list(seeds), duration_s=duration_s)
    rows, theta, rate = [], OBSERVATION_NAMES.index("theta_rad"), OBSERVATION_NAMES.index("phi_dot_rad_s")
    for r in summary.results:
        metrics: dict[str, Any] = {}
        if len(r.time_s) >= 2:
            obs = r.observations
            metrics = metrics_from_trajectory(r.time_s, obs[:, theta], r.torque_nm, obs[:, rate], success_std_rad)
        stop = f"simulation diverged: {r.diverged}" if r.diverged is not None else None
        # the torque of every step the controller commanded (the last sample has none)
        chatter = torque_total_variation_per_s(r.time_s[:-1], r.torque_nm[:-1])
        rows.append(_row(SIMULATOR, label, r.seed, metrics, chatter, stop))
    return rows


def summary_rows(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One row per (condition, controller): success rate with its Wilson interval, median swing-up time and worst
    upright std of the successes, largest peak torque, median torque chatter, and runs that ended early (Wilson
    intervals of :data:`CONFIDENCE`)."""
    groups: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["condition"], row["controller"]), []).append(row)

    def stat(function: Callable, values: list[float]) -> float:
        return float(function(values)) if values else math.nan

    out = []
    for (condition, controller), group in groups.items():
        good, n = [r for r in group if r["success"]], len(group)
        finite = {
            k: [r[k] for r in group if math.isfinite(r[k])] for k in ("torque_chatter_nm_per_s", "peak_torque_nm")
        }
        low, high = wilson_interval(len(good), n, CONFIDENCE)
        summary = {"condition": condition, "controller": controller, "starts": n, "successes": len(good)}
        summary |= {"success_rate": len(good) / n, "success_low": low, "success_high": high}
        summary |= {
            "swing_up_time_s": stat(np.median, [r["swing_up_time_s"] for r in good]),
            "upright_std_rad": stat(max, [r["upright_std_rad"] for r in good]),
            "peak_torque_nm": stat(max, finite["peak_torque_nm"]),
            "torque_chatter_nm_per_s": stat(np.median, finite["torque_chatter_nm_per_s"]),
        }
        out.append(summary | {"stops": sum(bool(r["stop"]) for r in group)})
    return out


class FrameKeeper:
    """An ``on_frame`` hook that keeps every ``every``-th frame as ``(index, frame_bgr, detection)`` in
    :attr:`frames` (at most :attr:`MAX_FRAMES`)."""

    MAX_FRAMES = 200

    def __init__(self, every: int = 15) -> None:
        self.every = int_at_least("every", every, 1)
        self.frames: list[tuple[int, np.ndarray, Any]] = []

    def __call__(self, index: int, frame: np.ndarray, detection: Any, measurement: Any) -> None:
        if index % self.every == 0 and len(self.frames) < self.MAX_FRAMES:
            self.frames.append((int(index), frame.copy(), detection))

    def at_loop_times(self, camera_log: str | Path) -> list[tuple[float, np.ndarray, Any]]:
        """The kept frames the control loop received, as ``(capture time on the loop's clock, frame, detection)``."""
        log = read_sample_log(camera_log)
        capture = dict(zip(log["frame"].astype(int).tolist(), log["capture_device_time_s"].tolist()))
        return [(float(capture[i]), frame, detection) for i, frame, detection in self.frames if i in capture]


def text_figures(
    summary: Sequence[Mapping[str, Any]], controllers: Mapping[str, str], conditions: Mapping[str, str]
) -> dict[str, str]:
    """The figures of :func:`summary_rows` as text, keyed ``<controller key>_<condition key>_<figure>``
    (``controllers`` and ``conditions``: short key -> label)."""

    def fixed(value: float, digits: int) -> str:
        if math.isnan(value):
            return "none"
        return "inf" if math.isinf(value) else f"{value:.{digits}f}"

    by_key = {(r["controller"], r["condition"]): r for r in summary}
    out: dict[str, str] = {}
    for (short, label), (key, condition) in itertools.product(controllers.items(), conditions.items()):
        r = by_key.get((label, condition))
        cells = dict.fromkeys(("success", "interval", "swing_up_s", "std_rad", "chatter", "stops"), "not run")
        if r is not None:
            cells = {
                "success": f"{r['successes']} of {r['starts']}",
                "interval": f"{r['success_low']:.2f} to {r['success_high']:.2f}",
                "swing_up_s": fixed(r["swing_up_time_s"], 2),
                "std_rad": fixed(r["upright_std_rad"], 3),
                "chatter": fixed(r["torque_chatter_nm_per_s"], 2),
                "stops": str(r["stops"]),
            }
        out |= {f"{short}_{key}_{name}": text for name, text in cells.items()}
    return out


class TimedController:
    """``controller(observation, q, q_dot, time_s)`` with each call's wall time kept in :attr:`step_ms` [ms];
    :meth:`reset` clears them and resets ``controller`` where it has a ``reset``.  ``info``: figures of the
    controller to report beside its step times."""

    def __init__(self, controller: Any, info: Optional[Mapping[str, Any]] = None) -> None:
        self.controller, self.info = controller, dict(info or {})
        self.step_ms: list[float] = []

    def reset(self) -> None:
        self.step_ms = []
        if hasattr(self.controller, "reset"):
            self.controller.reset()

    def __call__(self, observation: Any, q: Any, q_dot: Any, time_s: float) -> float:
        started = time.perf_counter()
        try:
            return self.controller(observation, q, q_dot, time_s)
        finally:
            self.step_ms.append((time.perf_counter() - started) * 1e3)


def step_time_figures(step_ms: Sequence[float], control_period_s: float) -> dict[str, float]:
    """Calls timed, median, 95th percentile and largest wall time of a controller's calls [ms] beside its control
    period [ms], and the fraction of calls longer than the period (NaN statistics for no call)."""
    ms = np.asarray(step_ms, dtype=float)
    stats = np.percentile(ms, [50, 95, 100]) if ms.size else np.full(3, math.nan)
    names = ("step_ms_median", "step_ms_p95", "step_ms_max")
    figures = {"steps_timed": int(ms.size)} | dict(zip(names, map(float, stats)))
    over = float(np.mean(ms > control_period_s * 1e3)) if ms.size else math.nan
    return figures | {"control_period_ms": float(control_period_s) * 1e3, "steps_over_period": over}


def planner_twin_figures(
    seeds: Sequence[int], duration_s: float = 10.0, overrides: Optional[Mapping[str, Any]] = None
) -> dict[str, Any]:
    """The planner (:func:`softpend.study.data_efficiency.planner_config` with ``overrides``) learned in simulation on
    the nominal rod, then on the nominal twin from ``seeds`` (fresh starts: seeds shared with its selection starts
    raise ``ValueError``) with torch on one thread: successes of :func:`summary_rows`, the plant seconds it learned
    in, and :func:`step_time_figures` over every controller call of every start."""
    from softpend.control.planner import run_planner
    from softpend.study.data_efficiency import planner_config
    from softpend.torch_threads import one_torch_thread

    task, condition = Task(), RigCondition("nominal twin")
    with one_torch_thread():
        result = run_planner(planner_config(task, overrides), progress=False)
        if shared := sorted(set(int(s) for s in seeds) & set(result.config.selection_seeds)):
            raise ValueError(f"seeds must be fresh starts, disjoint from selection_seeds; shared: {shared}")
        timed, step_ms, rows = TimedController(result.controller), [], []
        with tempfile.TemporaryDirectory() as tmp:
            for seed in seeds:
                rows.append(twin_start(timed, PLANNER, task, condition, seed, duration_s, Path(tmp) / str(seed)))
                step_ms += timed.step_ms
    figures = {"starts": len(rows), "successes": summary_rows(rows)[0]["successes"], "plant_s": result.plant_seconds}
    return figures | step_time_figures(step_ms, task.dt_s) | {"rows": rows}
