"""System-identification datasets: trials of positions ``(T, N, P)``, backward-difference velocities ``(T, N, P)``
and held torques ``(T, N - 1)`` (optionally the simulator's true observations and joint states) in one
deterministic ``.npz`` file with JSON metadata (schema ``softpend.sysid.dataset`` v1); never unpickled."""

from __future__ import annotations

import io
import json
import math
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from softpend.checks import in_range, one_of
from softpend.io.arrays import read_npz
from softpend.io.outputs import atomic_write
from softpend.plant import OBSERVATION_NAMES, RodParams
from softpend.sysid.variables import ANGLE_NAMES, POSITION_NAMES, velocity_name

SCHEMA_NAME = "softpend.sysid.dataset"
SCHEMA_VERSION = 1
#: Every dataset has at least the limited-information variables: base angle and tip position.
REQUIRED_POSITION_NAMES: tuple[str, ...] = ("phi_rad", "ex_m", "ey_m")
_SOURCES = ("simulation", "rig")
_REQUIRED_METADATA = tuple(
    "schema schema_version softpend_version source dt_s n_trials n_samples position_names velocity_names "
    "differentiation plant plant_params seed protocol notes".split()
)
#: Accepted sampling steps [s]; a ``dt_s`` outside is a corrupt or mistyped file.
DT_S_RANGE: tuple[float, float] = (1e-6, 10.0)
_ARRAYS_REQUIRED = ("positions", "velocities", "torques_nm")
_ARRAYS = (*_ARRAYS_REQUIRED, "true_observations", "joint_positions_rad", "joint_velocities_rad_s")
_ZIP_DATE_TIME = (1980, 1, 1, 0, 0, 0)


