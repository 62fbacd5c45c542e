"""Any controller of the project on a rig (real or the digital twin): encoder and camera in, torque out.

:func:`run_closed_loop` runs the rig loop (:class:`~softpend.hardware.loop.RigLoop`), paced by the device's
STATE stream (100 Hz).  For each state it

1. feeds the encoder sample to the :class:`~softpend.hardware.estimator.RigStateEstimator` (every state, also
   the ones that queued up while the host was busy);
2. hands the controller what it was designed for -- ``controller(observation, q, q_dot, time_s)`` with the
   estimate (the :class:`softpend.evaluation.Controller` protocol) -- and sends the torque, which the driver
   clamps to the torque limit;
3. then feeds every camera measurement that arrived since the last state
   (:class:`~softpend.vision.tip_source.TipSource`), placed at its capture time on the device clock
   (:class:`~softpend.hardware.estimator.DeviceClock`): its correction reaches the next state's estimate, and
   the replay of the model from the capture time stays off the path from state to command, whose duration
   sets the loop's jitter;
4. appends the sample, the estimate and the command to a crash-safe motor log (one line per state, written
   before anything else can fail) and each camera measurement to a camera log.

Control starts ("arms") with the first camera frame that corrects the estimate (zero torque until then,
at most ``arm_timeout_s``).  The motor gets zero torque on every exit path: the run completing (STOP), a
camera that has not corrected the estimate for ``max_blind_s`` (a *safe stop*: STOP, reason in the
result and the log's ``status`` column, no exception), and any exception -- controller, estimator, link,
Ctrl-C -- (STOP, the sample being processed logged with the torque actually in force, then the exception
propagates).  The device watchdog stops the motor if the host itself dies.

:func:`run_twin_control` runs the same loop on the digital twin in simulated time: the device
(:class:`~softpend.hardware.emulator.SimRig`) behind the real protocol bytes and the real driver, the synthetic
live camera filming it (:class:`~softpend.vision.tip_source.SyntheticLiveCamera`), all on one
:class:`~softpend.hardware.clock.SimClock`; the same start and seeds give the same logs, bit for bit.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Optional

import numpy as np

from softpend.checks import non_negative, positive
from softpend.hardware.driver import MotorLink
from softpend.hardware.estimator import DeviceClock, EstimatorConfig, RigStateEstimator
from softpend.hardware.loop import RigLoop, SecondsBar, jitter_ms_p95
from softpend.io.samplelog import SampleLog
from softpend.plant import OBSERVATION_NAMES

__all__ = [
    "CAMERA_LOG_COLUMNS",
    "STATUS_CODES",
    "ClosedLoopResult",
    "TwinCamera",
    "TwinControlRun",
    "measure_one_way_latency_s",
    "rig_control_columns",
    "run_closed_loop",
    "run_twin_control",
]

#: ``status`` column of the motor log: what the loop was doing when it wrote the row.
STATUS_CODES: dict[str, int] = {
    "arming": 0,  # waiting for the first camera correction (zero torque)
    "running": 1,
    "completed": 2,  # the last sample of a run that lasted its duration
    "camera_blind": 3,  # safe stop: no camera correction for max_blind_s
    "arm_timeout": 4,  # safe stop: the camera never corrected the estimate
    "error": 5,  # an exception (controller, estimator, link, interrupt): STOP, then it propagates
}

#: Columns of the camera log.
CAMERA_LOG_COLUMNS: tuple[str, ...] = (
    "frame",
    "capture_host_time_s",
    "delivered_host_time_s",
    "polled_host_time_s",
    "capture_device_time_s",
    "x_m",
    "y_m",
    "theta_rad",
    "lost",
    "accepted",
)


def rig_control_columns(n_coordinates: int) -> list[str]:
    """Columns of the motor log of :func:`run_closed_loop` for a model with ``n_coordinates`` coordinates."""
    return (
        [
            "host_time_s",
            "device_time_s",
            "time_s",
            "state_seq",
            "phi_rad",
            "phi_dot_rad_s",
            "applied_torque_nm",
            "flags",
            "command_torque_nm",
            "commanded",
            "late_command",
            "camera_frames",
            "blind_s",
            "est_time_s",
        ]
        + [f"est_{name}" for name in OBSERVATION_NAMES]
        + [f"est_q{i}_rad" for i in range(n_coordinates)]
        + [f"est_q{i}_dot_rad_s" for i in range(n_coordinates)]
        + ["est_tip_std_m", "status"]
    )


@dataclass
class ClosedLoopResult:
    """Summary of one :func:`run_closed_loop` run.

    Attributes
    ----------
    samples : int
        States processed (rows of the motor log).
    duration_s : float
        Device time from the first to the last state [s].
    stop_reason : str or None
        Why the loop stopped before ``duration_s`` (a safe stop), None when it ran its course.
    status : str
        Key of :data:`STATUS_CODES` of the last row.
    command_periods_s : ndarray
        Time between consecutive torque commands on the link's clock [s].
    late_commands : int
        Commands that the device had not received by its next tick (the state after them still reported
        the previous command in force).
    dropped_states, bad_frames, watchdog_trips : int
        Link figures.
    blind_max_s : float
        Longest time without a camera correction while armed [s].
    armed_at_s : float
        Time control started (first camera correction) [s] (NaN if never).
    camera, estimator : dict
        The tip source's and the estimator's counters.
    """

    samples: int
    duration_s: float
    stop_reason: Optional[str]
    status: str
    command_periods_s: np.ndarray
    late_commands: int
    dropped_states: int
    bad_frames: int
    watchdog_trips: int
    blind_max_s: float
    armed_at_s: float
    camera: dict = field(default_factory=dict)
    estimator: dict = field(default_factory=dict)

    @property
    def jitter_ms_p95(self) -> float:
        """95th percentile of ``|period - median period|`` between consecutive torque commands [ms]."""
        return jitter_ms_p95(self.command_periods_s)

    def summary(self) -> dict[str, Any]:
        """The figures as a JSON-ready dict."""
        return {
            "samples": self.samples,
            "duration_s": self.duration_s,
            "stop_reason": self.stop_reason,
            "status": self.status,
            "late_commands": self.late_commands,
            "dropped_states": self.dropped_states,
            "bad_frames": self.bad_frames,
            "watchdog_trips": self.watchdog_trips,
            "blind_max_s": self.blind_max_s,
            "armed_at_s": self.armed_at_s,
            "jitter_ms_p95": self.jitter_ms_p95,
            "camera": self.camera,
            "estimator": self.estimator,
        }


class _SafeStop(Exception):
    def __init__(self, status: str, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.reason = reason


def measure_one_way_latency_s(link: MotorLink, pings: int = 5) -> float:
    """Half the shortest HEARTBEAT round trip of ``pings`` [s]."""
    return min(link.ping() for _ in range(max(1, int(pings)))) / 2


def run_closed_loop(
    link: MotorLink,
    controller: Any,
    estimator: RigStateEstimator,
    duration_s: float,
    tip_source: Any = None,
    log: Optional[SampleLog] = None,
    camera_log: Optional[SampleLog] = None,
    clock: Optional[DeviceClock] = None,
    arm_timeout_s: float = 2.0,
    progress: bool = False,
    on_sample: Optional[Callable[[dict], None]] = None,
) -> ClosedLoopResult:
    """Run ``controller`` on the rig behind ``link`` for ``duration_s`` of device time (module docstring).

    Parameters
    ----------
    link : MotorLink
        An open link.
    controller : Controller
        ``reset()`` (optional) and ``controller(observation, q, q_dot, time_s) -> torque_nm``.
    estimator : RigStateEstimator
        The state estimator (reset by this function at the first state).
    duration_s : float
        Run length from the first state [s].
    tip_source : TipSource, optional
        The camera (started by the caller).  Without one, control starts at once and the estimate rests
        on the encoder and the model alone (no blindness limit).
    log : SampleLog, optional
        Motor log with columns :func:`rig_control_columns` of the estimator's model.
    camera_log : SampleLog, optional
        Camera log with columns :data:`CAMERA_LOG_COLUMNS`.
    clock : DeviceClock, optional
        Host-to-device clock map (default: one with half a measured HEARTBEAT round trip as latency).
    arm_timeout_s : float
        Longest wait for the first camera correction [s].
    progress : bool
        Show a progress bar with the estimated tip angle, the torque and the camera's blind time.
    on_sample : callable, optional
        Called with each motor-log row as a dict (after it is logged).

    Returns
    -------
    ClosedLoopResult

    Raises
    ------
    LinkError, ValueError, SimulationDiverged, KeyboardInterrupt, or what the controller raises
        After STOP; the samples up to and including the failing one are in ``log``.
    """
    _check_loop_arguments(link, estimator, duration_s, arm_timeout_s, log, camera_log)
    if clock is None:
        clock = DeviceClock(measure_one_way_latency_s(link))
    if hasattr(controller, "reset"):
        controller.reset()
    link.drain_states()  # states queued before the run (pings, set-up) are stale
    bar = SecondsBar(duration_s, "rig control", progress)
    loop = _ClosedLoop(link, controller, estimator, duration_s, tip_source, clock, arm_timeout_s)
    loop.log, loop.camera_log, loop.on_sample = log, camera_log, on_sample
    loop.run(bar)
    link.stop()
    return loop.result()


def _check_loop_arguments(
    link: MotorLink,
    estimator: RigStateEstimator,
    duration_s: float,
    arm_timeout_s: float,
    log: Optional[SampleLog],
    camera_log: Optional[SampleLog],
) -> None:
    """Raise ``ValueError`` for arguments :func:`run_closed_loop` cannot run with."""
    positive("duration_s", duration_s)
    non_negative("arm_timeout_s", arm_timeout_s)
    if not link.is_open:
        raise ValueError("link must be open")
    if log is not None and list(log.columns) != rig_control_columns(estimator.n):
        raise ValueError(f"log must have the columns rig_control_columns({estimator.n}), got {log.columns}")
    if camera_log is not None and list(camera_log.columns) != list(CAMERA_LOG_COLUMNS):
        raise ValueError(f"camera_log must have the columns CAMERA_LOG_COLUMNS, got {camera_log.columns}")


@contextlib.contextmanager
def _one_torch_thread() -> Iterator[None]:
    """A learned controller evaluates one small network per state: torch on one thread while the loop runs
    (torch is not imported for this)."""
    torch = sys.modules.get("torch")
    torch_threads = torch.get_num_threads() if torch is not None else None
    if torch is not None:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        if torch is not None:
            torch.set_num_threads(torch_threads)


@dataclass
class _Tick:
    """What one state's row records, filled in as the state is processed (an exception leaves it partial)."""

    late_flag: int
    row_status: str
    estimate_values: list[float]
    frames: int = 0
    commanded: int = 0


