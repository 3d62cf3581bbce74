"""How far a team's labels agree, and how far each person is from known returns (no ROS).

Input: label records (`label_files`), the latest per labeller and episode. An episode is
(source, task, episode). **Gold** labels are those of a labeller whose id starts with `gold/` or
`oracle/` (known returns: the page's gold episodes, an oracle labeller's labels in a recording);
every other labeller is a person. Figures:

- per labeller: labels given, and on gold episodes their mean absolute error and the largest one;
- agreement: episodes labelled by two or more people, the mean absolute difference over every
  pair of their labels on the same episode, and per pair of people the same with its Pearson
  correlation (from 3 shared episodes on).

Comparisons (`comparison_report`): per labeller the comparisons given and, on pairs a gold
labeller also compared, how often they answered as gold did; agreement: pairs compared by two or
more people and the fraction of those people's answers that are the same (per pair of people too).
"""

from __future__ import annotations

from collections import defaultdict
from itertools import combinations

import numpy as np

GOLD_PREFIXES = ("gold/", "oracle/")


def is_gold(labeller: str) -> bool:
    return labeller.startswith(GOLD_PREFIXES)


def label_report(records: list[dict]) -> dict:
    """{"labellers": {id: {"labels", "gold_n", "gold_mae", "gold_max"}}, "agreement": {"episodes",
    "pairs_of_labels", "mean_abs_diff", "people": [{"a", "b", "episodes", "mean_abs_diff",
    "correlation"}]}} of the latest label per labeller and episode."""
    from .label_files import latest

    by_episode: dict = defaultdict(dict)  # episode key -> labeller -> value
    counts: dict = defaultdict(int)
    for r in latest(records):
        by_episode[(r["source"], r["task"], r["episode"])][r["labeller"]] = r["return"]
        counts[r["labeller"]] += 1
    gold_err: dict = defaultdict(list)
    pair_values: dict = defaultdict(list)  # (a, b) -> [(value a, value b)]
    diffs, shared = [], 0
    for labels in by_episode.values():
        gold = [v for lab, v in labels.items() if is_gold(lab)]
        people = sorted(lab for lab in labels if not is_gold(lab))
        if gold:
            for lab in people:
                gold_err[lab].append(abs(labels[lab] - gold[-1]))
        if len(people) >= 2:
            shared += 1
            for a, b in combinations(people, 2):
                pair_values[(a, b)].append((labels[a], labels[b]))
                diffs.append(abs(labels[a] - labels[b]))
    labellers = {}
    for lab in sorted(counts):
        errs = gold_err.get(lab, [])
        labellers[lab] = {"labels": counts[lab], "gold_n": len(errs),
                          "gold_mae": float(np.mean(errs)) if errs else None,
                          "gold_max": float(np.max(errs)) if errs else None}
    pairs = []
    for (a, b), values in sorted(pair_values.items()):
        x, y = np.array(values).T
        corr = None
        if len(values) >= 3 and x.std() > 0 and y.std() > 0:
            corr = float(np.corrcoef(x, y)[0, 1])
        pairs.append({"a": a, "b": b, "episodes": len(values),
                      "mean_abs_diff": float(np.mean(np.abs(x - y))), "correlation": corr})
    return {"labellers": labellers,
            "agreement": {"episodes": shared, "pairs_of_labels": len(diffs),
                          "mean_abs_diff": float(np.mean(diffs)) if diffs else None, "people": pairs}}


def format_report(report: dict) -> list[str]:
    """The report as lines of text (for `nmrm labels report`)."""
    lines = [f"{'labeller':28s} {'labels':>7s}  gold episodes, mean abs error [largest]"]
    for lab, r in report["labellers"].items():
        gold = ("(gold)" if is_gold(lab) else
                "-" if not r["gold_n"] else f"{r['gold_n']}, {r['gold_mae']:.3g} [{r['gold_max']:.3g}]")
        lines.append(f"{lab:28s} {r['labels']:7d}  {gold}")
    a = report["agreement"]
    if not a["episodes"]:
        lines.append("agreement: no episode labelled by two or more people")
    else:
        lines.append(f"agreement: {a['episodes']} episode(s) labelled by two or more people; mean abs "
                     f"difference {a['mean_abs_diff']:.3g} over {a['pairs_of_labels']} pair(s) of labels")
        for p in a["people"]:
            corr = "" if p["correlation"] is None else f", correlation {p['correlation']:.3f}"
            lines.append(f"  {p['a']} vs {p['b']}: {p['episodes']} episode(s), mean abs difference "
                         f"{p['mean_abs_diff']:.3g}{corr}")
    return lines


def _oriented(r: dict) -> float:
    """A comparison's answer as P(min episode better)."""
    return r["p"] if r["a"] < r["b"] else 1.0 - r["p"]


def comparison_report(records: list[dict]) -> dict:
    """{"labellers": {id: {"comparisons", "gold_n", "gold_agree"}}, "agreement": {"pairs",
    "same", "people": [{"a", "b", "pairs", "same"}]}} of the latest answer per labeller and pair."""
    from .label_files import latest_comparisons

    by_pair: dict = defaultdict(dict)
    counts: dict = defaultdict(int)
    for r in latest_comparisons(records):
        by_pair[(r["source"], r["task"], min(r["a"], r["b"]), max(r["a"], r["b"]))][r["labeller"]] = _oriented(r)
        counts[r["labeller"]] += 1
    gold_hits: dict = defaultdict(list)
    pair_same: dict = defaultdict(list)
    same, shared = [], 0
    for answers in by_pair.values():
        gold = [v for lab, v in answers.items() if is_gold(lab)]
        people = sorted(lab for lab in answers if not is_gold(lab))
        if gold:
            for lab in people:
                gold_hits[lab].append(answers[lab] == gold[-1])
        if len(people) >= 2:
            shared += 1
            for a, b in combinations(people, 2):
                pair_same[(a, b)].append(answers[a] == answers[b])
                same.append(answers[a] == answers[b])
    labellers = {lab: {"comparisons": counts[lab], "gold_n": len(gold_hits.get(lab, [])),
                       "gold_agree": float(np.mean(gold_hits[lab])) if gold_hits.get(lab) else None}
                 for lab in sorted(counts)}
    people = [{"a": a, "b": b, "pairs": len(v), "same": float(np.mean(v))} for (a, b), v in sorted(pair_same.items())]
    return {"labellers": labellers, "agreement": {"pairs": shared, "same": float(np.mean(same)) if same else None,
                                                  "people": people}}


def format_comparison_report(report: dict) -> list[str]:
    """The comparison report as lines of text (for `nmrm labels report`)."""
    lines = [f"{'labeller':28s} {'compared':>8s}  pairs also compared by gold, answered as gold"]
    for lab, r in report["labellers"].items():
        gold = ("(gold)" if is_gold(lab) else "-" if not r["gold_n"] else f"{r['gold_n']}, {r['gold_agree']:.0%}")
        lines.append(f"{lab:28s} {r['comparisons']:8d}  {gold}")
    a = report["agreement"]
    if not a["pairs"]:
        lines.append("agreement: no pair compared by two or more people")
    else:
        lines.append(f"agreement: {a['pairs']} pair(s) compared by two or more people; {a['same']:.0%} of "
                     f"their answers the same")
        for p in a["people"]:
            lines.append(f"  {p['a']} vs {p['b']}: {p['pairs']} pair(s), {p['same']:.0%} the same")
    return lines
