"""``softpend book``: execute the notebooks of ``_toc.yml`` with papermill under a profile of ``book/profiles.yml``,
cached by source, parameters and the ``softpend`` code they use; write the execution page; build the HTML."""

from __future__ import annotations

import ast
import datetime
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
import threading
import time
import tokenize
from collections import namedtuple
from concurrent.futures import Future, ThreadPoolExecutor, wait
from pathlib import Path
from typing import Any, Iterable, Mapping, Optional, Sequence

from softpend.io.outputs import atomic_write, json_text
from softpend.io.reading import MAX_CONFIG_BYTES, read_json_object, read_text_checked, read_yaml_checked, yaml_line

DEFAULT_PROFILE = "full"
GENERATED_PREFIX = "book/_generated/"
EXECUTION_PAGE = "execution"  # the toc entry under GENERATED_PREFIX that the runner writes (not a notebook)
WORKERS = 2  # notebooks executing at once
_CACHE_VERSION = "3"  # bump to invalidate every cached notebook
FRONT_MATTER_KEYS = ("after", "book_runs")  # a notebook's front matter under ``softpend:``
DATA_SUFFIXES = (".csv", ".json", ".npy", ".npz", ".toml", ".txt", ".yaml", ".yml")  # the package's data files
_KERNEL_ARGS = [
    "--InlineBackend.figure_formats=png",
    "--IPKernelApp.log_level=ERROR",
    "--IPKernelApp.exec_lines=__import__('warnings').filterwarnings('ignore', message='IProgress "
    "not found', category=__import__('tqdm').TqdmWarning)",
]


class NotebookExecutionError(RuntimeError):
    """A notebook raised while executing; the partial output is kept at ``output_path``."""

    def __init__(self, message: str, cell_index: int, code_cell_number: int, output_path: Path) -> None:
        super().__init__(message)
        self.cell_index, self.code_cell_number, self.output_path = cell_index, code_cell_number, output_path