class _ClosedLoop(RigLoop):
    """The counters and the per-state step of one :func:`run_closed_loop` run."""

    drains = True
    log: Optional[SampleLog] = None
    camera_log: Optional[SampleLog] = None
    on_sample: Optional[Callable[[dict], None]] = None

    def __init__(
        self,
        link: MotorLink,
        controller: Any,
        estimator: RigStateEstimator,
        duration_s: float,
        tip_source: Any,
        clock: DeviceClock,
        arm_timeout_s: float,
    ) -> None:
        super().__init__(link, duration_s, 1.0 / link.device.state_rate_hz if link.device else estimator.dt_s)
        self.controller, self.estimator, self.tip_source = controller, estimator, tip_source
        self.clock, self.arm_timeout_s = clock, arm_timeout_s
        self.columns = rig_control_columns(estimator.n)
        self.nan_estimate = [math.nan] * (1 + len(OBSERVATION_NAMES) + 2 * estimator.n + 1)
        self.estimate_values = self.nan_estimate
        self.late = 0
        self.expected_cmd_seq: Optional[int] = None
        self.armed = tip_source is None
        self.armed_at = 0.0 if self.armed else math.nan
        self.blind_max = 0.0
        self.status = "arming" if not self.armed else "running"

    def run(self, bar: SecondsBar) -> None:
        with _one_torch_thread():
            super().run(bar)

    def show(self, bar: SecondsBar) -> None:
        if bar.advance(self.t):
            values = self.estimate_values
            theta = values[2] if values is not self.nan_estimate else math.nan
            bar.postfix(
                f"theta {theta:+.2f} rad, torque {self.link.last_command_nm:+.3f} N m, "
                f"blind {self.estimator.blind_s * 1e3:.0f} ms"
            )

    def step(self, state: Any, newest: bool) -> None:
        """Process one state (the command and the camera only for the ``newest`` of a batch), log its row."""
        tick = _Tick(self._count(state), self.status, self.nan_estimate)
        try:
            estimator = self.estimator
            if not estimator.started:
                estimator.reset(self.t, state.phi_rad, state.phi_dot_rad_s, state.applied_torque_nm)
            else:
                estimator.update_encoder(self.t, state.phi_rad, state.phi_dot_rad_s, state.applied_torque_nm)
            if newest:
                self._check_safety()
                self._command(tick)
                if self.tip_source is not None:
                    self._poll_camera(tick)
            tick.row_status = self.status
        except _SafeStop as stop:
            self.link.stop()
            self.status = tick.row_status = stop.status
            self.stop_reason = stop.reason
        except BaseException:
            self.link.emergency_stop()  # zero torque first, so the log records what is in force
            tick.row_status = "error"
            raise
        finally:
            if newest and self.stop_reason is None and tick.row_status != "error" and self.t >= self.duration_s:
                tick.row_status = "completed"
            self._log_row(state, tick)
        self.samples += 1
        self.estimate_values = tick.estimate_values

    def _count(self, state: Any) -> int:
        """Clock, time and link counters of one state; return its late-command flag."""
        self.clock.observe(state.host_time_s, state.device_time_s)
        self.count(state)
        late_flag = int(self.expected_cmd_seq is not None and state.last_cmd_seq != self.expected_cmd_seq)
        self.late += late_flag
        self.expected_cmd_seq = None
        return late_flag

    def _check_safety(self) -> None:
        """Raise :class:`_SafeStop` for a camera blind for too long or one that never corrected the estimate."""
        estimator = self.estimator
        if self.armed and self.tip_source is not None:
            self.blind_max = max(self.blind_max, estimator.blind_s)
            if estimator.is_blind:
                raise _SafeStop(
                    "camera_blind",
                    f"no camera correction for {estimator.blind_s:.3f} s "
                    f"(max_blind_s {estimator.config.max_blind_s} s) at t = {self.t:.2f} s",
                )
        if not self.armed and self.t > self.arm_timeout_s:
            raise _SafeStop(
                "arm_timeout",
                f"the camera did not correct the estimate within arm_timeout_s = {self.arm_timeout_s} s",
            )

    def _command(self, tick: _Tick) -> None:
        """Estimate, ask the controller (zero torque until armed), send the torque."""
        estimate = self.estimator.estimate()
        tick.estimate_values = (
            [estimate.time_s]
            + list(estimate.observation)
            + list(estimate.q)
            + list(estimate.q_dot)
            + [estimate.tip_std_m]
        )
        command = (
            float(self.controller(estimate.observation, estimate.q, estimate.q_dot, estimate.time_s))
            if self.armed
            else 0.0
        )
        self.expected_cmd_seq = self.link.send_torque(command)
        self.send_times.append(self.link.clock.now_s())
        tick.commanded = int(self.armed)

    def _poll_camera(self, tick: _Tick) -> None:
        """Feed the camera measurements that arrived to the estimator (the first accepted one arms the loop).

        They come after the command: the costly replay of a delayed frame (see RigStateEstimator.update_tip)
        stays off the path from state to command, and the corrected estimate serves the next state."""
        assert self.t0 is not None
        polled = self.link.clock.now_s()
        for m in self.tip_source.poll():
            tick.frames += 1
            capture = self.clock.to_device(m.capture_time_s) - self.t0
            accepted = (not m.lost) and self.estimator.update_tip(capture, m.x_m, m.y_m)
            if accepted and not self.armed:
                self.armed, self.armed_at, self.status = True, self.t, "running"
            if self.camera_log is not None:
                self.camera_log.append(
                    [
                        m.frame,
                        m.capture_time_s,
                        m.delivered_time_s,
                        polled,
                        capture,
                        m.x_m,
                        m.y_m,
                        m.theta_rad,
                        m.lost,
                        accepted,
                    ]
                )

    def _log_row(self, state: Any, tick: _Tick) -> None:
        """Append the state's row to the motor log and hand it to ``on_sample``."""
        row = [
            state.host_time_s,
            state.device_time_s,
            self.t,
            state.seq,
            state.phi_rad,
            state.phi_dot_rad_s,
            state.applied_torque_nm,
            state.flags,
            self.link.last_command_nm,
            tick.commanded,
            tick.late_flag,
            tick.frames,
            self.estimator.blind_s if self.estimator.started else math.nan,
            *tick.estimate_values,
            STATUS_CODES[tick.row_status],
        ]
        if self.log is not None:
            self.log.append(row)
        if self.on_sample is not None:
            self.on_sample(dict(zip(self.columns, row)))

    def result(self) -> ClosedLoopResult:
        """The run's :class:`ClosedLoopResult` (after the STOP)."""
        tip_source = self.tip_source
        return ClosedLoopResult(
            samples=self.samples,
            duration_s=self.t,
            stop_reason=self.stop_reason,
            status=self.status if self.stop_reason is not None else "completed",
            command_periods_s=np.diff(self.send_times),
            late_commands=self.late,
            dropped_states=self.dropped,
            bad_frames=self.link.bad_frames,
            watchdog_trips=self.watchdog,
            blind_max_s=self.blind_max,
            armed_at_s=self.armed_at,
            camera=tip_source.stats() if tip_source is not None and hasattr(tip_source, "stats") else {},
            estimator=self.estimator.stats(),
        )


