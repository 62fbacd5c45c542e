"""Commissioning an unknown rod on the twin (softpend rig commission): every stage end to end on a tiny budget,
resumed after an interruption, the twin's truth never opened by the commissioning process; unknown rods; the
uncertainty draws; refusals."""

from __future__ import annotations

import builtins
import io
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from softpend.cli import main
from softpend.plant import RodParams
from softpend.study import commission as commission_module
from softpend.study import twin_side
from softpend.study.commission import CommissionConfig, commission, identified_values, verification_seeds
from softpend.study.twin_side import TwinTruth
from softpend.study.unknown_rod import SPREAD_FACTOR, UNKNOWN_FIELDS, UnknownRod, draw_unknown_rod

#: The learners on the smallest budgets that train them: an episode or trial of 1 s, one evaluation start.
TINY_LEARNERS = {
    "dqn": {"episodes": 2, "episode_s": 1.0, "learning_starts": 50, "eval_seeds": [1000], "stop.confirm_seeds": []},
    "mbpo": {"episodes": 3, "episode_s": 1.0, "initial_random_episodes": 2, "eval_seeds": [1000]},
    "pilco": {"n_policy_trials": 1, "horizon_s": 1.0, "prediction_s": None, "optimiser.iterations": 5},
}
for _settings in TINY_LEARNERS.values():
    _settings.update({"eval_duration_s": 1.0} | ({"stop.confirm_seeds": []} if "episodes" in _settings else {}))
TINY_LEARNERS["pilco"].update({"gp.max_points": 20, "compiled": False, "eval_seeds": [1000]})
#: Every stage, each on the smallest budget that runs it.
TINY = CommissionConfig(
    learners=TINY_LEARNERS,
    excite_s=1.5,
    trial_length_s=1.0,
    window_s=0.2,
    max_windows=6,
    max_iterations=2,
    check_draws=1,
    check_starts=1,
    check_duration_s=1.0,
    verify_starts=1,
    verify_duration_s=1.0,
    train_attempts=1,
)
#: A hand-made unknown rod.
TRUTH = UnknownRod(
    RodParams(
        hub_inertia_kgm2=2.4e-4,
        hub_friction_nms_per_rad=2.5e-3,
        youngs_modulus_pa=60e6,
        joint_damping_nms_per_rad=2.4e-4,
        tip_mass_kg=0.012,
    ),
    torque_gain=1.15,
)


