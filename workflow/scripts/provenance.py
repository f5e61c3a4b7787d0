"""The committed snapshots under ``docs/results/``: what each holds, the run and the command that make it, and
its provenance file (``PROVENANCE.json``): the commit, the date, the config's digest and the fingerprint of the
code of every stage that made its files.

A snapshot is *fresh* when each of its stages' code fingerprint (``workflow/scripts/code_deps.py``, the one the
workflow puts into every stage's params) is what the working tree's code gives: a fresh run of the same config
would run the same code. It is *stale* when one differs, or when its provenance records none (a snapshot copied
by hand). :data:`KNOWN_STALE` names the stale ones with their reason, and ``tests/workflow/test_provenance.py`` holds it to
the truth both ways, as a ratchet: a snapshot not listed must be fresh, a listed one that became fresh must come
off the list. The README's verdict marks a listed snapshot's answers "stale".

The standard library only (``make snapshot`` runs it with the system Python, no torch).
"""
from __future__ import annotations

import datetime
import hashlib
import json
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import code_deps
import job_times

ROOT = code_deps.ROOT
#: Where the snapshots live: the default run's in this folder itself, the others in a folder each.
SNAPSHOTS = ROOT / "docs" / "results"
#: The provenance file each snapshot folder holds.
PROVENANCE = "PROVENANCE.json"

#: The tables of the default run and of the real sample's: Tables 1-4, their summaries and Table 3's tuning.
DEFAULT_TABLES = tuple(
    f"{table}.{kind}" for table in ("table1", "table2", "table3", "table4") for kind in ("csv", "md", "tex")
) + ("table3_summary.md", "table3_tuning.csv", "table3_tuning.md", "table4_bias.csv", "table4_summary.md")
#: The stages of the default run (every one its target asks for), in the Snakefile's order.
DEFAULT_STAGES = ("synthetic", "data", "sample", "sky", "split", "tune", "best", "noise", "tables", "baseline_tune",
                  "baseline_runs", "floor_runs", "table3", "rule_runs", "rule_bias", "table4", "figures", "report")
#: The stages the opt-in tables run on: the data, the Sky set and its split, the tuning.
UPSTREAM = ("synthetic", "data", "sample", "sky", "split", "tune", "best")


@dataclass(frozen=True)
class Part:
    """One snapshot: its folder under :data:`SNAPSHOTS`, the run that makes it and what is copied from that run.

    ``files`` maps a file of the snapshot (relative to its folder) to the run's file it copies (relative to the
    run's results folder). A folder of ``whole`` is the run's alone: taking the snapshot replaces it whole, so no
    file of an earlier take stays in it; elsewhere in the snapshot's folder only the listed files are replaced (its
    README and measurement logs kept beside it stay). ``stages``: every stage whose jobs made those files, and the
    stages upstream of them (``tests/workflow/test_workflow.py`` checks them against a dry run). ``facts``: the file of the
    verdict's facts it holds, if any (``workflow/scripts/verdict_text.py``).
    """

    name: str
    folder: str
    results: str
    config: tuple[str, ...]
    files: dict[str, str]
    stages: tuple[str, ...]
    whole: tuple[str, ...] = ()
    facts: str | None = None
    words: str = ""

    @property
    def take(self) -> str:
        """The command that takes the snapshot from its run's files."""
        return "make snapshot" if self.name == "default" else f"make snapshot-{self.name}"

    @property
    def run(self) -> str:
        """The command that runs the workflow for it (config.yaml with the snapshot's overlay)."""
        return "make run" if self.name == "default" else f"make run-{self.name}"

    @property
    def refresh(self) -> str:
        """Both, in order: what remakes the snapshot at the working tree's code."""
        return f"{self.run} && {self.take}"

    def path(self, snapshots: Path = SNAPSHOTS) -> Path:
        return snapshots / self.folder if self.folder else snapshots


def _same(folder: str, names) -> dict[str, str]:
    return {f"{folder}/{name}": f"{folder}/{name}" for name in names}


