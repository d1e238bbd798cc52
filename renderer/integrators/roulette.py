"""Russian roulette: how a path of unlimited depth ends without bias.

From ``RR_DEPTH`` scattering events on, a path survives with probability
q = min(max(β)·Πη², cap) and carries β/q on. At surfaces the cap is ``RR_MAX`` = 0.95, as in
Mitsuba 3 (the η² undoes the radiance scaling of refraction: pbrt-v4's etaScale, Mitsuba's
``eta``); at medium events it is 1 (pbrt-v4's rule, so long walks in high-albedo media are not cut
short). So an unlimited ``max_depth`` (−1) stays unbiased.
"""

from __future__ import annotations

from renderer.integrators.sampler import draw
from renderer.jit import block, kernel

RR_DEPTH = 5
RR_MAX = 0.95  # at surfaces; inside media the survival probability is not capped (see there)


@kernel
def survive(br, bg, bb, eta_scale, cap, u):
    """Survive with q = min(max(β)·Πη², cap), then β/q. Returns (alive, β)."""
    q = min(max(br, bg, bb) * eta_scale, cap)
    if u >= q:
        return False, br, bg, bb
    return True, br / q, bg / q, bb / q


@block
def roulette(S, br, bg, bb, eta_scale, cap, depth, key, dim, sidx, sob):
    """The roulette after a vertex's ``depth``-th scattering event: (alive, β); no draw before
    ``RR_DEPTH``."""
    if depth < RR_DEPTH:
        return True, br, bg, bb
    return survive(br, bg, bb, eta_scale, cap, draw(S, key, dim, 6, sidx, sob))
