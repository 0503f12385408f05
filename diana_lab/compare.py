"""``python -m diana_lab.compare [filter=...] [metrics=[...]] [experiments=[...]] output=<dir>``

Compares tracked runs: selects them with an MLflow filter, groups runs that differ only in their seed, and
writes ``runs.csv``/``runs.md`` (one row per run: chosen options, seed, metrics), ``groups.csv``/``groups.md``
(mean ± std over seeds), ``curves_<metric>.png`` (learning curves) and ``final_metrics.png``; with ``baseline``,
``paired.csv``/``paired.md`` (each other group against it, seed by seed: mean difference, 95 % interval, paired t)::

    python -m diana_lab.compare output=cmp
    python -m diana_lab.compare "filter=\\"tags.algo = 'sac' and metrics.eval_spl > 0.8\\"" output=cmp
    python -m diana_lab.compare 'group_by=[algo,reward]' 'metrics=[eval_spl,eval_tipover_rate]' output=cmp
    python -m diana_lab.compare tracking.uri=sqlite:///runs/mlflow.db 'experiments=[diana_lab,sweep]'
    python -m diana_lab.compare baseline=8e955d66 output=cmp   # + paired.csv/.md: against the group of that run
    python -m diana_lab.compare "baseline='lr=0.0003'" output=cmp   # or a part of its label (quoted for Hydra)

No run matching (or a store, experiment or filter that does not exist), a ``group_by`` tag no selected run
carries, a ``baseline`` that names no group or several, or ``variants``/``include_evaluations`` other than
true/false print one paragraph naming the key and exit with status 2. The metric names are in ``docs/metrics.md``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from omegaconf import DictConfig

from diana_lab.cli import hydra_app
from diana_lab.core.validation import boolean

__all__ = ["main"]

FLAGS = ("variants", "include_evaluations")


@hydra_app(config_name="compare")
def main(cfg: DictConfig) -> None:
    from diana_lab.comparison import compare_runs, write_report
    from diana_lab.comparison.report import groups_markdown, paired_markdown

    for key in FLAGS:  # bool("no") is True: a word that is not true/false must not switch an option on
        boolean(key, cfg[key])
    experiments = [str(e) for e in cfg.experiments] or [str(cfg.tracking.experiment)]
    c = compare_runs(
        str(cfg.tracking.uri),
        experiments,
        str(cfg.filter or ""),
        metrics=[str(m) for m in cfg.metrics],
        curves=[str(m) for m in cfg.curves],
        group_by=[str(g) for g in cfg.group_by],
        variants=cfg.variants,
        include_evaluations=cfg.include_evaluations,
        baseline="" if cfg.baseline is None else str(cfg.baseline),
    )
    for metric, close in c.missing_metrics.items():
        hint = f" (did you mean {', '.join(close)}?)" if close else ""
        print(f"warning: no selected run logged {metric}{hint}", file=sys.stderr)
    if c.skipped:
        print(
            f"note: left out {len(c.skipped)} run(s) without any of the metrics: {', '.join(c.skipped)}",
            file=sys.stderr,
        )
    for group, seeds in c.repeated_seeds.items():
        print(
            f"warning: group {group!r} has runs sharing seed(s) {', '.join(seeds)} ('?': no seed tag); their std "
            "is not a spread over seeds (keep one run per seed with filter=...)",
            file=sys.stderr,
        )
    for group, runs in c.unfinished.items():
        print(
            f"warning: group {group!r} counts {len(runs)} run(s) that did not finish: {', '.join(runs)}; their "
            "metrics are what they logged before they stopped (leave them out with "
            "filter=\"attributes.status = 'FINISHED'\")",
            file=sys.stderr,
        )
    for group, kinds in c.mixed_hosts.items():
        print(
            f"warning: group {group!r} has runs trained on {len(kinds)} kinds of CPU ({'; '.join(kinds)}); a seed's "
            "figures differ across kinds of CPU, so its spread includes the hosts' difference (group_by=[...,"
            "host_cpu] splits it)",
            file=sys.stderr,
        )
    mixed = c.paired[c.paired["hosts"].astype(str).str.startswith("mixed")]
    for group in dict.fromkeys(mixed["group"]):
        print(
            f"warning: group {group!r} is paired with the baseline on runs trained on different kinds of CPU: "
            "those differences measure the hosts as well as the change",
            file=sys.stderr,
        )
    files = write_report(c, Path(str(cfg.output)))
    where = f"{', '.join(experiments)}" + (f", filter {cfg.filter!r}" if cfg.filter else "")
    print(f"{len(c.runs)} runs in {len(c.groups)} groups ({where}):\n")
    print(groups_markdown(c))
    if c.baseline:
        print(f"\nagainst {c.baseline!r}, paired by seed:\n")
        print(paired_markdown(c))
    print("\nwrote " + ", ".join(str(p) for p in files))


if __name__ == "__main__":
    main()
