"""The executable book: ``softpend book`` runs the notebooks with papermill, then builds the HTML with Jupyter Book.

``_toc.yml`` lists the notebooks (entries under ``book/_generated/``), ``book/profiles.yml`` their parameters per
profile, ``notebooks/NAME.md`` their jupytext sources.  :func:`run_notebooks` checks every parameter first, then
executes the notebooks in toc order, two at a time, each kernel in the project root, into
``book/_generated/NAME.ipynb``; a notebook whose source, parameters and used ``softpend`` code
(:class:`PackageCode`) are unchanged comes from the cache.  Front matter ``softpend: {after: [...]}`` orders
notebooks; ``softpend: {book_runs: [...]}`` names the runs ``softpend sweep --book`` trains beforehand.  Each
executed notebook ends with a generated "Rerun this figure" section; every run writes the execution page.
"""

from __future__ import annotations

import ast
import hashlib
import io
import json
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
import tokenize
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping, Optional, Sequence

from softpend.io.reading import MAX_CONFIG_BYTES, read_text_checked, read_yaml_checked, yaml_line

DEFAULT_PROFILE = "full"
GENERATED_PREFIX = "book/_generated/"
#: The toc entry under :data:`GENERATED_PREFIX` that is the page the runner writes (not a notebook).
EXECUTION_PAGE = "execution"
#: Bump when the way outputs are produced changes, to invalidate every cached notebook.
_CACHE_VERSION = "3"
#: The keys of a notebook's front matter under ``softpend:`` (any other is an error).
FRONT_MATTER_KEYS = ("after", "book_runs")
#: PNG figures; the kernel logs errors only; tqdm's "IProgress not found" warning would print paths on every page.
_KERNEL_ARGUMENTS = [
    "--InlineBackend.figure_formats=png",
    "--IPKernelApp.log_level=ERROR",
    "--IPKernelApp.exec_lines=__import__('warnings').filterwarnings('ignore', message='IProgress "
    "not found', category=__import__('tqdm').TqdmWarning)",
]


class NotebookExecutionError(RuntimeError):
    """A notebook raised while executing; the partially executed output is kept at ``output_path``.
    ``cell_index`` counts every cell of the source, ``code_cell_number`` its code cells from 1."""

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
        self.notebook, self.cell_index, self.code_cell_number = notebook, cell_index, code_cell_number
        self.execution_count, self.output_path = execution_count, output_path


@dataclass(frozen=True)
class BookLayout:
    """Where the book's files live below a project root."""

    root: Path

    @classmethod
    def at(cls, root: Path | str = ".") -> "BookLayout":
        layout = cls(Path(root).resolve())
        if (layout.root / "_toc.yml").exists() and not (layout.root / "_toc.yml").is_file():
            raise ValueError(f"{layout.root / '_toc.yml'} is not a regular file")
        if not (layout.root / "_toc.yml").is_file():
            raise FileNotFoundError(f"no _toc.yml in {layout.root} (run from the project root or pass --root)")
        return layout

    toc_path = property(lambda self: self.root / "_toc.yml")
    profiles_path = property(lambda self: self.root / "book" / "profiles.yml")
    generated_dir = property(lambda self: self.root / GENERATED_PREFIX.rstrip("/"))
    record_path = property(lambda self: self.generated_dir / f"{EXECUTION_PAGE}.json")
    execution_page_path = property(lambda self: self.generated_dir / f"{EXECUTION_PAGE}.md")
    #: What ``softpend sweep --book`` trained last (:func:`softpend.study.run_pool.train_book`).
    training_path = property(lambda self: self.generated_dir / "training.json")

    def source_path(self, name: str) -> Path:
        return self.root / "notebooks" / f"{name}.md"

    def output_path(self, name: str) -> Path:
        return self.generated_dir / f"{name}.ipynb"

    def key_path(self, name: str) -> Path:
        return self.generated_dir / f"{name}.sha256"


@dataclass(frozen=True)
class NotebookRun:
    """What :func:`run_notebooks` did with one notebook: ``status`` is ``"executed"`` or ``"cached"``."""

    name: str
    status: str
    seconds: float
    output_path: Path


# --------------------------------------------------------------------------- configuration
def _load_yaml(path: Path | str, what: str) -> Any:
    """The YAML document at ``path`` through the checked reader (a regular file of bounded size; a syntax
    error names the file and the line), its mappings and lists knowing their lines (:func:`yaml_line`)."""
    return read_yaml_checked(path, what, lines=True)


