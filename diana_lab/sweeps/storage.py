"""Where a study lives: a journal file by default (nothing to start), or any Optuna RDB URL for many machines.

* A value without ``://`` is a journal file (``optuna.journal``, relative to the working directory): Optuna's
  JournalFileBackend appends under a file lock, so workers on one machine (or an NFS share) can share it; a
  lock left by a killed worker is broken after its grace period, so nobody waits forever.
* ``sqlite:///x.db``, ``postgresql+psycopg2://user:pw@host:5432/db``, ``mysql+pymysql://...``: an RDBStorage.
  Workers send a heartbeat every ``heartbeat_s`` seconds; a trial whose worker died (SIGKILL, a lost machine)
  is failed by the next worker that starts, or starts a trial, so it does not stay RUNNING for ever.

``optuna-dashboard <storage>`` reads both forms (:func:`dashboard_command`).
"""

from __future__ import annotations

import inspect
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import optuna
from optuna.storages import BaseStorage, JournalStorage, RDBStorage
from optuna.storages.journal import JournalFileBackend

from diana_lab.core.validation import ConfigError
from diana_lab.tracking.mlflow_run import resolve_uri

__all__ = ["dashboard_command", "display_url", "is_rdb", "make_storage", "resolve_storage"]


def is_rdb(storage: str) -> bool:
    return "://" in storage


def resolve_storage(storage: str) -> str:
    """An absolute journal path or SQLite file, so every worker and the dashboard find the same study."""
    if is_rdb(storage):
        return resolve_uri(storage)
    return str(Path(storage).expanduser().resolve())


def display_url(storage: str) -> str:
    """The storage without its password (for tags and messages)."""
    if not is_rdb(storage):
        return storage
    try:
        from sqlalchemy.engine import make_url

        return make_url(storage).render_as_string(hide_password=True)
    except Exception:
        return storage.split("@", 1)[-1] if "@" in storage else storage


EXPECTED = (
    "expected a journal file path or an RDB URL such as sqlite:///optuna.db or postgresql+psycopg2://u:pw@host/db"
)


def _check_journal(path: Path) -> None:
    """Refuse an existing file that is not a journal (an SQLite database given without ``sqlite:///``, a sweep
    file) before Optuna appends to it and fails on reading it with a message that names neither."""
    if path.is_dir():
        raise ConfigError(f"sweep.storage={path}: a folder; {EXPECTED}")
    if not path.is_file() or path.stat().st_size == 0:
        return
    with path.open("rb") as f:
        head = f.read(16)
    if head.startswith(b"SQLite format 3"):
        raise ConfigError(
            f"sweep.storage={path}: an SQLite database, not a journal file (as a storage: sqlite:///PATH)"
        )
    if not head.startswith(b"{"):  # every journal line is a JSON object (even one a worker is writing now)
        raise ConfigError(f"sweep.storage={path}: not an Optuna journal file; {EXPECTED}")


_CREATE_TRIES = 4  # opening an RDB storage whose tables another worker is creating at the same moment

# Optuna >= 4.9 renamed RDBStorage's failed_trial_callback (deprecated since) to heartbeat_stale_trial_callback
_STALE_KWARG = (
    "heartbeat_stale_trial_callback"
    if "heartbeat_stale_trial_callback" in inspect.signature(RDBStorage).parameters
    else "failed_trial_callback"
)


def make_storage(
    storage: str,
    heartbeat_s: int = 60,
    on_stale: Callable[[optuna.Study, optuna.trial.FrozenTrial], None] | None = None,
) -> BaseStorage:
    """The Optuna storage for ``sweep.storage`` (already resolved); a clear error when it cannot be opened.
    ``on_stale(study, trial)``: RDB storages call it for each trial of a dead worker their heartbeats fail."""
    if not is_rdb(storage):
        _check_journal(Path(storage))
    try:
        if not is_rdb(storage):
            path = Path(storage)
            path.parent.mkdir(parents=True, exist_ok=True)
            return JournalStorage(JournalFileBackend(str(path)))
        heartbeat: dict = {}
        if heartbeat_s:
            heartbeat = {"heartbeat_interval": heartbeat_s, "grace_period": 2 * heartbeat_s, _STALE_KWARG: on_stale}
        return _rdb_storage(storage, heartbeat)
    except ImportError as exc:  # e.g. postgresql:// without psycopg2
        raise ConfigError(f"sweep.storage={display_url(storage)}: missing database driver ({exc})") from exc
    except (optuna.exceptions.StorageInternalError, OSError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"sweep.storage={display_url(storage)}: cannot open the study storage ({first})") from exc
    except Exception as exc:  # SQLAlchemy's OperationalError and friends: a server that is not there
        if type(exc).__name__ == "NoSuchModuleError":  # redis://, http://: not a database SQLAlchemy knows
            scheme = storage.split("://", 1)[0]
            raise ConfigError(
                f"sweep.storage={display_url(storage)}: '{scheme}' is not a database SQLAlchemy knows; {EXPECTED}"
            ) from exc
        if type(exc).__module__.startswith("sqlalchemy"):
            first = str(exc).strip().splitlines()[0]
            raise ConfigError(f"sweep.storage={display_url(storage)}: cannot connect ({first})") from exc
        raise


def _rdb_storage(storage: str, heartbeat: dict) -> RDBStorage:
    """Workers starting together on an empty database (several machines, one command) all create Optuna's
    tables; PostgreSQL fails all but one of them (a duplicate key in its catalogue, or the table already
    there). The tables are then in place: try again, a few times, rather than stop that worker."""
    from sqlalchemy.exc import IntegrityError, ProgrammingError

    for attempt in range(_CREATE_TRIES):
        try:
            with warnings.catch_warnings():  # heartbeats are "experimental" in Optuna; we rely on them knowingly
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                return RDBStorage(storage, engine_kwargs={"pool_pre_ping": True}, **heartbeat)
        except (IntegrityError, ProgrammingError):
            if attempt + 1 == _CREATE_TRIES:
                raise
            time.sleep(0.5 * (attempt + 1))
    raise AssertionError("unreachable")


def dashboard_command(storage: str) -> str:
    return f"optuna-dashboard {display_url(storage)}"
