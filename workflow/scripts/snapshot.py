"""The default run's results, committed: ``docs/results/``, and the README's verdict taken from it.

    python workflow/scripts/snapshot.py take      # results/ -> docs/results/, then the README's verdict section
    python workflow/scripts/snapshot.py check     # exit 1 (naming each) on a README or docs number not in it

``take`` (``make snapshot``, after ``make run``) replaces ``docs/results/{tables,figures,report}/`` with
the default run's files (:data:`DEFAULT_RUN`) of ``results/tables/`` (CSV, Markdown and LaTeX tables, the
``*_summary.md`` texts), ``results/figures/`` (PNG) and ``results/report/`` (the reproduction report and the
verdict), and writes ``docs/results/report/verdict.md`` into README.md between the verdict markers (figure
paths made relative to the README). It is atomic and exact: it first checks that every file of the default run
is in ``results/`` (and that each CSV matches its checksum file), and exits naming the missing or damaged ones
before anything is touched; it builds the new parts beside the old ones and swaps them in, then the README.
The opt-in stages' files (Tables 5-7 and their figures) are never taken: their snapshots have folders of their
own. Nothing else in ``docs/results/`` is touched (``timing.md`` is written by ``make timing``).

``check`` holds the README and docs to the snapshot: the verdict section must be the snapshot's verdict,
and every results number they quote -- a distance in 1e-3 m (``5.76e-3 m``) or a ratio (``1.6x``,
``1.6-1.9x``), in README.md, docs/workflow.md, or a paragraph of the other docs/*.md and docs/method/*.md that
says it speaks of the run (``the default run``, ``docs/results``, ``results/tables``, ...) -- must be a value the snapshot holds at the
quoted precision (``5.76`` matches a table's ``5.758``). A paragraph that
names the command its numbers come from (``benchmarks/...``, ``make bench``) quotes that command's
measurement, not the run's, and is not checked. The standard library only: no torch, no pandas.
"""
from __future__ import annotations

import re
import secrets
import shutil
import sys
from pathlib import Path

from code_deps import library_io  # sdm/io.py (the CSVs' checksums), loaded without importing sdm (torch)

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "results"
SNAPSHOT = ROOT / "docs" / "results"
README = ROOT / "README.md"
#: The parts of results/ the snapshot holds, and the default run's files of each: all of them must be there.
#: (Not the tables' and the report's HTML pages: the same text again, made for `make report`; not the opt-in
#: stages' Tables 5-7 and figures.)
DEFAULT_RUN = {
    "tables": [f"{table}.{kind}" for table in ("table1", "table2", "table3", "table4") for kind in ("csv", "md", "tex")]
    + ["table3_summary.md", "table3_tuning.csv", "table3_tuning.md", "table4_bias.csv", "table4_summary.md"],
    "figures": [f"{name}.png" for name in ("baselines", "distances", "fig1_configuration", "fig2_forward",
                                           "fig3_backward", "fig4_noise", "research_rules", "theta_path")],
    "report": ["reproduction.md", "verdict.md"],
}
BEGIN = "<!-- verdict: written by `make snapshot` from docs/results/report/verdict.md; do not edit by hand -->"
END = "<!-- end of verdict -->"
#: A results number: a distance in 1e-3 m or a ratio, alone or as a range (``1.6-1.9x``, ``30 to 68e-3 m``).
QUOTED = re.compile(r"(?<![\w.])(\d+(?:\.\d+)?)(?:\s*(?:-|to)\s*(\d+(?:\.\d+)?))?(e-3 m\b|e-3\b|x\b)")
#: Where a paragraph says its numbers are a named command's measurement, not the run's.
OWN_SOURCE = re.compile(r"benchmarks/|make bench")
#: Where a paragraph of docs/method/*.md or the other docs (notes of experiments, each with its own command) says
#: it quotes the workflow's run.
SPEAKS_OF_THE_RUN = re.compile(r"default run|the run's|docs/results|results/tables|make run")


def take(results: Path = RESULTS, snapshot: Path = SNAPSHOT, readme: Path = README) -> None:
    """Copy the default run's results into the snapshot, then write the README's verdict section from it.

    Exits (``SystemExit``, naming each file) before touching anything where a file of :data:`DEFAULT_RUN` is
    missing from ``results`` or a CSV does not match its checksum file; then builds the new parts beside the old
    ones and swaps them in, part by part (a rename each), and writes the README atomically last.
    """
    io = library_io()
    problems = []
    for part, names in DEFAULT_RUN.items():
        for name in names:
            path = results / part / name
            if not path.is_file():
                problems.append(f"{path}: missing")
            elif path.suffix == ".csv" and (damage := io.csv_damage(path)) is not None:
                problems.append(f"{path}: {damage}")
    if problems:
        raise SystemExit("the default run is not complete in results/ (run `make run` first); docs/results/ is "
                         "unchanged:\n" + "\n".join(problems))
    text = with_verdict(readme.read_text(), "")  # the README has its one verdict section, before anything moves
    staging = snapshot / f".take-{secrets.token_hex(6)}"
    try:
        for part, names in DEFAULT_RUN.items():
            (staging / part).mkdir(parents=True)
            for name in names:
                shutil.copy2(results / part / name, staging / part / name)
        verdict = readme_verdict(staging, readme, snapshot)
        for part in DEFAULT_RUN:  # the swap, a rename each (same folder): old part aside, new part in
            target = snapshot / part
            if target.exists():
                target.rename(staging / f"{part}.old")
            (staging / part).rename(target)
        io.write_text(readme, with_verdict(text, verdict))
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def readme_verdict(snapshot: Path = SNAPSHOT, readme: Path = README, linked: Path | None = None) -> str:
    """The snapshot's verdict as the README shows it: its relative links made relative to the README (to the
    snapshot at ``linked``, where ``snapshot`` is a copy being built)."""
    verdict = (snapshot / "report" / "verdict.md").read_text()
    base = ((linked or snapshot) / "report").relative_to(readme.parent)

    def rebased(match: re.Match) -> str:
        target = (base / match.group(2)).as_posix()
        while "/../" in f"/{target}":  # docs/results/report/../figures -> docs/results/figures
            target = re.sub(r"(^|/)[^/.][^/]*/\.\./", r"\1", target, count=1)
        return f"{match.group(1)}({target})"

    return re.sub(r"(!?\[[^\]]*\])\((?!https?:)([^)]+)\)", rebased, verdict)