def _shape_error(path: Path | str, node: Any, key: Any, expected: str, got: Any) -> ValueError:
    """``ValueError`` naming the file, the line of ``key`` in ``node`` and what was expected there."""
    return ValueError(f"{path}, line {yaml_line(node, key)}: expected {expected}, got {_kind(got)}")


def _kind(value: Any) -> str:
    return "nothing" if value is None else f"{type(value).__name__.removeprefix('Line').lower()} {value!r}"[:80]


def _check_toc(path: Path | str, toc: Any) -> None:
    """``_toc.yml`` has the shape jupyter-book reads: a mapping with ``root``; ``parts``, ``chapters`` and
    ``sections`` lists of mappings; ``file``, ``root`` and ``caption`` strings."""
    if not isinstance(toc, dict):
        raise _shape_error(path, toc, None, "a mapping with format, root and parts or chapters", toc)
    if "root" not in toc:
        raise ValueError(f"{path}, line {yaml_line(toc)}: expected a 'root' entry (the book's first page)")

    def walk(node: dict) -> None:
        for key, value in node.items():
            if key in ("file", "root", "caption", "format", "title", "url") and not isinstance(value, str):
                raise _shape_error(path, node, key, f"'{key}' to be a string", value)
            if key in ("parts", "chapters", "sections") and value is not None:  # (an empty entry lists nothing)
                if not isinstance(value, list):
                    raise _shape_error(path, node, key, f"'{key}' to be a list of entries", value)
                for index, entry in enumerate(value):
                    if not isinstance(entry, dict):
                        raise _shape_error(path, value, index, f"each of '{key}' to be a mapping (file: ...)", entry)
                    walk(entry)

    walk(toc)


def toc_notebooks(toc_path: Path | str) -> list[str]:
    """Names of the executed notebooks in a ``_toc.yml`` (its ``file``/``root`` entries under
    ``book/_generated/`` except the execution page), in reading order."""

    def files(node: Any) -> Iterable[str]:
        for key, value in node.items() if isinstance(node, dict) else enumerate(node if isinstance(node, list) else []):
            yield from [value] if key in ("file", "root") and isinstance(value, str) else files(value)

    toc = _load_yaml(Path(toc_path), "table of contents")
    _check_toc(toc_path, toc)
    entries = [entry.removesuffix(".ipynb") for entry in files(toc)]
    names = [
        entry[len(GENERATED_PREFIX) :]
        for entry in entries
        if entry.startswith(GENERATED_PREFIX) and entry != GENERATED_PREFIX + EXECUTION_PAGE
    ]
    if duplicates := sorted({name for name in names if names.count(name) > 1}):
        raise ValueError(f"{toc_path}: notebook(s) listed more than once: {duplicates}")
    return names


def load_profiles(path: Path | str) -> dict[str, dict[str, dict[str, Any]]]:
    """``profiles.yml`` as ``profile -> notebook -> {parameter: value}`` (empty: the notebook's defaults)."""
    data = _load_yaml(path, "profiles file") or {}
    if not isinstance(data, dict):
        raise _shape_error(path, data, None, "a mapping profile -> notebook -> parameters", data)
    for profile, notebooks in data.items():
        if not isinstance(notebooks or {}, dict):
            raise _shape_error(
                path, data, profile, f"a mapping notebook -> parameters for profile {profile!r}", notebooks
            )
        for notebook, parameters in (notebooks or {}).items():
            if not isinstance(parameters or {}, dict) or not all(isinstance(key, str) for key in parameters or {}):
                raise _shape_error(
                    path,
                    notebooks,
                    notebook,
                    f"a mapping parameter -> value for notebook {notebook!r} of profile {profile!r}",
                    parameters,
                )
    return {
        str(profile): {str(notebook): dict(parameters or {}) for notebook, parameters in (notebooks or {}).items()}
        for profile, notebooks in data.items()
    }


def read_notebook(source_path: Path | str):
    """A jupytext MyST notebook as an ``nbformat`` notebook (no outputs)."""
    import jupytext

    return jupytext.reads(_source_text(source_path), fmt="md:myst")  # FileNotFoundError naming it when missing


def _source_text(source_path: Path | str) -> str:
    """A notebook source through the checked reader (a regular file of bounded size: a FIFO never blocks)."""
    return read_text_checked(source_path, "notebook source", MAX_CONFIG_BYTES)


