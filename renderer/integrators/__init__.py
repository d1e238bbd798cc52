"""Light transport algorithms: unidirectional path tracing (``path.py``)."""
