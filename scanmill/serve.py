"""``scanmill serve``: run the planning service (FastAPI under uvicorn) on the embedded defaults.

Defaults: SQLite job store and files under ``SCANMILL_DATA_DIR`` (``./scanmill-data``), local
worker processes, ``127.0.0.1:8000``. Settings come from ``SCANMILL_*`` variables and an optional
TOML/JSON file (``--config`` or ``SCANMILL_CONFIG``); the flags here win over both. One server per
data directory (a lock file enforces it); uvicorn runs one process, which holds the job runner.
"""

from __future__ import annotations

import logging
import sys


def serve(*, host: str | None = None, port: int | None = None, data_dir: str | None = None,
          workers: int | None = None, config: str | None = None, log_level: str | None = None) -> int:
    """Load the settings, build the app and serve it until interrupted. Returns an exit status."""
    from service.settings import SettingsError, load_settings
    from service.storage import Storage, StorageLocked

    try:
        settings = load_settings(config, host=host, port=port, data_dir=data_dir, workers=workers,
                                 log_level=log_level)
    except SettingsError as exc:
        print(f"error [invalid_settings]: {exc}", file=sys.stderr)
        return 2
    storage = Storage(settings.data_dir)
    try:                       # fail early and clearly if another server holds this data directory
        storage.open()
    except StorageLocked as exc:
        print(f"error [data_dir_locked]: {exc}", file=sys.stderr)
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
    print(f"scanmill serve: http://{settings.host}:{settings.port}  data: {settings.data_dir.resolve()}  "
          f"workers: {settings.workers}", file=sys.stderr, flush=True)
    app = create_app(settings)
    uvicorn.run(app, host=settings.host, port=settings.port, log_level=settings.log_level,
                timeout_graceful_shutdown=10, access_log=settings.log_level == "debug")
    return 0
