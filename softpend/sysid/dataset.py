"""System-identification datasets: one ``.npz`` file of trials plus JSON metadata.

File format (schema ``softpend.sysid.dataset``, version 1)
----------------------------------------------------------
A zip archive readable with ``numpy.load(path, allow_pickle=False)``, written byte-for-byte
deterministically (fixed zip timestamps, no pickles), holding these ``.npy`` members.  ``T`` is the
number of trials, ``N`` the number of samples per trial (every trial has the same length and sampling
step ``dt_s``), ``P`` the number of position variables named in ``metadata["position_names"]``, ``J`` the
number of joint coordinates of a simulated plant.

``positions``  float64 ``(T, N, P)``
    Observed positions at the sample times, in the order of ``position_names`` (a subset of
    ``phi_rad, theta_rad, ex_m, ey_m, er_rad`` that must include ``phi_rad, ex_m, ey_m``).  Angles
    [rad] from upright, counter-clockwise positive, wrapped to ``[-pi, pi)``; tip coordinates [m]
    relative to the hub axis, y up.  These are what the sensors reported (with noise and camera delay
    if any).
``velocities``  float64 ``(T, N, P)``
    Their first derivatives [rad/s, m/s] as the rig computes them: backward differences of the
    unwrapped positions (``metadata["differentiation"]`` says which scheme).  Sample ``i`` uses samples
    ``i`` and ``i - 1``; a writer records one extra sample before the first stored one for this.
``torques_nm``  float64 ``(T, N - 1)``
    Base torque [N m] held constant (zero-order hold) from sample ``i`` to sample ``i + 1``, after
    clipping to the torque limit: the torque that actually acted.
``true_observations``  float64 ``(T, N, 10)``, optional (simulated data only)
    The simulator's noise-free, undelayed observation at each sample, in
    :data:`softpend.plant.OBSERVATION_NAMES` order, with the true (not differenced) velocities.
``joint_positions_rad``, ``joint_velocities_rad_s``  float64 ``(T, N, J)``, optional (simulated only)
    The plant's full joint state ``(q, q_dot)`` (hub angle unwrapped, then the spring angles).
``metadata``  0-d unicode array
    UTF-8 JSON object with: ``schema`` (``"softpend.sysid.dataset"``), ``schema_version`` (1),
    ``softpend_version``, ``source`` (``"simulation"`` or ``"rig"``), ``dt_s``, ``n_trials``,
    ``n_samples``, ``position_names``, ``velocity_names``, ``differentiation``, ``plant`` (plant
    name or null), ``plant_params`` (:meth:`softpend.plant.RodParams.to_dict` or null), ``seed``
    (int or null), ``protocol`` (object: how the torques were generated), ``notes`` (free text).

A rig writes the same format with :func:`save_dataset` (``source="rig"``, no ``true_observations`` or
joint arrays; ``er_rad`` may be absent when the camera tracks only the tip dot).
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from softpend.io.arrays import read_npz
from softpend.io.outputs import atomic_write
from softpend.plant import OBSERVATION_NAMES, RodParams
from softpend.sysid.variables import POSITION_NAMES, velocity_name

__all__ = [
    "SCHEMA_NAME",
    "SCHEMA_VERSION",
    "REQUIRED_POSITION_NAMES",
    "TrajectoryDataset",
    "save_dataset",
    "load_dataset",
    "DT_S_RANGE",
]

SCHEMA_NAME = "softpend.sysid.dataset"
SCHEMA_VERSION = 1
#: Every dataset has at least the limited-information variables: base angle and tip position.
REQUIRED_POSITION_NAMES: tuple[str, ...] = ("phi_rad", "ex_m", "ey_m")
_SOURCES = ("simulation", "rig")
_REQUIRED_METADATA = (
    "schema",
    "schema_version",
    "softpend_version",
    "source",
    "dt_s",
    "n_trials",
    "n_samples",
    "position_names",
    "velocity_names",
    "differentiation",
    "plant",
    "plant_params",
    "seed",
    "protocol",
    "notes",
)
#: Accepted sampling steps [s]: 1 microsecond (far below any encoder or camera rate) to 10 s (far above any
#: step at which a pendulum of this size can be identified); a ``dt_s`` outside is a corrupt or mistyped file.
DT_S_RANGE: tuple[float, float] = (1e-6, 10.0)
_ARRAYS_REQUIRED = ("positions", "velocities", "torques_nm")
_ARRAYS_OPTIONAL = ("true_observations", "joint_positions_rad", "joint_velocities_rad_s")
# fixed timestamp so that the same content gives the same bytes
_ZIP_DATE_TIME = (1980, 1, 1, 0, 0, 0)


@dataclass(frozen=True, eq=False)
class TrajectoryDataset:
    """Trials of sampled observations and the torques that produced them (see the module docstring for
    the arrays, their shapes and units).  Build with :func:`save_dataset`/:func:`load_dataset` or
    :func:`softpend.sysid.babble`; the constructor validates everything."""

    positions: np.ndarray
    velocities: np.ndarray
    torques_nm: np.ndarray
    metadata: dict[str, Any]
    true_observations: Optional[np.ndarray] = None
    joint_positions_rad: Optional[np.ndarray] = None
    joint_velocities_rad_s: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        _validate(self)

    # -------------------------------------------------------------- convenience
    @property
    def n_trials(self) -> int:
        """Number of trials ``T``."""
        return int(self.positions.shape[0])

    @property
    def n_samples(self) -> int:
        """Samples per trial ``N`` (``N - 1`` transitions)."""
        return int(self.positions.shape[1])

    @property
    def n_transitions(self) -> int:
        """Total number of transitions ``T * (N - 1)``."""
        return self.n_trials * (self.n_samples - 1)

    @property
    def dt_s(self) -> float:
        """Sampling step [s]."""
        return float(self.metadata["dt_s"])

    @property
    def position_names(self) -> tuple[str, ...]:
        """Names of the columns of :attr:`positions`."""
        return tuple(self.metadata["position_names"])

    @property
    def velocity_names(self) -> tuple[str, ...]:
        """Names of the columns of :attr:`velocities`."""
        return tuple(self.metadata["velocity_names"])

    @property
    def params(self) -> Optional[RodParams]:
        """The plant parameters, if recorded."""
        data = self.metadata.get("plant_params")
        return None if data is None else RodParams.from_dict(data)

    @property
    def time_s(self) -> np.ndarray:
        """Sample times from the first stored sample [s], shape ``(N,)``."""
        return np.arange(self.n_samples) * self.dt_s

    def column(self, name: str) -> np.ndarray:
        """One observed variable (position or velocity name), shape ``(T, N)``."""
        if name in self.position_names:
            return self.positions[..., self.position_names.index(name)]
        if name in self.velocity_names:
            return self.velocities[..., self.velocity_names.index(name)]
        raise ValueError(f"name must be one of {self.position_names + self.velocity_names}, got {name!r}")

    def true_column(self, name: str) -> np.ndarray:
        """One variable of :attr:`true_observations`, shape ``(T, N)`` (simulated data only)."""
        if self.true_observations is None:
            raise ValueError("this dataset has no true_observations (not simulated)")
        if name not in OBSERVATION_NAMES:
            raise ValueError(f"name must be one of {OBSERVATION_NAMES}, got {name!r}")
        return self.true_observations[..., OBSERVATION_NAMES.index(name)]

    def select_trials(self, trials: np.ndarray | list[int]) -> "TrajectoryDataset":
        """A dataset with only the given trials (metadata ``n_trials`` updated)."""
        index = np.asarray(trials, dtype=np.int64).reshape(-1)
        if index.size == 0 or index.min() < 0 or index.max() >= self.n_trials:
            raise ValueError(f"trials must be non-empty indices in [0, {self.n_trials}), got {trials!r}")
        metadata = dict(self.metadata, n_trials=int(index.size))
        take = lambda a: None if a is None else a[index]  # noqa: E731
        return TrajectoryDataset(
            positions=self.positions[index],
            velocities=self.velocities[index],
            torques_nm=self.torques_nm[index],
            metadata=metadata,
            true_observations=take(self.true_observations),
            joint_positions_rad=take(self.joint_positions_rad),
            joint_velocities_rad_s=take(self.joint_velocities_rad_s),
        )

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays present, by file member name."""
        out = {name: getattr(self, name) for name in _ARRAYS_REQUIRED}
        for name in _ARRAYS_OPTIONAL:
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        return out


