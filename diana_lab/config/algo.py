"""Config schemas of the ``algo`` group: one per RL algorithm, with the features extractor it trains.

Each ``conf/algo/<name>.yaml`` extends the schema of its algorithm, so a misspelt hyperparameter
(``algo.n_step=...``) is rejected by Hydra at composition time. ``_target_`` names the Stable-Baselines3
class; every field that is not in :data:`NON_SB3_KEYS` is passed to its constructor as a keyword argument
(see :mod:`diana_lab.agents.factory`), so adding a hyperparameter is one line here and one in the YAML.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from omegaconf import MISSING

from diana_lab.config.store import register
from diana_lab.core.validation import (
    ConfigError,
    in_range,
    non_negative,
    non_negative_int,
    one_of,
    positive,
    positive_int,
)

ELEVATION_ENCODERS = ("auto", "cnn", "mlp", "strips")

# algo keys that configure the runner / policy rather than being constructor arguments of the SB3 class
NON_SB3_KEYS = frozenset(
    {
        "_target_",
        "name",
        "net_arch",
        "normalize",
        "norm_obs_keys",
        "norm_reward",
        "extractor",
        "policy_kwargs",
        "action_noise_std",
        "learning_rate_end",
    }
)


# ActorCriticPolicy kwargs that shape a Gaussian action distribution: a categorical policy would ignore them
GAUSSIAN_POLICY_KWARGS = ("log_std_init", "full_std", "use_expln", "squash_output")


def _layers(key: str, value: list[int]) -> None:
    for i, v in enumerate(value):
        positive_int(f"{key}[{i}]", v)


# ----------------------------------------------------------------------------------------------- algo


@dataclass
class StripsConfig:
    """The per-heading strip network of :mod:`diana_lab.agents.strips` (``elevation_encoder: strips``); its map
    geometry and candidates come from ``sensor.elevation_map`` and ``action_space`` (set by the factory)."""

    lateral: list[float] = field(default_factory=lambda: [-0.25, 0.0, 0.25])  # the track's lines (m, left +)
    step: float = 0.25  # spacing of a line's points (m)
    reach: float = 4.0  # how far out along the heading (m)
    hidden: int = 64  # width of the per-heading network
    context: int = 32  # channels of the convolution over neighbouring headings

    def __post_init__(self) -> None:
        key = "algo.extractor.strips"
        if not self.lateral:
            raise ConfigError(f"{key}.lateral: expected at least one offset (m), e.g. [0.0]")
        positive(f"{key}.step", self.step)
        positive(f"{key}.reach", self.reach)
        if self.reach < self.step:
            raise ConfigError(f"{key}.reach: expected at least {key}.step ({self.step}), got {self.reach}")
        positive_int(f"{key}.hidden", self.hidden)
        positive_int(f"{key}.context", self.context)


@dataclass
class ExtractorConfig:
    """The features extractor of :mod:`diana_lab.agents.extractors`: one encoder per observation key.

    Every sensor encoder ends in ``sensor_features`` units, the goal MLP in ``goal_hidden[-1]``; the
    policy and value heads (``algo.net_arch``) see their concatenation.
    """

    goal_hidden: list[int] = field(default_factory=lambda: [64, 64])
    cnn_channels: list[int] = field(default_factory=lambda: [16, 32, 32])  # depth image / elevation map CNN
    cnn_pool: list[int] = field(default_factory=lambda: [3, 4])  # adaptive pooling grid (rows, cols) after it
    sensor_features: int = 128
    # auto (strips where the action space is discrete in the rover's frame, else cnn) | cnn | mlp | strips (one
    # network scoring every candidate heading's strip of the map, see ``strips``)
    elevation_encoder: str = "auto"
    point_hidden: list[int] = field(default_factory=lambda: [64, 128])  # PointNet shared per-point MLP
    strips: StripsConfig = field(default_factory=StripsConfig)

    def __post_init__(self) -> None:
        _layers("algo.extractor.goal_hidden", self.goal_hidden)
        _layers("algo.extractor.cnn_channels", self.cnn_channels)
        _layers("algo.extractor.point_hidden", self.point_hidden)
        _layers("algo.extractor.cnn_pool", self.cnn_pool)
        if not self.goal_hidden or not self.cnn_channels or not self.point_hidden or len(self.cnn_pool) != 2:
            raise ConfigError(
                "algo.extractor: goal_hidden, cnn_channels and point_hidden need at least one "
                "layer each, cnn_pool exactly two numbers"
            )
        positive_int("algo.extractor.sensor_features", self.sensor_features)
        one_of("algo.extractor.elevation_encoder", self.elevation_encoder, ELEVATION_ENCODERS)


@dataclass
class AlgoConfig:
    """Keys common to every algorithm. ``net_arch`` sizes the policy/value (or actor/critic) MLP heads."""

    _target_: str = MISSING
    name: str = MISSING
    policy: str = "MultiInputPolicy"
    learning_rate: float = 3e-4
    # null: a constant rate; a number: the rate falls linearly from learning_rate to it over
    # train.total_timesteps (SB3's LinearSchedule), so the last updates move the policy less
    learning_rate_end: float | None = None
    gamma: float = 0.99
    net_arch: list[int] = field(default_factory=lambda: [64, 64])
    normalize: bool = False  # VecNormalize (saved as vecnormalize.pkl next to every model)
    norm_obs_keys: list[str] = field(default_factory=lambda: ["goal"])  # images and point masks stay raw
    norm_reward: bool = True
    extractor: ExtractorConfig = field(default_factory=ExtractorConfig)
    policy_kwargs: dict[str, Any] = field(default_factory=dict)  # extra policy kwargs (e.g. TQC n_quantiles)

    def __post_init__(self) -> None:
        positive("algo.learning_rate", self.learning_rate)
        if self.learning_rate_end is not None:
            non_negative("algo.learning_rate_end", self.learning_rate_end)
        in_range("algo.gamma", self.gamma, 0.0, 1.0)
        _layers("algo.net_arch", self.net_arch)
        encoder = self.extractor.elevation_encoder
        if encoder == "strips" and self.normalize and "goal" in self.norm_obs_keys:
            raise ConfigError(
                "algo.normalize: the strips encoder turns the raw goal vector's bearing onto every heading, so 'goal' "
                "cannot be normalised; set algo.normalize=false or drop 'goal' from algo.norm_obs_keys"
            )

    @property
    def off_policy(self) -> bool:
        return False

    @property
    def discrete_actions(self) -> bool:
        """Whether the SB3 class takes a ``Discrete`` action space (a categorical policy head). SAC, TQC,
        DDPG and TD3 differentiate their critic through a continuous action, so they need a ``Box``."""
        return False


@dataclass
class OnPolicyConfig(AlgoConfig):
    n_steps: int = 256  # per env and update
    gae_lambda: float = 0.95
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5

    def __post_init__(self) -> None:
        super().__post_init__()
        positive_int("algo.n_steps", self.n_steps)
        in_range("algo.gae_lambda", self.gae_lambda, 0.0, 1.0)
        non_negative("algo.ent_coef", self.ent_coef)
        non_negative("algo.vf_coef", self.vf_coef)
        positive("algo.max_grad_norm", self.max_grad_norm)

    @property
    def discrete_actions(self) -> bool:
        return True  # PPO and A2C: a Categorical distribution over the candidates


@dataclass
class PPOConfig(OnPolicyConfig):
    _target_: str = "stable_baselines3.PPO"
    name: str = "ppo"
    batch_size: int = 64
    n_epochs: int = 10
    clip_range: float = 0.2

    def __post_init__(self) -> None:
        super().__post_init__()
        positive_int("algo.batch_size", self.batch_size)
        positive_int("algo.n_epochs", self.n_epochs)
        positive("algo.clip_range", self.clip_range)


@dataclass
class A2CConfig(OnPolicyConfig):
    _target_: str = "stable_baselines3.A2C"
    name: str = "a2c"
    n_steps: int = 16
    learning_rate: float = 7e-4
    gae_lambda: float = 1.0
    use_rms_prop: bool = True
    normalize_advantage: bool = False


@dataclass
class OffPolicyConfig(AlgoConfig):
    """Replay-buffer algorithms. The buffer holds every observation twice in float32: with a 64 x 48 depth
    image that is ~25 kB per transition, so the default is 20 000 transitions (~0.5 GB)."""

    buffer_size: int = 20_000
    learning_starts: int = 1000
    batch_size: int = 256
    tau: float = 0.005
    train_freq: int = 1
    gradient_steps: int = 1

    def __post_init__(self) -> None:
        super().__post_init__()
        positive_int("algo.buffer_size", self.buffer_size)
        non_negative_int("algo.learning_starts", self.learning_starts)
        positive_int("algo.batch_size", self.batch_size)
        in_range("algo.tau", self.tau, 0.0, 1.0)
        positive_int("algo.train_freq", self.train_freq)
        if (
            isinstance(self.gradient_steps, bool)
            or not isinstance(self.gradient_steps, int)
            or (self.gradient_steps == 0 or self.gradient_steps < -1)
        ):
            raise ConfigError(f"algo.gradient_steps: expected a positive integer or -1, got {self.gradient_steps!r}")

    @property
    def off_policy(self) -> bool:
        return True


@dataclass
class SACConfig(OffPolicyConfig):
    _target_: str = "stable_baselines3.SAC"
    name: str = "sac"
    ent_coef: Any = "auto"  # "auto", "auto_<init>" or a number


@dataclass
class TQCConfig(SACConfig):
    _target_: str = "sb3_contrib.TQC"
    name: str = "tqc"
    top_quantiles_to_drop_per_net: int = 2

    def __post_init__(self) -> None:
        super().__post_init__()
        non_negative_int("algo.top_quantiles_to_drop_per_net", self.top_quantiles_to_drop_per_net)


@dataclass
class DDPGConfig(OffPolicyConfig):
    _target_: str = "stable_baselines3.DDPG"
    name: str = "ddpg"
    learning_rate: float = 1e-3
    action_noise_std: float = 0.1  # Gaussian exploration noise on the [-1, 1] actions; 0 turns it off

    def __post_init__(self) -> None:
        super().__post_init__()
        non_negative("algo.action_noise_std", self.action_noise_std)


@dataclass
class TD3Config(DDPGConfig):
    _target_: str = "stable_baselines3.TD3"
    name: str = "td3"
    policy_delay: int = 2
    target_policy_noise: float = 0.2
    target_noise_clip: float = 0.5

    def __post_init__(self) -> None:
        super().__post_init__()
        positive_int("algo.policy_delay", self.policy_delay)
        non_negative("algo.target_policy_noise", self.target_policy_noise)
        non_negative("algo.target_noise_clip", self.target_noise_clip)


def check_action_space(algo: AlgoConfig, shape: str) -> None:
    """Refuse an ``algo`` that cannot drive ``action_space.shape`` before anything is built, naming both keys
    (SB3 would only fail in the model's constructor, with an assertion about space classes)."""
    if shape != "discrete":
        return
    if not algo.discrete_actions:
        raise ConfigError(
            f"algo={algo.name} with action_space.shape=discrete: {algo.name} needs a continuous (Box) action; "
            "use algo=ppo or algo=a2c with the discrete action space, or action_space=square|circle"
        )
    gaussian = [k for k in GAUSSIAN_POLICY_KWARGS if k in algo.policy_kwargs]
    if gaussian:
        raise ConfigError(
            f"algo.policy_kwargs.{gaussian[0]}: a Gaussian-policy setting, but action_space.shape=discrete gives "
            "a categorical policy that would ignore it; drop it"
        )


register(
    "algo",
    {
        "ppo": PPOConfig,
        "a2c": A2CConfig,
        "sac": SACConfig,
        "tqc": TQCConfig,
        "ddpg": DDPGConfig,
        "td3": TD3Config,
    },
)
