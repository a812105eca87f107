"""Quotas and retention: the bytes each job keeps stored, and indexes for the per-key sums and the sweep.

``stored_bytes`` is the size of a job's files (its upload; after success, upload and artifacts; 0 once
a cancelled job's files are freed). NULL for jobs accepted before this revision, until the
retention sweep measures them. ``jobs_owner_status`` serves the per-key count of queued and
running jobs and the per-key sum of stored bytes (from the index alone); ``jobs_finished_at`` the
retention sweep.

Revision ID: 0003
Revises: 0002
"""

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as t:
        t.add_column(sa.Column("stored_bytes", sa.BigInteger))
    op.create_index("jobs_owner_status", "jobs", ["owner", "status", "stored_bytes"])
    op.create_index("jobs_finished_at", "jobs", ["finished_at"])


def downgrade() -> None:
    op.drop_index("jobs_finished_at", "jobs")
    op.drop_index("jobs_owner_status", "jobs")
    with op.batch_alter_table("jobs") as t:
        t.drop_column("stored_bytes")
