"""``scanmill worker``: a Celery worker that runs planning jobs for the distributed backend.

It reads the same ``SCANMILL_*`` settings as ``scanmill serve`` (``SCANMILL_BROKER_URL``,
``SCANMILL_DATABASE_URL``, ``SCANMILL_DATA_DIR`` naming the shared directory, ``SCANMILL_WORKERS``
jobs at once, ``SCANMILL_WORKER_THREADS`` BLAS threads per job). BLAS/OpenMP threads are pinned
before numpy is imported, then the planning modules are imported once in the main process so that
every child process the pool forks starts with them loaded; unless the numba cache holds their kernels
already, ``scanmill warmup`` compiles them first. ``scanmill db upgrade`` migrates the job database
without starting anything.
"""

from __future__ import annotations

import logging
import os
import socket
import sys


def run_worker(*, concurrency: int | None = None, name: str | None = None, config: str | None = None,
               log_level: str | None = None) -> int:
    """Start a Celery worker consuming the scanmill queue until it is stopped. Returns an exit status."""
    from service.settings import SettingsError, load_settings
    try:
        settings = load_settings(config, workers=concurrency, log_level=log_level)
    except SettingsError as exc:
        print(f"error [invalid_settings]: {exc}", file=sys.stderr)
        return 2
    if not settings.broker_url:
        print("error [invalid_settings]: scanmill worker needs SCANMILL_BROKER_URL (redis://HOST:PORT/DB)",
              file=sys.stderr)
        return 2
    from service.workers import PRELOAD, pin_thread_env
    pin_thread_env(settings.threads_per_job)          # before numpy is imported anywhere in this process
    logging.basicConfig(level=settings.log_level.upper(),
                        format="%(asctime)s %(levelname)s %(processName)s %(name)s: %(message)s")
    from service.db import DatabaseError, database_url
    from service.store import JobStore
    try:                                             # fail early and clearly: database reachable and migrated
        JobStore(database_url(settings.database_url, settings.data_dir)).close()
    except DatabaseError as exc:
        print(f"error [database_unavailable]: {exc}", file=sys.stderr)
        return 2
    if not settings.data_dir.is_dir():
        print(f"error [data_dir_missing]: the shared data directory {settings.data_dir} does not exist on this "
              "machine; mount it (SCANMILL_DATA_DIR) before starting the worker", file=sys.stderr)
        return 2
    import importlib
    for mod in PRELOAD:
        importlib.import_module(mod)
    from planning.warmup import is_warm
    if not is_warm():   # compile the kernels into the numba cache before taking jobs; in a process of its own,
        # so that this one (which the pool forks) never starts the OpenMP threads of a parallel kernel
        import subprocess
        print("scanmill worker: compiling the planning kernels first (scanmill warmup)", file=sys.stderr, flush=True)
        subprocess.run([sys.executable, "-m", "scanmill.cli", "warmup"], check=False)
    from service.celery_app import configure
    app = configure(settings)
    import service.celery_tasks  # noqa: F401 - registers the task
    node = name or f"scanmill-{os.getpid()}@{socket.gethostname()}"
    print(f"scanmill worker {node}: broker {_redact(settings.broker_url)}, queue {settings.celery_queue}, "
          f"{settings.workers} job(s) at once, {settings.threads_per_job} BLAS thread(s) each, files in "
          f"{settings.data_dir.resolve()}", file=sys.stderr, flush=True)
    argv = ["worker", "--pool=prefork", f"--concurrency={settings.workers}", f"--hostname={node}",
            f"--queues={settings.celery_queue}", f"--loglevel={settings.log_level.upper()}",
            "--without-gossip", "--without-mingle"]
    app.worker_main(argv)
    return 0


def upgrade_database(config: str | None = None) -> int:
    """Create or migrate the job database named by the settings to the newest schema."""
    from service.db import DatabaseError, current_revision, database_url, make_engine, upgrade
    from service.settings import SettingsError, load_settings
    try:
        settings = load_settings(config)
        engine = make_engine(database_url(settings.database_url, settings.data_dir))
        before = current_revision(engine)
        after = upgrade(engine)
    except (SettingsError, DatabaseError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"job database {engine.url.render_as_string(hide_password=True)}: revision {before or '(empty)'} -> "
          f"{after}")
    return 0


def _redact(url: str | None) -> str:
    from sqlalchemy.engine import make_url
    try:
        return make_url(url).render_as_string(hide_password=True) if url else "-"
    except Exception:  # noqa: BLE001
        return "(unparsable)"
