"""Config schema of the ``sweep`` node of ``conf/sweep.yaml`` (``python -m diana_lab.sweep``).

The search space, base overrides, objective and budget live in the sweep file ``sweeps/<name>.yaml``; the
node here chooses the file and says how to run it. Keys left ``None`` take the sweep file's value, so
``sweep.n_trials=50`` overrides the file's budget without editing it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from diana_lab.config.store import register
from diana_lab.core.validation import ConfigError, check_seed, one_of, positive

SAMPLERS = ("tpe", "random", "cmaes")
PRUNERS = ("median", "successive_halving", "none")
DIRECTIONS = ("maximize", "minimize")


def _positive_int_or_none(key: str, value: int | None) -> None:
    if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value <= 0):
        raise ConfigError(f"{key}: expected a positive integer (or null for the sweep file's value), got {value!r}")


@dataclass
class SweepConfig:
    """How to run a study; ``None`` means "as the sweep file says"."""

    name: str = "reward_shaping"  # diana_lab/sweeps/specs/<name>.yaml, or a path to a sweep file
    n_trials: int | None = None  # the study's total (finished trials count, so a rerun tops it up)
    sampler: str = "tpe"  # tpe | random | cmaes
    sampler_seed: int | None = None  # for a reproducible single worker; None: each worker draws its own
    pruner: str = "median"  # median | successive_halving | none (on the periodic evaluations)
    pruner_startup_trials: int = 5  # median pruner: trials that are never pruned, to learn the median
    # a journal file (relative to the working directory) or an Optuna RDB URL (sqlite:///x.db,
    # postgresql+psycopg2://user:pw@host/db) that several workers on several machines can share
    storage: str = "optuna.journal"
    study_name: str | None = None  # default: the sweep file's name
    seeds: list[int] = field(default_factory=list)  # training seeds per trial (objective = mean); []: `seed`
    timeout_s: float | None = None  # this worker starts no new trial after this many seconds
    heartbeat_s: int = 60  # RDB storages: trials of a dead worker are failed after 2 missed heartbeats
    metric: str | None = None  # objective: an evaluation summary key (spl, success_rate, ...)
    direction: str | None = None  # maximize | minimize
    timesteps: int | None = None  # training steps per trial (and per seed)
    eval_episodes: int | None = None  # episodes of the fixed evaluation suite (the objective's)
    eval_every: int | None = None  # steps between the evaluations the pruner sees
    prune_after: int | None = None  # median pruner: training steps before which no trial is pruned
    top: int = 10  # trials in the printed table
    # worker processes of this study on this machine, each pinned to its share of the cores (a run uses two
    # cores poorly, so 2 workers on 2 cores run about twice the trials of one); 1: this process only
    workers: int = 1
    # a new study's first trial: the composed config's own values of the searched keys (reward=default's
    # weights, say), so the table says whether anything beats them
    baseline: bool = True
    # a study in this storage whose best sweep.top_k trials this study re-runs on sweep.seeds (fresh ones),
    # enqueued instead of sampled and never pruned, before a best is named (diana_lab/sweeps/confirm.py)
    top_of: str | None = None
    top_k: int = 5

    def __post_init__(self) -> None:
        if not str(self.name).strip():
            raise ConfigError(
                "sweep.name: expected the name of a file in diana_lab/sweeps/specs/ (e.g. reward_shaping)"
            )
        one_of("sweep.sampler", self.sampler, SAMPLERS)
        one_of("sweep.pruner", self.pruner, PRUNERS)
        if self.direction is not None:
            one_of("sweep.direction", self.direction, DIRECTIONS)
        if not str(self.storage).strip():
            raise ConfigError("sweep.storage: expected a journal file path or an RDB URL such as sqlite:///optuna.db")
        for key in ("n_trials", "timesteps", "eval_episodes"):
            _positive_int_or_none(f"sweep.{key}", getattr(self, key))
        if self.eval_every is not None and (
            isinstance(self.eval_every, bool) or not isinstance(self.eval_every, int) or self.eval_every < 0
        ):
            raise ConfigError(f"sweep.eval_every: expected an integer >= 0 (0: no pruning), got {self.eval_every!r}")
        if self.prune_after is not None and (
            isinstance(self.prune_after, bool) or not isinstance(self.prune_after, int) or self.prune_after < 0
        ):
            raise ConfigError(f"sweep.prune_after: expected an integer >= 0 (training steps), got {self.prune_after!r}")
        if self.timeout_s is not None:
            positive("sweep.timeout_s", self.timeout_s)
        if isinstance(self.heartbeat_s, bool) or not isinstance(self.heartbeat_s, int) or self.heartbeat_s < 0:
            raise ConfigError(f"sweep.heartbeat_s: expected an integer >= 0 (0 disables), got {self.heartbeat_s!r}")
        if isinstance(self.pruner_startup_trials, bool) or self.pruner_startup_trials < 0:
            raise ConfigError(
                f"sweep.pruner_startup_trials: expected an integer >= 0, got {self.pruner_startup_trials!r}"
            )
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1:
            raise ConfigError(
                f"sweep.workers: expected a positive integer (processes on this machine), got {self.workers!r}"
            )
        if isinstance(self.top_k, bool) or not isinstance(self.top_k, int) or self.top_k < 1:
            raise ConfigError(f"sweep.top_k: expected a positive integer (trials to re-run), got {self.top_k!r}")
        if self.top_of is not None and not self.seeds:
            raise ConfigError(
                f"sweep.top_of={self.top_of}: a re-run of the top trials needs sweep.seeds, training seeds other "
                "than the one they were picked on (e.g. 'sweep.seeds=[1,2,3]')"
            )
        if isinstance(self.top, bool) or self.top <= 0:
            raise ConfigError(f"sweep.top: expected a positive integer, got {self.top!r}")
        for i, seed in enumerate(self.seeds):
            check_seed(f"sweep.seeds[{i}]", seed)
        if self.sampler_seed is not None:
            check_seed("sweep.sampler_seed", self.sampler_seed)
        if len(set(self.seeds)) != len(self.seeds):
            raise ConfigError(f"sweep.seeds: expected distinct seeds, got {list(self.seeds)!r}")


register("sweep", {"sweep": SweepConfig})