class BookLayout:
    """Where the book's files live below a project root (:meth:`at`: one that holds a ``_toc.yml``)."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.toc_path = root / "_toc.yml"
        self.profiles_path = root / "book" / "profiles.yml"
        self.generated_dir = root / GENERATED_PREFIX.rstrip("/")
        self.record_path = self.generated_dir / f"{EXECUTION_PAGE}.json"
        self.execution_page_path = self.generated_dir / f"{EXECUTION_PAGE}.md"
        self.training_path = self.generated_dir / "training.json"  # written by `softpend sweep --book`

    @classmethod
    def at(cls, root: Path | str = ".") -> "BookLayout":
        layout = cls(Path(root).resolve())
        if layout.toc_path.exists() and not layout.toc_path.is_file():
            raise ValueError(f"{layout.toc_path} is not a regular file")
        if not layout.toc_path.is_file():
            raise FileNotFoundError(f"no _toc.yml in {layout.root} (run from the project root or pass --root)")
        return layout

    def source_path(self, name: str) -> Path:
        return self.root / "notebooks" / f"{name}.md"

    def output_path(self, name: str) -> Path:
        return self.generated_dir / f"{name}.ipynb"

    def key_path(self, name: str) -> Path:
        return self.generated_dir / f"{name}.sha256"


#: One notebook of :func:`run_notebooks`: ``status`` is ``"executed"`` or ``"cached"``.
NotebookRun = namedtuple("NotebookRun", "name status seconds output_path")


def _expect(ok: bool, path: Path | str, node: Any, key: Any, expected: str, got: Any) -> None:
    """``ValueError`` naming the file, the line of ``node[key]`` and what was expected unless ``ok``."""
    kind = "nothing" if got is None else f"{type(got).__name__.removeprefix('_Line').lower()} {got!r}"[:80]
    if not ok:
        raise ValueError(f"{path}, line {yaml_line(node, key)}: expected {expected}, got {kind}")


def toc_notebooks(toc_path: Path | str) -> list[str]:
    """Names of the executed notebooks of a ``_toc.yml`` (entries under ``book/_generated/``), in reading order;
    ``ValueError`` unless it has the shape jupyter-book reads (a mapping with ``root``, lists of mappings)."""
    toc, entries = read_yaml_checked(Path(toc_path), "table of contents", lines=True), list[str]()
    _expect(isinstance(toc, dict), toc_path, toc, None, "a mapping with format, root and parts or chapters", toc)
    if "root" not in toc:
        raise ValueError(f"{toc_path}, line {yaml_line(toc)}: expected a 'root' entry (the book's first page)")

    def walk(node: dict) -> None:
        for key, value in node.items():
            strings = ("file", "root", "caption", "format", "title", "url")
            _expect(key not in strings or isinstance(value, str), toc_path, node, key, f"'{key}' to be a string", value)
            if key in ("file", "root") and value.startswith(GENERATED_PREFIX):
                entries.append(value[len(GENERATED_PREFIX) :].removesuffix(".ipynb"))
            if key in ("parts", "chapters", "sections") and value is not None:
                _expect(isinstance(value, list), toc_path, node, key, f"'{key}' to be a list of entries", value)
                for index, entry in enumerate(value):
                    expected = f"each of '{key}' to be a mapping (file: ...)"
                    _expect(isinstance(entry, dict), toc_path, value, index, expected, entry)
                    walk(entry)

    walk(toc)
    names = [name for name in entries if name != EXECUTION_PAGE]
    if duplicates := sorted({name for name in names if names.count(name) > 1}):
        raise ValueError(f"{toc_path}: notebook(s) listed more than once: {duplicates}")
    return names


def load_profiles(path: Path | str) -> dict[str, dict[str, dict[str, Any]]]:
    """``profiles.yml`` as ``profile -> notebook -> {parameter: value}``."""
    data = read_yaml_checked(path, "profiles file", lines=True) or {}
    _expect(isinstance(data, dict), path, data, None, "a mapping profile -> notebook -> parameters", data)
    for profile, notebooks in data.items():
        expected = f"a mapping notebook -> parameters for profile {profile!r}"
        _expect(isinstance(notebooks or {}, dict), path, data, profile, expected, notebooks)
        for notebook, parameters in (notebooks or {}).items():
            ok = isinstance(parameters or {}, dict) and all(isinstance(key, str) for key in parameters or {})
            expected = f"a mapping parameter -> value for notebook {notebook!r} of profile {profile!r}"
            _expect(ok, path, notebooks, notebook, expected, parameters)
    return {str(p): {str(n): dict(v or {}) for n, v in (nbs or {}).items()} for p, nbs in data.items()}


def book_profile(root: Path | str, profile: str) -> tuple[BookLayout, list[str], dict[str, dict[str, Any]]]:
    """The book's layout at ``root``, its toc's notebooks and ``profile``'s parameters per notebook."""
    layout = BookLayout.at(root)
    toc, profiles = toc_notebooks(layout.toc_path), load_profiles(layout.profiles_path)
    if profile not in profiles:
        raise ValueError(f"unknown profile {profile!r}; {layout.profiles_path} defines {sorted(profiles)}")
    return layout, toc, profiles[profile]


def read_notebook(source_path: Path | str):
    """A jupytext MyST notebook as an ``nbformat`` notebook."""
    import jupytext

    return jupytext.reads(_source_text(source_path), fmt="md:myst")


def _source_text(source_path: Path | str) -> str:
    return read_text_checked(source_path, "notebook source", MAX_CONFIG_BYTES)


def _parameters_cell(nb) -> Optional[str]:
    tagged = (c for c in nb.cells if c.cell_type == "code" and "parameters" in c.get("metadata", {}).get("tags", []))
    return next((cell.source for cell in tagged), None)


def check_parameters(notebook_path: Path | str, name: str, parameters: dict[str, Any]) -> dict[str, Any]:
    """The parameters a notebook (``.ipynb``) declares; ``ValueError`` if ``parameters`` names another one."""
    import papermill

    if unknown := sorted(set(parameters) - set(declared := papermill.inspect_notebook(str(notebook_path)))):
        defined = f"(it defines {sorted(declared)})"
        raise ValueError(f"notebook {name!r}: parameter(s) {unknown} are not defined in its parameters cell {defined}")
    return declared


