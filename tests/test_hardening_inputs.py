"""Bad input gets a named error -- never silent garbage, unbounded work or a traceback."""

from __future__ import annotations

import io
import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from support import one_line_error

from softpend.cli import main

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def datasets(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("data")
    out = {}
    for name, dt in (("train", "0.01"), ("other_dt", "0.02")):
        out[name] = folder / f"{name}.npz"
        assert (
            main(
                ["babble", str(out[name]), "--n-trials", "3", "--trial-length-s", "0.2", "--dt-s", dt, "--no-progress"]
            )
            == 0
        )
    return out


# ------------------------------------------------------------------------------------------------ silent garbage
def test_fit_model_refuses_test_data_at_another_time_step(datasets, tmp_path, capsys):
    capsys.readouterr()
    args = [
        "fit-model",
        str(datasets["train"]),
        str(tmp_path / "m"),
        "--test-data",
        str(datasets["other_dt"]),
        "--max-epochs",
        "2",
        "--no-progress",
    ]
    assert main(args) == 2
    one_line_error(capsys, "dt_s is 0.02, expected 0.01")
    assert not (tmp_path / "m.pt").exists()


def test_datasets_refuse_an_absurd_time_step(datasets, tmp_path):
    from softpend.sysid import load_dataset, save_dataset

    good = load_dataset(datasets["train"])
    with pytest.raises(ValueError, match="dt_s must lie in"):
        save_dataset(tmp_path / "x.npz", good.positions, good.velocities, good.torques_nm, dt_s=1e-300)
    # a file whose metadata says 1e-300 (written around the checks)
    with zipfile.ZipFile(datasets["train"]) as archive:
        members = {info.filename: archive.read(info) for info in archive.infolist()}
    meta = json.loads(str(np.load(io.BytesIO(members["metadata.npy"]))[()]))
    meta["dt_s"] = 1e-300
    buffer = io.BytesIO()
    np.save(buffer, np.array(json.dumps(meta)))
    members["metadata.npy"] = buffer.getvalue()
    with zipfile.ZipFile(tmp_path / "tiny_dt.npz", "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    with pytest.raises(ValueError, match="dt_s must lie in"):
        load_dataset(tmp_path / "tiny_dt.npz")


def test_episodes_shorter_than_one_agent_step_are_refused(tmp_path, capsys):
    from softpend.rl.config import DQNConfig

    with pytest.raises(ValueError, match="at least one agent step"):
        DQNConfig(episode_s=1e-9)
    assert DQNConfig(episode_s=0.04).episode_agent_steps == 1
    assert main(["train", "--algo", "dqn", "--out", str(tmp_path / "r"), "--set", "episode_s=1e-9"]) == 2
    one_line_error(capsys, "episode_s")


def test_the_discrete_env_takes_only_members_of_its_action_space():
    from softpend.envs import SoftPendulumDiscreteEnv

    env = SoftPendulumDiscreteEnv()
    env.reset(seed=0)
    for action in (2.7, [1, 2], True, np.array([1.0]), "1", None, np.float64(2.0), 5, -1):
        with pytest.raises(ValueError, match="action must be"):
            env.step(action)
    for action in (2, np.int64(3), np.array(1), np.array([4]), [0]):
        env.step(action)


def test_rod_params_accept_numpy_integers_and_cap_the_links():
    from softpend.plant import RodParams

    assert RodParams(n_links=np.int64(4)) == RodParams(n_links=4)
    assert type(RodParams(n_links=np.int64(4)).n_links) is int
    assert RodParams(n_links=64).n_links == 64
    with pytest.raises(ValueError, match="at most 64"):
        RodParams(n_links=100_000)


@pytest.fixture(scope="module")
def figure_book(tmp_path_factory) -> Path:
    """A project root holding the real Figure 1 and 2 notebooks (to run them with bad parameters)."""
    root = tmp_path_factory.mktemp("book")
    (root / "notebooks").mkdir()
    (root / "book").mkdir()
    names = ["fig01_prb_rod", "fig02_reward"]
    chapters = "\n".join(f"      - file: book/_generated/{name}" for name in names)
    (root / "_toc.yml").write_text(
        f"format: jb-book\nroot: book/intro\nparts:\n  - caption: Figures\n    chapters:\n{chapters}\n"
    )
    (root / "book" / "profiles.yml").write_text(json.dumps({"quick": {}}))
    for name in names:
        shutil.copy(ROOT / "notebooks" / f"{name}.md", root / "notebooks" / f"{name}.md")
    return root


@pytest.mark.parametrize(
    "notebook, assignment, message",
    [
        ("fig02_reward", "n_points=0", "n_points must be an integer >= 2"),
        ("fig02_reward", "dt_s=-0.01", "dt_s must be positive"),
        ("fig01_prb_rod", "n_links=100000", "n_links must be at most 64"),
    ],
)
@pytest.mark.timeout(600)  # a guard against a hang, not a timing figure
def test_figure_notebooks_refuse_impossible_parameters(figure_book, capsys, notebook, assignment, message):
    args = [
        "book",
        "--root",
        str(figure_book),
        "--profile",
        "quick",
        "--only",
        notebook,
        "--set",
        assignment,
        "--force",
    ]
    assert main(args) == 1
    assert message in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------ bounds
@pytest.mark.parametrize(
    "option, value, words",
    [
        ("--dt-s", "1e-9", ("dt_s must lie in",)),
        ("--n-trials", "10000000000", ("GiB", "samples")),
        ("--trial-length-s", "1e9", ("GiB", "samples")),
    ],
)
def test_babble_refuses_work_that_cannot_fit_before_starting(tmp_path, capsys, option, value, words):
    assert main(["babble", str(tmp_path / "d.npz"), option, value, "--no-progress"]) == 2
    one_line_error(capsys, *words)
    assert not (tmp_path / "d.npz").exists()


# ------------------------------------------------------------------------------------------------ one-line errors
@pytest.mark.parametrize(
    "args",
    [
        ["--dt-s", "0.2", "--n-trials", "2", "--trial-length-s", "2"],
        ["--n-links", "40", "--n-trials", "2", "--trial-length-s", "1"],
    ],
)
def test_a_diverging_babble_is_one_line(tmp_path, capsys, args):
    assert main(["babble", str(tmp_path / "d.npz"), "--no-progress", *args]) == 2
    one_line_error(capsys, "SimulationDiverged", "trial 0")


@pytest.mark.parametrize(
    "assignment",
    [
        "eval_seeds=[null]",
        "eval_seeds=[[1]]",
        "learner.net_arch=[1e400]",
        'learner.net_arch={"a": 1}',
        "eval_seeds=[-1]",
        "task.rod.n_links=1e30",
        "task.substeps=1e9",
        "learner.buffer_size=1e12",
        "learner.net_arch=[100000000]",
        "learner.batch_size=1000000000",
    ],
)
def test_wrong_train_set_values_are_one_line(tmp_path, capsys, assignment):
    assert main(["train", "--algo", "dqn", "--out", str(tmp_path / "r"), "--no-progress", "--set", assignment]) == 2
    one_line_error(capsys)
    assert not [p for p in tmp_path.rglob("*") if p.is_file()]  # refused before any work: nothing written


@pytest.fixture(scope="module")
def agent_run(tmp_path_factory) -> Path:
    from softpend.rl.config import DQNConfig
    from softpend.rl.dqn import train_dqn

    folder = tmp_path_factory.mktemp("agent") / "run"
    train_dqn(
        DQNConfig(learning_starts=10, episode_s=0.5, eval_seeds=(0,), eval_duration_s=0.5),
        seed=0,
        episodes=1,
        run_dir=folder,
        progress=False,
    )
    return folder


@pytest.mark.parametrize(
    "args, words",
    [
        (["--seeds", "-1"], ("seeds must be an integer >= 0",)),
        (["--duration-s", "1e12"], ("GiB", "steps")),
        (["--duration-s", "nan"], ("duration_s",)),
    ],
)
def test_evaluate_refuses_bad_seeds_and_durations(agent_run, capsys, args, words):
    assert main(["evaluate", str(agent_run), *args]) == 2
    one_line_error(capsys, *words)


def test_deeply_nested_and_huge_dataset_files_are_named_errors(datasets, tmp_path, capsys):
    from softpend.sysid import load_dataset

    with zipfile.ZipFile(datasets["train"]) as archive:
        members = {info.filename: archive.read(info) for info in archive.infolist()}
    nested = dict(members)
    buffer = io.BytesIO()
    np.save(buffer, np.array("[" * 100_000 + "]" * 100_000))
    nested["metadata.npy"] = buffer.getvalue()
    huge = dict(members)
    header = io.BytesIO()  # a header that claims 10**13 float64 values, with none behind it
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (10**13,)})
    huge["positions.npy"] = b"\x93NUMPY\x01\x00" + header.getvalue()[8:]
    for name, content in (("nested", nested), ("huge", huge)):
        path = tmp_path / f"{name}.npz"
        with zipfile.ZipFile(path, "w") as archive:
            for member, data in content.items():
                archive.writestr(member, data)
        with pytest.raises(ValueError):
            load_dataset(path)
        assert main(["fit-model", str(path), str(tmp_path / "m"), "--no-progress"]) == 2
        one_line_error(capsys, str(path))


