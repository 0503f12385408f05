"""Evaluation: fixed episode suites, classical baselines, metrics with confidence intervals, plots, videos.

The training runner relies on this API (keep the names)::

    suite = make_suite(env, n, seed, min_distance, max_distance)     # list[EpisodeSpec]
    df = run_suite(policy, env, suite, video_path=None)              # one row per episode
    summary = summarize(df)                                          # dict of rates / means + "_ci95"
    summary = evaluate(policy, env, cfg.eval, out_dir)               # all of it, plus files in out_dir

Policies: :class:`StraightLine`, :class:`AStarOracle`, :class:`SB3Policy` (any object with ``reset(env)`` and
``act(obs, env)`` works). ``python -m diana_lab.evaluate`` is the command-line front end.
"""

from diana_lab.config.evaluation import EvalConfig
from diana_lab.evaluation.core import eval_env, evaluate, summary_table, sweep_sensor_noise
from diana_lab.evaluation.metrics import SUMMARY_KEYS, mean_ci, spl, summarize, to_json, wilson
from diana_lab.evaluation.policies import Policy, SB3Policy, StraightLine
from diana_lab.evaluation.runner import COLUMNS, EpisodeTrace, run_episodes, run_suite
from diana_lab.evaluation.suite import EpisodeSpec, make_suite
from diana_lab.experts import waypoint_action
from diana_lab.experts.oracle import AStarOracle

__all__ = [
    "COLUMNS",
    "SUMMARY_KEYS",
    "AStarOracle",
    "EpisodeSpec",
    "EpisodeTrace",
    "EvalConfig",
    "Policy",
    "SB3Policy",
    "StraightLine",
    "eval_env",
    "evaluate",
    "make_suite",
    "mean_ci",
    "run_episodes",
    "run_suite",
    "spl",
    "summarize",
    "summary_table",
    "sweep_sensor_noise",
    "to_json",
    "waypoint_action",
    "wilson",
]
