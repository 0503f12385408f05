"""``python -m diana_lab.scorecard policy=<run id | model .zip | ...> [eval.seed=...] [output=card.json]``

Evaluates the policy under test and the baselines beside it on every condition of ``conf/scorecard.yaml`` (the
Mars yard, physics, sensor noise, unseen craters: issue 51's suites) and checks the policy's figures against
the targets there (:mod:`diana_lab.evaluation.scorecard`)::

    python -m diana_lab.scorecard policy=<run id> eval.seed=1002                      # a validation suite
    python -m diana_lab.scorecard policy=<run id> 'only.conditions=[yard,noise]' eval.episodes=20
    python -m diana_lab.scorecard policy=<run id> 'only.entries=[network,bearing + veto]' output=card.json

Every command-line override applies to every evaluation (repeat those the policy was trained with, as for
``python -m diana_lab.evaluate``); a condition's or an entry's own overrides of the same key win. Each
evaluation writes its files to ``<run dir>/<condition>/<entry>/``. One that fails (a baseline that cannot run
there) is recorded in the card with its error and the rest go on; the command then exits with status 2.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from diana_lab.cli import USER_ERRORS, UserError, hydra_app, output_file

__all__ = ["main", "merge_overrides", "run"]

OWN_KEYS = ("conditions", "entries", "comparisons", "only", "output")  # the card's keys, not the evaluations'
# the suite: the command line's (or the card's defaults), for every entry, unless a condition or entry sets it
# itself; a preset an entry adds (+experiment=reference sets eval.episodes: 50) would otherwise change it
SUITE_KEYS = ("eval.episodes", "eval.seed", "eval.min_distance", "eval.max_distance", "eval.deterministic")


def _key(override: str) -> str:
    return override.lstrip("+~").split("=", 1)[0].split("@", 1)[0]


def merge_overrides(base: list[str], *layers: tuple[str, ...]) -> list[str]:
    """``base`` then each layer; an override of a key a later layer sets (or of a key inside it:
    ``policy.source`` under ``policy=bearing``) is dropped, so that the later one wins."""
    out = list(base)
    for layer in layers:
        keys = {_key(o) for o in layer}
        out = [o for o in out if not any(_key(o) == k or _key(o).startswith(k + ".") for k in keys)]
        out += list(layer)
    return out


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("_") or "entry"


def _fmt(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{value:.2f}"


def _card_table(conditions: list[Any], entries: list[Any], cells: dict[str, dict[str, Any]]) -> str:
    """Entries x conditions: success / SPL, then tip-over and collision rates, or the cell's error."""
    import pandas as pd

    rows = {}
    for entry in entries:
        row = {}
        for cond in conditions:
            s = cells[entry.name][cond.name]
            if "error" in s:
                row[cond.name] = f"error: {s['error'][:40]}"
            else:
                rates = f"tip {s['tipover_rate']:.2f} col {s['collision_rate']:.2f}"
                row[cond.name] = f"{s['success_rate']:.2f} / {s['spl']:.2f}  {rates}"
        rows[entry.name] = row
    return pd.DataFrame.from_dict(rows, orient="index").to_string()


