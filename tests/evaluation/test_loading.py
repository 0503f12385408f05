import re
from pathlib import Path

import numpy as np
import pytest

from diana_lab.cli import UserError
from diana_lab.config import ConfigError, compose, to_object
from diana_lab.evaluation import run_suite
from diana_lab.evaluation.compatibility import check_observation_space
from diana_lab.evaluation.loading import POLICY_NAMES, load_policy
from diana_lab.evaluation.suite import EpisodeSpec


def test_a_saved_sb3_model_loads_runs_and_is_refused_on_other_observations(tmp_path, flat_env):
    from stable_baselines3 import PPO

    from tests.evaluation.conftest import small_env

    model = PPO(
        "MultiInputPolicy",
        flat_env,
        n_steps=8,
        batch_size=8,
        policy_kwargs={"net_arch": [8]},
        device="cpu",
        seed=0,
    )
    model.save(tmp_path / "model.zip")
    cfg = compose(["world=flat"])
    loaded = load_policy(str(tmp_path / "model.zip"), cfg, to_object("eval", cfg.eval))
    assert loaded.model is not None and loaded.policy.vecnormalize is None
    # the slope shield picks among candidates: a continuous policy behind it is refused, naming the key
    shielded = compose(["world=flat", "eval.shield.enabled=true"])
    with pytest.raises(UserError, match=r"eval\.shield\.enabled.*continuous"):
        load_policy(str(tmp_path / "model.zip"), shielded, to_object("eval", shielded.eval))
    check_observation_space(loaded.model.observation_space, flat_env.observation_space, loaded.label)
    spec = EpisodeSpec(np.array([-3.0, 0.0]), 0.0, np.array([3.0, 0.0]), seed=1)
    assert len(run_suite(loaded.policy, flat_env, [spec])) == 1
    other = small_env("sensor.width=32", "sensor.height=24")
    try:
        with pytest.raises(ConfigError, match=r"depth_image.*\(1, 48, 64\).*\(1, 24, 32\)"):
            check_observation_space(loaded.model.observation_space, other.observation_space, loaded.label)
    finally:
        other.close()


def test_pretrained_without_its_files_says_what_is_missing(tmp_path, monkeypatch):
    """An install without the package data (e.g. a source tree copied without ``assets/``) names the file."""
    import diana_lab.evaluation.loading as loading
    from diana_lab.cli import UserError

    monkeypatch.setattr(loading, "PRETRAINED_DIR", tmp_path)
    with pytest.raises(UserError, match="not shipped") as err:
        load_policy("pretrained", compose([]), to_object("eval", compose([]).eval))
    assert str(tmp_path / "model.zip") in str(err.value)


def test_a_checkpoint_loads_its_own_observation_statistics_and_a_normalised_run_without_them_is_refused(
    tmp_path, flat_env
):
    """``checkpoints/rl_model_<n>_steps.zip`` used to look for ``vecnormalize.pkl`` beside it, find none and run
    on raw observations without a word."""
    from omegaconf import OmegaConf
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from tests.evaluation.conftest import small_env

    model = PPO("MultiInputPolicy", flat_env, n_steps=8, batch_size=8, policy_kwargs={"net_arch": [8]}, seed=0)
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / ".hydra").mkdir()
    OmegaConf.save(compose(["world=flat", "algo.normalize=true"]), run / ".hydra" / "config.yaml")
    model.save(run / "checkpoints" / "rl_model_8_steps.zip")
    stats = VecNormalize(DummyVecEnv([small_env]), norm_obs_keys=["goal"])
    stats.obs_rms["goal"].mean[:] = 3.25  # recognisable
    stats.save(run / "checkpoints" / "rl_model_vecnormalize_8_steps.pkl")
    stats.venv.close()
    cfg = compose(["world=flat"])
    loaded = load_policy(str(run / "checkpoints" / "rl_model_8_steps.zip"), cfg, to_object("eval", cfg.eval))
    assert loaded.policy.vecnormalize is not None
    assert np.allclose(loaded.policy.vecnormalize.obs_rms["goal"].mean, 3.25)

    (run / "checkpoints" / "rl_model_vecnormalize_8_steps.pkl").unlink()
    with pytest.raises(UserError, match=r"algo\.normalize=true.*rl_model_vecnormalize_8_steps\.pkl"):
        load_policy(str(run / "checkpoints" / "rl_model_8_steps.zip"), cfg, to_object("eval", cfg.eval))


