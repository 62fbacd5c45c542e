"""The host-side rig loop: a controller against a rig (real or emulated) through :class:`MotorLink`.

:class:`RigLoop` is the one loop of both programs on the rig.  It is paced by the device's STATE stream
(100 Hz) and hands each state to a step; whatever goes wrong -- controller exception, link error -- the motor
gets zero torque: any exception sends STOP and propagates.

:func:`run_control_loop` (the babbling of :func:`softpend.hardware.twin.run_twin_session` and ``softpend rig
babble``) steps with what the encoder measures at that tick: it builds a :class:`RigObservation` (hub angle
and rate), asks the controller -- a program of time and hub angle such as babbling -- for a torque, sends it
(clamped by the driver) and appends the sample to a crash-safe :class:`SampleLog` *before* anything else can
fail (the sample that was being processed is still logged, with the torque actually commanded).  Controllers
of the project, which need the joint state or the observed variables with their rates, step behind the state
estimator in :func:`softpend.hardware.closed_loop.run_closed_loop`.
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
    "RigLoop",
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


class RigLoop:
    """One run of the rig loop, paced by the device's STATE stream: read a state (with :attr:`drains`, also
    the ones that queued up while the host was busy), hand each to :meth:`step`, until ``duration_s`` of
    device time or a safe stop (:attr:`stop_reason`); any exception sends STOP and propagates.  Subclasses
    say what a state does (:meth:`step`): the babbling loop here, the closed loop behind the state estimator
    in :mod:`softpend.hardware.closed_loop`."""

    #: Process the states that queued up since the last one too (only the newest gets a command).
    drains = False

    def __init__(self, link: MotorLink, duration_s: float, nominal_period_s: float) -> None:
        self.link = link
        self.duration_s = duration_s
        self.nominal_period = nominal_period_s
        self.send_times: list[float] = []
        self.samples = self.dropped = self.watchdog = 0
        self.t0: Optional[float] = None
        self.last_device_time: Optional[float] = None
        self.t = 0.0
        self.stop_reason: Optional[str] = None

    def count(self, state: MotorState) -> None:
        """The loop time of ``state`` and the link counters (dropped states, watchdog trips)."""
        if self.t0 is None:
            self.t0 = state.device_time_s
        self.t = state.device_time_s - self.t0
        if self.last_device_time is not None:
            self.dropped += max(0, int(round((state.device_time_s - self.last_device_time) / self.nominal_period)) - 1)
        self.last_device_time = state.device_time_s
        self.watchdog += int(state.watchdog_tripped)

    def step(self, state: MotorState, newest: bool) -> None:
        """Process one state (``newest``: the last of those read together)."""
        raise NotImplementedError

    def show(self, bar: SecondsBar) -> None:
        """Advance the progress bar after a batch of states."""
        bar.advance(self.t)

    def run(self, bar: SecondsBar) -> None:
        """Process the states until the run's end or a safe stop; any exception: emergency STOP, then it
        propagates.  Closes ``bar``."""
        link = self.link
        try:
            while True:
                states = [link.read_state()]
                if self.drains:
                    states += link.drain_states()
                for index, state in enumerate(states):
                    self.step(state, newest=index == len(states) - 1)
                    if self.stop_reason is not None:
                        break
                self.show(bar)
                if self.stop_reason is not None or self.t >= self.duration_s:
                    break
        except BaseException:
            link.emergency_stop()
            raise
        finally:
            bar.close()


class _BabbleLoop(RigLoop):
    """:func:`run_control_loop`: a command for every state from what the encoder measures."""

    def __init__(
        self,
        link: MotorLink,
        controller: Callable[[RigObservation, float], float],
        duration_s: float,
        log: Optional[SampleLog],
    ) -> None:
        super().__init__(link, duration_s, 1.0 / link.device.state_rate_hz if link.device else 0.01)
        self.controller = controller
        self.log = log

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
                self.log.append(
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
        self.samples += 1


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
    loop = _BabbleLoop(link, controller, duration_s, log)
    loop.run(bar)
    link.send_torque(0.0)
    return LoopResult(loop.samples, np.diff(loop.send_times), loop.dropped, link.bad_frames, loop.watchdog)