def run(cfg: DictConfig, out_dir: Path, overrides: list[str]) -> dict[str, Any]:
    """The card behind the command (testable without Hydra): every entry on every condition, then the targets
    and comparisons; returns what ``output`` receives. ``overrides``: the command line's."""
    from diana_lab import evaluate
    from diana_lab.config import SCHEMAS, compose, validate
    from diana_lab.evaluation.metrics import to_json
    from diana_lab.evaluation.scorecard import check, compare, parse_card

    own = OmegaConf.to_container(cfg, resolve=True)
    only = own.get("only") or {}
    conditions, entries, comparisons = parse_card(
        own.get("conditions"), own.get("entries"), own.get("comparisons"), only.get("conditions"), only.get("entries")
    )
    output = output_file(cfg.output) if cfg.get("output") else None
    base = [o for o in overrides if _key(o).split(".", 1)[0] not in OWN_KEYS]
    if cfg.get("policy") is None and any(not any(_key(o) == "policy" for o in e.overrides) for e in entries):
        names = [e.name for e in entries if not any(_key(o) == "policy" for o in e.overrides)]
        raise UserError(f"policy: expected the policy under test (entries {names} run it), e.g. policy=<run id>")
    # compose every cell first: a bad override fails before any evaluation runs
    plans = []
    for cond in conditions:
        for entry in entries:
            own_suite = {_key(o) for o in (*cond.overrides, *entry.overrides)}
            suite = tuple(f"{k}={OmegaConf.select(cfg, k)}" for k in SUITE_KEYS if k not in own_suite)
            cell = merge_overrides(base, cond.overrides, entry.overrides, suite)
            try:
                cell_cfg = compose(cell, config_name="evaluate")
                validate(cell_cfg, [g for g in cell_cfg if g in SCHEMAS])  # every group's checks, as the CLI's
            except Exception as exc:  # Hydra's composition errors and the groups' own: name the cell at fault
                raise UserError(
                    f"conditions.{cond.name} x entries.{entry.name}: {str(exc).splitlines()[0]} (overrides: {cell})"
                ) from exc
            plans.append((cond, entry, cell, cell_cfg))
    cells: dict[str, dict[str, Any]] = {e.name: {} for e in entries}
    for i, (cond, entry, cell, cell_cfg) in enumerate(plans):
        print(f"\n[{i + 1}/{len(plans)}] {entry.name} on {cond.name}", flush=True)
        where = out_dir / cond.name / _slug(entry.name)
        where.mkdir(parents=True, exist_ok=True)
        try:
            cells[entry.name][cond.name] = evaluate.run(cell_cfg, where, evaluate.chosen_dynamics(cell_cfg, cell), cell)
        except (*USER_ERRORS, UserError) as exc:  # recorded; the other cells go on
            print(f"{entry.name} on {cond.name} failed: {exc}")
            cells[entry.name][cond.name] = {"error": str(exc)}
    failed = [(e, c) for e in cells for c in cells[e] if "error" in cells[e][c]]
    ok = {e: {c: s for c, s in by.items() if "error" not in s} for e, by in cells.items()}
    targets = check(conditions, entries, ok)
    usable = [c for c in conditions if all(c.name in ok[x] for comp in comparisons for x in (comp.entry, comp.over))]
    versus = compare(usable, comparisons, ok)
    payload = {
        "conditions": {
            c.name: {"overrides": list(c.overrides), "targets": [t.text for t in c.targets]} for c in conditions
        },
        "entries": {e.name: {"overrides": list(e.overrides), "scored": e.scored} for e in entries},
        "summaries": cells,
        "targets": targets,
        "comparisons": versus,
        "overrides": base,
    }
    text = to_json(payload)  # strict JSON: a bound with no reference figure (NaN) is null
    (out_dir / "card.json").write_text(text)
    if output is not None:
        output.write_text(text)
    print("\nscorecard (success / SPL, tip-over, collisions):\n" + _card_table(conditions, entries, cells))
    for row in targets:
        mark = "met" if row["met"] else "NOT met"
        print(
            f"  {row['entry']} on {row['condition']}: {row['key']} {_fmt(row['value'])} "
            f"(target {row['target']}, bound {_fmt(row['bound'])}): {mark}"
        )
    for row in versus:
        verdict = "clearly better" if row["clearly"] else "not clearly better"
        print(
            f"  {row['entry']} over {row['over']} on {row['condition']}: {row['key']} {_fmt(row['value'])} "
            f"against {_fmt(row['other'])}: {verdict} (95 % intervals)"
        )
    met = sum(r["met"] for r in targets)
    print(f"targets met: {met} of {len(targets)}; card in {out_dir / 'card.json'}")
    if failed:
        listed = ", ".join(f"{e} on {c}" for e, c in failed)
        raise UserError(f"{len(failed)} evaluation(s) failed ({listed}); the rest are in {out_dir / 'card.json'}")
    return payload


@hydra_app(config_name="scorecard")
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    from diana_lab.cli import task_overrides

    run(cfg, Path(HydraConfig.get().runtime.output_dir), task_overrides())


if __name__ == "__main__":
    main()
