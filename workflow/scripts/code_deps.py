"""The code each stage runs, and its fingerprint: the workflow's code rerun trigger.

A stage runs its notebook (``notebooks/<name>.py``), the library modules the notebook imports,
directly or through other modules, and the runner (``stage.py``, ``run_notebook.py``, ``kernel.py``). The
rules put :func:`fingerprint` of those files into each stage's param ``stage`` (its ``code``), so
that Snakemake's params trigger reruns a stage, and everything after it, when any of them
changes, and no other stage. Read at parse time: the standard library only, never torch or
``sdm`` (the imports are read from the source with :mod:`ast`, nothing is imported).

What counts as a change:

* a notebook: any edit of its text (the rendered HTML shows every cell, prose included);
* a module or runner script: an edit of its syntax tree without docstrings -- code, not
  comments, docstrings or layout (:func:`_parsed`); no library code reads a docstring (the
  runner prints its own only as its usage);
* a file a module reads beside itself (:data:`RESOURCES`, the native kernel's C sources and headers): any edit.

Parsing the library takes about a second, paid by every Snakemake start (a dry run, each cluster
job). So what a parse gives (the imports, the digest) is kept in ``code_deps-<python>.json`` in the
cache folder (:func:`sdm.io.cache_dir`), per file content: an edited file is parsed anew, the others
are read back (:class:`ParseCache`). It is only ever a shortcut to the same result: an unreadable or
damaged file, entries of another Python or of another version of this file are ignored, and a
folder that cannot be written to is left alone.

Which modules a notebook reaches follows Python's import semantics: ``import sdm.a.b`` runs
``sdm/__init__.py``, ``sdm/a/__init__.py`` and ``sdm/a/b.py``; ``from . import x`` and
``from .m import y`` resolve against the importing module's package; imports inside functions
count (they run when the function is called). ``sdm/__init__.py`` imports the layer, training
and metrics, so every notebook reaches those.

    python workflow/scripts/code_deps.py table   # the module-to-stages table of docs/maintaining.md
"""
from __future__ import annotations

import ast
import functools
import hashlib
import importlib.util
import json
import re
import sys
from pathlib import Path

#: The project root (this file is workflow/scripts/code_deps.py).
ROOT = Path(__file__).resolve().parents[2]
#: The library's package, under ROOT/src.
PACKAGE = "sdm"
#: What every stage runs besides its notebook: the rule's script, the runner it calls, the kernel's
#: launcher, this file (the runner loads the atomic writer through it) and the writer itself (loaded from
#: its file by :func:`library_io`, not by an import statement).
RUNNER = ("workflow/scripts/stage.py", "workflow/scripts/run_notebook.py", "workflow/scripts/kernel.py",
          "workflow/scripts/code_deps.py", "src/sdm/io.py")
#: Files a module reads beside itself (not Python, hashed as they are): the module -> its files.
#: tests/workflow/test_workflow_code.py checks that every non-Python file under src/sdm is listed here.
RESOURCES = {"src/sdm/mapping/build.py": tuple(f"src/sdm/mapping/kernel/{name}" for name in (
    "chain.c", "crossing.c", "mismatch.c", "noise.c", "targets.c", "train.c", "train_setup.c",
    "kernel.h", "targets.h", "train.h", "train_points.h"))}


class CodeDepsError(Exception):
    """A notebook or module that cannot be read or parsed (the message names the file)."""


