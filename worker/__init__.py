"""Lucent's Celery workers: thin tasks that call ``renderer.render.render_tile``.

``celery_app`` is the application, ``config`` its configuration, ``tasks`` the one task
(``render_pass``), ``runtime`` what each worker process keeps: the compiled-scene cache, the JIT
warm-up and the heartbeat.
"""
