"""The shape of ``src/sdm`` (docs/library.md, "The package"): the layer never imports the experiments, the
arrows between the package's parts point one way, imports sit at the top of their module, and files and functions
(the compiled kernel's C functions too) stay readable in size.

Sizes are held by a ratchet: the files and functions over the bars today are listed with their size, and may only
shrink; anything new over a bar fails. Every list names only what is still true, so a split that lands must take
its entry out.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "sdm"

#: The layer a model needs (docs/library.md): what it imports from sdm stays inside this list.
LAYER = {"sdm", "batch", "camera", "depth", "errors", "io", "mapping", "metrics", "representation", "sharing", "sky",
         "sky_native", "train", "zoom"}

MAX_FILE_LINES = 500
MAX_FUNCTION_LINES = 80  # docstring excluded

#: Files over MAX_FILE_LINES, with their line count today: they may only shrink.
OVERSIZED_FILES: dict[str, int] = {}

#: Functions over MAX_FUNCTION_LINES (``file:qualified name``), with their length today: they may only shrink.
OVERSIZED_FUNCTIONS: dict[str, int] = {}

#: The compiled kernel's C files, and the bar on a C function's body (from its opening brace to its closing one).
KERNEL = PACKAGE / "mapping" / "kernel"
MAX_C_FUNCTION_LINES = 80

#: C functions over MAX_C_FUNCTION_LINES (``file:name``), with their length today: they may only shrink.
OVERSIZED_C_FUNCTIONS: dict[str, int] = {}

#: Imports inside a function, each ``(file, function, module)``: optional dependencies, imported where they are
#: needed so that the layer and the tables that do not use them run without them (pyproject.toml's extras).
OPTIONAL_IMPORTS = {
    ("experiments/baselines/pycma.py", "import_cma", "cma"),  # pycma: the `baselines` extra
    ("experiments/baselines/sinkhorn.py", "fit_runs", "geomloss"),  # the `baselines` extra
    ("experiments/baselines/common.py", "to_frame", "pandas"),  # the `experiments` extra
    ("train/settings.py", "to_frame", "pandas"),  # the layer's History as a table, for the experiments
    ("experiments/report/figures.py", "show_figure", "IPython.display"),  # a notebook's display, only inside one
    ("experiments/report/figures.py", "_in_notebook", "IPython"),
    ("experiments/report/tables.py", "markdown_page", "mistune"),  # the HTML pages of the tables
    ("experiments/report/baselines.py", "baselines_figure", ".figures"),  # matplotlib, only where a figure is drawn
    ("experiments/report/network.py", "plot_curves", ".figures"),
    ("experiments/report/objects.py", "plot_table6", ".figures"),
    ("experiments/report/scaling.py", "plot_scaling", ".figures"),
    ("experiments/report/research.py", "rules_figure", ".figures"),
    ("experiments/report/depth.py", "depth_figure", ".figures"),
}

#: Imports inside a function that are no optional dependency: to move to the top of their module.
LEFT_TO_MOVE: set[tuple[str, str, str]] = set()


def _sources() -> dict[str, str]:
    return {path.relative_to(PACKAGE).as_posix(): path.read_text() for path in sorted(PACKAGE.rglob("*.py"))}


def _module(relative: str) -> str:
    parts = ["sdm", *Path(relative).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _part(module: str) -> str:
    """The part of the package a module belongs to: ``sdm`` itself, its first name below ``sdm``, or below
    ``sdm.experiments`` the experiment part (``experiments.objects``; ``experiments`` for its ``__init__``)."""
    parts = module.split(".")
    if len(parts) > 2 and parts[1] == "experiments":
        return f"experiments.{parts[2]}"
    return parts[1] if len(parts) > 1 else "sdm"


def _imported(relative: str, node: ast.ImportFrom | ast.Import) -> list[str]:
    """The sdm modules (absolute names) an import statement of the file ``relative`` names."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names if alias.name.split(".")[0] == "sdm"]
    if not node.level:
        return [node.module] if node.module and node.module.split(".")[0] == "sdm" else []
    module = _module(relative)
    package = module if relative.endswith("__init__.py") else module.rpartition(".")[0]
    base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
    if node.module:
        return [".".join([*base, node.module])]
    return [".".join([*base, alias.name]) for alias in node.names]