def _parameters_cell(nb) -> Optional[str]:
    return next(
        (
            cell.source
            for cell in nb.cells
            if cell.cell_type == "code" and "parameters" in cell.get("metadata", {}).get("tags", [])
        ),
        None,
    )


def check_parameters(notebook_path: Path | str, name: str, parameters: dict[str, Any]) -> dict[str, Any]:
    """The parameters the notebook (``.ipynb``) declares (``papermill.inspect_notebook``); ``ValueError`` when it
    has no cell tagged ``parameters`` or ``parameters`` names one it does not define."""
    import nbformat
    import papermill

    if _parameters_cell(nbformat.read(str(notebook_path), as_version=4)) is None:
        raise ValueError(f"notebook {name!r} has no code cell tagged 'parameters'")
    declared = papermill.inspect_notebook(str(notebook_path))
    if unknown := sorted(set(parameters) - set(declared)):
        raise ValueError(
            f"notebook {name!r}: parameter(s) {unknown} are not defined in its parameters cell "
            f"(it defines {sorted(declared)})"
        )
    return declared


def front_matter(nb, name: str, known: Sequence[str]) -> dict[str, list[str]]:
    """The notebook's ``softpend:`` front matter, checked: ``after`` (toc notebooks it waits for) and
    ``book_runs`` (the run sets ``softpend sweep --book`` trains for it, checked there); any other key is an error."""
    meta = nb.metadata.get("softpend") or {}
    if unknown := sorted(set(meta) - set(FRONT_MATTER_KEYS)):
        raise ValueError(f"notebook {name!r}: unknown front-matter key(s) softpend.{', softpend.'.join(unknown)}")
    after = meta.get("after", [])
    if not isinstance(after, list) or not all(entry in known and entry != name for entry in after):
        raise ValueError(f"notebook {name!r}: softpend.after must list other notebooks of _toc.yml, got {after!r}")
    return {"after": list(after), "book_runs": meta.get("book_runs", [])}


def execution_order(names: Sequence[str], after: Mapping[str, Sequence[str]]) -> list[str]:
    """``names`` in toc order, except that a notebook follows the selected notebooks of its ``after``."""
    selected, pending, done = set(names), list(names), []
    while pending:
        ready = next(
            (name for name in pending if all(dep in done or dep not in selected for dep in after.get(name, ()))), None
        )
        if ready is None:
            raise ValueError(f"notebooks {pending} wait for each other (softpend.after in their front matter)")
        pending.remove(ready)
        done.append(ready)
    return done


# --------------------------------------------------------------------------- cache
#: Suffixes of non-Python files inside the package that count as data the code may read.
DATA_SUFFIXES = (".csv", ".json", ".npy", ".npz", ".toml", ".txt", ".yaml", ".yml")


def _drop_docstrings(tree: ast.AST) -> ast.AST:
    """Remove every bare string statement (docstrings) from ``tree``; an emptied body becomes ``pass``."""
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list):
            kept = [
                s
                for s in body
                if not (
                    isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant) and isinstance(s.value.value, str)
                )
            ]
            if len(kept) != len(body):
                setattr(node, "body", kept or [ast.Pass()])
    return tree


def _parse_cell(source: str) -> Optional[ast.Module]:
    """A code cell as an ``ast`` tree (IPython magics translated); None when it does not parse."""
    from IPython.core.inputtransformer2 import TransformerManager

    for text in (source, TransformerManager().transform_cell(source)):
        try:
            return ast.parse(text)
        except SyntaxError:
            continue
    return None


