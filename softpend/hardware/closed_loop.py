"""The host's rig loops, paced by the STATE stream, STOP on any exception: :func:`run_control_loop` (a program
of time), :func:`run_closed_loop` and :func:`run_twin_control` (a controller behind the state estimator)."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from softpend.checks import positive
from softpend.hardware.driver import MotorLink, MotorState
from softpend.hardware.estimator import DeviceClock, EstimatorConfig, RigStateEstimator
from softpend.io.samplelog import SampleLog
from softpend.plant import OBSERVATION_NAMES
from softpend.torch_threads import one_torch_thread

#: Columns of the motor log written by :func:`run_control_loop`.
LOOP_LOG_COLUMNS: tuple[str, ...] = tuple(
    "host_time_s device_time_s state_seq phi_rad phi_dot_rad_s applied_torque_nm command_torque_nm flags".split()
)


@dataclass(frozen=True)
class RigObservation:
    """What a program sees on the rig: device time since the loop's start [s], hub angle (unwrapped) and rate."""

    time_s: float
    phi_rad: float
    phi_dot_rad_s: float


@dataclass
class LoopResult:
    """Summary of one loop run."""

    samples: int
    command_periods_s: np.ndarray
    dropped_states: int
    bad_frames: int
    watchdog_trips: int

    @property
    def jitter_ms_p95(self) -> float:
        """95th percentile of ``|period - median period|`` between consecutive torque commands [ms]."""
        periods = np.asarray(self.command_periods_s, dtype=float)
        if periods.size == 0:
            return math.nan
        return float(np.percentile(np.abs(periods - float(np.median(periods))), 95) * 1e3)


def _check_run(link: MotorLink, duration_s: float, *logs: tuple[str, Optional[SampleLog], Any, str]) -> None:
    """Raise ``ValueError`` for a loop that cannot run: ``logs`` are ``(name, log, columns, columns' name)``."""
    positive("duration_s", duration_s)
    if not link.is_open:
        raise ValueError("link must be open")
    for name, log, columns, what in logs:
        if log is not None and list(log.columns) != list(columns):
            raise ValueError(f"{name} must have the columns {what}, got {log.columns}")


class _RigLoop:
    """A run paced by the STATE stream: each state (and, if ``drains``, those queued) goes to :meth:`step`."""

    drains = False

    def __init__(
        self, link: MotorLink, controller: Callable, duration_s: float, log: Optional[SampleLog], period_s: float = 0.01
    ) -> None:
        self.link, self.controller, self.duration_s, self.log = link, controller, duration_s, log
        self.nominal_period = 1.0 / link.device.state_rate_hz if link.device else period_s
        self.send_times: list[float] = []
        self.samples = self.dropped = self.watchdog = 0
        self.t0: Optional[float] = None
        self.last_device_time: Optional[float] = None
        self.stop_reason: Optional[str] = None
        self.t = 0.0

    def count(self, state: MotorState) -> None:
        if self.t0 is None:
            self.t0 = state.device_time_s
        self.t = state.device_time_s - self.t0
        if self.last_device_time is not None:
            self.dropped += max(0, int(round((state.device_time_s - self.last_device_time) / self.nominal_period)) - 1)
        self.last_device_time = state.device_time_s
        self.watchdog += int(state.watchdog_tripped)

    def postfix(self) -> str:
        return ""

    def run(self, desc: str, progress: bool) -> None:
        from tqdm.auto import tqdm

        link = self.link
        bar = tqdm(total=round(self.duration_s, 1), unit="s", desc=desc, mininterval=0.5, disable=not progress)
        try:
            while True:
                states = [link.read_state()]
                if self.drains:
                    states += link.drain_states()
                for index, state in enumerate(states):
                    self.step(state, newest=index == len(states) - 1)
                    if self.stop_reason is not None:
                        break
                shown = round(min(self.t, self.duration_s), 1)
                if progress and shown > bar.n:
                    bar.update(round(shown - bar.n, 1))
                    bar.set_postfix_str(self.postfix(), refresh=False)
                if self.stop_reason is not None or self.t >= self.duration_s:
                    break
        except BaseException:
            link.emergency_stop()
            raise
        finally:
            bar.close()

    def counts(self) -> dict[str, Any]:
        """The :class:`LoopResult` fields of the run, by name."""
        return dict(
            samples=self.samples,
            command_periods_s=np.diff(self.send_times),
            dropped_states=self.dropped,
            bad_frames=self.link.bad_frames,
            watchdog_trips=self.watchdog,
        )

    def step(self, state: MotorState, newest: bool) -> None:
        self.count(state)
        link, t = self.link, self.t
        try:
            link.send_torque(float(self.controller(RigObservation(t, state.phi_rad, state.phi_dot_rad_s), t)))
        except BaseException:
            link.emergency_stop()  # zero torque first, so the log records what is in force
            raise
        finally:
            self.send_times.append(link.clock.now_s())
            if self.log is not None:
                names = ("host_time_s", "device_time_s", "seq", "phi_rad", "phi_dot_rad_s", "applied_torque_nm")
                self.log.append([*(getattr(state, name) for name in names), link.last_command_nm, state.flags])
        self.samples += 1


