"""The counter-based generator (renderer/rng.py): uniform, independent, a pure function of its key.

Statistical checks use 10⁶ draws and a 5σ tolerance: a correct generator fails one of them with
probability ~6e-7 each, while a bias of 0.3 % in the mean (or a correlation of 0.01 between
neighbours) is already 5σ at this N. The chi² checks use the Bonferroni threshold of
tests/conftest.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.jit import alloc_kernel
from renderer.rng import mix64, sample_key, uniform

N_PIX, N_SAMP, N_DIM = 1000, 250, 4  # 10⁶ values in all


@alloc_kernel
def _table(seed, pixel0, n_pix, sample0, n_samp, n_dim):
    """uniform(sample_key(seed, pixel, sample), dim) for a block of pixels, samples and dims."""
    out = np.empty((n_pix, n_samp, n_dim))
    for i in range(n_pix):
        for j in range(n_samp):
            key = sample_key(seed, pixel0 + i, sample0 + j)
            for d in range(n_dim):
                out[i, j, d] = uniform(key, d)
    return out


@alloc_kernel
def _keys(seed, n_pix, n_samp):
    out = np.empty(n_pix * n_samp, np.uint64)
    for i in range(n_pix):
        for j in range(n_samp):
            out[i * n_samp + j] = sample_key(seed, i, j)
    return out


@pytest.fixture(scope="module")
def table() -> np.ndarray:
    return _table(7, 0, N_PIX, 0, N_SAMP, N_DIM)


def corr(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])


def test_range_and_resolution(table):
    assert table.min() >= 0.0 and table.max() < 1.0
    # Every value is a multiple of 2⁻⁵³ (53 random bits, exactly representable).
    scaled = table * 2.0**53
    assert np.all(scaled == np.floor(scaled))


def test_mean_and_variance(table):
    x = table.ravel()
    n = x.size
    # E[U] = 1/2, sd of the mean √(1/12)/√n; E[(U − ½)²] = 1/12, whose estimator has sd
    # √(E[(U − ½)⁴] − 1/144)/√n = √(1/80 − 1/144)/√n = √(1/180)/√n.
    assert abs(x.mean() - 0.5) < 5.0 * math.sqrt(1.0 / 12.0 / n)
    assert abs(np.mean((x - 0.5) ** 2) - 1.0 / 12.0) < 5.0 * math.sqrt(1.0 / 180.0 / n)


def test_uniform_chi2(table, chi2_counts):
    x = table.ravel()
    counts, _ = np.histogram(x, bins=100, range=(0.0, 1.0))
    chi2_counts(counts, np.full(100, x.size / 100), "uniform() on 100 bins")
    # Pairs of consecutive dimensions fill the unit square uniformly (the generator's use: a
    # 2D warp takes two consecutive dimensions).
    counts, _, _ = np.histogram2d(table[:, :, 0].ravel(), table[:, :, 1].ravel(), bins=20,
                                  range=[[0, 1], [0, 1]])
    chi2_counts(counts, np.full((20, 20), N_PIX * N_SAMP / 400), "(dim 0, dim 1) pairs")


def test_no_correlation_between_neighbours(table):
    # Pearson's r of independent uniforms has sd 1/√n; 5σ.
    def bound(a):
        return 5.0 / math.sqrt(a.size)

    for d in range(N_DIM - 1):  # consecutive dimensions of one sample
        a, b = table[:, :, d], table[:, :, d + 1]
        assert abs(corr(a, b)) < bound(a), f"dims {d}, {d + 1}"
    a, b = table[:-1], table[1:]  # neighbouring pixels, same sample and dim
    assert abs(corr(a, b)) < bound(a), "neighbouring pixels"
    a, b = table[:, :-1], table[:, 1:]  # neighbouring samples of one pixel
    assert abs(corr(a, b)) < bound(a), "neighbouring samples"
    other = _table(8, 0, N_PIX, 0, N_SAMP, N_DIM)  # the next seed, same everything else
    assert abs(corr(table, other)) < bound(table), "neighbouring seeds"


def test_deterministic(table):
    # The same (seed, pixel, sample, dim) gives the same value, called from Python or from a loop,
    # in any order and from any starting point of a block (the property tiling relies on).
    again = _table(7, 0, N_PIX, 0, N_SAMP, N_DIM)
    np.testing.assert_array_equal(table, again)
    block = _table(7, 600, 50, 100, 30, N_DIM)
    np.testing.assert_array_equal(block, table[600:650, 100:130])
    assert uniform(sample_key(7, 123, 45), 2) == table[123, 45, 2]
    assert int(mix64(np.uint64(12345))) == int(mix64(np.uint64(12345)))


def test_seeds_pixels_and_samples_give_different_streams(table):
    other = _table(8, 0, N_PIX, 0, N_SAMP, N_DIM)
    # Two independent 53-bit streams agree somewhere with probability ~n²/2⁵³ ≈ 1e-4.
    assert np.count_nonzero(other == table) == 0
    keys = _keys(7, 1000, 1000)  # 10⁶ (pixel, sample) keys, all distinct (collision ~ n²/2⁶⁵)
    assert np.unique(keys).size == keys.size
    assert sample_key(7, 1, 0) != sample_key(7, 0, 1)  # pixel and sample are not interchangeable
    assert sample_key(0, 0, 0) != sample_key(1, 0, 0)


def test_large_indices():
    # Pixels of a 16k² frame and samples beyond 2³² stay distinct and in range.
    key = sample_key(3, 16384 * 16384 - 1, 2**33 + 5)
    values = [uniform(key, d) for d in range(64)]
    assert all(0.0 <= v < 1.0 for v in values)
    assert len(set(values)) == 64


def test_mix64_reference_values():
    # SplitMix64 (Steele et al. 2014; Vigna's splitmix64.c): the first outputs of the generator
    # seeded with 0 are mix64(k·0x9E3779B97F4A7C15) for k = 1, 2, …; reference values from the
    # published C code.
    golden = 0x9E3779B97F4A7C15
    expected = [0xE220A8397B1DCDAF, 0x6E789E6AA1B965F4, 0x06C45D188009454F]
    for k, e in enumerate(expected, start=1):
        assert int(mix64(np.uint64((k * golden) % 2**64))) == e


# --- the sobol sampler's sequences ----------------------------------------------------------------


def test_sobol_prefixes_are_02_nets():
    """Every power-of-two prefix of a pixel's shuffled, scrambled sequence is a (0,m,2)-net: one
    point in each of the 2^m elementary intervals of every shape 2^a × 2^(m−a) (the property the
    scrambles and the shuffle must keep)."""
    from renderer.rng import block_seed, sobol_sample

    for pixel in range(40):
        seed = block_seed(np.uint64(pixel * 7919 + 1), pixel % 6)
        for m in range(1, 9):
            n = 1 << m
            pts = np.array([(sobol_sample(i, seed, 0), sobol_sample(i, seed, 1))
                            for i in range(n)])
            for a in range(m + 1):
                cells = {(int(x * (1 << a)), int(y * (1 << (m - a)))) for x, y in pts}
                assert len(cells) == n, (pixel, m, a)


def test_sobol_values_are_uniform_and_blocks_independent(chi2_counts):
    """Across pixels, a sample's values are uniform in each block, and two blocks of the same
    sample (the light's point and the BSDF direction) are independent: chi² on a 16×16 grid of
    (block 2, x; block 4, x) over sample 3 of 40,000 pixels, and on each marginal."""
    from renderer.rng import block_seed, sample_key, sobol_sample

    n = 40_000
    a = np.empty(n)
    b = np.empty(n)
    for pixel in range(n):
        ps = np.uint64(sample_key(1, pixel, 0))
        a[pixel] = sobol_sample(3, block_seed(ps, 2), 0)
        b[pixel] = sobol_sample(3, block_seed(ps, 4), 0)
    joint = np.histogram2d(a, b, bins=16, range=[[0, 1], [0, 1]])[0].ravel()
    chi2_counts(joint, np.full(joint.size, n / joint.size), "joint of two blocks")
    for v, what in ((a, "block 2"), (b, "block 4")):
        counts = np.histogram(v, bins=64, range=(0, 1))[0]
        chi2_counts(counts, np.full(64, n / 64), what)


def _burley_sobol(sample: int, seed: int, component: int) -> float:
    """Burley's shuffled, Owen-scrambled Sobol' point spelled out in Python integers, as the paper
    has it (JCGT 9(4), listings 2-4): the index shuffled by a nested uniform scramble, the point
    generated (dimension 0: the bit reversal; dimension 1: the Pascal matrix's direction
    numbers), then scrambled, with the seeds the renderer derives (mix64 of the block's seed)."""
    mask = 0xFFFFFFFF

    def reverse(x):
        return int(f"{x & mask:032b}"[::-1], 2)

    def laine_karras(x, s):
        x = (x + s) & mask
        for k in (0x6C50B47C, 0xB82F1E52, 0xC7AFE638, 0x8D22F6E6):
            x ^= (x * k) & mask
        return x

    def owen(x, s):
        return reverse(laine_karras(reverse(x), s))

    index = owen(sample & mask, seed)
    if component == 0:
        v = reverse(index)
    else:
        v, direction = 0, 1 << 31
        for bit in range(32):
            if index >> bit & 1:
                v ^= direction
            direction ^= direction >> 1
    scramble = int(mix64(np.uint64((seed + component + 1) % 2**64))) & mask
    return owen(v, scramble) / 2**32


def test_sobol_sample_is_burleys_construction_bit_for_bit():
    """The kernels' shortcuts (the two cancelled bit reversals, the Pascal matrix folded with the
    reversals into byte tables, the per-pixel seeds computed once) give Burley's values exactly,
    for both components, small and large indices and many seeds."""
    from renderer.rng import block_seed, scramble_seed, sobol_block_seeds, sobol_sample, sobol_value

    rng = np.random.default_rng(5)
    samples = [0, 1, 2, 3, 255, 256, 65535, 65536, 2**31 - 1, 2**31, 2**32 - 1,
               *rng.integers(0, 2**32, 40).tolist()]
    for pixel_seed in [0, 1, 2**63 + 12345, *rng.integers(0, 2**63, 6).tolist()]:
        table = np.zeros((11, 3), np.uint64)
        sobol_block_seeds(np.uint64(pixel_seed), table)
        for block in range(11):
            seed = int(block_seed(np.uint64(pixel_seed), block))
            assert int(table[block, 0]) == seed
            for component in (0, 1):
                assert int(table[block, 1 + component]) == int(scramble_seed(seed, component))
                for i in samples:
                    expected = _burley_sobol(i, seed, component)
                    assert sobol_sample(i, seed, component) == expected, (i, seed, component)
                    assert sobol_value(i, table[block, 0], table[block, 1 + component],
                                       component) == expected