@dataclass(frozen=True, eq=False)
class TrajectoryDataset:
    """Trials of sampled observations and the torques that produced them; the constructor validates everything."""

    positions: np.ndarray
    velocities: np.ndarray
    torques_nm: np.ndarray
    metadata: dict[str, Any]
    true_observations: Optional[np.ndarray] = None
    joint_positions_rad: Optional[np.ndarray] = None
    joint_velocities_rad_s: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        _validate(self)

    @property
    def n_trials(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_samples(self) -> int:
        return int(self.positions.shape[1])

    @property
    def n_transitions(self) -> int:
        return self.n_trials * (self.n_samples - 1)

    @property
    def dt_s(self) -> float:
        return float(self.metadata["dt_s"])

    @property
    def position_names(self) -> tuple[str, ...]:
        return tuple(self.metadata["position_names"])

    @property
    def velocity_names(self) -> tuple[str, ...]:
        return tuple(self.metadata["velocity_names"])

    @property
    def params(self) -> Optional[RodParams]:
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

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays present, by file member name."""
        return {name: getattr(self, name) for name in _ARRAYS if getattr(self, name) is not None}


def _validate(ds: TrajectoryDataset) -> None:
    meta = ds.metadata
    if not isinstance(meta, dict):
        raise ValueError(f"metadata must be a dict, got {type(meta).__name__}")
    missing = [key for key in _REQUIRED_METADATA if key not in meta]
    if missing:
        raise ValueError(f"metadata is missing keys {missing}")
    for key, allowed in (("schema", (SCHEMA_NAME,)), ("schema_version", (SCHEMA_VERSION,)), ("source", _SOURCES)):
        one_of(f"metadata {key}", meta[key], allowed)
    in_range("metadata dt_s", meta["dt_s"], *DT_S_RANGE)
    names = meta["position_names"]
    known = isinstance(names, (list, tuple)) and all(n in POSITION_NAMES for n in names)
    if not (known and len(set(names)) == len(names) and set(REQUIRED_POSITION_NAMES) <= set(names)):
        raise ValueError(
            f"metadata position_names must include {REQUIRED_POSITION_NAMES} in distinct names of {POSITION_NAMES}, "
            f"got {names!r}"
        )

    def integer(value: Any, low: float = -math.inf) -> bool:
        return isinstance(value, int) and not isinstance(value, bool) and value >= low

    velocity_names = [velocity_name(n) for n in names]
    rules = {
        "velocity_names": (meta["velocity_names"] == velocity_names, str(velocity_names)),
        "plant_params": (meta["plant_params"] is None or isinstance(meta["plant_params"], dict), "an object or null"),
        "seed": (meta["seed"] is None or integer(meta["seed"]), "an integer or null"),
        "protocol": (isinstance(meta["protocol"], dict), "an object"),
        "n_trials": (integer(meta["n_trials"], 1), "an integer >= 1"),
        "n_samples": (integer(meta["n_samples"], 2), "an integer >= 2"),
    }
    for key, (ok, what) in rules.items():
        if not ok:
            raise ValueError(f"metadata {key} must be {what}, got {meta[key]!r}")
    if meta["plant_params"] is not None:
        RodParams.from_dict(meta["plant_params"])
    try:
        json.dumps(meta, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"metadata must be JSON-serialisable without NaN: {exc}") from exc
    t, n = meta["n_trials"], meta["n_samples"]
    shapes = {"positions": (t, n, len(names)), "velocities": (t, n, len(names)), "torques_nm": (t, n - 1)}
    shapes["true_observations"] = (t, n, len(OBSERVATION_NAMES))
    for name in _ARRAYS:
        value = getattr(ds, name)
        if value is None:
            if name in _ARRAYS_REQUIRED:
                raise ValueError(f"missing arrays: {name} is required")
            continue
        if not isinstance(value, np.ndarray) or value.dtype != np.float64:
            raise ValueError(f"{name} must be a numpy array of dtype float64, got {getattr(value, 'dtype', value)!r}")
        joints = value.shape[-1] if value.ndim == 3 and value.shape[-1] else "J"  # joint arrays: (T, N, J)
        expected = shapes.get(name, (t, n, joints))
        if value.shape != expected:
            raise ValueError(f"{name} must have shape {expected} (from metadata), got {value.shape}")
        if not np.all(np.isfinite(value)):
            bad = np.argwhere(~np.isfinite(value))[0]
            raise ValueError(f"{name} has non-finite values (first at index {tuple(int(i) for i in bad)})")
    if getattr(ds.joint_positions_rad, "shape", None) != getattr(ds.joint_velocities_rad_s, "shape", None):
        raise ValueError("joint_positions_rad and joint_velocities_rad_s must be given together, of one shape")
    wrapped = ds.positions[..., [i for i, n in enumerate(names) if n in ANGLE_NAMES]]
    if wrapped.size and (wrapped.min() < -np.pi - 1e-9 or wrapped.max() > np.pi + 1e-9):
        raise ValueError("angle columns of positions must be wrapped to [-pi, pi)")
    params = ds.params
    if params is not None and np.abs(ds.torques_nm).max(initial=0.0) > params.torque_limit_nm * (1 + 1e-9):
        raise ValueError(f"torques_nm exceed the torque limit {params.torque_limit_nm} N m of plant_params")


def dataset_metadata(
    positions: Any,
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
) -> dict[str, Any]:
    """The metadata of a dataset with these positions ``(T, N, P)``."""
    from softpend import __version__

    if isinstance(plant_params, RodParams):
        plant_params = plant_params.to_dict()
    names = [str(n) for n in position_names]
    shape = np.shape(positions) if np.ndim(positions) == 3 else (-1, -1)
    dt = float(dt_s) if isinstance(dt_s, (int, float, np.floating)) and not isinstance(dt_s, bool) else dt_s
    return {
        "schema": SCHEMA_NAME,
        "schema_version": SCHEMA_VERSION,
        "softpend_version": __version__,
        "source": source,
        "dt_s": dt,
        "n_trials": int(shape[0]),
        "n_samples": int(shape[1]),
        "position_names": names,
        "velocity_names": [velocity_name(n) if n in POSITION_NAMES else n for n in names],
        "plant": plant,
        "differentiation": str(differentiation),
        "seed": None if seed is None else int(seed),
        "notes": str(notes),
        "plant_params": plant_params,
        "protocol": json.loads(json.dumps(protocol or {}, default=np.generic.item)),  # numpy scalars, tuples
    }


def save_dataset(
    path: str | Path,
    positions: np.ndarray,
    velocities: np.ndarray,
    torques_nm: np.ndarray,
    *,
    true_observations: Optional[np.ndarray] = None,
    joint_positions_rad: Optional[np.ndarray] = None,
    joint_velocities_rad_s: Optional[np.ndarray] = None,
    **metadata: Any,
) -> TrajectoryDataset:
    """Validate arrays plus metadata (the keywords of :func:`dataset_metadata`) and write them as a dataset file
    (``.npz`` appended if missing); returns the dataset as written.  ``ValueError`` names what is invalid."""
    meta = dataset_metadata(positions, **metadata)
    if np.ndim(positions) != 3:
        raise ValueError(f"positions must have shape (T, N, P), got {np.shape(positions)}")
    given = (positions, velocities, torques_nm, true_observations, joint_positions_rad, joint_velocities_rad_s)
    arrays = {name: _as_float64(name, value) for name, value in zip(_ARRAYS, given) if value is not None}
    dataset = TrajectoryDataset(metadata=meta, **arrays)
    write_dataset(path, dataset)
    return dataset


def write_dataset(path: str | Path, dataset: TrajectoryDataset) -> Path:
    """Write a :class:`TrajectoryDataset` (``.npz`` appended if missing); returns the path written."""
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    members = dataset.arrays() | {"metadata": np.array(json.dumps(dataset.metadata, sort_keys=True, allow_nan=False))}
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


def load_dataset(path: str | Path, *, expected_dt_s: Optional[float] = None) -> TrajectoryDataset:
    """Read and validate a dataset file, optionally checking its ``dt_s``; raises
    ``FileNotFoundError`` if ``path`` does not exist, ``ValueError`` saying what is wrong otherwise."""
    path = Path(path)
    members = read_npz(path, "dataset file")
    raw = members.pop("metadata", np.array(None))
    if raw.ndim != 0 or raw.dtype.kind != "U":
        raise ValueError(f"{path}: metadata must be a 0-d unicode array, got {raw.dtype} {raw.shape}")
    try:
        metadata = json.loads(str(raw[()]))
    except (json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"{path}: metadata is not valid JSON: {type(exc).__name__}: {exc}") from None
    unknown = set(members) - set(_ARRAYS)
    if unknown:
        raise ValueError(f"{path}: unexpected members {sorted(unknown)}")
    arrays: dict[str, Any] = {name: None for name in _ARRAYS_REQUIRED} | members
    try:
        dataset = TrajectoryDataset(metadata=metadata, **arrays)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    if expected_dt_s is not None and not math.isclose(dataset.dt_s, expected_dt_s, rel_tol=1e-12):
        raise ValueError(f"{path}: dt_s is {dataset.dt_s}, expected {expected_dt_s}")
    return dataset
