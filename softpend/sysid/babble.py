"""Motor babbling: drive the simulated rod with band-limited random torques (plus a weak PD on the hub encoder in
most trials) and record what a rig would see.  Trial ``i`` draws from ``SeedSequence(seed).spawn(n_trials)[i]``."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
from tqdm.auto import tqdm

from softpend.checks import (
    check_work_size,
    in_range,
    in_unit_interval,
    int_at_least,
    non_negative,
    one_of,
    positive,
    positive_int,
)
from softpend.plant import OBSERVATION_NAMES, PRBPlant, RodParams, SimulationDiverged, make_plant, wrap_angle_rad
from softpend.sysid.dataset import DT_S_RANGE, TrajectoryDataset, dataset_metadata, write_dataset
from softpend.sysid.variables import POSITION_NAMES, backward_difference, is_angle

_STARTS = ("upright", "hanging", "random")
#: Torque programs of :class:`BabbleProtocol`.
PROGRAMS = ("noise", "multisine")


@dataclass(frozen=True)
class BabbleProtocol:
    """How to babble: trials, start, the torque program (``"noise"``: low-pass noise, std a fraction of the torque
    limit; ``"multisine"``: from 0.2 Hz to ``torque_bandwidth_hz``, peak a fraction of the limit), the PD on the
    differenced hub encoder rate in a fraction of trials, sensor noise and the camera delay [samples]."""

    n_trials: int = 60
    trial_length_s: float = 5.0
    dt_s: float = 0.01
    substeps: int = 2
    start: str = "upright"
    start_angle_std_rad: float = 0.1
    start_bend_std_rad: float = 0.02
    start_rate_std_rad_s: float = 0.2
    torque_std_fraction: float = 0.5
    torque_bandwidth_hz: float = 2.0
    feedback_kp_nm_per_rad: float = 0.8
    feedback_kd_nms_per_rad: float = 0.015
    feedback_trial_fraction: float = 0.8
    phi_noise_std_rad: float = 0.0
    tip_noise_std_m: float = 0.0
    er_noise_std_rad: float = 0.0
    camera_delay_steps: int = 0
    program: str = "noise"
    multisine_peak_fraction: float = 0.8

    def __post_init__(self) -> None:
        one_of("start", self.start, _STARTS)
        one_of("program", self.program, PROGRAMS)
        for f in dataclasses.fields(self):
            if f.name not in ("start", "program"):
                non_negative(f.name, getattr(self, f.name))
        for name in ("n_trials", "substeps"):
            object.__setattr__(self, name, positive_int(name, getattr(self, name)))
        object.__setattr__(self, "camera_delay_steps", int_at_least("camera_delay_steps", self.camera_delay_steps, 0))
        positive("torque_bandwidth_hz", self.torque_bandwidth_hz)
        in_range("dt_s", self.dt_s, *DT_S_RANGE)  # the range a dataset file accepts
        if self.n_samples < 2:
            raise ValueError(f"trial_length_s must cover at least 2 samples of dt_s, got {self.trial_length_s}")
        in_unit_interval("feedback_trial_fraction", self.feedback_trial_fraction)
        in_unit_interval("multisine_peak_fraction", self.multisine_peak_fraction)

    @property
    def n_samples(self) -> int:
        """Stored samples per trial."""
        return int(round(self.trial_length_s / self.dt_s))

    def replace(self, **changes: Any) -> "BabbleProtocol":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


def multisine_frequencies_hz(period_s: float, band_hz: tuple[float, float]) -> np.ndarray:
    """The harmonics ``k / period_s`` of the period that lie in ``band_hz`` (inclusive)."""
    positive("period_s", period_s)
    low, high = (float(b) for b in band_hz)
    if not (math.isfinite(low) and math.isfinite(high) and 0 < low <= high):
        raise ValueError(f"band_hz must be (low, high) with 0 < low <= high, got {band_hz!r}")
    k = np.arange(math.ceil(low * period_s - 1e-9), math.floor(high * period_s + 1e-9) + 1)
    if k.size == 0:
        raise ValueError(f"band_hz {band_hz!r} holds no harmonic of 1 / period_s = {1 / period_s:g} Hz")
    return k / period_s


def multisine(
    n_steps: int,
    dt_s: float,
    peak_nm: float,
    band_hz: tuple[float, float] = (0.2, 6.0),
    period_s: float = 5.0,
) -> np.ndarray:
    """``n_steps`` samples (step ``dt_s``) of a multisine of period ``period_s``: equal-amplitude harmonics in
    ``band_hz`` with Schroeder phases ``-pi k (k - 1) / K`` (a low crest factor), peak exactly ``peak_nm``."""
    n_steps = positive_int("n_steps", n_steps)
    positive("dt_s", dt_s)
    positive("peak_nm", peak_nm)
    if band_hz[1] >= 0.5 / dt_s:
        raise ValueError(f"band_hz upper edge must lie below the Nyquist frequency {0.5 / dt_s:g} Hz, got {band_hz!r}")
    f = multisine_frequencies_hz(period_s, band_hz)
    k = np.arange(1, f.size + 1)
    phase = -math.pi * k * (k - 1) / f.size

    def wave(steps: int) -> np.ndarray:
        return np.cos(2 * math.pi * np.outer(np.arange(steps) * dt_s, f) + phase).sum(axis=1)

    scale = peak_nm / np.max(np.abs(wave(max(int(round(period_s / dt_s)), 1))))  # the peak of one period
    return np.clip(scale * wave(n_steps), -peak_nm, peak_nm)


def band_limited_noise(
    rng: np.random.Generator, n_steps: int, std: float, bandwidth_hz: float, dt_s: float
) -> np.ndarray:
    """Stationary first-order low-pass Gaussian noise: ``u[k+1] = a u[k] + sqrt(1 - a^2) std w[k]``,
    ``a = exp(-2 pi f_c dt)``, ``u[0] ~ N(0, std^2)``."""
    a = math.exp(-2 * math.pi * bandwidth_hz * dt_s)
    w = rng.standard_normal(n_steps)
    u = np.empty(n_steps)
    u[0] = std * w[0]
    gain = math.sqrt(1 - a * a) * std
    for k in range(1, n_steps):
        u[k] = a * u[k - 1] + gain * w[k]
    return u


def _run_trial(plant: Any, protocol: BabbleProtocol, rng: np.random.Generator) -> dict[str, np.ndarray]:
    n, delay = protocol.n_samples, protocol.camera_delay_steps
    n_steps = n + delay  # one extra sample for the first backward difference
    limit = plant.params.torque_limit_nm
    q0, qd0 = np.zeros(plant.n_coordinates), np.zeros(plant.n_coordinates)
    centre = {"upright": 0.0, "hanging": math.pi}.get(protocol.start)
    spread = protocol.start_angle_std_rad
    q0[0] = rng.uniform(-math.pi, math.pi) if centre is None else centre + spread * rng.standard_normal()
    bends = protocol.start_bend_std_rad * rng.standard_normal(plant.n_coordinates - 1)  # drawn for the beam too
    if isinstance(plant, PRBPlant):  # the beam starts straight
        q0[1:] = bends
    qd0[0] = protocol.start_rate_std_rad_s * rng.standard_normal()
    use_feedback = bool(rng.uniform() < protocol.feedback_trial_fraction)
    if protocol.program == "multisine":
        babble = multisine(
            n_steps, protocol.dt_s, protocol.multisine_peak_fraction * limit, (0.2, protocol.torque_bandwidth_hz)
        )
    else:
        babble = band_limited_noise(
            rng, n_steps, protocol.torque_std_fraction * limit, protocol.torque_bandwidth_hz, protocol.dt_s
        )
    kp, kd = (protocol.feedback_kp_nm_per_rad, protocol.feedback_kd_nms_per_rad) if use_feedback else (0.0, 0.0)
    obs = np.empty((n_steps + 1, len(OBSERVATION_NAMES)))
    joint_q = np.empty((n_steps + 1, plant.n_coordinates))
    joint_qd = np.empty_like(joint_q)
    torques = np.empty(n_steps)
    o = plant.reset(q0, qd0)
    phi_previous = o.phi_rad - o.phi_dot_rad_s * protocol.dt_s
    for k in range(n_steps + 1):
        obs[k] = o.as_array()
        joint_q[k], joint_qd[k] = plant.joint_state()
        if k == n_steps:
            break
        phi_rate = float(wrap_angle_rad(o.phi_rad - phi_previous)) / protocol.dt_s
        phi_previous = o.phi_rad
        torques[k] = min(max(-kp * o.phi_rad - kd * phi_rate + babble[k], -limit), limit)
        o = plant.step(torques[k])

    # sensor model: noise on the sampled positions, camera quantities delayed by `delay` samples
    raw = np.empty((n + 1, 5))
    clock = np.arange(delay, delay + n + 1)  # encoder and torque clock
    i_phi, i_theta, i_ex, i_ey, i_er = range(5)
    noise_std = {
        i_phi: protocol.phi_noise_std_rad,
        i_ex: protocol.tip_noise_std_m,
        i_ey: protocol.tip_noise_std_m,
        i_er: protocol.er_noise_std_rad,
    }
    for i, std in noise_std.items():  # drawn in this order; the encoder on the torque's clock
        raw[:, i] = obs[clock if i == i_phi else slice(n + 1), i] + std * rng.standard_normal(n + 1)
    raw[:, i_theta] = np.arctan2(-raw[:, i_ex], raw[:, i_ey])
    angle_mask = np.array([is_angle(x) for x in POSITION_NAMES])
    raw[:, angle_mask] = wrap_angle_rad(raw[:, angle_mask])
    stored = clock[1:]
    return {
        "positions": raw[1:],
        "velocities": backward_difference(raw, protocol.dt_s, angle_mask),
        "torques_nm": torques[stored[:-1]],
        "true_observations": obs[stored],
        "joint_positions_rad": joint_q[stored],
        "joint_velocities_rad_s": joint_qd[stored],
        "feedback": np.array(use_feedback),
    }


def babble(
    protocol: Optional[BabbleProtocol] = None,
    params: Optional[RodParams] = None,
    seed: int = 0,
    plant: str = "prb",
    path: Optional[str | Path] = None,
    progress: bool = True,
) -> TrajectoryDataset:
    """Run the babbling protocol on a simulated plant (a :func:`softpend.plant.make_plant` name); the dataset,
    also written to ``path`` if given.  Raises ``ValueError`` on bad arguments or a dataset too large (before the
    first trial), ``SimulationDiverged`` naming the trial if the simulator fails."""
    protocol = protocol if protocol is not None else BabbleProtocol()
    params = params if params is not None else RodParams()
    seed = int_at_least("seed", seed, 0)
    sim = make_plant(plant, params=params, dt_s=protocol.dt_s, substeps=protocol.substeps)
    per_sample = 8 * (2 * len(POSITION_NAMES) + 1 + len(OBSERVATION_NAMES) + 2 * sim.n_coordinates)
    n_samples = float(protocol.n_trials) * (protocol.n_samples + protocol.camera_delay_steps + 1)
    check_work_size(
        f"babbling {protocol.n_trials} trials of {protocol.n_samples} samples",
        2 * n_samples * per_sample,
        f"{n_samples:.3g} samples x {per_sample} bytes, held twice while the trials are stacked",
    )
    streams = np.random.SeedSequence(seed).spawn(protocol.n_trials)
    trials = []
    for i in tqdm(range(protocol.n_trials), desc="babbling", unit="trial", disable=not progress):
        try:
            trials.append(_run_trial(sim, protocol, np.random.default_rng(streams[i])))
        except SimulationDiverged as exc:
            raise SimulationDiverged(f"trial {i}: {exc.reason}") from exc
    arrays = {key: np.ascontiguousarray(np.stack([t[key] for t in trials])) for key in trials[0] if key != "feedback"}
    record = dict(dataclasses.asdict(protocol), feedback_trials=[int(t["feedback"]) for t in trials])
    notes = "motor babbling (softpend.sysid.babble)"
    described: dict[str, Any] = dict(source="simulation", plant=plant, plant_params=params, seed=seed, notes=notes)
    metadata = dataset_metadata(arrays["positions"], dt_s=protocol.dt_s, protocol=record, **described)
    dataset = TrajectoryDataset(metadata=metadata, **arrays)
    if path is not None:
        write_dataset(path, dataset)
    return dataset