def front_matter(nb, name: str, known: Sequence[str]) -> dict[str, list[str]]:
    """The notebook's checked ``softpend:`` front matter: ``after`` (notebooks it waits for), ``book_runs``."""
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
        waiting = (n for n in pending if all(dep in done or dep not in selected for dep in after.get(n, ())))
        if (ready := next(waiting, None)) is None:
            raise ValueError(f"notebooks {pending} wait for each other (softpend.after in their front matter)")
        pending.remove(ready)
        done.append(ready)
    return done


class PackageCode:
    """A package's modules (default ``softpend``) read with ``ast``: the closure of some code's imports (strings
    naming a module or an entry point ``"pkg.a:Name"`` included) and each module's hash without docstrings."""

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
        if module not in self._read:
            path = self.modules[module]
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            for node in ast.walk(tree):  # without docstrings (an emptied body becomes ``pass``)
                if isinstance(body := getattr(node, "body", None), list):
                    setattr(node, "body", [s for s in body if not _is_text(s)] or [ast.Pass()])
            digest = hashlib.sha256(ast.dump(tree).encode()).hexdigest()
            self._read[module] = (digest, frozenset(self._tree_imports(tree, module)))
        return self._read[module]

    def _tree_imports(self, tree: ast.AST, module: Optional[str] = None) -> set[str]:
        found: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and (module or not node.level):
                target = node.module or ""
                if node.level and module:  # relative to the module's package
                    base = module.split(".")[: None if self.modules[module].name == "__init__.py" else -1]
                    target = ".".join(base[: len(base) - node.level + 1] + ([node.module] if node.module else []))
                targets = [target, *(f"{target}.{alias.name}" for alias in node.names)]
            elif isinstance(node, ast.Constant) and isinstance(node.value, str) and self.name in node.value:
                targets = [match.group(0) for match in self._entry_point.finditer(node.value)]
                targets += [node.value.strip()] if node.value.strip() in self.modules else []
            else:
                continue
            parents = (".".join(t.split(".")[:i]) for t in targets for i in range(1, t.count(".") + 2))
            found.update(name for name in parents if name in self.modules)
        found.discard(module)
        return found

    def closure(self, code_cells: Iterable[str]) -> set[str]:
        """Modules the code uses, directly or through the package; all of them when a cell does not parse."""
        from IPython.core.inputtransformer2 import TransformerManager

        pending: set[str] = set()
        for cell in code_cells:
            try:  # as IPython runs it (magics translated); every module where it does not parse
                tree = ast.parse(TransformerManager().transform_cell(cell))
            except SyntaxError:
                return set(self.modules)
            pending |= self._tree_imports(tree)
        used: set[str] = set()
        while pending:
            if (module := pending.pop()) not in used:
                used.add(module)
                pending |= self._module(module)[1] - used
        return used

    def code_hashes(self, code_cells: Iterable[str]) -> dict[str, str]:
        """The hash of each module the code uses and of each data file of the package."""
        hashes = {module: self._module(module)[0] for module in sorted(self.closure(code_cells))}
        return hashes | _file_hashes(self.root, self.name, DATA_SUFFIXES)


def _is_text(statement: ast.stmt) -> bool:
    """Whether a statement is a bare string (a docstring)."""
    return isinstance(statement, ast.Expr) and isinstance(getattr(statement.value, "value", None), str)


def _file_hashes(folder: Path, prefix: str, suffixes: Sequence[str] = ()) -> dict[str, str]:
    """SHA-256 of each file under ``folder`` (ending in one of ``suffixes`` if given) as ``prefix/relative path``."""
    return {
        f"{prefix}/{path.relative_to(folder).as_posix()}": hashlib.sha256(path.read_bytes()).hexdigest()
        for path in (sorted(folder.rglob("*")) if folder.is_dir() else [])
        if path.is_file() and "__pycache__" not in path.parts and (not suffixes or path.suffix in suffixes)
    }