def _refuse_opening(monkeypatch, *forbidden: Path) -> list[str]:
    """Make this process refuse to open anything at or under ``forbidden`` (a spawned child is not affected);
    the refused paths."""
    roots = [Path(p).resolve() for p in forbidden]
    refused: list[str] = []

    def guard(file) -> None:
        if isinstance(file, int):
            return
        path = Path(os.fsdecode(file)).resolve()
        if any(path == root or root in path.parents for root in roots):
            refused.append(str(path))
            raise PermissionError(f"the commissioning process may not open {path}")

    real_open, real_os_open = builtins.open, os.open

    def checked_open(file, *args, **kwargs):
        guard(file)
        return real_open(file, *args, **kwargs)

    def checked_os_open(path, *args, **kwargs):
        guard(path)
        return real_os_open(path, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", checked_open)
    monkeypatch.setattr(io, "open", checked_open)
    monkeypatch.setattr(os, "open", checked_os_open)
    return refused


def test_a_tiny_unknown_rod_is_commissioned_resumed_after_an_interruption_and_its_truth_never_read(
    tmp_path, monkeypatch
):
    rod_file = tmp_path / "secret" / "rod.json"
    rod_file.parent.mkdir()
    rod_file.write_text(json.dumps(TRUTH.to_dict()))
    out = tmp_path / "commission"
    refused = _refuse_opening(monkeypatch, rod_file, out / "twin")
    for name in ("draw_unknown_rod", "_resolve"):  # nor is the truth drawn or resolved in this process
        monkeypatch.setattr(twin_side, name, lambda *a, **k: pytest.fail("the truth was resolved on the host"))
    jobs: list[str] = []
    spawn = twin_side.on_twin_side

    def counted(twin, function, *args):
        jobs.append(function.__name__)
        return spawn(twin, function, *args)

    monkeypatch.setattr(commission_module, "on_twin_side", counted)
    truth = TwinTruth(rod_file=str(rod_file))

    identify = commission_module._STAGE_WORK["identify"]

    def interrupted(run):
        raise KeyboardInterrupt

    monkeypatch.setitem(commission_module._STAGE_WORK, "identify", interrupted)
    with pytest.raises(KeyboardInterrupt):
        commission(out, truth, TINY)
    excite = out / "excite" / "excite.json"
    assert excite.is_file() and not (out / "identify" / "identification.json").exists()
    first = excite.read_bytes()

    # interrupted again in the training, after DQN's run: that run is kept, the others trained
    monkeypatch.setitem(commission_module._STAGE_WORK, "identify", identify)
    train_one, trained = commission_module._train_one, []

    def train_until_mbpo(learner, *args):
        trained.append(learner)
        if learner == "mbpo" and trained.count("mbpo") == 1:
            raise KeyboardInterrupt
        return train_one(learner, *args)

    monkeypatch.setattr(commission_module, "_train_one", train_until_mbpo)
    with pytest.raises(KeyboardInterrupt):
        commission(out, truth, TINY)
    dqn_log = next((out / "train").glob("dqn-*-seed0")) / "log.json"
    dqn_logged = dqn_log.read_bytes()
    told: list[tuple[str, bool]] = []
    report = commission(out, truth, TINY, on_stage=lambda stage, ran, output: told.append((stage, ran)))
    assert told == [("excite", False), ("identify", False), ("design", False)] + [
        (stage, True) for stage in ("train", "verify", "report")
    ]
    assert trained == ["dqn", "mbpo", "dqn", "mbpo", "pilco"] and dqn_log.read_bytes() == dqn_logged
    assert excite.read_bytes() == first
    assert jobs == ["excite_on_twin", "verify_on_twin", "truth_errors"]
    assert refused == []

    # the host's files hold no trace of the truth: no rig settings in the motor log, the guess in the dataset
    motor_header = (out / "excite" / "motor_log.csv").read_text().splitlines()[0]
    assert "rod" not in motor_header and "youngs" not in motor_header
    from softpend.sysid.dataset import load_dataset

    assert load_dataset(out / "excite" / "rig_dataset.npz").params == RodParams()

    assert TINY.session_s <= report["plant_s"]["excite"] <= TINY.session_s + 0.3  # and the STOP after it
    excited = json.loads((out / "excite" / "excite.json").read_text())
    assert excited["program"] == "noise" and 0.0 < excited["peak_torque_nm"] <= RodParams().torque_limit_nm
    assert report["plant_s"]["identify"] == report["plant_s"]["design"] == report["plant_s"]["train"] == 0.0
    assert set(report["identified"]) == set(UNKNOWN_FIELDS) | {"torque_gain"}
    gain = report["identified"]["torque_gain"]
    assert gain["truth"] == pytest.approx(TRUTH.torque_gain)
    assert gain["relative_error"] == pytest.approx(gain["estimate"] / TRUTH.torque_gain - 1)
    assert all(math.isfinite(v["std"]) for v in report["identified"].values())
    classes = report["classes"]
    assert list(classes) == ["swingup", "dqn", "mbpo", "pilco"]
    swingup = classes["swingup"]
    assert [r["condition"] for r in swingup["verification"]] == ["nominal", "harsh"]
    # the controller designed on the default rod, from the same fresh starts of the same twin, beside it
    assert [(r["condition"], r["controller"]) for r in swingup["default_rod_verification"]] == [
        ("nominal", "energy swing-up + LQR (observations), default rod"),
        ("harsh", "energy swing-up + LQR (observations), default rod"),
    ]
    assert {r["controller"] for r in swingup["verification"]} == {commission_module.CONTROLLER}
    for name, entry in classes.items():
        rows = entry["verification"] + (entry["default_rod_verification"] or [])
        assert [r["condition"] for r in entry["verification"]] == ["nominal", "harsh"], name
        for row in rows:
            assert row["starts"] == 1 and 0 <= row["success_low"] <= row["success_rate"] <= row["success_high"] <= 1
        # plant seconds: the excitation and this class's verification, two twin starts of 1 s (and the STOP)
        assert report["plant_s"]["excite"] + 2.0 <= entry["plant_s"] <= report["plant_s"]["excite"] + 2.5, name
    assert not set(report["seeds"]["verification"]) & set(report["seeds"]["commissioning"])

    # the learners trained on the identified rod, each episode or trial on a rod drawn from its uncertainty
    from softpend.control.identified import identified_uncertainty
    from softpend.pilco.loop import PilcoResult
    from softpend.rl.config import load_config

    identification = json.loads((out / "identify" / "identification.json").read_text())
    uncertainty = identified_uncertainty(commission_module._greybox_result(identification["greybox"]), 2.0)
    assert report["rod_uncertainty"] == uncertainty.to_dict()
    for name, training in ((n, classes[n]["training"]) for n in ("dqn", "mbpo", "pilco")):
        folder = out / training["folder"]
        saved = PilcoResult.load(folder).config if name == "pilco" else load_config(folder / "config.json")
        assert saved.task.rod.to_dict() == identification["model_rod"] and saved.rod_uncertainty == uncertainty
        assert training["simulator_s"] == classes[name]["simulator_s"] > 0
    assert classes["dqn"]["training"]["episodes"] == 2 and classes["pilco"]["training"]["trials"] == 2
    assert classes["dqn"]["default_rod_verification"] is None  # no default-rod run given

    # done: a third call redoes nothing and reads the same report
    told.clear()
    assert commission(out, truth, TINY, on_stage=lambda stage, ran, output: told.append((stage, ran))) == report
    assert [ran for _, ran in told] == [False] * 6


class _FakeRun:
    """A commissioning folder's stage outputs, read by a stage under test."""

    def __init__(self, config: CommissionConfig, outputs: dict, out: Path) -> None:
        self.config, self.outputs_by_stage, self.out = config, outputs, out

    def read(self, stage: str) -> dict:
        return self.outputs_by_stage[stage]


def test_a_learner_is_trained_again_with_the_next_seed_until_a_run_balances(monkeypatch, tmp_path):
    from softpend.control import identified

    monkeypatch.setattr(commission_module, "_greybox_result", lambda data: data)
    monkeypatch.setattr(identified, "identified_uncertainty", lambda result, scale: identified.RodUncertainty((), 2.0))
    monkeypatch.setattr(commission_module, "learner_config", lambda learner, model, unc, settings, seed: seed)
    balances = {("dqn", 5): False, ("dqn", 6): True, ("pilco", 5): False, ("pilco", 6): False, ("pilco", 7): False}
    calls = []

    def train_one(learner, seed_in_config, seed, episodes, root):
        assert seed_in_config == seed
        calls.append((learner, seed))
        return {"folder": f"{learner}-{seed}", "simulator_s": 10.0, "wall_s": 1.0, "balanced": balances[learner, seed]}

    monkeypatch.setattr(commission_module, "_train_one", train_one)
    config = CommissionConfig(controllers=("dqn", "pilco"), seed=5, train_attempts=3)
    run = _FakeRun(config, {"identify": {"model_rod": RodParams().to_dict(), "greybox": {}}}, tmp_path)
    runs = commission_module._train(run)["runs"]
    assert calls == [("dqn", 5), ("dqn", 6), ("pilco", 5), ("pilco", 6), ("pilco", 7)]
    assert runs["dqn"]["folder"] == "dqn-6" and runs["dqn"]["balanced"] and runs["dqn"]["attempts"] == 2
    assert runs["dqn"]["simulator_s"] == 20.0 and runs["dqn"]["seed"] == 6
    assert runs["pilco"]["folder"] == "pilco-7" and not runs["pilco"]["balanced"] and runs["pilco"]["attempts"] == 3
    assert runs["pilco"]["simulator_s"] == 30.0


def test_a_parameter_held_at_the_guess_is_fitted_again_with_the_others_from_their_fit(monkeypatch, tmp_path):
    from types import SimpleNamespace

    from softpend.sysid import dataset, greybox

    partial = RodParams(youngs_modulus_pa=70e6)
    full = RodParams(youngs_modulus_pa=71e6, hub_inertia_kgm2=3e-4)
    fits = []

    def identify(data, settings, initial_params):
        fits.append((settings.parameters, initial_params))
        if "hub_inertia_kgm2" in settings.parameters and initial_params == RodParams():
            raise greybox.NotIdentifiable("hub_inertia_kgm2", "not at the guess")
        params = full if "hub_inertia_kgm2" in settings.parameters else partial
        return SimpleNamespace(params=params, estimates={}, std={}, to_dict=lambda: {"rod": params.to_dict()})

    monkeypatch.setattr(greybox, "identify", identify)
    monkeypatch.setattr(dataset, "load_dataset", lambda path: None)
    monkeypatch.setattr(commission_module, "identified_values", lambda *a: {})
    out = commission_module._identify(_FakeRun(CommissionConfig(), {}, tmp_path))
    every = commission_module.IDENTIFIED_PARAMETERS
    assert [f[0] for f in fits] == [every, tuple(p for p in every if p != "hub_inertia_kgm2"), every]
    assert fits[2][1] == partial and out["model_rod"] == full.to_dict() and out["not_identified"] == []


def test_the_uncertainty_draws_are_as_wide_as_the_identification_is_uncertain():
    from softpend.control.identified import uncertainty_draws
    from softpend.sysid.greybox import GreyBoxResult

    guess = RodParams()
    estimates = {"hub_inertia_kgm2": 3e-4, "tip_mass_kg": 0.02, "torque_gain": 1.3}
    std = {"hub_inertia_kgm2": 3e-5, "tip_mass_kg": 0.0, "torque_gain": 0.5}
    result = GreyBoxResult(
        params=guess.replace(hub_inertia_kgm2=3e-4, tip_mass_kg=0.02),
        initial_params=guess,
        estimates=estimates,
        std=std,
        residual_rms_rad=0.0,
        n_windows=1,
        window_steps=2,
        n_residuals=1,
        n_variables=1,
        identify_s=0.0,
        nfev=1,
        njev=1,
        status=1,
        message="",
    )
    draws = uncertainty_draws(result, 200, seed=5, scale=2.0)
    inertia = np.array([d.hub_inertia_kgm2 for d in draws])
    # a 10 % standard deviation, two of them wide on the log scale: within exp(+-0.2), and filling it
    assert np.all(np.abs(np.log(inertia / 3e-4)) <= 0.2 + 1e-12)
    assert np.abs(np.log(inertia / 3e-4)).max() > 0.18
    assert all(d.tip_mass_kg == 0.02 for d in draws)  # no uncertainty: no spread
    assert all(d.youngs_modulus_pa == guess.youngs_modulus_pa for d in draws)  # not estimated: held
    assert draws == uncertainty_draws(result, 200, seed=5, scale=2.0)
    wider = np.array([d.hub_inertia_kgm2 for d in uncertainty_draws(result, 200, seed=5, scale=4.0)])
    assert np.abs(np.log(wider / 3e-4)).max() > 0.3


def test_a_torque_gain_is_the_rod_with_its_masses_stiffness_and_damping_divided():
    from softpend.plant import PRBPlant

    rod = TRUTH.rod.replace(torque_limit_nm=10.0)
    geared, effective = (
        PRBPlant(r, dt_s=0.01, substeps=2) for r in (rod, UnknownRod(rod, TRUTH.torque_gain).effective_rod())
    )
    for plant in (geared, effective):
        plant.reset(*plant.hanging_state())
    torque = 0.05 * np.sin(np.arange(150) * 0.07)
    for u in torque:
        a, b = geared.step(TRUTH.torque_gain * u), effective.step(u)
        assert a.phi_rad == pytest.approx(b.phi_rad, abs=1e-4) and a.ex_m == pytest.approx(b.ex_m, abs=1e-5)

    values = identified_values(
        {**{n: getattr(TRUTH.effective_rod(), n) for n in UNKNOWN_FIELDS}, "mass_kg": TRUTH.effective_rod().mass_kg},
        {**{n: 0.1 * getattr(TRUTH.effective_rod(), n) for n in UNKNOWN_FIELDS}, "mass_kg": 0.0},
        RodParams().mass_kg,
    )
    assert values["torque_gain"]["estimate"] == pytest.approx(TRUTH.torque_gain)
    for name in UNKNOWN_FIELDS:
        assert values[name]["estimate"] == pytest.approx(getattr(TRUTH.rod, name))
        assert values[name]["relative_std"] == pytest.approx(0.1)


def test_unknown_rods_lie_within_a_factor_two_are_balanced_and_repeat_with_their_seed():
    rod, draws = draw_unknown_rod(7, starts=2, needed=2, duration_s=6.0)
    assert draws >= 1
    default = RodParams()
    for name in UNKNOWN_FIELDS:
        assert 1 / SPREAD_FACTOR <= getattr(rod.rod, name) / getattr(default, name) <= SPREAD_FACTOR
    assert 1 / SPREAD_FACTOR <= rod.torque_gain <= SPREAD_FACTOR
    assert draw_unknown_rod(7, starts=2, needed=2, duration_s=6.0) == (rod, draws)
    assert UnknownRod.from_dict(rod.to_dict()) == rod


def test_verification_seeds_are_fresh():
    config = CommissionConfig(check_draws=3, check_starts=4, seed=12)
    seeds = verification_seeds(config)
    assert len(seeds) == 10 and not set(seeds) & set(config.commissioning_seeds())


def test_bad_input_is_refused_by_name(tmp_path, capsys):
    rod_file = tmp_path / "rod.json"
    rod_file.write_text(json.dumps(TRUTH.to_dict()))
    out = str(tmp_path / "out")
    cases = [
        (["--twin-rod", str(tmp_path / "missing.json")], "--twin-rod"),
        (["--twin-rod", str(tmp_path)], "--twin-rod"),
        (["--twin-rod", str(rod_file), "--verify-starts", "0"], "--verify-starts"),
        (["--twin-rod", str(rod_file), "--train-attempts", "0"], "--train-attempts"),
        (["--twin-rod", str(rod_file), "--seed", "-1"], "--seed"),
        (["--twin-seed", "-3"], "--twin-seed"),
        (["--twin-rod", str(rod_file), "--excite-s", "0.1"], "excite_s"),
        (["--twin-rod", str(rod_file), "--excite-s", "nan"], "--excite-s"),
    ]
    for extra, name in cases:
        assert main(["rig", "commission", "--out", out, *extra]) == 2, extra
        err = capsys.readouterr().err.strip()
        assert err.startswith("softpend rig") and "error:" in err and name in err and "\n" not in err, err
    assert not os.path.exists(out)
    assert main(["rig", "commission", "--out", out, "--twin-rod", str(rod_file), "--twin-seed", "1"]) == 2
    assert "--twin-seed" in capsys.readouterr().err  # exactly one of the two

    # another commissioning's folder
    (tmp_path / "earlier").mkdir()
    from softpend.io.outputs import Outputs

    outputs = Outputs()
    outputs.folder(tmp_path / "earlier", ("commission.json",))
    outputs.write_json(tmp_path / "earlier" / "commission.json", {"twin": {}, "config": {}})
    with pytest.raises(ValueError, match="other settings"):
        commission(tmp_path / "earlier", TwinTruth(rod_file=str(rod_file)), TINY)
    for changes, name in (
        ({"program": "chirp"}, "program"),
        ({"noise_std_fraction": 1.5}, "noise_std_fraction"),
        ({"controllers": ("swingup", "ppo")}, "controllers"),
        ({"controllers": ()}, "controllers"),
        ({"learners": {"ppo": {}}}, "learners"),
        ({"learners": {"dqn": {"episodes": 0}}}, "learners.dqn.episodes"),
        ({"default_rod_runs": {"dqn": 3}}, "default_rod_runs"),
        ({"train_attempts": 0}, "train_attempts"),
        ({"train_attempts": 101}, "train_attempts"),
    ):
        with pytest.raises(ValueError, match=name):
            CommissionConfig(**changes)
    with pytest.raises(ValueError, match="exactly one"):
        TwinTruth()
    with pytest.raises(ValueError, match="rod file .*torque_gain"):
        UnknownRod.from_dict({"rod_params": RodParams().to_dict(), "torque_gain": -1.0}, "rod file x")


def test_the_commission_bench_figures_are_the_worst_rod_and_count_a_held_parameter_as_unbounded_error():
    """The bench's figures from two hand-made reports: the worst rod's successes (out of 10), the largest error,
    infinite when a parameter was held at the guess, and the plant seconds."""
    import math

    from softpend.study.bench.control import commission_figures

    def report(nominal, harsh, errors, parameters, excite_s, dqn_nominal=10):
        def entry(nominal, harsh, plant_s):
            return {
                "verification": [
                    {"condition": "nominal", "successes": nominal, "starts": 10},
                    {"condition": "harsh", "successes": harsh, "starts": 10},
                ],
                "plant_s": plant_s,
            }

        return {
            "classes": {"swingup": entry(nominal, harsh, excite_s - 1), "dqn": entry(dqn_nominal, 10, excite_s + 10)},
            "identified": {name: {"relative_error": e} for name, e in errors.items()},
            "identification_fit": {"parameters": parameters},
            "plant_s": {"excite": excite_s},
        }

    # as a real report: the rod's mass stands for the torque gain; the camera's delay has no truth
    both = ["hub_inertia_kgm2", "tip_mass_kg", "mass_kg", "camera_delay_s"]
    first = report(10, 9, {"hub_inertia_kgm2": 0.01, "tip_mass_kg": -0.04, "torque_gain": 0.002}, both, 12.0)
    second = report(9, 7, {"hub_inertia_kgm2": 0.02, "tip_mass_kg": 0.0, "torque_gain": -0.03}, both, 14.0)
    figures = commission_figures([first, second])
    assert figures["commission_success_min"] == 9.0 and figures["commission_harsh_success_min"] == 7.0
    assert figures["commission_max_param_error_pct"] == pytest.approx(4.0)
    assert figures["commission_identify_s"] == 14.0 and figures["commission_plant_s_swingup_lqr"] == 12.0
    assert figures["commission_plant_s_dqn"] == 23.0
    # the worst class on the worst rod
    worse = report(10, 9, {"torque_gain": 0.0}, both, 12.0, dqn_nominal=4)
    assert commission_figures([first, worse])["commission_success_min"] == 4.0
    held = report(10, 10, {"hub_inertia_kgm2": 0.0, "torque_gain": 0.0}, both, 12.0)  # tip mass held at the guess
    assert math.isinf(commission_figures([first, held])["commission_max_param_error_pct"])