def run_control_loop(
    link: MotorLink,
    controller: Callable[[RigObservation, float], float],
    duration_s: float,
    log: Optional[SampleLog] = None,
    progress: bool = False,
) -> LoopResult:
    """Run ``controller(observation, time_s) -> torque_nm`` on the open ``link`` for ``duration_s`` of device time,
    one row of :data:`LOOP_LOG_COLUMNS` in ``log`` per state; a link error stops the motor and propagates."""
    _check_run(link, duration_s, ("log", log, LOOP_LOG_COLUMNS, "LOOP_LOG_COLUMNS"))
    loop = _RigLoop(link, controller, duration_s, log)
    loop.run("rig loop", progress)
    link.send_torque(0.0)
    return LoopResult(**loop.counts())


#: ``status`` column of the motor log (``camera_blind`` and ``arm_timeout`` are safe stops).
STATUS_CODES: dict[str, int] = {
    name: code for code, name in enumerate(("arming", "running", "completed", "camera_blind", "arm_timeout", "error"))
}

#: Columns of the camera log.
CAMERA_LOG_COLUMNS: tuple[str, ...] = tuple(
    "frame capture_host_time_s delivered_host_time_s polled_host_time_s capture_device_time_s x_m y_m theta_rad "
    "lost accepted".split()
)


def rig_control_columns(n_coordinates: int) -> list[str]:
    return (
        "host_time_s device_time_s time_s state_seq phi_rad phi_dot_rad_s applied_torque_nm flags command_torque_nm "
        "commanded late_command camera_frames blind_s est_time_s".split()
        + [f"est_{name}" for name in OBSERVATION_NAMES]
        + [f"est_q{i}_rad" for i in range(n_coordinates)]
        + [f"est_q{i}_dot_rad_s" for i in range(n_coordinates)]
        + ["est_tip_std_m", "status"]
    )


@dataclass
class ClosedLoopResult(LoopResult):
    """Summary of one :func:`run_closed_loop` run (``status`` a key of :data:`STATUS_CODES`)."""

    duration_s: float
    stop_reason: Optional[str]
    status: str
    late_commands: int
    blind_max_s: float
    armed_at_s: float
    camera: dict
    estimator: dict

    def summary(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "command_periods_s"}
        return {**out, "jitter_ms_p95": self.jitter_ms_p95}


#: Device time the camera has to make its first correction before the loop stops [s].
ARM_TIMEOUT_S = 2.0


class _SafeStop(Exception): ...  # args: (status, reason)


def run_closed_loop(
    link: MotorLink,
    controller: Any,
    estimator: RigStateEstimator,
    duration_s: float,
    tip_source: Any = None,
    log: Optional[SampleLog] = None,
    camera_log: Optional[SampleLog] = None,
    progress: bool = False,
) -> ClosedLoopResult:
    """Run ``controller(observation, q, q_dot, time_s)`` on the open ``link`` for ``duration_s`` of device time (rows
    of :func:`rig_control_columns` in ``log``, of :data:`CAMERA_LOG_COLUMNS` in ``camera_log``), starting at once
    without a ``tip_source``, else at the first camera correction (within :data:`ARM_TIMEOUT_S`)."""
    _check_run(
        link,
        duration_s,
        ("log", log, rig_control_columns(estimator.n), f"rig_control_columns({estimator.n})"),
        ("camera_log", camera_log, CAMERA_LOG_COLUMNS, "CAMERA_LOG_COLUMNS"),
    )
    clock = DeviceClock(min(link.ping() for _ in range(5)) / 2)
    if hasattr(controller, "reset"):
        controller.reset()
    link.drain_states()  # states queued before the run are stale
    loop = _ClosedLoop(link, controller, estimator, duration_s, tip_source, clock, log, camera_log)
    with one_torch_thread() if "torch" in sys.modules else contextlib.nullcontext():  # torch on one thread
        loop.run("rig control", progress)
    link.stop()
    status = loop.status if loop.stop_reason is not None else "completed"
    return ClosedLoopResult(
        **loop.counts(),
        duration_s=loop.t,
        stop_reason=loop.stop_reason,
        status=status,
        late_commands=loop.late,
        blind_max_s=loop.blind_max,
        armed_at_s=loop.armed_at,
        camera=tip_source.stats() if hasattr(tip_source, "stats") else {},
        estimator=estimator.stats(),
    )


