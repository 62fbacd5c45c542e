"""The book runner's schedule: which notebook starts when (softpend.study.book_schedule)."""

from __future__ import annotations

import pytest

from softpend.study.book_schedule import Needs, next_to_start

ORDER = ["fig01", "rig", "fig04", "ledger"]
NEEDS = {"fig01": Needs(), "rig": Needs(runs=frozenset({"dqn-seed0"}), realtime=True),
         "fig04": Needs(runs=frozenset({"dqn-seed0", "dqn-seed1"})), "ledger": Needs(after=frozenset({"fig04"}))}


def step(started=(), finished=(), trained=(), lanes=2):
    return next_to_start(ORDER, NEEDS, set(started), set(finished), set(trained), lanes)


def test_a_notebook_starts_when_what_it_waits_for_has_finished():
    assert step() == "fig01"
    assert step(started={"fig01"}) is None  # the others wait for runs or for fig04
    assert step(started={"fig01"}, trained={"dqn-seed1"} | {"dqn-seed0"}) is None  # "rig" is ready and next: it holds
    assert step(started={"fig01", "rig"}, finished={"fig01", "rig"}, trained={"dqn-seed0", "dqn-seed1"}) == "fig04"
    assert step(started={"fig01", "fig04"}, finished={"fig01", "fig04"}, trained={"dqn-seed0", "dqn-seed1"}) == "rig"
    assert step(started={"fig01", "rig", "fig04"}, finished={"fig01", "rig", "fig04"},
                trained={"dqn-seed0", "dqn-seed1"}) == "ledger"
    assert step(started=ORDER, finished=ORDER, trained={"dqn-seed0", "dqn-seed1"}) is None


def test_lanes_bound_the_notebooks_at_once():
    trained = {"dqn-seed1"}
    assert step(started={"fig01"}, trained=trained | {"dqn-seed0"}, lanes=1) is None
    assert step(started={"fig01"}, finished={"fig01"}, trained=trained, lanes=1) is None  # rig, fig04 wait for runs
    with pytest.raises(ValueError, match="lanes must be at least 1"):
        step(lanes=0)


def test_a_real_time_notebook_runs_alone_and_is_not_passed_over():
    trained = {"dqn-seed0", "dqn-seed1"}
    order = ["fig01", "rig", "fig04"]
    # ready, but fig01 runs: it waits, and fig04 (ready too, later in line) does not pass it
    assert next_to_start(order, NEEDS, {"fig01"}, set(), trained, 2) is None
    assert next_to_start(order, NEEDS, {"fig01"}, {"fig01"}, trained, 2) == "rig"
    # while it runs, nothing starts, whatever the free lanes
    assert next_to_start(order, NEEDS, {"fig01", "rig"}, {"fig01"}, trained, 4) is None
    # one that is not ready does not hold the others back
    assert next_to_start(order, NEEDS, {"fig01"}, set(), {"dqn-seed1"}, 2) is None  # fig04 lacks dqn-seed0 too
    assert next_to_start(["rig", "fig01"], NEEDS, set(), set(), set(), 2) == "fig01"


def test_a_real_time_notebook_waits_for_the_training_pool_without_holding_the_others():
    trained = {"dqn-seed0"}
    order = ["rig", "fig01"]
    assert next_to_start(order, NEEDS, set(), set(), trained, 2, training=True) == "fig01"
    assert next_to_start(order, NEEDS, {"fig01"}, {"fig01"}, trained, 2, training=True) is None
    assert next_to_start(order, NEEDS, {"fig01"}, {"fig01"}, trained, 2, training=False) == "rig"
