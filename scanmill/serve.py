"""``scanmill serve``: run the planning service (FastAPI under uvicorn).

Defaults (embedded): SQLite job store and files under ``SCANMILL_DATA_DIR`` (``./scanmill-data``),
local worker processes, ``127.0.0.1:8000``; one server per data directory (a lock file enforces it).
With ``SCANMILL_BACKEND=celery`` the server only accepts and serves jobs: ``scanmill worker``
processes run them (see README, "Scale out"). Settings come from ``SCANMILL_*`` variables and an
optional TOML/JSON file (``--config`` or ``SCANMILL_CONFIG``); the flags here win over both.
"""

from __future__ import annotations

import logging
import sys


def serve(*, host: str | None = None, port: int | None = None, data_dir: str | None = None,
          workers: int | None = None, config: str | None = None, log_level: str | None = None) -> int:
    """Load the settings, build the app and serve it until interrupted. Returns an exit status."""
    from service.settings import SettingsError, load_settings
    from service.db import DatabaseError, database_url
    from service.storage import StorageLocked, open_storage
    from service.store import JobStore

    try:
        settings = load_settings(config, host=host, port=port, data_dir=data_dir, workers=workers,
                                 log_level=log_level)
    except SettingsError as exc:
        print(f"error [invalid_settings]: {exc}", file=sys.stderr)
        return 2
    storage = open_storage(settings.data_dir, settings.storage_kind)
    try:                       # fail early and clearly if another server holds this data directory
        storage.open()
        JobStore(database_url(settings.database_url, settings.data_dir)).close()   # reachable, migrated
    except StorageLocked as exc:
        print(f"error [data_dir_locked]: {exc}", file=sys.stderr)
        return 2
    except DatabaseError as exc:
        print(f"error [database_unavailable]: {exc}", file=sys.stderr)
        return 2
    finally:
        storage.close()
    import uvicorn

    from service.app import create_app
    from service.auth import is_loopback

    logging.basicConfig(level=settings.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if settings.anonymous:
        where = "loopback clients only" if is_loopback(settings.host) else \
            f"loopback clients only, although it listens on {settings.host}"
        print(f"warning: SCANMILL_API_KEYS is empty: no authentication; anonymous requests accepted from {where}",
              file=sys.stderr)
    runs = f"workers: {settings.workers}" if settings.backend == "embedded" else \
        f"backend: celery (queue {settings.celery_queue})"
    print(f"scanmill serve: http://{settings.host}:{settings.port}  data: {settings.data_dir.resolve()}  {runs}",
          file=sys.stderr, flush=True)
    app = create_app(settings)
    # proxy_headers=False: uvicorn would rewrite the client from X-Forwarded-For alone (and trust FORWARDED_ALLOW_IPS
    # from its own environment); service.auth.client_address applies the one rule instead, with
    # SCANMILL_FORWARDED_ALLOW_IPS, to Forwarded, X-Forwarded-For and X-Real-IP alike.
    uvicorn.run(app, host=settings.host, port=settings.port, log_level=settings.log_level,
                timeout_graceful_shutdown=10, access_log=settings.log_level == "debug", proxy_headers=False)
    return 0