PARTS = {
    "default": Part(
        "default", "", "results", ("config.yaml",),
        files={**_same("tables", DEFAULT_TABLES),
               **_same("figures", [f"{name}.png" for name in (
                   "baselines", "distances", "fig1_configuration", "fig2_forward", "fig3_backward", "fig4_noise",
                   "research_rules", "theta_path")]),
               **_same("report", ["reproduction.md", "verdict.json"])},
        stages=DEFAULT_STAGES, whole=("tables", "figures", "report"), facts="report/verdict.json",
        words="the default run: Tables 1-4 on synthetic annotations"),
    "depth": Part(
        "depth", "depth", "results", ("config.yaml", "profiles/snapshots/depth.yaml"),
        files={**{name: f"tables/{name}" for name in (
            "table5.csv", "table5.md", "table5.tex", "table5_bias.csv", "table5_summary.md")},
               "research_depth.png": "figures/research_depth.png"},
        stages=UPSTREAM + ("depth_runs", "table5"), words="Table 5: the shift with depth"),
    "objects": Part(
        "objects", "objects", "results", ("config.yaml", "profiles/snapshots/objects.yaml"),
        files={**{name: f"tables/{name}" for name in (
            "table6.csv", "table6.md", "table6.tex", "table6_summary.md", "table6_units.csv.gz",
            "table6_verdict.json")},
               **{name: f"figures/{name}" for name in ("objects.png", "objects_scaling.png")}},
        stages=UPSTREAM + ("noise", "tables", "objects_runs", "objects_scaling", "table6"),
        facts="table6_verdict.json", words="Table 6: parameters attached to points"),
    "network": Part(
        "network", "network", "results", ("config.yaml", "profiles/snapshots/network.yaml"),
        files={**{name: f"tables/{name}" for name in (
            "table7.csv", "table7.md", "table7.tex", "table7_summary.md", "table7_verdict.json",
            "table7_curves.csv")},
               "network_curves.png": "figures/network_curves.png",
               "table7_bias.csv": "research/network/bias.csv"},
        stages=("synthetic", "data", "sample", "sky", "network_train", "network_test", "network_bias", "table7"),
        facts="table7_verdict.json", words="Table 7: SDM inside a network"),
    "sample": Part(
        "sample", "apollocar3d-sample", "results/apollocar3d-sample",
        ("config.yaml", "data/apollocar3d-sample/config.yaml"),
        files={**_same("tables", DEFAULT_TABLES), **_same("figures", ["distances.png", "research_rules.png"]),
               **_same("report", ["reproduction.md", "verdict.json"])},
        stages=tuple(stage for stage in DEFAULT_STAGES if stage not in ("synthetic", "figures")),
        whole=("tables", "figures", "report"), facts="report/verdict.json",
        words="the 57 real frames of data/apollocar3d-sample: Tables 1-4"),
}

#: The snapshots known to be stale, each with why (``tests/workflow/test_provenance.py`` checks that every listed one is stale
#: and every other one fresh, and names the command that refreshes a snapshot: :attr:`Part.refresh`; take one off
#: the list once it is taken again, then write the README's verdict again: ``make verdict``).
KNOWN_STALE: dict[str, str] = {}


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def config_digest(files, root: Path = ROOT) -> str:
    """SHA-256 over ``<path> <SHA-256 of its bytes>`` of each config file, in order (the overlays after
    config.yaml, as Snakemake merges them)."""
    return hashlib.sha256("".join(f"{name} {sha256(root / name)}\n" for name in files).encode()).hexdigest()


def git_commit(root: Path = ROOT) -> tuple[str | None, str]:
    """The checked-out commit and whether tracked files outside ``docs/`` and ``README.md`` (what takes write) differ
    from it (``"clean"`` or ``"modified"``); ``(None, "unknown")`` outside a git checkout."""
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                                check=True).stdout.strip()
        changed = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".",
                                  ":(exclude)docs", ":(exclude)README.md"], cwd=root,
                                 capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None, "unknown"
    return commit, "modified" if changed else "clean"


