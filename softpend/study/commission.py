"""Commissioning an unknown rod on the twin, in resumable stages, each writing its output in one folder:

``excite`` (random torque, or a multisine, from hanging through the rig's own I/O, synchronised into a rig
dataset), ``identify`` (grey-box, from ``RodParams()``), ``design`` (energy swing-up + LQR on the observations of
the identified rod, checked in the simulator on rods drawn from the identification's uncertainty), ``train`` (DQN,
DQN-MBPO and PILCO from the book's settings in the simulator of the identified rod, each training episode or trial on
a rod drawn from the identification's uncertainty), ``verify`` (every commissioned class on the twin from fresh
hanging starts under each sensor condition, beside the same class for the default rod) and ``report``.  The twin's
truth stays on the twin's side (:mod:`softpend.study.twin_side`, a child process); only the report's relative
errors come from it.
"""

from __future__ import annotations

import dataclasses
import json
import math
from concurrent.futures import Executor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np

from softpend.checks import in_range, instance_of, int_at_least, one_of, positive, set_ints
from softpend.envs.randomised import RodUncertainty
from softpend.plant import RodParams
from softpend.study.twin_side import (
    CONDITIONS,
    TwinTruth,
    excite_on_twin,
    on_twin_side,
    truth_errors,
    twin_process,
    verify_on_twin,
)
from softpend.study.unknown_rod import UNKNOWN_FIELDS
from softpend.sysid.babble import PROGRAMS

#: The stages in order.
STAGES = ("excite", "identify", "design", "train", "verify", "report")
#: The learned controller classes, trained in the ``train`` stage.
LEARNERS = ("dqn", "mbpo", "pilco")
#: The controller classes commissioned (``swingup``: the energy swing-up + LQR on the observations).
CLASSES = ("swingup",) + LEARNERS
#: Each learner's changes to the book's settings (``episodes``: the training episodes of DQN and DQN-MBPO).
DEFAULT_LEARNERS: dict[str, dict[str, Any]] = {"dqn": {"episodes": 250}, "mbpo": {"episodes": 80}, "pilco": {}}
#: What the identification estimates: the rod fields and the rod's mass, which with the mass known stands for the
#: torque gain (a gain ``g`` is the rod with every mass, inertia, stiffness and damping over ``g``), and the camera's
#: delay within a sample left after the clock synchronisation (unmodelled, it biases the damping estimates).
IDENTIFIED_PARAMETERS: tuple[str, ...] = UNKNOWN_FIELDS + ("mass_kg", "camera_delay_s")
#: Length of the start-up wiggle before the excitation program (the clock synchronisation's reference) [s].
WIGGLE_S = 2.0
#: Rest after the program, so the last trial ends within the session [s].
REST_S = 0.5
#: Verification seeds start here (commissioning seeds lie below it).
VERIFY_SEED_OFFSET = 1_000_000_000
#: Names of the classes in the report's rows.
CLASS_NAMES = {"swingup": "energy swing-up + LQR (observations)", "dqn": "DQN", "mbpo": "DQN-MBPO", "pilco": "PILCO"}
#: Label of the commissioned swing-up + LQR.
CONTROLLER = f"{CLASS_NAMES['swingup']}, identified rod"
SETTINGS_FILE = "commission.json"


