"""The volumetric method: a homogeneous medium behind the boundary, walked event by event.

A ``translucent`` material with ``method: volumetric`` is a homogeneous medium behind a dielectric
(or, at ior 1, index-matched) boundary (the boundary is the BSDF's: ``renderer.materials.bsdf``).
Inside, free flights are sampled from exp(−σt·s) with the grey σt = density, each scattering event
weights the path by the albedo and samples the Henyey–Greenstein phase function (Mitsuba 3's
volpath, analogue sampling). Behind an index-matched boundary, scattering events also take a
light sample, whose shadow ray carries the medium's transmittance; behind a refracting boundary
they cannot (the boundary is a delta BSDF). The seed paper's single-scatter medium is walked here
too, ended after its one event (``renderer/integrators/subsurface/single_scatter.py``).
"""

from __future__ import annotations

import math

from renderer.integrators.direct import medium_direct
from renderer.integrators.roulette import roulette
from renderer.integrators.sampler import draw
from renderer.jit import block
from renderer.materials.bsdf import SINGLE_SCATTER
from renderer.materials.phase import hg_sample
from renderer.materials.translucent import ALBEDO, DENSITY, IOR, G

# What a segment inside a medium ended in
SURFACE = 0  # the free flight reached the surface: the path goes on there
SCATTERED = 1  # a scattering event: the path goes on from it
ENDED = 2  # the path ends (the depth limit, roulette)


@block
def medium_segment(S, medium, t, o, d, depth, unweighted, prev_pdf, prev_p, single_done, lr, lg,
                   lb, br, bg, bb, eta_scale, max_depth, key, dim, sidx, sob, stack):
    """A segment from o along d inside ``medium``, whose boundary is t away: a free flight from
    exp(−σt·s), and, if it ends first, a scattering event there (albedo, a light sample where one
    can leave the medium, the phase function's direction, roulette). Returns the event and the
    path's state after it: (event, o, d, depth, unweighted, prev_pdf, prev_p, single_done,
    lr, lg, lb, br, bg, bb); past the surface (P(s ≥ t) = exp(−σt t) = Tr(t), weight 1) the
    state is unchanged."""
    mm = S.mat_param[medium]
    single = S.mat_kind[medium] == SINGLE_SCATTER
    s_flight = -math.log(1.0 - draw(S, key, dim, 7, sidx, sob)) / mm[DENSITY]
    if not s_flight < t:
        return (SURFACE, o, d, depth, unweighted, prev_pdf, prev_p, single_done, lr, lg, lb, br,
                bg, bb)
    if max_depth >= 0 and depth >= max_depth:
        return (ENDED, o, d, depth, unweighted, prev_pdf, prev_p, single_done, lr, lg, lb, br, bg,
                bb)
    p = (o[0] + s_flight * d[0], o[1] + s_flight * d[1], o[2] + s_flight * d[2])
    # σs/σt = albedo: the grey free flight leaves only the albedo as weight
    br *= mm[ALBEDO]
    bg *= mm[ALBEDO + 1]
    bb *= mm[ALBEDO + 2]
    g = mm[G]
    # A light sample from inside: behind an index-matched boundary (or the seed paper's)
    lit = (mm[IOR] == 1.0 or single) and S.light_kind.shape[0] > 0
    if lit:
        c = medium_direct(S, p, d, g, medium, br, bg, bb, key, dim, sidx, sob, stack)
        lr += c[0]
        lg += c[1]
        lb += c[2]
    wi, pdf = hg_sample(d, g, draw(S, key, dim, 3, sidx, sob), draw(S, key, dim, 4, sidx, sob))
    depth += 1
    # No cap below 1 in a medium: at albedo 0.999 a walk needs hundreds of events, and a 0.95 cap
    # would make their weight heavy-tailed (1/0.95^k) for nothing; the albedo itself brings β
    # and so the survival probability down.
    alive, br, bg, bb = roulette(S, br, bg, bb, eta_scale, 1.0, depth, key, dim, sidx, sob)
    event = SCATTERED if alive else ENDED
    return event, p, wi, depth, not lit, pdf, p, single, lr, lg, lb, br, bg, bb
