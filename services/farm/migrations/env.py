"""Alembic's environment for the job records (``services.farm.records``).

``Records.migrate`` runs it with a connection of its own in ``config.attributes["connection"]``
(inside a transaction that holds the migration lock); there is no ``alembic.ini``. To write a new
migration, copy the newest file of ``versions/`` and set its ``down_revision`` to that one's
``revision``.
"""

from alembic import context

connection = context.config.attributes["connection"]
context.configure(connection=connection, transactional_ddl=True)
with context.begin_transaction():
    context.run_migrations()
