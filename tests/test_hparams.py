"""The tuned settings as data: ``book/hparams/<method>.yml`` read into the configs by ``load_hparams``."""

import dataclasses

import pytest
import yaml

from softpend.control.planner import PlannerConfig
from softpend.pilco import PilcoConfig
from softpend.rl.config import DQNConfig, MBPOConfig
from softpend.study.presets import CONFIG_CLASSES, HPARAMS_DIR, load_hparams, load_settings
from softpend.task import Task

#: The settings files that list the settings they run with in full, defaults included.
LISTS_DEFAULTS = {"planner"}
#: Every settings file's config class: the book's training methods, and the planner.
SETTINGS = {**CONFIG_CLASSES, "planner": PlannerConfig}


@pytest.mark.parametrize("method", sorted(SETTINGS))
def test_every_setting_in_a_file_is_a_field_of_its_config_and_is_applied(method):
    cls = SETTINGS[method]
    data = yaml.safe_load((HPARAMS_DIR / f"{method}.yml").read_text())
    assert isinstance(data, dict) and data
    fields = {f.name for f in dataclasses.fields(cls)}
    assert set(data) <= fields - {"task"}
    config = load_settings(cls, HPARAMS_DIR / f"{method}.yml")
    assert type(config) is cls
    assert method == "planner" or load_hparams(method) == config
    _assert_applied(config, cls(), data, may_repeat=method in LISTS_DEFAULTS)


def _assert_applied(config, default, data, prefix="", may_repeat=False):
    """Every setting of ``data`` (nested groups as mappings) is applied and differs from the default (unless
    ``may_repeat``); every other field keeps the class's default (the plain algorithm's)."""
    for name, value in data.items():
        got, plain = getattr(config, name), getattr(default, name)
        if dataclasses.is_dataclass(got):
            assert isinstance(value, dict), prefix + name
            _assert_applied(got, plain, value, f"{prefix}{name}.", may_repeat)
            continue
        assert (list(got) if isinstance(got, tuple) else got) == value, prefix + name
        assert may_repeat or got != plain, f"{prefix}{name} repeats the default of {type(default).__name__}"
    for f in dataclasses.fields(config):
        if f.name not in data:
            assert getattr(config, f.name) == getattr(default, f.name), prefix + f.name


def test_the_classes_and_the_files():
    assert CONFIG_CLASSES == {"dqn": DQNConfig, "mbpo": MBPOConfig, "pilco": PilcoConfig}
    assert sorted(path.stem for path in HPARAMS_DIR.glob("*.yml")) == sorted(SETTINGS)


def test_an_unknown_setting_is_a_one_line_error_naming_it_and_the_file(tmp_path):
    (tmp_path / "dqn.yml").write_text("learner: {learning_rate: 1.0e-3}\nlerning_starts: 5\n")
    with pytest.raises(ValueError, match=r"dqn\.yml: 'lerning_starts' is not a DQNConfig setting") as info:
        load_hparams("dqn", path=tmp_path / "dqn.yml")
    assert "\n" not in str(info.value)
    (tmp_path / "pilco.yml").write_text("task: {}\n")
    with pytest.raises(ValueError, match="'task' is not a PilcoConfig setting"):
        load_hparams("pilco", path=tmp_path / "pilco.yml")
    (tmp_path / "dqn.yml").write_text("rollout: {per_real_step: 5}\n")  # a DQN-MBPO setting
    with pytest.raises(ValueError, match="'rollout' is not a DQNConfig setting"):
        load_hparams("dqn", path=tmp_path / "dqn.yml")
    (tmp_path / "mbpo.yml").write_text("rollout: {per_real_step: 5}\n")
    assert load_hparams("mbpo", path=tmp_path / "mbpo.yml").rollout.per_real_step == 5
    with pytest.raises(ValueError, match=r"missing/dqn\.yml: cannot read the settings"):
        load_hparams("dqn", path=tmp_path / "missing" / "dqn.yml")


def test_a_bad_value_or_a_file_that_is_not_a_mapping_is_a_one_line_error(tmp_path):
    (tmp_path / "dqn.yml").write_text("learner: {gamma: 1.5}\n")
    with pytest.raises(ValueError, match=r"dqn\.yml: .*gamma") as info:
        load_hparams("dqn", path=tmp_path / "dqn.yml")
    assert "\n" not in str(info.value)
    (tmp_path / "pilco.yml").write_text("- 1\n- 2\n")
    with pytest.raises(ValueError, match=r"pilco\.yml: expected a mapping of PilcoConfig fields"):
        load_hparams("pilco", path=tmp_path / "pilco.yml")
    with pytest.raises(ValueError, match="unknown method 'sac'"):
        load_hparams("sac")


def test_task_and_overrides_come_after_the_file():
    task = Task(plant="beam")
    config = load_hparams("mbpo", task, {"episode_s": 1.0, "task.rod.torque_limit_nm": 0.08})
    assert config.task == task.replace(torque_limit_nm=0.08) and config.episode_s == 1.0
    assert config.learner.gradient_steps == load_hparams("mbpo").learner.gradient_steps
    with pytest.raises(ValueError, match="unknown PilcoConfig field 'bogus'"):
        load_hparams("pilco", overrides={"bogus": 1})
