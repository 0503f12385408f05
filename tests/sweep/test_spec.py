"""Sweep files: the shipped ones are complete and compose; mistakes name the file and the line."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from omegaconf import OmegaConf

from diana_lab.config import ConfigError, compose, validate
from diana_lab.sweeps import runner
from diana_lab.sweeps.compose import compose_run
from diana_lab.sweeps.objective import suggest
from diana_lab.sweeps.spec import SWEEPS_DIR, load_spec

from .helpers import run_in_process, sweep_args, write_sweep

ROOT = Path(__file__).resolve().parents[2]


def test_reward_shaping_searches_every_default_term_and_the_deadband():
    spec = load_spec("reward_shaping")
    terms = yaml.safe_load((ROOT / "diana_lab/conf/reward/default.yaml").read_text())["terms"]
    keys = {p.key for p in spec.params}
    assert {f"reward.terms.{t}.weight" for t in terms} <= keys
    assert "reward.terms.roll.params.deadband_deg" in keys
    # one deadband: pitch follows roll's sampled value
    cfg = compose([*spec.base, "reward.terms.roll.params.deadband_deg=7.5"])
    assert cfg.reward.terms.pitch.params.deadband_deg == 7.5
    assert validate(cfg, ["reward"])["reward"].terms["pitch"].params["deadband_deg"] == 7.5  # as the runner sees it


def test_reward_shaping_runs_the_main_command_on_the_yard_judged_on_a_validation_suite():
    spec = load_spec("reward_shaping")
    main = compose([])
    cfg = compose(list(spec.base))
    assert cfg.world.name == "mars_yard" and cfg.algo == main.algo and cfg.reward == main.reward
    assert (cfg.train.n_envs, cfg.train.vec_env) == (main.train.n_envs, main.train.vec_env)
    assert cfg.sensor == main.sensor and cfg.robot.tilt_guard_deg == main.robot.tilt_guard_deg
    assert cfg.eval.seed != main.eval.seed  # settings are chosen off the reported suite
    assert spec.timesteps < main.train.total_timesteps and spec.eval_every and spec.n_trials >= 30
    flat = compose(list(load_spec("reward_shaping_flat").base))
    assert flat.world.name == "flat" and {p.key for p in load_spec("reward_shaping_flat").params} == {
        p.key for p in spec.params
    }


@pytest.mark.parametrize(
    ("name", "keys"),
    [
        ("ppo", {"algo.learning_rate", "algo.n_steps", "algo.batch_size", "algo.gamma", "algo.ent_coef"}),
        ("sac", {"algo.learning_rate", "algo.batch_size", "algo.tau", "algo.gamma", "algo.train_freq"}),
    ],
)
def test_algorithm_sweeps_name_their_hyperparameters_and_compose(name, keys):
    spec = load_spec(name)
    assert {p.key for p in spec.params} == keys
    assert spec.metric in ("spl", "success_rate") and spec.n_trials > 0 and spec.timesteps and spec.eval_episodes
    low = [p.override(p.ends()[0]) for p in spec.params]
    cfg = compose([*spec.base, *low])
    assert cfg.algo.name == name
    assert next(p for p in spec.params if p.key == "algo.learning_rate").distribution.log


def test_every_shipped_sweep_loads():
    assert {p.stem for p in SWEEPS_DIR.glob("*.yaml")} >= {"reward_shaping", "ppo", "sac"}
    for path in SWEEPS_DIR.glob("*.yaml"):
        assert load_spec(path.stem).params


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        (
            "params:\n  a.b: interval(0, 1)\n  c.d: interval(5, 1)\n",
            3,
            "params.c.d: interval(5.0, 1.0) needs low < high",
        ),
        ("params:\n  a.b: tag(log, interval(0, 1))\n", 2, "low > 0"),
        ("params:\n  a.b: choice(1,\n", 2, "cannot parse 'a.b=choice(1,'"),
        ("params:\n  a.b: [1,\n", None, "not valid YAML"),
        ("objective:\n  metric: reward\nparams:\n  a.b: interval(0, 1)\n", 2, "unknown metric 'reward'"),
        ("budget:\n  n_trial: 3\nparams:\n  a.b: interval(0, 1)\n", 2, "budget.n_trial: unknown key"),
        ("budget:\n  n_trials: -1\nparams:\n  a.b: interval(0, 1)\n", 2, "expected a positive integer"),
        ("bases: [world=flat]\nparams:\n  a.b: interval(0, 1)\n", 1, "bases: unknown section"),
        ("base:\n  - world=flat\n  - worldflat\nparams:\n  a.b: interval(0, 1)\n", 3, "base[1]: expected an override"),
        ("params:\n  a.b: 3\n", 1, "no searched key"),
    ],
)
def test_mistakes_name_the_file_and_line(tmp_path, text, line, message):
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_spec(str(path))
    err = str(info.value)
    assert message in err
    assert "bad.yaml" in err
    if line is not None:
        assert f"bad.yaml:{line}:" in err


def test_unknown_sweep_name_is_a_clear_error_with_exit_2(tmp_path, capsys):
    code = run_in_process(["sweep=no_such_sweep", f"hydra.run.dir={tmp_path}/out", f"sweep.storage={tmp_path}/j"])
    err = capsys.readouterr().err
    assert code == 2
    assert "unknown sweep" in err and "reward_shaping" in err and "Traceback" not in err
    assert not (tmp_path / "j").exists()


def test_searched_key_missing_from_the_config_names_its_line(tmp_path, capsys):
    path = write_sweep(
        tmp_path, params={"algo.learning_rate": "interval(1e-4, 1e-3)", "algo.lerning_rate": "interval(0, 1)"}
    )
    code = run_in_process(sweep_args(tmp_path, path))
    err = capsys.readouterr().err
    assert code == 2
    lines = path.read_text().splitlines()
    lineno = next(i + 1 for i, text in enumerate(lines) if "lerning" in text)
    assert f"tiny.yaml:{lineno}: params.algo.lerning_rate: no such key" in err
    assert not (tmp_path / "optuna.journal").exists()  # nothing created before the checks pass


def test_low_end_the_schema_rejects_names_its_line(tmp_path, capsys):
    path = write_sweep(tmp_path, params={"algo.learning_rate": "interval(0, 1e-3)"})
    code = run_in_process(sweep_args(tmp_path, path))
    err = capsys.readouterr().err
    assert code == 2
    assert "algo.learning_rate: expected a positive number" in err and "tiny.yaml:" in err


@pytest.mark.parametrize("name", ["reward_shaping", "ppo", "sac"])
def test_shipped_sweeps_pass_the_start_up_checks(name):
    from diana_lab.sweeps.runner import _check

    spec = load_spec(name)
    assert _check(spec, spec.params, ()).enabled  # composes and validates every group at the low ends


def _line(path: Path, text: str) -> int:
    return next(i + 1 for i, line in enumerate(path.read_text().splitlines()) if text in line)


@pytest.mark.parametrize(
    ("key", "expression", "message"),
    [
        ("algo.gamma", "interval(0.9, 1.5)", "reaches 1.5, which the config rejects: algo.gamma: expected a number in"),
        ("algo.n_steps", "choice(64, 128, -5)", "reaches -5, which the config rejects: algo.n_steps: expected a"),
        ("algo.n_steps", "interval(64, 128)", "search it with int(interval(a, b)) or range(a, b)"),
    ],
)
def test_a_value_of_the_range_the_schema_rejects_stops_before_any_trial(tmp_path, capsys, key, expression, message):
    """Only the low end used to be checked: a bad high end (or later choice) failed every trial and exited 0."""
    path = write_sweep(tmp_path, params={"algo.learning_rate": "interval(1e-4, 1e-3)", key: expression})
    code = run_in_process(sweep_args(tmp_path, path))
    err = capsys.readouterr().err
    assert code == 2
    assert f"tiny.yaml:{_line(path, f'{key}: ')}: params.{key}: {expression} reaches" in err and message in err
    assert not (tmp_path / "optuna.journal").exists()


def test_a_file_that_is_not_text_names_the_file(tmp_path):
    path = tmp_path / "binary.yaml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    with pytest.raises(ConfigError, match=r"binary\.yaml: not a text file"):
        load_spec(str(path))


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["seed=-1"], "tiny.yaml: base overrides and command line: seed: expected an integer from 0 to 2**32 - 1"),
        (["sweep.seeds=[0,-3]"], "sweep.seeds[1]: expected an integer from 0 to 2**32 - 1, got -3"),
        (["sweep.sampler_seed=-1"], "sweep.sampler_seed: expected an integer from 0 to 2**32 - 1"),
        (["seed=1", "sweep.seeds=[0,1]"], "seed and sweep.seeds both set the trials' training seeds"),
        (["eval.episodes=3", "sweep.eval_episodes=4"], "eval.episodes and sweep.eval_episodes both set"),
    ],
)
def test_bad_or_conflicting_seeds_and_budgets_exit_2(tmp_path, capsys, extra, message):
    path = write_sweep(tmp_path)
    code = run_in_process(sweep_args(tmp_path, path, *extra))
    assert code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "optuna.journal").exists()


def test_the_command_line_budget_wins_over_the_sweep_file(tmp_path, monkeypatch, capsys):
    """The file's budget is applied after the command line's overrides; it used to replace them silently."""
    composed = []

    class Compose:  # the objective without training: the trial's config as it would train
        def __init__(self, plan, worker):
            self.plan = plan

        def __call__(self, trial):
            composed.append(compose_run(self.plan.overrides({p.key: suggest(trial, p) for p in self.plan.params}))[0])
            return 0.5

    monkeypatch.setattr(runner, "Objective", Compose)
    path = write_sweep(tmp_path, n_trials=1)  # budget: timesteps 128, eval_episodes 2, eval_every 128
    cli = ["train.total_timesteps=64", "eval.episodes=3", "eval.every=0", "tracking.enabled=false"]
    code = run_in_process(sweep_args(tmp_path, path, *cli))
    err = capsys.readouterr().err
    assert code == 0, err
    (cfg,) = composed
    assert (cfg.train.total_timesteps, cfg.eval.episodes, cfg.eval.every) == (64, 3, 0)
    assert "note: train.total_timesteps is set on the command line, so budget.timesteps is not used" in err


def test_reward_tuned_is_the_shipped_studys_named_best():
    """conf/reward/tuned.yaml holds the weights of the best re-run in docs/studies (no hand edit, no rounding)."""
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    storage = JournalStorage(JournalFileBackend(str(ROOT / "docs/studies/reward_shaping.journal")))
    best = optuna.load_study(study_name="reward_shaping_top5", storage=storage).best_trial
    assert not best.user_attrs.get("baseline")  # a re-run beat reward=default's own on the fresh seeds
    cfg = compose(["reward=tuned"])
    for key, value in best.params.items():
        assert OmegaConf.select(cfg, key) == value, key
    assert cfg.reward.terms.pitch.params.deadband_deg == best.params["reward.terms.roll.params.deadband_deg"]
    assert validate(cfg, ["reward"])["reward"].name == "tuned"
