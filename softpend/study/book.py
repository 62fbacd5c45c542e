"""The executable book: run the figure notebooks with papermill, then build the HTML with Jupyter Book.

Layout (relative to the project root)::

    _toc.yml               the book's table of contents; entries under ``book/_generated/`` are notebooks
    book/profiles.yml      notebook parameters per profile: ``{profile: {notebook: {name: value}}}``
    notebooks/NAME.md      the notebook sources (jupytext MyST, one code cell tagged ``parameters``)
    book/_generated/       executed notebooks ``NAME.ipynb`` plus their cache keys ``NAME.sha256`` (gitignored)

:func:`run_notebooks` converts each notebook listed in the toc (in toc order) with jupytext, injects the
profile's parameters with papermill, executes it with the ``python3`` kernel of the running interpreter
(working directory: the project root) and writes ``book/_generated/NAME.ipynb``.  A notebook is skipped
when its source, its parameters and the code of the ``softpend`` modules it uses (:class:`PackageCode`:
the closure of its imports, docstrings and comments left out) are unchanged since the output was written
(the execution cache).  A notebook whose front matter says ``softpend: {after: [NAME, ...]}`` (one that
reads what those notebooks wrote, such as their glued values) executes after them wherever the toc lists it,
and their cache keys are part of its own.  A notebook whose front matter says ``softpend: {book_runs: [...]}``
reads the book's training runs (:data:`softpend.study.run_pool.BOOK_RUN_SETS`): when such notebooks are to
execute with their own parameters, those runs are trained in one pool of workers
(:func:`softpend.study.run_pool.train_book_runs`), so that no worker idles while one notebook's last runs
finish.  With more than one worker the pool trains in the background, at the lowest scheduling priority, while
notebooks execute side by side, each as soon as what it waits for has finished; a notebook whose front
matter says ``softpend: {realtime: true}`` (it runs the rig's twin by the wall clock) executes alone, after the
pool (:mod:`softpend.study.book_schedule`); with one worker the pool trains first and the notebooks execute one
at a time.  Every run ends by writing the execution record
``book/_generated/execution.json`` (:func:`write_execution_record`: per notebook the wall time and date of
its last execution, whether this run took it from the cache, its profile, parameters and overrides; the
package versions of ``environment.lock``, the Python version, the CPU count and the date; what the training
pool trained, and when each notebook started) and the page that
shows it, ``book/_generated/execution.md`` (the toc entry ``book/_generated/execution``, which is a page,
not a notebook).  :func:`build_html` then runs ``jupyter-book build`` with warnings as errors; the book
itself never executes notebooks.
"""

from __future__ import annotations

import ast
import hashlib
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

from softpend.study.book_schedule import Needs, next_to_start

__all__ = [
    "BookLayout",
    "DEFAULT_PROFILE",
    "EXECUTION_PAGE",
    "NotebookExecutionError",
    "NotebookRun",
    "PackageCode",
    "build_html",
    "cache_key",
    "check_parameters",
    "code_cells",
    "execution_order",
    "execution_record",
    "load_profiles",
    "notebook_after",
    "profile_parameters",
    "read_notebook",
    "run_notebooks",
    "toc_notebooks",
    "write_execution_record",
]

#: Profile used when none is given: the parameters that produce the published figures.
DEFAULT_PROFILE = "full"
#: Prefix of toc entries that are executed notebooks.
GENERATED_PREFIX = "book/_generated/"
#: The toc entry under :data:`GENERATED_PREFIX` that is the execution page the runner writes (not a notebook).
EXECUTION_PAGE = "execution"
#: Bump when the way outputs are produced changes, to invalidate every cached notebook.
_CACHE_VERSION = "2"
#: Kernel arguments: matplotlib figures are embedded in the notebooks (and the book) as PNG images.
#: (The kernel's own log is limited to errors: a failing cell is reported from the notebook's outputs.)
#: tqdm's warning that ipywidgets is missing (it then draws text bars, or none with ``disable=True``) is
#: silenced before the first cell: it would print the machine's paths on every page; other warnings show.
_KERNEL_ARGUMENTS = [
    "--InlineBackend.figure_formats=png",
    "--IPKernelApp.log_level=ERROR",
    "--IPKernelApp.exec_lines=__import__('warnings').filterwarnings('ignore', message='IProgress not found', "
    "category=__import__('tqdm').TqdmWarning)",
]


class NotebookExecutionError(RuntimeError):
    """A notebook raised while executing; the partially executed output is kept at ``output_path``.

    Attributes
    ----------
    notebook : str
        Notebook name (``notebooks/<notebook>.md``).
    cell_index : int
        Index of the failing cell among the cells of the source notebook (0-based, markdown cells count).
    code_cell_number : int
        The failing cell counted among the source's code cells (1-based, the parameters cell is 1 if first).
    execution_count : int or None
        Its ``In [n]`` number in the executed notebook.
    output_path : pathlib.Path
        The partially executed notebook.
    """

    def __init__(
        self,
        notebook: str,
        cell_index: int,
        code_cell_number: int,
        execution_count: Optional[int],
        source: str,
        error: str,
        output_path: Path,
    ) -> None:
        first_line = next((line for line in source.splitlines() if line.strip()), "")
        super().__init__(
            f"notebook {notebook!r} failed in code cell {code_cell_number} of notebooks/{notebook}.md "
            f"(In [{execution_count}], starting {first_line!r}): {error}; "
            f"the partially executed notebook is kept in {output_path}"
        )
        self.notebook = notebook
        self.cell_index = cell_index
        self.code_cell_number = code_cell_number
        self.execution_count = execution_count
        self.output_path = output_path


def _locate_cell(source_nb, executed_index: int, cell_source: str) -> tuple[int, int]:
    """Map a cell of the executed notebook (which has papermill's injected-parameters cell) back to the
    source notebook: ``(cell_index, code_cell_number)``; ``(-1, 0)`` when it cannot be found."""
    matches = [i for i, cell in enumerate(source_nb.cells) if cell.cell_type == "code" and cell.source == cell_source]
    if not matches:
        return -1, 0
    index = min(matches, key=lambda i: abs(i - executed_index))
    code_number = sum(cell.cell_type == "code" for cell in source_nb.cells[: index + 1])
    return index, code_number


