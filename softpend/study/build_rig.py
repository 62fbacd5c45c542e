"""Building the rig: the numbers that choose its parts and the procedure from a box of parts to a balancing rod."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from softpend.checks import int_at_least, positive
from softpend.evaluation import evaluate_controller
from softpend.hardware.rig_design import TPU_MODULUS_RANGE_PA, V5_CARTRIDGES, MotorCartridge, RigDesign, rig_design
from softpend.plant import OBSERVATION_NAMES, RodParams
from softpend.plant.observation import wrap_angle_rad
from softpend.study.rig_runs import rig_controllers
from softpend.study.rod_design import rod_design
from softpend.task import Task

#: Least ratio of the torque a cartridge gives at the peak hub rate to the controllers' torque limit.
MIN_TORQUE_MARGIN = 1.5
#: Largest RMS residual of the marker fit of a good calibration [px].
CALIBRATION_MAX_RESIDUAL_PX = 0.5
#: Largest distance of the tracked hanging tip from where the design puts it [m].
HANGING_TIP_TOLERANCE_M = 0.005
#: Horizon of the open-loop rollout error that judges the identified model [s].
IDENTIFY_HORIZON_S = 0.5
#: Cameras the closed loop has run under on the twin: name -> (frame rate [1/s], latency [s]).
TESTED_CAMERAS: dict[str, tuple[float, float]] = {"nominal": (60.0, 0.020), "harsh": (30.0, 0.040)}
#: The peaks :func:`swing_up_needs` reports (``peak_<name>``).
_PEAKS = ("torque_nm", "hub_rate_rad_s", "tip_speed_m_s")


def swing_up_needs(task: Task, seeds: Sequence[int], duration_s: float) -> list[dict[str, Any]]:
    """Per rig controller and seed: success, swing-up time, upright std and peak torque, hub rate and tip speed."""
    phi_dot, ex_dot, ey_dot = (OBSERVATION_NAMES.index(n) for n in ("phi_dot_rad_s", "ex_dot_m_s", "ey_dot_m_s"))
    rows = []
    for label, make in rig_controllers(task).items():
        for r in evaluate_controller(make(), task, name=label, seeds=list(seeds), duration_s=duration_s).results:
            obs = r.observations
            peaks = (r.torque_nm, obs[:, phi_dot], np.hypot(obs[:, ex_dot], obs[:, ey_dot]))
            row = {"controller": label, "seed": r.seed, "success": bool(r.success)}
            row |= {k: float(getattr(r, k)) for k in ("swing_up_time_s", "upright_std_rad")}
            rows.append(row | {f"peak_{k}": float(np.max(np.abs(v))) for k, v in zip(_PEAKS, peaks)})
    return rows


def motor_rows(peak_hub_rate_rad_s: float, torque_nm: float) -> list[dict[str, Any]]:
    """Each V5 cartridge against the peak hub rate and ``torque_nm`` (qualifies: faster, :data:`MIN_TORQUE_MARGIN`)."""
    rows = []
    for c in V5_CARTRIDGES:
        available = c.available_torque_nm(peak_hub_rate_rad_s)
        speed_margin = c.free_speed_rad_s / peak_hub_rate_rad_s if peak_hub_rate_rad_s > 0 else math.inf
        row = {"cartridge": c.name, "free_speed_rad_s": c.free_speed_rad_s, "stall_torque_nm": c.stall_torque_nm}
        torque_margin = available / torque_nm
        row |= {"speed_margin": speed_margin, "torque_at_peak_rate_nm": available, "torque_margin": torque_margin}
        qualifies = bool(speed_margin > 1.0 and torque_margin >= MIN_TORQUE_MARGIN)
        rows.append(row | {"encoder_ticks_per_rev": c.encoder_ticks_per_rev, "qualifies": qualifies})
    return rows


def choose_cartridge(rows: Sequence[dict[str, Any]]) -> MotorCartridge:
    """The qualifying cartridge of :func:`motor_rows` with the finest encoder."""
    good = [c for c, r in zip(V5_CARTRIDGES, rows) if r["qualifies"]]
    if not good:
        raise ValueError("rows: no cartridge gives the swing-up's torque at its peak hub rate")
    return max(good, key=lambda c: c.encoder_ticks_per_rev)


class QuantisedHub:
    """A controller that sees the hub angle only to ``counts_per_rev`` encoder ticks (zero at hanging)."""

    def __init__(self, controller: Any, counts_per_rev: int) -> None:
        self.controller = controller
        self.tick_rad = 2.0 * math.pi / int_at_least("counts_per_rev", counts_per_rev, 4)

    def reset(self) -> None:
        if hasattr(self.controller, "reset"):
            self.controller.reset()

    def _quantise(self, phi_rad: float) -> float:
        return math.pi + round((phi_rad - math.pi) / self.tick_rad) * self.tick_rad

    def __call__(self, observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        q = np.array(q, dtype=float)
        q[0] = self._quantise(float(q[0]))
        observation = observation._replace(phi_rad=wrap_angle_rad(self._quantise(observation.phi_rad)))
        return float(self.controller(observation, q, q_dot, time_s))


def encoder_rows(task: Task, counts: Sequence[int], seeds: Sequence[int], duration_s: float) -> list[dict[str, Any]]:
    """Per encoder resolution and rig controller: successes and worst upright std with the hub angle quantised, and
    its LQR's torque step for one tick over the torque limit."""
    from softpend.control.lqr import LQRController

    obs = LQRController.from_params(task.rod, task.dt_s, state="observation")
    assert obs.model is not None  # from_params keeps its design model
    gain = {"observations": abs(float(obs.gain[0, obs.model.state_names.index("phi_rad")]))}
    if task.plant == "prb":
        gain["joint state"] = abs(float(LQRController.from_params(task.rod, task.dt_s, state="joint").gain[0, 0]))
    rows = []
    for n in counts:
        tick = 2.0 * math.pi / int_at_least("counts_per_rev", n, 4)
        for label, make in rig_controllers(task).items():
            summary = evaluate_controller(
                QuantisedHub(make(), n), task, name=label, seeds=list(seeds), duration_s=duration_s
            )
            stds = [r.upright_std_rad for r in summary.results if r.success]
            row = {"counts_per_rev": int(n), "controller": label, "starts": len(summary.results)}
            row |= {"successes": summary.successes, "worst_upright_std_rad": max(stds) if stds else math.nan}
            step = gain["joint state" if "joint" in label else "observations"] * tick / task.torque_limit_nm
            rows.append(row | {"torque_per_tick_fraction": step})
    return rows


