"""A throw-away PostgreSQL server on loopback for storage tests: ``initdb`` a cluster in a temporary folder,
``pg_ctl start`` it on a free port with its socket in that folder, yield a SQLAlchemy URL, stop it after.

PostgreSQL refuses to run as root; under root the cluster belongs to the ``postgres`` system user (created
by Debian's package) and every server command runs as that user. Anything missing raises
:class:`PostgresUnavailable` with the reason, which the tests turn into a failure (never a skip): the set-up
(``./dev setup``) installs the ``postgresql`` package.
"""

from __future__ import annotations

import contextlib
import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["PostgresUnavailable", "postgres_server"]

DB_USER = "diana"
DB_NAME = "sweeps"


class PostgresUnavailable(RuntimeError):
    """The server could not be started; the message says why."""


def _bindir() -> Path:
    dirs = sorted(glob.glob("/usr/lib/postgresql/*/bin"), key=lambda d: int(Path(d).parent.name.split(".")[0]))
    for d in reversed(dirs):
        if (Path(d) / "initdb").is_file():
            return Path(d)
    found = shutil.which("initdb")
    if found:
        return Path(found).resolve().parent
    raise PostgresUnavailable("no initdb: install Debian's postgresql package (./dev setup does)")


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _run(args: list[str], user: str | None, timeout: float = 120) -> None:
    try:
        done = subprocess.run(
            args, user=user, capture_output=True, text=True, timeout=timeout, check=False, cwd=tempfile.gettempdir()
        )
    except (OSError, subprocess.SubprocessError) as exc:
        raise PostgresUnavailable(f"{Path(args[0]).name} could not run: {exc}") from exc
    if done.returncode != 0:
        raise PostgresUnavailable(f"{' '.join(args)} failed ({done.returncode}): {done.stderr.strip()[-800:]}")


@contextlib.contextmanager
def postgres_server() -> Iterator[str]:
    """``postgresql+psycopg2://diana@127.0.0.1:<port>/sweeps`` of a fresh server, stopped afterwards."""
    bindir = _bindir()
    user: str | None = None
    root = Path(tempfile.mkdtemp(prefix="diana_pg_"))
    if os.geteuid() == 0:
        try:
            pw = pwd.getpwnam("postgres")
        except KeyError as exc:
            raise PostgresUnavailable("running as root and there is no 'postgres' user to own the cluster") from exc
        user = "postgres"
        os.chown(root, pw.pw_uid, pw.pw_gid)
    data, log = root / "data", root / "server.log"
    port = _free_port()
    started = False
    try:
        _run([str(bindir / "initdb"), "-D", str(data), "-U", DB_USER, "-A", "trust", "--no-sync", "-E", "UTF8"], user)
        options = f"-p {port} -k {root} -c listen_addresses=127.0.0.1 -c fsync=off -c full_page_writes=off"
        try:
            _run(
                [str(bindir / "pg_ctl"), "-D", str(data), "-l", str(log), "-o", options, "-w", "-t", "60", "start"],
                user,
            )
        except PostgresUnavailable as exc:
            tail = log.read_text()[-800:] if log.is_file() else ""
            raise PostgresUnavailable(f"{exc}\nserver log: {tail}") from exc
        started = True
        _run([str(bindir / "createdb"), "-h", "127.0.0.1", "-p", str(port), "-U", DB_USER, DB_NAME], user)
        yield f"postgresql+psycopg2://{DB_USER}@127.0.0.1:{port}/{DB_NAME}"
    finally:
        if started:
            with contextlib.suppress(PostgresUnavailable):
                _run([str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "-w", "stop"], user, timeout=60)
        shutil.rmtree(root, ignore_errors=True)