@dataclass(frozen=True)
class CommissionConfig:
    """Budgets of :func:`commission`: ``excite_s`` of the babbling ``program`` (``"noise"``: random torque of standard
    deviation ``noise_std_fraction`` of the torque limit, low-passed at ``band_high_hz``, clipped at the limit;
    ``"multisine"``: peak ``peak_fraction`` of the limit, up to ``band_high_hz``) cut into trials of
    ``trial_length_s``; the identification's windows and iterations; the
    design check's ``check_draws`` rods ``uncertainty_scale`` standard deviations wide, ``check_starts`` starts of
    ``check_duration_s`` each (the learners' training rods are drawn as wide); the ``controllers`` commissioned
    (of :data:`CLASSES`), ``learners``: each learner's changes to the book's settings (:data:`DEFAULT_LEARNERS`);
    ``default_rod_runs``: run folders of learners trained for the default rod, verified beside; ``train_attempts``:
    training runs per learner at most, seeds ``seed``, ``seed + 1``, ... until one balances on its own evaluation
    starts; ``verify_starts`` twin starts of ``verify_duration_s`` per condition; ``seed`` (also the first training
    seed)."""

    excite_s: float = 10.0
    program: str = "noise"
    noise_std_fraction: float = 0.5
    peak_fraction: float = 0.8
    band_high_hz: float = 6.0
    trial_length_s: float = 3.0
    window_s: float = 0.3
    max_windows: int = 60
    max_iterations: int = 25
    check_draws: int = 8
    check_starts: int = 2
    check_duration_s: float = 10.0
    uncertainty_scale: float = 2.0
    verify_starts: int = 10
    verify_duration_s: float = 10.0
    seed: int = 0
    controllers: tuple[str, ...] = CLASSES
    learners: Mapping[str, Mapping[str, Any]] = field(default_factory=lambda: dict(DEFAULT_LEARNERS))
    default_rod_runs: Mapping[str, str] = field(default_factory=dict)
    train_attempts: int = 3

    def __post_init__(self) -> None:
        controllers = tuple(self.controllers) if isinstance(self.controllers, (list, tuple)) else ()
        if not controllers or len(set(controllers)) != len(controllers) or not set(controllers) <= set(CLASSES):
            raise ValueError(f"controllers must be distinct names of {list(CLASSES)}, got {self.controllers!r}")
        object.__setattr__(self, "controllers", tuple(c for c in CLASSES if c in controllers))
        for name, allowed in (("learners", dict), ("default_rod_runs", str)):
            value = getattr(self, name)
            if not isinstance(value, Mapping) or not set(value) <= set(LEARNERS):
                raise ValueError(f"{name} must map names of {list(LEARNERS)}, got {value!r}")
            if not all(isinstance(v, allowed) for v in value.values()):
                raise ValueError(f"{name}: every value must be a {allowed.__name__}, got {value!r}")
        learners = {k: {**v, **self.learners.get(k, {})} for k, v in DEFAULT_LEARNERS.items()}
        for name in ("dqn", "mbpo"):
            learners[name]["episodes"] = int_at_least(f"learners.{name}.episodes", learners[name]["episodes"], 1)
        object.__setattr__(self, "learners", learners)
        object.__setattr__(self, "default_rod_runs", dict(self.default_rod_runs))
        for name in "excite_s trial_length_s window_s check_duration_s uncertainty_scale verify_duration_s".split():
            positive(name, getattr(self, name))
        for name, low, high in (("peak_fraction", 1e-3, 1), ("noise_std_fraction", 1e-3, 1), ("band_high_hz", 0.5, 20)):
            in_range(name, getattr(self, name), low, high)
        one_of("program", self.program, PROGRAMS)
        set_ints(self, "max_windows max_iterations check_draws check_starts verify_starts train_attempts", 1)
        set_ints(self, "seed", 0)
        for name, high in (("verify_starts", 1000), ("seed", 10**6 - 1), ("train_attempts", 100)):
            in_range(name, getattr(self, name), 0, high)
        if self.session_s < self.trial_length_s + 3:
            raise ValueError(
                f"excite_s must be at least trial_length_s + {3 - WIGGLE_S - REST_S:g} s (the session with the "
                f"wiggle must hold trial_length_s + 3 s), got {self.excite_s!r}"
            )

    @property
    def session_s(self) -> float:
        """The whole excitation session on the plant: wiggle, program, rest [s]."""
        return WIGGLE_S + self.excite_s + REST_S

    def commissioning_seeds(self) -> list[int]:
        """Every seed the commissioning draws with: the session and its wiggle, the uncertainty draws and the
        design check's starts."""
        return sorted({self.seed, self.seed + 1} | set(self.check_seeds()))

    def check_seeds(self) -> list[int]:
        return [self.seed + 2 + j for j in range(self.check_draws * self.check_starts)]


def verification_seeds(config: CommissionConfig) -> list[int]:
    """The fresh starts of the verification: disjoint from :meth:`CommissionConfig.commissioning_seeds`."""
    seeds = [VERIFY_SEED_OFFSET + config.seed * 1000 + i for i in range(config.verify_starts)]
    if shared := set(seeds) & set(config.commissioning_seeds()):
        raise AssertionError(f"verification seeds {sorted(shared)} were used by the commissioning")
    return seeds


