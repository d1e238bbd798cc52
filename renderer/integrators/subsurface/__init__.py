"""The translucent methods' transport, one file a method (as Mitsuba has one plugin a file).

``volumetric`` (the unbiased reference: a random walk in the medium), ``single_scatter`` (the
seed paper), ``diffuse_entry`` (the seed student project), ``backlight`` (the seed lecture) and
``diffusion`` (a BSSRDF with the Christensen–Burley profile). ``trace_path``
(``renderer/integrators/path.py``) calls each at the vertex where its method acts; the materials'
parameter rows are packed in ``renderer/materials/translucent.py`` and ``diffusion.py``. The
methods' pages: docs/methods/.
"""
