"""Distributed execution: which worker runs a job, its heartbeat, and when it was handed to the broker.

Revision ID: 0002
Revises: 0001
"""

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as t:
        t.add_column(sa.Column("worker", sa.Text))
        t.add_column(sa.Column("heartbeat_at", sa.Text))
        t.add_column(sa.Column("dispatched_at", sa.Text))
    op.create_index("jobs_status_heartbeat", "jobs", ["status", "heartbeat_at"])


def downgrade() -> None:
    op.drop_index("jobs_status_heartbeat", "jobs")
    with op.batch_alter_table("jobs") as t:
        t.drop_column("dispatched_at")
        t.drop_column("heartbeat_at")
        t.drop_column("worker")
