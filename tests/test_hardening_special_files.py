"""Special files and oversized files where a file is read: one named line, never a hang or a memory blow-up.

Every command's entry point runs (in-process, :func:`softpend.cli.main`) with a named pipe (FIFO) and with a
folder where it reads or writes a file -- under an alarm, so that a command that blocks on the FIFO fails the
test instead of hanging it -- and must end in one line ``softpend ...: error: ...`` naming the file.  The
checked reader itself (:mod:`softpend.io.reading`) refuses devices, FIFOs, folders and files over the
format's bound before it reads, and zip archives member by member from their directory.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from support import alarm, refused

from softpend.cli import main
from softpend.io.arrays import read_npz
from softpend.io.reading import (
    check_zip_members,
    open_regular_file,
    read_bytes_checked,
    read_json_checked,
    read_json_object,
    read_yaml_checked,
    read_zip_member,
)

ALARM_S = 60.0
TINY_PILCO = [
    "--set",
    "state=tip",
    "--set",
    "horizon_s=0.5",
    "--set",
    "prediction_s=null",
    "--set",
    "eval_seeds=[1000]",
    "--set",
    "eval_duration_s=0.5",
    "--set",
    "policy.n_basis=3",
    "--set",
    "gp.max_points=10",
    "--set",
    "gp.iterations=2",
    "--set",
    "optimiser.iterations=1",
    "--set",
    "compiled=false",
]
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


def assert_named_error(argv: list[str], *words: str) -> str:
    return refused(argv, "error", *words, codes=(1, 2))


# ------------------------------------------------------------------------------------------------ the reader
@pytest.fixture
def fifo(tmp_path) -> Path:
    path = tmp_path / "pipe"
    os.mkfifo(path)
    return path


@pytest.mark.timeout(120, method="thread")
def test_reader_refuses_fifo_folder_and_devices(tmp_path, fifo):
    with alarm(10):
        for path, kind in (
            (fifo, "named pipe"),
            (tmp_path, "folder"),
            (Path("/dev/zero"), "character device"),
            (Path("/dev/null"), "character device"),
        ):
            with pytest.raises(ValueError, match=kind) as info:
                read_bytes_checked(path, "config file", 100)
            assert str(path) in str(info.value) and "config file" in str(info.value)
        with pytest.raises(FileNotFoundError, match="config file"):
            read_bytes_checked(tmp_path / "missing", "config file", 100)
        dangling = tmp_path / "dangling"
        dangling.symlink_to(tmp_path / "nowhere")
        with pytest.raises(FileNotFoundError):
            read_bytes_checked(dangling, "config file", 100)
        to_fifo = tmp_path / "to_fifo"
        to_fifo.symlink_to(fifo)
        with pytest.raises(ValueError, match="named pipe"):
            read_json_checked(to_fifo, "config file")
        assert read_json_object(fifo, 100) is None and read_json_object(Path("/dev/zero"), 100) is None


def test_reader_bounds_size_and_follows_symlinks_to_regular_files(tmp_path):
    path = tmp_path / "a.json"
    path.write_text('{"a": 1}')
    link = tmp_path / "link.json"
    link.symlink_to(path)
    assert read_json_checked(link, "config file") == {"a": 1}
    assert read_bytes_checked(path, "x", 8) == b'{"a": 1}'
    with pytest.raises(ValueError, match="more than the 7"):
        read_bytes_checked(path, "x", 7)
    with open_regular_file(path, "x", 100) as handle:
        assert handle.read() == b'{"a": 1}'


def test_reader_reads_pseudo_files_with_the_bound():
    """A /proc file reports size 0 but has content: the read itself is bounded."""
    with pytest.raises(ValueError, match="more than the 10 bytes"):
        read_bytes_checked("/proc/self/status", "status", 10)


def test_json_and_yaml_errors_name_file_and_line(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{\n  "a": 1,\n  "b": \n}')
    with pytest.raises(ValueError, match=r"bad.json, line 4 column 1: not valid JSON"):
        read_json_checked(bad, "config file")
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000)
    with pytest.raises(ValueError, match="nested too deeply|not valid JSON"):
        read_json_checked(deep, "config file")
    latin = tmp_path / "latin.json"
    latin.write_bytes(b'{"a": "\xe9"}')
    with pytest.raises(ValueError, match="not UTF-8 text"):
        read_json_checked(latin, "config file")
    yml = tmp_path / "p.yml"
    yml.write_text("quick:\n  a: 1\n b: [\n")
    with pytest.raises(ValueError, match=r"p.yml, line \d+ column \d+: not valid YAML") as info:
        read_yaml_checked(yml, "profiles file")
    assert "\n" not in str(info.value)
    python = tmp_path / "python.yml"
    python.write_text("!!python/object/apply:os.system ['true']\n")
    with pytest.raises(ValueError, match="not valid YAML"):
        read_yaml_checked(python, "profiles file")


def _zip(members: dict[str, bytes]) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return out.getvalue()


def test_zip_members_bounded_from_the_directory(tmp_path):
    """A member that unpacks to more than its bound is refused before it is decompressed (5 GiB of zeros
    compress to a few MiB; here 64 MiB to 64 KiB)."""
    blob = _zip({"data": b"{}", "policy.pth": bytes(64 * 2**20)})
    assert len(blob) < 2**20
    with zipfile.ZipFile(io.BytesIO(blob)) as archive:
        with pytest.raises(ValueError, match="'policy.pth' would unpack to 67108864 bytes"):
            check_zip_members(archive, "agent.zip", "agent file", 2**20)
        with pytest.raises(ValueError, match="more than the 100 a agent file can have"):
            check_zip_members(archive, "agent.zip", "agent file", 2**27, 100)
        assert read_zip_member(archive, "data", "agent.zip", "agent file", 10) == b"{}"
        with pytest.raises(ValueError, match="more than the 10"):
            read_zip_member(archive, "policy.pth", "agent.zip", "agent file", 10)


# ------------------------------------------------------------------------------------------------ npz
def _npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, array, allow_pickle=True)
    return buffer.getvalue()


def test_read_npz_round_trip(tmp_path):
    arrays = {
        "c": np.arange(12.0).reshape(3, 4),
        "f": np.asfortranarray(np.arange(12).reshape(3, 4)),
        "s": np.array("h\u00e9llo"),
        "b": np.array(True),
        "e": np.zeros((0, 3)),
        "r": np.zeros(2, dtype=[("x", "<f4"), ("y", "<i8")]),
    }
    np.savez(tmp_path / "t.npz", **arrays)
    read = read_npz(tmp_path / "t.npz", "test file")
    assert sorted(read) == sorted(arrays)
    for name, array in arrays.items():
        assert read[name].dtype == array.dtype and read[name].shape == array.shape
        assert np.array_equal(read[name], array)
        assert read[name].flags.writeable


@pytest.mark.parametrize(
    "member, reason",
    [
        (pickle.dumps({"x": 1}), "not a .npy array"),
        (_npy(np.array([{"x": 1}], dtype=object)), "holds Python objects"),
        (_npy(np.zeros(4))[:-8], "declares shape"),
    ],
)
def test_read_npz_refuses_pickles_and_lying_headers(tmp_path, member, reason):
    path = tmp_path / "bad.npz"
    path.write_bytes(_zip({"positions.npy": _npy(np.zeros(3)), "metadata.npy": member}))
    with pytest.raises(ValueError, match=reason) as info:
        read_npz(path, "dataset file")
    assert "metadata.npy" in str(info.value) and str(path) in str(info.value)


def test_read_npz_refuses_a_header_that_asks_for_terabytes(tmp_path):
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, {"descr": "<f8", "fortran_order": False, "shape": (10**13,)})
    buffer.write(bytes(8))
    path = tmp_path / "huge.npz"
    path.write_bytes(_zip({"positions.npy": buffer.getvalue()}))
    with pytest.raises(ValueError, match="declares shape"):
        read_npz(path, "dataset file")


def test_read_npz_bounds_the_file_and_its_members(tmp_path):
    path = tmp_path / "big.npz"
    np.savez_compressed(path, x=np.zeros(2**20))  # 8 MiB unpacked, a few KiB packed
    with pytest.raises(ValueError, match="would unpack to"):
        read_npz(path, "dataset file", max_bytes=2**20)
    assert read_npz(path, "dataset file")["x"].shape == (2**20,)


# ------------------------------------------------------------------------------------------------ commands
@pytest.fixture(scope="module")
def world(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("special")
    quiet = contextlib.redirect_stdout(io.StringIO())
    with quiet:
        assert (
            main(["babble", str(root / "data.npz"), "--n-trials", "2", "--trial-length-s", "0.1", "--no-progress"]) == 0
        )
        assert (
            main(["train", "--algo", "dqn", "--episodes", "1", "--out", str(root / "run"), "--no-progress", *TINY_RL])
            == 0
        )
        assert (
            main(
                [
                    "train",
                    "--algo",
                    "pilco",
                    "--episodes",
                    "1",
                    "--out",
                    str(root / "pilco"),
                    "--no-progress",
                    *TINY_PILCO,
                ]
            )
            == 0
        )
    return {"root": root, "data": root / "data.npz", "run": root / "run", "pilco": root / "pilco"}


def _special(kind: str, path: Path) -> Path:
    if path.exists() or path.is_symlink():
        shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink()
    if kind == "fifo":
        os.mkfifo(path)
    else:
        path.mkdir()
    return path


def _run_with(world, tmp_path: Path, member: str) -> Path:
    """A copy of the tiny DQN run folder (the agent files only), or of the PILCO run for its files."""
    run = tmp_path / "run"
    source = world["pilco"] if member in ("pilco.json", "policy.pt") else world["run"]
    shutil.copytree(source, run, ignore=shutil.ignore_patterns("checkpoint"))
    return run


#: (name, argv builder(world, tmp, special path maker) -> argv, words the error line must hold)
def _cases():
    def simple(*argv):
        return lambda w, t, s: [str(a) if not callable(a) else a(w, t, s) for a in argv]

    special = lambda w, t, s: str(s(t / "x"))  # noqa: E731 - the special path itself
    data = lambda w, t, s: str(w["data"])  # noqa: E731

    def run_member(member):
        def build(w, t, s):
            run = _run_with(w, t, member)
            s(run / member)
            return str(run)

        return build

    return [
        ("fit-model DATASET", simple("fit-model", special, lambda w, t, s: str(t / "m"), "--no-progress"), ["x"]),
        (
            "fit-model --test-data",
            simple(
                "fit-model",
                data,
                lambda w, t, s: str(t / "m"),
                "--test-data",
                special,
                "--max-epochs",
                "1",
                "--no-progress",
            ),
            ["x"],
        ),
        ("identify DATASET", simple("identify", special), ["x"]),
        (
            "identify --initial-params",
            simple("identify", data, "--initial-params", special, "--max-iterations", "1"),
            ["x"],
        ),
        ("identify --out", simple("identify", data, "--out", special, "--max-iterations", "1"), ["x"]),
        (
            "babble OUTPUT",
            lambda w, t, s: [
                "babble",
                str(s(t / "x.npz")),
                "--n-trials",
                "1",
                "--trial-length-s",
                "0.05",
                "--no-progress",
            ],
            ["x.npz"],
        ),
        ("evaluate AGENT", simple("evaluate", special, "--seeds", "0", "--duration-s", "0.1"), ["x"]),
        (
            "evaluate config.json",
            lambda w, t, s: ["evaluate", run_member("config.json")(w, t, s), "--seeds", "0", "--duration-s", "0.1"],
            ["config.json"],
        ),
        (
            "evaluate agent.zip",
            lambda w, t, s: [
                "evaluate",
                run_member("agent.zip")(w, t, s),
                "--which",
                "final",
                "--seeds",
                "0",
                "--duration-s",
                "0.1",
            ],
            ["agent.zip"],
        ),
        (
            "evaluate best_agent.zip",
            lambda w, t, s: ["evaluate", run_member("best_agent.zip")(w, t, s), "--seeds", "0", "--duration-s", "0.1"],
            ["best_agent.zip"],
        ),
        (
            "train --resume config.json",
            lambda w, t, s: [
                "train",
                "--algo",
                "dqn",
                "--resume",
                "--episodes",
                "2",
                "--out",
                run_member("config.json")(w, t, s),
                "--no-progress",
                *TINY_RL,
            ],
            ["run"],
        ),
        (
            "rig control RUN (config.json)",
            lambda w, t, s: [
                "rig",
                "control",
                run_member("config.json")(w, t, s),
                "--twin",
                "--out",
                str(t / "o"),
                "--duration",
                "0.1",
                "--no-progress",
            ],
            ["config.json"],
        ),
        (
            "rig control PILCO (policy.pt)",
            lambda w, t, s: [
                "rig",
                "control",
                run_member("policy.pt")(w, t, s),
                "--twin",
                "--out",
                str(t / "o"),
                "--duration",
                "0.1",
                "--no-progress",
            ],
            ["policy.pt"],
        ),
        (
            "rig control PILCO (pilco.json)",
            lambda w, t, s: [
                "rig",
                "control",
                run_member("pilco.json")(w, t, s),
                "--twin",
                "--out",
                str(t / "o"),
                "--duration",
                "0.1",
                "--no-progress",
            ],
            ["run"],
        ),
        (
            "rig control --out",
            simple("rig", "control", "lqr", "--twin", "--out", special, "--duration", "0.1", "--no-progress"),
            ["x"],
        ),
        ("track VIDEO", simple("track", special, "--out", lambda w, t, s: str(t / "o.csv")), ["x"]),
        (
            "track --markers",
            simple(
                "track",
                lambda w, t, s: str(t / "v.avi"),
                "--markers",
                special,
                "--out",
                lambda w, t, s: str(t / "o.csv"),
            ),
            ["x"],
        ),
        (
            "track --calibration",
            simple(
                "track",
                lambda w, t, s: str(t / "v.avi"),
                "--calibration",
                special,
                "--out",
                lambda w, t, s: str(t / "o.csv"),
            ),
            ["x"],
        ),
        (
            "rig calibrate --markers",
            simple("rig", "calibrate", "--twin", "--markers", special, "--out", lambda w, t, s: str(t / "c.json")),
            ["x"],
        ),
        (
            "rig calibrate --camera",
            simple(
                "rig",
                "calibrate",
                "--camera",
                special,
                "--markers",
                "[[0.1, 0.1], [-0.1, 0.1], [0.1, -0.1]]",
                "--out",
                lambda w, t, s: str(t / "c.json"),
            ),
            ["x"],
        ),
        ("rig check --out", simple("rig", "check", "--twin", "--out", special, "--rest-s", "0.1"), ["x"]),
        (
            "rig calibrate --out",
            simple(
                "rig",
                "calibrate",
                "--twin",
                "--markers",
                "[[0.15, 0.1], [-0.15, 0.1], [0.15, -0.25], [-0.15, -0.25]]",
                "--out",
                special,
            ),
            ["x"],
        ),
        (
            "rig babble --out",
            simple(
                "rig",
                "babble",
                "--twin",
                "--out",
                special,
                "--duration",
                "3.2",
                "--trial-length-s",
                "0.1",
                "--no-progress",
            ),
            ["x"],
        ),
        (
            "rig control --port",
            simple(
                "rig",
                "control",
                "lqr",
                "--port",
                special,
                "--no-camera",
                "--out",
                lambda w, t, s: str(t / "o"),
                "--duration",
                "0.2",
                "--no-progress",
            ),
            ["x"],
        ),
        ("rig check --port", simple("rig", "check", "--port", special), ["x"]),
        ("sweep --runs-root", simple("sweep", "--seeds", "0", "--runs-root", special), ["x"]),
        ("book --root", simple("book", "--root", special, "--profile", "quick"), ["x"]),
        ("sweep --book --root", simple("sweep", "--book", "--root", special, "--profile", "quick"), ["x"]),
        (
            "rig design --out",
            lambda w, t, s: ["rig", "design", "--out", str(s(t / "x"))] if not (t / "x").exists() else [],
            ["x"],
        ),
        ("rig --truth-log", simple("rig", "--truth-log", special, "--duration", "0.2"), ["x"]),
    ]


CASES = _cases()


#: Options that take a folder: only a FIFO is a wrong kind of file for them.
FOLDER_OPTIONS = ("rig design --out", "rig control --out", "rig babble --out", "sweep --runs-root")
SPECIAL_CASES = [
    (kind, *case)
    for case in CASES
    for kind in ("fifo", "folder")
    if not (kind == "folder" and case[0] in FOLDER_OPTIONS)
]


@pytest.mark.timeout(600, method="thread")
@pytest.mark.parametrize("kind, name, build, words", SPECIAL_CASES, ids=[f"{c[1]}-{c[0]}" for c in SPECIAL_CASES])
def test_command_on_a_special_file(world, tmp_path, kind, name, build, words):

    def make(path: Path) -> Path:
        return _special(kind, path)

    argv = build(world, tmp_path, make)
    line = assert_named_error(argv, *words)
    assert "softpend" in line


def test_agent_file_with_a_huge_member_is_refused_unread(world, tmp_path):
    """A 5 GiB member (here 256 MiB of zeros, 256 KiB packed) in an agent zip is refused from the zip
    directory: the bound comes from the run's network size."""
    run = _run_with(world, tmp_path, "agent.zip")
    with zipfile.ZipFile(run / "agent.zip") as archive:
        members = {info.filename: archive.read(info) for info in archive.infolist()}
    members["policy.pth"] = bytes(256 * 2**20)
    (run / "agent.zip").write_bytes(_zip(members))
    line = assert_named_error(
        ["evaluate", str(run), "--which", "final", "--seeds", "0", "--duration-s", "0.1"],
        "agent.zip",
        "policy.pth",
        "would unpack to",
    )
    assert "268435456" in line


