"""Adaptive sampling to a frame error: ``render.target_error`` is the frame's expected relMSE.

**The error.** For a pixel estimate I (RGB) of the true value R, the chart suite's relative MSE
(``bench.accuracy.rel_mse``) is the mean over pixels and channels of

    (I_c − R_c)² / (R_c² + ε),   ε = 0.01,

and ``render.target_error`` asks that its expectation over the frame be at most the target. With
n_p independent samples of per-sample variance s²_pc, pixel p contributes Var[I_pc] = s²_pc / n_p,
so the frame's expected relMSE is

    E = (1/P) Σ_p v_p / n_p,   v_p = (1/3) Σ_c s²_pc / (m_pc² + ε),

v_p a pixel's per-sample relative variance (m its mean standing in for R).

**The allocation.** For a given total Σ n_p the n_p that minimise E are n_p ∝ √v_p (Lagrange:
∂/∂n_p [v_p/n_p + λ n_p] = 0); for a given time, with c_p a sample's cost at p (path segments,
``sample_cost``), n_p ∝ √(v_p / c_p). So the frame reaches E = T in the least time at

    n_p = λ √(v_p / c_p),

clamped to [samples it already has, ``render.spp``] (``allocate`` solves for λ with the clamps,
by bisection: E is monotone in it). The earlier rule (every pixel below the target on its own,
n_p ∝ v_p) spent most samples on the noisiest pixels and overshot the target 3–25×.

**No low bias.** A pixel's own samples never decide how many samples it gets: the ``v_p`` and
``c_p`` that shape the counts are estimated from the other 24 pixels of its 5×5 neighbourhood
(``neighbour_variance``, ``sample_cost``), so n_p is independent of the samples averaged into I_p
and the mean of a number of independent samples fixed by other pixels' samples stays unbiased.
Stopping each pixel on its own variance biases heavy-tailed pixels low (a pixel whose rare bright
path has not come yet looks converged and stops with it missing): measured 1.4–3.8 % low on the
backlit slab with the earlier rule; ``tests/renderer/film/test_adaptive.py`` shows the own-sample
rule biased and this one not on a heavy-tailed synthetic frame. (The floor of the shaping
estimate, a tenth of the frame's mean, the scale λ and the frame's stop below hold each pixel's
samples as one of P.)

**The error estimate.** The frame's error is estimated from each pixel's *own* samples
(``sample_variance``): Σ s²_p / n_p with s²_p its sample variance, unbiased because n_p does not
depend on them (the same independence the image's mean needs). Not from the neighbour estimate
that shapes the counts: a pixel's count grows with that estimate, so Σ ṽ_p / n_p over the same ṽ
weighs each pixel by an estimate that chose its count, and where the estimate is noisy (rare
bright paths, seen in some windows and not in others) it comes out low: 1.65× low at target
0.01 on the caustic floor, which an ad-hoc correction for few samples (1 + 3/√n, as this rule
had) did not follow from scene to scene.

**Pilot, rounds, stop.** Every pixel first takes ``PILOT`` samples, in two passes: after the
first ``FIRST_LOOK`` the loop stops where the frame's estimated error plus ``FIRST_LOOK_Z``
standard errors of it over the pixels is within the aim and at least ``FIRST_LOOK_PIXELS``
pixels carry it (``first_look_reached``; at 4 samples a pixel the estimate alone is low in some
runs where a few pixels' rare bright paths carry it).
Then before every pass the
allocation is recomputed from all the samples so far, a round adding at most as much work as the
frame has had, the first round after the pilot evenly (every pixel the same count: the pilot's
estimates do not yet shape the counts), a later round shaped only where the shape, priced by
each pixel's own variance, reaches the aim with less work than even counts would
(``shape_pays``: a cross-validation of the neighbour estimate; else that round is even too);
the render stops when the estimated error is within
``STOP_SLACK`` of ``AIM`` × target (``stopping_error``; calibrated by ``python -m
bench.target_error``: docs/adaptive-sampling.md).

The farm uses the same rule on a tile's merged buffer (``pass_counts``), a pure function of it
and of the frame's scale λ, estimated error and first-look bound, which the merge keeps up to
date from every tile's summary (``tile_summary``, ``frame_scale``, ``first_look_bound``), and
stops as the loop does (at the first look, on the tile's own bound until every tile has one;
at the end of the pilot, on the frame's estimate there, or takes the loop's even round).
"""

from __future__ import annotations

import math

import numpy as np

from renderer.film.buffer import SampleBuffer
from renderer.jit import inline_kernel, kernel

EPSILON = 0.01
# Samples every pixel takes before any allocation (the pilot); the variance estimates of the
# first allocation pool 24 neighbours × PILOT samples.
PILOT = 8
# The pilot's first half, after which the loop may stop where the estimate is known well enough
# (``first_look_reached``): its upper bound, FIRST_LOOK_Z standard errors over the pixels' terms
# above it, within the aim
FIRST_LOOK = 4
FIRST_LOOK_Z = 2.0
# ... where at least this many pixels carry the estimate: the effective number (Σ e)² / Σ e² of
# its terms e (a normal approximation of their mean is not trusted on fewer)
FIRST_LOOK_PIXELS = 30
# The allocation aims at AIM × target: achieved/target measured over the chart suite and the
# targets 0.1 … 0.002 (python -m bench.target_error; docs/adaptive-sampling.md).
AIM = 0.8
# The variance estimate's neighbourhood (a (2·RADIUS+1)² window without the pixel) and its floor
# (a fraction of the buffer's mean variance): neighbour_variance.
RADIUS = 2
FLOOR = 0.1
# Halvings of the allocation's scale once bracketed within a factor 2: the scale to 2⁻¹³ of
# itself, so no pixel's count is more than ~n/8000 above the least that meets the target (one
# sample at most below 8000 samples).
BISECTIONS = 12
# Halvings of [0, scale] for a round's budget (a round's size needs no finer grain)
BUDGET_BISECTIONS = 12
# The loop stops once the frame's estimated error is within STOP_SLACK of the aim
# (sample_to_target): a round to close a smaller gap costs a pass and a round's bookkeeping and
# changes the error by less than the estimate's own noise
STOP_SLACK = 0.05
# A sample's cost besides its path segments (the camera ray, the pixel's bookkeeping), in
# segments (sample_cost)
SEGMENT_OVERHEAD = 1.0