@dataclass(frozen=True)
class BookLayout:
    """Where the book's files live below a project root (see the module docstring)."""

    root: Path

    @classmethod
    def at(cls, root: Path | str = ".") -> "BookLayout":
        """Layout rooted at ``root``; raises ``FileNotFoundError`` when ``root/_toc.yml`` is missing."""
        layout = cls(Path(root).resolve())
        if not layout.toc_path.is_file():
            raise FileNotFoundError(f"no _toc.yml in {layout.root} (run from the project root or pass --root)")
        return layout

    @property
    def toc_path(self) -> Path:
        return self.root / "_toc.yml"

    @property
    def profiles_path(self) -> Path:
        return self.root / "book" / "profiles.yml"

    @property
    def notebooks_dir(self) -> Path:
        return self.root / "notebooks"

    @property
    def generated_dir(self) -> Path:
        return self.root / GENERATED_PREFIX.rstrip("/")

    def source_path(self, name: str) -> Path:
        """The notebook's jupytext source ``notebooks/NAME.md``."""
        return self.notebooks_dir / f"{name}.md"

    def output_path(self, name: str) -> Path:
        """The executed notebook ``book/_generated/NAME.ipynb``."""
        return self.generated_dir / f"{name}.ipynb"

    def key_path(self, name: str) -> Path:
        """The cache key of the executed notebook, next to it."""
        return self.generated_dir / f"{name}.sha256"

    @property
    def record_path(self) -> Path:
        """The execution record of the last run, ``book/_generated/execution.json``."""
        return self.generated_dir / f"{EXECUTION_PAGE}.json"

    @property
    def execution_page_path(self) -> Path:
        """The execution page, ``book/_generated/execution.md``."""
        return self.generated_dir / f"{EXECUTION_PAGE}.md"

    @property
    def lock_path(self) -> Path:
        """The pinned package versions, ``environment.lock``."""
        return self.root / "environment.lock"


@dataclass(frozen=True)
class NotebookRun:
    """What :func:`run_notebooks` did with one notebook."""

    name: str
    status: str  # "executed" or "cached"
    seconds: float
    output_path: Path
    started_s: Optional[float] = None  # when it started, in seconds after the runner began executing


# --------------------------------------------------------------------------- configuration
def _load_yaml(path: Path) -> Any:
    import yaml

    with open(path, encoding="utf-8") as handle:
        return yaml.safe_load(handle)


def toc_notebooks(toc_path: Path | str) -> list[str]:
    """Names of the executed notebooks in a ``_toc.yml``, in reading order.

    Every ``file:`` entry (root, chapters, parts, sections) that starts with ``book/_generated/`` is a
    notebook whose source is ``notebooks/<name>.md``, except the execution page (:data:`EXECUTION_PAGE`),
    which the runner writes itself.
    """
    names: list[str] = []

    def visit(node: Any) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                if key in ("file", "root") and isinstance(value, str):
                    entry = value.removesuffix(".ipynb")
                    if entry.startswith(GENERATED_PREFIX) and entry[len(GENERATED_PREFIX) :] != EXECUTION_PAGE:
                        names.append(entry[len(GENERATED_PREFIX) :])
                else:
                    visit(value)
        elif isinstance(node, list):
            for item in node:
                visit(item)

    visit(_load_yaml(Path(toc_path)))
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise ValueError(f"{toc_path}: notebook(s) listed more than once: {duplicates}")
    return names