# ---------------------------------------------------------------------------------------- validation
def _validate(ds: TrajectoryDataset) -> None:
    meta = ds.metadata
    if not isinstance(meta, dict):
        raise ValueError(f"metadata must be a dict, got {type(meta).__name__}")
    missing = [key for key in _REQUIRED_METADATA if key not in meta]
    if missing:
        raise ValueError(f"metadata is missing keys {missing}")
    if meta["schema"] != SCHEMA_NAME:
        raise ValueError(f"metadata schema must be {SCHEMA_NAME!r}, got {meta['schema']!r}")
    if meta["schema_version"] != SCHEMA_VERSION:
        raise ValueError(
            f"metadata schema_version {meta['schema_version']!r} is not supported (expected {SCHEMA_VERSION})"
        )
    if meta["source"] not in _SOURCES:
        raise ValueError(f"metadata source must be one of {_SOURCES}, got {meta['source']!r}")
    dt = meta["dt_s"]
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not math.isfinite(dt) or dt <= 0:
        raise ValueError(f"metadata dt_s must be a positive number, got {dt!r}")
    if not DT_S_RANGE[0] <= dt <= DT_S_RANGE[1]:
        raise ValueError(f"metadata dt_s must lie in [{DT_S_RANGE[0]:g}, {DT_S_RANGE[1]:g}] s, got {dt!r}")
    names = meta["position_names"]
    if not isinstance(names, (list, tuple)) or not names or any(n not in POSITION_NAMES for n in names):
        raise ValueError(f"metadata position_names must be a list drawn from {POSITION_NAMES}, got {names!r}")
    if len(set(names)) != len(names):
        raise ValueError(f"metadata position_names has duplicates: {names!r}")
    absent = [n for n in REQUIRED_POSITION_NAMES if n not in names]
    if absent:
        raise ValueError(f"metadata position_names must include {REQUIRED_POSITION_NAMES}; missing {absent}")
    expected_velocity_names = [velocity_name(n) for n in names]
    if not isinstance(meta["velocity_names"], list) or meta["velocity_names"] != expected_velocity_names:
        raise ValueError(f"metadata velocity_names must be {expected_velocity_names}, got {meta['velocity_names']!r}")
    if meta["plant_params"] is not None:
        if not isinstance(meta["plant_params"], dict):
            raise ValueError(f"metadata plant_params must be an object or null, got {meta['plant_params']!r}")
        RodParams.from_dict(meta["plant_params"])  # raises ValueError on unknown or invalid fields
    if meta["seed"] is not None and (isinstance(meta["seed"], bool) or not isinstance(meta["seed"], int)):
        raise ValueError(f"metadata seed must be an integer or null, got {meta['seed']!r}")
    if not isinstance(meta["protocol"], dict):
        raise ValueError(f"metadata protocol must be an object, got {meta['protocol']!r}")
    for key in ("n_trials", "n_samples"):
        if isinstance(meta[key], bool) or not isinstance(meta[key], int):
            raise ValueError(f"metadata {key} must be an integer, got {meta[key]!r}")
    n_trials, n_samples, n_pos = meta["n_trials"], meta["n_samples"], len(names)
    if n_trials < 1 or n_samples < 2:
        raise ValueError(f"need n_trials >= 1 and n_samples >= 2, got {n_trials} and {n_samples}")
    try:
        json.dumps(meta, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"metadata must be JSON-serialisable without NaN: {exc}") from exc

    shapes = {
        "positions": (n_trials, n_samples, n_pos),
        "velocities": (n_trials, n_samples, n_pos),
        "torques_nm": (n_trials, n_samples - 1),
        "true_observations": (n_trials, n_samples, len(OBSERVATION_NAMES)),
    }
    joint_shape = None
    for name in _ARRAYS_REQUIRED + _ARRAYS_OPTIONAL:
        value = getattr(ds, name)
        if value is None:
            if name in _ARRAYS_REQUIRED:
                raise ValueError(f"{name} is required")
            continue
        if not isinstance(value, np.ndarray):
            raise ValueError(f"{name} must be a numpy array, got {type(value).__name__}")
        if value.dtype != np.float64:
            raise ValueError(f"{name} must have dtype float64, got {value.dtype}")
        expected = shapes.get(name)
        if expected is None:  # joint arrays: (T, N, J) with the same J for both
            if value.ndim != 3 or value.shape[:2] != (n_trials, n_samples) or value.shape[2] < 1:
                raise ValueError(f"{name} must have shape ({n_trials}, {n_samples}, J), got {value.shape}")
            if joint_shape is not None and value.shape != joint_shape:
                raise ValueError(
                    f"joint_positions_rad and joint_velocities_rad_s shapes differ: {joint_shape} vs {value.shape}"
                )
            joint_shape = value.shape
        elif value.shape != expected:
            raise ValueError(f"{name} must have shape {expected} (from metadata), got {value.shape}")
        if not np.all(np.isfinite(value)):
            bad = np.argwhere(~np.isfinite(value))[0]
            raise ValueError(f"{name} has non-finite values (first at index {tuple(int(i) for i in bad)})")
    if (ds.joint_positions_rad is None) != (ds.joint_velocities_rad_s is None):
        raise ValueError("joint_positions_rad and joint_velocities_rad_s must be given together")
    angle_columns = [i for i, n in enumerate(names) if n in ("phi_rad", "theta_rad", "er_rad")]
    wrapped = ds.positions[..., angle_columns]
    if wrapped.size and (wrapped.min() < -np.pi - 1e-9 or wrapped.max() > np.pi + 1e-9):
        raise ValueError("angle columns of positions must be wrapped to [-pi, pi)")
    params = ds.params
    if params is not None:
        limit = params.torque_limit_nm
        if np.abs(ds.torques_nm).max(initial=0.0) > limit * (1 + 1e-9):
            raise ValueError(f"torques_nm exceed the torque limit {limit} N m of plant_params")


