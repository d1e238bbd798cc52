"""One file a migration, applied in ``down_revision`` order."""
