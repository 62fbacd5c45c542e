"""The rig's design follows the rod's parameters, its part choices agree with the device program and the closed-loop
chapter, and the 'Build the rig' procedure runs end to end on the digital twin (a dry run of exactly the commands
the chapter prints)."""

from __future__ import annotations

import ast
import json
import math
import subprocess
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from softpend.hardware.rig_design import V5_CARTRIDGES, rig_design
from softpend.io.overrides import apply_overrides, parse_assignment
from softpend.plant import RodParams
from softpend.study.build_rig import (
    TESTED_CAMERAS,
    TWIN,
    BuildBudget,
    BuildTarget,
    QuantisedHub,
    build_steps,
    check_step,
    choose_cartridge,
    motor_rows,
)
from softpend.study.figures.rig_design import draw_rig_design
from softpend.vision.camera import DEFAULT_MARKERS_M

#: A dry run's budget: a few seconds per real-time run.
QUICK_BUDGET = BuildBudget(babble_s=8.0, trial_length_s=2.0, max_epochs=5, control_s=4.0)

REPO = Path(__file__).resolve().parents[1]


def _labels(params: RodParams) -> list[str]:
    fig = draw_rig_design(rig_design(params))
    try:
        return [t.get_text() for ax in fig.axes for t in ax.texts if t.get_gid() == "dimension"]
    finally:
        plt.close(fig)


def test_the_drawing_changes_with_a_set_override_of_the_rod_length():
    default = RodParams()
    longer = apply_overrides(default, [parse_assignment("length_m=0.4")])
    assert "L = 300 mm" in _labels(default) and "L = 400 mm" not in _labels(default)
    assert "L = 400 mm" in _labels(longer)
    a, b = rig_design(default), rig_design(longer)
    assert b.beam_length_m - a.beam_length_m == pytest.approx(0.1)
    # the longer rod pushes the markers and the field of view out, keeping the markers clear and in view
    assert np.array_equal(a.markers_m, DEFAULT_MARKERS_M) and np.all(abs(b.markers_m) > abs(a.markers_m))
    for design in (a, b):
        assert design.min_marker_gap_m > 0 and design.markers_in_view() and design.swing_in_view()
    assert b.camera_model.px_per_m < a.camera_model.px_per_m


def test_the_beam_section_keeps_the_rods_flexural_rigidity():
    params = RodParams()
    assert rig_design(params).beam_thickness_m == pytest.approx(params.depth_m)
    for modulus in (10e6, 26e6, 100e6):
        d = rig_design(params, print_modulus_pa=modulus)
        assert modulus * d.beam_width_m * d.beam_thickness_m**3 / 12 == pytest.approx(params.bending_stiffness_nm2)
    assert rig_design(params, print_modulus_pa=10e6).beam_thickness_m > params.depth_m
    with pytest.raises(ValueError, match="bending stiffness"):
        rig_design(params.replace(stiffness_scale=0.0))
    with pytest.raises(ValueError, match="print_modulus_pa"):
        rig_design(params, print_modulus_pa=-1.0)


