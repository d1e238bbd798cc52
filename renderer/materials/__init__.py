"""Scattering models, one file a family, dispatched by tag in ``bsdf.py`` (pbrt's Material list).

Every model answers pbrt's three questions in world space with the unit geometric normal ``n``
(outward for closed shapes) and ``wo`` pointing back along the path:
``eval`` → f(wo, wi)·|cos θi|, ``pdf`` → the density ``sample`` draws wi with, and ``sample`` →
(wi, f·|cos θi|/pdf, pdf, is_delta, ok).
"""
