"""The twin's camera in a process of its own, as a rig's camera is a device of its own.

:class:`CameraProcess` is a :class:`~softpend.vision.tip_source.TipSource` whose frames are rendered and
tracked by :class:`~softpend.vision.tip_source.SyntheticLiveCamera` in a child process
(``python -m softpend.hardware.camera_process``) that films the emulator's pose feed (the scene pipe of
:class:`~softpend.hardware.emulator.EmulatorProcess`).  The child writes one JSON line per tracked frame to its
standard output; :meth:`CameraProcess.poll` reads what has arrived without waiting.  Rendering and tracking
then share no interpreter with the host's control loop: on the twin they would otherwise hold the loop's
thread back (Python runs one thread at a time) for as long as a frame takes, which is most of the jitter
of the loop's commands.  The measurements are the same as from the in-process camera: capture and delivery
times on the host's monotonic clock, which both processes read.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import select
import signal
import subprocess
import sys
import tempfile
import time
from typing import Any, Optional

import numpy as np

from softpend.vision.tip_source import TipMeasurement

__all__ = ["CameraProcess", "camera_settings"]


def camera_settings(fps: float, latency_s: float, effects: Any = None, model: Any = None, faults: Any = None,
                    seed: int = 0) -> dict[str, Any]:
    """The child's camera as a JSON-ready dict (``effects``, ``model``, ``faults``: the dataclasses of
    :class:`~softpend.vision.tip_source.SyntheticLiveCamera`, or None for its defaults)."""
    return {"fps": float(fps), "latency_s": float(latency_s), "seed": int(seed),
            "effects": None if effects is None else dataclasses.asdict(effects),
            "model": None if model is None else dataclasses.asdict(model),
            "faults": None if faults is None else dataclasses.asdict(faults)}


def _camera_from_settings(settings: dict[str, Any], scene):
    from softpend.vision.camera import CameraEffects, CameraModel
    from softpend.vision.tip_source import CameraFaults, SyntheticLiveCamera

    effects = CameraEffects(**settings["effects"]) if settings.get("effects") is not None else None
    model = None
    if settings.get("model") is not None:
        model = CameraModel(**{**settings["model"], "centre_px": tuple(settings["model"]["centre_px"])})
    faults = None
    if settings.get("faults") is not None:
        raw = settings["faults"]
        faults = CameraFaults(**{**raw, "occlusions_s": tuple(tuple(w) for w in raw["occlusions_s"])})
    return SyntheticLiveCamera(scene, fps=settings["fps"], latency_s=settings["latency_s"], effects=effects,
                               model=model, faults=faults, seed=settings["seed"])


class CameraProcess:
    """The synthetic live camera in a child process, filming the emulator's scene pipe (module docstring).

    Parameters
    ----------
    scene_fd : int
        Read end of the emulator's scene pipe (:attr:`EmulatorProcess.scene_fd`); the child takes it over and
        this process closes its copy.
    task : Task
        The emulator's task (the rod the scene draws).
    settings : dict
        The camera (:func:`camera_settings`).
    start_timeout_s : float
        Longest wait for the child to report that it runs [s].
    """

    name = "synthetic-camera-process"

    def __init__(self, scene_fd: int, task, settings: dict[str, Any], start_timeout_s: float = 30.0) -> None:
        self._stderr = tempfile.TemporaryFile(mode="w+")
        cmd = [sys.executable, "-m", "softpend.hardware.camera_process", "--scene-fd", str(int(scene_fd)),
               "--task-json", json.dumps(task.to_dict()), "--settings-json", json.dumps(settings)]
        try:
            self.process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stdin=subprocess.PIPE,
                                            stderr=self._stderr, pass_fds=(int(scene_fd),))
        finally:
            os.close(int(scene_fd))  # the child holds its own copy
        self._fd = self.process.stdout.fileno()
        self._buffer = b""
        self._queue: list[TipMeasurement] = []
        self._child_stats: dict[str, float] = {}
        self._error: Optional[str] = None
        self._frames_tracked = 0
        self.frames_lost = 0
        self._ages_s: list[float] = []
        self._ready = False
        deadline = time.monotonic() + start_timeout_s
        while not self._ready and time.monotonic() < deadline and self.process.poll() is None:
            self._pump(timeout_s=0.05)
        if not self._ready:
            what = "exited" if self.process.poll() is not None else f"did not start within {start_timeout_s} s"
            tail = self._stderr_tail()
            self.close()
            raise RuntimeError(f"the camera process {what}: {tail}")
        os.set_blocking(self._fd, False)

    # ------------------------------------------------------------------ reading the child
    def _stderr_tail(self) -> str:
        self._stderr.seek(0)
        return " ".join(self._stderr.read()[-2000:].split())

    def _pump(self, timeout_s: float = 0.0) -> None:
        if timeout_s > 0:
            ready, _, _ = select.select([self._fd], [], [], timeout_s)
            if not ready:
                return
        while True:
            try:
                chunk = os.read(self._fd, 65536)
            except BlockingIOError:
                break
            if not chunk:
                break
            self._buffer += chunk
            if timeout_s > 0:
                break
        *lines, self._buffer = self._buffer.split(b"\n")
        for line in lines:
            record = json.loads(line)
            if "m" in record:
                frame, capture, delivered, x_m, y_m, lost = record["m"]
                m = TipMeasurement(math.nan if x_m is None else x_m, math.nan if y_m is None else y_m, bool(lost),
                                   capture, int(frame), delivered)
                self._queue.append(m)
                self._frames_tracked += 1
                self.frames_lost += int(m.lost)
                self._ages_s.append(m.age_s)
            elif "stats" in record:
                self._child_stats = record["stats"]
            elif "error" in record:
                self._error = record["error"]
            elif "ready" in record:
                self._ready = True

    # ------------------------------------------------------------------ TipSource
    def start(self) -> None:
        """The child films from its start; nothing to do."""

    def poll(self) -> list[TipMeasurement]:
        """The measurements that arrived since the last call, oldest first; raises ``RuntimeError`` once the
        child has failed and everything it sent was polled."""
        self._pump()
        out, self._queue = self._queue, []
        if not out and self._error is not None:
            error, self._error = self._error, None
            raise RuntimeError(f"the camera process failed: {error}")
        return out

    @property
    def frames_tracked(self) -> int:
        """Frames tracked so far (what has arrived, polled or not)."""
        if self._ready and not self._stderr.closed:
            self._pump()
        return self._frames_tracked

    @property
    def running(self) -> bool:
        """The child is alive."""
        return self.process.poll() is None

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the child (SIGTERM, then SIGKILL) and collect its last records and counters."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        try:
            os.set_blocking(self._fd, False)
            self._pump()
        except (OSError, ValueError):
            pass
        for stream in (self.process.stdout, self.process.stdin):
            if stream is not None:
                try:
                    stream.close()
                except OSError:
                    pass
        self._stderr.close()

    def stats(self) -> dict[str, float]:
        ages = np.asarray(self._ages_s) * 1e3
        out = {"frames_tracked": float(self._frames_tracked), "frames_lost": float(self.frames_lost),
               "frames_dropped": float(self._child_stats.get("frames_dropped", math.nan)),
               "delivery_latency_ms_median": float(np.median(ages)) if ages.size else math.nan,
               "delivery_latency_ms_p95": float(np.percentile(ages, 95)) if ages.size else math.nan}
        for key in ("frames_stalled", "frames_occluded"):
            out[key] = float(self._child_stats.get(key, math.nan))
        return out

    def __enter__(self) -> "CameraProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ---------------------------------------------------------------------- the child
def _main(argv: Optional[list[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m softpend.hardware.camera_process")
    parser.add_argument("--scene-fd", type=int, required=True)
    parser.add_argument("--task-json", required=True)
    parser.add_argument("--settings-json", required=True)
    args = parser.parse_args(argv)

    from softpend.hardware.realtime import CAMERA_PRIORITY, realtime_priority
    from softpend.hardware.scene import EmulatorScene
    from softpend.task import Task

    out = sys.stdout.buffer
    stopping = []
    signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))

    def send(record: dict[str, Any]) -> None:
        out.write(json.dumps(record).encode() + b"\n")
        out.flush()

    def on_frame(index, frame, detection, m: TipMeasurement) -> None:
        send({"m": [m.frame, m.capture_time_s, m.delivered_time_s, None if m.lost else m.x_m,
                    None if m.lost else m.y_m, int(m.lost)]})

    scene = EmulatorScene(args.scene_fd, Task.from_dict(json.loads(args.task_json)))
    camera = _camera_from_settings(json.loads(args.settings_json), scene)
    camera.on_frame = on_frame
    try:
        send({"ready": True})
        with realtime_priority(CAMERA_PRIORITY):  # the camera's thread, started in the block, keeps it
            camera.start()
        while not stopping and camera.running:
            time.sleep(0.02)
        camera.close()
        try:
            camera.poll()  # raises the camera thread's error, if any
        except Exception as exc:  # noqa: BLE001 (reported to the parent, which raises it)
            send({"error": f"{type(exc).__name__}: {exc}"})
        send({"stats": camera.stats()})
    except BrokenPipeError:
        return 0
    finally:
        scene.close()
    return 0


if __name__ == "__main__":
    sys.exit(_main())