def identified_values(estimates: dict[str, float], std: dict[str, float], nominal_mass_kg: float) -> dict[str, dict]:
    """The rod fields and the torque gain with standard deviations from an identification of the effective rod
    (``mass_kg`` estimated: gain = nominal mass / estimate, each field times the gain; held: gain 1); relative
    standard deviations add in quadrature (the estimates' correlation is not kept)."""
    mass_kg = estimates.get("mass_kg", nominal_mass_kg)
    gain, gain_rel = nominal_mass_kg / mass_kg, std.get("mass_kg", 0.0) / mass_kg
    out: dict[str, dict] = {}
    for name in (n for n in UNKNOWN_FIELDS if n in estimates):
        value, rel = estimates[name], math.hypot(std[name] / estimates[name] if estimates[name] else math.inf, gain_rel)
        out[name] = {"estimate": value * gain, "std": abs(value * gain) * rel, "relative_std": rel}
    out["torque_gain"] = {"estimate": gain, "std": gain * gain_rel, "relative_std": gain_rel}
    return out


def _greybox_result(data: dict) -> Any:
    """What the uncertainty draws need of an identification's :meth:`GreyBoxResult.to_dict`: rod, estimates, std."""
    return SimpleNamespace(params=RodParams.from_dict(data["rod_params"]), estimates=data["estimates"], std=data["std"])


#: Each stage's output in a commissioning folder (the excitation's also its rig dataset).
OUTPUTS = {stage: f"{stage}/{stage}.json" for stage in STAGES} | {
    "identify": "identify/identification.json",
    "report": "report.json",
}


class _Run:
    """One commissioning folder: its stage files, planned and checked before any work."""

    def __init__(self, out: Path, truth: TwinTruth, config: CommissionConfig, twin: Executor) -> None:
        from softpend.io.outputs import Outputs
        from softpend.io.reading import read_json_checked

        self.out, self.truth, self.config, self.outputs, self.process = out, truth, config, Outputs(), twin
        for relative in (SETTINGS_FILE, "excite/rig_dataset.npz", *OUTPUTS.values()):
            self.outputs.folder((out / relative).parent, ((out / relative).name,), what="--out")
        settings, path = {"twin": truth.to_dict(), "config": asdict(config)}, out / SETTINGS_FILE
        if not path.is_file():
            self.outputs.write_json(path, settings)
        elif read_json_checked(path, "--out settings file") != json.loads(json.dumps(settings)):
            raise ValueError(
                f"--out {out} holds a commissioning with other settings ({path}); pass the same settings to "
                "resume it, or another --out"
            )

    def path(self, stage: str) -> Path:
        return self.out / OUTPUTS[stage]

    def read(self, stage: str) -> dict:
        from softpend.io.reading import read_json_checked

        return read_json_checked(self.path(stage), f"{stage} output")

    def twin(self, function: Callable[..., Any], *args: Any) -> Any:
        """``function(truth, private folder, *args)`` on the twin's side."""
        return on_twin_side(self.process, function, self.truth, str(self.out / "twin"), *args)


def _excite(run: _Run) -> dict:
    from softpend.hardware.sync import build_rig_dataset
    from softpend.sysid.babble import band_limited_noise, multisine

    c, guess, dt_s, folder = run.config, RodParams(), 0.01, run.out / "excite"
    n_steps, limit = int(round(c.excite_s / dt_s)), guess.torque_limit_nm
    if c.program == "multisine":
        program = multisine(n_steps, dt_s, c.peak_fraction * limit, band_hz=(0.2, c.band_high_hz))
    else:
        rng, std = np.random.default_rng(c.seed), c.noise_std_fraction * limit
        program = np.clip(band_limited_noise(rng, n_steps, std, c.band_high_hz, dt_s), -limit, limit)
    figures = run.twin(excite_on_twin, str(folder), program.tolist(), c.session_s, c.trial_length_s, c.seed)
    files = (folder / "motor_log.csv", folder / "camera.csv", run.outputs.live(folder / "rig_dataset.npz"))
    dataset, sync = build_rig_dataset(*files, guess, dt_s, c.trial_length_s, "commissioning excitation on the twin")
    run.outputs.done(files[-1])
    figures |= {"program": c.program, "program_s": c.excite_s, "peak_torque_nm": float(abs(program).max())}
    return figures | {"n_trials": dataset.n_trials, "clock_offset_s": sync.offset.offset_s, "gaps": len(sync.gaps)}


