"""The README's verdict: the snapshots' facts, answered as data (:func:`verdict`) and put into words by one function
(:func:`render`).

The facts are the runs' own (``report/verdict.json`` of the default run and of the real sample, Table 6's
``table6_verdict.json``, Table 7's ``table7_verdict.json``: ``sdm.experiments.report.verdict`` and the ``verdict_facts`` of
``sdm.experiments.report.objects`` and ``sdm.experiments.report.network``). :func:`verdict` picks what each answer needs, with the
snapshots it comes from; :func:`render` is the only place that words them, so the wording can change while the
tests hold the data. The verdict is a short table in millimetres, then at most five answers, one sentence each:
does SDM reproduce the paper, does it beat black-box search on the paper's problem, what to use instead and when,
what SDM is good for, and the recommended schedule with where it was measured. Each answer ends with its
sources: the snapshot folder, its commit, and "stale" for a snapshot of :data:`provenance.KNOWN_STALE`.

The standard library only (``make snapshot`` runs it with the system Python).
"""
from __future__ import annotations

#: Where the terms the verdict uses are defined (relative to the README).
LINKS = {
    "cmaes": "docs/method/paper.md#against-other-losses-table-3",
    "schedule": "docs/method/floor.md#the-schedule-that-reaches-the-floor-closed_centred_r1-then-group_crossing-passes",
    "objects": "docs/method/objects.md#doing-nothing",
    "gate": "docs/method/objects.md#the-prior-gate",
    "network": "docs/method/network.md",
    "data": "docs/data.md",
    "stale": "docs/results/README.md#provenance-and-stale-snapshots",
    "figure": "docs/results/figures/research_rules.png",
}
#: The sharing level and screen the per-unit answer reads (Table 6's first screen: where a car is identifiable).
PER_UNIT = "car"


def _span(values, digits: int = 2, suffix: str = "x") -> str:
    """``1.61-1.86x`` (one value alone where they agree at that precision)."""
    low, high = f"{min(values):.{digits}f}", f"{max(values):.{digits}f}"
    return f"{low}{suffix}" if low == high else f"{low}-{high}{suffix}"


def _levels(noise_levels) -> str:
    """``[1, 2, 3, 4]`` -> ``"levels 1-4"``; ``[0, 2]`` -> ``"levels 0 and 2"``; ``[3]`` -> ``"level 3"``."""
    noise_levels = sorted(int(noise_level) for noise_level in noise_levels)
    if len(noise_levels) == 1:
        return f"level {noise_levels[0]}"
    if len(noise_levels) > 2 and noise_levels == list(range(noise_levels[0], noise_levels[-1] + 1)):
        return f"levels {noise_levels[0]}-{noise_levels[-1]}"
    return "levels " + ", ".join(str(noise_level) for noise_level in noise_levels[:-1]) + f" and {noise_levels[-1]}"


def _data_words(data: dict) -> str:
    if data.get("source") == "synthetic":
        return "the synthetic default"
    return f"the {data.get('images')} real frames of {data.get('folder')}"


def _per_unit(objects: dict | None) -> dict | None:
    """Table 6's rows of :data:`PER_UNIT` on its first screen, as ranges over the noise levels."""
    if not objects or not objects.get("rows"):
        return None
    scale = objects["scales"][0]
    rows = [row for row in objects["rows"] if row["scale"] == scale and row["sharing"] == PER_UNIT]
    if not rows:
        return None
    peered = [row for row in rows if row["peer"] is not None]
    return {"scale": scale, "screen": rows[0]["screen"], "levels": [row["noise_level"] for row in rows],
            "gated": all(row.get("gated") for row in rows),
            "removed": [row["removed"] for row in rows], "closer": [row["closer"] for row in rows],
            "peer": peered[0]["peer_label"] if peered else None, "peer_method": peered[0]["peer"] if peered else None,
            "peer_removed": [row["peer_removed"] for row in peered], "cpu_ratio": [row["cpu_ratio"] for row in peered]}


