"""Lucent's FastAPI service: ``main.py`` builds the app, ``api/`` holds the routes and their
dependencies, ``store.py`` the Redis job store, ``planner.py`` tiles × passes, ``merger.py`` the
exactly-once merge and the image; ``launcher.py`` and ``client.py`` back ``lucent up``/``demo``/
``worker``/``submit``. See docs/farm.md.
"""
