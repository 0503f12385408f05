"""The benchmark's outputs: the printed table (pandas) and the JSON document (schema in benchmarks/README.md)."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

__all__ = ["SCHEMA_VERSION", "figures_table", "markdown_table", "write_json"]

SCHEMA_VERSION = 1
COLUMNS = ["figure", "value", "unit", "p10", "p90", "n", "target", "met"]


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "NO"
    if isinstance(v, float):
        if not math.isfinite(v):
            return "-"
        return f"{v:.4g}" if abs(v) < 1e5 else f"{v:.0f}"
    return str(v)


def _rows(figures: Mapping[str, Mapping[str, Any]]) -> list[dict[str, str]]:
    rows = []
    for key, f in figures.items():
        t = f.get("target")
        rows.append(
            {
                "figure": key,
                "value": _fmt(f.get("value")) if f.get("error") is None else "ERROR",
                "unit": f.get("unit", ""),
                "p10": _fmt(f.get("p10")),
                "p90": _fmt(f.get("p90")),
                "n": _fmt(f.get("n")),
                "target": f"{t['op']} {t['value']:g}" if t else "",
                "met": _fmt(f.get("met")) if t else "",
            }
        )
    return rows


def figures_table(figures: Mapping[str, Mapping[str, Any]]) -> str:
    """A plain-text table of the figures (pandas), one row per key."""
    import pandas as pd

    frame = pd.DataFrame(_rows(figures), columns=COLUMNS)
    return frame.to_string(index=False)


def markdown_table(result: Mapping[str, Any], keys: Iterable[str] | None = None) -> str:
    """The figures of a result document as a Markdown table (what benchmarks/README.md shows)."""
    import pandas as pd

    figures = result["figures"]
    if keys is not None:
        figures = {k: figures[k] for k in keys if k in figures}
    return pd.DataFrame(_rows(figures), columns=COLUMNS).to_markdown(index=False)


def write_json(result: Mapping[str, Any], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2) + "\n")
