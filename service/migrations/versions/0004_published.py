"""The outbox's second mark: when the broker took a job's message.

``dispatched_at`` is set when an API takes a queued job for publication, before it sends the
message; ``published_at`` once the broker has accepted it. A job queued with the first and without
the second, for longer than ``SCANMILL_PUBLISH_GRACE_S``, was taken by an API that died (or lost the
database) between the two: the reaper clears the mark and publishes it again. Rows from before this
revision that were taken for publication are counted as published (they were, unless the API died in
that window, which nothing recorded).

Revision ID: 0004
Revises: 0003
"""

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as t:
        t.add_column(sa.Column("published_at", sa.Text))
    op.execute("UPDATE jobs SET published_at = dispatched_at WHERE dispatched_at IS NOT NULL")


def downgrade() -> None:
    with op.batch_alter_table("jobs") as t:
        t.drop_column("published_at")