def cache_key(source_text: str, parameters: dict[str, Any], code_hashes: dict[str, str], after: Any = None) -> str:
    """Cache key of one executed notebook: source, parameters, package code and the keys of its ``after``."""
    payload: dict[str, Any] = {"version": _CACHE_VERSION, "source": source_text, "parameters": parameters}
    payload |= {"code": sorted(code_hashes.items()), **({"after": after} if after else {})}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=repr).encode()).hexdigest()


_UNITS = "_rad_s=rad/s,_nm=N m,_ms=ms,_mm=mm,_rad=rad,_deg=deg,_hz=Hz,_fps=1/s,_kg=kg,_dn=DN,_s=s,_m=m"
UNIT_SUFFIXES = [pair.partition("=")[::2] for pair in _UNITS.split(",")]  # name suffix -> unit, first match counts


def _value(value: Any) -> str:
    """A value as ``--set NAME=VALUE`` reads it: JSON, else its text."""
    return value if isinstance(value, str) else json.dumps(value, separators=(",", ":"), default=repr)


def notebook_parameters(cell: str) -> list[dict[str, Any]]:
    """The assignments of a ``parameters`` cell: ``name``, ``default`` (as ``--set`` reads it; the expression where
    the cell does not evaluate: ``evaluated`` False), ``unit`` and the line's ``comment``."""
    tokens = tokenize.generate_tokens(io.StringIO(cell).readline)
    comments = {t.start[0]: t.string.lstrip("#").strip() for t in tokens if t.type == tokenize.COMMENT}
    namespace: dict[str, Any] = {}
    try:
        exec(compile(cell, "<parameters>", "exec"), namespace)  # noqa: S102 -- assignments, imports of presets
    except Exception:  # noqa: BLE001 -- the expression is shown instead
        namespace = {}
    found = []
    for node in ast.parse(cell).body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            name, comment = node.targets[0].id, comments.get(node.end_lineno or 0, "")
            bracket = re.search(r"\[([^\],'\"]+)\]", comment)  # "[N m]", not "[16, 16]"
            unit = bracket.group(1) if bracket else next((u for end, u in UNIT_SUFFIXES if name.endswith(end)), "")
            default = _value(namespace[name]) if name in namespace else ast.get_source_segment(cell, node.value)
            found.append(dict(name=name, evaluated=name in namespace, comment=comment, default=default, unit=unit))
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
    rows, table = notebook_parameters(cell), ""
    for row in rows:
        build = f"`{_md(_value(used[row['name']]), 60)}`" if row["name"] in used else ""
        default, meaning = _md(row["default"], 60), _md(row["comment"], 90)
        table += f"| `{row['name']}` | `{default}` | {build} | {row['unit']} | {meaning} |\n"
    example = next((f"{row['name']}={row['default']}" for row in rows if row["evaluated"]), "NAME=VALUE")
    profile_option = ["--profile", profile] if profile != DEFAULT_PROFILE else []
    command = shlex.join(["softpend", "book", "--only", name, *profile_option, "--set", example])
    return f"""## Rerun this {"figure" if name.startswith("fig") else "chapter"}

This page was executed by `softpend book --profile {profile}` with the parameters below (defaults from the \
notebook's `parameters` cell; *this build* where the profile or `--set` changed one).

| parameter | default | this build | unit | meaning |
|---|---|---|---|---|
{table}
To rerun it from the project root with other values (one `--set NAME=VALUE` per parameter, VALUE as JSON, else \
a string; add `--html` to rebuild the page):

```bash
{command}
```
"""


