"""Random and hostile inputs at the commands, the file loaders, the environments and ``--set`` parsing.

Every draw comes from a seeded ``numpy`` generator (the same cases every run).  Each case ends in one of two
outcome classes -- a *named error* (a command: exit status 2, or 1 for a failed notebook, with exactly one line
on stderr and no traceback; a function: ``ValueError``/``OSError``) or a *legitimate result* (exit 0 with valid
JSON where JSON is printed; a loaded object; finite observations and rewards) -- and never anything else: no
other exception, no traceback, no hang (every case runs under an alarm), no NaN in printed JSON and no file
lost (a file the command did not write keeps its bytes).  The counts per entry point are printed at the end
(``pytest -s``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import os
import re
import shutil
import signal
import traceback
import zipfile
from collections import defaultdict
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

from softpend.cli import main

#: Seed of every draw (``SOFTPEND_FUZZ_SEED`` explores other cases; the suite runs this one).
SEED = int(os.environ.get("SOFTPEND_FUZZ_SEED", "20240518"))
CASE_LIMIT_S = 30.0
COUNTS: dict[str, dict[str, int]] = defaultdict(lambda: {"tried": 0, "named error": 0, "legitimate": 0, "other": 0})
OTHER: dict[str, list[str]] = defaultdict(list)


class Hang(BaseException):
    """Raised by the alarm when a case runs past :data:`CASE_LIMIT_S` (a BaseException: nothing catches it)."""


@contextlib.contextmanager
def alarm(seconds: float):
    def ring(signum, frame):
        raise Hang(f"no result after {seconds} s")

    previous = signal.signal(signal.SIGALRM, ring)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def record(entry: str, outcome: str, detail: str = "") -> None:
    COUNTS[entry]["tried"] += 1
    COUNTS[entry][outcome] += 1
    if outcome == "other":
        OTHER[entry].append(detail[:600])


def _strict_json(text: str) -> Any:
    def refuse(constant: str):
        raise ValueError(f"non-JSON constant {constant}")

    return json.loads(text, parse_constant=refuse)


def run_cli(entry: str, argv: list[str], guarded: list[Path]) -> None:
    """Run ``softpend argv`` in-process and classify it; ``guarded`` files must keep their bytes."""
    before = {p: p.read_bytes() for p in guarded if p.is_file()}
    out, err = io.StringIO(), io.StringIO()
    try:
        with alarm(CASE_LIMIT_S), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = main(argv)
    except BaseException as exc:  # noqa: BLE001 - anything escaping main is the outcome under test
        record(entry, "other", f"{argv}: {type(exc).__name__}: {exc}")
        return
    stderr, stdout = err.getvalue(), out.getvalue()
    lost = [str(p) for p, data in before.items() if not p.is_file() or p.read_bytes() != data]
    # progress bars (tqdm: carriage returns, "NN%|") are not messages
    lines = [line.split("\r")[-1] for line in stderr.split("\n")]
    lines = [line for line in lines if line.strip() and not re.search(r"\d+%\|", line)]
    if lost:
        record(entry, "other", f"{argv}: lost or changed {lost}")
    elif rc in (1, 2) and len(lines) == 1 and "Traceback" not in stderr and "error" in lines[0]:
        record(entry, "named error")
    elif rc == 0 and "Traceback" not in stderr:
        text = stdout.strip()
        try:
            if text.startswith("{"):
                _strict_json(text[: text.rindex("}") + 1])
        except ValueError as exc:
            record(entry, "other", f"{argv}: printed invalid JSON: {exc}")
            return
        record(entry, "legitimate")
    else:
        record(entry, "other", f"{argv}: rc={rc} stderr={stderr[-400:]!r}")


def run_call(entry: str, call: Callable[[], Any], check: Callable[[Any], None] | None = None, label: str = "") -> None:
    """Run a Python entry point and classify it (``check`` validates a legitimate result)."""
    try:
        with alarm(CASE_LIMIT_S):
            result = call()
            if check is not None:
                check(result)
    except (ValueError, OSError):
        record(entry, "named error")
        return
    except BaseException as exc:  # noqa: BLE001
        where = traceback.extract_tb(exc.__traceback__)[-1]
        record(entry, "other", f"{label}: {type(exc).__name__}: {exc} (at {where.filename}:{where.lineno})")
        return
    record(entry, "legitimate")


# ------------------------------------------------------------------------------------------------ inputs
HOSTILE_NUMBERS = ["0", "-1", "-0.0", "nan", "inf", "-inf", "1e400", "1e-300", "1e300", "abc", "", "1,2", "[1]",
                   "null", "true", "9" * 400, "0x10", "1e9", "-1e9", "2.5"]
HOSTILE_JSON = [None, True, -1, 0, 1.5, 1e308, -1e308, "x", "", [], [None], [[1]], {}, {"a": 1}, "nan", "1e400",
                10**30, -(10**30), [1, 2, 3], "prb", "beam", "random"]


def pick(rng: np.random.Generator, values: list) -> Any:
    return values[int(rng.integers(len(values)))]


def mutate_bytes(rng: np.random.Generator, data: bytes) -> bytes:
    kind = int(rng.integers(3))
    buf = bytearray(data)
    if kind == 0:  # flip bits
        for _ in range(int(rng.integers(1, 16))):
            i = int(rng.integers(len(buf)))
            buf[i] ^= 1 << int(rng.integers(8))
        return bytes(buf)
    if kind == 1:  # truncate
        return bytes(buf[: int(rng.integers(len(buf)))])
    i = int(rng.integers(len(buf)))  # overwrite a run with random bytes
    n = int(rng.integers(1, 64))
    buf[i : i + n] = rng.integers(0, 256, size=min(n, len(buf) - i), dtype=np.uint8).tobytes()
    return bytes(buf)


def mutate_json(rng: np.random.Generator, value: Any, depth: int = 0) -> Any:
    """``value`` with one randomly chosen entry (at any depth) replaced by a hostile JSON value."""
    if isinstance(value, dict) and value and (depth == 0 or rng.random() < 0.7):
        key = pick(rng, sorted(value, key=str))
        out = dict(value)
        if rng.random() < 0.15:
            del out[key]
        else:
            out[key] = mutate_json(rng, value[key], depth + 1)
        return out
    if isinstance(value, list) and value and rng.random() < 0.7:
        i = int(rng.integers(len(value)))
        return value[:i] + [mutate_json(rng, value[i], depth + 1)] + value[i + 1 :]
    return pick(rng, HOSTILE_JSON)


def rewrite_zip(data: bytes, change: Callable[[str, bytes], bytes]) -> bytes:
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        members = [(info.filename, archive.read(info)) for info in archive.infolist()]
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        for name, member in members:
            archive.writestr(name, change(name, member))
    return out.getvalue()


# ------------------------------------------------------------------------------------------------ fixtures
TINY_RL = ["--set", "episode_s=0.2", "--set", "eval_seeds=[0]", "--set", "eval_duration_s=0.2", "--set", "learning_starts=5",
           "--set", "buffer_size=1000", "--set", "net_arch=[16]"]
TINY_PILCO = ["--set", "state=tip", "--set", "horizon_s=0.5", "--set", "prediction_s=null", "--set", "eval_seeds=[1000]", "--set", "eval_duration_s=0.5",
              "--set", "n_basis=3", "--set", "max_gp_points=10", "--set", "gp_iterations=2", "--set", "policy_iterations=1",
              "--set", "compiled=false"]


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> dict[str, Path]:
    """Files the fuzz reads: a tiny dataset (and one at another dt), a tiny DQN run, a precious foreign file."""
    root = tmp_path_factory.mktemp("fuzz")
    paths = {"root": root}
    quiet = contextlib.redirect_stdout(io.StringIO())
    quiet.__enter__()
    for name, dt in (("data", "0.01"), ("data_dt2", "0.02")):
        paths[name] = root / f"{name}.npz"
        assert main(["babble", str(paths[name]), "--n-trials", "3", "--trial-length-s", "0.1", "--dt-s", dt, "--no-progress"]) == 0
    paths["run"] = root / "run"
    assert main(["train", "--algo", "dqn", "--episodes", "1", "--out", str(paths["run"]), "--no-progress", *TINY_RL]) == 0
    paths["model"] = root / "model"
    assert main(["fit-model", str(paths["data"]), str(paths["model"]), "--max-epochs", "2", "--no-progress"]) == 0
    paths["precious"] = root / "precious.npz"
    paths["precious"].write_bytes(b"a file the commands did not write")
    paths["a_file"] = root / "a_file"
    paths["a_file"].write_text("not a folder")
    (root / "folder").mkdir()
    quiet.__exit__(None, None, None)
    return paths


def _paths(world: dict[str, Path], rng: np.random.Generator, fresh: str, hostile: bool) -> str:
    root = world["root"]
    if not hostile:
        return str(pick(rng, [root / fresh, root / "new" / fresh]))
    return str(pick(rng, [world["precious"], world["a_file"] / "x", root / "folder", Path("/proc/fuzz/x")]))


def _options(rng: np.random.Generator, sane: dict[str, list[str]], hostile: dict[str, list[str]], n_hostile: int) -> list[str]:
    """Some options with sane values, ``n_hostile`` of them with hostile ones (their own, or hostile numbers)."""
    chosen = {option: pick(rng, values) for option, values in sane.items() if rng.random() < 0.4}
    for option in rng.choice(sorted(sane), size=n_hostile, replace=False):
        pool = hostile.get(option, []) + (HOSTILE_NUMBERS if rng.random() < 0.5 or option not in hostile else [])
        chosen[str(option)] = pick(rng, pool)
    return [item for option, value in chosen.items() for item in (option, value)]


def _n_hostile(rng: np.random.Generator) -> int:
    """0 (a clean case) about a third of the time, else 1, sometimes 2."""
    return int(rng.choice([0, 1, 1, 2]))


def test_fuzz_babble(world):
    rng = np.random.default_rng([SEED, 1])
    sane = {"--n-trials": ["1", "2"], "--trial-length-s": ["0.05", "0.1"], "--dt-s": ["0.01", "0.005", "0.02"],
            "--start": ["upright", "hanging", "random"], "--torque-std-fraction": ["0.5", "1"],
            "--torque-bandwidth-hz": ["2", "10"], "--feedback-trial-fraction": ["0.5", "0"], "--feedback-kp": ["0.8"],
            "--feedback-kd": ["0.01"], "--phi-noise-std-rad": ["0.01"], "--tip-noise-std-m": ["0.001"],
            "--er-noise-std-rad": ["0", "0.01"], "--camera-delay-steps": ["0", "1"], "--n-links": ["2", "4"], "--seed": ["0", "3"]}
    hostile = {"--n-trials": ["10000000000", "1000000000000000000000", "0"], "--trial-length-s": ["1e12", "0.001"],
               "--dt-s": ["1e-9", "20", "0.2"], "--n-links": ["100000", "65", "40", "0"], "--camera-delay-steps": ["1000000000000", "-1"],
               "--start": ["sideways"], "--feedback-trial-fraction": ["1.5"], "--seed": ["-1", str(2**70)]}
    for i in range(60):
        n_hostile = _n_hostile(rng)
        path_hostile = n_hostile > 0 and rng.random() < 0.3
        argv = ["babble", _paths(world, rng, f"b{i}.npz", path_hostile), "--no-progress"]
        argv += _options(rng, sane, hostile, n_hostile - path_hostile)
        run_cli("softpend babble", argv, [world["precious"], world["data"]])
    assert not OTHER["softpend babble"], OTHER["softpend babble"]


def test_fuzz_fit_model(world):
    rng = np.random.default_rng([SEED, 2])
    sane = {"--information": ["full", "limited"], "--history": ["0", "1", "2"], "--velocity-source": ["observed", "true"],
            "--hidden-widths": ["8", "8,8", "4,4,4"], "--activation": ["silu", "tanh"], "--ensemble-size": ["1", "2"],
            "--batch-size": ["16", "1000"], "--learning-rate": ["0.001", "0.01"], "--patience": ["1", "3"],
            "--validation-fraction": ["0.3", "0.5"], "--seed": ["0", "1"], "--threads": ["1"], "--max-epochs": ["1", "2"]}
    hostile = {"--hidden-widths": ["0", "-4", "a,b", "", "1000000000", "8,,8", "1e3"], "--activation": ["nope", ""],
               "--history": ["1000000000", "-1"], "--ensemble-size": ["1000000000", "0"], "--threads": ["0", "100000"],
               "--learning-rate": ["1e30", "nan", "-1"], "--max-epochs": ["0", "-3"], "--validation-fraction": ["1", "0"]}
    bad_data = world["root"] / "mutated.npz"
    original = world["data"].read_bytes()
    for i in range(40):
        n_hostile = _n_hostile(rng)
        where = int(rng.integers(3)) if n_hostile else -1  # 0: the dataset, 1: the output, 2: --test-data
        dataset = world["data"]
        if where == 0:
            bad_data.write_bytes(mutate_bytes(rng, original))
            dataset = pick(rng, [bad_data, world["root"] / "missing.npz", world["root"] / "folder", world["precious"]])
        argv = ["fit-model", str(dataset), _paths(world, rng, f"m{i}", where == 1), "--no-progress"]
        if where == 2 or rng.random() < 0.2:
            argv += ["--test-data", str(pick(rng, [world["data_dt2"], world["precious"], world["root"] / "x.npz"]) if where == 2 else world["data"])]
        argv += _options(rng, sane, hostile, max(0, n_hostile - (where >= 0)))
        if "--max-epochs" not in argv:
            argv += ["--max-epochs", "2"]
        run_cli("softpend fit-model", argv, [world["precious"], world["data"]])
    assert not OTHER["softpend fit-model"], OTHER["softpend fit-model"]


def test_fuzz_train(world):
    rng = np.random.default_rng([SEED, 3])
    # hostile values are invalid, or large enough to be refused by the size estimates (never merely slow)
    rl_fields = {"learning_rate": ["0", "-1", "1e30", "nan"], "buffer_size": ["0", "1e15", "null"],
                 "batch_size": ["0", "1e12", "[1]"], "gamma": ["1.5", "-0.1", "nan"], "net_arch": ["[]", "[0]", "[1e400]", "[100000000]", "{}"],
                 "episode_s": ["1e-9", "0", "1e12", "inf"], "eval_seeds": ["[]", "[-1]", "[null]", "[[1]]"],
                 "eval_duration_s": ["0", "1e12", "-1"], "action_repeat": ["0", "2.5"], "n_torque_levels": ["1", "0", "x"],
                 "training_start": ["sideways", "5"], "task.rod.n_links": ["0", "100000", "1e30", "2.5"],
                 "task.rod.mass_kg": ["0", "-1", "nan"], "task.dt_s": ["0", "-0.01", "x"], "task.substeps": ["0", "1e9"],
                 "task.plant": ["nope", "5"], "train_freq": ["0", "7"], "no_such_field": ["1"], "task.no_field": ["1"],
                 "clip_q_targets": ["1", "yes"], "exploration_fraction": ["2"], "model_buffer_size": ["0", "1e15"]}
    pilco_fields = {"horizon_s": ["0", "1e12", "nan"], "max_gp_points": ["5", "1e6"], "n_basis": ["0", "1e9"], "state": ["nope"],
                    "control_dt_s": ["0.015", "0"], "eval_seeds": ["[-1]", "[null]"], "cost_width_m": ["0", "-1"],
                    "n_random_trials": ["0"], "eval_duration_s": ["1e12"], "task.rod.n_links": ["100000"], "seed": ["x"]}
    for i in range(30):
        algo = pick(rng, ["dqn", "dqn", "mbpo", "pilco"])
        n_hostile = _n_hostile(rng)
        out_hostile = n_hostile > 0 and rng.random() < 0.25
        argv = ["train", "--algo", algo, "--out", _paths(world, rng, f"r{i}", out_hostile), "--no-progress", "--episodes", "1"]
        argv += TINY_PILCO if algo == "pilco" else TINY_RL
        if algo == "mbpo":
            argv += ["--set", "initial_random_episodes=1", "--set", "model_fit_steps=5", "--set", "ensemble_size=1"]
        fields = pilco_fields if algo == "pilco" else rl_fields
        for _ in range(n_hostile - out_hostile):
            kind = rng.random()
            if kind < 0.7:
                name = pick(rng, sorted(fields))
                argv += ["--set", f"{name}={pick(rng, fields[name])}"]
            elif kind < 0.8:
                argv += ["--set", pick(rng, ["=1", "a b=1", "1x=2", "task..rod=1", "noequals"])]
            elif kind < 0.9:
                argv += [pick(rng, ["--torque-limit-nm", "--n-links", "--seed", "--episodes"]), pick(rng, HOSTILE_NUMBERS)]
            else:
                argv += ["--resume"]
        run_cli("softpend train", argv, [world["precious"], world["run"] / "config.json"])
    assert not OTHER["softpend train"], OTHER["softpend train"]


def test_fuzz_evaluate(world):
    rng = np.random.default_rng([SEED, 4])
    mutated = world["root"] / "mutated_run"
    for i in range(40):
        n_hostile = _n_hostile(rng)
        agent = world["run"]
        if n_hostile and rng.random() < 0.5:
            n_hostile -= 1
            shutil.rmtree(mutated, ignore_errors=True)
            shutil.copytree(world["run"], mutated)
            roll = rng.random()
            if roll < 0.4:
                path = mutated / "agent.zip"
                path.write_bytes(mutate_bytes(rng, path.read_bytes()))
            elif roll < 0.8:
                path = mutated / "config.json"
                path.write_text(json.dumps(mutate_json(rng, json.loads(path.read_text()))))
            agent = pick(rng, [mutated, mutated / "agent.zip", world["precious"], world["root"] / "folder", world["root"] / "missing"])
        seeds = [pick(rng, ["0", "1", "7", str(2**70)]) for _ in range(int(rng.integers(1, 3)))]
        duration = pick(rng, ["0.2", "0.3"])
        if n_hostile:
            if rng.random() < 0.5:
                seeds[0] = pick(rng, ["-1", "x", "", "1.5"])
            else:
                duration = pick(rng, ["0", "-1", "nan", "inf", "1e12", "0.001", "x"])
        argv = ["evaluate", str(agent), "--which", pick(rng, ["best", "final"]), "--seeds", *seeds, "--duration-s", duration]
        if rng.random() < 0.5:
            argv.append("--json")
        run_cli("softpend evaluate", argv, [world["precious"], world["run"] / "agent.zip"])
    assert not OTHER["softpend evaluate"], OTHER["softpend evaluate"]


def test_fuzz_book_arguments(world):
    """``softpend book`` arguments that must be refused before a notebook runs (no kernel starts)."""
    rng = np.random.default_rng([SEED, 5])
    repo = Path(__file__).resolve().parents[1]
    for _ in range(15):
        argv = ["book", "--root", str(pick(rng, [repo, repo, world["root"], world["precious"], world["root"] / "missing"]))]
        argv += ["--profile", pick(rng, ["quick", "nope", ""])]
        argv += ["--only", pick(rng, ["fig02_reward", "fig99", "", "../etc/passwd"])]
        argv += ["--set", pick(rng, ["no_such_parameter=1", "=1", "x", "n_pointz=3"])]
        run_cli("softpend book", argv, [world["precious"]])
    # a few executions of the reward figure (a kernel each) with random parameters, valid or not
    book = world["root"] / "book_root"
    (book / "notebooks").mkdir(parents=True)
    (book / "book").mkdir()
    (book / "_toc.yml").write_text("format: jb-book\nroot: book/intro\nparts:\n  - caption: F\n    chapters:\n"
                                   "      - file: book/_generated/fig02_reward\n")
    (book / "book" / "profiles.yml").write_text(json.dumps({"quick": {}}))
    shutil.copy(repo / "notebooks" / "fig02_reward.md", book / "notebooks" / "fig02_reward.md")
    for k in range(3):
        points = ["3", "50"] if k == 0 else ["3", "50", "0", "-5", "1e12", "x"]
        steps = ["0.01", "0.05"] if k == 0 else ["0.01", "0.05", "-0.01", "0", "1e-300", "1"]
        argv = ["book", "--root", str(book), "--profile", "quick", "--force",
                "--set", f"n_points={pick(rng, points)}", "--set", f"dt_s={pick(rng, steps)}"]
        run_cli("softpend book", argv, [world["precious"]])
    assert not OTHER["softpend book"], OTHER["softpend book"]


# ------------------------------------------------------------------------------------------------ loaders
def test_fuzz_load_dataset(world):
    from softpend.sysid import load_dataset

    rng = np.random.default_rng([SEED, 6])
    original = world["data"].read_bytes()
    with zipfile.ZipFile(io.BytesIO(original)) as archive:
        metadata = json.loads(str(np.load(io.BytesIO(archive.read("metadata.npy")))[()]))
    path = world["root"] / "fuzz_dataset.npz"
    for i in range(300):
        kind = i % 3
        if kind == 0:
            data = mutate_bytes(rng, original)
        elif kind == 1:
            changed = json.dumps(mutate_json(rng, metadata))
            data = rewrite_zip(original, lambda name, member: _npy(np.array(changed)) if name == "metadata.npy" else member)
        else:
            target = pick(rng, ["positions.npy", "velocities.npy", "torques_nm.npy", "true_observations.npy", "extra.npy"])
            array = pick(rng, [np.zeros((3, 10, 5)), np.full((3, 9), np.nan), np.zeros((2,), dtype=np.int8),
                               np.array(["x"]), np.zeros((3, 10, 5), dtype=np.float32), np.zeros(0), np.array(np.inf)])
            data = rewrite_zip(original, lambda name, member: _npy(array) if name == target else member)
            if target == "extra.npy":
                data = _add_member(data, "extra.npy", _npy(array))
        path.write_bytes(data)
        run_call("load_dataset", lambda: load_dataset(path), _finite_dataset, label=f"case {i}")
    assert not OTHER["load_dataset"], OTHER["load_dataset"]


def _npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def _add_member(data: bytes, name: str, member: bytes) -> bytes:
    out = io.BytesIO(data)
    with zipfile.ZipFile(out, "a") as archive:
        archive.writestr(name, member)
    return out.getvalue()


def _finite_dataset(dataset) -> None:
    assert np.all(np.isfinite(dataset.positions)) and math.isfinite(dataset.dt_s)


def test_fuzz_load_agent(world):
    from softpend.rl.dqn import load_agent

    rng = np.random.default_rng([SEED, 7])
    folder = world["root"] / "fuzz_agent"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    shutil.copy(world["run"] / "config.json", folder / "config.json")
    original = (world["run"] / "agent.zip").read_bytes()
    with zipfile.ZipFile(io.BytesIO(original)) as archive:
        data = json.loads(archive.read("data"))
    marker = world["root"] / "pwned"
    for i in range(120):
        kind = i % 3
        if kind == 0:
            blob = mutate_bytes(rng, original)
        elif kind == 1:
            changed = mutate_json(rng, data)
            if rng.random() < 0.3:
                changed = dict(changed, **{pick(rng, ["env", "policy", "evil", "lr_schedule"]): {":serialized:": "gARLAS4="}})
            blob = rewrite_zip(original, lambda name, member: json.dumps(changed).encode() if name == "data" else member)
        else:
            import torch

            state = {"q_net.q_net.0.weight": pick(rng, [torch.zeros(3), torch.full((256, 11), math.nan), torch.zeros((256, 11), dtype=torch.int64)])}
            buffer = io.BytesIO()
            torch.save(state, buffer)
            blob = rewrite_zip(original, lambda name, member: buffer.getvalue() if name == "policy.pth" else member)
        (folder / "agent.zip").write_bytes(blob)
        run_call("load_agent", lambda: load_agent(folder, which="final"), label=f"case {i}")
    assert not marker.exists()
    assert not OTHER["load_agent"], OTHER["load_agent"]


def test_fuzz_load_model_config_and_log(world):
    from softpend.rl.config import load_config
    from softpend.rl.training_log import TrainingLog
    from softpend.sysid import load_model

    rng = np.random.default_rng([SEED, 8])
    pt, meta = (world["model"].with_name("model.pt").read_bytes(), json.loads(world["model"].with_name("model.json").read_text()))
    config = json.loads((world["run"] / "config.json").read_text())
    log = json.loads((world["run"] / "log.json").read_text())
    target = world["root"] / "fuzz_model"
    for i in range(100):
        if i % 2:
            target.with_name("fuzz_model.pt").write_bytes(pt)
            target.with_name("fuzz_model.json").write_text(json.dumps(mutate_json(rng, meta)))
        else:
            target.with_name("fuzz_model.pt").write_bytes(mutate_bytes(rng, pt))
            target.with_name("fuzz_model.json").write_text(json.dumps(meta))
        run_call("load_model", lambda: load_model(target), label=f"case {i}")
    for i in range(80):
        path = world["root"] / "fuzz_config.json"
        path.write_text(json.dumps(mutate_json(rng, config)) if i % 4 else mutate_bytes(rng, json.dumps(config).encode()).decode("latin-1"))
        run_call("load_config", lambda: load_config(path), label=f"case {i}")
    for i in range(40):
        path = world["root"] / "fuzz_log.json"
        path.write_text(json.dumps(mutate_json(rng, log)))
        run_call("TrainingLog.load", lambda: TrainingLog.load(path), label=f"case {i}")
    for entry in ("load_model", "load_config", "TrainingLog.load"):
        assert not OTHER[entry], OTHER[entry]


# ------------------------------------------------------------------------------------------------ environments
def test_fuzz_environments():
    from softpend.envs import SoftPendulumDiscreteEnv, SoftPendulumEnv

    rng = np.random.default_rng([SEED, 9])
    sane = {"dt_s": [0.01, 0.02], "substeps": [1, 2], "torque_limit_nm": [0.06, 0.03], "start": ["hanging", "upright", "random"],
            "start_noise_rad": [0.05, 0.0], "plant": ["prb"]}
    hostile = {"dt_s": [0.0, -0.01, math.nan, 1e-300, 1e300, "x", None], "substeps": [0, 2.5, 10**9, True],
               "torque_limit_nm": [0.0, -1.0, math.inf, 1e300, "x"], "start": ["sideways", 3, None],
               "start_noise_rad": [-1.0, math.nan, 1e300], "plant": ["nope", None, 5], "n_torque_levels": [1, 0, 2.5, "x", 10**12]}
    actions_discrete = [0, 4, np.int64(2), np.array([1]), 2.7, [1, 2], -1, 5, True, None, "1", np.array([1.0]), math.nan]
    actions_continuous = [0.0, 1.0, -1.0, 5.0, np.array([0.3], dtype=np.float32), math.nan, math.inf, None, "x", [1, 2], [[0.1]]]
    for i in range(60):
        discrete = bool(i % 2)
        kwargs = {k: pick(rng, v) for k, v in sane.items() if rng.random() < 0.4}
        if discrete and rng.random() < 0.3:
            kwargs["n_torque_levels"] = pick(rng, [2, 3, 5])
        if rng.random() < 0.5:
            name = pick(rng, sorted(hostile) if discrete else sorted(set(hostile) - {"n_torque_levels"}))
            kwargs[name] = pick(rng, hostile[name])
        cls = SoftPendulumDiscreteEnv if discrete else SoftPendulumEnv

        def make(cls=cls, kwargs=kwargs):
            env = cls(**kwargs)
            obs, _ = env.reset(seed=int(rng.integers(0, 1000)))
            assert np.all(np.isfinite(obs))
            return env

        try:
            with alarm(CASE_LIMIT_S):
                env = make()
        except (ValueError, OSError):
            record("env construction", "named error")
            continue
        except BaseException as exc:  # noqa: BLE001
            record("env construction", "other", f"{kwargs}: {type(exc).__name__}: {exc}")
            continue
        record("env construction", "legitimate")
        for _ in range(8):
            action = pick(rng, actions_discrete if discrete else actions_continuous)

            def step(env=env, action=action):
                obs, reward, terminated, truncated, info = env.step(action)
                assert np.all(np.isfinite(obs)) and math.isfinite(reward), (obs, reward)
                return obs

            run_call("env.step", step, label=f"{kwargs} {action!r}")
    for entry in ("env construction", "env.step"):
        assert not OTHER[entry], OTHER[entry]


# ------------------------------------------------------------------------------------------------ --set parsing
def test_fuzz_set_parsing():
    from softpend.io.overrides import apply_overrides, parse_assignment
    from softpend.pilco.loop import PilcoConfig
    from softpend.rl.config import DQNConfig, MBPOConfig

    rng = np.random.default_rng([SEED, 10])
    alphabet = list("abcdefghijklmnopqrstuvwxyz_.=0123456789 []{}\",-+e\u00e9\u2603")
    bases = [DQNConfig(), MBPOConfig(), PilcoConfig()]
    for i in range(500):
        base = pick(rng, bases)
        if i % 2:
            fields = [f.name for f in dataclasses.fields(base)] + ["task.rod.n_links", "task.dt_s", "task.plant", "nope"]
            text = f"{pick(rng, fields)}={json.dumps(pick(rng, HOSTILE_JSON)) if rng.random() < 0.7 else pick(rng, HOSTILE_NUMBERS)}"
        else:
            text = "".join(pick(rng, alphabet) for _ in range(int(rng.integers(0, 30))))

        def parse_and_apply(text=text, base=base):
            name, value = parse_assignment(text)
            return apply_overrides(base, {name: value})

        run_call("--set parsing", parse_and_apply, label=repr(text))
    assert not OTHER["--set parsing"], OTHER["--set parsing"]


def test_fuzz_summary(capsys):
    """Print the counts per entry point (run with ``-s`` to see them); nothing fell outside the two classes."""
    with capsys.disabled():
        print("\nfuzz outcomes per entry point (tried / named error / legitimate / other)")
        for entry, c in COUNTS.items():
            print(f"  {entry:<22} {c['tried']:>4} / {c['named error']:>4} / {c['legitimate']:>4} / {c['other']:>2}")
    assert all(c["other"] == 0 for c in COUNTS.values()), dict(OTHER)
