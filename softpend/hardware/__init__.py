"""The hardware rig: serial motor link, rig emulator (the digital twin in simulated time, or a pty on the wall
clock; :mod:`~softpend.hardware.clock`), host control loops (open-loop programs in
:mod:`~softpend.hardware.loop`; any controller with the camera in the loop and the state estimator in
:mod:`~softpend.hardware.closed_loop` and :mod:`~softpend.hardware.estimator`), crash-safe logs, and time
synchronisation of the motor and camera streams."""

from softpend.hardware.clock import SimClock
from softpend.hardware.driver import (
    DeviceError,
    DeviceInfo,
    HandshakeError,
    LinkChecksumError,
    LinkDisconnected,
    LinkError,
    LinkTimeout,
    MotorLink,
    MotorState,
)
from softpend.hardware.emulator import EmulatorProcess, RigConfig, RigEmulator, SimRig, start_emulator_process
from softpend.io.samplelog import SampleLog, read_sample_log

__all__ = [
    "DeviceError",
    "DeviceInfo",
    "EmulatorProcess",
    "HandshakeError",
    "LinkChecksumError",
    "LinkDisconnected",
    "LinkError",
    "LinkTimeout",
    "MotorLink",
    "MotorState",
    "RigConfig",
    "RigEmulator",
    "SampleLog",
    "SimClock",
    "SimRig",
    "read_sample_log",
    "start_emulator_process",
]
