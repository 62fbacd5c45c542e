"""The twin's side of commissioning, run in a spawned child process: the commissioning hands it the truth only as
a :class:`TwinTruth` (a rod file's path or a seed); the child resolves it, keeps its own files in a private
folder, and hands back what a rig gives its host (motor and camera logs, verification rows)."""

from __future__ import annotations

import concurrent.futures
import multiprocessing
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np

from softpend.checks import int_at_least
from softpend.study.rig_runs import RigCondition
from softpend.study.unknown_rod import DRAW_DURATION_S, DRAW_NEEDED, DRAW_STARTS, UnknownRod, draw_unknown_rod
from softpend.vision.camera import CameraEffects

#: The verification's sensor conditions: the nominal rig camera, and a harsh one (30 fps, 50 ms, noisy image).
CONDITIONS: dict[str, RigCondition] = {
    "nominal": RigCondition("nominal"),
    "harsh": RigCondition("harsh", fps=30.0, camera_latency_s=0.05, effects=CameraEffects.noisy()),
}
#: The files the excitation hands the host (in its public folder).
EXCITATION_FILES = ("motor_log.csv", "camera.csv")
#: How a seeded twin's rod is drawn (:func:`draw_unknown_rod`): hanging starts, of them balanced, their length [s].


@dataclass(frozen=True)
class TwinTruth:
    """Where the twin's unknown rod comes from: ``rod_file`` (a JSON of :meth:`UnknownRod.from_dict`) or ``seed``
    (:func:`draw_unknown_rod`), exactly one."""

    rod_file: Optional[str] = None
    seed: Optional[int] = None

    def __post_init__(self) -> None:
        if (self.rod_file is None) == (self.seed is None):
            raise ValueError("the twin's rod needs exactly one of rod_file (--twin-rod) and seed (--twin-seed)")
        if self.rod_file is not None and not str(self.rod_file).strip():
            raise ValueError("--twin-rod: the path is empty")
        if self.rod_file is not None:
            object.__setattr__(self, "rod_file", str(self.rod_file))
        if self.seed is not None:
            object.__setattr__(self, "seed", int_at_least("--twin-seed", self.seed, 0))

    def to_dict(self) -> dict[str, Any]:
        draw = {"draw_starts": DRAW_STARTS, "draw_needed": DRAW_NEEDED, "draw_duration_s": DRAW_DURATION_S}
        return asdict(self) | draw


def twin_process() -> concurrent.futures.ProcessPoolExecutor:
    """The twin's side: one spawned child process (a fresh interpreter: nothing of this process's state goes
    along but the arguments of each call), started at the first call and kept for the next ones."""
    return concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"))


def on_twin_side(twin: concurrent.futures.Executor, function: Callable[..., Any], *args: Any) -> Any:
    """``function(*args)`` in the ``twin`` process (:func:`twin_process`); its exceptions are raised here."""
    return twin.submit(function, *args).result()


def _resolve(truth: TwinTruth, private: Path, outputs: Any) -> UnknownRod:
    """The unknown rod: read from its file, or drawn from its seed once and kept in ``private/rod.json``."""
    if truth.seed is None:
        return UnknownRod.from_json(str(truth.rod_file))
    path = private / "rod.json"
    if path.is_file():
        return UnknownRod.from_json(path)
    rod, draws = draw_unknown_rod(truth.seed, DRAW_STARTS, DRAW_NEEDED, DRAW_DURATION_S)
    outputs.folder(private, ("rod.json",), what="twin folder")
    outputs.write_json(path, {**rod.to_dict(), "seed": truth.seed, "draws": draws})
    return rod