@kernel
def _window_sums_kernel(values, radius, rows, out):
    """Σ of ``values`` (h, w, c), C-contiguous, over each pixel's (2r+1)² window less the pixel
    itself (zero outside the frame) into ``out`` (h, w, c); ``rows`` (h, w, c) is scratch.
    Separable (along each row the window less its centre column, then down each column the full
    rows above and below and the centre row less its centre: 4r additions a value, not
    (2r+1)² − 1) and without a subtraction, so a pixel's own value never enters its sum, not
    even as a rounding residue: a firefly's variance cannot leak into its own estimate or wipe
    out its neighbours' small ones. Each row is one run of w·c values, an offset at a time, so
    the additions vectorise (on 1-D row views from 0: indexing the 2-D arrays at an offset, they
    did not, 2.4x slower on a 64×48 frame of 9 channels); every sum still adds its terms in
    window order."""
    h, w, channels = values.shape
    n = w * channels
    flat = values.reshape((h, n))
    row_sums = rows.reshape((h, n))
    sums = out.reshape((h, n))
    for y in range(h):
        src = flat[y]
        dst = row_sums[y]
        for j in range(n):
            dst[j] = 0.0
        for d in range(-radius, radius + 1):
            if d != 0:
                lo = max(0, -d) * channels
                hi = min(w, w - d) * channels
                into = dst[lo:hi]
                add = src[lo + d * channels:hi + d * channels]
                for j in range(hi - lo):
                    into[j] += add[j]
    for y in range(h):
        dst = sums[y]
        for j in range(n):
            dst[j] = 0.0
        for yy in range(max(0, y - radius), min(h, y + radius + 1)):
            row = row_sums[yy]
            if yy != y:
                own = flat[yy]
                for j in range(n):
                    dst[j] += row[j]
                    dst[j] += own[j]
            else:
                for j in range(n):
                    dst[j] += row[j]