class _ClosedLoop(_RigLoop):
    drains = True

    def __init__(self, link, controller, estimator, duration_s, tip_source, clock, log, camera_log) -> None:
        super().__init__(link, controller, duration_s, log, estimator.dt_s)
        self.estimator, self.tip_source, self.clock, self.camera_log = estimator, tip_source, clock, camera_log
        self.nan_estimate = [math.nan] * (1 + len(OBSERVATION_NAMES) + 2 * estimator.n + 1)
        self.estimate_values, self.late, self.blind_max = self.nan_estimate, 0, 0.0
        self.expected_cmd_seq: Optional[int] = None
        self.armed = tip_source is None
        self.armed_at, self.status = (0.0, "running") if self.armed else (math.nan, "arming")

    def postfix(self) -> str:
        theta, torque, blind_ms = self.estimate_values[2], self.link.last_command_nm, self.estimator.blind_s * 1e3
        return f"theta {theta:+.2f} rad, torque {torque:+.3f} N m, blind {blind_ms:.0f} ms"

    def step(self, state: Any, newest: bool) -> None:
        self.clock.observe(state.host_time_s, state.device_time_s)
        self.count(state)
        late = int(self.expected_cmd_seq is not None and state.last_cmd_seq != self.expected_cmd_seq)
        self.late += late
        self.expected_cmd_seq = None
        estimate, frames, commanded, status = self.nan_estimate, 0, 0, self.status
        try:
            measured = (self.t, state.phi_rad, state.phi_dot_rad_s, state.applied_torque_nm)
            (self.estimator.update_encoder if self.estimator.started else self.estimator.reset)(*measured)
            if newest:
                self._check_safety()
                e = self.estimator.estimate()
                estimate = [e.time_s, *e.observation, *e.q, *e.q_dot, e.tip_std_m]
                command = float(self.controller(e.observation, e.q, e.q_dot, e.time_s)) if self.armed else 0.0
                self.expected_cmd_seq = self.link.send_torque(command)
                self.send_times.append(self.link.clock.now_s())
                commanded = int(self.armed)
                if self.tip_source is not None:
                    frames = self._poll_camera()
            status = self.status
        except _SafeStop as stop:
            self.link.stop()
            status, self.stop_reason = stop.args
            self.status = status
        except BaseException:
            self.link.emergency_stop()  # zero torque first, so the log records what is in force
            status = "error"
            raise
        finally:
            if newest and self.stop_reason is None and status != "error" and self.t >= self.duration_s:
                status = "completed"
            if self.log is not None:
                row = [state.host_time_s, state.device_time_s, self.t, state.seq, state.phi_rad, state.phi_dot_rad_s]
                row += [state.applied_torque_nm, state.flags, self.link.last_command_nm, commanded, late, frames]
                blind = self.estimator.blind_s if self.estimator.started else math.nan
                self.log.append([*row, blind, *estimate, STATUS_CODES[status]])
        self.samples += 1
        self.estimate_values = estimate

    def _check_safety(self) -> None:
        estimator = self.estimator
        if self.armed and self.tip_source is not None:
            self.blind_max = max(self.blind_max, estimator.blind_s)
            if estimator.is_blind:
                raise _SafeStop(
                    "camera_blind",
                    f"no camera correction for {estimator.blind_s:.3f} s "
                    f"(max_blind_s {estimator.config.max_blind_s} s) at t = {self.t:.2f} s",
                )
        if not self.armed and self.t > ARM_TIMEOUT_S:
            raise _SafeStop("arm_timeout", f"the camera did not correct the estimate within {ARM_TIMEOUT_S} s")

    def _poll_camera(self) -> int:
        """Feed the camera's new measurements to the estimator, the first accepted one arming the loop; how many."""
        assert self.t0 is not None
        polled = self.link.clock.now_s()
        measurements = self.tip_source.poll()
        for m in measurements:
            capture = self.clock.to_device(m.capture_time_s) - self.t0
            accepted = (not m.lost) and self.estimator.update_tip(capture, m.x_m, m.y_m)
            if accepted and not self.armed:
                self.armed, self.armed_at, self.status = True, self.t, "running"
            if self.camera_log is not None:
                times = [m.capture_time_s, m.delivered_time_s, polled, capture]
                self.camera_log.append([m.frame, *times, m.x_m, m.y_m, m.theta_rad, m.lost, accepted])
        return len(measurements)