def camera_rows(
    design: RigDesign,
    peak_tip_speed_m_s: float,
    search_radius_px: float,
    exposure_s: float,
    fps_values: Sequence[float],
) -> list[dict[str, Any]]:
    """Per frame rate: the tip's largest step between frames and its motion blur against the search radius and the
    dot's diameter [px]."""
    speed_px = peak_tip_speed_m_s * design.camera_model.px_per_m
    dot_px = 2.0 * design.dot_radius_m * design.camera_model.px_per_m
    return [
        {
            "fps": float(fps),
            "step_px": speed_px / fps,
            "search_radius_px": float(search_radius_px),
            "within_window": bool(speed_px / fps < search_radius_px),
            "blur_px": speed_px * exposure_s,
            "dot_diameter_px": dot_px,
            "max_exposure_ms": 1e3 * dot_px / speed_px if speed_px > 0 else math.inf,
        }
        for fps in fps_values
    ]


def modulus_rows(params: RodParams) -> list[dict[str, Any]]:
    """Per modulus (softest TPU, the rod's, stiffest TPU): the design figures, and the thickness keeping the stiffness."""
    rows = []
    for e in (TPU_MODULUS_RANGE_PA[0], params.youngs_modulus_pa, TPU_MODULUS_RANGE_PA[1]):
        figures = rod_design(params.replace(youngs_modulus_pa=e))
        row = {k: getattr(figures, k) for k in ("tip_sag_fraction", "torque_ratio", "buckling_load_factor")}
        thickness_mm = 1e3 * rig_design(params, print_modulus_pa=e).beam_thickness_m
        rows.append({"modulus_mpa": e / 1e6, **row, "thickness_for_design_mm": thickness_mm})
    return rows