def _network(network: dict | None) -> dict | None:
    if not network or not network.get("loss"):
        return None
    rows = network["levels"]
    pick = lambda key: [row[key] for row in rows if row.get(key) is not None]  # noqa: E731
    paired = [row["paired"]["silhouette"] for row in rows if (row.get("paired") or {}).get("silhouette")]
    return {"rule": network["rule"], "levels": [row["noise_level"] for row in rows], "to_nothing": pick("to_nothing"),
            "to_supervised": pick("to_supervised"), "ahead_of_silhouette": paired.count("closer"),
            "behind_silhouette": paired.count("farther"), "paired_levels": len(paired)}


def _schedule(default: dict, sample: dict | None) -> dict | None:
    """The recommended schedule on the default data and, where it names the same schedule, the real sample: the
    worst ratio to CMA-ES's mean over both, and per data set the levels beyond the bar."""
    schedule = default.get("schedule")
    if not schedule or not schedule.get("name"):
        return None
    measured = [("default", default, schedule)]
    if sample and (sample.get("schedule") or {}).get("name") == schedule["name"]:
        measured.append(("sample", sample, sample["schedule"]))
    worst, beyond, data = None, [], []
    for name, facts, own in measured:
        kind = "synthetic" if facts["data"].get("source") == "synthetic" else "real"
        data.append({"words": _data_words(facts["data"]), "runs": (own.get("to_search") or {}).get("runs")})
        against = own.get("to_search")
        if not against:
            continue
        if worst is None or against["high"] > worst["high"]:
            worst = {"high": against["high"], "noise_level": against["worst_level"], "data": _data_words(facts["data"])}
        if against["beyond"]:
            beyond.append({"kind": kind, "levels": against["beyond"]})
    return {"name": schedule["name"], "meets_bar": schedule["meets_bar"], "judged": schedule["judged"],
            "factor": schedule["factor"], "worst": worst, "beyond": beyond, "data": data,
            "sources": [name for name, *_ in measured]}


def verdict(snapshots: dict[str, dict]) -> dict:
    """The verdict as data, from each snapshot's ``{"facts": ..., "provenance": ..., "stale": bool}`` by name
    (``default`` is needed; ``sample``, ``objects``, ``network`` are read where they are given).

    Returns ``{"table": ..., "answers": [...], "sources": {name: {"folder", "commit", "stale"}}}``: the table's rows
    (millimetres) and data, and per answer its ``key``, its ``level`` where it has one, its numbers and the names of
    its ``sources``.
    """
    default = snapshots["default"]["facts"]
    facts = {name: snapshot["facts"] for name, snapshot in snapshots.items()}
    answers = [{"key": "reproduction", **default["reproduction"], "sources": ["default"]}]
    search = default.get("search")
    if search:
        answers.append({"key": "search", **search, "sources": ["default"]})
    per_unit, network = _per_unit(facts.get("objects")), _network(facts.get("network"))
    if search or per_unit:
        answers.append({"key": "instead", "search": search, "per_unit": per_unit,
                        "sources": ["default"] + (["objects"] if per_unit else [])})
    if per_unit or network:
        answers.append({"key": "good_for", "per_unit": per_unit, "network": network,
                        "sources": (["objects"] if per_unit else []) + (["network"] if network else [])})
    schedule = _schedule(default, facts.get("sample"))
    if schedule:
        answers.append({"key": "schedule", **schedule})
    return {"table": {"data": default["data"], "rows": default["levels"], "schedule": (schedule or {}).get("name"),
                      "sources": ["default"]},
            "answers": answers,
            "sources": {name: {"folder": snapshot["folder"], "commit": snapshot["commit"], "stale": snapshot["stale"]}
                        for name, snapshot in snapshots.items()}}


# -- the words -------------------------------------------------------------------------------------------------


def _mm(value) -> str:
    return "-" if value is None else f"{value:.3f}"


