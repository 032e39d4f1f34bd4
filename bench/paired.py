"""Benchmark: a candidate row against today's, paired by case and seed, from a workflow run's
``results/table.csv``: what a rule in docs/decisions.md reads. Run the candidate as a tagged entry
beside the untagged one (``{name: diff, views: 1, tag: prior, settings: {decide_prior: 0.03}}``
next to ``{name: diff, views: 1}``) on the dev cases and seeds the rule names, then

    .venv/bin/python bench/paired.py results/table.csv [--pair BASE CANDIDATE ...] [--metric shape_iou]
        [--out results/bench/paired.json]

Every tagged row is compared with its untagged twin (the same method, view count and masks) unless
``--pair`` names the rows. Per pair: the paired change's mean and standard error, each class and
family's means (the mean over its cases of their seed means) before and after, each case's mean
change and the worst, and how many pairs moved. The metric is each row's headline (the shape IoU
where the camera is withheld, else the 64-view world IoU) unless ``--metric`` says. Runs missing
on either side are left out and counted. Tune on dev cases only; on test cases this reports.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd


def twins(rows: list[str]) -> list[tuple[str, str]]:
    """(untagged row, tagged row) for every tagged row whose twin (the same method, view count
    and mask degradation, no tag) ran (``ipm.table.untagged``)."""
    from ipm.table import untagged

    present = set(rows)
    pairs = [(untagged(row), row) for row in rows]
    return [(base, row) for base, row in pairs if base in present]


def compare(table: pd.DataFrame, base: str, cand: str, metric: str | None = None) -> dict:
    """The paired comparison of row ``cand`` against row ``base`` on ``metric`` (default: the
    rows' headline, ``ipm.table.scored_by``); ``ValueError`` where the rows share no case and seed."""
    from ipm.table import CLASS_NAMES, scored_by

    metric = scored_by(base) if metric is None else metric
    cols = ["case", "seed", "generator", "family", metric]
    a = table.loc[table["row"] == base, cols].dropna(subset=[metric])
    b = table.loc[table["row"] == cand, ["case", "seed", metric]].dropna(subset=[metric])
    pairs = a.merge(b, on=["case", "seed"], suffixes=("_base", "_cand"))
    if pairs.empty:
        raise ValueError(f"rows {base} and {cand} share no case and seed with {metric}")
    diff = pairs[f"{metric}_cand"] - pairs[f"{metric}_base"]
    pairs = pairs.assign(change=diff)
    cases = pairs.groupby("case", sort=False).agg(generator=("generator", "first"), family=("family", "first"),
                                                  base=(f"{metric}_base", "mean"), cand=(f"{metric}_cand", "mean"),
                                                  change=("change", "mean"), seeds=("seed", "size"))
    groups = {}
    for (gen, fam), part in cases.groupby(["generator", "family"], sort=False):
        groups[f"{CLASS_NAMES.get(gen, gen)} {fam}"] = {"cases": len(part), "base": round(float(part["base"].mean()), 4),
                                                 "cand": round(float(part["cand"].mean()), 4)}
    worst = cases["change"].idxmin()
    n = len(diff)
    return {
        "base": base, "candidate": cand, "metric": metric, "pairs": n,
        "left_out": int(len(a) + len(b) - 2 * n),
        "paired": round(float(diff.mean()), 4),
        "se": round(float(diff.std(ddof=1) / np.sqrt(n)), 4) if n > 1 else None,
        "moved": int((diff.abs() > 5e-4).sum()),
        "groups": groups,
        "worst_case": {"case": worst, "change": round(float(cases.loc[worst, "change"]), 4)},
        "cases": {c: {"base": round(float(r["base"]), 4), "cand": round(float(r["cand"]), 4),
                      "change": round(float(r["change"]), 4)} for c, r in cases.iterrows()},
    }


def report(result: dict) -> str:
    """A few lines a person reads against a rule's clauses."""
    se = "" if result["se"] is None else f" (SE {result['se']:.4f})"
    lines = [f"{result['candidate']} against {result['base']} on {result['metric']}: paired "
             f"{result['paired']:+.4f}{se} over {result['pairs']} pairs, {result['moved']} moved"
             + (f", {result['left_out']} runs without a twin left out" if result["left_out"] else "")]
    lines += [f"  {name}: {g['base']:.4f} -> {g['cand']:.4f} ({g['cand'] - g['base']:+.4f}, {g['cases']} cases)"
              for name, g in result["groups"].items()]
    lines.append(f"  worst case: {result['worst_case']['case']} {result['worst_case']['change']:+.4f}")
    lines += [f"    {c}: {r['base']:.4f} -> {r['cand']:.4f} ({r['change']:+.4f})" for c, r in result["cases"].items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("table", help="a workflow run's results/table.csv")
    ap.add_argument("--pair", nargs=2, action="append", metavar=("BASE", "CANDIDATE"), default=None,
                    help="rows to compare (default: every tagged row against its untagged twin)")
    ap.add_argument("--metric", default=None, help="a column of table.csv (default: each row's headline)")
    ap.add_argument("--out", default=None, help="write the comparisons as JSON here too")
    args = ap.parse_args(argv)
    path = Path(args.table)
    if not path.is_file():
        print(f"paired: no such table: {path}", file=sys.stderr)
        return 2
    table = pd.read_csv(path)
    if args.metric is not None and args.metric not in table.columns:
        print(f"paired: {path} has no column {args.metric!r}", file=sys.stderr)
        return 2
    pairs = [tuple(p) for p in args.pair] if args.pair else twins(list(table["row"].drop_duplicates()))
    unknown = sorted({r for p in pairs for r in p} - set(table["row"]))
    if unknown or not pairs:
        print(f"paired: {'no rows ' + ', '.join(unknown) if unknown else 'no tagged row with its twin'} in {path}",
              file=sys.stderr)
        return 2
    try:
        results = [compare(table, base, cand, args.metric) for base, cand in pairs]
    except ValueError as err:
        print(f"paired: {err} in {path}", file=sys.stderr)
        return 2
    print("\n\n".join(report(r) for r in results))
    if args.out:
        from ipm.io.atomic import atomic_path

        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(args.out) as tmp:
            tmp.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
