"""Plots of a suite: the driven paths over a hillshade of the terrain, and the tilt along each path.

Figures are drawn on matplotlib's Agg canvas directly (``Figure`` + ``FigureCanvasAgg``), so plotting
never switches the process-wide backend nor needs a display: the training runner plots in the middle of a
run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from diana_lab.envs.render import hillshade
from diana_lab.evaluation.runner import EpisodeTrace
from diana_lab.sim.world import World

__all__ = ["OUTCOME_COLOURS", "plot_tilt", "plot_trajectories"]

OUTCOME_COLOURS = {
    "success": "#2ca02c",
    "collision": "#d62728",
    "tipover": "#9467bd",
    "stuck": "#ff7f0e",
    "timeout": "#1f77b4",
    "out_of_bounds": "#8c564b",
    "sim_error": "#7f7f7f",
}
TILT_LIMIT_DEG = 15.0


def _colour(outcome: str) -> str:
    return OUTCOME_COLOURS.get(outcome, "#000000")


def _legend(outcomes: list[str]) -> list[Line2D]:
    counts = pd.Series(outcomes).value_counts()
    return [Line2D([], [], color=_colour(o), lw=2, label=f"{o} ({counts[o]})") for o in OUTCOME_COLOURS if o in counts]


def _save(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=120)
    return path


def plot_trajectories(world: World, df: pd.DataFrame, traces: list[EpisodeTrace], path: Path, title: str = "") -> Path:
    """Every episode's path over the terrain, coloured by outcome; squares mark starts, circles goals."""
    fig = Figure(figsize=(7.5, 7.0))
    ax = fig.add_subplot()
    x0, x1, y0, y1 = world.bounds
    ax.imshow(hillshade(world, 512), extent=(x0, x1, y0, y1), origin="upper", interpolation="bilinear")
    for row, trace in zip(df.itertuples(index=False), traces):
        c = _colour(row.outcome)
        ax.plot(trace.xy[:, 0], trace.xy[:, 1], color=c, lw=1.2, alpha=0.85)
        ax.plot([row.start_x], [row.start_y], "s", ms=4, mfc="white", mec=c, mew=1.0)
        ax.plot([row.goal_x], [row.goal_y], "o", ms=5, mfc="none", mec=c, mew=1.2)
        if row.outcome != "success" and len(trace.xy):
            ax.plot([trace.xy[-1, 0]], [trace.xy[-1, 1]], "x", ms=6, color=c, mew=1.5)
    ax.set(xlim=(x0, x1), ylim=(y0, y1), xlabel="x (m)", ylabel="y (m)", aspect="equal")
    ax.set_title(title or f"{world.name}: {len(df)} episodes")
    ax.legend(handles=_legend(list(df["outcome"])), loc="upper right", fontsize=8, framealpha=0.85)
    fig.tight_layout()
    return _save(fig, path)


def plot_tilt(
    df: pd.DataFrame,
    traces: list[EpisodeTrace],
    path: Path,
    tipover_deg: float | None = None,
    title: str = "",
) -> Path:
    """Tilt against distance driven for every episode, with the 15-degree line and the tip-over limit."""
    fig = Figure(figsize=(8.0, 4.0))
    ax = fig.add_subplot()
    for row, trace in zip(df.itertuples(index=False), traces):
        ax.plot(trace.distance, trace.tilt_deg, color=_colour(row.outcome), lw=0.9, alpha=0.7)
    ax.axhline(TILT_LIMIT_DEG, color="k", ls="--", lw=0.8, label="15 deg")
    if tipover_deg is not None:
        ax.axhline(tipover_deg, color="#9467bd", ls=":", lw=1.0, label=f"tip-over {tipover_deg:g} deg")
    top = max([float(np.max(t.tilt_deg)) for t in traces if len(t.tilt_deg)] + [TILT_LIMIT_DEG])
    ax.set(xlabel="distance driven (m)", ylabel="tilt (deg)", ylim=(0, max(top, tipover_deg or 0) * 1.08))
    ax.set_title(title or "tilt along the path")
    ax.legend(
        handles=[*_legend(list(df["outcome"])), *ax.get_legend_handles_labels()[0]],
        fontsize=8,
        loc="upper right",
    )
    fig.tight_layout()
    return _save(fig, path)