def parts_list(design: RigDesign, cartridge: MotorCartridge, camera_fps: float) -> list[dict[str, str]]:
    """What to print and buy, with the dimensions of ``design`` (rows of ``part``, ``quantity``, ``spec``)."""
    d, hub, cam, mm = design.to_dict(), design.hub, design.camera, 1e3
    markers = ", ".join(f"({x * mm:.0f}, {y * mm:.0f})" for x, y in design.markers_m)
    table = [
        f"TPU beam (printed) | 1 | {d['beam_length_mm']:.1f} x {d['beam_width_mm']:.1f} x {d['beam_thickness_mm']:.2f} mm (length x width out of plane x thickness in plane), E = {d['print_modulus_mpa']:.3g} MPa, solid infill, about {d['beam_mass_g']:.0f} g",
        f"hub mount (printed, rigid: PLA or PETG) | 1 | boss radius {d['mount_boss_radius_mm']:.0f} mm, square bore {d['mount_bore_mm']:.3f} mm for the shaft, beam pocket from {mm * hub.pocket_start_m:.0f} mm, marker flag {d['flag_length_mm']:.0f} mm long {mm * hub.flag_gap_m:.0f} mm in front of the beam",
        f"tip mass (steel disc) | 1 | diameter {d['tip_disc_diameter_mm']:.0f} mm, thickness {d['tip_disc_thickness_mm']:.2f} mm, {d['tip_mass_g']:.3g} g, matte blue dot of the same diameter on its front",
        f"calibration markers (matte green discs) | {len(design.markers_m)} | diameter {d['marker_diameter_mm']:.0f} mm on a board in the dot's plane, at {markers} mm from the hub axis",
        f"hub marker (matte magenta disc) | 1 | diameter {2e3 * hub.hub_marker_dot_radius_m:.0f} mm on the flag, {d['hub_marker_radius_mm']:.0f} mm from the hub axis",
        f"VEX V5 Smart Motor | 1 | {cartridge.name} cartridge ({cartridge.encoder_ticks_per_rev} encoder ticks per revolution), torque limit {design.params.torque_limit_nm:g} N m set in the device program",
        "VEX V5 Robot Brain, battery, 1/8 inch square shaft, bearing flat | 1 each | the device program runs on the brain; USB to the host computer",
        f"camera | 1 | {cam.width_px} x {cam.height_px} px at >= {camera_fps:g} frames/s, horizontal field of view {cam.horizontal_fov_deg:g} deg, {d['camera_distance_mm']:.0f} mm from the rod plane, square on, optical axis through the hub axis",
    ]
    return [dict(zip(("part", "quantity", "spec"), row.split(" | "))) for row in table]