def _arrows() -> dict[str, set[str]]:
    """Part -> the parts it imports (module level and inside functions alike)."""
    arrows: dict[str, set[str]] = {}
    for relative, source in _sources().items():
        part = _part(_module(relative))
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                arrows.setdefault(part, set()).update(_part(name) for name in _imported(relative, node))
        arrows.setdefault(part, set()).discard(part)
    return arrows


def test_the_layer_imports_nothing_of_the_experiments():
    offenders = {part: sorted(targets - LAYER) for part, targets in _arrows().items()
                 if part in LAYER and targets - LAYER}
    assert not offenders, f"the layer imports the experiments: {offenders}"


def _cycle(arrows: dict[str, set[str]]) -> list[str] | None:
    """A cycle of ``arrows`` (as a path that returns to its start), or ``None``."""
    state: dict[str, int] = {}

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for target in sorted(arrows.get(node, ())):
            if target == "sdm":  # every module runs sdm/__init__ first: its arrows are the package's own
                continue
            if state.get(target) == 1:
                return path[path.index(target):] + [target] if target in path else [node, target]
            if target not in state and (found := visit(target, path + [target])):
                return found
        state[node] = 2
        return None

    for start in sorted(arrows):
        if start not in state and (found := visit(start, [start])):
            return found
    return None


def test_the_arrows_between_the_parts_point_one_way():
    assert _cycle(_arrows()) is None, f"a cycle between the package's parts: {' -> '.join(_cycle(_arrows()))}"


def test_the_cycle_check_finds_a_planted_cycle():
    """The negative control: an arrow back from the layer to the experiments closes a loop."""
    arrows = _arrows()
    arrows["sky"] = arrows["sky"] | {"experiments.objects"}
    found = _cycle(arrows)
    assert found is not None and found[0] == found[-1]


def _function_lengths(source: str) -> dict[str, int]:
    """Qualified name -> lines from the first statement after the docstring to the end."""
    lengths: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    body = child.body
                    first = body[1] if (len(body) > 1 and isinstance(body[0], ast.Expr)
                                        and isinstance(body[0].value, ast.Constant)
                                        and isinstance(body[0].value.value, str)) else body[0]
                    lengths[name] = child.end_lineno - first.lineno + 1
                visit(child, name + ".")

    visit(ast.parse(source), "")
    return lengths


def test_no_file_grows_past_its_bar():
    sizes = {relative: source.count("\n") for relative, source in _sources().items()}
    over = {relative: lines for relative, lines in sizes.items() if lines > MAX_FILE_LINES}
    new = {relative: lines for relative, lines in over.items() if relative not in OVERSIZED_FILES}
    assert not new, f"files over {MAX_FILE_LINES} lines: split them along their seams: {new}"
    grown = {relative: (over[relative], bar) for relative, bar in OVERSIZED_FILES.items()
             if relative in over and over[relative] > bar}
    assert not grown, f"listed files grew (lines now, listed): {grown}"
    stale = sorted(set(OVERSIZED_FILES) - set(over))
    assert not stale, f"no longer over the bar: take them out of OVERSIZED_FILES: {stale}"


def test_no_function_grows_past_its_bar():
    over = {f"{relative}:{name}": length for relative, source in _sources().items()
            for name, length in _function_lengths(source).items() if length > MAX_FUNCTION_LINES}
    new = {name: length for name, length in over.items() if name not in OVERSIZED_FUNCTIONS}
    assert not new, f"functions over {MAX_FUNCTION_LINES} lines (docstring excluded): {new}"
    grown = {name: (over[name], bar) for name, bar in OVERSIZED_FUNCTIONS.items()
             if name in over and over[name] > bar}
    assert not grown, f"listed functions grew (lines now, listed): {grown}"
    stale = sorted(set(OVERSIZED_FUNCTIONS) - set(over))
    assert not stale, f"no longer over the bar: take them out of OVERSIZED_FUNCTIONS: {stale}"