def load_profiles(path: Path | str) -> dict[str, dict[str, dict[str, Any]]]:
    """Read ``profiles.yml``: a mapping ``profile -> notebook -> {parameter: value}``.

    An empty profile or notebook entry means "the notebook's defaults".  Raises ``ValueError`` naming
    the offending entry when the structure is wrong.
    """
    data = _load_yaml(Path(path)) or {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping profile -> notebook -> parameters, got {type(data).__name__}")
    profiles: dict[str, dict[str, dict[str, Any]]] = {}
    for profile, notebooks in data.items():
        notebooks = notebooks or {}
        if not isinstance(notebooks, dict):
            raise ValueError(f"{path}: profile {profile!r} must map notebook names to parameters")
        profiles[str(profile)] = {}
        for notebook, parameters in notebooks.items():
            parameters = parameters or {}
            if not isinstance(parameters, dict) or not all(isinstance(key, str) for key in parameters):
                raise ValueError(f"{path}: profile {profile!r}, notebook {notebook!r}: parameters must be a mapping")
            profiles[str(profile)][str(notebook)] = dict(parameters)
    return profiles


def profile_parameters(profiles: dict[str, dict[str, dict[str, Any]]], profile: str, notebook: str) -> dict[str, Any]:
    """The parameters of ``notebook`` under ``profile`` (empty: the notebook's own defaults)."""
    if profile not in profiles:
        raise ValueError(f"unknown profile {profile!r}; profiles.yml defines {sorted(profiles)}")
    return dict(profiles[profile].get(notebook, {}))


def read_notebook(source_path: Path | str):
    """Read a jupytext MyST notebook into an ``nbformat`` notebook (no outputs)."""
    import jupytext

    source_path = Path(source_path)
    if not source_path.is_file():
        raise FileNotFoundError(f"notebook source {source_path} does not exist")
    return jupytext.read(source_path, fmt="md:myst")


def _has_parameters_cell(nb) -> bool:
    return any("parameters" in cell.get("metadata", {}).get("tags", []) for cell in nb.cells)


def check_parameters(notebook_path: Path | str, name: str, parameters: dict[str, Any]) -> dict[str, Any]:
    """Check ``parameters`` against the notebook's ``parameters`` cell (via ``papermill.inspect_notebook``).

    Parameters
    ----------
    notebook_path : path
        The notebook as ``.ipynb``.
    name : str
        Notebook name, for messages.
    parameters : dict
        Values to inject.

    Returns
    -------
    dict
        The notebook's declared parameters as papermill infers them (name -> details).

    Raises
    ------
    ValueError
        If the notebook has no cell tagged ``parameters`` or a parameter is not defined in it.
    """
    import nbformat
    import papermill

    if not _has_parameters_cell(nbformat.read(str(notebook_path), as_version=4)):
        raise ValueError(f"notebook {name!r} has no code cell tagged 'parameters'")
    declared = papermill.inspect_notebook(str(notebook_path))
    unknown = sorted(set(parameters) - set(declared))
    if unknown:
        raise ValueError(
            f"notebook {name!r}: parameter(s) {unknown} are not defined in its parameters cell "
            f"(it defines {sorted(declared)})"
        )
    return declared


# --------------------------------------------------------------------------- cache
#: Suffixes of non-Python files inside the package that count as data the code may read.
DATA_SUFFIXES = (".csv", ".json", ".npy", ".npz", ".toml", ".txt", ".yaml", ".yml")


def _drop_docstrings(tree: ast.AST) -> ast.AST:
    """Remove every statement that is a bare string constant (the docstrings of the module, its classes and
    functions, and attribute docstrings) from ``tree``, in place; an emptied body becomes ``pass``."""
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if not isinstance(body, list):
            continue
        kept = [
            statement
            for statement in body
            if not (
                isinstance(statement, ast.Expr)
                and isinstance(statement.value, ast.Constant)
                and isinstance(statement.value.value, str)
            )
        ]
        if len(kept) != len(body):
            node.body = kept or [ast.Pass()]
    return tree


def _parse_cell(source: str) -> Optional[ast.Module]:
    """A notebook code cell as an ``ast`` tree (IPython magics translated); ``None`` when it does not parse."""
    try:
        return ast.parse(source)
    except SyntaxError:
        pass
    try:
        from IPython.core.inputtransformer2 import TransformerManager

        return ast.parse(TransformerManager().transform_cell(source))
    except (ImportError, SyntaxError):
        return None


class PackageCode:
    """The modules of one Python package, read with ``ast``: what a piece of code imports from it, and a
    hash of each module's code with docstrings and comments left out.

    Parameters
    ----------
    package_root : path, optional
        The package directory (its name is the package name); default: the installed ``softpend``.

    Notes
    -----
    The modules a piece of code uses are the closure of its imports over the package's own imports:
    ``import pkg.a.b`` and ``from pkg.a import b`` (``b`` counts when it is a submodule), relative imports
    resolved, imports anywhere in a module (inside functions too) counted, and a package's ``__init__``
    counted with each of its submodules.  A string constant in the code that names a module of the package,
    alone (``"pkg.a.b"``) or as an entry point (``"pkg.a.b:attr"``, as the plant and environment registries
    use), counts as an import of that module.
    """

    def __init__(self, package_root: Path | str | None = None) -> None:
        if package_root is None:
            package_root = Path(__file__).resolve().parents[1]
        self.root = Path(package_root).resolve()
        if not (self.root / "__init__.py").is_file():
            raise ValueError(f"package_root must be a package directory with an __init__.py, got {self.root}")
        self.name = self.root.name
        self.modules: dict[str, Path] = {}
        for path in sorted(self.root.rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            parts = path.relative_to(self.root).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            self.modules[".".join((self.name, *parts))] = path
        self._trees: dict[str, ast.Module] = {}
        self._imports: dict[str, frozenset[str]] = {}
        self._hashes: dict[str, str] = {}
        self._entry_point = re.compile(rf"\b{re.escape(self.name)}(?:\.[A-Za-z_]\w*)*(?=:[A-Za-z_])")

    # ------------------------------------------------------------------ reading
    def tree(self, module: str) -> ast.Module:
        """The module's ``ast`` tree without docstrings."""
        if module not in self._trees:
            path = self.modules[module]
            self._trees[module] = _drop_docstrings(ast.parse(path.read_text(encoding="utf-8"), filename=str(path)))
        return self._trees[module]

    def module_hash(self, module: str) -> str:
        """SHA-256 of the module's code: ``ast.dump`` of its tree without docstrings (so comments, blank lines
        and formatting do not count either)."""
        if module not in self._hashes:
            self._hashes[module] = hashlib.sha256(ast.dump(self.tree(module)).encode()).hexdigest()
        return self._hashes[module]

    def data_hashes(self) -> dict[str, str]:
        """SHA-256 of every data file in the package (suffix in :data:`DATA_SUFFIXES`), by relative path."""
        hashes = {}
        for path in sorted(self.root.rglob("*")):
            if path.is_file() and path.suffix in DATA_SUFFIXES and "__pycache__" not in path.parts:
                hashes[f"{self.name}/{path.relative_to(self.root).as_posix()}"] = hashlib.sha256(path.read_bytes()).hexdigest()
        return hashes

    # ------------------------------------------------------------------ imports
    def _with_parents(self, module: str) -> set[str]:
        """``module`` and the packages above it that are modules of this package (their ``__init__`` runs)."""
        parts = module.split(".")
        return {name for name in (".".join(parts[: i + 1]) for i in range(len(parts))) if name in self.modules}

    def _tree_imports(self, tree: ast.AST, module: Optional[str] = None) -> set[str]:
        """Modules of this package that ``tree`` imports (``module``: its own name, to resolve relative imports)."""
        found: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    found |= self._with_parents(alias.name)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    if module is None:
                        continue
                    base = module.split(".")
                    if self.modules[module].name != "__init__.py":
                        base = base[:-1]
                    base = base[: len(base) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                found |= self._with_parents(target)
                for alias in node.names:
                    if f"{target}.{alias.name}" in self.modules:
                        found |= self._with_parents(f"{target}.{alias.name}")
            elif isinstance(node, ast.Constant) and isinstance(node.value, str) and self.name in node.value:
                if node.value.strip() in self.modules:
                    found |= self._with_parents(node.value.strip())
                for match in self._entry_point.finditer(node.value):
                    found |= self._with_parents(match.group(0))
        found.discard(module)
        return found

    def imports(self, module: str) -> frozenset[str]:
        """Modules of this package that ``module`` imports directly (see the class notes)."""
        if module not in self._imports:
            self._imports[module] = frozenset(self._tree_imports(self.tree(module), module))
        return self._imports[module]

    def closure(self, code_cells: Iterable[str]) -> set[str]:
        """Modules of this package that the code (e.g. a notebook's code cells) uses, directly or through the
        package's own imports; every module when a cell does not parse (its use cannot be read)."""
        pending: set[str] = set()
        for cell in code_cells:
            tree = _parse_cell(cell)
            if tree is None:
                return set(self.modules)
            pending |= self._tree_imports(tree)
        used: set[str] = set()
        while pending:
            module = pending.pop()
            if module not in used:
                used.add(module)
                pending |= self.imports(module) - used
        return used

    def code_hashes(self, code_cells: Iterable[str]) -> dict[str, str]:
        """Hash of each module the code uses (:meth:`closure`, :meth:`module_hash`) and of each data file of
        the package (:meth:`data_hashes`); the part of a notebook's cache key that the package contributes."""
        hashes = {module: self.module_hash(module) for module in sorted(self.closure(code_cells))}
        hashes.update(self.data_hashes())
        return hashes


def code_cells(nb) -> list[str]:
    """The sources of an ``nbformat`` notebook's code cells."""
    return [cell.source for cell in nb.cells if cell.cell_type == "code"]


def _records_hashes(layout: "BookLayout") -> dict[str, str]:
    """SHA-256 of every file under ``book/records/`` (the stored run records some notebooks read)."""
    folder = layout.root / "book" / "records"
    if not folder.is_dir():
        return {}
    return {f"book/records/{path.relative_to(folder).as_posix()}": hashlib.sha256(path.read_bytes()).hexdigest()
            for path in sorted(folder.rglob("*")) if path.is_file()}


def cache_key(source_text: str, parameters: dict[str, Any], code_hashes: dict[str, str]) -> str:
    """Cache key of one executed notebook: its source, its parameters and the hashes of the package code it
    uses (:meth:`PackageCode.code_hashes`)."""
    payload = json.dumps(
        {
            "version": _CACHE_VERSION,
            "source": source_text,
            "parameters": parameters,
            "code": sorted(code_hashes.items()),
        },
        sort_keys=True,
        default=repr,
    )
    return hashlib.sha256(payload.encode()).hexdigest()


# --------------------------------------------------------------------------- order
def notebook_book_runs(nb, name: str) -> list[str]:
    """The book's training runs that notebook ``name`` reads: its front matter's ``softpend: {book_runs: [...]}``
    (among :data:`softpend.study.run_pool.BOOK_RUN_SETS`).  Executed with its own defaults, it finds them
    trained: :func:`run_notebooks` trains them first, in one pool.

    Raises
    ------
    ValueError
        If ``book_runs`` is not a list of known run set names.
    """
    from softpend.study.run_pool import BOOK_RUN_SETS

    run_sets = (nb.metadata.get("softpend") or {}).get("book_runs", [])
    if not isinstance(run_sets, list) or not all(entry in BOOK_RUN_SETS for entry in run_sets):
        raise ValueError(f"notebook {name!r}: softpend.book_runs must be a list among {list(BOOK_RUN_SETS)}, "
                         f"got {run_sets!r}")
    return list(run_sets)


def notebook_after(nb, name: str, known: Sequence[str]) -> list[str]:
    """The notebooks that notebook ``name`` executes after: its front matter's ``softpend: {after: [...]}``.

    Raises
    ------
    ValueError
        If ``after`` is not a list of names, names a notebook that ``known`` (the toc) does not list, or
        names the notebook itself.
    """
    after = (nb.metadata.get("softpend") or {}).get("after", [])
    if not isinstance(after, list) or not all(isinstance(entry, str) for entry in after):
        raise ValueError(f"notebook {name!r}: softpend.after must be a list of notebook names, got {after!r}")
    unknown = sorted(set(after) - set(known))
    if unknown:
        raise ValueError(f"notebook {name!r}: softpend.after names {unknown}, which _toc.yml does not list")
    if name in after:
        raise ValueError(f"notebook {name!r}: softpend.after names the notebook itself")
    return list(after)


def notebook_realtime(nb, name: str) -> bool:
    """Whether notebook ``name`` paces a rig emulator by the wall clock: its front matter's
    ``softpend: {realtime: true}`` (:mod:`softpend.study.book_schedule` runs it alone among the notebooks).

    Raises
    ------
    ValueError
        If ``realtime`` is not true or false.
    """
    value = (nb.metadata.get("softpend") or {}).get("realtime", False)
    if not isinstance(value, bool):
        raise ValueError(f"notebook {name!r}: softpend.realtime must be true or false, got {value!r}")
    return value


def execution_order(names: Sequence[str], after: dict[str, Sequence[str]]) -> list[str]:
    """``names`` in the order they execute: the given (toc) order, except that a notebook waits for the
    notebooks its ``after`` entry lists that are among ``names``.

    Raises
    ------
    ValueError
        If notebooks wait for each other (a cycle).
    """
    selected = set(names)
    pending, done = list(names), []
    while pending:
        ready = next((name for name in pending
                      if all(dep in done or dep not in selected for dep in after.get(name, ()))), None)
        if ready is None:
            raise ValueError(f"notebooks {pending} wait for each other (softpend.after in their front matter)")
        pending.remove(ready)
        done.append(ready)
    return done


def _with_upstream(key: str, after: Sequence[str], layout: "BookLayout", planned: dict[str, str]) -> str:
    """``key`` combined with the cache keys of the notebooks in ``after``: those of this run (``planned``),
    else the key files on disk (``"absent"`` when there is none)."""
    upstream = {}
    for dep in after:
        if dep in planned:
            upstream[dep] = planned[dep]
        else:
            path = layout.key_path(dep)
            upstream[dep] = path.read_text(encoding="utf-8").strip() if path.is_file() else "absent"
    payload = json.dumps({"key": key, "after": upstream}, sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()


# --------------------------------------------------------------------------- execution
def _execute_one(
    layout: BookLayout,
    name: str,
    parameters: dict[str, Any],
    key: str,
    converted_path: Path,
) -> None:
    import nbformat
    import papermill
    from papermill.exceptions import PapermillExecutionError

    output_path = layout.output_path(name)
    key_path = layout.key_path(name)
    key_path.unlink(missing_ok=True)  # an interrupted or failed run must not look cached
    kernel_name = nbformat.read(str(converted_path), as_version=4).metadata.get("kernelspec", {}).get("name", "python3")
    try:
        papermill.execute_notebook(
            str(converted_path),
            str(output_path),
            parameters=parameters,
            kernel_name=kernel_name,
            progress_bar=False,
            cwd=None,  # the kernel starts in this process's working folder, the project root (see _execute)
            extra_arguments=list(_KERNEL_ARGUMENTS),
        )
    except PapermillExecutionError as exc:
        source_nb = nbformat.read(str(converted_path), as_version=4)
        cell_index, code_number = _locate_cell(source_nb, exc.cell_index, exc.source)
        raise NotebookExecutionError(
            name, cell_index, code_number, exc.exec_count, exc.source, f"{exc.ename}: {exc.evalue}", output_path
        ) from None
    _fold_injected_parameters(output_path)
    key_path.write_text(key + "\n", encoding="utf-8")


def _fold_injected_parameters(output_path: Path) -> None:
    """Tag papermill's injected-parameters cell ``hide-input`` in an executed notebook, so that the book
    folds it under the notebook's own parameters cell (the execution page lists the values)."""
    import nbformat

    nb = nbformat.read(str(output_path), as_version=4)
    changed = False
    for cell in nb.cells:
        tags = cell.get("metadata", {}).get("tags", [])
        if "injected-parameters" in tags and "hide-input" not in tags:
            cell.metadata["tags"] = [*tags, "hide-input"]
            changed = True
    if changed:
        nbformat.write(nb, str(output_path))


def run_notebooks(
    root: Path | str = ".",
    profile: str = DEFAULT_PROFILE,
    only: Optional[Sequence[str]] = None,
    force: bool = False,
    progress: bool = True,
    overrides: Optional[dict[str, Any]] = None,
) -> list[NotebookRun]:
    """Execute the book's notebooks (toc order) with a profile's parameters into ``book/_generated/``.

    Parameters
    ----------
    root : path
        Project root (holds ``_toc.yml``, ``book/profiles.yml`` and ``notebooks/``).
    profile : str
        Profile in ``book/profiles.yml`` (``"full"`` for the published figures, ``"quick"`` for tests).
    only : sequence of str, optional
        Run only these notebooks (names as in the toc, e.g. ``"fig01_prb_rod"``).
    force : bool
        Execute even when the cached output is up to date.
    progress : bool
        Show a progress bar over the notebooks and one line per notebook.
    overrides : dict, optional
        Parameter values set on top of the profile in every selected notebook whose ``parameters`` cell
        defines them (e.g. ``{"plant": "beam"}`` regenerates the figure set on the continuum beam).

    Returns
    -------
    list of NotebookRun
        One entry per selected notebook, in execution order (toc order, except that a notebook with
        ``softpend.after`` in its front matter runs after those notebooks); notebooks execute side by side
        where :mod:`softpend.study.book_schedule` lets them.  The execution record and page are written at
        the end (:func:`write_execution_record`).

    Raises
    ------
    ValueError
        Unknown profile or notebook name, a notebook without a ``parameters`` cell, a profile parameter
        that the notebook's ``parameters`` cell does not define, or an override that no selected notebook
        defines.  All notebooks are validated before any
        is executed.
    NotebookExecutionError
        A notebook raised; its partially executed output is kept for inspection.
    """
    import nbformat

    layout = BookLayout.at(root)
    names = toc_names = toc_notebooks(layout.toc_path)
    profiles = load_profiles(layout.profiles_path)
    if profile not in profiles:
        raise ValueError(f"unknown profile {profile!r}; {layout.profiles_path} defines {sorted(profiles)}")
    for notebook in profiles[profile]:
        if notebook not in names:
            raise ValueError(f"profile {profile!r} in {layout.profiles_path} names notebook {notebook!r}, which _toc.yml does not list")
    if only:
        unknown = [name for name in only if name not in names]
        if unknown:
            raise ValueError(f"unknown notebook(s) {unknown} for --only; _toc.yml lists {names}")
        names = [name for name in names if name in set(only)]

    package_code = PackageCode()
    layout.generated_dir.mkdir(parents=True, exist_ok=True)
    runs: list[NotebookRun] = []
    with tempfile.TemporaryDirectory(prefix="softpend-book-") as scratch:
        # validate everything first: a typo in profiles.yml should not surface after an hour of execution
        overrides = dict(overrides or {})
        used_overrides: dict[str, Any] = {}
        plan = {}
        after: dict[str, list[str]] = {}
        book_runs: dict[str, list[str]] = {}
        realtime: dict[str, bool] = {}
        for name in names:
            nb = read_notebook(layout.source_path(name))
            after[name] = notebook_after(nb, name, toc_names)
            book_runs[name] = notebook_book_runs(nb, name)
            realtime[name] = notebook_realtime(nb, name)
            parameters = profile_parameters(profiles, profile, name)
            converted = Path(scratch) / f"{name}.ipynb"
            nbformat.write(nb, str(converted))
            declared = check_parameters(converted, name, parameters)
            applied = {key: value for key, value in overrides.items() if key in declared}
            # what the execution record reads back from the executed notebook
            nb.metadata["softpend"] = {"profile": profile, "source": f"notebooks/{name}.md",
                                       "parameters": dict(parameters), "overrides": applied}
            nbformat.write(nb, str(converted))
            used_overrides.update(applied)
            parameters.update(applied)
            source_text = layout.source_path(name).read_text(encoding="utf-8")
            hashes = package_code.code_hashes(code_cells(nb))
            if "softpend.study.records" in hashes:  # the stored run records are an input of that code
                hashes.update(_records_hashes(layout))
            plan[name] = (parameters, converted, cache_key(source_text, parameters, hashes))
        unused = sorted(set(overrides) - set(used_overrides))
        if unused:
            raise ValueError(f"override(s) {unused} are not parameters of any selected notebook ({names})")
        order = execution_order(names, after)

        planned: dict[str, str] = {}
        cached: dict[str, bool] = {}
        for name in order:  # every key is known before anything executes (upstream keys are planned ones)
            key = plan[name][2]
            if after[name]:
                key = _with_upstream(key, after[name], layout, planned)
            planned[name] = key
            output_path, key_path = layout.output_path(name), layout.key_path(name)
            cached[name] = (not force and output_path.is_file() and key_path.is_file()
                            and key_path.read_text(encoding="utf-8").strip() == key)
        # the book's training runs that the notebooks to execute read with their own defaults: trained in one
        # pool, in the background of the notebooks that need none of them (or first, with one worker)
        run_sets = sorted({run_set for name in order if not cached[name] and not plan[name][0]
                           for run_set in book_runs[name]})
        needs = _notebook_needs(order, plan, after, book_runs, realtime, cached)
        runs = _execute(layout, order, plan, planned, cached, needs, run_sets, progress, profile)
    write_execution_record(layout, execution_record(layout, profile, runs.notebooks, used_overrides, runs.pool))
    return runs.notebooks


def _notebook_needs(order: Sequence[str], plan: dict[str, tuple], after: dict[str, list[str]],
                    book_runs: dict[str, list[str]], realtime: dict[str, bool],
                    cached: dict[str, bool]) -> dict[str, Needs]:
    """What each notebook of ``order`` waits for (:class:`softpend.study.book_schedule.Needs`): the selected
    notebooks of its ``after``; with its own parameters, the book runs of its ``book_runs``; with other
    parameters, the earlier notebooks that read book runs, which may train the same runs in their kernels."""
    from softpend.study.run_pool import book_run_names

    needs, readers = {}, []
    for name in order:
        waits = {dep for dep in after[name] if dep in plan}
        runs: frozenset[str] = frozenset()
        if book_runs[name] and not cached[name]:
            if plan[name][0]:
                waits |= set(readers)
            else:
                runs = book_run_names(book_runs[name])
        if book_runs[name]:
            readers.append(name)
        needs[name] = Needs(frozenset(waits), runs, realtime[name])
    return needs


@dataclass
class _Execution:
    """What :func:`_execute` did: the notebooks' :class:`NotebookRun` entries and the training pool's record."""

    notebooks: list[NotebookRun]
    pool: Optional[dict[str, Any]]


def _execute(layout: BookLayout, order: Sequence[str], plan: dict[str, tuple], planned: dict[str, str],
             cached: dict[str, bool], needs: dict[str, Needs], run_sets: Sequence[str], progress: bool,
             profile: str) -> _Execution:
    """Train the missing runs of ``run_sets`` and execute the notebooks of ``order`` that are not ``cached``, on
    up to :func:`~softpend.study.sweep.default_workers` kernels at once (:mod:`softpend.study.book_schedule`).

    With several workers the training pool runs in a background thread, its workers at the lowest scheduling
    priority (:func:`~softpend.study.sweep.enter_background`), while the notebooks that need none of its runs
    execute; a notebook starts as soon as the runs it reads have finished.  With one worker the pool trains
    first and the notebooks then execute one at a time.  After a notebook fails, or the pool does, nothing
    further starts; the running notebooks and the pool finish (their results are kept) and the first error is
    raised.
    """
    from softpend.study.sweep import allocator_env, default_workers

    lanes = default_workers()
    began = time.perf_counter()
    # kernels start in the working folder of this process: papermill's own ``cwd`` changes it for the length of
    # one execution, which two executions in threads would undo for each other
    previous_cwd = os.getcwd()
    os.chdir(layout.root)
    try:
        with allocator_env():  # for the pool's workers and the kernels
            return _execute_in_root(layout, order, plan, planned, cached, needs, run_sets, progress, profile, lanes,
                                    began)
    finally:
        os.chdir(previous_cwd)


def _execute_in_root(layout: BookLayout, order: Sequence[str], plan: dict[str, tuple], planned: dict[str, str],
                     cached: dict[str, bool], needs: dict[str, Needs], run_sets: Sequence[str], progress: bool,
                     profile: str, lanes: int, began: float) -> _Execution:
    """:func:`_execute`, in the project root."""
    import queue
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from tqdm.auto import tqdm

    from softpend.study.run_pool import book_run_jobs, train_jobs

    jobs = book_run_jobs(run_sets, root=layout.root) if run_sets else []
    pending_runs = {name for name, _ in jobs}
    # a run the pool does not train (it was finished before) counts as trained from the start
    trained = {run for need in needs.values() for run in need.runs} - pending_runs
    events: "queue.Queue[tuple[str, str, Any]]" = queue.Queue()
    pool: Optional[dict[str, Any]] = None
    bar = tqdm(total=len(order), desc=f"book [{profile}]", unit="notebook", disable=not progress, file=sys.stderr)

    def say(text: str) -> None:
        if progress:
            bar.write(f"[book] {text}", file=sys.stderr)

    def train(background: bool) -> None:
        error: Optional[BaseException] = None
        try:
            train_jobs(jobs, progress=progress and not background, background=background,
                       on_finished=lambda name: events.put(("run", name, None)))
        except BaseException as exc:  # noqa: BLE001 -- handed to the scheduling thread, which raises it
            error = exc
        events.put(("pool", "", error))

    pool_thread = None
    if jobs:
        say(f"training {len(jobs)} of the book's runs ({', '.join(run_sets)}) in one pool"
            + (", in the background of the notebooks that need none of them" if lanes > 1 else ""))
        pool = {"run_sets": list(run_sets), "trained": len(jobs), "run_s": None, "background": lanes > 1}
        if lanes > 1:
            pool_thread = threading.Thread(target=train, args=(True,), name="softpend-book-pool", daemon=True)
            pool_thread.start()
        else:
            train(False)
    pool_done = pool is None
    errors: list[BaseException] = []
    finished = {name for name in order if cached[name]}
    started = set(finished)
    timings: dict[str, tuple[float, float]] = {}

    def take(event: tuple[str, str, Any]) -> None:
        """Apply one event of the pool (``"run"``, ``"pool"``) or of a notebook lane (``"notebook"``)."""
        nonlocal pool_done
        kind, name, payload = event
        if kind == "run":
            trained.add(name)
            if pool_thread is not None:
                say(f"run {name} trained ({len(trained & pending_runs)} of {len(pending_runs)})")
        elif kind == "pool":
            pool_done = True
            assert pool is not None
            pool["run_s"] = time.perf_counter() - began
            if payload is not None:
                errors.append(payload)
                if pool_thread is not None:
                    say(f"the training pool failed: {payload}")
        elif isinstance(payload, BaseException):
            finished.add(name)
            errors.append(payload)
            waiting = [what for what, busy in (("the running notebooks", started - finished),
                                               ("the training pool", not pool_done)) if busy]
            if waiting:  # else the error itself is the one message
                say(f"{name} failed; waiting for {' and '.join(waiting)} to finish (their results are kept)")
        else:
            finished.add(name)
            timings[name] = payload
            bar.update(1)
            say(f"{name}: executed in {payload[1]:.1f} s")

    while pool_thread is None and not events.empty():  # the pool trained first, in this thread
        take(events.get())

    def execute(name: str) -> None:
        start = time.perf_counter()
        try:
            _execute_one(layout, name, plan[name][0], planned[name], plan[name][1])
        except BaseException as exc:  # noqa: BLE001 -- handed to the scheduling thread, which raises it
            events.put(("notebook", name, exc))
            return
        events.put(("notebook", name, (start - began, time.perf_counter() - start)))

    for name in order:
        if cached[name]:
            say(f"{name}: up to date (cached)")
            bar.update(1)
    with ThreadPoolExecutor(max_workers=lanes, thread_name_prefix="softpend-book-notebook") as lanes_pool:
        while True:
            while not errors:
                name = next_to_start(order, needs, started, finished, trained, lanes, not pool_done)
                if name is None:
                    break
                started.add(name)
                bar.set_postfix_str(name)
                lanes_pool.submit(execute, name)
            if not started - finished and (pool_done or errors):
                break
            take(events.get())
    while not pool_done:  # a notebook failed: the pool's runs are kept, so let it finish
        take(events.get())
    bar.close()
    if errors:
        raise errors[0]
    never = [name for name in order if name not in started]
    if never:
        raise RuntimeError(f"notebooks {never} could not start: what they wait for never finished")
    notebooks = [NotebookRun(name, "cached" if cached[name] else "executed",
                             timings[name][1] if name in timings else 0.0, layout.output_path(name),
                             timings[name][0] if name in timings else None)
                 for name in order]
    return _Execution(notebooks, pool)




# --------------------------------------------------------------------------- execution record
def _title(source_path: Path) -> str:
    """The first ``# `` heading of a notebook source (its name when there is none)."""
    if source_path.is_file():
        for line in source_path.read_text(encoding="utf-8").splitlines():
            if line.startswith("# "):
                return line[2:].strip()
    return source_path.stem


def _processor(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The processor's model: on Linux its name, family and model from ``/proc/cpuinfo`` (the same seeds give the
    same runs on the same processor model; another one's vector units round differently), elsewhere
    :func:`platform.processor` or the machine type."""
    fields: dict[str, str] = {}
    try:
        for line in cpuinfo.read_text().splitlines():
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    if fields.get("model name"):
        return f"{fields['model name']} (family {fields.get('cpu family', '-')}, model {fields.get('model', '-')})"
    return platform.processor() or platform.machine() or "-"


def _locked_packages(lock_path: Path) -> tuple[list[dict[str, Any]], Optional[str]]:
    """The ``name==version`` lines of ``environment.lock`` with the installed version of each (``None`` when
    not installed), and the Python version its header names."""
    from importlib import metadata

    packages, python = [], None
    if not lock_path.is_file():
        return packages, python
    for line in lock_path.read_text(encoding="utf-8").splitlines():
        line = line.strip()
        if line.startswith("# Python "):
            python = line[len("# Python "):].strip()
        if not line or line.startswith("#") or "==" not in line:
            continue
        name, version = (part.strip() for part in line.split("==", 1))
        try:
            installed: Optional[str] = metadata.version(name)
        except metadata.PackageNotFoundError:
            installed = None
        packages.append({"name": name, "locked": version, "installed": installed})
    return packages, python


def execution_record(layout: "BookLayout", profile: str, runs: Sequence[NotebookRun],
                     overrides: Optional[dict[str, Any]] = None,
                     pool: Optional[dict[str, Any]] = None) -> dict[str, Any]:
    """What produced the executed notebooks in ``book/_generated/``, after a run of :func:`run_notebooks`.

    Returns
    -------
    dict
        ``date`` (UTC, ISO 8601), ``profile`` and ``overrides`` of the run; ``notebooks``: one entry per toc
        notebook, in toc order, with ``this_run`` (``"executed"``, ``"cached"`` or ``"not run"``: not
        selected by ``only``), ``run_s`` (this run's time for it), ``started_s`` (when this run started it,
        in seconds after the runner began executing; None if it did not execute), and from the executed
        notebook's metadata (papermill's and the runner's) ``executed_s`` and ``executed_at`` (wall time and
        end of its last execution), its ``profile``, the profile's ``parameters`` and the ``overrides`` applied
        (all None when there is no executed notebook); ``environment``: Python version, platform, CPU count, the CPUs
        this process may use, and the ``packages`` of ``environment.lock`` with their installed versions;
        ``training_pool``: ``pool`` (``run_sets``, ``trained``: how many runs, ``run_s``: when the last
        finished, in seconds after the runner began executing, ``background``: whether notebooks executed
        alongside it), None when this run trained none.
    """
    import datetime

    import nbformat

    this_run = {run.name: run for run in runs}
    notebooks = []
    for name in toc_notebooks(layout.toc_path):
        entry: dict[str, Any] = {"name": name, "title": _title(layout.source_path(name)),
                                 "this_run": this_run[name].status if name in this_run else "not run",
                                 "run_s": this_run[name].seconds if name in this_run else None,
                                 "started_s": this_run[name].started_s if name in this_run else None,
                                 "executed_s": None, "executed_at": None, "profile": None, "parameters": None,
                                 "overrides": None}
        output = layout.output_path(name)
        if output.is_file():
            metadata = nbformat.read(str(output), as_version=4).metadata
            papermill = metadata.get("papermill") or {}
            ours = metadata.get("softpend") or {}
            entry.update(executed_s=papermill.get("duration"), executed_at=papermill.get("end_time"),
                         profile=ours.get("profile"), parameters=ours.get("parameters"),
                         overrides=ours.get("overrides"))
        notebooks.append(entry)
    packages, lock_python = _locked_packages(layout.lock_path)
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "profile": profile,
        "overrides": dict(overrides or {}),
        "training_pool": pool,
        "notebooks": notebooks,
        "environment": {"python": platform.python_version(), "lock_python": lock_python,
                        "platform": platform.platform(), "processor": _processor(), "cpu_count": os.cpu_count(),
                        "cpus_available": cpus,
                        "packages": packages},
    }


def _markdown_cell(value: Any) -> str:
    """A Markdown table cell: ``-`` for None, mappings as ``name=value`` code spans, pipes escaped."""
    if value is None:
        return "-"
    if isinstance(value, dict):
        text = ", ".join(f"`{key}={json.dumps(item)}`" for key, item in value.items()) or "none"
    else:
        text = str(value)
    return text.replace("|", "\\|").replace("\n", " ")


def _when(iso: Optional[str]) -> str:
    """``2026-01-31T12:34:56.789+00:00`` as ``2026-01-31 12:34:56``; ``-`` for None."""
    if not iso:
        return "-"
    return str(iso).replace("T", " ")[:19]


def execution_page(record: dict[str, Any]) -> str:
    """The execution page (MyST Markdown) that shows an :func:`execution_record`."""
    env = record["environment"]
    lines = [
        "(execution)=",
        "# Execution",
        "",
        f"The notebooks of this book were executed by `softpend book --profile {record['profile']}`; this page was "
        f"written by that run, on {_when(record['date'])} UTC"
        + (f", with the overrides {_markdown_cell(record['overrides'])}" if record["overrides"] else "")
        + ". For every notebook: what this run did with it (*executed*, *cached*: taken from the execution cache "
        "because its source, parameters and the code it uses were unchanged, or *not run*: not selected), and "
        "the wall time, the end and the profile of its last execution.",
        "",
        "| notebook | this run | last execution [s] | ended (UTC) | profile |",
        "|---|---|---|---|---|",
    ]
    def title(entry: dict[str, Any]) -> str:
        return (f"{{doc}}`{_markdown_cell(entry['title'])} <{entry['name']}>`" if entry["executed_at"]
                else _markdown_cell(entry["title"]))

    for entry in record["notebooks"]:
        seconds = entry["executed_s"]
        lines.append("| " + " | ".join([
            title(entry), entry["this_run"], "-" if seconds is None else f"{seconds:.1f}",
            _when(entry["executed_at"]), _markdown_cell(entry["profile"]),
        ]) + " |")
    total = sum(entry["executed_s"] or 0.0 for entry in record["notebooks"])
    pool = record.get("training_pool")
    lines += [
        "",
        f"Sum of the last execution times: {total:.0f} s.",
    ]
    if pool and pool["trained"] and pool.get("background"):
        lines += [
            "",
            f"This run trained {pool['trained']} of the runs the notebooks read ({', '.join(pool['run_sets'])}) "
            f"in one pool of workers at the lowest scheduling priority, in {pool['run_s']:.0f} s. The notebooks "
            "executed alongside, several at a time, each once the runs it reads had finished; a notebook that "
            "runs the rig's twin in real time executed alone, after the training. The times above are those of a "
            "shared machine.",
            "",
            "| notebook | started [s] | wall [s] |",
            "|---|---|---|",
        ]
        for entry in sorted((entry for entry in record["notebooks"] if entry.get("started_s") is not None),
                            key=lambda entry: entry["started_s"]):
            lines.append(f"| {title(entry)} | {entry['started_s']:.0f} | {entry['run_s']:.1f} |")
    elif pool and pool["trained"]:
        lines += [
            "",
            f"Before the notebooks, this run trained {pool['trained']} of the runs they read "
            f"({', '.join(pool['run_sets'])}) in one pool of workers, in {pool['run_s']:.0f} s; the notebooks "
            "then found them finished, so their times above leave that training out.",
        ]
    lines += [
        "",
        "## Parameters",
        "",
        "The parameters each notebook's last execution set on top of the notebook's own `parameters` cell: "
        "those of its profile in `book/profiles.yml`, then the overrides (`softpend book --set NAME=VALUE`).",
        "",
    ]
    for entry in record["notebooks"]:
        lines.append(f"- {title(entry)}: profile {_markdown_cell(entry['parameters'])}; "
                     f"overrides {_markdown_cell(entry['overrides'])}")
    lines += [
        "",
        "## Environment",
        "",
        "| | |",
        "|---|---|",
        f"| Python | {env['python']} (environment.lock: {env['lock_python'] or '-'}) |",
        f"| platform | {_markdown_cell(env['platform'])} |",
        f"| processor | {_markdown_cell(env.get('processor'))} |",
        f"| CPU count | {env['cpu_count']} ({env['cpus_available']} available to the run) |",
        "",
        "Package versions pinned in `environment.lock`, and the version installed where it differs:",
        "",
        "| package | version | installed |",
        "|---|---|---|",
    ]
    for package in env["packages"]:
        installed = package["installed"]
        lines.append(f"| {package['name']} | {package['locked']} | "
                     f"{'same' if installed == package['locked'] else (installed or 'not installed')} |")
    return "\n".join(lines) + "\n"


def write_execution_record(layout: "BookLayout", record: dict[str, Any]) -> None:
    """Write ``record`` to :attr:`BookLayout.record_path` (JSON) and its page to
    :attr:`BookLayout.execution_page_path`, each atomically."""
    from softpend.io.outputs import atomic_write, json_text

    with atomic_write(layout.record_path, "w") as handle:
        handle.write(json_text(record, indent=2) + "\n")
    with atomic_write(layout.execution_page_path, "w") as handle:
        handle.write(execution_page(record))


# --------------------------------------------------------------------------- HTML
def jupyter_book_command(root: Path | str = ".", path_output: Optional[Path | str] = None) -> list[str]:
    """The ``jupyter-book build`` command line: warnings are errors (``-W -n --keep-going``).

    Jupyter Book 1 writes the HTML to ``<path_output>/_build/html`` (``path_output`` defaults to ``root``).
    """
    script = Path(sys.executable).parent / "jupyter-book"
    executable = str(script) if script.exists() else (shutil.which("jupyter-book") or "jupyter-book")
    root = Path(root).resolve()
    path_output = Path(path_output).resolve() if path_output is not None else root
    return [executable, "build", str(root), "--path-output", str(path_output), "-W", "-n", "--keep-going"]


def build_html(root: Path | str = ".", path_output: Optional[Path | str] = None, quiet: bool = False) -> Path:
    """Build the HTML book from the executed notebooks; returns the HTML folder (``.../_build/html``).

    Raises
    ------
    RuntimeError
        If ``jupyter-book build`` fails or reports a warning.
    """
    layout = BookLayout.at(root)
    command = jupyter_book_command(layout.root, path_output)
    if quiet:
        command.append("-q")
    print("[book] " + " ".join(command), file=sys.stderr, flush=True)
    result = subprocess.run(command, cwd=layout.root)
    if result.returncode != 0:
        raise RuntimeError(f"jupyter-book build failed with exit code {result.returncode} (warnings count as errors)")
    html_dir = Path(command[command.index("--path-output") + 1]) / "_build" / "html"
    if not (html_dir / "index.html").is_file():
        raise RuntimeError(f"jupyter-book build wrote no {html_dir / 'index.html'}")
    return html_dir


def summary(runs: Iterable[NotebookRun]) -> str:
    """One line: how many notebooks were executed and how many came from the cache."""
    runs = list(runs)
    executed = sum(run.status == "executed" for run in runs)
    return f"{executed} notebook(s) executed, {len(runs) - executed} up to date"
