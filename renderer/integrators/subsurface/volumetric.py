"""The volumetric method: a homogeneous medium behind the boundary, walked event by event.

A ``translucent`` material with ``method: volumetric`` is a homogeneous medium behind a dielectric
(or, at ior 1, index-matched) boundary (the boundary is the BSDF's: ``renderer.materials.bsdf``).
Inside, free flights are sampled from exp(−σt·s) with the grey σt = density, each scattering event
weights the path by the albedo and samples the Henyey–Greenstein phase function (Mitsuba 3's
volpath, analogue sampling). Behind an index-matched boundary, scattering events also take a
light sample, whose shadow ray carries the medium's transmittance; behind a refracting boundary
they cannot (the boundary is a delta BSDF). The seed paper's single-scatter medium is walked here
too, ended after its one event (``renderer/integrators/subsurface/single_scatter.py``).

A chromatic medium (σt per channel) samples each flight from one channel's exponential, the
channel chosen in proportion to the path's throughput in it times its mean free path, and
weights every channel by the balance heuristic over the three (one-sample MIS over the
channels: the estimator's density is the mixture Σ_c P_c σt_c e^{−σt_c s}, as pbrt-v4's
VolPathIntegrator does over its wavelengths): a scattering event at s multiplies channel k by
σs_k e^{−σt_k s} / Σ_c P_c σt_c e^{−σt_c s}, a flight that reaches the surface at t by
e^{−σt_k t} / Σ_c P_c e^{−σt_c t}. Every channel stays unbiased whichever is sampled (any shares
do that are positive where the throughput is); a channel whose throughput has died is never
sampled, and one whose throughput grows is sampled more (roulette takes the largest).
"""

from __future__ import annotations

import math

from renderer.integrators.direct import medium_direct
from renderer.integrators.roulette import roulette
from renderer.integrators.sampler import draw
from renderer.jit import block, kernel
from renderer.materials.bsdf import SINGLE_SCATTER
from renderer.materials.phase import hg_sample
from renderer.materials.translucent import ALBEDO, CHROMATIC, DENSITY, IOR, SIGMA_T, G

# What a segment inside a medium ended in
SURFACE = 0  # the free flight reached the surface: the path goes on there
SCATTERED = 1  # a scattering event: the path goes on from it
ENDED = 2  # the path ends (the depth limit, roulette)

ONE_MINUS_EPS = 1.0 - 2.0**-53  # the largest float below 1


@kernel
def channel_probabilities(br, bg, bb, sr, sg, sb):
    """The chance that a chromatic flight is sampled from each channel: in proportion to the
    path's throughput β in it times its mean free path 1/σt (a channel that carries nothing is
    never sampled); uniform when that is not a usable weight.

    Why the mean free path: a flight of the sparse channel k (small σt_k) that another channel c
    would rarely sample has MIS weight e^{−σt_k s}/Σ P_c e^{−σt_c s} up to 1/P_k, growing with s,
    while a dense channel's weight under the sparse one's flights stays below σt_max/σt_min; so
    the sparse channel's share is what bounds the heavy weights. Measured against the per-channel
    split render at equal spp (``python -m bench.chromatic_split``, docs/methods/volumetric.md):
    MSE ratio 1.07 on the chromatic wax and 1.47 on the jade slab, against 1.23 and 2.1 with
    shares in proportion to β alone (pbrt-v4's VolPathIntegrator samples its hero wavelength)."""
    wr, wg, wb = br / sr, bg / sg, bb / sb
    total = wr + wg + wb
    if not (total > 0.0 and total < math.inf):
        return 1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0
    return wr / total, wg / total, wb / total


@kernel
def chromatic_flight(sr, sg, sb, pr, pg, pb, u):
    """A free-flight distance from the mixture Σ_c P_c σt_c e^{−σt_c s}: u picks the channel,
    then, rescaled within the channel's share, its exponential (one random number, stratified)."""
    if u < pr:
        lo, pc, sigma = 0.0, pr, sr
    elif u < pr + pg or pb == 0.0:
        lo, pc, sigma = pr, pg, sg
    else:
        lo, pc, sigma = pr + pg, pb, sb
    v = min(max((u - lo) / pc, 0.0), ONE_MINUS_EPS)
    return -math.log(1.0 - v) / sigma


@kernel
def pass_weights(sr, sg, sb, pr, pg, pb, t):
    """Each channel's weight for a chromatic flight that passed distance t: its transmittance over
    the mixture's probability of passing t (0 when even that underflows)."""
    er, eg, eb = math.exp(-sr * t), math.exp(-sg * t), math.exp(-sb * t)
    q = pr * er + pg * eg + pb * eb
    if not q > 0.0:
        return 0.0, 0.0, 0.0
    return er / q, eg / q, eb / q


@kernel
def event_weights(sr, sg, sb, ar, ag, ab, pr, pg, pb, s):
    """Each channel's weight for a chromatic flight that scattered at s: σs e^{−σt s} over the
    mixture's density at s (0 when that underflows)."""
    er, eg, eb = math.exp(-sr * s), math.exp(-sg * s), math.exp(-sb * s)
    q = pr * sr * er + pg * sg * eg + pb * sb * eb
    if not q > 0.0:
        return 0.0, 0.0, 0.0
    return ar * sr * er / q, ag * sg * eg / q, ab * sb * eb / q


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
    chromatic = mm[CHROMATIC] > 0.0
    u = draw(S, key, dim, 7, sidx, sob)
    pr = pg = pb = 0.0
    if chromatic:
        pr, pg, pb = channel_probabilities(br, bg, bb, mm[SIGMA_T], mm[SIGMA_T + 1],
                                           mm[SIGMA_T + 2])
        s_flight = chromatic_flight(mm[SIGMA_T], mm[SIGMA_T + 1], mm[SIGMA_T + 2], pr, pg, pb, u)
    else:
        s_flight = -math.log(1.0 - u) / mm[DENSITY]
    if not s_flight < t:
        if chromatic:
            w = pass_weights(mm[SIGMA_T], mm[SIGMA_T + 1], mm[SIGMA_T + 2], pr, pg, pb, t)
            br, bg, bb = br * w[0], bg * w[1], bb * w[2]
        return (SURFACE, o, d, depth, unweighted, prev_pdf, prev_p, single_done, lr, lg, lb, br,
                bg, bb)
    if max_depth >= 0 and depth >= max_depth:
        return (ENDED, o, d, depth, unweighted, prev_pdf, prev_p, single_done, lr, lg, lb, br, bg,
                bb)
    p = (o[0] + s_flight * d[0], o[1] + s_flight * d[1], o[2] + s_flight * d[2])
    if chromatic:
        w = event_weights(mm[SIGMA_T], mm[SIGMA_T + 1], mm[SIGMA_T + 2], mm[ALBEDO],
                          mm[ALBEDO + 1], mm[ALBEDO + 2], pr, pg, pb, s_flight)
        br, bg, bb = br * w[0], bg * w[1], bb * w[2]
        if not (br > 0.0 or bg > 0.0 or bb > 0.0):
            return (ENDED, o, d, depth, unweighted, prev_pdf, prev_p, single_done, lr, lg, lb,
                    br, bg, bb)
    else:
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
