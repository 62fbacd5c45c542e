"""The host's rig loop, paced by the device's STATE stream (STOP on any exception), and :func:`run_control_loop`:
a program of time and hub angle (babbling) on a rig, every state logged before anything else can fail."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Optional, Sequence

import numpy as np

from softpend.checks import positive
from softpend.hardware.driver import MotorLink, MotorState
from softpend.io.samplelog import SampleLog

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


class SecondsBar:
    """A progress bar over the seconds of a run, redrawn when the shown tenth of a second changes."""

    def __init__(self, duration_s: float, desc: str, enabled: bool = True) -> None:
        self.duration_s = duration_s
        self._bar = None
        if enabled:
            from tqdm.auto import tqdm

            self._bar = tqdm(total=round(duration_s, 1), unit="s", desc=desc, mininterval=0.5)

    def advance(self, time_s: float) -> bool:
        """Show ``time_s``; whether the bar moved."""
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


def check_run(link: MotorLink, duration_s: float, logs: Sequence[tuple[str, Optional[Any], Sequence[str], str]]):
    """Raise ``ValueError`` for a loop that cannot run: ``logs`` are ``(name, log, columns, columns' name)``."""
    positive("duration_s", duration_s)
    if not link.is_open:
        raise ValueError("link must be open")
    for name, log, columns, what in logs:
        if log is not None and list(log.columns) != list(columns):
            raise ValueError(f"{name} must have the columns {what}, got {log.columns}")


class RigLoop:
    """One run paced by the STATE stream: each state read goes to :meth:`step` until ``duration_s`` of device time
    or a safe stop (:attr:`stop_reason`)."""

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
        if self.t0 is None:
            self.t0 = state.device_time_s
        self.t = state.device_time_s - self.t0
        if self.last_device_time is not None:
            self.dropped += max(0, int(round((state.device_time_s - self.last_device_time) / self.nominal_period)) - 1)
        self.last_device_time = state.device_time_s
        self.watchdog += int(state.watchdog_tripped)

    def step(self, state: MotorState, newest: bool) -> None:
        raise NotImplementedError

    def show(self, bar: SecondsBar) -> None:
        bar.advance(self.t)

    def run(self, bar: SecondsBar) -> None:
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
    def __init__(self, link: MotorLink, controller: Callable, duration_s: float, log: Optional[SampleLog]) -> None:
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
    check_run(link, duration_s, [("log", log, LOOP_LOG_COLUMNS, "LOOP_LOG_COLUMNS")])
    loop = _BabbleLoop(link, controller, duration_s, log)
    loop.run(SecondsBar(duration_s, "rig loop", progress))
    link.send_torque(0.0)
    return LoopResult(loop.samples, np.diff(loop.send_times), loop.dropped, link.bad_frames, loop.watchdog)