@dataclass(frozen=True)
class TwinCamera:
    """Settings of the twin's :class:`softpend.vision.tip_source.SyntheticLiveCamera`."""

    fps: float = 60.0
    latency_s: float = 0.02
    effects: Any = None
    model: Any = None
    faults: Any = None
    seed: int = 0


@dataclass
class TwinControlRun:
    motor_log: Path
    camera_log: Path
    truth_log: Path
    result: ClosedLoopResult
    emulator_stats: dict


#: The files :func:`run_twin_control` writes in its folder (the three logs first).
TWIN_CONTROL_FILES = ("motor_log.csv", "camera_log.csv", "truth_log.csv", "summary.json")


def run_twin_control(
    controller: Any,
    workdir: str | Path,
    duration_s: float,
    rig: Optional[Any] = None,
    camera: Optional[TwinCamera] = TwinCamera(),
    estimator_config: Optional[EstimatorConfig] = None,
    progress: bool = False,
    on_frame: Optional[Callable] = None,
    camera_wait_s: float = 1.0,
    outputs: Optional[Any] = None,
    estimator_task: Optional[Any] = None,
) -> TwinControlRun:
    """Run ``controller`` on the twin ``rig`` in simulated time, filmed by ``camera`` (None: none), writing
    :data:`TWIN_CONTROL_FILES` to ``workdir``; the estimator's model is ``estimator_task`` (default ``rig.task``)."""
    from softpend.hardware.emulator import RigConfig, SimRig
    from softpend.io.outputs import Outputs
    from softpend.vision.tip_source import SyntheticLiveCamera

    rig = rig if rig is not None else RigConfig()
    outputs = outputs if outputs is not None else Outputs()
    workdir = outputs.folder(workdir, TWIN_CONTROL_FILES, what="workdir")
    motor_path, camera_path, truth_path, summary_path = (workdir / name for name in TWIN_CONTROL_FILES)
    logs = (motor_path, camera_path, truth_path)
    for path in logs:
        outputs.live(path)
    config = estimator_config if estimator_config is not None else EstimatorConfig(counts_per_rev=rig.counts_per_rev)
    estimator = RigStateEstimator(estimator_task if estimator_task is not None else rig.task, config)
    metadata = {
        "rig": rig.to_dict(),
        "estimator": dataclasses.asdict(estimator.config),
        "camera": None if camera is None else {"fps": camera.fps, "latency_s": camera.latency_s, "seed": camera.seed},
    }
    try:
        with SimRig(rig, truth_log=truth_path) as device, contextlib.ExitStack() as closing:
            source = None
            if camera is not None:
                source = SyntheticLiveCamera(device.poses, device.clock, **vars(camera), on_frame=on_frame)
                closing.enter_context(contextlib.closing(source)).start()
                if not device.clock.wait_for(lambda: source.counts["frames_tracked"] > 0, camera_wait_s):
                    raise ValueError(
                        f"the twin's camera delivered no frame within {camera_wait_s} s (of simulated "
                        "time: a camera latency near that, or a dot the tracker cannot find)"
                    )
                source.poll()  # the frames of the rod before the run
            with (
                MotorLink("twin", torque_limit_nm=rig.task.torque_limit_nm, serial=device.connect()) as link,
                SampleLog(motor_path, rig_control_columns(estimator.n), metadata=metadata) as log,
                SampleLog(camera_path, CAMERA_LOG_COLUMNS, metadata=metadata) as camera_log,
            ):
                try:
                    result = run_closed_loop(link, controller, estimator, duration_s, source, log, camera_log, progress)
                except BaseException as exc:
                    outputs.write_json(summary_path, {"result": None, "error": f"{type(exc).__name__}: {exc}"})
                    raise
                outputs.write_json(summary_path, {"result": result.summary(), "error": None})
    finally:
        for path in logs:
            outputs.done(path)
    return TwinControlRun(*logs, result, device.stats())