def _source_tag(names, sources) -> str:
    """`` — source: docs/results/objects/, commit f6a5ffb (stale)``: what an answer reads."""
    shown = [f"[{sources[name]['folder']}]({sources[name]['folder']}), commit {sources[name]['commit']}"
             + (" (**stale**)" if sources[name]["stale"] else "") for name in names if name in sources]
    return f" — *source{'s' if len(shown) > 1 else ''}:* " + "; ".join(shown)


def _reproduction(answer: dict) -> str:
    free, noisy, tuning = answer["noise_free"], answer["noisy"], answer["tuning"]
    parts = []
    if free:
        parts.append(f"the noise-free mean is {free['mm']:.3f} mm (paper: {free['paper_mm']:.3f} mm)")
    if noisy:
        band = f"{noisy['band'][0]:g}-{noisy['band'][1]:g}x"
        parts.append(f"the noisy means are {_span([noisy['low'], noisy['high']])} the paper's (acceptance band: "
                     f"{band}{'' if noisy['within'] else ', missed'})")
    if not tuning["same"]:
        parts.append(f"tuning picks {tuning['n_epoch']} epochs at learning rate {tuning['lr']:.0e} (paper: "
                     f"{tuning['paper_n_epoch']} at {tuning['paper_lr']:.0e})")
    joined = parts[0] + (", but " + ", and ".join(parts[1:]) if len(parts) > 1 else "")
    return f"**Reproduces the paper?** {answer['verdict'].capitalize()}: {joined}."


def _search(answer: dict) -> str:
    worst = answer["worst"]
    head = {"no": "No", "partly": "Not everywhere", "yes": "Yes"}[answer["verdict"]]
    if answer["verdict"] == "yes":
        return (f"**Beats black-box search?** Yes: SDM ends closer than [CMA-ES]({LINKS['cmaes']}) at every "
                f"noise level.")
    where = "every noise level" if not answer["sdm_closer_at"] else _levels(answer["search_closer_at"])
    sdm = f"; SDM only at {_levels(answer['sdm_closer_at'])}" if answer["sdm_closer_at"] else ""
    return (f"**Beats black-box search?** {head}: [CMA-ES]({LINKS['cmaes']}), a search of the pixel mismatch "
            f"over theta, ends closer at {where}, by up to {worst['ratio']:.0f}x ({worst['search_mm']:.3f} against "
            f"{worst['sdm_mm']:.3f} mm at level {worst['noise_level']}){sdm}.")


def _instead(answer: dict) -> str:
    search, unit = answer["search"], answer["per_unit"]
    parts = []
    if search and search["verdict"] != "yes":
        seconds = search.get("seconds_per_run")
        parts.append(f"CMA-ES for one shift shared by every configuration"
                     + (f" ({seconds:.2f} s a run)" if seconds is not None else ""))
    if unit and unit["peer"]:
        if min(unit["peer_removed"]) > max(unit["removed"]):
            cmaes = str(unit["peer_method"]).startswith("cmaes")
            who = ("it" if parts else "CMA-ES") if cmaes else unit["peer"]
            peer, own = (_span([100 * v for v in unit[key]], 0, " %") for key in ("peer_removed", "removed"))
            parts.append(f"per car {who} still removes more error ({peer} against SDM's {own}) but takes "
                         f"{_span(unit['cpu_ratio'], 0)} SDM's CPU time")
        else:
            more = all(own > peer for own, peer in zip(unit["removed"], unit["peer_removed"]))
            parts.append(f"per car SDM, which removes {'more error than' if more else 'as much error as'} the "
                         f"{unit['peer']} at 1/{min(unit['cpu_ratio']):.0f} of its CPU time")
    return "**Use instead, and when?** " + ("; ".join(parts) if parts else "SDM itself") + "."


