"""Real, throwaway database servers on 127.0.0.1 for the tests: Redis and PostgreSQL.

:class:`RedisServer` runs ``redis-server`` without persistence (or, with ``appendonly=True``, with an
append-only file, and then :meth:`RedisServer.restart` stops it and starts it again on the same port
and file, as an operator's restart would); :class:`PostgresServer` runs
``initdb`` + ``postgres`` in a temporary directory (as the ``postgres`` system user when the
tests run as root, since PostgreSQL refuses to run as root). Both take a free loopback port,
wait until they answer, and stop gently, then by force; an atexit hook kills whatever is left.

Fixtures: ``redis_server`` / ``postgres_server`` (session, started once) and ``redis_url``
(the session server after FLUSHALL) / ``postgres_url`` (a fresh database per test). Missing
binaries fail the fixtures, never skip them. ``redis_url`` and ``postgres_url`` need their
session fixture importable too: ``from servers import *`` brings all four.
Every wait is a loop bounded in count; nothing asserts on elapsed time.
"""

from __future__ import annotations

import atexit
import glob
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Self
from urllib.parse import quote

import pytest

__all__ = ["PostgresServer", "RedisServer", "postgres_available", "postgres_server", "postgres_url",
           "redis_available", "redis_server", "redis_url"]

INSTALL_HINT = "apt-get install -y redis-server postgresql"
PG_USER = "scanmill"          # the superuser initdb creates (trust authentication)
PG_SYSTEM_USER = "postgres"   # the Debian system user that runs PostgreSQL when we are root
READY_TRIES = 200             # readiness: up to READY_TRIES x READY_PAUSE_S
READY_PAUSE_S = 0.05
STOP_TRIES = 100              # shutdown: up to STOP_TRIES x STOP_PAUSE_S before SIGKILL
STOP_PAUSE_S = 0.05

#: Server processes (with their gentle stop signal) and directories still alive, for atexit.
_LIVE_PROCS: dict[int, tuple[subprocess.Popen, int]] = {}
_LIVE_DIRS: set[str] = set()


def _cleanup_at_exit() -> None:
    for proc, first_signal in list(_LIVE_PROCS.values()):
        _stop_process(proc, first_signal, tries=40)
    _LIVE_PROCS.clear()
    for d in list(_LIVE_DIRS):
        shutil.rmtree(d, ignore_errors=True)
    _LIVE_DIRS.clear()


atexit.register(_cleanup_at_exit)


# ----------------------------------------------------------------------------- helpers


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _log_tail(path: Path, n_chars: int = 4000) -> str:
    try:
        return path.read_text(errors="replace")[-n_chars:]
    except OSError as e:
        return f"<no log: {e}>"


def _make_tmpdir(prefix: str, owner: str | None = None) -> Path:
    """A fresh directory under the system temp dir, mode 0755, optionally chowned to ``owner``."""
    d = tempfile.mkdtemp(prefix=prefix)
    os.chmod(d, 0o755)
    if owner is not None:
        shutil.chown(d, user=owner, group=owner)
    _LIVE_DIRS.add(d)
    return Path(d)


def _remove_tmpdir(d: Path | None) -> None:
    if d is not None:
        shutil.rmtree(d, ignore_errors=True)
        _LIVE_DIRS.discard(str(d))


def _children(pid: int) -> list[int]:
    """Direct children of ``pid`` (from /proc; empty where there is no /proc)."""
    kids = []
    for stat in glob.glob("/proc/[0-9]*/stat"):
        try:
            with open(stat) as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if len(fields) > 1 and fields[1] == str(pid):
            kids.append(int(stat.split("/")[2]))
    return kids


