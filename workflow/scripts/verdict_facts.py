"""A committed snapshot's verdict facts, computed again from its own CSVs, without rerunning its workflow.

    .venv/bin/python workflow/scripts/verdict_facts.py NAME...    # default, sample, objects, network

A run writes its verdict facts itself (the report stage's ``report/verdict.json``, Table 6's and Table 7's
``table<n>_verdict.json``), and ``make snapshot-<name>`` copies them. This script computes the same facts with the
same library functions (``sdm.experiments.report.verdict.facts``, ``sdm.experiments.report.objects.verdict_facts``,
``sdm.experiments.report.network.verdict_facts``) from the CSVs a snapshot holds, for a snapshot whose run wrote none or whose
facts changed shape since. It writes the facts file into the snapshot's folder and records in its
``PROVENANCE.json`` the file's new SHA-256 and, under ``derived``, that this script made it, at which commit, from
which files. The verdict reads the config (``config.yaml`` and the snapshot's overlay, merged as Snakemake merges
them) for the methods and rules it compares and for the data's size.
"""
from __future__ import annotations

import sys
from pathlib import Path

import yaml

import provenance
from code_deps import ROOT
from provenance import PARTS
from sdm.io import write_json
from sdm.experiments.report import network, objects
from sdm.experiments.report.io import read_csv
from sdm.experiments.report.verdict import data_facts, facts

#: The CSVs each snapshot's facts are computed from (relative to its folder).
SOURCES = {
    "default": ("tables/table1.csv", "tables/table2.csv", "tables/table3.csv", "tables/table4.csv"),
    "sample": ("tables/table1.csv", "tables/table2.csv", "tables/table3.csv", "tables/table4.csv"),
    "objects": ("table6.csv",),
    "network": ("table7.csv",),
}


def merged_config(files) -> dict:
    """The config files merged key by key, the later over the earlier (Snakemake's ``--configfile``)."""

    def merge(base: dict, over: dict) -> dict:
        for key, value in over.items():
            base[key] = merge(dict(base.get(key) or {}), value) if isinstance(value, dict) else value
        return base

    config: dict = {}
    for name in files:
        config = merge(config, yaml.safe_load((ROOT / name).read_text()) or {})
    return config


def images(config: dict) -> int:
    """How many images the run's data has: the synthetic set's size, or the annotation files of a real folder."""
    data = config["data"]
    if data["source"] == "synthetic":
        return int(data["synthetic"]["n_images"])
    return len(list((ROOT / data["apollo_folder"]).glob("car_poses/*.json")))


def facts_of(name: str, folder: Path) -> dict:
    """The verdict facts of snapshot ``name`` from the CSVs in ``folder``."""
    tables = [read_csv(folder / source) for source in SOURCES[name]]
    if name == "objects":
        return objects.verdict_facts(tables[0])
    if name == "network":
        return network.verdict_facts(tables[0])
    config = merged_config(PARTS[name].config)
    methods = ["sdm", *config["baselines"]["methods"]] if config["baselines"]["enabled"] else ["sdm"]
    rules = config["research"]["rules"]["names"] if config["research"]["rules"]["enabled"] else []
    return facts(tables[0], tables[1], tables[2], methods, tables[3], rules,
                 data=data_facts(config, {"images": images(config)}))


def main(names: list[str]) -> int:
    unknown = [name for name in names if name not in SOURCES]
    if not names or unknown:
        sys.exit(__doc__ + (f"\nunknown: {', '.join(unknown)}" if unknown else ""))
    commit, tree = provenance.git_commit()
    for name in names:
        part = PARTS[name]
        folder = part.path()
        recorded = provenance.read(folder)
        if recorded is None:
            sys.exit(f"{folder}: no {provenance.PROVENANCE}; take the snapshot first (`{part.refresh}`)")
        write_json(folder / part.facts, facts_of(name, folder))
        recorded["files"][part.facts] = provenance.sha256(folder / part.facts)
        recorded.setdefault("derived", {})[part.facts] = {
            "by": "workflow/scripts/verdict_facts.py", "commit": commit, "tree": tree, "date": provenance.now(),
            "from": list(SOURCES[name])}
        provenance.write(folder, recorded)
        print(f"wrote {(folder / part.facts).relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