def _c_function_lengths(source: str) -> dict[str, int]:
    """Name -> body lines (opening brace to closing brace) of each function a C file defines: its signature starts
    in column 0 and ends in ``{`` (or holds the whole one-line function), its body ends at a ``}`` alone in column 0
    (the kernel's layout)."""
    lengths: dict[str, int] = {}
    signature: list[str] = []
    name, start = "", -1
    for number, line in enumerate(source.splitlines()):
        if start >= 0:  # in a body
            if line == "}":
                lengths[name], start = number - start + 1, -1
            continue
        if not signature and (not re.match(r"[A-Za-z_]", line) or line.startswith("typedef")):
            continue  # comments, preprocessor lines, types
        signature.append(line)
        text = re.sub(r"__attribute__\s*\(\(.*?\)\)", "", " ".join(signature)).strip()
        found = re.search(r"(\w+)\s*\(", text)
        if found and text.endswith("{") and "=" not in text.partition("(")[0]:
            name, start = found.group(1), number
        elif found and text.endswith("}"):
            lengths[found.group(1)] = 1
        if text.endswith(("{", "}", ";")):
            signature = []
    return lengths


def test_no_c_function_grows_past_its_bar():
    lengths = {f"{path.name}:{name}": length for path in sorted(KERNEL.glob("*.[ch]"))
               for name, length in _c_function_lengths(path.read_text()).items()}
    assert {"train.c:sdm_train", "chain.c:sdm_chain", "train_points.h:project_avx2", "kernel.h:clamp_unit"} <= set(
        lengths), "the C functions are not found: see _c_function_lengths"
    over = {name: length for name, length in lengths.items() if length > MAX_C_FUNCTION_LINES}
    new = {name: length for name, length in over.items() if name not in OVERSIZED_C_FUNCTIONS}
    assert not new, f"C functions over {MAX_C_FUNCTION_LINES} lines: split them into per-part functions: {new}"
    grown = {name: (over[name], bar) for name, bar in OVERSIZED_C_FUNCTIONS.items()
             if name in over and over[name] > bar}
    assert not grown, f"listed C functions grew (lines now, listed): {grown}"
    stale = sorted(set(OVERSIZED_C_FUNCTIONS) - set(over))
    assert not stale, f"no longer over the bar: take them out of OVERSIZED_C_FUNCTIONS: {stale}"


def test_the_c_function_count_sees_a_long_function():
    """The negative control: a planted function of 81 body lines (with an attribute and a prototype before it)."""
    body = "".join(f"    x += {k};\n" for k in range(79))
    source = ("int64_t declared(int64_t x);\nstatic inline int one(int x) { return x; }\n"
              "__attribute__((target(\"avx2\"))) static int64_t\nlong_one(int64_t x) {\n" + body + "}\n")
    assert _c_function_lengths(source) == {"one": 1, "long_one": MAX_C_FUNCTION_LINES + 1}


def _inner_imports() -> set[tuple[str, str, str]]:
    found = set()
    for relative, source in _sources().items():
        for function in ast.walk(ast.parse(source)):
            if isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for node in ast.walk(function):
                    if isinstance(node, ast.Import):
                        found.update((relative, function.name, alias.name) for alias in node.names)
                    elif isinstance(node, ast.ImportFrom):
                        found.add((relative, function.name, "." * node.level + (node.module or "")))
    return found


def test_imports_inside_functions_are_the_listed_optional_ones():
    found = _inner_imports()
    unlisted = sorted(found - OPTIONAL_IMPORTS - LEFT_TO_MOVE)
    assert not unlisted, f"imports inside functions (move them to the module's top): {unlisted}"
    stale = sorted((OPTIONAL_IMPORTS | LEFT_TO_MOVE) - found)
    assert not stale, f"listed but gone: take them out of the lists: {stale}"


@pytest.mark.parametrize("source, expected", [
    ("def f():\n    '''doc\n    more'''\n    a = 1\n    return a\n", {"f": 2}),
    ("class C:\n    def g(self):\n        return 1\n", {"C.g": 1}),
])
def test_function_lengths_leave_the_docstring_out(source, expected):
    assert _function_lengths(source) == expected

