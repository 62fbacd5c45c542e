"""Fixtures shared by several test modules."""

from __future__ import annotations

import shutil
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import pytest
from browser import chromium_executable

from softpend.study import book
from softpend.study.book import build_html, run_notebooks
from softpend.study.run_pool import train_book

REPO_ROOT = Path(__file__).resolve().parents[1]

#: Chromium found or being installed, started by the fixture ``quick_book`` (at most one entry).
_CHROMIUM: list[Future] = []


@pytest.fixture(scope="session")
def quick_book(tmp_path_factory):
    """The whole book built once per test session with the quick profile as ``make book PROFILE=quick`` builds it
    (training step, notebooks, HTML), in a temporary copy of the project (so neither ``_build`` nor
    ``book/_generated`` of the working tree is touched): ``(root, runs, html_dir)``."""
    # others edit the package while the tests run: hash each notebook's code once, so the cache check of
    # tests/test_book.py is stable
    # (only softpend's own code: other tests hash packages of their own, which must be read every time)
    hash_code = book.PackageCode.code_hashes
    softpend_root = book.PackageCode().root
    hashes: dict[tuple[str, ...], dict[str, str]] = {}

    def code_hashes_once(self, cells):
        if self.root != softpend_root:
            return hash_code(self, cells)
        cells = tuple(cells)
        if cells not in hashes:
            hashes[cells] = hash_code(self, cells)
        return hashes[cells]

    # the browser checks of the book (tests/test_book_browser.py) come after the build, on this worker: find or
    # install Chromium meanwhile (apt-get on a fresh machine waits mostly on the network and the disk)
    with ThreadPoolExecutor(1) as pool:
        _CHROMIUM.append(pool.submit(chromium_executable))
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(book.PackageCode, "code_hashes", code_hashes_once)
            yield _build_quick_book(tmp_path_factory.mktemp("book"))


@pytest.fixture(scope="session")
def chromium() -> str:
    """Debian's chromium (tests/browser.py), installed with apt-get when missing; a clear failure (never a skip)
    otherwise.  The search or install that ``quick_book`` started is awaited when there is one."""
    try:
        return _CHROMIUM[0].result() if _CHROMIUM else chromium_executable()
    except RuntimeError as exc:
        pytest.fail(str(exc))


def _build_quick_book(root: Path):
    for name in ("_config.yml", "_toc.yml", "environment.lock"):
        shutil.copy2(REPO_ROOT / name, root / name)
    shutil.copytree(REPO_ROOT / "book", root / "book", ignore=shutil.ignore_patterns("_generated"))
    shutil.copytree(REPO_ROOT / "notebooks", root / "notebooks", ignore=shutil.ignore_patterns(".ipynb_checkpoints"))
    # the kernels make their temporary folders in root/kernel-tmp (tests/test_book.py checks none is left)
    (root / "kernel-tmp").mkdir()
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("TMPDIR", str(root / "kernel-tmp"))
        # as `make book` does: the training step first (each run once, in one pool), then the notebooks
        train_book(root, profile="quick")
        runs = run_notebooks(root, profile="quick", progress=False)
    html_dir = build_html(root, quiet=True)
    return root, runs, html_dir


#: The test files that read the quick book (fixture ``quick_book``).
QUICK_BOOK_TEST_FILES = frozenset({"tests/test_book.py", "tests/test_book_browser.py"})

#: The tests that run ``torch.compile``: the first compile in a process also pays the compiler's set-up (its
#: probes of the C++ compiler and the processor, its pool of compile workers), once per process.
TORCH_COMPILE_TESTS = frozenset(
    {
        "tests/test_pilco_moments.py::test_the_compiled_rollout_equals_the_eager_one_and_goes_through_torchs_disk_caches",
        "tests/test_batched_chain.py::test_compiled_chain_equals_the_eager_one_and_differentiates_eagerly",
    }
)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """Under pytest-xdist (``make test`` runs ``-n auto``): the tests of :data:`QUICK_BOOK_TEST_FILES` go to one
    worker, so the quick book is built once per run rather than once per worker, and those of
    :data:`TORCH_COMPILE_TESTS` to one worker, so the compiler is set up once; every other test is scheduled on
    its own, as ``--dist load`` does."""
    from xdist.scheduler import LoadScopeScheduling

    class SharedSetUpOnOneWorker(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            if nodeid.split("::", 1)[0] in QUICK_BOOK_TEST_FILES:
                return "quick_book"
            return "torch_compile" if nodeid in TORCH_COMPILE_TESTS else nodeid

    return SharedSetUpOnOneWorker(config, log)