# ---------------------------------------------------------------------------------------- writing
def save_dataset(
    path: str | Path,
    positions: np.ndarray,
    velocities: np.ndarray,
    torques_nm: np.ndarray,
    *,
    dt_s: float,
    position_names: tuple[str, ...] | list[str] = POSITION_NAMES,
    source: str = "rig",
    plant: Optional[str] = None,
    plant_params: Optional[RodParams | dict] = None,
    seed: Optional[int] = None,
    protocol: Optional[dict[str, Any]] = None,
    differentiation: str = "backward",
    notes: str = "",
    true_observations: Optional[np.ndarray] = None,
    joint_positions_rad: Optional[np.ndarray] = None,
    joint_velocities_rad_s: Optional[np.ndarray] = None,
) -> TrajectoryDataset:
    """Validate arrays plus metadata and write them as a dataset file (see the module docstring).

    Parameters
    ----------
    path : str or Path
        Output file (``.npz`` is appended if missing); parent folders are created.
    positions, velocities : ndarray, shape (T, N, P)
        Observed positions [rad, m] (angles wrapped to ``[-pi, pi)``) and their derivatives [rad/s, m/s];
        use :func:`softpend.sysid.backward_difference` on ``N + 1`` samples to get the latter as a rig.
    torques_nm : ndarray, shape (T, N - 1)
        Torque applied between consecutive samples [N m].
    dt_s : float
        Sampling step [s].
    position_names : sequence of str
        Column names of ``positions`` (subset of ``phi_rad, theta_rad, ex_m, ey_m, er_rad`` containing
        ``phi_rad, ex_m, ey_m``).
    source : {"rig", "simulation"}
        Where the data came from.
    plant, plant_params, seed, protocol, differentiation, notes
        Metadata (plant name, :class:`RodParams` or its dict, random seed, how the torques were made,
        velocity scheme, free text).
    true_observations, joint_positions_rad, joint_velocities_rad_s : ndarray, optional
        Simulator ground truth (see the module docstring).

    Returns
    -------
    TrajectoryDataset
        The dataset as written (so ``load_dataset(path)`` returns an equal one).

    Raises
    ------
    ValueError
        If any array or metadata entry is invalid (the message names it).
    """
    from softpend import __version__

    if isinstance(plant_params, RodParams):
        plant_params = plant_params.to_dict()
    names = [str(n) for n in position_names]
    metadata = {
        "schema": SCHEMA_NAME,
        "schema_version": SCHEMA_VERSION,
        "softpend_version": __version__,
        "source": source,
        "dt_s": float(dt_s) if isinstance(dt_s, (int, float, np.floating)) and not isinstance(dt_s, bool) else dt_s,
        "n_trials": int(np.shape(positions)[0]) if np.ndim(positions) == 3 else -1,
        "n_samples": int(np.shape(positions)[1]) if np.ndim(positions) == 3 else -1,
        "position_names": names,
        "velocity_names": [velocity_name(n) if n in POSITION_NAMES else n for n in names],
        "differentiation": str(differentiation),
        "plant": plant,
        "plant_params": plant_params,
        "seed": None if seed is None else int(seed),
        "protocol": {} if protocol is None else _jsonable(protocol),
        "notes": str(notes),
    }
    if np.ndim(positions) != 3:
        raise ValueError(f"positions must have shape (T, N, P), got {np.shape(positions)}")
    dataset = TrajectoryDataset(
        positions=_as_float64("positions", positions),
        velocities=_as_float64("velocities", velocities),
        torques_nm=_as_float64("torques_nm", torques_nm),
        metadata=metadata,
        true_observations=None if true_observations is None else _as_float64("true_observations", true_observations),
        joint_positions_rad=None
        if joint_positions_rad is None
        else _as_float64("joint_positions_rad", joint_positions_rad),
        joint_velocities_rad_s=None
        if joint_velocities_rad_s is None
        else _as_float64("joint_velocities_rad_s", joint_velocities_rad_s),
    )
    write_dataset(path, dataset)
    return dataset


