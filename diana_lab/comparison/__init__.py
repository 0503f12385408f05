"""Compare tracked runs: MLflow runs into pandas, grouped over seeds, learning curves and tables.

    from diana_lab.comparison import compare_runs
    c = compare_runs("sqlite:///mlflow.db", ["diana_lab"], "tags.world = 'flat'")
    c.groups            # mean/std over seeds per group of runs
    plot_learning_curves(c.curves, "eval_spl")

``python -m diana_lab.compare`` is the same as a command that writes tables and plots (``docs/dashboard.md``).
"""

from diana_lab.comparison.groups import aggregate, assign_groups, learning_curves, runs_table
from diana_lab.comparison.plots import plot_final_metrics, plot_learning_curves
from diana_lab.comparison.report import (
    DEFAULT_CURVES,
    DEFAULT_GROUP_BY,
    DEFAULT_METRICS,
    Comparison,
    compare_runs,
    write_report,
)
from diana_lab.comparison.runs import ComparisonError, load_runs, metric_histories

__all__ = [
    "DEFAULT_CURVES",
    "DEFAULT_GROUP_BY",
    "DEFAULT_METRICS",
    "Comparison",
    "ComparisonError",
    "aggregate",
    "assign_groups",
    "compare_runs",
    "learning_curves",
    "load_runs",
    "metric_histories",
    "plot_final_metrics",
    "plot_learning_curves",
    "runs_table",
    "write_report",
]