def test_a_run_id_in_a_store_that_does_not_exist_is_refused_without_creating_it(tmp_path):
    db = tmp_path / "mlflow.db"
    cfg = compose([f"tracking.uri=sqlite:///{db}"])
    with pytest.raises(UserError, match=r"policy=0123456789abcdef0123456789abcdef: .*tracking\.uri=.*has no store"):
        load_policy("0123456789abcdef0123456789abcdef", cfg, to_object("eval", cfg.eval))
    assert not db.exists()


def test_the_readmes_list_of_policies_is_the_one_the_program_accepts_and_names():
    """The README's Commands table left out some of them once."""
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    lists = [m.group(1) for m in re.finditer(r"python -m diana_lab\.evaluate policy=<([^>]*)>", readme)]
    full = [names for names in lists if "pretrained" in names]  # the Commands table's, beside the tour's examples
    assert len(full) == 1
    assert [n.strip() for n in full[0].split(",")] == [
        "run id",
        "model path",
        "models:/name/version",
        "pretrained",
        *POLICY_NAMES,
    ]
    cfg = compose([])
    with pytest.raises(UserError, match="policy=astr: no such model file") as err:
        load_policy("astr", cfg, to_object("eval", cfg.eval))
    assert f"({', '.join(POLICY_NAMES)})" in str(err.value)


def test_every_policy_option_composes_and_builds_with_its_keys():
    from diana_lab.experts import AStarOracle, SeenMapOracle

    built = {}
    for name in POLICY_NAMES:
        cfg = compose([f"policy={name}", "action_space=discrete"], config_name="evaluate")
        built[name] = load_policy(cfg.policy, cfg, to_object("eval", cfg.eval)).policy
        assert built[name].name == name
    assert isinstance(built["astar_seen"], SeenMapOracle)
    memory = built["astar_memory"]
    assert isinstance(memory, AStarOracle) and memory.knowledge_radius == 12.0 and memory.knowledge_memory
    cfg = compose(["policy=astar", "policy.spacing=0.6", "policy.plain=true"], config_name="evaluate")
    astar = load_policy(cfg.policy, cfg, to_object("eval", cfg.eval)).policy
    assert (astar.spacing, astar.plain, astar.knowledge_radius) == (0.6, True, None)


@pytest.mark.parametrize(
    ("overrides", "named"),
    [
        (["policy=astar", "policy.spacing=1.5"], r"policy\.spacing: expected a number in \[0\.0, 1\.0\], got 1\.5"),
        (["policy=astar_memory", "policy.knowledge_radius=-2"], r"policy\.knowledge_radius: expected a positive"),
        (["policy=model"], r"policy\.source: missing, and required for policy=model: a Stable-Baselines3 \.zip"),
    ],
)
def test_a_bad_policy_key_is_refused_naming_it(overrides, named):
    cfg = compose(overrides, config_name="evaluate")
    with pytest.raises(UserError, match=named):
        load_policy(cfg.policy, cfg, to_object("eval", cfg.eval))


def test_a_path_or_run_id_given_as_policy_reads_as_the_model_options_source(tmp_path):
    from diana_lab.config import CONF_DIR
    from diana_lab.config.policy import source_overrides

    run_id = "0123456789abcdef0123456789abcdef"
    assert source_overrides(["policy=astar", f"policy={run_id}", "eval.episodes=2"], CONF_DIR) == [
        "policy=astar",
        "policy=model",
        f"policy.source='{run_id}'",
        "eval.episodes=2",
    ]
    odd = tmp_path / "run=1 (copy)" / "model.zip"
    for name, expected in ((run_id, run_id), (str(odd), str(odd)), ("pretrained", "pretrained")):
        for config_name in ("evaluate", "export"):
            assert compose([f"policy={name}"], config_name=config_name).policy.source == expected
    assert "policy" not in compose([], config_name="evaluate")
