"""The hardware rig: serial motor link, rig emulator and digital twin, host control loops, state estimator, crash-safe
logs, time synchronisation of the motor and camera streams."""

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
