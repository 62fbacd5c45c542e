"""Motor babbling: drive the simulated rod with random torques and record what a rig would see.

Protocol (the report's, made explicit; every number is a field of :class:`BabbleProtocol`)
-----------------------------------------------------------------------------------------
* ``n_trials`` trials (60) of ``trial_length_s`` (5 s) at ``dt_s`` (0.01 s): 500 stored samples and
  499 transitions a trial.  The plant is reset between trials.
* **Start state** near the upright equilibrium (``start="upright"``): hub angle ``~ N(0, 0.1 rad)``,
  each spring angle ``~ N(0, 0.02 rad)``, hub rate ``~ N(0, 0.2 rad/s)``.  ``"hanging"`` and
  ``"random"`` (hub angle uniform) are available for data that covers the swing-up region.
* **Torque** = clip(feedback + babble, +-torque limit).  The babble term is band-limited Gaussian noise:
  white noise through a first-order low-pass filter (an Ornstein-Uhlenbeck process) with cut-off
  ``torque_bandwidth_hz`` (2 Hz) and stationary standard deviation ``torque_std_fraction`` (0.5) times
  the torque limit, started from its stationary normal distribution.  The feedback term is a weak
  stabilising PD on the hub encoder, ``-kp * phi - kd * phi_dot`` (0.8 N m/rad, 0.015 N m s/rad), with
  ``phi_dot`` the backward difference of the sampled hub angle as a rig's controller computes it,
  active in a fraction ``feedback_trial_fraction`` (0.8) of the trials, so that those trials keep the
  rod wobbling in the upright region where the controllers work (|theta| mostly below 0.3 rad; an
  occasional trial still falls) while the noise excites it; in the other trials the rod falls from
  upright and swings under the random torque, so the data also covers falling and the hanging region.
  A hub encoder and a PD loop on it are what a rig has, so the protocol runs on hardware as is.  (A PD
  on the simulator's true hub rate makes the torque chatter with the rod's fast bending modes, which
  the sampled observations cannot resolve; the differenced rate keeps the data far more predictable.)
* **Observations**: the positions ``phi, theta, ex, ey, er`` are sampled, optionally with Gaussian
  sensor noise (``phi_noise_std_rad``, ``tip_noise_std_m`` on ``ex, ey`` before ``theta`` is computed
  from them, ``er_noise_std_rad``) and a camera delay of ``camera_delay_steps`` samples on the camera
  quantities ``theta, ex, ey, er`` (the encoder angle and the torque are not delayed).  Velocities are
  backward differences of the unwrapped sampled positions
  (:func:`softpend.sysid.backward_difference`); the simulator's true observation (true velocities) and
  joint state are kept alongside.

Each trial draws from its own stream ``SeedSequence(seed).spawn(n_trials)[i]``, so the same seed gives
the same dataset (and the same file bytes) on any machine.
"""

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
    in_unit_interval,
    int_at_least,
    non_negative,
    one_of,
    positive,
    positive_int,
)
from softpend.plant import OBSERVATION_NAMES, RodParams, SimulationDiverged, make_plant, wrap_angle_rad
from softpend.sysid.dataset import DT_S_RANGE, TrajectoryDataset, write_dataset
from softpend.sysid.differentiation import backward_difference
from softpend.sysid.variables import POSITION_NAMES, VELOCITY_NAMES, is_angle

__all__ = ["BabbleProtocol", "babble", "band_limited_noise"]

_STARTS = ("upright", "hanging", "random")