class PackageCode:
    """The modules of one package (default: the installed ``softpend``), read with ``ast``: the closure of a
    piece of code's imports over the package's own, and a hash of each module's code without docstrings and
    comments.  Imports anywhere count (in functions, relative ones resolved, a package's ``__init__`` with each
    submodule), and so does a string constant naming a module, alone or as an entry point (``"pkg.a:Name"``)."""

    def __init__(self, package_root: Path | str | None = None) -> None:
        self.root = Path(package_root or Path(__file__).resolve().parents[1]).resolve()
        if not (self.root / "__init__.py").is_file():
            raise ValueError(f"package_root must be a package directory with an __init__.py, got {self.root}")
        self.name = self.root.name
        self.modules: dict[str, Path] = {}
        for path in sorted(self.root.rglob("*.py")):
            if "__pycache__" not in path.parts:
                parts = path.relative_to(self.root).with_suffix("").parts
                self.modules[".".join((self.name, *parts[: -1 if parts[-1] == "__init__" else None]))] = path
        self._read: dict[str, tuple[str, frozenset[str]]] = {}  # module -> (hash, imports)
        self._entry_point = re.compile(rf"\b{re.escape(self.name)}(?:\.[A-Za-z_]\w*)*(?=:[A-Za-z_])")

    def _module(self, module: str) -> tuple[str, frozenset[str]]:
        """The module's hash (``ast.dump`` without docstrings: comments and layout do not count) and imports."""
        if module not in self._read:
            path = self.modules[module]
            tree = _drop_docstrings(ast.parse(path.read_text(encoding="utf-8"), filename=str(path)))
            self._read[module] = (
                hashlib.sha256(ast.dump(tree).encode()).hexdigest(),
                frozenset(self._tree_imports(tree, module)),
            )
        return self._read[module]

    def _with_parents(self, module: str) -> set[str]:
        parts = module.split(".")
        return {name for name in (".".join(parts[: i + 1]) for i in range(len(parts))) if name in self.modules}

    def _tree_imports(self, tree: ast.AST, module: Optional[str] = None) -> set[str]:
        found: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    found |= self._with_parents(alias.name)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    if module is None:
                        continue
                    base = module.split(".")[: None if self.modules[module].name == "__init__.py" else -1]
                    target = ".".join(base[: len(base) - (node.level - 1)] + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                found |= self._with_parents(target)
                for alias in node.names:
                    found |= self._with_parents(f"{target}.{alias.name}")
            elif isinstance(node, ast.Constant) and isinstance(node.value, str) and self.name in node.value:
                found |= self._with_parents(node.value.strip()) if node.value.strip() in self.modules else set()
                for match in self._entry_point.finditer(node.value):
                    found |= self._with_parents(match.group(0))
        found.discard(module)
        return found

    def closure(self, code_cells: Iterable[str]) -> set[str]:
        """Modules the code uses, directly or through the package's imports; all of them when a cell does not
        parse."""
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
                pending |= self._module(module)[1] - used
        return used

    def code_hashes(self, code_cells: Iterable[str]) -> dict[str, str]:
        """The package's part of a notebook's cache key: the hash of each module the code uses and of each data file
        of the package (suffix in :data:`DATA_SUFFIXES`)."""
        hashes = {module: self._module(module)[0] for module in sorted(self.closure(code_cells))}
        return hashes | {
            f"{self.name}/{path.relative_to(self.root).as_posix()}": hashlib.sha256(path.read_bytes()).hexdigest()
            for path in sorted(self.root.rglob("*"))
            if path.is_file() and path.suffix in DATA_SUFFIXES and "__pycache__" not in path.parts
        }


def code_cells(nb) -> list[str]:
    return [cell.source for cell in nb.cells if cell.cell_type == "code"]


def _data_hashes(layout: BookLayout, folder_name: str) -> dict[str, str]:
    """SHA-256 of every file under ``book/<folder_name>/`` (data that package code reads: stored run records,
    the methods' tuned settings)."""
    folder = layout.root / "book" / folder_name
    return (
        {
            f"book/{folder_name}/{path.relative_to(folder).as_posix()}": hashlib.sha256(path.read_bytes()).hexdigest()
            for path in sorted(folder.rglob("*"))
            if path.is_file()
        }
        if folder.is_dir()
        else {}
    )


def cache_key(source_text: str, parameters: dict[str, Any], code_hashes: dict[str, str], after: Any = None) -> str:
    """Cache key of one executed notebook: source, parameters, package code and the keys of its ``after``."""
    payload = {
        "version": _CACHE_VERSION,
        "source": source_text,
        "parameters": parameters,
        "code": sorted(code_hashes.items()),
        **({"after": after} if after else {}),
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=repr).encode()).hexdigest()


# --------------------------------------------------------------------------- "Rerun this figure"
#: Units read from a parameter name's suffix (a ``[unit]`` in the line's comment comes first).
UNIT_SUFFIXES = (
    ("_rad_s", "rad/s"),
    ("_nm", "N m"),
    ("_ms", "ms"),
    ("_mm", "mm"),
    ("_rad", "rad"),
    ("_deg", "deg"),
    ("_hz", "Hz"),
    ("_fps", "1/s"),
    ("_kg", "kg"),
    ("_dn", "DN"),
    ("_s", "s"),
    ("_m", "m"),
)


