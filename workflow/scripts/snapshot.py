"""The committed snapshots of the workflow's runs (``docs/results/``), their provenance, and the README's verdict.

    python workflow/scripts/snapshot.py take [--part NAME]...  # runs' files -> their snapshot folders, then the verdict
    python workflow/scripts/snapshot.py verdict             # the README's verdict, assembled from the snapshots
    python workflow/scripts/snapshot.py status              # each snapshot: its commit, fresh or stale, its command
    python workflow/scripts/snapshot.py check               # exit 1 (naming each) on a README or docs number not held

The snapshots are :data:`provenance.PARTS`: ``default`` (``make snapshot``: the default run's
``results/{tables,figures,report}/`` into ``docs/results/``), ``depth``, ``objects``, ``network`` (``make
snapshot-depth`` and so on: Tables 5-7 from a run with the overlay ``profiles/snapshots/<name>.yaml``, into
``docs/results/<name>/``) and ``sample`` (``make snapshot-sample``: the real sample's run,
``results/apollocar3d-sample/``, into ``docs/results/apollocar3d-sample/``). ``make run-<name>`` makes each run.

``take`` is atomic and exact. Before anything is touched it checks that every file of the snapshot is in the
run's folder, that each CSV matches its checksum file, and that every stage of the snapshot ran, with one version
of its code, the working tree's: each executed notebook (``<results>/notebooks/<job>.ipynb``) records its stage's
code fingerprint (``workflow/scripts/run_notebook.py``). Otherwise it exits naming each problem. It then builds
the new files beside the old ones and swaps them in (a folder the run owns whole, such as ``tables/``, at once; a
file beside a README or a measurement log, file by file), writes the folder's ``PROVENANCE.json``
(:mod:`provenance`) and, last, the README's verdict.

``verdict`` writes the README's verdict section from the snapshots' facts (:mod:`verdict_text`), each answer
naming its snapshot, that snapshot's commit and whether it is stale (:data:`provenance.KNOWN_STALE`).

``check`` holds the README and docs to the snapshots: the verdict section must be what ``verdict`` writes, and
every results number they quote -- a distance in 1e-3 m (``5.76e-3 m``) or a ratio (``1.6x``, ``1.6-1.9x``), in
README.md, docs/workflow.md, or a paragraph of the other docs/*.md and docs/method/*.md that says it speaks of the
run (``the default run``, ``docs/results``, ``results/tables``, ...) -- must be a value the snapshots' Markdown
holds at the quoted precision (``5.76`` matches a table's ``5.758``). A paragraph that names the command its
numbers come from (``benchmarks/...``, ``make bench``) quotes that command's measurement, not the run's, and is not
checked. The standard library only: no torch, no pandas.
"""
from __future__ import annotations

import argparse
import json
import re
import secrets
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

import job_times as jobs
import provenance
import verdict_text
from code_deps import fingerprint, library_io  # sdm/io.py (the CSVs' checksums), loaded without importing sdm
from provenance import PARTS
from run_notebook import STAGE_METADATA

ROOT = Path(__file__).resolve().parents[2]
SNAPSHOT = ROOT / "docs" / "results"
README = ROOT / "README.md"
#: The default run's files per part of results/ (tables/, figures/, report/): the default snapshot.
DEFAULT_RUN = {part: sorted(name.partition("/")[2] for name in PARTS["default"].files if name.startswith(part + "/"))
               for part in PARTS["default"].whole}
BEGIN = "<!-- verdict: assembled by `make snapshot` from the snapshots under docs/results/; do not edit by hand -->"
END = "<!-- end of verdict -->"
#: A results number: a distance in 1e-3 m or a ratio, alone or as a range (``1.6-1.9x``, ``30 to 68e-3 m``).
QUOTED = re.compile(r"(?<![\w.])(\d+(?:\.\d+)?)(?:\s*(?:-|to)\s*(\d+(?:\.\d+)?))?(e-3 m\b|e-3\b|x\b)")
#: Where a paragraph says its numbers are a named command's measurement, not the run's.
OWN_SOURCE = re.compile(r"benchmarks/|make bench")
#: Where a paragraph of docs/method/*.md or the other docs (notes of experiments, each with its own command) says
#: it quotes the workflow's run.
SPEAKS_OF_THE_RUN = re.compile(r"default run|the run's|docs/results|results/tables|make run")