@dataclass(frozen=True)
class BabbleProtocol:
    """How to babble (see the module docstring for the meaning and defaults).

    Parameters
    ----------
    n_trials : int
        Number of trials.
    trial_length_s : float
        Length of a trial [s]; ``round(trial_length_s / dt_s)`` samples are stored.
    dt_s : float
        Sampling and control step [s].
    substeps : int
        Implicit solver steps per control step.
    start : {"upright", "hanging", "random"}
        Start region.
    start_angle_std_rad, start_bend_std_rad, start_rate_std_rad_s : float
        Standard deviations of the start hub angle [rad], spring angles [rad] and hub rate [rad/s].
    torque_std_fraction : float
        Stationary standard deviation of the random torque, as a fraction of the torque limit.
    torque_bandwidth_hz : float
        Cut-off frequency of the first-order low-pass filter on the white noise [Hz].
    feedback_kp_nm_per_rad, feedback_kd_nms_per_rad : float
        Stabilising PD gains on the hub angle [N m/rad] and rate [N m s/rad].
    feedback_trial_fraction : float
        Probability that a trial uses the PD feedback (0 = pure random torque).
    feedback_velocity : {"differenced", "true"}
        Hub rate used by the PD: the backward difference of the sampled hub angle (as the rig's
        controller computes it; default) or the simulator's true rate.
    phi_noise_std_rad, tip_noise_std_m, er_noise_std_rad : float
        Sensor noise standard deviations [rad, m, rad].
    camera_delay_steps : int
        Delay of the camera quantities ``theta, ex, ey, er`` [samples].
    """

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
    feedback_velocity: str = "differenced"
    phi_noise_std_rad: float = 0.0
    tip_noise_std_m: float = 0.0
    er_noise_std_rad: float = 0.0
    camera_delay_steps: int = 0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "start":
                one_of("start", value, _STARTS)
            elif f.name == "feedback_velocity":
                one_of("feedback_velocity", value, ("differenced", "true"))
            else:
                non_negative(f.name, value)
        for name in ("n_trials", "substeps"):
            object.__setattr__(self, name, positive_int(name, getattr(self, name)))
        object.__setattr__(self, "camera_delay_steps", int_at_least("camera_delay_steps", self.camera_delay_steps, 0))
        for name in ("dt_s", "torque_bandwidth_hz"):
            positive(name, getattr(self, name))
        low, high = DT_S_RANGE
        if not low <= self.dt_s <= high:
            raise ValueError(
                f"dt_s must lie in [{low:g}, {high:g}] s (the range a dataset file accepts), got {self.dt_s!r}"
            )
        if self.n_samples < 2:
            raise ValueError(f"trial_length_s must cover at least 2 samples of dt_s, got {self.trial_length_s}")
        in_unit_interval("feedback_trial_fraction", self.feedback_trial_fraction)

    @property
    def n_samples(self) -> int:
        """Stored samples per trial (``n_samples - 1`` transitions)."""
        return int(round(self.trial_length_s / self.dt_s))

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for JSON metadata)."""
        return dataclasses.asdict(self)

    def replace(self, **changes: Any) -> "BabbleProtocol":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


def band_limited_noise(
    rng: np.random.Generator, n_steps: int, std: float, bandwidth_hz: float, dt_s: float
) -> np.ndarray:
    """Gaussian noise through a first-order low-pass filter (stationary Ornstein-Uhlenbeck samples).

    ``u[0] ~ N(0, std^2)`` and ``u[k+1] = a u[k] + sqrt(1 - a^2) std w[k]`` with ``a = exp(-2 pi f_c dt)``
    and ``w ~ N(0, 1)``: every sample is ``N(0, std^2)`` and the spectrum falls off above ``f_c``.
    """
    a = math.exp(-2 * math.pi * bandwidth_hz * dt_s)
    w = rng.standard_normal(n_steps)
    u = np.empty(n_steps)
    u[0] = std * w[0]
    gain = math.sqrt(1 - a * a) * std
    for k in range(1, n_steps):
        u[k] = a * u[k - 1] + gain * w[k]
    return u


def _start_state(
    rng: np.random.Generator, protocol: BabbleProtocol, n_coordinates: int, bend_joints: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Random start state; ``bend_joints`` perturbs the spring angles too (PRB chains only: other plants,
    such as the continuum beam, have coordinates that are not joint angles and start straight)."""
    q = np.zeros(n_coordinates)
    qd = np.zeros(n_coordinates)
    centre = {"upright": 0.0, "hanging": math.pi}.get(protocol.start)
    q[0] = (
        rng.uniform(-math.pi, math.pi)
        if centre is None
        else centre + protocol.start_angle_std_rad * rng.standard_normal()
    )
    bends = protocol.start_bend_std_rad * rng.standard_normal(n_coordinates - 1)
    if bend_joints:
        q[1:] = bends
    qd[0] = protocol.start_rate_std_rad_s * rng.standard_normal()
    return q, qd


