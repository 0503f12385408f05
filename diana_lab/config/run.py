"""Config schemas of an experiment run besides the algorithm (:mod:`diana_lab.config.algo`): ``train`` (budget,
vectorised envs, device, checkpoints, imitation) and ``tracking`` (MLflow)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from diana_lab.config.store import register
from diana_lab.core.validation import (
    ConfigError,
    in_range,
    non_negative_int,
    one_of,
    positive,
    positive_int,
)

VEC_ENVS = ("auto", "batched", "dummy", "subproc")
# torch device strings SB3 accepts ("auto": cuda when available); checked here, not by torch deep in the run
DEVICE = re.compile(r"^(auto|cpu|mps|cuda(:\d+)?)$")
# a registered model name that models:/<name>/<version> and models:/<name>@<alias> read back unambiguously
MODEL_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,255}")

# ----------------------------------------------------------------------------------------------- train

EXPERTS = ("astar", "astar_memory", "astar_seen")


@dataclass
class ImitationConfig:
    """DAgger from the planner oracle before reinforcement learning (:mod:`diana_lab.training.imitation`).

    Why: from scratch, PPO spends most of a CPU budget learning that steep ground tips the rover over. The
    receding-horizon A* oracle knows the map and labels every state the learner visits; imitating it gives
    the RL stage a policy that already avoids hazards, which RL then adapts to what the sensor can see.
    Iteration ``k`` executes the expert's action with probability ``beta * beta_decay**k`` (``k = 0``:
    plain behaviour cloning), the learner's otherwise, and trains on every label gathered so far.
    """

    enabled: bool = False
    # "astar": the receding-horizon A* oracle with the whole cost map (privileged); "astar_memory": the same
    # oracle knowing only what lay within ``knowledge_radius`` of the rover so far in the episode (unknown
    # ground is taken as the cheapest), so its choices depend only on what a mapping policy could know;
    # "astar_seen": "astar_memory" knowing only the cells the policy's own map has data for (needs
    # sensor.encoding=elevation_map with memory), so its choices depend only on where that map has data
    expert: str = "astar"
    knowledge_radius: float = 12.0  # m, for "astar_memory"
    iterations: int = 6
    steps_per_iteration: int = 8192  # env steps per iteration, over all training envs
    beta: float = 1.0
    beta_decay: float = 0.5
    epochs: int = 4  # passes over the aggregated data per iteration
    batch_size: int = 256
    learning_rate: float = 1.0e-3
    # torch threads while fitting (0: every core this process may use): the training envs wait meanwhile, so
    # the cores train.torch_threads leaves to them are free
    fit_threads: int = 0
    # Gaussian policies only (PPO/A2C): the log std set after imitation, so RL starts near the imitated policy
    # (a categorical policy, action_space=discrete, has none: its exploration is the fitted probabilities)
    log_std: float | None = -1.5

    def __post_init__(self) -> None:
        key = "train.imitation"
        one_of(f"{key}.expert", self.expert, EXPERTS)
        positive(f"{key}.knowledge_radius", self.knowledge_radius)
        positive_int(f"{key}.iterations", self.iterations)
        positive_int(f"{key}.steps_per_iteration", self.steps_per_iteration)
        in_range(f"{key}.beta", self.beta, 0.0, 1.0)
        in_range(f"{key}.beta_decay", self.beta_decay, 0.0, 1.0)
        positive_int(f"{key}.epochs", self.epochs)
        positive_int(f"{key}.batch_size", self.batch_size)
        positive(f"{key}.learning_rate", self.learning_rate)
        non_negative_int(f"{key}.fit_threads", self.fit_threads)
        if self.log_std is not None:
            in_range(f"{key}.log_std", self.log_std, -5.0, 2.0)


@dataclass
class TrainConfig:
    """How long and how parallel to train, and when to checkpoint."""

    total_timesteps: int = 200_000  # the target step count (a resumed run trains up to it)
    n_envs: int = 4
    # more worlds to train in besides ``world``: conf/world options, each optionally with overrides of its own
    # ("craters world.seed=7"); env i of the n_envs drives in [world, *worlds][i % (1 + len(worlds))], so one
    # policy meets every terrain in every rollout. Evaluation stays on ``world``.
    worlds: list[str] = field(default_factory=list)
    # batched: every rover as arrays in one process, stepped by compiled calls (kinematic dynamics only);
    # dummy: one RoverNavEnv after another in one process; subproc: one process per env; auto: batched with
    # dynamics=kinematic, dummy otherwise
    vec_env: str = "dummy"
    checkpoint_every: int = 20_000  # env steps between checkpoints; 0: only at the end and on interrupt
    resume: str | None = None  # an MLflow run id, a Hydra run dir or a checkpoint .zip
    log_interval: int = 1  # SB3 logger dumps: every N updates (on-policy) or N episodes (off-policy)
    progress_bar: bool = True
    final_eval: bool = True  # evaluate the final model on eval.episodes episodes (episodes.csv, plots, GIF)
    device: str = "cpu"
    # 1: while the rovers step, a second OpenMP thread spin-waits against the env for the same cores (a small
    # network's forward pass is many times slower with 2 threads than with 1 on 2 cores). 0: torch's default
    torch_threads: int = 1
    # torch threads for the gradient updates between rollouts: the envs wait then, so their cores are free
    # (0: every core this process may use); train.torch_threads applies again at the next rollout
    update_threads: int = 0
    # collect the next rollout in a background thread while the update learns from the current one (PPO, A2C: one
    # update of lag, the rollout re-centred on the live policy; diana_lab/agents/overlap.py). While overlapping,
    # train.torch_threads also holds during the updates (train.update_threads is not used)
    overlap: bool = False
    imitation: ImitationConfig = field(default_factory=ImitationConfig)

    def __post_init__(self) -> None:
        positive_int("train.total_timesteps", self.total_timesteps)
        positive_int("train.n_envs", self.n_envs)
        for i, entry in enumerate(self.worlds):
            name, *overrides = str(entry).split() or [""]
            if not name or any(not o.startswith("world.") or "=" not in o for o in overrides):
                raise ConfigError(
                    f"train.worlds[{i}]: expected a conf/world option, optionally followed by world.<key>=<value> "
                    f"overrides (e.g. 'craters world.seed=7'), got {entry!r}"
                )
        if self.n_envs < 1 + len(self.worlds):
            raise ConfigError(
                f"train.worlds: {1 + len(self.worlds)} worlds (world and {len(self.worlds)} more) need "
                f"train.n_envs >= {1 + len(self.worlds)}, got {self.n_envs}: a world without an env is never trained in"
            )
        one_of("train.vec_env", self.vec_env, VEC_ENVS)
        non_negative_int("train.checkpoint_every", self.checkpoint_every)
        positive_int("train.log_interval", self.log_interval)
        non_negative_int("train.torch_threads", self.torch_threads)
        non_negative_int("train.update_threads", self.update_threads)
        if not DEVICE.match(str(self.device)):
            raise ConfigError(
                f"train.device: expected 'cpu', 'cuda', 'cuda:<index>', 'mps' or 'auto', got {self.device!r}"
            )
        if self.resume is not None and not str(self.resume).strip():
            raise ConfigError("train.resume: expected an MLflow run id or a path, got an empty string")


# ----------------------------------------------------------------------------------------------- tracking


@dataclass
class TrackingConfig:
    """MLflow tracking. The default store is an SQLite file in the working directory: no server needed."""

    enabled: bool = True
    uri: str = "sqlite:///mlflow.db"
    experiment: str = "diana_lab"
    run_name: str | None = None  # default: <algo>-<world>-<sensor>-s<seed>
    log_checkpoints: bool = True  # upload every checkpoint (model + vecnormalize) as an artefact
    log_replay_buffer: bool = False  # replay buffers are large: they stay in the Hydra run dir unless true
    # a name in the MLflow model registry: the run's final policy (its MLflow model policy_model) becomes a new
    # version of it, loadable as policy=models:/<name>/<version> (or @<alias>) by evaluate and export
    register_model: str | None = None

    def __post_init__(self) -> None:
        if not self.uri.strip():
            raise ConfigError("tracking.uri: expected an MLflow tracking URI such as sqlite:///mlflow.db")
        if not self.experiment.strip():
            raise ConfigError("tracking.experiment: expected a non-empty experiment name")
        if self.register_model is not None:
            if not MODEL_NAME.fullmatch(str(self.register_model)):
                raise ConfigError(
                    f"tracking.register_model: expected a registered model name of letters, digits, '_', '-' and "
                    f"'.' (starting with a letter or digit, at most 256 characters; it goes into "
                    f"models:/<name>/<version>), got {self.register_model!r}"
                )
            if not self.enabled:
                raise ConfigError(
                    f"tracking.register_model={self.register_model}: registers the run's policy in MLflow, which "
                    "tracking.enabled=false turns off; drop one of them"
                )


register("train", {"train": TrainConfig})
register("tracking", {"tracking": TrackingConfig})
