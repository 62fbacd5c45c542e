"""How the host writes a frame to the motor link: a stalled writer is not a dead link, a full port is."""

from __future__ import annotations

import os
import time
import tty

import pytest
import serial

from softpend.hardware import driver


@pytest.fixture()
def port():
    """A pyserial port on a raw pseudo-terminal whose other end nobody reads; the master fd for reading."""
    master, slave = os.openpty()
    tty.setraw(slave)
    ser = serial.Serial(os.ttyname(slave), 115200, timeout=0, write_timeout=0.05)
    yield ser, master
    ser.close()
    os.close(slave)
    os.close(master)


def test_a_writer_that_was_not_scheduled_still_writes_the_whole_frame(port, monkeypatch):
    """The writing thread is held up for twice the timeout inside the write (a loaded computer): the frame
    arrives whole and no timeout is raised, because the port never refused a byte."""
    ser, master = port
    real_write = os.write

    def slow_write(fd, data):
        n = real_write(fd, data)
        time.sleep(0.1)  # the timeout is 0.05 s
        return n

    monkeypatch.setattr(driver.os, "write", slow_write)
    frame = bytes(range(40))
    driver._write_frame(ser, frame, 0.05)
    monkeypatch.undo()
    assert os.read(master, 4096) == frame


def test_a_port_that_takes_no_byte_times_out(port):
    """Nobody reads the other end: the buffer fills, and the write that finds no room for the timeout raises
    pyserial's timeout (which the link reports as a disconnect), naming how much was left unsent."""
    ser, _ = port
    frame = bytes(100)
    with pytest.raises(serial.SerialTimeoutException, match=r"took no byte for 0.05 s \(\d+ of 100 bytes unsent\)"):
        for _ in range(10_000):  # a pty buffers a few tens of kB
            driver._write_frame(ser, frame, 0.05)
