"""Comparison plots: learning curves (mean over seeds with a +-1 std band) and final metrics per group.

Drawn on ``Figure`` objects with the Agg canvas, like :mod:`diana_lab.evaluation.plots`, so neither the CLI
nor a test switches matplotlib's global backend or needs a display; a notebook shows a returned figure
inline, or passes its own ``ax``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

__all__ = ["is_fraction", "plot_final_metrics", "plot_learning_curves", "save_figure"]


def is_fraction(metric: str) -> bool:
    """Rates, fractions and SPL live in [0, 1]: their axes are pinned there so groups compare at a glance."""
    return metric.endswith(("_rate", "_frac", "spl")) or "outcome_" in metric


def save_figure(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=110)
    return path


def _axes(ax: Axes | None, size: tuple[float, float]) -> tuple[Figure, Axes]:
    if ax is not None:
        return ax.figure, ax  # type: ignore[return-value]
    fig = Figure(figsize=size, layout="constrained")
    return fig, fig.add_subplot()


OUTSIDE_LEGEND_FROM = 5  # groups: from this many the legend goes beside the axes, where it covers no data


def _legend(ax: Axes, groups: int) -> None:
    if groups >= OUTSIDE_LEGEND_FROM:
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    else:
        ax.legend(fontsize=8, loc="best")


def plot_learning_curves(curves: pd.DataFrame, metric: str, ax: Axes | None = None) -> Figure:
    """One line per group of :func:`~diana_lab.comparison.groups.learning_curves` for ``metric``: the mean
    over its runs, a band of +-1 standard deviation where two or more runs were evaluated."""
    fig, ax = _axes(ax, (7.0, 4.2))
    data = curves[curves["metric"] == metric]
    for group, block in data.groupby("group", sort=False):
        block = block.sort_values("step")
        runs = int(block["n"].max())
        (line,) = ax.plot(block["step"], block["mean"], marker="o", ms=3, lw=1.6, label=f"{group} (n={runs})")
        lo, hi = block["mean"] - block["std"], block["mean"] + block["std"]
        if is_fraction(metric):
            lo, hi = lo.clip(0.0, 1.0), hi.clip(0.0, 1.0)
        if np.isfinite(block["std"]).any():
            ax.fill_between(block["step"], lo, hi, color=line.get_color(), alpha=0.2, lw=0)
    ax.set_xlabel("timesteps")
    ax.set_ylabel(metric)
    if is_fraction(metric):
        ax.set_ylim(-0.03, 1.03)
    ax.grid(alpha=0.3)
    if len(data):
        _legend(ax, data["group"].nunique())
    else:
        ax.text(0.5, 0.5, f"no history of {metric}", ha="center", va="center", transform=ax.transAxes)
    ax.set_title(f"{metric} during training (mean ± std over seeds)")
    return fig


def plot_final_metrics(groups: pd.DataFrame, metrics: Sequence[str], ax: Axes | None = None) -> Figure:
    """Bars of each group's mean (error bars: std over seeds) for the fraction-valued ``metrics``."""
    shown = [m for m in metrics if is_fraction(m) and f"{m}_mean" in groups and groups[f"{m}_mean"].notna().any()]
    fig, ax = _axes(ax, (max(6.0, 1.3 * len(shown) + 2.0), 4.2))
    width = 0.8 / max(len(groups), 1)
    x = np.arange(len(shown))
    for i, row in enumerate(groups.to_dict("records")):  # records: metric names may hold "/"
        means = [row[f"{m}_mean"] for m in shown]
        errs = np.asarray([row[f"{m}_std"] for m in shown], dtype=float)  # NaN (one run): no error bar
        ax.bar(x + (i - (len(groups) - 1) / 2) * width, means, width, yerr=errs, capsize=3, label=row["group"])
    ax.set_xticks(x, [m.removeprefix("eval_") for m in shown], rotation=20, ha="right")
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("final value (mean ± std over seeds)")
    ax.grid(axis="y", alpha=0.3)
    if len(groups):
        _legend(ax, len(groups))
    return fig