def _good_for(answer: dict) -> str:
    unit, network = answer["per_unit"], answer["network"]
    parts = []
    if unit:
        gated = f"[gated]({LINKS['gate']}) " if unit.get("gated") else ""
        parts.append(f"per car ({unit['screen'][0]} x {unit['screen'][1]} screen) {gated}SDM removes "
                     f"{_span([100 * v for v in unit['removed']], 0, ' %')} of [doing nothing]({LINKS['objects']})'s "
                     f"error")
    if network:
        against = (f"{_span(network['to_nothing'])} doing nothing's error" if network["to_nothing"] else
                   f"{_span(network['to_supervised'])} a labelled network's error")
        words = f"a label-free [SDM-trained network]({LINKS['network']}), {against}"
        if network.get("paired_levels"):  # paired by training seed: ahead or behind beyond the seeds' spread
            ahead, behind, noise_levels = (network[key] for key in ("ahead_of_silhouette", "behind_silhouette",
                                                              "paired_levels"))
            if ahead:
                words += f", beats silhouette training at {ahead} of {noise_levels} levels"
                words += f", loses at {behind}" if behind else ""
            elif behind:
                words += f", loses to silhouette training at {behind} of {noise_levels} levels"
            else:
                words += f", level with silhouette training at all {noise_levels} levels"
        parts.append(words)
    return "**Good for?** Many unknowns at once: " + "; ".join(parts) + "."


def _schedule_words(answer: dict) -> str:
    measured = " and ".join(item["words"] for item in answer["data"])
    runs = sorted({item["runs"] for item in answer["data"] if item["runs"]})
    worst, factor = answer["worst"], answer["factor"]
    if worst is None:
        against = f"meeting half the paper's mean at {answer['meets_bar']} of {answer['judged']} levels"
    elif not answer["beyond"]:
        against = f"within {worst['high']:.2f}x of CMA-ES's mean at every level"
    else:
        missed = " and ".join(f"{item['kind']} {_levels(item['levels'])}" for item in answer["beyond"])
        against = f"within {factor:g}x of CMA-ES's mean but at {missed} ({worst['high']:.2f}x at worst)"
    return (f"**Which schedule?** [`{answer['name']}`]({LINKS['schedule']}), {against}, measured on {measured}"
            + (f", {'/'.join(str(run) for run in runs)} runs per level" if runs else "") + ".")


WORDS = {"reproduction": _reproduction, "search": _search, "instead": _instead, "good_for": _good_for,
         "schedule": _schedule_words}


def render(data: dict) -> str:
    """The verdict's Markdown: the caption, the table, one line per answer (its sources at its end), the figure."""
    table, sources = data["table"], data["sources"]
    schedule = f"SDM with the [recommended schedule]({LINKS['schedule']})" if table["schedule"] else None
    header = ["noise level (px)", "the paper's SDM", "our SDM", "[CMA-ES]" + f"({LINKS['cmaes']})"]
    header += [schedule] if schedule else []
    about = table["data"]
    on = (f"the default run's synthetic annotations: {about.get('images')} images generated in ApolloCar3D's layout"
          if about.get("source") == "synthetic" else f"{about.get('images')} real frames of {about.get('folder')}")
    lines = [
        f"Mean distance to the true shift theta* = (a, b), in mm, per noise level (pixels of noise on the target "
        f"masks), on {on} ([{LINKS['data']}]({LINKS['data']})).",
        "The paper's problem is one shift shared by every configuration (the cars of one image); our SDM uses the "
        "paper's rule, CMA-ES is a black-box search.",
        f"Each answer names its snapshot and commit; [stale]({LINKS['stale']}) marks one made by older code."
        + _source_tag(table["sources"], sources),
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---:|" * len(header),
    ]
    for row in table["rows"]:
        cells = [str(row["noise_level"]), _mm(row["paper_mm"]), _mm(row["sdm_mm"]), _mm(row["search_mm"])]
        cells += [_mm(row["schedule_mm"])] if schedule else []
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    for answer in data["answers"]:
        lines.append("- " + WORDS[answer["key"]](answer) + _source_tag(answer["sources"], sources))
    lines += ["", f"![Each rule's mean distance per noise level, with CMA-ES and the floor]({LINKS['figure']})"]
    return "\n".join(lines) + "\n"