# ---------------------------------------------------------------------- the digital twin
@dataclass(frozen=True)
class TwinCamera:
    """The synthetic live camera of the twin (:class:`softpend.vision.tip_source.SyntheticLiveCamera`).

    Parameters
    ----------
    fps : float
        Frame rate [1/s].
    latency_s : float
        End of exposure to arrival at the tracker [s].
    effects : CameraEffects, optional
        Default :meth:`~softpend.vision.camera.CameraEffects.rig`.
    model : CameraModel, optional
        Default 640x480.
    faults : CameraFaults, optional
        Injected stalls, drops, occlusions.
    seed : int
        Seed of the image noise.
    """

    fps: float = 60.0
    latency_s: float = 0.02
    effects: Any = None
    model: Any = None
    faults: Any = None
    seed: int = 0


@dataclass
class TwinControlRun:
    """Files and figures of one :func:`run_twin_control` run."""

    workdir: Path
    motor_log: Path
    camera_log: Path
    truth_log: Path
    result: ClosedLoopResult
    emulator_stats: dict
    error: Optional[str] = None


#: The files :func:`run_twin_control` writes in its folder (the three logs first).
TWIN_CONTROL_FILES = ("motor_log.csv", "camera_log.csv", "truth_log.csv", "summary.json")


def run_twin_control(
    controller: Any,
    workdir: str | Path,
    duration_s: float,
    rig: Optional[Any] = None,
    camera: Optional[TwinCamera] = TwinCamera(),
    estimator_config: Optional[EstimatorConfig] = None,
    arm_timeout_s: float = 2.0,
    progress: bool = False,
    on_frame: Optional[Callable] = None,
    camera_wait_s: float = 1.0,
    outputs: Optional[Any] = None,
) -> TwinControlRun:
    """Run ``controller`` on the digital twin, in simulated time, with the synthetic camera in the loop.

    The twin's device (:class:`~softpend.hardware.emulator.SimRig` of ``rig``, default
    :class:`~softpend.hardware.emulator.RigConfig`) writes a truth log; the synthetic camera (``camera``; None:
    no camera, encoder and model only) films it from the start; once it has tracked a frame (within
    ``camera_wait_s``) the driver connects over the in-memory link and :func:`run_closed_loop` runs.  Writes
    ``motor_log.csv``, ``camera_log.csv``, ``truth_log.csv`` and ``summary.json`` to ``workdir`` (created)
    through ``outputs`` (a :class:`softpend.io.outputs.Outputs`; default a new one): before the run, a file of
    these names that an earlier run did not write raises ``ValueError`` (nothing is changed).  The truth log goes on 0.1 s past the end, so that it records
    the motor after the STOP on every exit path.
    """
    from softpend.hardware.clock import SimClock
    from softpend.hardware.emulator import RigConfig, SimRig
    from softpend.io.outputs import Outputs

    rig = rig if rig is not None else RigConfig()
    outputs = outputs if outputs is not None else Outputs()
    workdir = outputs.folder(workdir, TWIN_CONTROL_FILES, what="workdir")
    paths = {name: workdir / name for name in TWIN_CONTROL_FILES}
    for name in TWIN_CONTROL_FILES[:3]:
        outputs.live(paths[name])
    estimator = RigStateEstimator(
        rig.task,
        estimator_config if estimator_config is not None else EstimatorConfig(counts_per_rev=rig.counts_per_rev),
    )
    metadata = {
        "rig": rig.to_dict(),
        "estimator": dataclasses.asdict(estimator.config),
        "camera": None if camera is None else {"fps": camera.fps, "latency_s": camera.latency_s, "seed": camera.seed},
    }
    clock = SimClock()
    device = SimRig(rig, clock, truth_log=paths["truth_log.csv"])
    source = None
    try:
        if camera is not None:
            source = _twin_tip_source(camera, device, clock, on_frame)
            _wait_for_first_frame(source, clock, camera_wait_s)
        with (
            MotorLink("twin", torque_limit_nm=rig.task.torque_limit_nm, serial=device.connect()) as link,
            SampleLog(paths["motor_log.csv"], rig_control_columns(estimator.n), metadata=metadata) as log,
            SampleLog(paths["camera_log.csv"], CAMERA_LOG_COLUMNS, metadata=metadata) as camera_log,
        ):
            result = _run_and_summarise(
                lambda: run_closed_loop(
                    link,
                    controller,
                    estimator,
                    duration_s,
                    tip_source=source,
                    log=log,
                    camera_log=camera_log,
                    arm_timeout_s=arm_timeout_s,
                    progress=progress,
                ),
                outputs,
                paths["summary.json"],
            )
    finally:
        if source is not None:
            source.close()
        clock.sleep_until(clock.now_s() + 0.1)  # the truth log records the motor after the STOP
        device.close()
        for name in TWIN_CONTROL_FILES[:3]:
            outputs.done(paths[name])
    return TwinControlRun(
        workdir, paths["motor_log.csv"], paths["camera_log.csv"], paths["truth_log.csv"], result, device.stats(), None
    )


