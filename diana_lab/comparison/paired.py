"""Each group against a baseline group, paired by training seed (``python -m diana_lab.compare baseline=...``).

Why paired: two configs trained on the same seeds share the seed's luck (its episodes, its initial weights), so the
per-seed difference varies far less than either group does, and a change too small for the groups' means and
standard deviations to tell apart can be measured on a handful of seeds. For each metric this gives the mean of the
per-seed differences (group minus baseline) over the seeds both groups ran, its sample standard deviation, the
95 % confidence interval and the paired t statistic with its two-sided p-value (Student's t with ``pairs - 1``
degrees of freedom; NaN below two pairs).

Why the host column: a seed reproduces bit for bit on one kind of CPU only, and on another it moves a policy's
figures as much as another seed does (``diana_lab.tracking.host``), so a pair whose two runs trained on different
kinds of CPU measures the hosts as well as the change. ``hosts`` says ``same``, ``mixed (k of n pairs)``, or
``unknown`` where a run has no ``host_cpu`` tag (runs logged before the tag).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import pandas as pd
from scipy import stats

from diana_lab.comparison.groups import in_seed_order
from diana_lab.comparison.runs import ComparisonError
from diana_lab.tracking.host import HOST_TAG

__all__ = ["COLUMNS", "empty", "mixed_host_groups", "paired_differences", "resolve_baseline"]

COLUMNS = (
    "group",
    "metric",
    "pairs",
    "seeds",
    "baseline_mean",
    "group_mean",
    "diff_mean",
    "diff_std",
    "ci95_low",
    "ci95_high",
    "t",
    "p_two_sided",
    "hosts",
)


def resolve_baseline(table: pd.DataFrame, baseline: str) -> str:
    """The group ``baseline`` names in ``table`` (:func:`~diana_lab.comparison.groups.runs_table`'s frame): its
    exact label; else the group of the run whose id starts with it (8 characters at least, as ``runs.md`` shows
    them); else the one label that contains it. Anything else (no group, several) is a :class:`ComparisonError`
    listing the labels, so a typo is never a silent choice."""
    labels = [str(g) for g in dict.fromkeys(table["group"])]
    if baseline in labels:
        return baseline
    if len(baseline) >= 8:
        owners = set(table.loc[table["run_id"].astype(str).str.startswith(baseline), "group"])
        if len(owners) == 1:
            return str(owners.pop())
    hits = [g for g in labels if baseline in g]
    if len(hits) == 1:
        return hits[0]
    listed = "\n".join(f"  {g}" for g in labels)
    why = f"is part of {len(hits)} group labels" if hits else "is no group's label, part of one or a run's id"
    raise ComparisonError(
        f"baseline={baseline!r} {why}; expected the label of a group, a part of exactly one, or the id (8 "
        f"characters or more) of one of its runs:\n{listed}"
    )


def _per_seed(block: pd.DataFrame, metric: str) -> pd.DataFrame:
    """One row per seed with a finite value: the value (the mean of runs repeating a seed) and its hosts."""
    rows = block[block["seed"].astype(str) != ""].dropna(subset=[metric])
    host = rows[HOST_TAG] if HOST_TAG in rows else pd.Series("", index=rows.index)
    rows = rows.assign(seed=rows["seed"].astype(str), **{HOST_TAG: host.fillna("").astype(str)})
    return rows.groupby("seed").agg(value=(metric, "mean"), hosts=(HOST_TAG, frozenset))


def _hosts(a: pd.Series, b: pd.Series) -> str:
    """``same`` when each pair's runs trained on one named kind of CPU; ``mixed (k of n pairs)``; ``unknown``."""
    mixed = sum(1 for x, y in zip(a, b, strict=True) if len((x | y) - {""}) > 1)
    if mixed:
        return f"mixed ({mixed} of {len(a)} pairs)"
    if any("" in x | y for x, y in zip(a, b, strict=True)):
        return "unknown"
    return "same"


def paired_differences(table: pd.DataFrame, baseline: str, metrics: Sequence[str]) -> pd.DataFrame:
    """Every other group of ``table`` (:func:`~diana_lab.comparison.groups.runs_table`'s frame, with a
    ``host_cpu`` column where known) against the group ``baseline``, one row per group and metric (columns
    :data:`COLUMNS`). A group sharing no seed with the baseline gets rows with ``pairs`` 0."""
    base = table[table["group"] == baseline]
    if base.empty:
        raise ComparisonError(f"baseline={baseline!r}: no run in that group")
    rows: list[dict[str, object]] = []
    for name, block in table[table["group"] != baseline].groupby("group", sort=False):
        for metric in metrics:
            if metric not in table:
                continue
            a, b = _per_seed(base, metric), _per_seed(block, metric)
            seeds = in_seed_order(set(a.index) & set(b.index))
            d = b.loc[seeds, "value"].to_numpy(float) - a.loc[seeds, "value"].to_numpy(float)
            n = len(d)
            mean = float(d.mean()) if n else math.nan
            std = float(d.std(ddof=1)) if n > 1 else math.nan
            t = p = low = high = math.nan
            if n > 1:
                half = float(stats.t.ppf(0.975, n - 1)) * std / math.sqrt(n)
                low, high = mean - half, mean + half
                if std > 0:
                    t = mean / (std / math.sqrt(n))
                    p = float(2 * stats.t.sf(abs(t), n - 1))
            rows.append(
                {
                    "group": name,
                    "metric": metric,
                    "pairs": n,
                    "seeds": ",".join(seeds),
                    "baseline_mean": float(a.loc[seeds, "value"].mean()) if n else math.nan,
                    "group_mean": float(b.loc[seeds, "value"].mean()) if n else math.nan,
                    "diff_mean": mean,
                    "diff_std": std,
                    "ci95_low": low,
                    "ci95_high": high,
                    "t": t,
                    "p_two_sided": p,
                    "hosts": _hosts(a.loc[seeds, "hosts"], b.loc[seeds, "hosts"]) if n else "",
                }
            )
    return pd.DataFrame(rows, columns=list(COLUMNS))


def mixed_host_groups(table: pd.DataFrame) -> dict[str, list[str]]:
    """Groups whose runs trained on more than one named kind of CPU, with those kinds: their spread over seeds
    includes the hosts' difference."""
    if HOST_TAG not in table:
        return {}
    out: dict[str, list[str]] = {}
    for name, block in table.groupby("group", sort=False):
        kinds = sorted({h for h in block[HOST_TAG].fillna("").astype(str) if h})
        if len(kinds) > 1:
            out[str(name)] = kinds
    return out


def empty() -> pd.DataFrame:
    """The table of a comparison without a baseline."""
    return pd.DataFrame(columns=list(COLUMNS))