def _moments(buf: SampleBuffer) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel: the mean (h, w, 3), the per-sample variance s² (h, w, 3), and whether the pixel
    has at least 2 samples (h, w)."""
    n = buf.count.astype(np.float64)[..., None]
    ok = buf.count >= 2
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = np.where(ok[..., None], buf.sum / n, 0.0)
        s2 = np.where(ok[..., None],
                      np.maximum(buf.sum_sq - n * mean * mean, 0.0) / (n - 1), 0.0)
    return mean, s2, ok


@kernel
def _pixel_moments(sums, sums_sq, count, moments):
    """``_moments`` into ``moments`` (h, w, 7): each pixel's s² per channel (0–2), its mean
    (3–5) and a 1 (6) where it has 2 samples, zeros where not."""
    h, w = count.shape
    for y in range(h):
        for x in range(w):
            n = count[y, x]
            for c in range(7):
                moments[y, x, c] = 0.0
            if n >= 2:
                for c in range(3):
                    m = sums[y, x, c] / n
                    moments[y, x, c] = max(sums_sq[y, x, c] - n * m * m, 0.0) / (n - 1)
                    moments[y, x, 3 + c] = m
                moments[y, x, 6] = 1.0


@kernel
def _sample_variance_kernel(sums, sums_sq, count, eps, moments, means, rows, window, out):
    """``sample_variance`` in one kernel instead of the dozen numpy passes it took: each pixel's
    moments (``_pixel_moments``), the sums of their means and flags over its 3×3 window less
    itself (``_window_sums_kernel`` of the four, not the variances it does not need), then
    v = mean_c s²_c / (m̃_c² + eps), m̃ the neighbours' mean, into ``out`` (NaN below 2 samples).
    ``moments`` (h, w, 7), ``means``, ``rows`` and ``window`` (h, w, 4) are scratch. Returns the
    frame's sums the loop decides on in the same pass (``error_sums``): Σ e_p and Σ e_p² of the
    error terms e_p = v_p / n_p (``error_terms``: 0 below 2 samples) and Σ v_p over the pixels
    where v_p is finite and > 0 (what ``allocate`` sums for even counts)."""
    h, w = count.shape
    _pixel_moments(sums, sums_sq, count, moments)
    for y in range(h):
        for x in range(w):
            for c in range(4):
                means[y, x, c] = moments[y, x, 3 + c]
    _window_sums_kernel(means, 1, rows, window)
    err_sum = 0.0
    err_sq_sum = 0.0
    v_sum = 0.0
    for y in range(h):
        for x in range(w):
            if count[y, x] < 2:
                out[y, x] = np.nan
                continue
            k = window[y, x, 3]
            v = 0.0
            for c in range(3):
                d = window[y, x, c] / k if k > 0.0 else moments[y, x, 3 + c]
                v += moments[y, x, c] / (d * d + eps)
            v /= 3.0
            out[y, x] = v
            if math.isfinite(v):
                e = v / count[y, x]
                err_sum += e
                err_sq_sum += e * e
                if v > 0.0:
                    v_sum += v
    return err_sum, err_sq_sum, v_sum


def sample_variance(buf: SampleBuffer) -> np.ndarray:
    """Each pixel's per-sample relative variance from its own samples, v_p = mean_c s²_c /
    (m̃_c² + ε), (h, w), NaN below 2 samples; m̃ the mean of its eight neighbours' means (its own
    where it has none): what ``expected_error`` reports with.

    Not the pixel's own mean in the denominator: a pixel whose few samples hold one bright outlier
    has a large own mean, which would divide its large variance away (with its own mean the frame
    estimate came out 2–13× low at 16 spp on the chart suite; with the neighbours', within
    0.8–1.4× of the error against the reference at 16–1024 spp, conservative at low counts)."""
    return error_sums(buf)[0]


def error_sums(buf: SampleBuffer) -> tuple[np.ndarray, float, float, float]:
    """``sample_variance`` and, from the same pass over the buffer, the sums the local loop
    decides on: (v, Σ e_p, Σ e_p², Σ v_p), e_p the ``error_terms`` (their mean is the frame's
    estimated error, ``stopping_error``; the two sums are ``first_look_bound``'s) and Σ v_p over
    the pixels where it is finite and > 0 (an even round's ``allocate``). The sums are added in
    pixel order, not numpy's pairwise order: they agree with ``error_terms(buf).sum()`` and the
    rest to rounding. One kernel call where the loop took a dozen numpy passes a round: on the
    diffuse Cornell box at 64×48 and target 0.03 (three passes, 9 ms) the loop's time outside
    its passes went from 0.89-1.02 to 0.59-0.71 ms a frame (scratch, three runs of 100 each)."""
    h, w = buf.count.shape
    out = np.empty((h, w))
    sums = _sample_variance_kernel(np.ascontiguousarray(buf.sum, np.float64),
                                   np.ascontiguousarray(buf.sum_sq, np.float64),
                                   np.ascontiguousarray(buf.count, np.int64), EPSILON,
                                   np.empty((h, w, 7)), np.empty((h, w, 4)),
                                   np.empty((h, w, 4)), np.empty((h, w, 4)), out)
    return out, float(sums[0]), float(sums[1]), float(sums[2])


@kernel
def _neighbour_variance_kernel(sums, sums_sq, count, segments, radius, eps, moments, rows,
                               window, out_v, out_k, out_cost, out_ck):
    """``shape_estimates`` before their fallbacks and floor, in one kernel instead of the dozen
    numpy passes each took: each pixel's moments (``_pixel_moments``), its path segments a
    sample and a 1 where it has a sample (channels 7, 8; ``segments`` zeros where the buffer has
    none), their sums over its window less itself (``_window_sums_kernel``), then v = mean_c
    (Σs²/k) / ((Σm/k)² + eps) into ``out_v`` (NaN where no neighbour has 2 samples) and k into
    ``out_k``, and the neighbours' mean segments a sample into ``out_cost`` (NaN where none has
    a sample) and their number into ``out_ck``. ``moments``, ``rows`` and ``window`` (h, w, 9)
    are scratch."""
    h, w = count.shape
    _pixel_moments(sums, sums_sq, count, moments)
    for y in range(h):
        for x in range(w):
            n = count[y, x]
            moments[y, x, 7] = segments[y, x] / n if n > 0 else 0.0
            moments[y, x, 8] = 1.0 if n > 0 else 0.0
    _window_sums_kernel(moments, radius, rows, window)
    for y in range(h):
        for x in range(w):
            k = window[y, x, 6]
            out_k[y, x] = k
            if k > 0.0:
                v = 0.0
                for c in range(3):
                    m = window[y, x, 3 + c] / k
                    v += window[y, x, c] / k / (m * m + eps)
                out_v[y, x] = v / 3.0
            else:
                out_v[y, x] = np.nan
            kc = window[y, x, 8]
            out_ck[y, x] = kc
            out_cost[y, x] = window[y, x, 7] / kc if kc > 0.0 else np.nan


def shape_estimates(buf: SampleBuffer, floor: float | None = None,
                    radius: int = RADIUS) -> tuple[np.ndarray, np.ndarray | None]:
    """What shapes a round's counts, both from each pixel's neighbours within ``radius`` (a
    (2r+1)² window less the pixel) in one pass over the buffer: ``neighbour_variance`` and
    ``sample_cost`` (None where the buffer carries no segments)."""
    h, w = buf.count.shape
    v, k = np.empty((h, w)), np.empty((h, w))
    per, kc = np.empty((h, w)), np.empty((h, w))
    moments = np.empty((h, w, 9))
    has_segments = buf.segments is not None and bool(buf.segments.any())
    _neighbour_variance_kernel(np.ascontiguousarray(buf.sum, np.float64),
                               np.ascontiguousarray(buf.sum_sq, np.float64),
                               np.ascontiguousarray(buf.count, np.int64),
                               np.ascontiguousarray(buf.segments, np.int64) if has_segments
                               else np.zeros((h, w), np.int64), radius, EPSILON,
                               moments, np.empty((h, w, 9)), np.empty((h, w, 9)), v, k, per, kc)
    cost = None
    if has_segments:
        sampled = moments[..., 8] > 0
        fallback = float(moments[..., 7][sampled].mean()) if sampled.any() else 1.0
        cost = SEGMENT_OVERHEAD + np.where(kc > 0, per, fallback)
    ok = moments[..., 6] > 0
    if not ok.any():
        return np.full(ok.shape, math.nan), cost
    has = k > 0
    if has.any():
        fallback = float(v[has].mean())
    else:
        mean, s2, _ = _moments(buf)
        fallback = float(np.mean(s2[ok] / (mean[ok] ** 2 + EPSILON)))
    v = np.where(has, v, fallback)
    return np.maximum(v, (FLOOR if floor is None else floor) * float(v.mean())), cost


def neighbour_variance(buf: SampleBuffer, floor: float | None = None) -> np.ndarray:
    """The allocation's estimate of every pixel's v_p from its neighbours' samples only: over the
    pixels q of its 5×5 neighbourhood but itself that have samples, mean_c [mean_q s²_qc] /
    (M_c² + ε) with M the mean of their means; at least ``floor`` (default ``FLOOR``) × the
    buffer's mean estimate.
    A pixel without such neighbours (a 1×1 tile) takes the buffer's mean; NaN if nothing has
    samples. No term holds the pixel's own samples (the floor and the fallback hold them as one
    of all the buffer's pixels).

    The pooling and the floor are there because a few samples of heavy-tailed radiance (a path
    that is bright once in hundreds) mostly show no variance at all: on the chart suite a 16-sample
    pilot pooled over 3×3 and trusted as is left the frame 1.5–2× above its target."""
    return shape_estimates(buf, floor)[0]


# The least share of the target the loop leaves the samples' noise where a model ``auto``
# chose takes the rest (noise_target)
NOISE_FLOOR = 0.1


def noise_target(target: float, bias: float) -> float:
    """The samples' share of ``target`` (the frame's expected relMSE) where the frame's
    models add ``bias`` to it (``renderer.materials.auto.frame_bias``): the target less the
    bias, at least ``NOISE_FLOOR`` × the target (where the bias is nearly all of it, the loop
    would otherwise take samples without end; the frame may then end above the target by
    what the bias takes past that share)."""
    return max(target - max(bias, 0.0), NOISE_FLOOR * target)


def aim_reached(error: float, target: float) -> bool:
    """The stop of the local loop and of the farm's tile rule: the frame's estimated error is
    within ``STOP_SLACK`` of AIM × ``target``."""
    return error <= AIM * target * (1.0 + STOP_SLACK)


def first_look_bound(err_sum: float, err_sq_sum: float, pixels: int) -> float:
    """The bound the stop after the pilot's first half takes (``first_look_reached``), from the
    sums of the frame's (or a tile's) ``error_terms`` e_p and of their squares over its
    ``pixels``: their mean plus ``FIRST_LOOK_Z`` standard errors of it, the terms' spread over
    the pixels (the population one) over √pixels. inf (no stop) where fewer than
    ``FIRST_LOOK_PIXELS`` pixels carry the terms, (Σ e)² / Σ e² (a frame of no variance
    included): the normal approximation behind the bound needs many, and where a few pixels'
    rare bright paths carry the estimate it is low in some runs (the caustic floor at 4 samples
    a pixel, over 32 seeds: one run's estimate 0.25x its error, carried by about 3 pixels, its
    bound 0.87 of the aim at target 0.1; the Cornell box's carried by 74-330)."""
    if pixels <= 0 or err_sq_sum <= 0.0 or err_sum * err_sum < FIRST_LOOK_PIXELS * err_sq_sum:
        return math.inf
    mean = err_sum / pixels
    spread = math.sqrt(max(err_sq_sum / pixels - mean * mean, 0.0))
    return mean + FIRST_LOOK_Z * spread / math.sqrt(pixels)


def _look_sums(terms: np.ndarray) -> tuple[float, float, int]:
    """``first_look_bound``'s sums of ``terms``: (Σ e, Σ e², pixels). The squares summed by
    numpy, not ``np.dot``: a dot product of a frame's length runs on the BLAS library's threads,
    which then spin waiting for more and took the cores from the render's next passes (the wax
    sphere at 160×120: its pass after the first look 76-90 ms against 42-62, scratch)."""
    t = np.asarray(terms, np.float64).ravel()
    return float(t.sum()), float((t * t).sum()), t.size


def first_look_reached(terms: np.ndarray, target: float) -> bool:
    """The stop after the pilot's first half (``FIRST_LOOK`` samples a pixel), from its
    ``error_terms``: their mean, the frame's estimated error, plus ``FIRST_LOOK_Z`` standard
    errors of it over the pixels (``first_look_bound``: none where fewer than
    ``FIRST_LOOK_PIXELS`` pixels carry it), within the aim (``aim_reached``). At 4 samples a
    pixel the mean alone is unreliable where a few pixels' rare bright paths carry it: on the
    caustic floor and the sphere of albedo 0.5 it came out 0.25-0.49x the error in some runs,
    which stopped at 1.3-1.8x the target; there the terms' relative standard error is 0.24-0.90,
    on the diffuse Cornell box, whose estimate was 0.84-1.09x its error, 0.05-0.12 (32 seeds,
    docs/adaptive-sampling.md)."""
    return aim_reached(first_look_bound(*_look_sums(terms)), target)


@inline_kernel
def _clamped_count(lam, root, lo, cap):
    """A pixel's count at scale ``lam``: clamp(⌈λ root⌉, lo, cap), what ``allocate``'s counts
    give it (the error and the work of a scale, ``_allocation_error``, ``_allocation_cost``)."""
    return min(max(math.ceil(lam * root), lo), cap)


@kernel
def _allocation_error(lam, root, lo, ve, cap):
    """Σ v_p / n_p with n_p = clamp(⌈λ root_p⌉, lo_p, cap), at least 1: P × the expected frame
    error for the counts of scale ``lam`` (``allocate``'s solve evaluates it ~20 times a round),
    in one pass."""
    total = 0.0
    for i in range(root.shape[0]):
        total += ve[i] / max(_clamped_count(lam, root[i], lo[i], cap), 1.0)
    return total


@kernel
def _allocation_cost(lam, root, lo, c, cap):
    """Σ c_p (n_p − lo_p) with n_p = clamp(⌈λ root_p⌉, lo_p, cap): the work the counts of scale
    ``lam`` add (``allocate``'s budget, ~12 evaluations a round), in one pass."""
    total = 0.0
    for i in range(root.shape[0]):
        total += c[i] * (_clamped_count(lam, root[i], lo[i], cap) - lo[i])
    return total


@kernel
def _solve_scale(root, lo, ve, cap, pixels, target, guess, min_root, steps):
    """``allocate``'s scale, its ~20 evaluations of the error in one call: ``(0, 0.0)`` when the
    samples each pixel has already meet ``target``; ``(1, λ)`` when the cap binds first (λ where
    the pixel of least root > 0, ``min_root``, passes ``cap``: the cap everywhere needing
    samples); else ``(2, λ)``, the least scale whose error (1/P) Σ v_p / n_p is at most
    ``target``: bracketed within a factor 2 from ``guess`` (where it would be without the
    clamps), then the bracket halved ``steps`` times. ``root``, ``lo``, ``ve``: the pixels that
    add to the error (``_allocation_error``)."""
    if _allocation_error(0.0, root, lo, ve, cap) / pixels <= target:
        return 0, 0.0
    hi = guess if math.isfinite(guess) and guess > 0.0 else 1.0
    if _allocation_error(hi, root, lo, ve, cap) / pixels > target:
        while _allocation_error(hi, root, lo, ve, cap) / pixels > target:
            hi *= 2.0
            if hi * min_root > cap:
                return 1, hi
    else:
        while hi > 1e-300 and _allocation_error(0.5 * hi, root, lo, ve, cap) / pixels <= target:
            hi *= 0.5
    lo_lam = 0.5 * hi
    for _ in range(steps):
        mid = 0.5 * (lo_lam + hi)
        if _allocation_error(mid, root, lo, ve, cap) / pixels > target:
            lo_lam = mid
        else:
            hi = mid
    return 2, hi


@kernel
def _solve_budget(root, lo, c, cap, budget, scale, steps):
    """``allocate``'s scale cut to a round's ``budget``: ``scale`` if its counts add at most
    ``budget`` of work (``_allocation_cost``), else [0, scale] halved ``steps`` times towards
    the largest scale that does (its lower end)."""
    if _allocation_cost(scale, root, lo, c, cap) <= budget:
        return scale
    lo_lam, hi = 0.0, scale
    for _ in range(steps):
        mid = 0.5 * (lo_lam + hi)
        if _allocation_cost(mid, root, lo, c, cap) <= budget:
            lo_lam = mid
        else:
            hi = mid
    return lo_lam


def _even_count(error_sum: float, pixels: int, target: float, have: int, cap: int,
                budget: float | None) -> int:
    """``allocate``'s count when every pixel is alike (the same v, the same count ``have``, no
    cost): ``have`` if it meets the target ((1/P) Σ ve / have ≤ target), else the least n with
    error_sum / (P n) ≤ target, at most ``cap``, and with ``budget`` at most have + ⌊budget / P⌋
    (P × the samples added within the budget)."""
    if error_sum / (pixels * max(have, 1)) <= target:
        return have
    n = max(math.ceil(error_sum / (pixels * target)), 1)
    while n > 1 and error_sum / (pixels * (n - 1)) <= target:
        n -= 1  # (the least such n, whatever the rounding of the division above)
    while error_sum / (pixels * n) > target:
        n += 1
    n = min(max(n, have), cap)
    if budget is not None:
        n = min(n, have + max(int(budget // pixels), 0))
    return n


def allocate(v: np.ndarray, target: float, have: np.ndarray, cap: int,
             scale: float | None = None, budget: float | None = None,
             error_of: np.ndarray | None = None, cost: np.ndarray | None = None) -> np.ndarray:
    """Samples each pixel should have, (h, w) int64: n_p = clamp(λ √v_p, have_p, cap), with λ the
    smallest scale for which the expected error (1/P) Σ v_p / n_p is at most ``target`` (or the
    given ``scale``: the farm's frame-wide λ). Pixels whose v is NaN keep what they have. With
    ``budget``, at most that many samples are added in all: λ shrinks until they fit (a round of
    the progressive allocation, which re-estimates before it commits more). ``error_of``: the
    variances the expected error is measured with, when not ``v`` (the loop shapes the counts
    with the neighbours' estimate and measures with each pixel's own; NaN counts as 0).
    ``cost``: each pixel's cost of a sample (``sample_cost``); then n_p = λ √(v_p / c_p), the
    counts that reach the error in the least time rather than with the fewest samples (minimise
    Σ c_p n_p subject to the error), and ``budget`` is in cost (Σ c_p × samples added).

    A pure function of its arguments; where even ``cap`` samples everywhere cannot reach the
    target, every pixel gets ``cap``."""
    if target <= 0:
        raise ValueError("target must be > 0")
    have = np.asarray(have, np.int64)
    v = _finite_or_zero(v)
    lo = np.minimum(have, cap).astype(np.float64)
    c = np.ones(v.shape) if cost is None else np.maximum(np.asarray(cost, np.float64), 1e-9)
    root = np.sqrt(v / c)
    ve = v if error_of is None else _finite_or_zero(error_of)

    def counts(lam: float) -> np.ndarray:
        return np.clip(np.ceil(lam * root), lo, cap)

    if (scale is None and cost is None and v.size and root.min() > 0
            and root.min() == root.max() and lo.min() == lo.max()):
        # Every pixel alike (an even round: v uniform, every pixel the same count so far): the
        # counts are one n for all, the least whose error (1/P) Σ ve_p / n meets the target,
        # at most the cap, and at most the budget's share of a pixel; in closed form, not by the
        # solve's bisection (its answer, to the sample)
        return np.full(v.shape, _even_count(float(ve.sum()), v.size, target, int(lo.flat[0]),
                                            cap, budget), np.int64)
    if scale is None:
        # The error of a scale, over the pixels that add to it (on arrays cut to those pixels
        # once), solved in one kernel: from where the scale would be without the clamps
        # ((1/P) Σ v_p / (λ root_p) = target), bracketed within a factor 2, then halved
        # BISECTIONS times
        live = ve > 0
        ve_l, root_l, lo_l = ve[live], root[live], lo[live]
        guess = float(np.sum(ve_l[root_l > 0] / root_l[root_l > 0])) / (v.size * target)
        how, scale = _solve_scale(root_l, lo_l, ve_l, float(cap), float(v.size), float(target),
                                  guess, float(root.min(initial=math.inf, where=v > 0)),
                                  BISECTIONS)
        if how == 0:
            return lo.astype(np.int64)
        if how == 1:
            return counts(scale).astype(np.int64)  # the cap everywhere needing samples
    if budget is not None:
        scale = _solve_budget(root.ravel(), lo.ravel(),
                              np.ascontiguousarray(c, np.float64).ravel(), float(cap),
                              float(budget), float(scale), BUDGET_BISECTIONS)
    return counts(scale).astype(np.int64)


def sample_cost(buf: SampleBuffer) -> np.ndarray | None:
    """Each pixel's cost of one sample, in path segments (rays traced to the closest surface):
    ``SEGMENT_OVERHEAD`` plus the mean segments a sample of its 5×5 neighbours that have samples
    took (never its own: a path's length may go with its radiance; the buffer's mean where none
    has); None where the buffer carries no segments (a farm buffer read back, the wavefront
    kernel's)."""
    return shape_estimates(buf)[1]


def error_terms(buf: SampleBuffer) -> np.ndarray:
    """Each pixel's term v_p / n_p of the frame's expected relMSE, (h, w): its own per-sample
    relative variance (``sample_variance``) over its count, 0 below 2 samples (nothing known).
    Unbiased for the pixel's error where its count was fixed by other pixels' samples, as the
    allocation's are."""
    return _error_terms(sample_variance(buf), buf.count)


def _error_terms(v: np.ndarray, count: np.ndarray) -> np.ndarray:
    """``error_terms`` from a buffer's ``sample_variance`` already computed (the loop has it)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(np.isfinite(v), v / np.maximum(count, 1), 0.0)


def expected_error(buf: SampleBuffer) -> float:
    """The frame's expected relMSE from its buffer: (1/P) Σ v_p / n_p with each pixel's own
    sample variance; inf if a pixel has < 2 samples."""
    if buf.count.size == 0 or int(buf.count.min()) < 2:
        return math.inf
    return float(error_terms(buf).mean())


def stopping_error(buf: SampleBuffer) -> float:
    """The frame's expected relMSE as the loop judges it (what it stops on, the CLI reports and
    the farm's tile summaries add up): the mean of ``error_terms``, a pixel below 2 samples
    adding nothing; from ``error_sums``' Σ e_p, the very sum ``sample_to_target`` stops on."""
    pixels = buf.count.size
    return error_sums(buf)[1] / pixels if pixels else math.nan


def tile_summary(buf: SampleBuffer) -> tuple[float, float, int, float]:
    """What the farm keeps of a tile's merged buffer for the frame's allocation and its error:
    (Σ e_p, Σ w_p, pixels, Σ e_p²), the sums over the pixels with at least 2 samples, pixels
    those that have drawn 2 (a pixel whose samples were dropped as non-finite adds nothing to
    the sums, and is counted: the frame's estimate does not wait for it forever): e_p =
    ``error_terms``; w_p = s_p / √ṽ_p, the pixel's own relative variance s_p over the root of the
    floored neighbour estimate ṽ_p that ``pass_counts`` shapes its count with (0 where ṽ_p is 0),
    so that counts n_p = λ √ṽ_p give the tile the expected error Σ w_p / λ (``frame_scale``);
    and the squares, for the first look's bound (``first_look_bound``)."""
    ok = buf.count >= 2
    pixels = int(np.count_nonzero(buf.drawn >= 2))
    if not ok.any():
        return 0.0, 0.0, pixels, 0.0
    own = sample_variance(buf)[ok]
    shape = neighbour_variance(buf)[ok]
    n = buf.count[ok].astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(shape > 0, own / np.sqrt(shape), 0.0)
    e = own / n
    # (the squares summed by numpy, not np.dot, whose BLAS threads spin: _look_sums)
    return float(e.sum()), float(w.sum()), pixels, float((e * e).sum())


def frame_scale(weight_sum: float, pixels: int, target: float) -> float:
    """The frame-wide λ of n_p = λ √ṽ_p that brings the frame's expected error to AIM ×
    ``target``, from its tiles' summed ``tile_summary``: the unclamped counts give
    (1/P) Σ w_p / λ, so λ = Σ w_p / (P · AIM · target). inf when nothing is known (every pixel
    then takes its pass); 0 when nothing varies."""
    if pixels <= 0:
        return math.inf
    return max(weight_sum, 0.0) / (pixels * AIM * target)


@kernel
def _least_scale_kernel(ve, have, root, t, order, target, tail):
    """``least_scale`` on 1-D float64 arrays, ``ve`` finite and ≥ 0, given t = have / root (inf
    where root is 0) and ``order``, an argsort of t; ``tail`` (n + 1) is scratch. Two passes."""
    n = ve.size
    total = 0.0
    for i in range(n):
        total += ve[i] / have[i] if ve[i] > 0.0 else 0.0  # (inf: error and no sample)
    goal = n * target
    if total <= goal:
        return 0.0
    # tail[k]: Σ ve/have over the pixels order[k], order[k + 1], … (not scaled)
    tail[n] = 0.0
    for k in range(n - 1, -1, -1):
        i = order[k]
        tail[k] = tail[k + 1] + (ve[i] / have[i] if ve[i] > 0.0 else 0.0)
    head = 0.0  # Σ ve/root over the pixels order[0 … k] (scaled)
    for k in range(n):
        i = order[k]
        if root[i] > 0.0:
            head += ve[i] / root[i]
        rest = tail[k + 1]
        if goal > rest:
            lam = head / (goal - rest)
            upper = t[order[k + 1]] if k + 1 < n else np.inf
            # (the relative slack takes a solution on an interval's end as inside it)
            if t[i] * (1.0 - 1e-12) <= lam <= upper * (1.0 + 1e-12):
                return lam
    return np.inf


def least_scale(ve: np.ndarray, have: np.ndarray, root: np.ndarray, target: float) -> float:
    """The least λ ≥ 0 at which counts n_p = max(have_p, λ root_p), not rounded to whole
    samples, give (1/P) Σ ve_p / n_p ≤ ``target`` (ve NaN, below 2 samples, adding nothing):
    0 where the counts each pixel has already meet it, inf where no λ does (a pixel with error,
    no samples and root 0). ``shape_pays`` compares two shapes' work at it, unrounded: rounded,
    even counts (one whole count for every pixel) overshoot by half a sample a pixel on
    average, a few per cent of a round at tens of samples a pixel, which a shape's scale, finer
    than a sample, does not, and that alone made the shape look cheaper on even noise.

    Exact, in one sort (numpy's; the rest in ``_least_scale_kernel``): with the pixels ordered
    by t_p = have_p / root_p (where λ root_p passes what the pixel has), for λ between two
    consecutive t the error is (F + S/λ)/P, F the sum of ve/have over the pixels not yet
    scaled and S that of ve/root over those scaled; each interval's solution
    λ = S / (P·target − F) is tried in turn and the first inside its interval taken (the error
    falls with λ, so there is one)."""
    ve, have, root = (np.ascontiguousarray(a, np.float64).ravel() for a in (ve, have, root))
    ve = _finite_or_zero(ve)
    t = _crossings(have, root)
    return float(_least_scale_kernel(ve, have, root, t, np.argsort(t), float(target),
                                     np.empty(ve.size + 1)))


def _finite_or_zero(a: np.ndarray) -> np.ndarray:
    """``a`` with its NaNs, infinities and negative values as 0 (a variance that adds nothing)."""
    return np.where(np.isfinite(a), np.maximum(a, 0.0), 0.0)


def _crossings(have: np.ndarray, root: np.ndarray) -> np.ndarray:
    """t_p = have_p / root_p, the scale λ at which λ root_p passes what the pixel has (inf where
    root is 0): ``least_scale``'s order."""
    with np.errstate(divide="ignore"):
        return np.where(root > 0, have / np.where(root > 0, root, 1.0), np.inf)


@kernel
def _gate_work(ve, have, root, c, t, order, order_even, target, ones, tail):
    """``_gate``'s two works in one call: the shaped counts' (``root``, its t = have/root and
    ``order``, an argsort of t) and the even counts' (root 1, t = have, ``order_even`` an
    argsort of ``have``), each at its ``least_scale`` for ``target``: Σ c_p (max(have_p,
    λ root_p) − have_p), both inf where either scale is; and the even counts' scale, the one
    count they bring every pixel to. ``ones`` (n) holds 1s, ``tail`` (n + 1) is scratch."""
    lam = _least_scale_kernel(ve, have, root, t, order, target, tail)
    lam_even = _least_scale_kernel(ve, have, ones, have, order_even, target, tail)
    if not (math.isfinite(lam) and math.isfinite(lam_even)):
        return np.inf, np.inf, lam_even
    work = 0.0
    work_even = 0.0
    for i in range(ve.size):
        work += c[i] * (max(have[i], lam * root[i]) - have[i])
        work_even += c[i] * (max(have[i], lam_even) - have[i])
    return work, work_even, lam_even


def shape_pays(v: np.ndarray, cost: np.ndarray | None, v_error: np.ndarray, have: np.ndarray,
               aim: float) -> bool:
    """Whether a round's counts should be shaped: the loop's gate. True when the shaped counts
    (n_p ∝ √(v_p / cost_p), ``allocate``'s, from the neighbours' estimate ``v``) reach the
    ``aim`` with less work than even counts (every pixel brought to one count, those above it
    keeping theirs), both solved (``least_scale``) to the same error as each pixel's *own*
    variance ``v_error`` prices it, and their work the samples added times ``cost`` (one a
    sample where None).

    A cross-validation: neither set of counts depends on a pixel's own samples (the shaped ones
    on its neighbours', the even ones on none), so each pixel's own variance prices both without
    bias, and the estimate's noise counts against the shape it makes. Priced with the estimate
    that made the shape, the shape always looks better than even (Cauchy–Schwarz), by more the
    noisier the estimate: the rule's own estimates at 32 spp predict a 0.74-0.77 gain on the
    shell and 0.66-0.69 on the Cornell box, where the shape gains at most 0.97 and nothing
    (docs/adaptive-sampling.md, ``--oracle``). The cap (``render.spp``) is left out of both."""
    return _gate(v, cost, v_error, have, aim)[0]


def _gate(v: np.ndarray, cost: np.ndarray | None, v_error: np.ndarray, have: np.ndarray,
          aim: float) -> tuple[bool, float]:
    """``shape_pays``' verdict, and the one count the even counts bring every pixel to (their
    ``least_scale``; inf where none reaches the aim), which the farm's tile rule takes when the
    shape does not pay."""
    counts = np.asarray(have).ravel()
    n = counts.size
    have_f = counts.astype(np.float64)
    ve = _finite_or_zero(np.ascontiguousarray(v_error, np.float64).ravel())
    c = (np.ones(n) if cost is None
         else np.maximum(np.ascontiguousarray(cost, np.float64).ravel(), 1e-9))
    root = np.sqrt(_finite_or_zero(np.ascontiguousarray(v, np.float64).ravel()) / c)
    t = _crossings(have_f, root)
    # (the even counts' order: by count, none needed where every pixel has the same)
    order_even = (np.arange(n) if n == 0 or counts.min() == counts.max()
                  else np.argsort(counts, kind="stable"))
    work, work_even, even_scale = _gate_work(ve, have_f, root, c, t, np.argsort(t), order_even,
                                             float(aim), np.ones(n), np.empty(n + 1))
    return bool(work < work_even), float(even_scale)


def pass_counts(buf: SampleBuffer, target: float, cap: int, pass_samples: int,
                scale: float | None = None, frame_error: float | None = None,
                frame_bound: float | None = None, pilot_error: float | None = None
                ) -> np.ndarray:
    """The farm's rule, a pure function of a tile's merged buffer (and the frame's ``scale``,
    ``frame_scale`` of the job's tile summaries, its estimated error, their error sum over
    their pixels, its ``first_look_bound`` and its estimated error at the end of its pilot,
    ``pilot_error``, when known): the samples each pixel takes of the next pass of
    ``pass_samples``, (h, w) int32. Every pixel up to ``FIRST_LOOK``, the pilot's first half;
    then, as the local loop, nothing where the first look's bound is within the aim (the
    frame's, or before every tile has merged its first look the tile's own, which its re-check
    once the frame's is known replaces), else every pixel up to ``PILOT``; at the end of the
    pilot nothing until ``pilot_error`` is known, then nothing where it is within the aim, else
    every pixel the even count that takes it to the aim, at most twice the pilot (the local
    loop's first round); past that, nothing once the
    frame's estimated error is within ``STOP_SLACK`` of AIM × target (the local loop's stop:
    the frame's λ counts every pixel at its share, a pixel that already has more too, so the
    counts alone would go on past the aim); else each pixel its deficit against ``allocate``
    (the tile's floored neighbour variances at the frame's scale, or aiming the tile alone at
    AIM × target without one), at most the pass; or, where the loop's gate (``shape_pays``)
    finds that shape no cheaper than even counts at the same error of the tile (priced by its
    pixels' own variances), every pixel its deficit against the one count that reaches it."""
    count = buf.count
    # Where the pilot stands: the samples drawn, kept or dropped as non-finite (a pixel whose
    # every sample is dropped still ends its pilot, and the frame's estimates there do not wait
    # for it; past the pilot its count, 0, caps its passes at nothing). A pixel short of the
    # pilot's kept samples takes them again, as the local loop's does.
    low = int(buf.drawn.min(initial=PILOT))
    look = min(FIRST_LOOK, PILOT, cap)
    if low < look:
        # The pilot's first half (the local loop's first look), before anything is estimated
        want = np.full(count.shape, look, np.int64)
    elif low < min(PILOT, cap):
        # The first look: a stop where its bound is within the aim, else the rest of the pilot
        if (aim_reached(frame_bound, target) if frame_bound is not None
                else first_look_reached(error_terms(buf), target)):
            return np.zeros(count.shape, np.int32)
        want = np.full(count.shape, min(PILOT, cap), np.int64)
    elif low == int(count.max()) == PILOT < cap:
        # The end of the tile's pilot, as the local loop's, on the frame's estimated error at the
        # end of its pilot (nothing until every tile has ended its pilot: the tile waits,
        # converged, and is asked again once it is known, services.farm.targets.wake_converged):
        # a stop, else every pixel one count, the least that takes that error to the aim, at
        # most twice the pilot (the loop's first round). Not the job's running estimate, nor a
        # shape from the pilot, nor the tile's own estimate: each sent the pass to the tiles
        # that had met the rare bright paths, the running estimate fell as they took it, and the
        # tiles that ended their pilot later stopped on it with their paths unmet
        # (docs/adaptive-sampling.md).
        if pilot_error is None or aim_reached(pilot_error, target):
            return np.zeros(count.shape, np.int32)
        pixels = count.size
        want = np.full(count.shape, _even_count(pilot_error * pixels * low, pixels,
                                                AIM * target, low, cap, float(pixels * low)),
                       np.int64)
    elif frame_error is not None and aim_reached(frame_error, target):
        return np.zeros(count.shape, np.int32)
    else:
        v = neighbour_variance(buf)
        own = sample_variance(buf)
        framed = scale is not None and math.isfinite(scale)
        if framed:
            # the tile's share of the frame's aim: its error, as its pixels' own variances price
            # it, at the frame's scale (the counts unrounded, as the gate compares them)
            with np.errstate(invalid="ignore"):
                shaped = np.maximum(count, scale * np.sqrt(np.maximum(v, 0.0)))
            aim = float(np.mean(np.where(np.isfinite(own), own, 0.0) / shaped))
        else:
            aim = AIM * target
        # The local loop's gate: even counts where the shape, priced by each pixel's own
        # variance, would not reach the tile's aim with fewer samples (the shaped counts are
        # solved only where it does)
        pays, m = _gate(v, None, own, count, aim) if aim > 0 else (True, math.inf)
        if not pays and math.isfinite(m):
            want = np.clip(np.ceil(m), count, cap).astype(np.int64)
        elif framed:
            want = allocate(v, AIM * target, count, cap, scale=scale)
        else:
            want = allocate(v, AIM * target, count, cap, error_of=own)
    deficit = np.clip(want - count, 0, pass_samples)
    if low >= min(PILOT, cap):
        # Past the pilot, a pass at most doubles a pixel's samples, as a round of the local loop
        # adds at most as much work again as the frame has had: the estimates improve before
        # more is committed on them. (The plan's passes grow so on their own, 8, 8, 16, 32, …,
        # but the first look takes a pass of its own: the pass after the pilot holds 16 where
        # a pixel has 8, and the caustic floor's jobs took 20 and 10 spp a pixel to 0.41 and
        # 0.45x targets 0.03 and 0.1, against 15 and 8 to 0.57 and 0.55 before the first look.)
        deficit = np.minimum(deficit, count)
    return deficit.astype(np.int32)


def tile_converged(buf: SampleBuffer, target: float, cap: int, scale: float | None = None,
                   frame_error: float | None = None) -> bool:
    """A tile is done when no pixel takes samples of another pass (``pass_counts``)."""
    return not bool(pass_counts(buf, target, cap, cap, scale, frame_error).any())


def warm_up() -> None:
    """Load (or compile) the kernels of the rule on a 4×4 frame of 8 samples a pixel, so that a
    farm worker's first pass of a job with a target does not pay for them (its warm-up calls
    this: ``worker.runtime.warm_up_kernels``)."""
    buf = SampleBuffer.empty(0, 0, 4, 4)
    buf.count[:] = PILOT
    buf.sum[:] = np.arange(16, dtype=np.float64).reshape(4, 4, 1)
    buf.sum_sq[:] = 2.0 * buf.sum * buf.sum + 1.0
    pass_counts(buf, 0.01, 64, 8)
    # (the shaped counts' solve too, which pass_counts skips where its gate takes even counts)
    allocate(neighbour_variance(buf), 0.01, buf.count, 64, error_of=sample_variance(buf))
    tile_summary(buf)


def sample_to_target(render_pass, shape: tuple[int, int], target: float, spp: int,
                     plan=None, progress=None, max_pass: int | None = None,
                     max_rounds: int = 64, even: bool = False) -> SampleBuffer:
    """The local renderer's loop, given ``render_pass(index, counts) -> SampleBuffer`` that adds
    samples [index, index + counts[p]) to each pixel p of a frame of ``shape`` (h, w): a pilot of
    ``PILOT`` samples a pixel in two passes, with a stop after the first ``FIRST_LOOK``
    (``first_look_reached``), then rounds, each one pass of every pixel's deficit against the
    allocation (the first of them even: every pixel the same count; a later one shaped only
    where ``shape_pays``, else even too; at most as much work,
    samples × cost, as the frame has had: the estimates improve before more is committed on
    them), until the estimated frame error is within ``STOP_SLACK``
    of AIM × ``target``, no pixel lacks a sample, or every pixel has ``spp``. Sample indices are
    never reused: a pixel that sits out part of a round's index range has a gap, not a repeat.
    ``plan(mean_spp, error)`` is told the pilot's allocation and the frame error it expects of it
    (each pixel's own variance over its planned count: above the aim where ``spp`` caps it), or
    the first look's where that stops; ``progress(done, planned)`` after every pass;
    ``max_pass`` caps a pass's samples a pixel. ``even``: every round gives every pixel the same
    count (uniform sampling with the loop's rounds and stop; what the shape of the counts gains
    is measured against it, ``python -m bench.target_error --even``)."""
    h, w = shape
    frame = SampleBuffer.empty(0, 0, w, h)
    pilot = min(PILOT, spp)
    aim = AIM * target
    # The pilot in two passes: after its first half (FIRST_LOOK samples a pixel) the stop is
    # checked once, so a loose target that so few samples already reach stops there (the
    # diffuse Cornell box at 0.1: the whole pilot took it to 0.28x the target)
    look = min(FIRST_LOOK, pilot)
    pixels = h * w
    frame.add(render_pass(0, np.full((h, w), look, np.int32)))
    if look < pilot:
        # (first_look_reached, on the sums of error_sums' one pass)
        _, err_sum, err_sq_sum, _ = error_sums(frame)
        if aim_reached(first_look_bound(err_sum, err_sq_sum, pixels), target):
            if plan is not None:
                plan(float(frame.count.mean()), err_sum / max(pixels, 1))
            if progress is not None:
                total = int(frame.count.sum())
                progress(total, total)
            return frame
        frame.add(render_pass(look, np.full((h, w), pilot - look, np.int32)))
    index = pilot
    for _ in range(max_rounds):
        # Stop once the frame's estimated error (stopping_error: each pixel's own variance, which
        # did not shape its count) is within STOP_SLACK of the aim (chasing the last few samples
        # of a few pixels would change the error by less than its own noise); the estimates
        # that shape the counts are needed only to go on (and for the pilot's plan)
        # (stopping_error's sum, with the variances and Σ v the round needs from the same pass)
        v_error, err_sum, _, v_sum = error_sums(frame)
        met = aim_reached(err_sum / max(pixels, 1), target)
        if plan is not None:  # (the first round's, after the pilot: the allocation's total)
            plan_v, plan_cost = ((np.ones(frame.count.shape), None) if even else
                                 shape_estimates(frame))
            planned = allocate(plan_v, aim, frame.count, spp, error_of=v_error, cost=plan_cost)
            plan(float(planned.mean()), float(_error_terms(v_error, planned).mean()))
            plan = None
        if met:
            break
        if index == pilot or even:
            # The first round after the pilot gives every pixel the same count: 24 neighbours × 8
            # samples do not yet tell which pixels need more where rare bright paths carry the
            # image (a shape from them sent the round to where the pilot happened to see them,
            # at more path segments a sample and no gain: docs/adaptive-sampling.md); with
            # ``even``, every round does
            v, cost, shaped = None, None, False
        else:
            # The counts are shaped by the neighbours' floored estimate (no pixel trusted to be
            # noiseless on a few samples)
            v, cost = shape_estimates(frame)
            shaped = shape_pays(v, cost, v_error, frame.count, aim)
            if not shaped:
                # ... where that shape, priced by each pixel's own variance, reaches the aim with
                # less work than even counts; else the round is even (the shell, the Cornell box:
                # the estimates' noise makes a shape the variance does not have)
                v, cost = None, None
        # (the round's budget: as much work again as the frame has had)
        work = float(np.sum(frame.count * (1.0 if cost is None else cost)))
        have = int(frame.count.min()) if pixels else 0
        if not shaped and pixels and have == int(frame.count.max()):
            # Even counts from one count everywhere (the round after the pilot): allocate's
            # closed form for pixels alike, on error_sums' Σ v, without its passes over the frame
            deficit = np.full((h, w), _even_count(v_sum, pixels, aim, min(have, spp), spp,
                                                  work) - have, np.int64)
        else:
            want = allocate(np.ones(frame.count.shape) if v is None else v, aim, frame.count,
                            spp, budget=work, error_of=v_error, cost=cost)
            deficit = want - frame.count
        if max_pass is not None:
            deficit = np.minimum(deficit, max_pass)
        if not (deficit > 0).any():
            break
        if progress is not None:
            progress(int(frame.count.sum()), int(frame.count.sum() + deficit.sum()))
        k = int(deficit.max())
        frame.add(render_pass(index, deficit.astype(np.int32)))
        index += k
    if progress is not None:
        total = int(frame.count.sum())
        progress(total, total)
    return frame
