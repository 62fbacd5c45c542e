"""The host-side control loop: any controller against a rig (real or emulated) through :class:`MotorLink`.

The loop is paced by the device's STATE stream (100 Hz): for each state it builds a
:class:`RigObservation`, asks the controller for a torque, sends it (clamped by the driver) and appends the
sample to a crash-safe :class:`SampleLog` *before* anything else can fail.  Whatever goes wrong -- controller
exception, link error -- the motor gets zero torque: any exception sends STOP and propagates (the sample that
was being processed is still logged, with the torque actually commanded).

This loop hands a controller what the encoder measures at that tick (hub angle and rate) -- enough for programs
of time and hub angle such as babbling.  Controllers of the project, which
need the joint state or the observed variables with their rates, run in
:func:`softpend.hardware.closed_loop.run_closed_loop`, behind the state estimator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from softpend.checks import positive
from softpend.hardware.driver import MotorLink, MotorState
from softpend.io.samplelog import SampleLog

__all__ = [
    "LOOP_LOG_COLUMNS",
    "LoopResult",
    "RigObservation",
    "run_control_loop",
]

#: Columns of the motor log written by :func:`run_control_loop`.
LOOP_LOG_COLUMNS: tuple[str, ...] = (
    "host_time_s",
    "device_time_s",
    "state_seq",
    "phi_rad",
    "phi_dot_rad_s",
    "applied_torque_nm",
    "command_torque_nm",
    "flags",
)


@dataclass(frozen=True)
class RigObservation:
    """What a controller sees on the rig.

    Attributes
    ----------
    time_s : float
        Device time since the start of the loop [s].
    phi_rad : float
        Hub angle from upright, unwrapped [rad].
    phi_dot_rad_s : float
        Hub rate [rad/s].
    """

    time_s: float
    phi_rad: float
    phi_dot_rad_s: float


@dataclass
class LoopResult:
    """Summary of one loop run: samples processed, periods between commands, dropped/bad counts."""

    samples: int
    command_periods_s: np.ndarray
    dropped_states: int
    bad_frames: int
    watchdog_trips: int

    @property
    def jitter_ms_p95(self) -> float:
        """95th percentile of ``|period - median period|`` between consecutive torque commands [ms]."""
        return jitter_ms_p95(self.command_periods_s)


class SecondsBar:
    """A progress bar over the seconds of a loop run (``enabled=False``: does nothing); it redraws only when
    the shown tenth of a second changes, so a 100 Hz loop does not redraw every tick."""

    def __init__(self, duration_s: float, desc: str, enabled: bool = True) -> None:
        self.duration_s = duration_s
        self._bar = None
        if enabled:
            from tqdm.auto import tqdm

            self._bar = tqdm(total=round(duration_s, 1), unit="s", desc=desc, mininterval=0.5)

    def advance(self, time_s: float) -> bool:
        """Show ``time_s`` [s] of run time; True when the bar moved (the moment to refresh a postfix)."""
        if self._bar is None:
            return False
        shown = round(min(time_s, self.duration_s), 1)
        if shown <= self._bar.n:
            return False
        self._bar.update(round(shown - self._bar.n, 1))
        return True

    def postfix(self, text: str) -> None:
        if self._bar is not None:
            self._bar.set_postfix_str(text, refresh=False)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def jitter_ms_p95(command_periods_s: np.ndarray) -> float:
    """95th percentile of ``|period - median period|`` over the periods between consecutive torque commands
    [ms] (NaN without periods)."""
    periods = np.asarray(command_periods_s, dtype=float)
    if periods.size == 0:
        return math.nan
    return float(np.percentile(np.abs(periods - float(np.median(periods))), 95) * 1e3)


def run_control_loop(
    link: MotorLink,
    controller: Callable[[RigObservation, float], float],
    duration_s: float,
    log: Optional[SampleLog] = None,
    progress: bool = False,
) -> LoopResult:
    """Run ``controller`` on the rig behind ``link`` for ``duration_s`` of device time.

    Parameters
    ----------
    link : MotorLink
        An open link.
    controller : callable
        ``controller(observation: RigObservation, time_s) -> torque_nm``.
    duration_s : float
        Run length in device time [s].
    log : SampleLog, optional
        Log with columns :data:`LOOP_LOG_COLUMNS`; one line per received state, written before the next.
    progress : bool
        Show a tqdm progress bar.

    Returns
    -------
    LoopResult

    Raises
    ------
    LinkError
        From the driver (the motor has been stopped); the samples up to the failure are in ``log``.
    """
    positive("duration_s", duration_s)
    if not link.is_open:
        raise ValueError("link must be open")
    if log is not None and list(log.columns) != list(LOOP_LOG_COLUMNS):
        raise ValueError(f"log must have the columns LOOP_LOG_COLUMNS, got {log.columns}")
    bar = SecondsBar(duration_s, "rig loop", progress)
    send_times: list[float] = []
    samples = dropped = watchdog = 0
    t0_device: Optional[float] = None
    last_state: Optional[MotorState] = None
    nominal_period = 1.0 / link.device.state_rate_hz if link.device else 0.01
    try:
        while True:
            state = link.read_state()
            if t0_device is None:
                t0_device = state.device_time_s
            t = state.device_time_s - t0_device
            if last_state is not None:
                gap = state.device_time_s - last_state.device_time_s
                dropped += max(0, int(round(gap / nominal_period)) - 1)
            last_state = state
            watchdog += int(state.watchdog_tripped)
            try:
                link.send_torque(float(controller(RigObservation(t, state.phi_rad, state.phi_dot_rad_s), t)))
            except BaseException:
                link.emergency_stop()  # zero torque first, so the log records what is in force
                raise
            finally:
                send_times.append(link.clock.now_s())
                if log is not None:
                    log.append(
                        [
                            state.host_time_s,
                            state.device_time_s,
                            state.seq,
                            state.phi_rad,
                            state.phi_dot_rad_s,
                            state.applied_torque_nm,
                            link.last_command_nm,
                            state.flags,
                        ]
                    )
            samples += 1
            bar.advance(t)
            if t >= duration_s:
                break
    except BaseException:
        link.emergency_stop()
        raise
    finally:
        bar.close()
    link.send_torque(0.0)
    return LoopResult(samples, np.diff(send_times), dropped, link.bad_frames, watchdog)
