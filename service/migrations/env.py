"""Alembic environment of the job store: runs on the connection :func:`service.db.upgrade` hands in.

Run through ``scanmill db upgrade`` (or any start of the service or a worker); there is no
alembic.ini. Batch mode keeps ALTER TABLE working on SQLite.
"""

from alembic import context

from service.db import metadata

connection = context.config.attributes.get("connection")
if connection is None:  # pragma: no cover - only reachable from the alembic command line
    raise SystemExit("run the migrations with `scanmill db upgrade`, which connects to SCANMILL_DATABASE_URL")

context.configure(connection=connection, target_metadata=metadata, render_as_batch=True)
with context.begin_transaction():
    context.run_migrations()
