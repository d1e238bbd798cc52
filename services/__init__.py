"""Lucent's FastAPI service and dashboard.

Not built yet: this package is the farm and dashboard issues'. Until then the main job is a local
render (``lucent render``, ``make demo``).
"""