def excite_on_twin(
    truth: TwinTruth,
    private: str,
    public: str,
    program_nm: Sequence[float],
    duration_s: float,
    trial_length_s: float,
    seed: int,
) -> dict[str, float]:
    """Play ``program_nm`` (after the start-up wiggle) on the twin from hanging at rest, filmed, through the rig's
    own I/O (:func:`softpend.hardware.twin.run_twin_session` in ``private/excite``); copy the motor log (without
    the device's settings) and the tracked camera log into ``public``; the plant seconds and loop counters."""
    from softpend.hardware.closed_loop import LOOP_LOG_COLUMNS
    from softpend.hardware.emulator import RigConfig
    from softpend.hardware.twin import run_twin_session
    from softpend.io.outputs import Outputs
    from softpend.io.samplelog import SampleLog, read_sample_log
    from softpend.task import Task

    outputs, private_dir, public_dir = Outputs(), Path(private), Path(public)
    task = Task(rod=_resolve(truth, private_dir, outputs).effective_rod(), start_noise_rad=0.0)
    rig, program = RigConfig(task=task, seed=seed), np.asarray(program_nm, dtype=float)
    run: dict[str, Any] = dict(trial_length_s=trial_length_s, progress=False, outputs=outputs, program=program)
    session = run_twin_session(private_dir / "excite", duration_s, seed, rig, **run)
    outputs.folder(public_dir, EXCITATION_FILES, what="excitation folder")
    motor, motor_path = read_sample_log(session.motor_log), outputs.live(public_dir / "motor_log.csv")
    metadata = {"rig": "digital twin", "torque_limit_nm": task.torque_limit_nm, "dt_s": task.dt_s}
    with SampleLog(motor_path, LOOP_LOG_COLUMNS, metadata=metadata, fsync_every_s=None) as log:
        for row in zip(*(motor[c] for c in LOOP_LOG_COLUMNS)):
            log.append(row)
    outputs.done(motor_path)
    with open(session.camera_csv, "rb") as source, outputs.open(public_dir / "camera.csv", "wb") as copy:
        copy.write(source.read())
    loop, plant_s = session.loop, float(session.emulator_stats.get("ticks", 0.0)) * task.dt_s
    return {"plant_s": plant_s, "samples": float(loop.samples), "dropped_states": float(loop.dropped_states)}


def verify_on_twin(
    truth: TwinTruth,
    private: str,
    controllers: Mapping[str, Mapping[str, Any]],
    seeds: Sequence[int],
    duration_s: float,
) -> dict[str, dict[str, list[dict[str, Any]]]]:
    """The rows, by controller label of ``controllers`` and by condition of :data:`CONDITIONS`, from the hanging starts ``seeds`` of the
    twin's rod (logs in ``private``) of each controller: ``{"model_rod": rod}``, the energy swing-up + LQR on the
    observations designed on that rod, or ``{"run": folder}``, a DQN, DQN-MBPO or PILCO run's agent; the estimator
    models the controller's rod (the run's task), never the twin's."""
    from softpend.control.identified import design_swingup
    from softpend.io.outputs import Outputs
    from softpend.plant import RodParams
    from softpend.study.rig_runs import learned_controller, twin_start
    from softpend.task import Task

    private_dir = Path(private)
    true_task = Task(rod=_resolve(truth, private_dir, Outputs()).effective_rod())
    out: dict[str, dict[str, list[dict[str, Any]]]] = {}
    for i, (label, spec) in enumerate(controllers.items()):
        if "run" in spec:
            controller, model_task, _ = learned_controller(spec["run"], "best")
            make = lambda: controller  # noqa: E731  (reset by the control loop at each start)
        else:
            model_task = Task(rod=RodParams.from_dict(dict(spec["model_rod"])))
            make = lambda: design_swingup(model_task.rod)  # noqa: E731
        out[label], estimator = {name: [] for name in CONDITIONS}, Task(rod=model_task.rod)
        for name in CONDITIONS:
            for seed in seeds:
                workdir = private_dir / f"model_{i}" / name / f"start_{seed}"
                start = (make(), label, true_task, CONDITIONS[name], seed, duration_s, workdir)
                out[label][name].append(twin_start(*start, estimator_task=estimator))
    return out


def truth_errors(truth: TwinTruth, private: str, estimates: Mapping[str, float]) -> dict[str, dict[str, float]]:
    """The twin's true values of the drawn fields and the torque gain, and ``estimate / truth - 1`` of each
    name in ``estimates`` (for the report, after the commissioning)."""
    from softpend.io.outputs import Outputs

    values = _resolve(truth, Path(private), Outputs()).values()
    errors = {name: float(v) / values[name] - 1.0 for name, v in estimates.items() if name in values}
    return {"truth": values, "relative_error": errors}
