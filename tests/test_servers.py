"""Quick checks of the throwaway Redis and PostgreSQL servers in servers.py."""

# The fixtures are imported by name, then requested as arguments (F401/F811 would flag both).
# ruff: noqa: F811

from __future__ import annotations

import os

import redis
import sqlalchemy as sa
from servers import RedisServer, postgres_server, postgres_url, redis_server, redis_url  # noqa: F401

KEY = "scanmill-test-servers-key"


def test_redis_set_get(redis_url):
    client = redis.Redis.from_url(redis_url)
    try:
        assert client.dbsize() == 0
        client.set(KEY, b"value")
        assert client.get(KEY) == b"value"
    finally:
        client.close()


def test_redis_flushed_between_tests(redis_url):
    # runs after test_redis_set_get: its key must be gone
    client = redis.Redis.from_url(redis_url)
    try:
        assert client.get(KEY) is None
        assert client.dbsize() == 0
    finally:
        client.close()


def test_redis_server_stops_cleanly():
    with RedisServer() as server:
        pid, tmpdir = server.proc.pid, server.dir
        assert redis.Redis.from_url(server.url).ping()
    assert not tmpdir.exists()
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        pass
    else:
        raise AssertionError(f"redis-server {pid} still running after stop()")


def test_postgres_roundtrip(postgres_url):
    assert postgres_url.startswith("postgresql+psycopg://scanmill@127.0.0.1:")
    engine = sa.create_engine(postgres_url)
    try:
        with engine.begin() as conn:
            conn.execute(sa.text("CREATE TABLE t (id integer PRIMARY KEY, name text NOT NULL)"))
            conn.execute(sa.text("INSERT INTO t VALUES (1, 'one'), (2, 'two')"))
        with engine.connect() as conn:
            rows = conn.execute(sa.text("SELECT id, name FROM t ORDER BY id")).all()
        assert [tuple(r) for r in rows] == [(1, "one"), (2, "two")]
    finally:
        engine.dispose()


def test_postgres_databases_are_distinct(postgres_server, postgres_url):
    other_url = postgres_server.create_database()
    assert other_url != postgres_url
    a, b = sa.create_engine(postgres_url), sa.create_engine(other_url)
    try:
        with a.begin() as conn:
            conn.execute(sa.text("CREATE TABLE only_in_a (x integer)"))
        with a.connect() as conn:
            assert conn.execute(sa.text("SELECT current_database()")).scalar() in postgres_url
        with b.connect() as conn:
            assert conn.execute(sa.text("SELECT to_regclass('only_in_a')")).scalar() is None
            assert conn.execute(sa.text("SELECT current_database()")).scalar() in other_url
    finally:
        a.dispose()
        b.dispose()