def _identify(run: _Run) -> dict:
    from softpend.sysid.dataset import load_dataset
    from softpend.sysid.greybox import GreyBoxConfig, NotIdentifiable, identify

    c, guess = run.config, RodParams()
    dataset = load_dataset(run.out / "excite" / "rig_dataset.npz")

    def fit(parameters: list[str], start: RodParams):
        settings = GreyBoxConfig(tuple(parameters), c.window_s, c.max_windows, c.seed, c.max_iterations)
        return identify(dataset, settings, initial_params=start)

    parameters, held = list(IDENTIFIED_PARAMETERS), []
    while True:  # a parameter the data do not determine from the guess is held there, the others fitted ...
        try:
            result = fit(parameters, guess)
            break
        except NotIdentifiable as exc:
            if exc.parameter not in parameters or len(parameters) == 1:
                raise
            parameters.remove(exc.parameter)
            held.append(exc.parameter)
    if held:  # ... then every parameter is fitted again from there; one still not determined stays held
        try:
            result, held = fit(list(IDENTIFIED_PARAMETERS), result.params), []
        except NotIdentifiable:
            pass
    identified = identified_values(result.estimates, result.std, guess.mass_kg)
    output = {"greybox": result.to_dict(), "identified": identified, "not_identified": held}
    return output | {"model_rod": result.params.to_dict(), "plant_s": 0.0}


def _design(run: _Run) -> dict:
    from softpend.control.identified import design_swingup, uncertainty_draws
    from softpend.study.unknown_rod import balanced_starts

    c, identification = run.config, run.read("identify")
    model = RodParams.from_dict(identification["model_rod"])
    design_swingup(model)  # a design that fails is an error here, not on the plant
    fit = _greybox_result(identification["greybox"])
    draws = uncertainty_draws(fit, c.check_draws, c.seed + 1, c.uncertainty_scale)
    seeds, k = c.check_seeds(), c.check_starts
    balanced = [
        balanced_starts(rod, seeds[i * k : (i + 1) * k], c.check_duration_s, model) for i, rod in enumerate(draws)
    ]
    check = {"draws": len(draws), "starts_each": k, "duration_s": c.check_duration_s, "scale_std": c.uncertainty_scale}
    return {
        "controller": CONTROLLER,
        "model_rod": model.to_dict(),
        "uncertainty_check": check | {"balanced_starts": balanced, "all_balanced": all(b == k for b in balanced)},
        "simulator_s": len(draws) * k * c.check_duration_s,
        "plant_s": 0.0,
    }


def learner_config(
    learner: str, model: RodParams, uncertainty: RodUncertainty, settings: Mapping[str, Any], seed: int
) -> Any:
    """The book's settings of ``learner`` (:func:`~softpend.study.presets.load_hparams`) on the rod ``model``, with
    ``settings`` (but ``episodes``) applied and each training episode (PILCO: trial) on a rod drawn from
    ``uncertainty``; PILCO's seed ``seed``."""
    from softpend.study.presets import load_hparams
    from softpend.task import Task

    config = load_hparams(learner, Task(rod=model), {k: v for k, v in settings.items() if k != "episodes"})
    return dataclasses.replace(config, rod_uncertainty=uncertainty, **({"seed": seed} if learner == "pilco" else {}))


def _train_one(learner: str, config: Any, seed: int, episodes: int, root: Path) -> dict:
    """Train (or keep the finished run of) one learner under ``root``; its run folder and training figures."""
    from softpend.pilco.loop import PilcoResult
    from softpend.rl.training_log import TrainingLog
    from softpend.study.head_to_head import pilco_jobs, run_and_save
    from softpend.study.rl_runs import rl_jobs, run_folder, train_run

    folder = run_folder(root, learner, seed, config)
    if learner == "pilco":
        for _, (seeded, run_dir) in pilco_jobs(config, [seed], root):
            run_and_save(seeded, run_dir, progress=False)
        result = PilcoResult.load(folder)
        figures = {"trials": len(result.records), "simulator_s": result.plant_seconds_total}
        figures |= {"balanced": math.isfinite(result.real_seconds_to_balance), "wall_s": result.train_wall_s}
    else:
        for _, (algo, settings, run_seed, budget, run_dir, resume) in rl_jobs(
            [(learner, config, [seed], episodes)], root
        ):
            train_run(algo, settings, run_seed, budget, run_dir, resume, progress=False)
        log = TrainingLog.load(folder / "log.json")
        rows = log.episodes[-1:] + log.evaluations[-1:]
        figures = {"episodes": log.n_episodes, "simulator_s": log.plant_s, "balanced": log.stop_reason is not None}
        figures["wall_s"] = max((float(r.get("wall_s", 0.0)) for r in rows), default=0.0)
    return {"folder": str(folder.relative_to(root.parent)), **figures}