def test_pickled_dataset_member_is_a_named_error(world, tmp_path):
    """`softpend fit-model` on an .npz whose metadata member is a pickle: a named error, not AttributeError."""
    with zipfile.ZipFile(world["data"]) as archive:
        members = {info.filename: archive.read(info) for info in archive.infolist()}
    members["metadata.npy"] = pickle.dumps({"schema": "softpend.sysid.dataset"})
    bad = tmp_path / "bad.npz"
    bad.write_bytes(_zip(members))
    assert_named_error(["fit-model", str(bad), str(tmp_path / "m"), "--no-progress"], "metadata.npy", "not a .npy")
    members["positions.npy"] = _npy(np.array([object()], dtype=object))
    members.pop("metadata.npy")
    bad.write_bytes(_zip(members))
    assert_named_error(["identify", str(bad)], "positions.npy", "Python objects")


def test_config_json_of_a_run_that_is_dev_zero(world, tmp_path):
    """``config.json`` a symbolic link to /dev/zero: refused, not read until memory runs out."""
    run = _run_with(world, tmp_path, "config.json")
    (run / "config.json").unlink()
    (run / "config.json").symlink_to("/dev/zero")
    assert_named_error(["evaluate", str(run), "--seeds", "0", "--duration-s", "0.1"], "character device")


