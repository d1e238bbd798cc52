"""Lucent's Celery workers: thin tasks that call ``renderer.render.render_tile``.

Not built yet: this package is the farm issue's. The renderer's interface it will call —
``render_tile`` and ``SampleBuffer`` — is in ``renderer/``.
"""