def firmware_settings() -> dict[str, Any]:
    """The literal settings of the device program's source (``COUNTS_PER_REV``, ...) and its ``gear_setting``."""
    import ast

    from softpend.hardware.firmware import FIRMWARE_PATH

    tree = ast.parse(Path(FIRMWARE_PATH).read_text())
    values: dict[str, Any] = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            try:
                values[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                continue
    for found in ast.walk(tree):
        if isinstance(found, ast.Attribute) and isinstance(found.value, ast.Name) and found.value.id == "GearSetting":
            values["gear_setting"] = found.attr
    return values


@dataclass(frozen=True)
class BuildTarget:
    """Where the procedure runs: the digital twin, or a rig (serial ``port`` of the brain, ``camera`` index or URL)."""

    twin: bool = True
    port: str = "/dev/ttyACM1"
    camera: str = "0"

    def args(self, *names: str) -> list[str]:
        """``--twin``, or each of ``names`` as ``--NAME VALUE``."""
        return ["--twin"] if self.twin else [a for name in names for a in (f"--{name}", getattr(self, name))]


#: The twin target of the dry run.
TWIN = BuildTarget()


@dataclass(frozen=True)
class BuildBudget:
    """Run lengths of the procedure [s], training epochs of the identified model, and the seed."""

    babble_s: float = 65.0
    trial_length_s: float = 5.0
    max_epochs: int = 150
    control_s: float = 10.0
    seed: int = 0

    def __post_init__(self) -> None:
        positive("trial_length_s", self.trial_length_s)
        if not self.babble_s >= self.trial_length_s + 3:
            raise ValueError(f"babble_s must be at least trial_length_s + 3 s, got {self.babble_s!r}")
        int_at_least("max_epochs", self.max_epochs, 1)
        positive("control_s", self.control_s)


@dataclass(frozen=True)
class BuildStep:
    """One step of the procedure: short name, what it does, its command line and what a good result looks like."""

    key: str
    title: str
    argv: tuple[str, ...]
    good: str

    @property
    def command(self) -> str:
        """The command line as one shell line."""
        return " ".join(a if a and all(ch not in a for ch in " []{}\"',") else f"'{a}'" for a in self.argv)


def build_steps(
    folder: str | Path, target: BuildTarget = TWIN, budget: BuildBudget = BuildBudget(), overrides: Sequence[str] = ()
) -> list[BuildStep]:
    """The procedure from the design to the first closed-loop run into ``folder``; ``overrides``: ``--set`` values."""
    f = Path(folder)
    sets = [a for item in overrides for a in ("--set", item)]
    counts = ["--counts-per-rev", str(firmware_settings()["COUNTS_PER_REV"])]
    calibration = [] if target.twin else ["--calibration", str(f / "calibration.json")]
    rig = ("softpend", "rig")
    link, on_rig = target.args("port"), target.args("port", "camera")
    return [
        BuildStep(
            "design",
            "Compute the rig's dimensions and drawing from the rod's parameters",
            (*rig, "design", "--out", str(f / "design"), *sets),
            "every marker and the whole swing circle inside the image, every marker clear of the swing "
            "circle, and a dot larger than the tracker's smallest blob",
        ),
        BuildStep(
            "firmware",
            "Check that the device program carries the host's protocol",
            ("python", "-m", "softpend.hardware.firmware"),
            "'firmware protocol copy is up to date' and exit status 0",
        ),
        BuildStep(
            "check",
            "Power on: handshake, encoder at rest, direction, watchdog",
            (*rig, "check", *link, *(counts if target.twin else []), "--out", str(f / "check.json")),
            "the protocol version, torque limit and state rate the host expects; the hub at rest at the "
            "hanging angle; a positive torque turns the hub the positive way; the watchdog zeroes the torque "
            "after a silent host",
        ),
        BuildStep(
            "calibrate",
            "Fit the camera's affine map to the markers",
            (*rig, "calibrate", *target.args("camera"), "--markers", str(f / "design" / "markers.json"))
            + ("--out", str(f / "calibration.json"), *sets),
            f"marker residual at most {CALIBRATION_MAX_RESIDUAL_PX:g} px and the hanging tip within "
            f"{HANGING_TIP_TOLERANCE_M * 1e3:g} mm of where the design puts it",
        ),
        BuildStep(
            "babble",
            "Babble: random torque, encoder and camera logged and synchronised",
            (*rig, "babble", *on_rig, *calibration, "--out", str(f / "babble"))
            + ("--duration", f"{budget.babble_s:g}", "--trial-length-s", f"{budget.trial_length_s:g}")
            + ("--seed", str(budget.seed), "--no-progress"),
            "a clock offset found with a clear correlation peak, no gaps, and whole trials in the dataset",
        ),
        BuildStep(
            "identify",
            "Identify the rod: fit the dynamics model to the babbling",
            ("softpend", "fit-model", str(f / "babble" / "rig_dataset.npz"), str(f / "model"))
            + ("--information", "limited", "--max-epochs", str(budget.max_epochs), "--no-progress"),
            f"open-loop tip error {IDENTIFY_HORIZON_S:g} s into a rollout below the yardstick of a rod that stays put",
        ),
        BuildStep(
            "control",
            "First closed-loop run: energy swing-up and LQR on the observations",
            (*rig, "control", "swingup-obs", *on_rig, *calibration, *counts, "--out", str(f / "control"))
            + ("--duration", f"{budget.control_s:g}", "--no-progress"),
            "no early stop; on the twin, the rod's true tip swung up and held upright",
        ),
    ]


def check_step(step: BuildStep, folder: str | Path) -> dict[str, Any]:
    """The figures of the outputs of ``step`` (run with :func:`build_steps` into ``folder``), with ``good``."""
    from softpend.io.reading import MAX_CONFIG_BYTES, read_json_checked

    f = Path(folder)
    read = lambda *parts: read_json_checked(f.joinpath(*parts), "build output", MAX_CONFIG_BYTES)  # noqa: E731

    if step.key == "firmware":
        return {"good": True}
    if step.key == "design":
        d, markers = read("design", "rig_design.json"), read("design", "markers.json")
        good = d["markers_in_view"] and d["swing_in_view"] and d["min_marker_gap_mm"] > 0
        good = good and d["dot_area_px"] > d["tracker_min_area_px"]
        good = good and (f / "design" / "rig_design.png").stat().st_size > 0 and len(markers) == len(d["markers_m"])
        figures = {k: d[k] for k in ("beam_thickness_mm", "camera_distance_mm", "pixel_size_mm")}
        return {"good": bool(good), **figures, "tip_sag_mm": d["tip_sag_horizontal_mm"]}
    if step.key == "check":
        d = read("check.json")
        passed = {name: c["passed"] for name, c in d["checks"].items()}
        trip_ms = d["checks"]["watchdog"]["trip_ms"]
        return {"good": bool(d["passed"]), **passed, "watchdog_trip_ms": trip_ms, "round_trip_ms": d["round_trip_ms"]}
    if step.key == "calibrate":
        d = read("calibration.report.json")
        figures = {"residual_px": d["residual_px"], "tip_error_mm": 1e3 * d["tip_error_m"], "px_per_m": d["px_per_m"]}
        return {"good": bool(d["passed"]), **figures}
    if step.key == "babble":
        d = read("babble", "summary.json")
        good = d["n_trials"] >= 1 and d["gaps"] == 0 and d["peak_correlation"] > 0.5
        good = bool(good and (f / "babble" / "rig_dataset.npz").is_file())
        figures = {"n_trials": d["n_trials"], "clock_offset_ms": 1e3 * d["clock_offset_s"]}
        figures |= {"peak_correlation": d["peak_correlation"], "valid_fraction": d["grid_valid_fraction"]}
        return {"good": good, **figures}
    if step.key == "identify":
        v = read("model.json")["metadata"]["metrics"]["validation"]
        tip, hold = v.get(f"tip_rmse_m@{IDENTIFY_HORIZON_S:g}s"), v.get(f"hold_tip_rmse_m@{IDENTIFY_HORIZON_S:g}s")
        good = tip is not None and hold is not None and math.isfinite(tip) and tip < hold
        mm = {k: 1e3 * x if x is not None else math.nan for k, x in (("tip_rmse_mm", tip), ("hold_tip_rmse_mm", hold))}
        return {"good": bool(good), **mm}
    if step.key == "control":
        d = read("control", "summary.json")
        truth = d.get("truth") or {}
        good = bool(d["stop_reason"] is None and (bool(truth.get("success")) if truth else True))
        run = {"stop_reason": d["stop_reason"], "samples": d["samples"], "late_commands": d.get("late_commands", 0)}
        figures = {k: truth.get(k, math.nan) for k in ("swing_up_time_s", "upright_std_rad")}
        return {"good": good, **run, "success": bool(truth.get("success", False)), **figures}
    raise ValueError(f"unknown build step {step.key!r}")


def design_figures(params: RodParams, design: Optional[RigDesign] = None) -> dict[str, Any]:
    """:meth:`RigDesign.to_dict` with ``tip_sag_horizontal_mm`` (PRB statics) and ``tracker_min_area_px``."""
    from softpend.vision.tracker import TipTracker

    figures = (design if design is not None else rig_design(params)).to_dict()
    figures["tip_sag_horizontal_mm"] = 1e3 * rod_design(params).tip_sag_horizontal_m
    figures["tracker_min_area_px"] = TipTracker().min_area_px
    return figures