def test_json_file_larger_than_its_format(world, tmp_path):
    params = tmp_path / "params.json"
    params.write_text(json.dumps({"pad": "x" * (2 * 10**6)}))
    assert_named_error(["identify", str(world["data"]), "--initial-params", str(params)], "params.json", "bytes")


def test_replay_buffer_file_bounded_by_the_buffer(tmp_path):
    """A replay-buffer file can hold no more than the buffer it fills: a member of 64 MiB of zeros (a few KiB
    packed) for a buffer of 10 rows is refused from the zip directory, before it is unpacked."""
    from gymnasium import spaces
    from stable_baselines3.common.buffers import ReplayBuffer

    from softpend.rl.agent_files import AgentFileError, load_replay_buffer, save_replay_buffer

    buffer = ReplayBuffer(10, spaces.Box(-1, 1, (3,), dtype=np.float32), spaces.Discrete(5), device="cpu")
    path = tmp_path / "replay_buffer.npz"
    save_replay_buffer(buffer, path)
    load_replay_buffer(ReplayBuffer(10, buffer.observation_space, buffer.action_space, device="cpu"), path)
    np.savez_compressed(path, observations=np.zeros(8 * 2**20))
    with pytest.raises(AgentFileError, match="would unpack to"):
        load_replay_buffer(ReplayBuffer(10, buffer.observation_space, buffer.action_space, device="cpu"), path)


@pytest.mark.timeout(60, method="thread")
def test_a_fifo_swapped_in_after_the_check_does_not_block(fifo, monkeypatch):
    """The check before opening can race with a swap (a regular file replaced by a FIFO): the open is
    non-blocking and the descriptor is checked again, so the read is refused instead of waiting for a writer."""
    import softpend.io.reading as reading

    monkeypatch.setattr(reading, "check_regular_file", lambda *args, **kwargs: None)  # the swap won the race
    with alarm(10), pytest.raises(ValueError, match="named pipe"):
        reading.read_bytes_checked(fifo, "config file", 100)
