"""Alembic migrations of the job records (``services.farm.records``)."""