def run_notebooks(
    root: Path | str = ".",
    profile: str = DEFAULT_PROFILE,
    only: Optional[Sequence[str]] = None,
    force: bool = False,
    progress: bool = True,
    overrides: Optional[dict[str, Any]] = None,
) -> list[NotebookRun]:
    """Execute the toc's notebooks (``only``: these) with a profile's parameters and ``overrides`` (``--set``), write
    the execution page; ``ValueError`` before anything runs, :class:`NotebookExecutionError` for a failing notebook."""
    layout, toc, given = book_profile(root, profile)
    for what, listed in ((f"profile {profile!r} names", given), ("--only names", only or [])):
        if unknown := sorted(set(listed) - set(toc)):
            raise ValueError(f"{what} unknown notebook(s) {unknown}; _toc.yml lists {toc}")
    names = [name for name in toc if name in set(only)] if only else toc
    layout.generated_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="softpend-book-") as scratch:
        plans, used = _plan(layout, names, toc, profile, given, dict(overrides or {}), Path(scratch))
        _execute(layout, plans, force, progress)
    runs = [NotebookRun(n, p["status"], p.get("seconds", 0.0), layout.output_path(n)) for n, p in plans.items()]
    write_execution_record(layout, profile, runs, used)
    return runs


def _key_on_disk(layout: BookLayout, name: str) -> str:
    path = layout.key_path(name)
    return path.read_text(encoding="utf-8").strip() if path.is_file() else "absent"


def _plan(layout: BookLayout, names: list, toc: list, profile: str, given: dict, overrides: dict, scratch: Path):
    """The checked run plan of every notebook, in execution order (its cache key holds those of its ``after``: this
    run's, else the key files on disk), and the overrides used."""
    import nbformat

    notebooks = {name: read_notebook(layout.source_path(name)) for name in names}
    after = {name: front_matter(nb, name, toc)["after"] for name, nb in notebooks.items()}
    package_code, plans, used = PackageCode(), dict[str, dict[str, Any]](), dict[str, Any]()
    for name in execution_order(names, after):
        nb = notebooks[name]
        if (parameters_cell := _parameters_cell(nb)) is None:
            raise ValueError(f"notebook {name!r} has no code cell tagged 'parameters'")
        nbformat.write(nb, str(converted := scratch / f"{name}.ipynb"))
        declared = check_parameters(converted, name, given.get(name, {}))
        applied = {key: value for key, value in overrides.items() if key in declared}
        used |= applied
        parameters = given.get(name, {}) | applied
        hashes = package_code.code_hashes(cell.source for cell in nb.cells if cell.cell_type == "code")
        for module, folder in (("softpend.study.records", "records"), ("softpend.study.presets", "hparams")):
            if module in hashes:  # the book's data files that this code reads
                hashes |= _file_hashes(layout.root / "book" / folder, f"book/{folder}")
        upstream = {dep: plans[dep]["key"] if dep in plans else _key_on_disk(layout, dep) for dep in after[name]}
        plans[name] = {
            "after": after[name],
            "parameters": parameters,
            "converted": converted,
            "key": cache_key(_source_text(layout.source_path(name)), parameters, hashes, upstream),
            "record": {"profile": profile, "parameters": given.get(name, {}), "overrides": applied},
            "rerun": rerun_section(name, parameters_cell, profile, parameters),
        }
    if unused := sorted(set(overrides) - set(used)):
        raise ValueError(f"override(s) {unused} are not parameters of any selected notebook ({list(names)})")
    return plans, used