def readme_section(text: str) -> str:
    """What README.md holds between the verdict markers."""
    if text.count(BEGIN) != 1 or text.count(END) != 1 or text.index(BEGIN) > text.index(END):
        raise SystemExit(f"README.md: needs one verdict section, from {BEGIN!r} to {END!r}")
    return text[text.index(BEGIN) + len(BEGIN):text.index(END)].strip("\n") + "\n"


def with_verdict(text: str, verdict: str) -> str:
    """README.md's text with its verdict section replaced by ``verdict``."""
    readme_section(text)  # exactly one section
    return text[:text.index(BEGIN) + len(BEGIN)] + "\n\n" + verdict.strip("\n") + "\n\n" + text[text.index(END):]


def snapshot_values(snapshot: Path = SNAPSHOT) -> list[float]:
    """Every number the snapshot's Markdown shows (its tables in 1e-3 m, the summaries, the report, the
    verdict): what a reader can quote. Not the CSVs' full-precision metres: thousands of values there would
    match almost any quoted number at two decimals."""
    values = []
    for path in sorted(snapshot.rglob("*.md")):
        values += [abs(float(text)) for text in re.findall(r"\d+(?:\.\d+)?", path.read_text())]
    return values


def held(quoted: str, values: list[float]) -> bool:
    """Whether ``quoted`` (a decimal as written) is one of ``values`` at its precision."""
    decimals = len(quoted.partition(".")[2])
    target = float(quoted)
    return any(abs(value - target) <= 0.5 * 10 ** -decimals + 1e-12 for value in values)


def _paragraphs(text: str) -> list[tuple[int, str]]:
    """Paragraphs (blank-line separated) and table rows (one each), with their first line number."""
    found, start, lines = [], 1, []
    for number, line in enumerate(text.splitlines() + [""], start=1):
        if line.startswith("|"):
            if lines:
                found.append((start, "\n".join(lines)))
                lines = []
            found.append((number, line))
        elif line.strip():
            if not lines:
                start = number
            lines.append(line)
        elif lines:
            found.append((start, "\n".join(lines)))
            lines = []
    return found


def unheld_numbers(files: list[Path], values: list[float], everywhere: set[Path]) -> list[str]:
    """``file:line: number`` for each results number of ``files`` the snapshot does not hold; in a file of
    ``everywhere`` every paragraph is checked, elsewhere those that speak of the run's tables."""
    missing = []
    for path in files:
        text = path.read_text()
        if path == README and BEGIN in text:  # the verdict section is the snapshot's own text
            text = text[:text.index(BEGIN)] + "\n" * text[text.index(BEGIN):text.index(END)].count("\n") \
                + text[text.index(END):]
        # code blocks hold tolerances and examples, not quotes of the run: blanked, keeping the line numbers
        text = re.sub(r"^```.*?^```", lambda block: "\n" * block.group(0).count("\n"), text, flags=re.M | re.S)
        for line, paragraph in _paragraphs(text):
            if OWN_SOURCE.search(paragraph):
                continue
            if path not in everywhere and not SPEAKS_OF_THE_RUN.search(paragraph):
                continue
            for match in QUOTED.finditer(paragraph):
                if match.group(0).startswith("1e-3"):  # the unit itself, "in 1e-3 m"
                    continue
                for quoted in filter(None, match.group(1, 2)):
                    if ("." in quoted or match.group(3) != "x") and not held(quoted, values):
                        at = line + paragraph[:match.start()].count("\n")
                        shown = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
                        missing.append(f"{shown}:{at}: {match.group(0)}")
    return missing


def check(readme: Path = README, snapshot: Path = SNAPSHOT) -> list[str]:
    """Every disagreement of the README and docs with the snapshot, one line each (none: they agree)."""
    problems = []
    if readme_section(readme.read_text()) != readme_verdict(snapshot, readme).strip("\n") + "\n":
        problems.append(f"{readme.name}: the verdict section is not {snapshot / 'report' / 'verdict.md'} "
                        f"(run `make snapshot`)")
    docs = sorted([*(ROOT / "docs").glob("*.md"), *(ROOT / "docs" / "method").glob("*.md")])
    values = snapshot_values(snapshot)
    problems += [f"{line} is not in {snapshot}/" for line in
                 unheld_numbers([readme, *docs], values, {readme, ROOT / "docs" / "workflow.md"})]
    return problems


if __name__ == "__main__":
    if sys.argv[1:] == ["take"]:
        take()
    elif sys.argv[1:] == ["check"]:
        found = check()
        print("\n".join(found) or "README and docs agree with docs/results/")
        sys.exit(1 if found else 0)
    else:
        sys.exit(__doc__)