def test_static_equilibrium_solver_errors_are_simulation_diverged():
    from softpend.plant import PRBPlant, RodParams, SimulationDiverged

    plant = PRBPlant(RodParams(stiffness_scale=0.0))  # a chain of free hinges: no unique static equilibrium
    with pytest.raises(SimulationDiverged, match="static solver"):
        plant.static_equilibrium()


def test_debug_shows_the_traceback(tmp_path, capsys):
    assert main(["evaluate", str(tmp_path / "none")]) == 2
    one_line_error(capsys, "no agent")
    for args in (["--debug", "evaluate", str(tmp_path / "none")], ["evaluate", str(tmp_path / "none"), "--debug"]):
        with pytest.raises(FileNotFoundError):
            main(args)


def test_papermill_run_directly_refuses_an_unknown_parameter(tmp_path):
    import jupytext
    import nbformat
    import papermill
    from papermill.exceptions import PapermillExecutionError

    source = tmp_path / "fig02.ipynb"
    nbformat.write(jupytext.read(ROOT / "notebooks" / "fig02_reward.md", fmt="md:myst"), str(source))
    run = dict(kernel_name="python3", progress_bar=False, cwd=str(ROOT))
    with pytest.raises(PapermillExecutionError, match="n_pionts"):
        papermill.execute_notebook(str(source), str(tmp_path / "typo.ipynb"), parameters={"n_pionts": 11}, **run)
    papermill.execute_notebook(str(source), str(tmp_path / "ok.ipynb"), parameters={"n_points": 11}, **run)


def test_every_notebook_checks_its_parameters_right_after_the_parameters_cell():
    import jupytext

    for path in sorted((ROOT / "notebooks").glob("*.md")):
        cells = [c for c in jupytext.read(path, fmt="md:myst").cells if c.cell_type == "code"]
        index = next(i for i, c in enumerate(cells) if "parameters" in c.metadata.get("tags", []))
        assert "check_notebook_parameters()" in cells[index + 1].source, path.name