def _value(value: Any) -> str:
    """A value as ``--set NAME=VALUE`` reads it: JSON, else its text."""
    return value if isinstance(value, str) else json.dumps(value, separators=(",", ":"), default=repr)


def notebook_parameters(cell: str) -> list[dict[str, Any]]:
    """The assignments of a ``parameters`` cell: ``name``, ``default`` (its value as ``--set`` reads it, or the
    expression where the cell does not evaluate: ``evaluated`` False), ``unit`` and the line's ``comment``."""
    comments = {
        token.start[0]: token.string.lstrip("#").strip()
        for token in tokenize.generate_tokens(io.StringIO(cell).readline)
        if token.type == tokenize.COMMENT
    }
    namespace: dict[str, Any] = {}
    try:
        exec(compile(cell, "<parameters>", "exec"), namespace)  # noqa: S102 -- assignments, imports of presets
    except Exception:  # noqa: BLE001 -- the expression is shown instead
        namespace = {}
    found = []
    for node in ast.parse(cell).body:
        target = node.targets[0] if isinstance(node, ast.Assign) and len(node.targets) == 1 else None
        if isinstance(target, ast.Name):
            assert isinstance(node, ast.Assign) and node.end_lineno is not None  # a parsed assignment's lines
            comment, name = comments.get(node.end_lineno, ""), target.id
            unit = re.search(r"\[([^\],'\"]+)\]", comment)  # "[N m]", not "[16, 16]"
            found.append(
                {
                    "name": name,
                    "evaluated": name in namespace,
                    "comment": comment,
                    "default": _value(namespace[name])
                    if name in namespace
                    else ast.get_source_segment(cell, node.value),
                    "unit": unit.group(1)
                    if unit
                    else next((label for end, label in UNIT_SUFFIXES if name.endswith(end)), ""),
                }
            )
    return found


def _md(value: Any, limit: int = 0) -> str:
    """A table cell: ``-`` for None, mappings as ``name=value`` code spans, cut to ``limit`` characters."""
    if isinstance(value, dict):
        return ", ".join(f"`{key}={json.dumps(item)}`" for key, item in value.items()) or "none"
    text = "-" if value is None else str(value)
    text = text if not limit or len(text) <= limit else text[: limit - 3] + "..."
    return text.replace("|", "\\|").replace("\n", " ").replace("<", "&lt;")


def rerun_section(name: str, cell: str, profile: str, used: dict[str, Any]) -> str:
    """The generated closing section of an executed notebook: its parameters and the command that reruns it."""
    rows = notebook_parameters(cell)
    lines = [
        f"## Rerun this {'figure' if name.startswith('fig') else 'chapter'}",
        "",
        f"This page was executed by `softpend book --profile {profile}` with the parameters below (defaults "
        "from the notebook's `parameters` cell; *this build* where the profile or `--set` changed one).",
        "",
        "| parameter | default | this build | unit | meaning |",
        "|---|---|---|---|---|",
    ]
    for row in rows:
        build = f"`{_md(_value(used[row['name']]), 60)}`" if row["name"] in used else ""
        lines.append(
            f"| `{row['name']}` | `{_md(row['default'], 60)}` | {build} | {row['unit']} | {_md(row['comment'], 90)} |"
        )
    example = next((f"{row['name']}={row['default']}" for row in rows if row["evaluated"]), "NAME=VALUE")
    command = [
        "softpend",
        "book",
        "--only",
        name,
        *(["--profile", profile] if profile != DEFAULT_PROFILE else []),
        "--set",
        example,
    ]
    lines += [
        "",
        "To rerun it from the project root with other values (one `--set NAME=VALUE` per parameter, "
        "VALUE as JSON, else a string; add `--html` to rebuild the page):",
        "",
        "```bash",
        shlex.join(command),
        "```",
    ]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- execution
