"""The farm's core: settings, job store, planner, merge and stall rules, cost, Celery config, queue.

Imported by the API (``services.api``) and the worker (``worker``); imports only ``renderer``.
"""