def _execute(layout: BookLayout, plans: dict[str, dict[str, Any]], force: bool, progress: bool) -> None:
    """Execute the notebooks of ``plans`` whose output is not up to date (``force``: all), :data:`WORKERS` at a time,
    each after its ``after``, and set each one's ``status``; once one fails no other starts, and the first error is
    raised when the running ones end."""
    futures: dict[str, Future[None]] = {}
    errors: list[BaseException] = []
    slots = threading.Semaphore(WORKERS)

    def say(text: str) -> None:
        if progress:
            print(f"[book] {text}", file=sys.stderr, flush=True)

    def run(name: str) -> None:  # a thread per notebook; WORKERS of them execute at once
        wait([futures[dep] for dep in plans[name]["after"] if dep in futures])
        with slots:
            if errors:
                return
            say(f"{name}: executing")
            try:
                plans[name]["seconds"] = _execute_one(layout, name, plans[name])
                say(f"{name}: executed in {plans[name]['seconds']:.1f} s")
            except BaseException as error:  # noqa: BLE001 -- raised below once the running notebooks end
                errors.append(error)
                say(f"{name} failed")

    with ThreadPoolExecutor(max_workers=max(1, len(plans)), thread_name_prefix="softpend-book") as pool:
        for name, plan in plans.items():
            cached = not force and layout.output_path(name).is_file() and _key_on_disk(layout, name) == plan["key"]
            plan["status"] = "cached" if cached else "executed"
            if cached:
                say(f"{name}: up to date (cached)")
            else:
                futures[name] = pool.submit(run, name)
    if errors:
        raise errors[0]


def _execute_one(layout: BookLayout, name: str, plan: dict[str, Any]) -> float:
    """Execute one notebook (kernel in the project root) and append its rerun section; returns its wall time."""
    import nbformat
    import papermill
    from papermill.exceptions import PapermillExecutionError

    output, key_path = layout.output_path(name), layout.key_path(name)
    key_path.unlink(missing_ok=True)  # an interrupted or failed run must not look cached
    start = time.perf_counter()
    try:  # nbclient starts the kernel in resources' path: papermill's own cwd= would chdir this whole process
        where = {"metadata": {"path": str(layout.root)}}
        options = dict(progress_bar=False, extra_arguments=_KERNEL_ARGS, resources=where)
        nb = papermill.execute_notebook(str(plan["converted"]), str(output), plan["parameters"], **options)
    except PapermillExecutionError as exc:
        cells, at = nbformat.read(str(plan["converted"]), as_version=4).cells, exc.cell_index
        matches = [i for i, c in enumerate(cells) if c.cell_type == "code" and c.source == exc.source]
        index = min(matches, key=lambda i: abs(i - at), default=-1)
        number = sum(c.cell_type == "code" for c in cells[: index + 1])
        first_line = next((line for line in exc.source.splitlines() if line.strip()), "")
        message = (
            f"notebook {name!r} failed in code cell {number} of notebooks/{name}.md (In [{exc.exec_count}], "
            f"starting {first_line!r}): {exc.ename}: {exc.evalue}; the partially executed notebook is kept in {output}"
        )
        raise NotebookExecutionError(message, index, number, output) from None
    seconds = time.perf_counter() - start
    nb.metadata["softpend"] = plan["record"]  # read back by the execution record
    for cell in nb.cells:  # papermill gives every cell a list of tags
        if "injected-parameters" in cell.metadata.tags:
            cell.metadata.tags.append("hide-input")
    nb.cells.append(nbformat.v4.new_markdown_cell(plan["rerun"]))
    nbformat.write(nb, str(output))
    key_path.write_text(plan["key"] + "\n", encoding="utf-8")
    return seconds


