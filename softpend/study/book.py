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
(the execution cache).  :func:`build_html` then runs ``jupyter-book build`` with warnings as
errors; the book itself never executes notebooks.
"""

from __future__ import annotations

import ast
import hashlib
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

__all__ = [
    "BookLayout",
    "DEFAULT_PROFILE",
    "NotebookExecutionError",
    "NotebookRun",
    "PackageCode",
    "build_html",
    "cache_key",
    "check_parameters",
    "code_cells",
    "load_profiles",
    "profile_parameters",
    "read_notebook",
    "run_notebooks",
    "toc_notebooks",
]

#: Profile used when none is given: the parameters that produce the published figures.
DEFAULT_PROFILE = "full"
#: Prefix of toc entries that are executed notebooks.
GENERATED_PREFIX = "book/_generated/"
#: Bump when the way outputs are produced changes, to invalidate every cached notebook.
_CACHE_VERSION = "2"
#: Kernel arguments: matplotlib figures are embedded in the notebooks (and the book) as PNG images.
#: (The kernel's own log is limited to errors: a failing cell is reported from the notebook's outputs.)
_KERNEL_ARGUMENTS = ["--InlineBackend.figure_formats=png", "--IPKernelApp.log_level=ERROR"]


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


@dataclass(frozen=True)
class NotebookRun:
    """What :func:`run_notebooks` did with one notebook."""

    name: str
    status: str  # "executed" or "cached"
    seconds: float
    output_path: Path


# --------------------------------------------------------------------------- configuration
def _load_yaml(path: Path) -> Any:
    import yaml

    with open(path, encoding="utf-8") as handle:
        return yaml.safe_load(handle)


def toc_notebooks(toc_path: Path | str) -> list[str]:
    """Names of the executed notebooks in a ``_toc.yml``, in reading order.

    Every ``file:`` entry (root, chapters, parts, sections) that starts with ``book/_generated/`` is a
    notebook whose source is ``notebooks/<name>.md``.
    """
    names: list[str] = []

    def visit(node: Any) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                if key in ("file", "root") and isinstance(value, str):
                    entry = value.removesuffix(".ipynb")
                    if entry.startswith(GENERATED_PREFIX):
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
            cwd=str(layout.root),
            extra_arguments=list(_KERNEL_ARGUMENTS),
        )
    except PapermillExecutionError as exc:
        source_nb = nbformat.read(str(converted_path), as_version=4)
        cell_index, code_number = _locate_cell(source_nb, exc.cell_index, exc.source)
        raise NotebookExecutionError(
            name, cell_index, code_number, exc.exec_count, exc.source, f"{exc.ename}: {exc.evalue}", output_path
        ) from None
    key_path.write_text(key + "\n", encoding="utf-8")


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
        One entry per selected notebook.

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
    from tqdm.auto import tqdm

    layout = BookLayout.at(root)
    names = toc_notebooks(layout.toc_path)
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
        plan = []
        for name in names:
            nb = read_notebook(layout.source_path(name))
            parameters = profile_parameters(profiles, profile, name)
            nb.metadata["softpend"] = {"profile": profile, "source": f"notebooks/{name}.md"}
            converted = Path(scratch) / f"{name}.ipynb"
            nbformat.write(nb, str(converted))
            declared = check_parameters(converted, name, parameters)
            applied = {key: value for key, value in overrides.items() if key in declared}
            used_overrides.update(applied)
            parameters.update(applied)
            source_text = layout.source_path(name).read_text(encoding="utf-8")
            hashes = package_code.code_hashes(code_cells(nb))
            if "softpend.study.records" in hashes:  # the stored run records are an input of that code
                hashes.update(_records_hashes(layout))
            plan.append((name, parameters, converted, cache_key(source_text, parameters, hashes)))
        unused = sorted(set(overrides) - set(used_overrides))
        if unused:
            raise ValueError(f"override(s) {unused} are not parameters of any selected notebook ({names})")

        bar = tqdm(plan, desc=f"book [{profile}]", unit="notebook", disable=not progress, file=sys.stderr)
        for name, parameters, converted, key in bar:
            bar.set_postfix_str(name)
            start = time.perf_counter()
            output_path = layout.output_path(name)
            key_path = layout.key_path(name)
            cached = (
                not force
                and output_path.is_file()
                and key_path.is_file()
                and key_path.read_text(encoding="utf-8").strip() == key
            )
            if not cached:
                _execute_one(layout, name, parameters, key, converted)
            seconds = time.perf_counter() - start
            runs.append(NotebookRun(name, "cached" if cached else "executed", seconds, output_path))
            if progress:
                what = "up to date (cached)" if cached else f"executed in {seconds:.1f} s"
                bar.write(f"[book] {name}: {what}", file=sys.stderr)
    return runs


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
