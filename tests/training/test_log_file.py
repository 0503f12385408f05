"""The console's lines reach the Hydra job's log file (``<run dir>/<job name>.log``), once, without a bar's
control codes: training's progress lines and summary, the evaluation's table (``diana_lab.run_log``)."""

from __future__ import annotations

import io
import logging
import sys
from pathlib import Path

import pytest
from stable_baselines3 import PPO

from diana_lab.run_log import console_to_log_file, log_only, plain_line
from diana_lab.training.progress import ProgressWithStats
from tests import entrypoints

from ..agents.fake_env import FakeRoverEnv
from .helpers import ALGO_TINY, TINY, store_args

# TINY without its two hydra/*_logging=disabled: these tests need Hydra's log file; progress lines on
TINY_LOGGED = [a for a in TINY if not a.startswith(("hydra/", "train.progress_bar"))]


def _job_log(run_dir: Path) -> str:
    logs = sorted(run_dir.glob("*.log"))
    assert len(logs) == 1, logs
    return logs[0].read_text()


@pytest.fixture
def job_log(tmp_path):
    """A file handler on the root logger, as Hydra's ``job_logging`` sets one up; the file's path."""
    path = tmp_path / "job.log"
    handler = logging.FileHandler(path)
    handler.setFormatter(logging.Formatter("[%(name)s][%(levelname)s] - %(message)s"))
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        yield path
    finally:
        root.removeHandler(handler)
        handler.close()


def test_plain_line_keeps_what_a_terminal_shows_and_drops_bars():
    assert plain_line("[train] 512/512 steps (100%) | 0.1 min") == "[train] 512/512 steps (100%) | 0.1 min"
    assert plain_line("\x1b[1m\x1b[32mresults in\x1b[0m /tmp/run\r") == "results in /tmp/run"
    assert plain_line("draft\rfinal text") == "final text"
    assert plain_line("\r\x1b[2K\x1b[1A\x1b[2K") is None
    assert plain_line(" 40%|####      | 4/10 [00:01<00:01,  3.9it/s]") is None  # tqdm
    assert plain_line("stats ━━━━━━━━━━╸━━━━━  62% 320/512 [ 0:00:02 < 0:00:01 , 150 it/s ]") is None  # rich


def test_console_lines_go_to_the_log_file_and_the_console_unchanged(job_log, capsys):
    stdout, stderr = sys.stdout, sys.stderr
    with console_to_log_file() as teeing:
        assert teeing
        print("[train] 128/256 steps (50%) | 0.0 min")
        print("note: a warning", file=sys.stderr)
        sys.stdout.write("  3%|#         | 1/30\r  7%|##        | 2/30\r")  # tqdm redrawing in place
        sys.stdout.write("\r\x1b[2Kthe summary\nrow 1\nrow 2")  # rich's cursor moves; no final newline
        log_only("only in the file")
    out, err = capsys.readouterr()
    assert out.count("[train] 128/256") == 1 and "row 2" in out and "only in the file" not in out
    assert err == "note: a warning\n"
    text = job_log.read_text()
    assert "[diana_lab.console][INFO] - [train] 128/256 steps (50%)" in text
    assert "[diana_lab.console][WARNING] - note: a warning" in text
    assert "[INFO] - the summary\n" in text and "[INFO] - row 2\n" in text  # the unfinished line at the end
    assert "[INFO] - only in the file" in text
    assert "\x1b" not in text and "\r" not in text and "%|" not in text
    assert sys.stdout is stdout and sys.stderr is stderr  # put back
    print("after the job")
    log_only("after the job")
    assert "after the job" not in job_log.read_text()


def test_without_a_log_file_nothing_changes(capsys):
    stdout = sys.stdout
    with console_to_log_file() as teeing:
        assert not teeing and sys.stdout is stdout
        log_only("nowhere")
    assert capsys.readouterr().out == ""


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_bar_on_the_console_leaves_plain_lines_in_the_log_file(job_log):
    stream = _Terminal()
    with console_to_log_file():
        progress = ProgressWithStats(refresh_s=0.0, line_interval_s=0.0, stream=stream)
        model = PPO("MultiInputPolicy", FakeRoverEnv("elevation_map"), n_steps=32, batch_size=32, n_epochs=1, seed=0)
        model.learn(64, callback=progress)
        progress.close()
    assert "[train]" not in stream.getvalue()  # the console has the bar
    lines = [line for line in job_log.read_text().splitlines() if "[train]" in line]
    assert len(lines) >= 2
    assert "[train] 64/64 steps (100%)" in lines[-1]
    assert "━" not in job_log.read_text()


def test_training_writes_progress_and_summary_to_the_job_log(tmp_path):
    args = [*TINY_LOGGED, *ALGO_TINY["ppo"], "train.progress_bar=true", *store_args(tmp_path)]
    proc = entrypoints.run_subprocess("diana_lab", args, tmp_path)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    text = _job_log(tmp_path / "run")
    # stdout is a pipe: plain progress lines, on the console once and in the file
    assert out.count("[train] 256/256 steps (100%)") == 1
    assert "[train] 256/256 steps (100%)" in text
    assert "training FPS" in text and "dashboard: mlflow ui --backend-store-uri" in text  # the summary
    assert "\x1b" not in text and "\r" not in text


def test_evaluation_writes_its_table_to_the_job_log(tmp_path):
    args = [
        "policy=straight",
        "world=flat",
        "eval.episodes=2",
        "eval.plots=false",
        "eval.video=false",
        *store_args(tmp_path),
    ]
    proc = entrypoints.run_subprocess("diana_lab.evaluate", args, tmp_path)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    text = _job_log(tmp_path / "run")
    assert out.count("2 episodes, suite seed") == 1
    assert "2 episodes, suite seed" in text and "success_rate" in text and "results in" in text
    assert "MLflow run " in text