def _execute_one(layout: BookLayout, name: str, plan: dict[str, Any]) -> float:
    """Execute one notebook (kernel in the project root); returns its wall time.  The output ends with the
    rerun section and its injected-parameters cell is folded."""
    import nbformat
    import papermill
    from papermill.exceptions import PapermillExecutionError

    output, key_path = layout.output_path(name), layout.key_path(name)
    key_path.unlink(missing_ok=True)  # an interrupted or failed run must not look cached
    start = time.perf_counter()
    try:  # nbclient starts the kernel in resources' path: papermill's own cwd= would chdir this whole process
        papermill.execute_notebook(
            str(plan["converted"]),
            str(output),
            parameters=plan["parameters"],
            kernel_name=plan["kernel"],
            progress_bar=False,
            extra_arguments=_KERNEL_ARGUMENTS,
            resources={"metadata": {"path": str(layout.root)}},
        )
    except PapermillExecutionError as exc:
        source_nb, at = nbformat.read(str(plan["converted"]), as_version=4), exc.cell_index
        matches = [i for i, c in enumerate(source_nb.cells) if c.cell_type == "code" and c.source == exc.source]
        index = min(matches, key=lambda i: abs(i - at)) if matches else -1
        number = sum(c.cell_type == "code" for c in source_nb.cells[: index + 1]) if matches else 0
        raise NotebookExecutionError(
            name, index, number, exc.exec_count, exc.source, f"{exc.ename}: {exc.evalue}", output
        ) from None
    seconds = time.perf_counter() - start
    nb = nbformat.read(str(output), as_version=4)
    nb.metadata["softpend"] = plan["record"]  # read back by the execution record
    for cell in nb.cells:
        tags = cell.get("metadata", {}).get("tags", [])
        if "injected-parameters" in tags and "hide-input" not in tags:
            cell.metadata["tags"] = [*tags, "hide-input"]
    nb.cells.append(nbformat.v4.new_markdown_cell(plan["rerun"]))
    nbformat.write(nb, str(output))
    key_path.write_text(plan["key"] + "\n", encoding="utf-8")
    return seconds


def run_notebooks(
    root: Path | str = ".",
    profile: str = DEFAULT_PROFILE,
    only: Optional[Sequence[str]] = None,
    force: bool = False,
    progress: bool = True,
    overrides: Optional[dict[str, Any]] = None,
    workers: int = 2,
) -> list[NotebookRun]:
    """Execute the book's notebooks with a profile's parameters into ``book/_generated/``, ``workers`` at a time;
    returns one entry per selected notebook (``only``: names) in execution order, and writes the execution page.
    ``overrides`` (``--set``) apply to every selected notebook whose ``parameters`` cell defines them.  Every
    ``ValueError`` (unknown profile, notebook, parameter, override or front-matter key) comes before anything
    executes; a failing notebook raises :class:`NotebookExecutionError` once the running ones have finished."""
    import nbformat

    layout = BookLayout.at(root)
    toc = toc_notebooks(layout.toc_path)
    profiles = load_profiles(layout.profiles_path)
    if profile not in profiles:
        raise ValueError(f"unknown profile {profile!r}; {layout.profiles_path} defines {sorted(profiles)}")
    for what, listed in ((f"profile {profile!r} names", profiles[profile]), ("--only names", only or [])):
        if unknown := sorted(set(listed) - set(toc)):
            raise ValueError(f"{what} unknown notebook(s) {unknown}; _toc.yml lists {toc}")
    names = [name for name in toc if name in set(only)] if only else toc
    overrides, used_overrides = dict(overrides or {}), {}
    package_code, plans, after = PackageCode(), {}, {}
    layout.generated_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="softpend-book-") as scratch:
        for name in names:  # check everything first: a typo should not surface after an hour of execution
            nb = read_notebook(layout.source_path(name))
            after[name] = front_matter(nb, name, toc)["after"]
            parameters = dict(profiles[profile].get(name, {}))
            converted = Path(scratch) / f"{name}.ipynb"
            nbformat.write(nb, str(converted))
            declared = check_parameters(converted, name, parameters)
            applied = {key: value for key, value in overrides.items() if key in declared}
            record = {"profile": profile, "parameters": dict(parameters), "overrides": applied}
            used_overrides.update(applied)
            parameters.update(applied)
            hashes = package_code.code_hashes(code_cells(nb))
            # data files that package code reads are inputs of that code
            for module, folder_name in (("softpend.study.records", "records"), ("softpend.study.presets", "hparams")):
                if module in hashes:
                    hashes.update(_data_hashes(layout, folder_name))
            plans[name] = {
                "parameters": parameters,
                "converted": converted,
                "hashes": hashes,
                "record": record,
                "kernel": nb.metadata.get("kernelspec", {}).get("name", "python3"),
                "rerun": rerun_section(name, _parameters_cell(nb) or "", profile, parameters),
            }
        if unused := sorted(set(overrides) - set(used_overrides)):
            raise ValueError(f"override(s) {unused} are not parameters of any selected notebook ({names})")
        order = execution_order(names, after)
        cached = {}
        for name in order:  # upstream keys: this run's, else the key files on disk
            upstream = {
                dep: plans[dep]["key"]
                if dep in plans
                else (layout.key_path(dep).read_text().strip() if layout.key_path(dep).is_file() else "absent")
                for dep in after[name]
            }
            source = _source_text(layout.source_path(name))
            plans[name]["key"] = key = cache_key(source, plans[name]["parameters"], plans[name]["hashes"], upstream)
            cached[name] = (
                not force
                and layout.output_path(name).is_file()
                and layout.key_path(name).is_file()
                and layout.key_path(name).read_text(encoding="utf-8").strip() == key
            )
        seconds = _execute(layout, order, plans, after, cached, progress, max(1, int(workers)))
    runs = [
        NotebookRun(name, "cached" if cached[name] else "executed", seconds.get(name, 0.0), layout.output_path(name))
        for name in order
    ]
    write_execution_record(layout, profile, runs, used_overrides)
    return runs


