"""Any controller of the project on a rig (real or the digital twin): encoder and camera in, torque out.

:func:`run_closed_loop` is paced by the device's STATE stream (100 Hz).  For each state it

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

import dataclasses
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from softpend.checks import non_negative, positive
from softpend.hardware.driver import MotorLink
from softpend.hardware.estimator import DeviceClock, EstimatorConfig, RigStateEstimator
from softpend.hardware.loop import SecondsBar, jitter_ms_p95
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
    positive("duration_s", duration_s)
    non_negative("arm_timeout_s", arm_timeout_s)
    if not link.is_open:
        raise ValueError("link must be open")
    columns = rig_control_columns(estimator.n)
    if log is not None and list(log.columns) != columns:
        raise ValueError(f"log must have the columns rig_control_columns({estimator.n}), got {log.columns}")
    if camera_log is not None and list(camera_log.columns) != list(CAMERA_LOG_COLUMNS):
        raise ValueError(f"camera_log must have the columns CAMERA_LOG_COLUMNS, got {camera_log.columns}")
    if clock is None:
        clock = DeviceClock(measure_one_way_latency_s(link))
    if hasattr(controller, "reset"):
        controller.reset()
    link.drain_states()  # states queued before the run (pings, set-up) are stale
    bar = SecondsBar(duration_s, "rig control", progress)
    nominal_period = 1.0 / link.device.state_rate_hz if link.device else estimator.dt_s
    send_times: list[float] = []
    samples = dropped = watchdog = late = 0
    t0: Optional[float] = None
    last_device_time: Optional[float] = None
    expected_cmd_seq: Optional[int] = None
    armed = tip_source is None
    armed_at = 0.0 if armed else math.nan
    blind_max = 0.0
    status = "arming" if not armed else "running"
    stop_reason: Optional[str] = None
    t = 0.0
    nan_estimate = [math.nan] * (1 + len(OBSERVATION_NAMES) + 2 * estimator.n + 1)
    # a learned controller evaluates one small network per state: on one thread (torch is not imported for this)
    torch = sys.modules.get("torch")
    torch_threads = torch.get_num_threads() if torch is not None else None
    if torch is not None:
        torch.set_num_threads(1)
    try:
        while True:
            states = [link.read_state()]
            states += link.drain_states()
            for index, state in enumerate(states):
                newest = index == len(states) - 1
                clock.observe(state.host_time_s, state.device_time_s)
                if t0 is None:
                    t0 = state.device_time_s
                t = state.device_time_s - t0
                if last_device_time is not None:
                    dropped += max(0, int(round((state.device_time_s - last_device_time) / nominal_period)) - 1)
                last_device_time = state.device_time_s
                watchdog += int(state.watchdog_tripped)
                late_flag = int(expected_cmd_seq is not None and state.last_cmd_seq != expected_cmd_seq)
                late += late_flag
                expected_cmd_seq = None
                frames = 0
                commanded = 0
                estimate_values = nan_estimate
                row_status = status
                try:
                    if not estimator.started:
                        estimator.reset(t, state.phi_rad, state.phi_dot_rad_s, state.applied_torque_nm)
                    else:
                        estimator.update_encoder(t, state.phi_rad, state.phi_dot_rad_s, state.applied_torque_nm)
                    if newest and armed and tip_source is not None:
                        blind_max = max(blind_max, estimator.blind_s)
                        if estimator.is_blind:
                            raise _SafeStop(
                                "camera_blind",
                                f"no camera correction for {estimator.blind_s:.3f} s "
                                f"(max_blind_s {estimator.config.max_blind_s} s) at t = {t:.2f} s",
                            )
                    if newest and not armed and t > arm_timeout_s:
                        raise _SafeStop(
                            "arm_timeout",
                            f"the camera did not correct the estimate within arm_timeout_s = {arm_timeout_s} s",
                        )
                    if newest:
                        estimate = estimator.estimate()
                        estimate_values = (
                            [estimate.time_s]
                            + list(estimate.observation)
                            + list(estimate.q)
                            + list(estimate.q_dot)
                            + [estimate.tip_std_m]
                        )
                        command = (
                            float(controller(estimate.observation, estimate.q, estimate.q_dot, estimate.time_s))
                            if armed
                            else 0.0
                        )
                        expected_cmd_seq = link.send_torque(command)
                        send_times.append(link.clock.now_s())
                        commanded = int(armed)
                        if tip_source is not None:
                            # camera measurements after the command: the costly replay of a delayed frame
                            # (see RigStateEstimator.update_tip) stays off the path from state to command, and the
                            # corrected estimate serves the next state
                            polled = link.clock.now_s()
                            for m in tip_source.poll():
                                frames += 1
                                capture = clock.to_device(m.capture_time_s) - t0
                                accepted = (not m.lost) and estimator.update_tip(capture, m.x_m, m.y_m)
                                if accepted and not armed:
                                    armed, armed_at, status = True, t, "running"
                                if camera_log is not None:
                                    camera_log.append(
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
                    row_status = status
                except _SafeStop as stop:
                    link.stop()
                    status = row_status = stop.status
                    stop_reason = stop.reason
                except BaseException:
                    link.emergency_stop()  # zero torque first, so the log records what is in force
                    row_status = "error"
                    raise
                finally:
                    if newest and stop_reason is None and row_status != "error" and t >= duration_s:
                        row_status = "completed"
                    row = [
                        state.host_time_s,
                        state.device_time_s,
                        t,
                        state.seq,
                        state.phi_rad,
                        state.phi_dot_rad_s,
                        state.applied_torque_nm,
                        state.flags,
                        link.last_command_nm,
                        commanded,
                        late_flag,
                        frames,
                        estimator.blind_s if estimator.started else math.nan,
                        *estimate_values,
                        STATUS_CODES[row_status],
                    ]
                    if log is not None:
                        log.append(row)
                    if on_sample is not None:
                        on_sample(dict(zip(columns, row)))
                samples += 1
                if stop_reason is not None:
                    break
            if bar.advance(t):
                theta = estimate_values[2] if estimate_values is not nan_estimate else math.nan
                bar.postfix(
                    f"theta {theta:+.2f} rad, torque {link.last_command_nm:+.3f} N m, "
                    f"blind {estimator.blind_s * 1e3:.0f} ms"
                )
            if stop_reason is not None or t >= duration_s:
                break
    except BaseException:
        link.emergency_stop()
        raise
    finally:
        bar.close()
        if torch is not None:
            torch.set_num_threads(torch_threads)
    link.stop()
    if stop_reason is None:
        status = "completed"
    periods = np.diff(send_times)
    return ClosedLoopResult(
        samples=samples,
        duration_s=t,
        stop_reason=stop_reason,
        status=status,
        command_periods_s=periods,
        late_commands=late,
        dropped_states=dropped,
        bad_frames=link.bad_frames,
        watchdog_trips=watchdog,
        blind_max_s=blind_max,
        armed_at_s=armed_at,
        camera=tip_source.stats() if tip_source is not None and hasattr(tip_source, "stats") else {},
        estimator=estimator.stats(),
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
    from softpend.vision.tip_source import SyntheticLiveCamera

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
    result: Optional[ClosedLoopResult] = None
    error: Optional[str] = None
    clock = SimClock()
    device = SimRig(rig, clock, truth_log=paths["truth_log.csv"])
    source = None
    try:
        if camera is not None:
            source = SyntheticLiveCamera(
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
            source.start()
            if not clock.wait_for(lambda: source.frames_tracked > 0, camera_wait_s):
                raise ValueError(
                    f"the twin's camera delivered no frame within {camera_wait_s} s (of simulated "
                    "time: a camera latency near that, or a dot the tracker cannot find)"
                )
            source.poll()  # frames of the rod before the run (the calibration is fitted on the first)
        with (
            MotorLink("twin", torque_limit_nm=rig.task.torque_limit_nm, serial=device.connect()) as link,
            SampleLog(paths["motor_log.csv"], rig_control_columns(estimator.n), metadata=metadata) as log,
            SampleLog(paths["camera_log.csv"], CAMERA_LOG_COLUMNS, metadata=metadata) as camera_log,
        ):
            try:
                result = run_closed_loop(
                    link,
                    controller,
                    estimator,
                    duration_s,
                    tip_source=source,
                    log=log,
                    camera_log=camera_log,
                    arm_timeout_s=arm_timeout_s,
                    progress=progress,
                )
            except Exception as exc:
                error = f"{type(exc).__name__}: {exc}"
                raise
            finally:
                summary = {"result": result.summary() if result is not None else None, "error": error}
                outputs.write_json(paths["summary.json"], summary)
    finally:
        if source is not None:
            source.close()
        clock.sleep_until(clock.now_s() + 0.1)  # the truth log records the motor after the STOP
        device.close()
        for name in TWIN_CONTROL_FILES[:3]:
            outputs.done(paths[name])
    return TwinControlRun(
        workdir, paths["motor_log.csv"], paths["camera_log.csv"], paths["truth_log.csv"], result, device.stats(), error
    )
