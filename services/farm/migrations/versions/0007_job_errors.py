"""A job's target and expected error as columns: ``target_error``, ``expected_error``,
``expected_bias``, ``denoise``. Before, a job out of Redis kept them only in its ``tiles`` JSON
(kilobytes a job), which a listing's page does not read: ``GET /api/jobs`` listed every archived
job with its target and error null and ``denoise`` false while its detail gave them. The rows
that have that JSON (archived jobs) take them from it; the others are written as their jobs
are (``services.farm.records._progress``). A parked job's JSON never held them: its row keeps
them NULL until it is parked again.

Revision ID: 0007
Revises: 0006
"""

import json

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None

COLUMNS = ("target_error", "expected_error", "expected_bias", "denoise")
# rows read and written at a time, by id
BATCH = 500


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        for name in COLUMNS[:3]:
            batch.add_column(sa.Column(name, sa.Double))
        batch.add_column(sa.Column("denoise", sa.Boolean))
    jobs = sa.table("jobs", sa.column("id", sa.String), sa.column("tiles", sa.Text),
                    *(sa.column(name, sa.Double) for name in COLUMNS[:3]),
                    sa.column("denoise", sa.Boolean))
    conn = op.get_bind()
    after = ""
    while True:
        rows = conn.execute(sa.select(jobs.c.id, jobs.c.tiles)
                            .where(jobs.c.tiles.is_not(None), jobs.c.id > after)
                            .order_by(jobs.c.id).limit(BATCH)).all()
        if not rows:
            return
        values = []
        for job_id, tiles in rows:
            final = json.loads(tiles)
            kept = {name: final.get(name) for name in COLUMNS[:3]}
            if any(v is not None for v in kept.values()) or final.get("denoise"):
                values.append({"key": job_id, **kept, "denoise": bool(final.get("denoise"))})
        if values:
            conn.execute(sa.update(jobs).where(jobs.c.id == sa.bindparam("key")), values)
        after = rows[-1][0]


def downgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        for name in reversed(COLUMNS):
            batch.drop_column(name)