def _train(run: _Run) -> dict:
    """Each learner trained on the identified rod, seed after seed up to ``train_attempts`` runs until one balances
    on its own evaluation starts (the last run is kept when none does)."""
    from softpend.control.identified import identified_uncertainty

    config, identification = run.config, run.read("identify")
    model = RodParams.from_dict(identification["model_rod"])
    uncertainty = identified_uncertainty(_greybox_result(identification["greybox"]), config.uncertainty_scale)
    runs = {}
    for learner in (c for c in config.controllers if c in LEARNERS):
        settings = config.learners[learner]
        attempts = []
        for seed in range(config.seed, config.seed + config.train_attempts):
            learner_settings = learner_config(learner, model, uncertainty, settings, seed)
            attempts.append(_train_one(learner, learner_settings, seed, settings.get("episodes", 0), run.out / "train"))
            if attempts[-1]["balanced"]:
                break
        totals = {key: sum(a[key] for a in attempts) for key in ("simulator_s", "wall_s")}
        runs[learner] = attempts[-1] | {"seed": seed, "attempts": len(attempts)} | totals
    return {"rod_uncertainty": uncertainty.to_dict(), "runs": runs, "plant_s": 0.0}


def _class_controllers(run: _Run) -> dict[str, dict[str, dict]]:
    """Per commissioned class: the commissioned controller's and the default rod's (when there is one) label and
    twin-side spec (``model_rod`` of a swing-up + LQR, or the ``run`` folder of a learner)."""
    config, runs, model, out = run.config, run.read("train")["runs"], run.read("design")["model_rod"], {}
    for name in config.controllers:
        if name == "swingup":
            specs = {"identified": {"model_rod": model}, "default": {"model_rod": RodParams().to_dict()}}
        else:
            specs = {"identified": {"run": str(run.out / runs[name]["folder"])}}
            if name in config.default_rod_runs:
                specs["default"] = {"run": config.default_rod_runs[name]}
        out[name] = {
            version: {"label": f"{CLASS_NAMES[name]}, {version} rod", "spec": spec} for version, spec in specs.items()
        }
    return out


def _verify(run: _Run) -> dict:
    specs = {v["label"]: v["spec"] for versions in _class_controllers(run).values() for v in versions.values()}
    seeds = verification_seeds(run.config)
    rows = run.twin(verify_on_twin, specs, seeds, run.config.verify_duration_s)
    plant_s = {label: {c: sum(r["plant_s"] for r in by[c]) for c in CONDITIONS} for label, by in rows.items()}
    return {"seeds": seeds, "rows": rows, "plant_s": plant_s}


def _report(run: _Run) -> dict:
    from softpend.study.rig_runs import summary_rows

    config, (excite, identification, design, train, verify) = run.config, (run.read(s) for s in STAGES[:5])
    identified = identification["identified"]
    truth = run.twin(truth_errors, {n: v["estimate"] for n, v in identified.items()})
    for name, entry in identified.items():
        entry["truth"] = truth["truth"].get(name)
        entry["relative_error"] = truth["relative_error"].get(name)
    rows: dict[str, list] = {label: sum(by_condition.values(), []) for label, by_condition in verify["rows"].items()}
    classes = {}
    for name, versions in _class_controllers(run).items():
        label, default = versions["identified"]["label"], versions.get("default")
        classes[name] = {
            "label": label,
            "plant_s": excite["plant_s"] + sum(verify["plant_s"][label].values()),
            "verify_plant_s": verify["plant_s"][label],
            "simulator_s": design["simulator_s"] if name == "swingup" else train["runs"][name]["simulator_s"],
            "training": train["runs"].get(name),
            "verification": summary_rows(rows[label]),
            "default_rod_verification": summary_rows(rows[default["label"]]) if default else None,
        }
    fit = identification["greybox"]["fit"]
    return {
        "twin": run.truth.to_dict(),
        "settings": asdict(config),
        "plant_s": {"excite": excite["plant_s"], "identify": 0.0, "design": 0.0, "train": 0.0},
        "simulator_s": {"design": design["simulator_s"], **{k: v["simulator_s"] for k, v in train["runs"].items()}},
        "rod_uncertainty": train["rod_uncertainty"],
        "identified": identified,
        "truth_source": "the twin's side, for this report only (the commissioning never read it)",
        "identification_fit": {
            "parameters": list(IDENTIFIED_PARAMETERS),
            **{key: fit[key] for key in ("residual_rms_rad", "n_windows", "message", "at_bounds")},
            "camera_delay_s": identification["greybox"]["calibration"]["camera_delay_s"],
        },
        "design": design["uncertainty_check"],
        "classes": classes,
        "seeds": {"commissioning": config.commissioning_seeds(), "verification": verify["seeds"]},
    }


