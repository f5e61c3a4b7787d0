"""The code each stage runs, and its fingerprint: the workflow's code rerun trigger.

A stage runs its notebook (``notebooks/<name>.py``), the library modules the notebook imports,
directly or through other modules, and the runner (``stage.py``, ``run_notebook.py``). The
rules put :func:`fingerprint` of those files into each stage's param ``stage`` (its ``code``), so
that Snakemake's params trigger reruns a stage, and everything after it, when any of them
changes, and no other stage. Read at parse time: the standard library only, never torch or
``sdm`` (the imports are read from the source with :mod:`ast`, nothing is imported).

What counts as a change:

* a notebook: any edit of its text (the rendered HTML shows every cell, prose included);
* a module or runner script: an edit of its syntax tree without docstrings -- code, not
  comments, docstrings or layout (:func:`_parsed`); no library code reads a docstring (the
  runner prints its own only as its usage);
* a file a module reads beside itself (:data:`RESOURCES`, the native kernel's C source): any edit.

Which modules a notebook reaches follows Python's import semantics: ``import sdm.a.b`` runs
``sdm/__init__.py``, ``sdm/a/__init__.py`` and ``sdm/a/b.py``; ``from . import x`` and
``from .m import y`` resolve against the importing module's package; imports inside functions
count (they run when the function is called). ``sdm/__init__.py`` imports the layer, training
and metrics, so every notebook reaches those.

    python workflow/scripts/code_deps.py table   # the module-to-stages table of docs/workflow.md
"""
from __future__ import annotations

import ast
import functools
import hashlib
import re
import sys
from pathlib import Path

#: The project root (this file is workflow/scripts/code_deps.py).
ROOT = Path(__file__).resolve().parents[2]
#: The library's package, under ROOT/src.
PACKAGE = "sdm"
#: What every stage runs besides its notebook: the rule's script, the runner it calls, and the atomic
#: writer the runner loads from its file (``run_notebook._load_writer``, not an import statement).
RUNNER = ("workflow/scripts/stage.py", "workflow/scripts/run_notebook.py", "src/sdm/io.py")
#: Files a module reads beside itself (not Python, hashed as they are): the module -> its files.
#: tests/test_workflow_code.py checks that every non-Python file under src/sdm is listed here.
RESOURCES = {"src/sdm/mapping/native.py": ("src/sdm/mapping/_native.c",)}


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


@functools.lru_cache(maxsize=None)
def _parsed(path: Path) -> tuple[tuple[ast.stmt, ...], str]:
    """The import statements of a Python file (at any depth) and the SHA-256 of its syntax tree without
    docstrings (``ast.dump``: neither comments nor line numbers are in it). One parse, one walk."""
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    except (OSError, SyntaxError, UnicodeDecodeError) as error:
        raise CodeDepsError(f"{path}: cannot be read for the stage's code fingerprint ({error})") from None
    imports = []
    for node in ast.walk(tree):  # a node's children are queued before it is seen: its body can be changed
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            imports.append(node)
        elif isinstance(node, _DEFINITIONS) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                node.body = node.body[1:] or [ast.Pass()]
    return tuple(imports), hashlib.sha256(ast.dump(tree).encode()).hexdigest()


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
    for node in _parsed(path)[0]:
        if isinstance(node, ast.Import):
            for alias in node.names:
                found.update(_with_parents(alias.name))
            continue
        if node.level:
            parts = package.split(".") if package else []
            if node.level > len(parts):
                raise CodeDepsError(f"{path}:{node.lineno}: a relative import outside the package")
            base = ".".join(parts[: len(parts) - (node.level - 1)])
            base = f"{base}.{node.module}" if node.module else base
        else:
            base = node.module
        found.update(_with_parents(base))
        found.update(f"{base}.{alias.name}" for alias in node.names if module_file(f"{base}.{alias.name}"))
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
    return hashlib.sha256(lines.encode()).hexdigest()


# -- the table of docs/workflow.md ---------------------------------------------------------------------

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
    """The Markdown table of docs/workflow.md: every library file, and the stages whose notebook runs it."""
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