def _run_trial(plant: Any, protocol: BabbleProtocol, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Simulate one trial; returns the stored arrays for it."""
    n = protocol.n_samples
    delay = protocol.camera_delay_steps
    n_steps = n + delay  # raw samples 0 .. n + delay (one extra sample for the first backward difference)
    limit = plant.params.torque_limit_nm
    from softpend.plant import PRBPlant

    q0, qd0 = _start_state(rng, protocol, plant.n_coordinates, bend_joints=isinstance(plant, PRBPlant))
    use_feedback = bool(rng.uniform() < protocol.feedback_trial_fraction)
    babble = band_limited_noise(
        rng, n_steps, protocol.torque_std_fraction * limit, protocol.torque_bandwidth_hz, protocol.dt_s
    )
    kp = protocol.feedback_kp_nm_per_rad if use_feedback else 0.0
    kd = protocol.feedback_kd_nms_per_rad if use_feedback else 0.0

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
        if protocol.feedback_velocity == "differenced":  # as the rig's controller: encoder difference
            phi_rate = float(wrap_angle_rad(o.phi_rad - phi_previous)) / protocol.dt_s
        else:
            phi_rate = o.phi_dot_rad_s
        phi_previous = o.phi_rad
        torque = min(max(-kp * o.phi_rad - kd * phi_rate + babble[k], -limit), limit)
        torques[k] = torque
        o = plant.step(torque)

    # sensor model: noise on the sampled positions, camera quantities delayed by `delay` samples
    true_positions = obs[:, :5]
    raw = np.empty((n + 1, 5))
    clock = np.arange(delay, delay + n + 1)  # encoder/torque clock
    camera = np.arange(0, n + 1)
    names = POSITION_NAMES
    i_phi, i_theta, i_ex, i_ey, i_er = (names.index(x) for x in ("phi_rad", "theta_rad", "ex_m", "ey_m", "er_rad"))
    raw[:, i_phi] = true_positions[clock, i_phi] + protocol.phi_noise_std_rad * rng.standard_normal(n + 1)
    raw[:, i_ex] = true_positions[camera, i_ex] + protocol.tip_noise_std_m * rng.standard_normal(n + 1)
    raw[:, i_ey] = true_positions[camera, i_ey] + protocol.tip_noise_std_m * rng.standard_normal(n + 1)
    raw[:, i_theta] = np.arctan2(-raw[:, i_ex], raw[:, i_ey])
    raw[:, i_er] = true_positions[camera, i_er] + protocol.er_noise_std_rad * rng.standard_normal(n + 1)
    angle_mask = np.array([is_angle(x) for x in names])
    raw[:, angle_mask] = wrap_angle_rad(raw[:, angle_mask])
    velocities = backward_difference(raw, protocol.dt_s, angle_mask)
    stored = clock[1:]  # simulator sample index of each stored sample (encoder clock)
    return {
        "positions": raw[1:],
        "velocities": velocities,
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
    """Run the motor-babbling protocol on a simulated plant and return (and optionally save) the dataset.

    Parameters
    ----------
    protocol : BabbleProtocol, optional
        The protocol (default: the report's 60 x 5 s at dt = 0.01 s, see the module docstring).
    params : RodParams, optional
        Plant parameters (default: ``RodParams()``).
    seed : int
        Seed of every random draw (start states, torques, feedback on/off, sensor noise).
    plant : str
        Plant name for :func:`softpend.plant.make_plant`.
    path : str or Path, optional
        If given, the dataset is also written there (:func:`softpend.sysid.save_dataset` format).
    progress : bool
        Show a progress bar over trials.

    Raises
    ------
    ValueError
        On invalid arguments, or a dataset whose arrays would not fit in
        :data:`softpend.checks.MAX_WORK_BYTES` (checked before the first trial).
    SimulationDiverged
        If the simulator fails in a trial (the message names the trial).
    """
    protocol = protocol if protocol is not None else BabbleProtocol()
    if not isinstance(protocol, BabbleProtocol):
        raise ValueError(f"protocol must be a BabbleProtocol, got {type(protocol).__name__}")
    params = params if params is not None else RodParams()
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    sim = make_plant(plant, params=params, dt_s=protocol.dt_s, substeps=protocol.substeps)
    per_sample = 8 * (2 * len(POSITION_NAMES) + 1 + len(OBSERVATION_NAMES) + 2 * sim.n_coordinates)
    n_samples = float(protocol.n_trials) * (protocol.n_samples + protocol.camera_delay_steps + 1)
    check_work_size(
        f"babbling {protocol.n_trials} trials of {protocol.n_samples} samples",
        2 * n_samples * per_sample,
        f"{n_samples:.3g} samples x {per_sample} bytes, held twice while the trials are stacked",
    )
    streams = np.random.SeedSequence(int(seed)).spawn(protocol.n_trials)
    trials = []
    for i in tqdm(range(protocol.n_trials), desc="babbling", unit="trial", disable=not progress):
        try:
            trials.append(_run_trial(sim, protocol, np.random.default_rng(streams[i])))
        except SimulationDiverged as exc:
            raise SimulationDiverged(f"trial {i}: {exc.reason}") from exc
    stack = lambda key: np.ascontiguousarray(np.stack([t[key] for t in trials]))  # noqa: E731
    metadata = {
        "schema": "softpend.sysid.dataset",
        "schema_version": 1,
        "softpend_version": _version(),
        "source": "simulation",
        "dt_s": float(protocol.dt_s),
        "n_trials": protocol.n_trials,
        "n_samples": protocol.n_samples,
        "position_names": list(POSITION_NAMES),
        "velocity_names": list(VELOCITY_NAMES),
        "differentiation": "backward",
        "plant": plant,
        "plant_params": params.to_dict(),
        "seed": int(seed),
        "protocol": dict(protocol.to_dict(), feedback_trials=[int(t["feedback"]) for t in trials]),
        "notes": "motor babbling (softpend.sysid.babble)",
    }
    dataset = TrajectoryDataset(
        positions=stack("positions"),
        velocities=stack("velocities"),
        torques_nm=stack("torques_nm"),
        metadata=metadata,
        true_observations=stack("true_observations"),
        joint_positions_rad=stack("joint_positions_rad"),
        joint_velocities_rad_s=stack("joint_velocities_rad_s"),
    )
    if path is not None:
        write_dataset(path, dataset)
    return dataset


def _version() -> str:
    from softpend import __version__

    return __version__