def write_dataset(path: str | Path, dataset: TrajectoryDataset) -> Path:
    """Write an already validated :class:`TrajectoryDataset`; returns the path written."""
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    members = dict(dataset.arrays())
    members["metadata"] = np.array(json.dumps(dataset.metadata, sort_keys=True, allow_nan=False))
    with atomic_write(path) as handle, zipfile.ZipFile(handle, mode="w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name in sorted(members):
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_DATE_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            buffer = io.BytesIO()
            np.lib.format.write_array(buffer, np.require(members[name], requirements="C"), allow_pickle=False)
            archive.writestr(info, buffer.getvalue())
    return path


def _as_float64(name: str, value: Any) -> np.ndarray:
    try:
        array = np.asarray(value)
    except Exception as exc:  # ragged lists and the like
        raise ValueError(f"{name} must be a numeric array: {exc}") from exc
    if not np.issubdtype(array.dtype, np.number) or np.issubdtype(array.dtype, np.complexfloating):
        raise ValueError(f"{name} must be a real numeric array, got dtype {array.dtype}")
    return np.ascontiguousarray(array, dtype=np.float64)


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


# ---------------------------------------------------------------------------------------- reading
def load_dataset(
    path: str | Path,
    *,
    expected_params: Optional[RodParams] = None,
    expected_dt_s: Optional[float] = None,
) -> TrajectoryDataset:
    """Read and validate a dataset file written by :func:`save_dataset` (never unpickles).

    Parameters
    ----------
    path : str or Path
        The ``.npz`` file.
    expected_params : RodParams, optional
        If given, the file's ``plant_params`` must equal these.
    expected_dt_s : float, optional
        If given, the file's ``dt_s`` must equal this.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If the file is not a valid dataset (corrupt archive, missing or extra member, wrong shape,
        dtype or non-finite values, bad or mismatched metadata); the message says what is wrong.
    """
    path = Path(path)
    members = read_npz(path, "dataset file")
    if "metadata" not in members:
        raise ValueError(f"{path} has no metadata member (not a softpend dataset)")
    raw_metadata = members.pop("metadata")
    if raw_metadata.ndim != 0 or raw_metadata.dtype.kind != "U":
        raise ValueError(
            f"{path}: metadata must be a 0-d unicode array, got dtype {raw_metadata.dtype} shape {raw_metadata.shape}"
        )
    try:
        metadata = json.loads(str(raw_metadata[()]))
        if not isinstance(metadata, dict):
            raise TypeError(f"expected a JSON object, got {type(metadata).__name__}")
    except (json.JSONDecodeError, TypeError) as exc:
        raise ValueError(f"{path}: metadata is not valid JSON: {exc}") from exc
    except RecursionError:
        raise ValueError(f"{path}: metadata is nested too deeply to be a dataset's") from None
    unknown = set(members) - set(_ARRAYS_REQUIRED) - set(_ARRAYS_OPTIONAL)
    if unknown:
        raise ValueError(f"{path}: unexpected members {sorted(unknown)}")
    missing = [name for name in _ARRAYS_REQUIRED if name not in members]
    if missing:
        raise ValueError(f"{path}: missing arrays {missing}")
    try:
        dataset = TrajectoryDataset(metadata=metadata, **members)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    if expected_dt_s is not None and not math.isclose(dataset.dt_s, expected_dt_s, rel_tol=1e-12):
        raise ValueError(f"{path}: dt_s is {dataset.dt_s}, expected {expected_dt_s}")
    if expected_params is not None and dataset.metadata["plant_params"] != expected_params.to_dict():
        raise ValueError(
            f"{path}: plant_params {dataset.metadata['plant_params']} do not match the expected {expected_params.to_dict()}"
        )
    return dataset
