"""``--set NAME=VALUE``: one parser (JSON values, plain-string fallback) and one way to apply it to a config."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Optional

import pytest

from softpend.cli import main
from softpend.io.overrides import apply_overrides, parse_assignment, parse_value


@dataclass(frozen=True)
class Inner:
    mass_kg: float = 0.058
    n_links: int = 4

    def __post_init__(self) -> None:
        if self.mass_kg <= 0:
            raise ValueError(f"mass_kg must be positive, got {self.mass_kg!r}")


@dataclass(frozen=True)
class Middle:
    rod: Inner = field(default_factory=Inner)
    dt_s: float = 0.01


@dataclass(frozen=True)
class Outer:
    task: Middle = field(default_factory=Middle)
    seeds: tuple[int, ...] = (1000, 1001)
    widths: Optional[tuple[int, ...]] = None
    rate: Optional[float] = 3.0
    name: str = "tip"
    flag: bool = False


@pytest.mark.parametrize(
    "text, expected",
    [
        ("3", 3),
        ("1e-3", 1e-3),
        ("-0.5", -0.5),
        ("[0, 1]", [0, 1]),
        ("null", None),
        ("true", True),
        ('"3"', "3"),
        ("beam", "beam"),
        (" beam ", "beam"),
        ("0,1", "0,1"),
        ("", ""),
        ('{"a": 1}', {"a": 1}),
    ],
)
def test_parse_value_reads_json_and_falls_back_to_the_string(text, expected):
    assert parse_value(text) == expected
    assert type(parse_value(text)) is type(expected)


def test_parse_assignment_splits_at_the_first_equals_sign():
    assert parse_assignment("horizon_s=3.0") == ("horizon_s", 3.0)
    assert parse_assignment(" task.rod.mass_kg = 0.07") == ("task.rod.mass_kg", 0.07)
    assert parse_assignment("label=a=b") == ("label", "a=b")
    assert parse_assignment("eval_seeds=[0,1]") == ("eval_seeds", [0, 1])


@pytest.mark.parametrize("item", ["horizon_s", "=3", "3x=1", "a..b=1", "task.=1", "a-b=2", " =1"])
def test_parse_assignment_rejects_a_bad_item_quoting_it(item):
    with pytest.raises(ValueError, match="NAME=VALUE") as info:
        parse_assignment(item)
    assert repr(item) in str(info.value)


def test_apply_overrides_replaces_fields_and_keeps_the_rest():
    base = Outer()
    out = apply_overrides(base, {"name": "joint", "rate": None, "flag": True})
    assert (out.name, out.rate, out.flag) == ("joint", None, True)
    assert out.task == base.task and out.seeds == base.seeds
    assert base.name == "tip"  # the input is not modified


def test_apply_overrides_makes_tuples_of_lists_and_of_the_comma_form():
    assert apply_overrides(Outer(), {"seeds": [0, 1]}).seeds == (0, 1)
    assert apply_overrides(Outer(), {"seeds": "0,1"}).seeds == (0, 1)
    assert apply_overrides(Outer(), {"seeds": 5}).seeds == (5,)
    assert apply_overrides(Outer(), {"widths": [64, 64]}).widths == (64, 64)  # Optional[tuple] with None now
    assert apply_overrides(Outer(), [("seeds", [1]), ("seeds", [2])]).seeds == (2,)  # pairs: the last wins


def test_apply_overrides_reaches_nested_dataclasses_by_dotted_names():
    out = apply_overrides(Outer(), {"task.rod.mass_kg": 0.07, "task.dt_s": 0.02, "task.rod.n_links": 6})
    assert out.task.rod == Inner(mass_kg=0.07, n_links=6) and out.task.dt_s == 0.02
    assert apply_overrides(Outer(), {"task": {"rod": {"n_links": 2}}}).task.rod.n_links == 2


def test_apply_overrides_validates_the_copy():
    with pytest.raises(ValueError, match="mass_kg must be positive"):
        apply_overrides(Outer(), {"task.rod.mass_kg": -1.0})


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"nmae": "x"}, r"unknown Outer field 'nmae'; known: \['flag', 'name', 'rate', 'seeds', 'task', 'widths'\]"),
        ({"task.rod.masss_kg": 1.0}, r"unknown Inner field 'task.rod.masss_kg'; known: \['mass_kg', 'n_links'\]"),
        ({"name.length": 1}, r"cannot set name.length: name holds a str"),
        ({"task": Middle(), "task.dt_s": 0.1}, r"'task' is set both whole and through task.<field>"),
    ],
)
def test_apply_overrides_rejects_unknown_or_impossible_names(overrides, message):
    with pytest.raises(ValueError, match=message):
        apply_overrides(Outer(), overrides)


def test_apply_overrides_needs_a_dataclass_instance():
    with pytest.raises(ValueError, match="dataclass instance"):
        apply_overrides(Outer, {"name": "x"})
    with pytest.raises(ValueError, match="dataclass instance"):
        apply_overrides({"name": "x"}, {"name": "y"})


def test_rl_and_pilco_configs_take_the_same_overrides():
    from softpend.pilco.loop import PilcoConfig
    from softpend.rl.config import MBPOConfig

    rl = apply_overrides(
        MBPOConfig(),
        dict([parse_assignment("learner.net_arch=[32,32]"), parse_assignment("learner.learning_rate=1e-3")]),
    )
    assert rl.learner.net_arch == (32, 32) and rl.learner.learning_rate == 1e-3
    pilco = apply_overrides(
        PilcoConfig(),
        dict(
            map(
                parse_assignment,
                ["eval_seeds=[0,1]", "cost.rate_width_rad_s=null", "state=tip", "task.rod.mass_kg=0.07"],
            )
        ),
    )
    assert pilco.eval_seeds == (0, 1) and pilco.cost.rate_width_rad_s is None and pilco.state == "tip"
    assert pilco.task.rod.mass_kg == 0.07
    assert dataclasses.replace(pilco, task=PilcoConfig().task) == apply_overrides(
        PilcoConfig(), {"eval_seeds": "0,1", "cost": {"rate_width_rad_s": None}, "state": "tip"}
    )


@pytest.mark.parametrize(
    "argv, message",
    [
        (["train", "--algo", "dqn", "--set", "learning_rate"], "--set expects NAME=VALUE"),
        (["train", "--algo", "pilco", "--set", "no_such_field=1"], "unknown PilcoConfig field 'no_such_field'"),
        (["train", "--algo", "dqn", "--set", "learner.gamma=2"], "learner.gamma must lie in [0, 1]"),
        (["book", "--set", "3d=1"], "--set expects NAME=VALUE"),
    ],
)
def test_a_bad_set_is_one_line_on_stderr_and_exit_status_2(argv, message, capsys):
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert message in captured.err
    assert len(captured.err.strip().splitlines()) == 1 and "Traceback" not in captured.err
    assert captured.out == ""
