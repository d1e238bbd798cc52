"""The jobs table: one row a job, with the indexes that listing, filtering, retention and the
blob store's use counts read.

Revision ID: 0001
Revises: none
"""

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "jobs",
        sa.Column("id", sa.String(32), primary_key=True),
        sa.Column("name", sa.String(200), nullable=False),
        sa.Column("status", sa.String(16), nullable=False),
        sa.Column("priority", sa.Integer, nullable=False),
        sa.Column("submitter", sa.String(200)),
        *(sa.Column(name, sa.Integer, nullable=False)
          for name in ("width", "height", "spp", "tile_size", "spp_per_pass",
                       "max_spp_per_pass", "tasks_total", "tasks_merged")),
        sa.Column("samples_merged", sa.BigInteger, nullable=False),
        sa.Column("dropped", sa.BigInteger, nullable=False),
        sa.Column("version", sa.Integer, nullable=False),
        sa.Column("created_at", sa.Double, nullable=False),
        sa.Column("started_at", sa.Double),
        sa.Column("finished_at", sa.Double),
        sa.Column("error", sa.Text),
        sa.Column("methods", sa.Text, nullable=False),
        sa.Column("tiles", sa.Text),
        sa.Column("image_exr", sa.String(71)),
        sa.Column("image_png", sa.String(71)),
        sa.Column("archived_at", sa.Double),
        sa.Column("image_bytes", sa.BigInteger, nullable=False, server_default="0"),
        sa.Column("image_removed_at", sa.Double),
        sa.Column("state_blob", sa.String(71)),
    )
    # newest first, whole list and by status (the id breaks ties: a stable page order)
    op.create_index("jobs_created_at", "jobs", ["created_at", "id"])
    op.create_index("jobs_status_created_at", "jobs", ["status", "created_at", "id"])
    # retention: finished before a date
    op.create_index("jobs_finished_at", "jobs", ["finished_at"])
    # whether another job's image is the same blob, before the blob is deleted
    op.create_index("jobs_image_exr", "jobs", ["image_exr"])
    op.create_index("jobs_image_png", "jobs", ["image_png"])
    op.create_index("jobs_state_blob", "jobs", ["state_blob"])


def downgrade() -> None:
    op.drop_table("jobs")