_STAGE_WORK: dict[str, Callable[[_Run], dict]] = dict(
    zip(STAGES, (_excite, _identify, _design, _train, _verify, _report))
)


def commission(
    out: str | Path,
    truth: TwinTruth,
    config: Optional[CommissionConfig] = None,
    on_stage: Optional[Callable[[str, bool, dict], None]] = None,
) -> dict:
    """Run the stages (module docstring) not yet done in ``out``, each writing its output there; the report.

    ``on_stage(stage, ran, output)`` is told of every stage, ``ran`` False for one kept from an earlier run.
    ``out`` holding another commissioning's settings is a ``ValueError``."""
    config = instance_of("config", config if config is not None else CommissionConfig(), CommissionConfig)
    output: dict = {}
    with twin_process() as twin:  # one child for the stages that run on the twin's side
        run = _Run(Path(out), instance_of("truth", truth, TwinTruth), config, twin)
        for stage in STAGES:
            ran = not run.path(stage).is_file()
            if ran:
                output = _STAGE_WORK[stage](run)
                run.outputs.write_json(run.path(stage), output)
            output = run.read(stage)
            if on_stage is not None:
                on_stage(stage, ran, output)
    return output


def identification_errors(report: dict) -> list[float]:
    """The absolute relative errors of a report's identified rod parameters and torque gain, infinite for a rod
    parameter held at the guess (the camera's delay has no truth to compare with)."""
    identified = report["identified"]
    names = [n for n in report["identification_fit"]["parameters"] if n in UNKNOWN_FIELDS] + ["torque_gain"]
    return [abs(identified[n]["relative_error"]) if n in identified else math.inf for n in names]


def commissioned_rods(
    root: str | Path, rod_seeds: Sequence[int], config: Optional[CommissionConfig] = None
) -> list[dict]:
    """The reports of the unknown rods ``TwinTruth(seed=s)`` of ``rod_seeds``, each commissioned in
    ``root/rod_<s>`` (stages done there before are kept)."""
    return [commission(Path(root) / f"rod_{int(seed)}", TwinTruth(seed=int(seed)), config) for seed in rod_seeds]


def commission_table(reports: Sequence[dict]) -> list[dict]:
    """One row per report and class: the rod's seed, the class, the plant seconds of its commissioning (excitation
    and its verification), the simulator seconds of its design check or training, the largest relative error of an
    identified parameter (infinite when one was held at the guess), and per sensor condition the fresh starts the
    commissioned controller and the default rod's balanced ("not run" without a default-rod version)."""
    rows = []
    for report in reports:
        max_error_pct = 100.0 * max(identification_errors(report))
        for name, entry in report["classes"].items():
            row = {"rod": report["twin"]["seed"], "controller": CLASS_NAMES[name], "plant_s": entry["plant_s"]}
            row |= {"simulator_s": entry["simulator_s"], "max_error_pct": max_error_pct}
            for prefix, key in (("commissioned", "verification"), ("default_rod", "default_rod_verification")):
                row.update({f"{prefix}_{condition}": "not run" for condition in CONDITIONS})
                for summary in entry[key] or []:
                    row[f"{prefix}_{summary['condition']}"] = f"{summary['successes']} of {summary['starts']}"
            rows.append(row)
    return rows