def now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def record(part: Part, folder: Path, stages: dict[str, str], root: Path = ROOT, jobs: dict | None = None) -> dict:
    """The provenance of ``part`` as taken now into ``folder`` (its files already there): the commit, the date,
    the config's digest, each stage's code fingerprint as the run recorded it and each file's SHA-256; with ``jobs``
    (``workflow/scripts/snapshot.py``'s ``job_times``), each job's stage, CPU and wall seconds, and the CPU seconds of
    the jobs of each stage, summed."""
    commit, tree = git_commit(root)
    timing = {}
    if jobs is not None:
        per_stage = job_times.stage_times([{"stage": job["stage"], "cpu": job["cpu_s"], "wall": job["wall_s"]}
                                           for job in jobs.values()])
        timing = {"jobs": jobs, "stage_cpu_s": {row["stage"]: round(row["cpu"], 2)
                                                for row in sorted(per_stage, key=lambda row: row["stage"])}}
    return {
        "snapshot": part.name, "folder": (Path("docs/results") / part.folder).as_posix() + "/",
        "commit": commit, "tree": tree, "date": now(),
        "config": {"files": list(part.config), "sha256": config_digest(part.config, root)},
        "stages": dict(sorted(stages.items())),
        "files": {name: sha256(folder / name) for name in sorted(part.files)},
        "run": part.run, "take": part.take, **timing,
    }


def write(folder: Path, provenance: dict) -> None:
    """``PROVENANCE.json`` in ``folder``, atomically (``sdm/io.py``'s writer, loaded without torch)."""
    code_deps.library_io().write_text(folder / PROVENANCE, json.dumps(provenance, indent=2) + "\n")


def read(folder: Path) -> dict | None:
    """The provenance of the snapshot in ``folder``; None where it has none."""
    path = folder / PROVENANCE
    return json.loads(path.read_text()) if path.is_file() else None


def short(provenance: dict | None) -> str:
    """The commit as the verdict names it: its first 7 digits, or "no commit recorded"."""
    commit = (provenance or {}).get("commit")
    return commit[:7] if commit else "no commit recorded"


def stale_stages(part: Part, provenance: dict | None,
                 fingerprint: Callable[[str], str] = code_deps.fingerprint) -> list[str]:
    """Why the snapshot is stale: each stage whose recorded code fingerprint is not what the working tree's code
    gives (or that the snapshot's provenance does not record); empty when it is fresh."""
    if provenance is None:
        return ["no provenance file"]
    recorded = provenance.get("stages")
    if not recorded:
        return ["no code fingerprint recorded"]
    return [stage for stage in part.stages if recorded.get(stage) != fingerprint(stage)]


def staleness(snapshots: Path = SNAPSHOTS, fingerprint: Callable[[str], str] = code_deps.fingerprint,
              parts: dict[str, Part] = PARTS) -> dict[str, list[str]]:
    """Every snapshot's :func:`stale_stages`, by name."""
    return {name: stale_stages(part, read(part.path(snapshots)), fingerprint) for name, part in parts.items()}


def ratchet(stale: dict[str, list[str]], known: dict[str, str] = KNOWN_STALE,
            parts: dict[str, Part] = PARTS) -> list[str]:
    """What disagrees with :data:`KNOWN_STALE`, one line each naming the snapshot and the command that refreshes
    it: a stale snapshot not listed, a listed one that is fresh (or no snapshot at all)."""
    problems = []
    for name, why in stale.items():
        part = parts[name]
        where = (Path("docs/results") / part.folder).as_posix() + "/"
        if why and name not in known:
            problems.append(f"{where} is stale ({', '.join(why)}): refresh it with `{part.refresh}`, or list it in "
                            f"KNOWN_STALE (workflow/scripts/provenance.py) with the reason")
        elif not why and name in known:
            problems.append(f"{where} is fresh: take {name!r} off KNOWN_STALE (workflow/scripts/provenance.py)")
    problems += [f"KNOWN_STALE names {name!r}, which is no snapshot" for name in known if name not in stale]
    return problems


def file_problems(part: Part, folder: Path, provenance: dict | None) -> list[str]:
    """Where the snapshot's files are not what its provenance records: a file of the part it does not list, or a
    file whose bytes differ (an edit by hand after the take)."""
    if provenance is None:
        return [f"{folder}: no {PROVENANCE}"]
    listed = provenance.get("files", {})
    problems = [f"{folder / name}: not in {PROVENANCE}" for name in sorted(set(part.files) - set(listed))]
    for name, digest in sorted(listed.items()):
        path = folder / name
        if not path.is_file():
            problems.append(f"{path}: missing")
        elif sha256(path) != digest:
            problems.append(f"{path}: not the bytes {PROVENANCE} records")
    return problems