def run_stages(results: Path) -> dict[str, set[str]]:
    """Stage -> the code fingerprints its executed notebooks in ``results/notebooks/`` record (one per version of
    the code its jobs ran)."""
    found: dict[str, set[str]] = {}
    for path in sorted((results / "notebooks").glob("*.ipynb")):
        try:
            stage = json.loads(path.read_text(encoding="utf-8")).get("metadata", {}).get(STAGE_METADATA)
        except (OSError, ValueError):
            continue
        if isinstance(stage, dict) and "name" in stage and "code" in stage:
            found.setdefault(stage["name"], set()).add(stage["code"])
    return found


def job_times(results: Path, stages) -> dict[str, dict]:
    """Job -> its stage, its CPU seconds (its log's whole count, else Snakemake's ``benchmark:`` file's) and its wall
    seconds (:func:`job_times.job_times` on ``results/benchmarks/``, ``results/notebooks/`` and ``results/logs/``),
    for every job of ``stages`` with a measured CPU time; in job order."""
    measured = jobs.job_times(results / "benchmarks", results / "notebooks", results / "logs")
    return {job["job"]: {"stage": job["stage"], "cpu_s": round(job["cpu"], 2), "wall_s": round(job["wall"], 2)}
            for job in sorted(measured, key=lambda job: job["job"])
            if job["stage"] in stages and job["cpu"] == job["cpu"]}


def problems_of(part: provenance.Part, results: Path, code=fingerprint) -> list[str]:
    """Why the run in ``results`` cannot be taken as ``part``'s snapshot, one line each (none: it can)."""
    io, problems = library_io(), []
    for source in sorted(set(part.files.values())):
        path = results / source
        if not path.is_file():
            problems.append(f"{path}: missing")
        elif path.suffix == ".csv" and (damage := io.csv_damage(path)) is not None:
            problems.append(f"{path}: {damage}")
    ran = run_stages(results)
    for stage in part.stages:
        codes = ran.get(stage, set())
        if not codes:
            problems.append(f"stage {stage}: no executed notebook in {results / 'notebooks'} records it")
        elif len(codes) > 1:
            problems.append(f"stage {stage}: its jobs ran {len(codes)} versions of its code")
        elif codes != {code(stage)}:
            problems.append(f"stage {stage}: it ran other code than the working tree's (edited since the run?)")
    return problems


def _swap_in(part: provenance.Part, staging: Path, folder: Path) -> None:
    """Move the staged files and provenance into the snapshot's folder: each folder of ``part.whole`` at once (the old
    one aside), each other file by a rename of its own."""
    for name in part.whole:
        target = folder / name
        if target.exists():
            target.rename(staging / f"{name}.old")
        (staging / name).rename(target)
    for name in [*part.files, provenance.PROVENANCE]:
        if name.partition("/")[0] not in part.whole:
            (folder / name).parent.mkdir(parents=True, exist_ok=True)
            (staging / name).replace(folder / name)


def take(name: str = "default", results: Path | None = None, snapshot: Path = SNAPSHOT, readme: Path = README,
         code=fingerprint) -> None:
    """Copy the run's files of snapshot ``name`` into its folder with its provenance, then write the README's verdict
    (:func:`take_all` of that one snapshot; ``results``: its run's folder, by default its own)."""
    take_all([name], {name: results} if results is not None else None, snapshot, readme, code)


def take_all(names: Sequence[str], results: dict[str, Path] | None = None, snapshot: Path = SNAPSHOT,
             readme: Path = README, code=fingerprint) -> None:
    """Take the snapshots ``names`` together: the verdict is assembled once, from all of them as taken.

    Exits (``SystemExit``, naming each problem, :func:`problems_of`) before touching anything where one run is not
    complete and current; then builds every snapshot's new files, their provenance and the verdict beside the old
    ones, swaps the files in and writes the README atomically last. Taking several at once is how the snapshots are
    retaken at one commit when a change of the facts' form reaches all of them (one at a time, the verdict would
    read the others in their old form).
    """
    parts = {name: PARTS[name] for name in dict.fromkeys(names)}
    folders = {name: (results or {}).get(name) or ROOT / part.results for name, part in parts.items()}
    problems = {name: problems_of(part, folders[name], code) for name, part in parts.items()}
    for name, found in problems.items():
        if found:
            raise SystemExit(f"the run of snapshot {name!r} is not complete and current in {folders[name]} (run "
                             f"`{parts[name].run}` first); {parts[name].path(snapshot)} is unchanged:\n"
                             + "\n".join(found))
    text = with_verdict(readme.read_text(), "")  # the README has its one verdict section, before anything moves
    staged = {}
    try:
        for name, part in parts.items():
            folder = part.path(snapshot)
            folder.mkdir(parents=True, exist_ok=True)
            staged[name] = staging = folder / f".take-{secrets.token_hex(6)}"
            for target, source in part.files.items():
                (staging / target).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(folders[name] / source, staging / target)
            ran = run_stages(folders[name])
            provenance.write(staging, provenance.record(part, staging,
                                                        {stage: min(ran[stage]) for stage in part.stages},
                                                        jobs=job_times(folders[name], part.stages)))
        verdict = assemble(snapshot, staged=staged)
        for name, part in parts.items():
            _swap_in(part, staged[name], part.path(snapshot))
        library_io().write_text(readme, with_verdict(text, verdict))
    finally:
        for staging in staged.values():
            shutil.rmtree(staging, ignore_errors=True)