def _execute(
    layout: BookLayout, order: Sequence[str], plans: dict, after: dict, cached: dict, progress: bool, workers: int
) -> dict[str, float]:
    """Execute the notebooks of ``order`` that are not cached, ``workers`` at a time, each once the selected
    notebooks of its ``after`` have finished; after a failure nothing more starts and the first error is raised."""
    say = (lambda text: print(f"[book] {text}", file=sys.stderr, flush=True)) if progress else (lambda text: None)
    running: dict[Future[float], str]
    errors: list[BaseException]
    pending, running, seconds, errors = [name for name in order if not cached[name]], {}, {}, []
    done = {name for name in order if cached[name]}
    for name in (name for name in order if name in done):
        say(f"{name}: up to date (cached)")
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="softpend-book") as pool:
        while pending or running:
            ready = [name for name in pending if all(dep in done or dep not in order for dep in after[name])]
            for name in ready[: workers - len(running)] if not errors else []:
                pending.remove(name)
                say(f"{name}: executing")
                running[pool.submit(_execute_one, layout, name, plans[name])] = name
            if not running:
                break
            for future in wait(running, return_when=FIRST_COMPLETED).done:
                name = running.pop(future)
                if (error := future.exception()) is not None:
                    errors.append(error)
                    say(f"{name} failed" + ("; waiting for the running notebooks" if running else ""))
                else:
                    done.add(name)
                    seconds[name] = future.result()
                    say(f"{name}: executed in {seconds[name]:.1f} s")
    if errors:
        raise errors[0]
    return seconds