def _twin_tip_source(camera: TwinCamera, device: Any, clock: Any, on_frame: Optional[Callable]) -> Any:
    """The twin's synthetic live camera filming ``device`` (not started)."""
    from softpend.vision.tip_source import SyntheticLiveCamera

    return SyntheticLiveCamera(
        device.poses,
        clock,
        fps=camera.fps,
        latency_s=camera.latency_s,
        effects=camera.effects,
        model=camera.model,
        faults=camera.faults,
        seed=camera.seed,
        on_frame=on_frame,
    )


def _wait_for_first_frame(source: Any, clock: Any, camera_wait_s: float) -> None:
    """Start the twin's camera and wait (in simulated time) until it has tracked a frame; drop the frames of the
    rod before the run (the calibration is fitted on the first)."""
    source.start()
    if not clock.wait_for(lambda: source.frames_tracked > 0, camera_wait_s):
        raise ValueError(
            f"the twin's camera delivered no frame within {camera_wait_s} s (of simulated "
            "time: a camera latency near that, or a dot the tracker cannot find)"
        )
    source.poll()


def _run_and_summarise(run: Callable[[], ClosedLoopResult], outputs: Any, path: Path) -> ClosedLoopResult:
    """Run the loop; write its summary (or its error) to ``path``, also when it raises."""
    result: Optional[ClosedLoopResult] = None
    error: Optional[str] = None
    try:
        result = run()
    except Exception as exc:
        error = f"{type(exc).__name__}: {exc}"
        raise
    finally:
        summary = {"result": result.summary() if result is not None else None, "error": error}
        outputs.write_json(path, summary)
    assert result is not None
    return result