def _firmware_constants() -> dict:
    tree = ast.parse((REPO / "firmware" / "vex_v5_motor.py").read_text())
    values = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            try:
                values[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                pass
    return values, (REPO / "firmware" / "vex_v5_motor.py").read_text()


def test_the_chosen_cartridge_is_the_one_the_device_program_drives():
    rows = motor_rows(peak_hub_rate_rad_s=19.5, torque_nm=RodParams().torque_limit_nm)
    chosen = choose_cartridge(rows)
    assert chosen.name.startswith("green")
    assert not rows[0]["qualifies"]  # the 36:1 cartridge is slower than the swing-up's hub
    values, text = _firmware_constants()
    assert values["STALL_TORQUE_NM"] == chosen.stall_torque_nm
    assert values["TORQUE_LIMIT_NM"] == RodParams().torque_limit_nm
    assert "RATIO_18_1" in text and "18:1" in chosen.name
    with pytest.raises(ValueError, match="no cartridge"):
        choose_cartridge(motor_rows(peak_hub_rate_rad_s=100.0, torque_nm=0.06))
    assert len(V5_CARTRIDGES) == 3


def test_tested_cameras_are_the_closed_loop_chapters_conditions():
    source = (REPO / "notebooks" / "rig_closed_loop.md").read_text()
    cell = source.split(":tags: [parameters]", 1)[1].split("```", 1)[0]
    values = {}
    for node in ast.parse(cell).body:
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name):
            try:
                values[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                pass
    assert TESTED_CAMERAS["nominal"] == (values["nominal_fps"], values["nominal_camera_latency_ms"] / 1e3)
    assert TESTED_CAMERAS["harsh"] == (values["harsh_fps"], values["harsh_camera_latency_ms"] / 1e3)


def test_quantised_hub_rounds_the_hub_angle_to_ticks_from_hanging():
    from softpend.plant import Observation

    seen = []
    controller = QuantisedHub(lambda obs, q, q_dot, t: seen.append((obs.phi_rad, q[0])) or 0.0, counts_per_rev=4)
    obs = Observation(*([0.0] * 10))._replace(phi_rad=math.pi - 1.0)
    controller(obs, np.array([math.pi - 1.0, 0.1]), np.zeros(2), 0.0)
    phi, q0 = seen[0]
    assert q0 == pytest.approx(math.pi - math.pi / 2)
    assert phi == pytest.approx(math.pi / 2)


def test_the_rig_target_names_port_and_camera():
    rig = BuildTarget(twin=False, port="/dev/ttyACM1", camera="0")
    steps = {s.key: s for s in build_steps("build", rig)}
    assert "--port" in steps["check"].argv and "--camera" not in steps["check"].argv
    assert "--camera" in steps["calibrate"].argv and "--port" not in steps["calibrate"].argv
    assert "--calibration" in steps["control"].argv and "--twin" not in steps["control"].argv
    assert all(
        "--twin" in s.argv for s in build_steps("build", TWIN) if s.key in ("check", "calibrate", "babble", "control")
    )


def _run(argv: tuple[str, ...], cwd: Path) -> int:
    """One command of the procedure: ``softpend ...`` in this process, ``python -m ...`` as a child."""
    if argv[0] == "softpend":
        from softpend.cli import main

        return main(list(argv[1:]))
    assert argv[0] == "python"
    return subprocess.run([sys.executable, *argv[1:]], cwd=cwd, capture_output=True, text=True, timeout=60).returncode


def test_the_chapters_procedure_runs_on_the_twin(tmp_path, monkeypatch):
    """Every command of the chapter, in order, on the twin with the dry run's budget; each exits 0 and leaves
    outputs that look right."""
    monkeypatch.chdir(tmp_path)
    folder = Path("build")
    results = {}
    for step in build_steps(folder, TWIN, QUICK_BUDGET):
        assert _run(step.argv, tmp_path) == 0, step.command
        results[step.key] = check_step(step, folder)
    assert list(results) == ["design", "firmware", "check", "calibrate", "babble", "identify", "control"]
    for key in ("design", "check", "calibrate", "babble", "control"):
        assert results[key]["good"], (key, results[key])
    assert results["design"]["beam_thickness_mm"] == pytest.approx(1e3 * RodParams().depth_m)
    assert abs(results["check"]["watchdog_trip_ms"] - 100) <= 10  # one state period (simulated time)
    assert results["calibrate"]["residual_px"] < 0.5
    assert results["babble"]["n_trials"] >= 1
    # a five-epoch model need not beat the yardstick; its figures must exist
    assert math.isfinite(results["identify"]["tip_rmse_mm"]) and math.isfinite(results["identify"]["hold_tip_rmse_mm"])
    # the twin runs in simulated time: the closed loop completes, every state processed, the rod swung up and held
    summary = json.loads((tmp_path / folder / "control" / "summary.json").read_text())
    assert results["control"]["stop_reason"] is None and summary["truth"]["success"], summary["truth"]
    assert summary["samples"] == round(QUICK_BUDGET.control_s / 0.01) + 1 and summary["dropped_states"] == 0
    assert summary["camera"]["frames_tracked"] > 0
    assert 0 < summary["truth"]["peak_torque_nm"] <= RodParams().torque_limit_nm + 1e-6


def test_the_commands_refuse_bad_input_in_one_line(tmp_path, capsys):
    from softpend.cli import main

    assert main(["rig", "design", "--out", str(tmp_path / "d"), "--set", "length_m=-1"]) == 2
    assert main(["rig", "design", "--out", str(tmp_path / "d"), "--set", "no_such_field=1"]) == 2
    assert main(["rig", "babble", "--port", "/dev/null", "--out", str(tmp_path / "b")]) == 2  # no camera
    assert main(["rig", "babble", "--twin", "--duration", "3", "--out", str(tmp_path / "b")]) == 2  # too short
    assert main(["rig", "calibrate", "--twin", "--markers", "[[0, 0]]", "--out", str(tmp_path / "c.json")]) == 2
    assert main(["rig", "check", "--twin", "--push-fraction", "2"]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 6 and all(line.startswith("softpend rig: error:") for line in errors)
    assert not (tmp_path / "b").exists()


def test_the_power_on_check_fails_a_device_with_a_slow_watchdog():
    """A device whose watchdog is slower than the host expects fails the handshake check (and its watchdog trips on
    its own, slower time); the report says which check failed."""
    from softpend.commands.rig_build import rig_check
    from softpend.hardware.emulator import RigConfig, SimRig
    from softpend.task import Task

    task = Task(start_noise_rad=0.0)
    report = rig_check(
        "twin", task, rest_s=0.3, push_fraction=0.2, serial=SimRig(RigConfig(task=task, watchdog_ms=300)).connect()
    )
    assert not report["passed"]
    assert not report["checks"]["handshake"]["passed"]
    assert report["checks"]["rest"]["passed"] and report["checks"]["direction"]["passed"]
    assert abs(report["checks"]["watchdog"]["trip_ms"] - 300) <= 10  # one state period (simulated time)


def test_the_book_and_the_design_command_take_the_rod_through_set(tmp_path):
    """``softpend book --set rod_overrides=...`` is a parameter of the chapter, and ``softpend rig design --set``
    redraws the rig: both through softpend.io.overrides."""
    import json as json_module

    import nbformat

    from softpend.cli import main
    from softpend.study import book

    name, value = parse_assignment('rod_overrides={"length_m": 0.4}')
    path = tmp_path / "build_the_rig.ipynb"
    nbformat.write(book.read_notebook(REPO / "notebooks" / "build_the_rig.md"), str(path))
    book.check_parameters(path, "build_the_rig", {name: value})
    assert apply_overrides(RodParams(), value).length_m == 0.4
    assert main(["rig", "design", "--out", str(tmp_path / "d"), "--set", "length_m=0.4"]) == 0
    figures = json_module.loads((tmp_path / "d" / "rig_design.json").read_text())
    assert figures["rod_length_mm"] == pytest.approx(400) and figures["beam_length_mm"] == pytest.approx(396)
    assert json_module.loads((tmp_path / "d" / "markers.json").read_text()) == figures["markers_m"]