# --------------------------------------------------------------------------- execution page
def _processor(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The processor model (name, family, model of ``/proc/cpuinfo``; else what :mod:`platform` says)."""
    first = cpuinfo.read_text().split("\n\n")[0] if cpuinfo.is_file() else ""
    fields = {key.strip(): value.strip() for key, _, value in (line.partition(":") for line in first.splitlines())}
    if fields.get("model name"):
        return f"{fields['model name']} (family {fields.get('cpu family', '-')}, model {fields.get('model', '-')})"
    return platform.processor() or platform.machine() or "-"


def write_execution_record(
    layout: BookLayout, profile: str, runs: Sequence[NotebookRun], overrides: Optional[dict[str, Any]] = None
) -> dict[str, Any]:
    """Write (atomically) and return what produced ``book/_generated/`` (``execution.json``) and its page
    (``execution.md``): per toc notebook this run's status and its last execution's wall time, end and profile;
    the training step (``training.json`` of ``softpend sweep --book``); the machine."""
    import datetime

    import nbformat

    from softpend.io.outputs import atomic_write, json_text

    this_run, notebooks = {run.name: run for run in runs}, []
    for name in toc_notebooks(layout.toc_path):
        lines = _source_text(layout.source_path(name)).splitlines()
        entry = {
            "name": name,
            "title": next((line[2:].strip() for line in lines if line.startswith("# ")), name),
            "this_run": this_run[name].status if name in this_run else "not run",
            "executed_s": None,
            "executed_at": None,
            "profile": None,
        }
        if layout.output_path(name).is_file():
            meta = nbformat.read(str(layout.output_path(name)), as_version=4).metadata
            entry.update(
                executed_s=meta.get("papermill", {}).get("duration"),
                executed_at=meta.get("papermill", {}).get("end_time"),
                profile=meta.get("softpend", {}).get("profile"),
            )
        notebooks.append(entry)
    training = json.loads(layout.training_path.read_text()) if layout.training_path.is_file() else None
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    record = {
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "profile": profile,
        "overrides": dict(overrides or {}),
        "training": training,
        "notebooks": notebooks,
        "machine": {
            "processor": _processor(),
            "cpu_count": os.cpu_count(),
            "cpus_available": cpus,
            "platform": platform.platform(),
            "python": platform.python_version(),
        },
    }
    with atomic_write(layout.record_path, "w") as handle:
        handle.write(json_text(record, indent=2) + "\n")
    with atomic_write(layout.execution_page_path, "w") as handle:
        handle.write(execution_page(record))
    return record


def execution_page(record: dict[str, Any]) -> str:
    """The execution page (MyST Markdown) of a :func:`write_execution_record` record."""
    machine, training = record["machine"], record["training"]
    when = lambda iso: str(iso).replace("T", " ")[:19] if iso else "-"  # noqa: E731
    lines = [
        "(execution)=",
        "# Execution",
        "",
        f"Written by `softpend book --profile {record['profile']}` on {when(record['date'])} UTC"
        + (f" with {_md(record['overrides'])}" if record["overrides"] else "")
        + ". Per notebook: what this run "
        "did (*executed*; *cached*: its source, parameters and the code it uses were unchanged; *not run*: not "
        "selected) and its last execution. Each chapter ends with its parameters and the command that reruns it.",
        "",
        "| notebook | this run | last execution [s] | ended (UTC) | profile |",
        "|---|---|---|---|---|",
    ]
    for e in record["notebooks"]:
        title = f"{{doc}}`{_md(e['title'])} <{e['name']}>`" if e["executed_at"] else _md(e["title"])
        seconds = "-" if e["executed_s"] is None else f"{e['executed_s']:.1f}"
        lines.append(f"| {title} | {e['this_run']} | {seconds} | {when(e['executed_at'])} | {_md(e['profile'])} |")
    total = sum(e["executed_s"] or 0.0 for e in record["notebooks"])
    lines += [
        "",
        f"Sum of the last execution times: {total:.0f} s.",
        "",
        "## Training step",
        "",
        f"`softpend sweep --book --profile {training['profile']}` on {when(training['date'])} UTC trained "
        f"{len(training['trained'])} run(s) the notebooks read (the others were there already) in "
        f"{training['seconds']:.0f} s, with {training['workers']} worker(s)."
        if training
        else "No training step recorded (`softpend sweep --book`): the notebooks trained the runs they read.",
        "",
        "## Machine",
        "",
        "| | |",
        "|---|---|",
        f"| processor | {_md(machine['processor'])} |",
        f"| CPU cores | {machine['cpu_count']} ({machine['cpus_available']} available to the run) |",
        f"| platform | {_md(machine['platform'])}, Python {machine['python']} (packages: `environment.lock`) |",
    ]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- HTML
def build_html(root: Path | str = ".", path_output: Optional[Path | str] = None, quiet: bool = False) -> Path:
    """``jupyter-book build`` (warnings as errors) of the executed notebooks; returns the HTML folder
    ``<path_output or root>/_build/html`` (``RuntimeError`` on failure)."""
    layout = BookLayout.at(root)
    script = Path(sys.executable).parent / "jupyter-book"
    output = Path(path_output if path_output is not None else layout.root).resolve()
    command = [
        str(script) if script.exists() else (shutil.which("jupyter-book") or "jupyter-book"),
        "build",
        str(layout.root),
        "--path-output",
        str(output),
        "-W",
        "-n",
        "--keep-going",
    ] + (["-q"] if quiet else [])
    print("[book] " + " ".join(command), file=sys.stderr, flush=True)
    if subprocess.run(command, cwd=layout.root).returncode != 0:
        raise RuntimeError("jupyter-book build failed (warnings count as errors)")
    if not (output / "_build" / "html" / "index.html").is_file():
        raise RuntimeError(f"jupyter-book build wrote no {output / '_build' / 'html' / 'index.html'}")
    return output / "_build" / "html"
