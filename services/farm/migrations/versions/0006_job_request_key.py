"""A job's request key: the ``Idempotency-Key`` it was submitted with, scoped to its submitter
(``services.farm.records.request_key``), unique, so that a submission sent again finds the job
the first one made; and the digest of that request's body. NULL for a job submitted without one
(every job before this migration).

Revision ID: 0006
Revises: 0005
"""

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("request_key", sa.String(64)))
        batch.add_column(sa.Column("request_digest", sa.String(64)))
        batch.create_index("jobs_request_key", ["request_key"], unique=True)


def downgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.drop_index("jobs_request_key")
        batch.drop_column("request_digest")
        batch.drop_column("request_key")