def snapshots_read(snapshot: Path = SNAPSHOT, known: dict | None = None,
                   staged: dict[str, Path] | None = None) -> dict[str, dict]:
    """Each snapshot with verdict facts: ``{"facts", "folder", "commit", "stale"}`` by name (the default's needed);
    a snapshot of ``staged`` is read from the folder given there (one being taken)."""
    known = provenance.KNOWN_STALE if known is None else known
    found = {}
    for name, part in PARTS.items():
        folder = (staged or {}).get(name) or part.path(snapshot)
        if part.facts is None or not (folder / part.facts).is_file():
            continue
        found[name] = {"facts": json.loads((folder / part.facts).read_text()),
                       "folder": (Path("docs/results") / part.folder).as_posix() + "/",
                       "commit": provenance.short(provenance.read(folder)), "stale": name in known}
    if "default" not in found:
        raise SystemExit(f"{PARTS['default'].path(snapshot) / PARTS['default'].facts}: missing (run `make run` and "
                         f"`make snapshot`)")
    return found


def assemble(snapshot: Path = SNAPSHOT, known: dict | None = None, staged: dict[str, Path] | None = None) -> str:
    """The README's verdict from the snapshots (:func:`verdict_text.render` of :func:`verdict_text.verdict`)."""
    return verdict_text.render(verdict_text.verdict(snapshots_read(snapshot, known, staged)))


def write_verdict(readme: Path = README, snapshot: Path = SNAPSHOT) -> None:
    """The README's verdict section, assembled again from the snapshots (after :data:`provenance.KNOWN_STALE` or the
    wording changed)."""
    library_io().write_text(readme, with_verdict(readme.read_text(), assemble(snapshot)))


def status(snapshot: Path = SNAPSHOT) -> list[str]:
    """One line per snapshot: its folder, commit and date, fresh or stale (and why), the command that remakes it."""
    lines = []
    for name, part in PARTS.items():
        folder = part.path(snapshot)
        recorded = provenance.read(folder)
        stale = provenance.stale_stages(part, recorded)
        listed = provenance.KNOWN_STALE.get(name)
        state = "fresh" if not stale else f"stale ({', '.join(stale)})"
        shown = folder.relative_to(ROOT) if folder.is_relative_to(ROOT) else folder
        lines.append(f"{name} ({part.words}): {shown}/, commit "
                     f"{provenance.short(recorded)}, {(recorded or {}).get('date', 'no date')}: {state}"
                     + (f" (listed: {listed})" if listed else "") + f"; remade by `{part.refresh}`")
    return lines


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
    if readme_section(readme.read_text()) != assemble(snapshot).strip("\n") + "\n":
        problems.append(f"{readme.name}: the verdict section is not the one the snapshots give (run "
                        f"`python3 workflow/scripts/snapshot.py verdict`)")
    docs = sorted([*(ROOT / "docs").glob("*.md"), *(ROOT / "docs" / "method").glob("*.md")])
    values = snapshot_values(snapshot)
    problems += [f"{line} is not in {snapshot}/" for line in
                 unheld_numbers([readme, *docs], values, {readme, ROOT / "docs" / "workflow.md"})]
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=("take", "verdict", "status", "check"))
    parser.add_argument("--part", action="append", choices=sorted(PARTS),
                        help="the snapshot to take (default: default); given several times, they are taken together")
    args = parser.parse_args(argv)
    if args.command == "take":
        take_all(args.part or ["default"])
    elif args.command == "verdict":
        write_verdict()
    elif args.command == "status":
        print("\n".join(status()))
    else:
        found = check()
        print("\n".join(found) or "README and docs agree with docs/results/")
        return 1 if found else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