def _processor(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The processor model (``/proc/cpuinfo``, else :mod:`platform`)."""
    first = cpuinfo.read_text().split("\n\n")[0] if cpuinfo.is_file() else ""
    fields = {key.strip(): value.strip() for key, _, value in (line.partition(":") for line in first.splitlines())}
    if fields.get("model name"):
        return f"{fields['model name']} (family {fields.get('cpu family', '-')}, model {fields.get('model', '-')})"
    return platform.processor() or platform.machine() or "-"


def _when(iso: Optional[str]) -> str:
    """An ISO date and time as ``YYYY-MM-DD HH:MM:SS``; ``-`` for none."""
    return str(iso).replace("T", " ")[:19] if iso else "-"


def write_execution_record(layout: BookLayout, profile: str, runs: Sequence[NotebookRun], overrides: dict) -> None:
    """Write the record of what produced ``book/_generated/`` (``execution.json``) and the execution page (MyST)."""
    import nbformat

    this_run, notebooks = {run.name: run.status for run in runs}, []
    for name in toc_notebooks(layout.toc_path):
        lines = _source_text(layout.source_path(name)).splitlines()
        title = next((line[2:].strip() for line in lines if line.startswith("# ")), name)
        output = layout.output_path(name)
        meta = nbformat.read(str(output), as_version=4).metadata if output.is_file() else {}
        papermill = meta.get("papermill", {})
        entry = {"name": name, "title": title, "this_run": this_run.get(name, "not run")}
        entry |= {"executed_s": papermill.get("duration"), "executed_at": papermill.get("end_time")}
        notebooks.append(entry | {"profile": meta.get("softpend", {}).get("profile")})
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    machine = {"processor": _processor(), "cpu_count": os.cpu_count(), "cpus_available": cpus}
    machine |= {"platform": platform.platform(), "python": platform.python_version()}
    date = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    training = read_json_object(layout.training_path, MAX_CONFIG_BYTES)
    record: dict[str, Any] = {"date": date, "profile": profile, "overrides": dict(overrides), "training": training}
    record |= {"notebooks": notebooks, "machine": machine}
    with atomic_write(layout.record_path, "w") as handle:
        handle.write(json_text(record, indent=2) + "\n")
    rows = ""
    for e in notebooks:
        title = f"{{doc}}`{_md(e['title'])} <{e['name']}>`" if e["executed_at"] else _md(e["title"])
        seconds = "-" if e["executed_s"] is None else f"{e['executed_s']:.1f}"
        rows += f"| {title} | {e['this_run']} | {seconds} | {_when(e['executed_at'])} | {_md(e['profile'])} |\n"
    trained = (
        f"`softpend sweep --book --profile {training['profile']}` on {_when(training['date'])} UTC trained "
        f"{len(training['trained'])} run(s) the notebooks read (the others were there already) in "
        f"{training['seconds']:.0f} s, with {training['workers']} worker(s)."
        if training
        else "No training step recorded (`softpend sweep --book`): the notebooks trained the runs they read."
    )
    with_overrides = f" with {_md(overrides)}" if overrides else ""
    with atomic_write(layout.execution_page_path, "w") as handle:
        handle.write(f"""(execution)=
# Execution

Written by `softpend book --profile {profile}` on {_when(date)} UTC{with_overrides}. Per notebook: what this run did \
(*executed*; *cached*: its source, parameters and the code it uses were unchanged; *not run*: not \
selected) and its last execution. Each chapter ends with its parameters and the command that reruns it.

| notebook | this run | last execution [s] | ended (UTC) | profile |
|---|---|---|---|---|
{rows}
Sum of the last execution times: {sum(e["executed_s"] or 0.0 for e in notebooks):.0f} s.

## Training step

{trained}

## Machine

| | |
|---|---|
| processor | {_md(machine["processor"])} |
| CPU cores | {machine["cpu_count"]} ({machine["cpus_available"]} available to the run) |
| platform | {_md(machine["platform"])}, Python {machine["python"]} (packages: `environment.lock`) |
""")


def build_html(root: Path | str = ".", path_output: Optional[Path | str] = None, quiet: bool = False) -> Path:
    """``jupyter-book build -W`` of the executed notebooks into ``<path_output or root>/_build/html`` (returned)."""
    layout = BookLayout.at(root)
    script = Path(sys.executable).parent / "jupyter-book"
    output = Path(path_output if path_output is not None else layout.root).resolve()
    program = str(script) if script.exists() else (shutil.which("jupyter-book") or "jupyter-book")
    command = [program, "build", str(layout.root), "--path-output", str(output), "-W", "-n", "--keep-going"]
    command += ["-q"] if quiet else []
    print("[book] " + " ".join(command), file=sys.stderr, flush=True)
    if subprocess.run(command, cwd=layout.root).returncode != 0:
        raise RuntimeError("jupyter-book build failed (warnings count as errors)")
    if not (output / "_build" / "html" / "index.html").is_file():
        raise RuntimeError(f"jupyter-book build wrote no {output / '_build' / 'html' / 'index.html'}")
    return output / "_build" / "html"