def _relative(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


@functools.lru_cache(maxsize=None)
def module_file(name: str) -> Path | None:
    """The file of library module ``name`` (``sdm.mapping.flow``), or None if it is not one."""
    if name != PACKAGE and not name.startswith(PACKAGE + "."):
        return None
    base = ROOT / "src" / Path(*name.split("."))
    for path in (base / "__init__.py", base.with_suffix(".py")):
        if path.is_file():
            return path
    return None


_DEFINITIONS = (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)

#: One import statement as :func:`_parsed` gives it (plain data, so that it can be cached):
#: ``(module, names, level, line)``, with ``module`` None for ``import a.b, c`` (then ``names`` are the
#: modules) and the module after the dots of ``from ..m import x`` (None for ``from . import x``).
Import = tuple[str | None, tuple[str, ...], int, int]


@functools.lru_cache(maxsize=1)
def library_io():
    """The library's ``sdm/io.py`` (the atomic writer, the cache folder), loaded from its file: importing the
    ``sdm`` package imports torch (about 2 s per process), and ``sdm/io.py`` uses only the standard library."""
    spec = importlib.util.spec_from_file_location("sdm_io_for_workflow", ROOT / "src" / PACKAGE / "io.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _parse(path: Path, source: bytes) -> tuple[tuple[Import, ...], str]:
    """The import statements of a Python file (at any depth) and the SHA-256 of its syntax tree without
    docstrings (``ast.dump``: neither comments nor line numbers are in it). One parse, one walk."""
    try:
        tree = ast.parse(source.decode("utf-8"), filename=str(path))
    except (SyntaxError, UnicodeDecodeError) as error:
        raise CodeDepsError(f"{path}: cannot be read for the stage's code fingerprint ({error})") from None
    imports = []
    for node in ast.walk(tree):  # a node's children are queued before it is seen: its body can be changed
        if isinstance(node, ast.Import):
            imports.append((None, tuple(alias.name for alias in node.names), 0, node.lineno))
        elif isinstance(node, ast.ImportFrom):
            imports.append((node.module, tuple(alias.name for alias in node.names), node.level, node.lineno))
        elif isinstance(node, _DEFINITIONS) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                node.body = node.body[1:] or [ast.Pass()]
    return tuple(imports), hashlib.sha256(ast.dump(tree).encode()).hexdigest()


class ParseCache:
    """What :func:`_parse` gave for each file content, kept in ``<cache folder>/code_deps-py<X.Y>.json``.

    The file holds ``{"parser": SHA-256 of this file, "entries": {SHA-256 of a source: [imports, digest]}}``;
    entries are trusted only under the same parser (this file's bytes) and Python (``ast.dump`` changes
    between versions), and only in their exact shape. It keeps the last :data:`LIMIT` contents used, and is
    rewritten atomically when a run parsed something new (parallel runs: the last one's file stays whole).
    """

    LIMIT = 4096

    def __init__(self):
        self.entries, self.added = {}, False
        try:
            self.path = library_io().cache_dir() / f"code_deps-py{sys.version_info[0]}.{sys.version_info[1]}.json"
            self.parser = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()
            content = json.loads(self.path.read_text(encoding="utf-8"))
            if content.get("parser") == self.parser:
                self.entries = {key: value for key, value in content["entries"].items() if self._valid(value)}
        except (OSError, RuntimeError, ValueError, AttributeError, KeyError, TypeError):
            pass  # none yet, unreadable or damaged: parsed anew, and written whole if it can be

    @staticmethod
    def _valid(value) -> bool:
        return (isinstance(value, list) and len(value) == 2 and isinstance(value[1], str) and len(value[1]) == 64
                and isinstance(value[0], list) and all(
                    isinstance(item, list) and len(item) == 4 and isinstance(item[0], (str, type(None)))
                    and isinstance(item[1], list) and all(isinstance(name, str) for name in item[1])
                    and type(item[2]) is int and type(item[3]) is int for item in value[0]))

    def parsed(self, path: Path, source: bytes) -> tuple[tuple[Import, ...], str]:
        key = hashlib.sha256(source).hexdigest()
        if key in self.entries:
            imports, digest = self.entries.pop(key)
            self.entries[key] = [imports, digest]  # the most recently used last
            return tuple((module, tuple(names), level, line) for module, names, level, line in imports), digest
        imports, digest = _parse(path, source)
        self.entries[key] = [[[module, list(names), level, line] for module, names, level, line in imports], digest]
        self.added = True
        return imports, digest

    def save(self) -> None:
        if not self.added:
            return
        kept = dict(list(self.entries.items())[-self.LIMIT:])
        try:
            library_io().write_text(self.path, json.dumps({"parser": self.parser, "entries": kept}) + "\n")
        except (OSError, AttributeError):
            pass  # a read-only or missing cache folder: the next run parses again, nothing else changes
        self.added = False


@functools.lru_cache(maxsize=1)
def _parse_cache() -> ParseCache:
    return ParseCache()


@functools.lru_cache(maxsize=None)
def _parsed(path: Path) -> tuple[tuple[Import, ...], str]:
    """:func:`_parse` of the file at ``path``, through the :class:`ParseCache`."""
    try:
        source = path.read_bytes()
    except OSError as error:
        raise CodeDepsError(f"{path}: cannot be read for the stage's code fingerprint ({error})") from None
    return _parse_cache().parsed(path, source)


def _with_parents(name: str) -> list[str]:
    """``a.b.c`` -> ``a, a.b, a.b.c``: importing a module runs every package above it first."""
    parts = name.split(".")
    return [".".join(parts[: i + 1]) for i in range(len(parts))]


@functools.lru_cache(maxsize=None)
def imported(path: Path, name: str | None = None) -> frozenset[str]:
    """The library modules the file at ``path`` imports (module ``name``; None for a notebook or script).

    Relative imports resolve against the module's package (a package's ``__init__`` is its own
    package); ``from p import x`` imports ``p.x`` when that is a module, else only ``p``.
    """
    package = None
    if name is not None:
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for module, names, level, line in _parsed(path)[0]:
        if module is None and not level:  # import a.b, c
            for imported_module in names:
                found.update(_with_parents(imported_module))
            continue
        if level:
            parts = package.split(".") if package else []
            if level > len(parts):
                raise CodeDepsError(f"{path}:{line}: a relative import outside the package")
            base = ".".join(parts[: len(parts) - (level - 1)])
            base = f"{base}.{module}" if module else base
        else:
            base = module
        found.update(_with_parents(base))
        found.update(f"{base}.{member}" for member in names if module_file(f"{base}.{member}"))
    return frozenset(module for module in found if module_file(module) is not None)


@functools.lru_cache(maxsize=None)
def reached(notebook: str) -> tuple[str, ...]:
    """The library files (relative to ROOT) that ``notebooks/<notebook>.py`` runs when imported, sorted."""
    path = ROOT / "notebooks" / f"{notebook}.py"
    if not path.is_file():
        raise CodeDepsError(f"stage notebook {_relative(path)} does not exist")
    todo, seen = sorted(imported(path)), set()
    while todo:
        module = todo.pop()
        if module in seen:
            continue
        seen.add(module)
        todo.extend(imported(module_file(module), module) - seen)
    files = {_relative(module_file(module)) for module in seen}
    files |= {resource for module in files for resource in RESOURCES.get(module, ())}
    return tuple(sorted(files))


@functools.lru_cache(maxsize=None)
def file_digest(relative: str) -> str:
    """The digest of one tracked file (relative to ROOT): of its code (:func:`_parsed`) for a module or
    script, of its bytes for a notebook (its prose is rendered) or a resource."""
    path = ROOT / relative
    if relative.endswith(".py") and not relative.startswith("notebooks/"):
        return _parsed(path)[1]
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as error:
        raise CodeDepsError(f"{path}: cannot be read for the stage's code fingerprint ({error})") from None


def stage_files(notebook: str) -> list[str]:
    """Every file a stage running ``notebooks/<notebook>.py`` depends on as code, relative to ROOT, sorted."""
    return sorted({f"notebooks/{notebook}.py", *RUNNER, *reached(notebook)})


@functools.lru_cache(maxsize=None)
def fingerprint(notebook: str) -> str:
    """SHA-256 over ``path digest`` of :func:`stage_files` (paths relative: the project can move)."""
    lines = "".join(f"{path} {file_digest(path)}\n" for path in stage_files(notebook))
    _parse_cache().save()
    return hashlib.sha256(lines.encode()).hexdigest()


# -- the table of docs/maintaining.md ------------------------------------------------------------------

def stage_notebooks() -> dict[str, str]:
    """Stage -> the notebook it runs (``notebooks/<stage>.py``: one notebook per stage), from the
    ``notebook_stage("<stage>", ...)`` calls of the rule files the Snakefile includes, in its order (for the
    table; the rules know their own)."""
    stages = {}
    for rule_file in re.findall(r'^include: "([^"]+)"', (ROOT / "Snakefile").read_text(), flags=re.MULTILINE):
        for call in (ROOT / rule_file).read_text().split("\nnotebook_stage(")[1:]:
            stage = re.match(r'\s*"(\w+)"', call).group(1)
            stages[stage] = stage
    return stages


def module_table() -> str:
    """The Markdown table of docs/maintaining.md: every library file, and the stages whose notebook runs it."""
    stages = stage_notebooks()
    library = sorted(_relative(path) for path in (ROOT / "src" / PACKAGE).rglob("*")
                     if path.is_file() and "__pycache__" not in path.parts)
    rows = ["| library file | stages whose notebook runs it (each reruns, and every stage after it) |", "|---|---|"]
    for path in library:
        running = [stage for stage, notebook in stages.items() if path in stage_files(notebook)]
        others = [stage for stage in stages if stage not in running]
        if not others:
            shown = "every stage"
        elif len(others) <= 3:
            shown = "every stage but " + ", ".join(others)
        else:
            shown = ", ".join(running) or "none"
        rows.append(f"| `{path.removeprefix('src/')}` | {shown} |")
    return "\n".join(rows) + "\n"


if __name__ == "__main__":
    if sys.argv[1:] != ["table"]:
        sys.exit(__doc__)
    sys.stdout.write(module_table())