def _stop_process(proc: subprocess.Popen | None, first_signal: int, tries: int = STOP_TRIES) -> None:
    """Send ``first_signal``, wait (bounded), then SIGKILL the process, its group and its children.

    The children matter for postgres: its backends call setsid(), so they are not in its group.
    """
    if proc is None:
        return
    if proc.poll() is None:
        try:
            proc.send_signal(first_signal)
        except ProcessLookupError:
            pass
        for _ in range(tries):
            if proc.poll() is not None:
                break
            time.sleep(STOP_PAUSE_S)
    if proc.poll() is None:  # still alive (once reaped, its pid may belong to someone else)
        children = _children(proc.pid)
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        for pid in children:
            try:
                os.kill(pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            pass
    _LIVE_PROCS.pop(proc.pid, None)


def _wait_ready(server, probe, errors, failure: str) -> None:
    """Call ``probe`` until it returns True (at most READY_TRIES times, ``errors`` meaning not yet), while the
    server process lives; otherwise stop the server and raise RuntimeError with ``failure`` and its log tail."""
    for _ in range(READY_TRIES):
        if server.proc.poll() is not None:
            break
        try:
            if probe():
                return
        except errors:
            pass
        time.sleep(READY_PAUSE_S)
    code = server.proc.poll()
    tail = _log_tail(server.log_path)
    server.stop()
    raise RuntimeError(f"{failure} (exit code {code}); log tail:\n{tail}")


def _run_as_kwargs() -> dict:
    """Popen arguments that drop to the postgres system user when we are root."""
    if os.geteuid() == 0:
        return {"user": PG_SYSTEM_USER, "group": PG_SYSTEM_USER, "extra_groups": []}
    return {}


# ----------------------------------------------------------------------------- discovery


def _redis_binary() -> str | None:
    return shutil.which("redis-server") or (
        "/usr/bin/redis-server" if os.access("/usr/bin/redis-server", os.X_OK) else None)


def _postgres_bindir() -> Path | None:
    """The newest /usr/lib/postgresql/<ver>/bin with initdb and postgres, else the one on PATH."""
    def version(p: str) -> tuple[int, ...]:
        m = re.search(r"/postgresql/([\d.]+)/bin$", p)
        return tuple(int(x) for x in m.group(1).split(".") if x) if m else ()

    for d in sorted(glob.glob("/usr/lib/postgresql/*/bin"), key=version, reverse=True):
        if all(os.access(os.path.join(d, b), os.X_OK) for b in ("initdb", "postgres")):
            return Path(d)
    initdb, postgres = shutil.which("initdb"), shutil.which("postgres")
    if initdb and postgres and os.path.dirname(initdb) == os.path.dirname(postgres):
        return Path(initdb).parent
    return None


def redis_available() -> bool:
    return _redis_binary() is not None


def postgres_available() -> bool:
    if _postgres_bindir() is None:
        return False
    if os.geteuid() == 0:
        import pwd
        try:
            pwd.getpwnam(PG_SYSTEM_USER)
        except KeyError:
            return False
    return True


# ----------------------------------------------------------------------------- Redis


class RedisServer:
    """``redis-server`` on a free 127.0.0.1 port in its own temp dir; no persistence unless ``appendonly``.

    ``appendonly=True``: an append-only file written on every command (``appendfsync always``), so that
    :meth:`restart` brings the server back with every message it held, as a production broker would.
    """

    def __init__(self, *, appendonly: bool = False) -> None:
        self.appendonly = appendonly
        self.port: int | None = None
        self.dir: Path | None = None
        self.proc: subprocess.Popen | None = None
        self.restarts = 0

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    @property
    def log_path(self) -> Path:
        assert self.dir is not None
        return self.dir / "redis.log"

    def start(self) -> Self:
        binary = _redis_binary()
        if binary is None:
            raise RuntimeError(f"redis-server not found; install it: {INSTALL_HINT}")
        if self.dir is None:                      # a first start (restart() keeps the directory and port)
            self.dir = _make_tmpdir("scanmill-redis-")
            self.port = _free_port()
        self._spawn(binary)
        return self

    def _spawn(self, binary: str) -> None:
        """Run redis-server on ``self.port`` in ``self.dir`` and wait (bounded) until it answers PING."""
        import redis

        persistence = (["--appendonly", "yes", "--appendfsync", "always", "--appendfilename", "broker.aof"]
                       if self.appendonly else ["--appendonly", "no"])
        with open(self.log_path, "ab") as log:
            self.proc = subprocess.Popen(
                [binary, "--port", str(self.port), "--bind", "127.0.0.1", "--dir", str(self.dir),
                 "--save", "", *persistence, "--daemonize", "no", "--logfile", ""],
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, cwd=self.dir,
                start_new_session=True)
        _LIVE_PROCS[self.proc.pid] = (self.proc, signal.SIGTERM)
        def ping() -> bool:
            client = redis.Redis(host="127.0.0.1", port=self.port, socket_connect_timeout=1, socket_timeout=1)
            try:
                return bool(client.ping())
            finally:
                client.close()

        _wait_ready(self, ping, redis.exceptions.RedisError, f"redis-server on port {self.port} never answered PING")

    def restart(self, down_s: float = 0.0) -> None:
        """Stop the server (SIGTERM: it flushes its append-only file), stay down ``down_s`` seconds, and start
        it again on the same port and directory (bounded waits). Only meaningful with ``appendonly=True``:
        without it the restarted server is empty."""
        binary = _redis_binary()
        assert binary is not None and self.dir is not None, "restart() needs a started server"
        _stop_process(self.proc, signal.SIGTERM)
        self.proc = None
        time.sleep(down_s)
        self._spawn(binary)                  # redis-server binds with SO_REUSEADDR: the same port is free again
        self.restarts += 1

    def stop(self) -> None:
        _stop_process(self.proc, signal.SIGTERM)
        self.proc = None
        _remove_tmpdir(self.dir)
        self.dir = None

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


# ----------------------------------------------------------------------------- PostgreSQL


class PostgresServer:
    """A throwaway PostgreSQL cluster (initdb + postgres) on a free 127.0.0.1 port.

    Superuser ``scanmill`` with trust authentication; :meth:`create_database` hands out fresh
    databases as SQLAlchemy URLs (``postgresql+psycopg://``).
    """

    def __init__(self) -> None:
        self.port: int | None = None
        self.dir: Path | None = None
        self.proc: subprocess.Popen | None = None
        self.databases: list[str] = []

    @property
    def data_dir(self) -> Path:
        assert self.dir is not None
        return self.dir / "data"

    @property
    def socket_dir(self) -> Path:
        assert self.dir is not None
        return self.dir / "socket"

    @property
    def log_path(self) -> Path:
        assert self.dir is not None
        return self.dir / "postgres.log"

    def url(self, dbname: str = "postgres") -> str:
        return f"postgresql+psycopg://{PG_USER}@127.0.0.1:{self.port}/{quote(dbname, safe='')}"

    def _connect(self, dbname: str = "postgres", **kwargs):
        import psycopg
        return psycopg.connect(host="127.0.0.1", port=self.port, user=PG_USER, dbname=dbname,
                               connect_timeout=2, **kwargs)

    def start(self) -> Self:
        bindir = _postgres_bindir()
        if bindir is None:
            raise RuntimeError(f"PostgreSQL (initdb, postgres) not found; install it: {INSTALL_HINT}")
        import psycopg

        as_user = _run_as_kwargs()
        self.dir = _make_tmpdir("scanmill-pg-", owner=PG_SYSTEM_USER if as_user else None)
        self.socket_dir.mkdir()
        if as_user:
            shutil.chown(self.socket_dir, user=PG_SYSTEM_USER, group=PG_SYSTEM_USER)
        with open(self.log_path, "wb") as log:
            init = subprocess.run(
                [str(bindir / "initdb"), "-D", str(self.data_dir), "-A", "trust", "-U", PG_USER,
                 "--no-sync", "-E", "UTF8"],
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, cwd=self.dir,
                timeout=300, check=False, **as_user)
        if init.returncode != 0:
            tail = _log_tail(self.log_path)
            self.stop()
            raise RuntimeError(f"initdb failed (exit code {init.returncode}); log tail:\n{tail}")

        self.port = _free_port()
        with open(self.log_path, "ab") as log:
            self.proc = subprocess.Popen(
                [str(bindir / "postgres"), "-D", str(self.data_dir), "-p", str(self.port),
                 "-k", str(self.socket_dir), "-c", "listen_addresses=127.0.0.1",
                 "-c", "fsync=off", "-c", "full_page_writes=off", "-c", "synchronous_commit=off"],
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, cwd=self.dir,
                start_new_session=True, **as_user)
        _LIVE_PROCS[self.proc.pid] = (self.proc, signal.SIGINT)
        def select_1() -> bool:
            with self._connect() as conn:
                conn.execute("SELECT 1")
            return True

        _wait_ready(self, select_1, psycopg.Error, f"postgres on port {self.port} never accepted connections")
        return self

    def create_database(self, name: str | None = None) -> str:
        """Create a fresh database (a random name if None) and return its SQLAlchemy URL."""
        from psycopg import sql

        if name is None:
            name = "t_" + secrets.token_hex(6)
        with self._connect(autocommit=True) as conn:
            conn.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(name)))
        self.databases.append(name)
        return self.url(name)

    def drop_database(self, name: str) -> None:
        """Drop a database, closing any connections still open to it."""
        from psycopg import sql

        with self._connect(autocommit=True) as conn:
            conn.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(name)))
        if name in self.databases:
            self.databases.remove(name)

    def stop(self) -> None:
        # SIGINT = PostgreSQL's "fast" shutdown: disconnect clients, checkpoint, exit
        _stop_process(self.proc, signal.SIGINT)
        self.proc = None
        _remove_tmpdir(self.dir)
        self.dir = None
        self.databases = []

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="session")
def redis_server():
    if not redis_available():
        pytest.fail(f"redis-server is not installed; these tests need a real Redis: {INSTALL_HINT}",
                    pytrace=False)
    with RedisServer() as server:
        yield server


@pytest.fixture(scope="session")
def postgres_server():
    if not postgres_available():
        pytest.fail("PostgreSQL (initdb, postgres"
                    + (f", and the '{PG_SYSTEM_USER}' system user" if os.geteuid() == 0 else "")
                    + f") is not installed; these tests need a real PostgreSQL: {INSTALL_HINT}",
                    pytrace=False)
    with PostgresServer() as server:
        yield server


@pytest.fixture
def redis_url(redis_server):
    """The session Redis, emptied (FLUSHALL) for this test."""
    import redis

    client = redis.Redis.from_url(redis_server.url)
    try:
        client.flushall()
    finally:
        client.close()
    yield redis_server.url


@pytest.fixture
def postgres_url(postgres_server):
    """A fresh database on the session PostgreSQL, dropped (connections closed) after the test."""
    name = "t_" + secrets.token_hex(6)
    url = postgres_server.create_database(name)
    yield url
    import psycopg

    try:
        postgres_server.drop_database(name)
    except psycopg.Error:  # best effort: the whole cluster goes at the end of the session anyway
        pass
