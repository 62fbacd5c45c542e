"""Property-based fuzz (Hypothesis) of the commands, the file loaders, ``--set`` parsing and the environments.

Hypothesis draws hostile values for every command-line option and config field -- non-finite, huge, negative,
tiny, zero, the wrong type, empty, unicode -- and hostile files where a file is named: a FIFO, a folder,
``/dev/zero``, a dangling symbolic link, a link to a FIFO, an empty or garbage file, a name in unicode, a file
that is not the command's.  The draws are reproducible (``derandomize=True``: the same cases every run) and
bounded (``max_examples`` per test), so that the whole file stays well inside ``make test``'s time;
``SOFTPEND_FUZZ_EXPLORE=1`` draws fresh cases with ten times as many examples.

Each case ends in one of two outcome classes -- a *named error* (a command: exit status 2, or 1 for a failed
check or a safe stop, with at most one line on stderr and no traceback; a function: ``ValueError`` or
``OSError``) or a *legitimate result* (exit 0 with valid JSON where JSON is printed; a loaded object; finite
observations and rewards) -- and never anything else: no other exception, no traceback, no hang (every case
runs under an alarm), no NaN in printed JSON and no file lost (a file the command did not write keeps its
bytes, a FIFO stays a FIFO).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import itertools
import json
import math
import os
import re
import shutil
import stat
import traceback
import warnings
import zipfile
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support import alarm

from softpend.cli import main

EXPLORE = os.environ.get("SOFTPEND_FUZZ_EXPLORE") == "1"
CASE_LIMIT_S = 30.0


def fuzz_settings(max_examples: int) -> settings:
    """Reproducible (derandomised), bounded settings; no example database, no deadline (the alarm guards)."""
    return settings(
        max_examples=max_examples * (10 if EXPLORE else 1),
        derandomize=not EXPLORE,
        database=None,
        deadline=None,
        print_blob=False,
        suppress_health_check=[
            HealthCheck.function_scoped_fixture,
            HealthCheck.too_slow,
            HealthCheck.data_too_large,
            HealthCheck.filter_too_much,
        ],
    )


# ------------------------------------------------------------------------------------------------ strategies
#: Numbers as a command line spells them: non-finite, huge, negative, tiny, zero.
NON_FINITE = st.sampled_from(["nan", "inf", "-inf", "NaN", "1e400", "-1e400"])
HUGE = st.one_of(
    st.floats(min_value=1e9, max_value=1e308).map(repr), st.integers(min_value=10**9, max_value=10**40).map(str)
)
NEGATIVE = st.one_of(
    st.floats(min_value=-1e308, max_value=-1e-300).map(repr), st.integers(min_value=-(10**30), max_value=-1).map(str)
)
TINY = st.floats(min_value=1e-300, max_value=1e-9).map(repr)
ZERO = st.sampled_from(["0", "-0.0", "0.0", "0e5"])
#: Values of the wrong type, empty values and unicode.
WRONG_TYPE = st.sampled_from(["abc", "[1]", "{}", "null", "true", "1,2", "0x10", "1_000", "1e", ".", "--"])
EMPTY = st.sampled_from(["", " ", "\t"])
UNICODE = st.text(alphabet=st.characters(blacklist_categories=("Cs", "Cc")), min_size=1, max_size=12)
#: Any hostile value of a numeric option.
HOSTILE_NUMBER = st.one_of(NON_FINITE, HUGE, NEGATIVE, TINY, ZERO, WRONG_TYPE, EMPTY, UNICODE)
#: Any hostile value of a text option (a list of names, an activation, ...).
HOSTILE_TEXT = st.one_of(EMPTY, UNICODE, WRONG_TYPE, st.sampled_from(["0", "-4", "a,b", "8,,8", "1e3", "nope"]), HUGE)

#: JSON values: scalars of every type, non-finite spellings, and nested containers.
JSON_SCALAR = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**40), max_value=10**40),
    st.floats(allow_nan=False, allow_infinity=False),
    st.text(max_size=8),
    st.sampled_from(["nan", "1e400", "prb", "beam", "random", ""]),
)
HOSTILE_JSON = st.recursive(
    JSON_SCALAR,
    lambda inner: st.one_of(st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=8,
)

#: Special files, each built once by the ``special`` fixture.
SPECIAL_KINDS = (
    "fifo",
    "folder",
    "dev_zero",
    "dev_null",
    "dangling_link",
    "link_to_fifo",
    "missing",
    "unicode_missing",
    "empty",
    "garbage",
    "below_a_file",
    "precious",
)
SPECIAL = st.sampled_from(SPECIAL_KINDS)


def hostile_value(kind: str) -> st.SearchStrategy:
    return {"number": HOSTILE_NUMBER, "text": HOSTILE_TEXT}[kind]


# ------------------------------------------------------------------------------------------------ outcomes
def _strict_json(text: str) -> Any:
    def refuse(constant: str):
        raise ValueError(f"non-JSON constant {constant}")

    return json.loads(text, parse_constant=refuse)


def _snapshot(paths: list[Path]) -> dict[Path, Any]:
    """What must not change: the bytes of regular files, the kind of special files."""
    state: dict[Path, Any] = {}
    for path in paths:
        info = os.lstat(path) if os.path.lexists(path) else None
        if info is None:
            continue
        state[path] = path.read_bytes() if stat.S_ISREG(info.st_mode) else stat.S_IFMT(info.st_mode)
    return state


def run_cli(argv: list[str], guarded: list[Path]) -> None:
    """Run ``softpend argv`` in-process and assert an outcome of the two classes; ``guarded`` files keep their
    bytes (and special files their kind)."""
    before = _snapshot(guarded)
    out, err = io.StringIO(), io.StringIO()
    try:
        with (
            alarm(CASE_LIMIT_S),
            contextlib.redirect_stdout(out),
            contextlib.redirect_stderr(err),
            warnings.catch_warnings(record=True) as caught,
        ):
            warnings.simplefilter("always", RuntimeWarning)
            rc = main(argv)
    except BaseException as exc:  # noqa: BLE001 - anything escaping main is the outcome under test
        raise AssertionError(f"softpend {argv}: {type(exc).__name__}: {exc}") from exc
    # a result computed through an overflow is silent garbage, not a legitimate result
    overflows = [
        str(w.message)
        for w in caught
        if issubclass(w.category, RuntimeWarning) and re.search(r"overflow|invalid value", str(w.message))
    ]
    assert rc != 0 or not overflows, f"softpend {argv}: exit 0 after {overflows[:3]}"
    assert _snapshot(guarded) == before, f"softpend {argv}: changed a file it did not write"
    stderr, stdout = err.getvalue(), out.getvalue()
    assert "Traceback" not in stderr, f"softpend {argv}: {stderr[-600:]}"
    # progress bars (tqdm: carriage returns, "NN%|") and the rig's pty line are not messages
    lines = [line.split("\r")[-1] for line in stderr.split("\n")]
    lines = [line for line in lines if line.strip() and not re.search(r"\d+%\|", line)]
    if rc == 2 or (rc == 1 and lines):
        assert len(lines) == 1 and "error" in lines[0], f"softpend {argv}: rc={rc} stderr={stderr[-600:]!r}"
        return
    assert rc in (0, 1) and not lines, f"softpend {argv}: rc={rc} stderr={stderr[-600:]!r}"
    text = stdout.strip()
    if text.startswith("{"):
        _strict_json(text[: text.rindex("}") + 1])


def run_call(call: Callable[[], Any], check: Callable[[Any], None] | None = None, label: str = "") -> None:
    """Run a Python entry point: a named error (``ValueError``/``OSError``) or a result that passes ``check``."""
    try:
        with alarm(CASE_LIMIT_S):
            result = call()
    except (ValueError, OSError):
        return
    except BaseException as exc:  # noqa: BLE001
        where = traceback.extract_tb(exc.__traceback__)[-1]
        raise AssertionError(f"{label}: {type(exc).__name__}: {exc} (at {where.filename}:{where.lineno})") from exc
    if check is not None:
        check(result)


# ------------------------------------------------------------------------------------------------ fixtures
TINY_RL = [
    "--set",
    "episode_s=0.2",
    "--set",
    "eval_seeds=[0]",
    "--set",
    "eval_duration_s=0.2",
    "--set",
    "learning_starts=5",
    "--set",
    "learner.buffer_size=1000",
    "--set",
    "learner.net_arch=[16]",
]
MARKERS = [[0.15, 0.1], [-0.15, 0.1], [0.15, -0.25], [-0.15, -0.25]]
_COUNTER = itertools.count()


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> dict[str, Path]:
    """Files the fuzz reads: a tiny dataset, a tiny DQN run, a tiny model, a markers file, special files."""
    root = tmp_path_factory.mktemp("fuzz")
    paths = {
        "root": root,
        "data": root / "data.npz",
        "run": root / "run",
        "model": root / "model",
        "markers": root / "markers.json",
    }
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["babble", str(paths["data"]), "--n-trials", "3", "--trial-length-s", "0.1", "--no-progress"]) == 0
        assert (
            main(["train", "--algo", "dqn", "--episodes", "1", "--out", str(paths["run"]), "--no-progress", *TINY_RL])
            == 0
        )
        assert main(["fit-model", str(paths["data"]), str(paths["model"]), "--max-epochs", "2", "--no-progress"]) == 0
    paths["markers"].write_text(json.dumps(MARKERS))
    special = root / "special"
    special.mkdir()
    os.mkfifo(special / "fifo")
    (special / "folder").mkdir()
    (special / "dev_zero").symlink_to("/dev/zero")
    (special / "dev_null").symlink_to("/dev/null")
    (special / "dangling_link").symlink_to(special / "nowhere")
    (special / "link_to_fifo").symlink_to(special / "fifo")
    (special / "empty").write_bytes(b"")
    (special / "garbage").write_bytes(bytes(range(256)) * 4)
    (special / "precious").write_bytes(b"a file the commands did not write")
    (special / "a_file").write_text("not a folder")
    paths.update({kind: special / kind for kind in SPECIAL_KINDS})
    paths["missing"] = special / "missing.npz"
    paths["unicode_missing"] = special / "\u00fcn\u00efc\u00f6d\u00e9 \u2603.json"
    paths["below_a_file"] = special / "a_file" / "x"
    # (an empty file is not guarded: a crash-safe log may start in it, as in a file it created)
    paths["guarded"] = [paths[k] for k in ("fifo", "folder", "garbage", "precious", "data", "markers")] + [
        paths["run"] / "config.json",
        paths["run"] / "agent.zip",
        special / "a_file",
    ]
    return paths


def fresh(world, name: str) -> str:
    """A path no example has used."""
    return str(world["root"] / "out" / f"{next(_COUNTER)}-{name}")


# ------------------------------------------------------------------------------------------------ commands
#: command -> (base argv: cheap, legitimate settings; "{out}" a fresh output path, "{data}", "{run}", "{markers}"
#: the world's files), numeric options, text options, path options (each path option's position: its flag, or
#: an index into the base argv).
COMMANDS: dict[str, dict[str, Any]] = {
    "babble": {
        "argv": ["babble", "{out}.npz", "--n-trials", "1", "--trial-length-s", "0.05", "--no-progress"],
        "numbers": [
            "--n-trials",
            "--trial-length-s",
            "--dt-s",
            "--torque-std-fraction",
            "--torque-bandwidth-hz",
            "--feedback-trial-fraction",
            "--feedback-kp",
            "--feedback-kd",
            "--phi-noise-std-rad",
            "--tip-noise-std-m",
            "--er-noise-std-rad",
            "--camera-delay-steps",
            "--n-links",
            "--seed",
        ],
        "texts": ["--start"],
        "paths": [1],
    },
    "fit-model": {
        "argv": ["fit-model", "{data}", "{out}", "--max-epochs", "2", "--no-progress"],
        "numbers": [
            "--history",
            "--ensemble-size",
            "--max-epochs",
            "--batch-size",
            "--learning-rate",
            "--patience",
            "--validation-fraction",
            "--seed",
            "--threads",
        ],
        "texts": ["--hidden-widths", "--activation", "--information", "--velocity-source"],
        "paths": [1, 2, "--test-data"],
    },
    "identify": {
        "argv": ["identify", "{data}", "--max-iterations", "1", "--max-windows", "2", "--window-s", "0.05"],
        "numbers": ["--window-s", "--max-windows", "--max-iterations", "--seed"],
        "texts": ["--parameters"],
        "paths": [1, "--initial-params", "--out"],
    },
    "evaluate": {
        "argv": ["evaluate", "{run}", "--seeds", "0", "--duration-s", "0.2"],
        "numbers": ["--duration-s", "--seeds"],
        "texts": ["--which"],
        "paths": [1],
    },
    "train": {
        "argv": ["train", "--algo", "dqn", "--out", "{out}", "--episodes", "1", "--no-progress", *TINY_RL],
        "numbers": ["--seed", "--episodes", "--torque-limit-nm", "--n-links"],
        "texts": ["--algo"],
        "paths": ["--out"],
    },
    "rig control": {
        "argv": ["rig", "control", "lqr", "--twin", "--out", "{out}", "--duration", "0.2", "--no-progress"],
        "numbers": [
            "--duration",
            "--camera-fps",
            "--camera-latency-ms",
            "--max-blind-ms",
            "--tilt",
            "--start-noise",
            "--seed",
            "--latency-ms",
            "--counts-per-rev",
            "--n-links",
        ],
        "texts": ["--camera-effects", "--start", "--which"],
        "paths": [2, "--out"],
    },
    "rig design": {
        "argv": ["rig", "design", "--out", "{out}"],
        "numbers": ["--print-modulus-mpa"],
        "texts": [],
        "paths": ["--out"],
    },
    "rig check": {
        "argv": ["rig", "check", "--twin", "--rest-s", "0.1"],
        "numbers": ["--rest-s", "--push-fraction", "--counts-per-rev"],
        "texts": [],
        "paths": ["--out"],
    },
    "rig calibrate": {
        "argv": ["rig", "calibrate", "--twin", "--markers", "{markers}", "--out", "{out}.json"],
        "numbers": ["--seed"],
        "texts": ["--markers"],
        "paths": ["--markers", "--out"],
    },
    "rig": {
        "argv": ["rig", "--duration", "0.2"],
        "numbers": [
            "--duration",
            "--latency-ms",
            "--drop",
            "--garble",
            "--watchdog-ms",
            "--counts-per-rev",
            "--n-links",
            "--seed",
        ],
        "texts": [],
        "paths": ["--truth-log"],
    },
    "track": {
        "argv": ["track", "{out}.avi", "--out", "{out}.csv"],
        "numbers": ["--fps", "--min-area"],
        "texts": ["--markers"],
        "paths": [1, "--out", "--markers", "--calibration"],
    },
    "track --camera": {
        "argv": ["track", "--camera", "{out}.avi", "--out", "{out}.csv", "--duration", "0.2"],
        "numbers": ["--duration", "--camera-latency-ms", "--min-area"],
        "texts": ["--camera"],
        "paths": ["--camera", "--out"],
    },
}


def _fill(argv: list[str], world, out: str) -> list[str]:
    names = {"{out}": out, "{data}": str(world["data"]), "{run}": str(world["run"]), "{markers}": str(world["markers"])}
    filled = []
    for item in argv:
        for key, value in names.items():
            item = item.replace(key, value)
        filled.append(item)
    return filled


def _set(argv: list[str], option: Any, value: str) -> list[str]:
    """``argv`` with ``option`` (a flag, or an index of a positional) set to ``value``."""
    argv = list(argv)
    if isinstance(option, int):
        argv[option] = value
    elif option in argv:
        argv[argv.index(option) + 1] = value
    else:
        argv += [option, value]
    return argv


@st.composite
def hostile_command(draw, name: str, world) -> list[str]:
    """The base argv of command ``name`` with one or two options made hostile (a number, a text, a file)."""
    spec = COMMANDS[name]
    argv = _fill(spec["argv"], world, fresh(world, "o"))
    kinds = [k for k in ("numbers", "texts", "paths") if spec[k]]
    for _ in range(draw(st.integers(min_value=1, max_value=2))):
        kind = draw(st.sampled_from(kinds))
        option = draw(st.sampled_from(spec[kind]))
        if kind == "paths":
            value = str(world[draw(SPECIAL)])
        else:
            value = draw(hostile_value("number" if kind == "numbers" else "text"))
        argv = _set(argv, option, value)
    return argv


@pytest.mark.timeout(600, method="thread")
@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_fuzz_command(world, name):
    """Every command with hostile options and files: a named error or a legitimate result, never a traceback,
    a hang, invalid JSON or a lost file."""
    examples = {"train": 6, "rig control": 8, "rig check": 6, "rig calibrate": 5, "rig": 6}.get(name, 10)

    @fuzz_settings(examples)
    @given(argv=hostile_command(name, world))
    def case(argv):
        run_cli(argv, world["guarded"])

    case()


def _field_names(config: Any, prefix: str = "") -> list[str]:
    """Every field of a (nested) dataclass config by its dotted ``--set`` name."""
    names = []
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        names.append(prefix + f.name)
        if dataclasses.is_dataclass(value):
            names += _field_names(value, f"{prefix}{f.name}.")
    return names


@pytest.mark.timeout(600, method="thread")
@fuzz_settings(16)
@given(algo=st.sampled_from(["dqn", "mbpo"]), data=st.data())
def test_fuzz_train_set(world, algo, data):
    """``softpend train --set FIELD=VALUE`` with hostile JSON for every config field (nested ones included)."""
    from softpend.rl.config import DQNConfig, MBPOConfig

    config = DQNConfig() if algo == "dqn" else MBPOConfig()
    field = data.draw(st.sampled_from(_field_names(config) + ["no_such_field", "task.no_field"]))
    value = data.draw(st.one_of(HOSTILE_JSON.map(json.dumps), HOSTILE_NUMBER))
    argv = [
        "train",
        "--algo",
        algo,
        "--out",
        fresh(world, "r"),
        "--episodes",
        "1",
        "--no-progress",
        *TINY_RL,
        "--set",
        f"{field}={value}",
    ]
    if algo == "mbpo":
        argv += ["--set", "initial_random_episodes=1", "--set", "model.fit_steps=5", "--set", "model.ensemble_size=1"]
    run_cli(argv, world["guarded"])


@pytest.mark.timeout(600, method="thread")
@fuzz_settings(10)
@given(data=st.data())
def test_fuzz_rod_fields(world, data):
    """``softpend rig design --set FIELD=VALUE`` with hostile JSON for every RodParams field."""
    from softpend.plant import RodParams

    field = data.draw(st.sampled_from(_field_names(RodParams()) + ["no_such_field"]))
    value = data.draw(st.one_of(HOSTILE_JSON.map(json.dumps), HOSTILE_NUMBER))
    run_cli(["rig", "design", "--out", fresh(world, "d"), "--set", f"{field}={value}"], world["guarded"])


# ------------------------------------------------------------------------------------------------ loaders
def _npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, array, allow_pickle=True)
    return buffer.getvalue()


def _rewrite_zip(data: bytes, change: Callable[[str, bytes], bytes], extra: dict[str, bytes] | None = None) -> bytes:
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        members = [(info.filename, archive.read(info)) for info in archive.infolist()]
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, member in members:
            archive.writestr(name, change(name, member))
        for name, member in (extra or {}).items():
            archive.writestr(name, member)
    return out.getvalue()


@st.composite
def mutated_bytes(draw, data: bytes) -> bytes:
    """``data`` with bits flipped, truncated, or a run overwritten."""
    kind = draw(st.sampled_from(["flip", "truncate", "overwrite"]))
    buf = bytearray(data)
    if kind == "flip":
        for i in draw(st.lists(st.integers(min_value=0, max_value=len(buf) - 1), min_size=1, max_size=16)):
            buf[i] ^= 1 << draw(st.integers(min_value=0, max_value=7))
        return bytes(buf)
    if kind == "truncate":
        return bytes(buf[: draw(st.integers(min_value=0, max_value=len(buf) - 1))])
    i = draw(st.integers(min_value=0, max_value=len(buf) - 1))
    run = draw(st.binary(min_size=1, max_size=64))
    buf[i : i + len(run)] = run
    return bytes(buf)


@st.composite
def mutated_json(draw, value: Any, depth: int = 0) -> Any:
    """``value`` with one entry (at any depth) replaced by hostile JSON, or deleted."""
    if isinstance(value, dict) and value and (depth == 0 or draw(st.booleans())):
        key = draw(st.sampled_from(sorted(value, key=str)))
        out = dict(value)
        if draw(st.integers(min_value=0, max_value=6)) == 0:
            del out[key]
        else:
            out[key] = draw(mutated_json(value[key], depth + 1))
        return out
    if isinstance(value, list) and value and draw(st.booleans()):
        i = draw(st.integers(min_value=0, max_value=len(value) - 1))
        return value[:i] + [draw(mutated_json(value[i], depth + 1))] + value[i + 1 :]
    return draw(HOSTILE_JSON)


HOSTILE_ARRAYS = st.sampled_from(
    [
        np.zeros((3, 10, 5)),
        np.full((3, 9), np.nan),
        np.zeros((2,), dtype=np.int8),
        np.array(["x"]),
        np.zeros((3, 10, 5), dtype=np.float32),
        np.zeros(0),
        np.array(np.inf),
        np.array([{"a": 1}], dtype=object),
    ]
)


def _finite_dataset(dataset) -> None:
    assert np.all(np.isfinite(dataset.positions)) and math.isfinite(dataset.dt_s)


@pytest.mark.timeout(600, method="thread")
@fuzz_settings(120)
@given(data=st.data())
def test_fuzz_load_dataset(world, data):
    from softpend.sysid import load_dataset

    original = world["data"].read_bytes()
    kind = data.draw(st.sampled_from(["bytes", "metadata", "member", "extra", "pickle"]))
    if kind == "bytes":
        blob = data.draw(mutated_bytes(original))
    elif kind == "metadata":
        with zipfile.ZipFile(io.BytesIO(original)) as archive:
            metadata = json.loads(str(np.load(io.BytesIO(archive.read("metadata.npy")))[()]))
        text = json.dumps(data.draw(mutated_json(metadata)))
        blob = _rewrite_zip(original, lambda name, member: _npy(np.array(text)) if name == "metadata.npy" else member)
    elif kind in ("member", "extra"):
        target = data.draw(st.sampled_from(["positions.npy", "velocities.npy", "torques_nm.npy", "metadata.npy"]))
        array = data.draw(HOSTILE_ARRAYS)
        blob = _rewrite_zip(
            original,
            lambda name, member: _npy(array) if name == target and kind == "member" else member,
            {"extra.npy": _npy(array)} if kind == "extra" else None,
        )
    else:
        target = data.draw(st.sampled_from(["positions.npy", "metadata.npy"]))
        payload = data.draw(st.binary(max_size=64))
        blob = _rewrite_zip(original, lambda name, member: payload if name == target else member)
    path = world["root"] / "fuzz_dataset.npz"
    path.write_bytes(blob)
    run_call(lambda: load_dataset(path), _finite_dataset, label=kind)


@pytest.mark.timeout(600, method="thread")
@fuzz_settings(25)
@given(data=st.data())
def test_fuzz_load_agent(world, data):
    from softpend.rl.dqn import load_agent

    folder = world["root"] / "fuzz_agent"
    if not folder.exists():
        folder.mkdir()
        shutil.copy(world["run"] / "config.json", folder / "config.json")
    original = (world["run"] / "agent.zip").read_bytes()
    kind = data.draw(st.sampled_from(["bytes", "data", "pickled", "weights", "huge"]))
    if kind == "bytes":
        blob = data.draw(mutated_bytes(original))
    elif kind in ("data", "pickled"):
        with zipfile.ZipFile(io.BytesIO(original)) as archive:
            saved = json.loads(archive.read("data"))
        changed = data.draw(mutated_json(saved))
        if kind == "pickled":
            entry = data.draw(st.sampled_from(["env", "policy", "evil", "lr_schedule"]))
            changed = dict(changed, **{entry: {":serialized:": "gARLAS4="}})
        blob = _rewrite_zip(original, lambda name, member: json.dumps(changed).encode() if name == "data" else member)
    elif kind == "weights":
        import torch

        state = {
            "q_net.q_net.0.weight": data.draw(
                st.sampled_from(
                    [torch.zeros(3), torch.full((16, 11), math.nan), torch.zeros((16, 11), dtype=torch.int64)]
                )
            )
        }
        buffer = io.BytesIO()
        torch.save(state, buffer)
        blob = _rewrite_zip(original, lambda name, member: buffer.getvalue() if name == "policy.pth" else member)
    else:  # a member far beyond the network's size (zeros compress a thousandfold)
        blob = _rewrite_zip(original, lambda name, member: member, {"padding.bin": bytes(64 * 2**20)})
    (folder / "agent.zip").write_bytes(blob)
    marker = world["root"] / "pwned"
    run_call(lambda: load_agent(folder, which="final"), label=kind)
    assert not marker.exists()


@pytest.mark.timeout(600, method="thread")
@fuzz_settings(60)
@given(data=st.data())
def test_fuzz_json_loaders(world, data):
    """Every JSON loader on hostile documents and on mutated versions of the real ones."""
    from softpend.plant import RodParams
    from softpend.rl.config import load_config
    from softpend.rl.training_log import TrainingLog
    from softpend.sysid import load_model
    from softpend.vision.calibration import AffineCalibration

    which = data.draw(st.sampled_from(["config", "log", "model", "rod", "calibration"]))
    target = world["root"] / "fuzz_json"
    if which == "config":
        document = json.loads((world["run"] / "config.json").read_text())
        load: Callable[[], Any] = lambda: load_config(target)  # noqa: E731
    elif which == "log":
        document = json.loads((world["run"] / "log.json").read_text())
        load = lambda: TrainingLog.load(target)  # noqa: E731
    elif which == "model":
        document = json.loads(world["model"].with_name("model.json").read_text())
        shutil.copy(world["model"].with_name("model.pt"), target.with_suffix(".pt"))
        load = lambda: load_model(target.with_suffix(".json"))  # noqa: E731
    elif which == "rod":
        document = RodParams().to_dict()
        load = lambda: RodParams.from_json(target)  # noqa: E731
    else:
        document = {"pixel_to_metre": [[0.001, 0, -0.3], [0, -0.001, 0.2]], "residual_rms_m": 0.0}
        load = lambda: AffineCalibration.load(target)  # noqa: E731
    how = data.draw(st.sampled_from(["mutated", "hostile", "bytes"]))
    if how == "mutated":
        text = json.dumps(data.draw(mutated_json(document))).encode()
    elif how == "hostile":
        text = json.dumps(data.draw(HOSTILE_JSON)).encode()
    else:
        text = data.draw(mutated_bytes(json.dumps(document).encode()))
    for path in (target, target.with_suffix(".json")):
        path.write_bytes(text)
    run_call(load, label=f"{which} {how}")


#: File readers by name: each takes a path.
def _readers() -> dict[str, Callable[[Path], Any]]:
    from softpend.io.samplelog import read_sample_log
    from softpend.plant import RodParams
    from softpend.rl.config import load_config
    from softpend.rl.training_log import TrainingLog
    from softpend.study.presets import load_hparams  # noqa: F401 - the settings reader, through its folder below
    from softpend.sysid import load_dataset, load_model
    from softpend.vision.calibration import AffineCalibration, read_json_file

    return {
        "load_dataset": load_dataset,
        "load_config": load_config,
        "TrainingLog.load": TrainingLog.load,
        "RodParams.from_json": RodParams.from_json,
        "AffineCalibration.load": AffineCalibration.load,
        "read_json_file": lambda p: read_json_file("--markers", p, 10**6),
        "read_sample_log": read_sample_log,
        "load_model": load_model,
    }


@pytest.mark.timeout(600, method="thread")
@fuzz_settings(40)
@given(reader=st.sampled_from(sorted(_readers())), kind=SPECIAL)
def test_fuzz_readers_on_special_files(world, reader, kind):
    """Every reader on every special file: a named error (or, for an empty or garbage file, a refusal), never a
    hang on a FIFO or a read of /dev/zero until memory runs out."""
    run_call(lambda: _readers()[reader](world[kind]), label=f"{reader}({kind})")


# ------------------------------------------------------------------------------------------------ environments
ENV_SANE = {
    "dt_s": [0.01, 0.02],
    "substeps": [1, 2],
    "start": ["hanging", "upright", "random"],
    "start_noise_rad": [0.05, 0.0],
    "plant": ["prb"],
}
ENV_HOSTILE = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**12), max_value=10**12),
    st.none(),
    st.booleans(),
    st.text(max_size=6),
    st.sampled_from(["sideways", "nope"]),
)
ACTIONS = st.one_of(
    st.integers(min_value=-3, max_value=8),
    st.floats(allow_nan=True, allow_infinity=True),
    st.none(),
    st.text(max_size=3),
    st.booleans(),
    st.lists(st.floats(min_value=-2, max_value=2), max_size=2),
    st.sampled_from([np.int64(2), np.array([1]), np.array([0.3], dtype=np.float32), np.array([1.0])]),
)


@pytest.mark.timeout(600, method="thread")
@fuzz_settings(25)
@given(
    discrete=st.booleans(),
    sane=st.fixed_dictionaries({}, optional={k: st.sampled_from(v) for k, v in ENV_SANE.items()}),
    hostile_field=st.sampled_from(sorted(ENV_SANE) + ["n_torque_levels", None]),
    hostile=ENV_HOSTILE,
    actions=st.lists(ACTIONS, min_size=1, max_size=5),
    seed=st.integers(min_value=0, max_value=1000),
)
def test_fuzz_environments(discrete, sane, hostile_field, hostile, actions, seed):
    from softpend.envs import SoftPendulumDiscreteEnv, SoftPendulumEnv

    kwargs = dict(sane)
    if hostile_field is not None and (discrete or hostile_field != "n_torque_levels"):
        kwargs[hostile_field] = hostile
    cls = SoftPendulumDiscreteEnv if discrete else SoftPendulumEnv
    env = None

    def make():
        nonlocal env
        env = cls(**kwargs)
        obs, _ = env.reset(seed=seed)
        assert np.all(np.isfinite(obs))

    run_call(make, label=f"{cls.__name__}({kwargs})")
    if env is None:
        return
    for action in actions:

        def step(action=action):
            obs, reward, terminated, truncated, info = env.step(action)
            assert np.all(np.isfinite(obs)) and math.isfinite(reward), (obs, reward)

        run_call(step, label=f"{kwargs} step({action!r})")


# ------------------------------------------------------------------------------------------------ --set parsing
SET_TEXT = st.text(
    alphabet=st.sampled_from(list('abcdefghijklmnopqrstuvwxyz_.=0123456789 []{}",-+e\u00e9\u2603')), max_size=30
)


@pytest.mark.timeout(600, method="thread")
@fuzz_settings(150)
@given(base=st.sampled_from(["dqn", "mbpo", "pilco"]), data=st.data())
def test_fuzz_set_parsing(base, data):
    from softpend.io.overrides import apply_overrides, parse_assignment
    from softpend.pilco.loop import PilcoConfig
    from softpend.rl.config import DQNConfig, MBPOConfig

    config = {"dqn": DQNConfig, "mbpo": MBPOConfig, "pilco": PilcoConfig}[base]()
    if data.draw(st.booleans()):
        fields = [f.name for f in dataclasses.fields(config)] + ["task.rod.n_links", "task.dt_s", "task.plant", "nope"]
        name = data.draw(st.sampled_from(fields))
        value = data.draw(st.one_of(HOSTILE_JSON.map(json.dumps), HOSTILE_NUMBER))
        text = f"{name}={value}"
    else:
        text = data.draw(SET_TEXT)

    def parse_and_apply():
        name, value = parse_assignment(text)
        return apply_overrides(config, {name: value})

    run_call(parse_and_apply, label=repr(text))
