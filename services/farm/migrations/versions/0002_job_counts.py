"""Jobs counted by status in a table of their own, kept by triggers on ``jobs``.

A listing answers with the number of jobs that match; ``count(*)`` walks an index of every job
(about 50 ms at 100 000 jobs on SQLite), this reads one row. The triggers keep it right whatever
writes ``jobs``: an insert adds one to its status, a delete takes one away, a change of status
moves one.

Revision ID: 0002
Revises: 0001
"""

from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None

STATUSES = ("queued", "running", "done", "failed", "cancelled")

SQLITE_TRIGGERS = """
CREATE TRIGGER jobs_count_insert AFTER INSERT ON jobs BEGIN
  UPDATE job_counts SET n = n + 1 WHERE status = NEW.status;
END;
CREATE TRIGGER jobs_count_delete AFTER DELETE ON jobs BEGIN
  UPDATE job_counts SET n = n - 1 WHERE status = OLD.status;
END;
CREATE TRIGGER jobs_count_update AFTER UPDATE OF status ON jobs
WHEN OLD.status <> NEW.status BEGIN
  UPDATE job_counts SET n = n - 1 WHERE status = OLD.status;
  UPDATE job_counts SET n = n + 1 WHERE status = NEW.status;
END;
"""

POSTGRESQL_TRIGGER = """
CREATE FUNCTION jobs_count() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
  IF TG_OP = 'UPDATE' AND OLD.status = NEW.status THEN RETURN NULL; END IF;
  IF TG_OP IN ('UPDATE', 'DELETE') THEN
    UPDATE job_counts SET n = n - 1 WHERE status = OLD.status;
  END IF;
  IF TG_OP IN ('UPDATE', 'INSERT') THEN
    UPDATE job_counts SET n = n + 1 WHERE status = NEW.status;
  END IF;
  RETURN NULL;
END $$;
CREATE TRIGGER jobs_count AFTER INSERT OR DELETE OR UPDATE OF status ON jobs
FOR EACH ROW EXECUTE FUNCTION jobs_count();
"""


def upgrade() -> None:
    op.execute("CREATE TABLE job_counts (status VARCHAR(16) PRIMARY KEY, n BIGINT NOT NULL)")
    for status in STATUSES:
        op.execute(f"INSERT INTO job_counts (status, n) SELECT '{status}', count(*) FROM jobs "
                   f"WHERE status = '{status}'")
    if op.get_bind().dialect.name == "postgresql":
        op.execute(POSTGRESQL_TRIGGER)
    else:
        for statement in SQLITE_TRIGGERS.split("END;")[:-1]:
            op.execute(statement + "END;")


def downgrade() -> None:
    if op.get_bind().dialect.name == "postgresql":
        op.execute("DROP TRIGGER jobs_count ON jobs")
        op.execute("DROP FUNCTION jobs_count()")
    else:
        for name in ("insert", "delete", "update"):
            op.execute(f"DROP TRIGGER jobs_count_{name}")
    op.execute("DROP TABLE job_counts")
