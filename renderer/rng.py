"""Counter-based random numbers: every value is a pure function of (seed, pixel, sample, dimension).

Nothing is carried from one sample to the next, so an image is the same however the frame is cut
into tiles and sample ranges and whichever thread or worker renders each piece.

The generator is SplitMix64 (Steele, Lea & Flood, "Fast splittable pseudorandom number
generators", OOPSLA 2014) used as a hash: a sample's key is the mix of (seed, pixel, sample), and
dimension d is the d-th output of the SplitMix64 stream started at that key. SplitMix64's finalizer
passes BigCrush on a counter input, which is exactly this use.
"""

from __future__ import annotations

import numpy as np

from renderer.jit import kernel

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_ONE = np.uint64(1)
_TWO_POW_M53 = 1.0 / 9007199254740992.0


@kernel
def mix64(z):
    """SplitMix64's output function: a bijective 64-bit avalanche mix."""
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@kernel
def sample_key(seed, pixel, sample):
    """The key of one sample: pixel is the global pixel index y·width + x, sample is global too."""
    k = mix64(np.uint64(seed) + _GOLDEN)
    k = mix64(k ^ np.uint64(pixel))
    return mix64(k ^ (np.uint64(sample) * _GOLDEN + _ONE))


@kernel
def uniform(key, dim):
    """The uniform value in [0, 1) of dimension ``dim`` of the sample with this key."""
    z = mix64(key + (np.uint64(dim) + _ONE) * _GOLDEN)
    return float(z >> _S11) * _TWO_POW_M53


# --- the "sobol" sampler: shuffled, Owen-scrambled Sobol' (0,2)-sequences ------------------------
# Burley, "Practical Hash-based Owen Scrambling", JCGT 9(4), 2020: the first two Sobol' dimensions
# (van der Corput and the Pascal matrix) form a (0,2)-sequence, so every power-of-two prefix of a
# pixel's samples is a (0,m,2)-net: one point in each elementary interval. Each block of
# dimensions (the camera pair, the first vertex's light and BSDF samples) gets its own index
# shuffle and point scramble (nested uniform scrambles keyed by pixel and block), so the blocks
# are independent of each other (Burley's padding) and every value is uniform: the estimate is
# unbiased for any sample count. All arithmetic is on 32-bit values held in uint64.

_U32 = np.uint64(0xFFFFFFFF)
_TOP = np.uint64(1 << 31)
_LK1 = np.uint64(0x6C50B47C)
_LK2 = np.uint64(0xB82F1E52)
_LK3 = np.uint64(0xC7AFE638)
_LK4 = np.uint64(0x8D22F6E6)
_B1 = np.uint64(0x55555555)
_B2 = np.uint64(0x33333333)
_B4 = np.uint64(0x0F0F0F0F)
_B8 = np.uint64(0x00FF00FF)
_B16 = np.uint64(0x0000FFFF)
_SH = (np.uint64(1), np.uint64(2), np.uint64(4), np.uint64(8), np.uint64(16))
_TWO_POW_M32 = 1.0 / 4294967296.0


@kernel
def reverse_bits32(x):
    x = ((x >> _SH[0]) & _B1) | ((x & _B1) << _SH[0])
    x = ((x >> _SH[1]) & _B2) | ((x & _B2) << _SH[1])
    x = ((x >> _SH[2]) & _B4) | ((x & _B4) << _SH[2])
    x = ((x >> _SH[3]) & _B8) | ((x & _B8) << _SH[3])
    return ((x >> _SH[4]) & _B16) | ((x & _B16) << _SH[4])


@kernel
def _laine_karras(x, seed):
    x = (x + seed) & _U32
    x ^= (x * _LK1) & _U32
    x ^= (x * _LK2) & _U32
    x ^= (x * _LK3) & _U32
    x ^= (x * _LK4) & _U32
    return x


@kernel
def nested_uniform_scramble(x, seed):
    """An Owen scramble of the 32-bit binary fraction x (Laine–Karras hash, Burley's form)."""
    return reverse_bits32(_laine_karras(reverse_bits32(x), seed))


def _pascal_tables() -> np.ndarray:
    """Sobol' dimension 2 as four byte tables: the generator (the Pascal matrix mod 2) is linear
    over GF(2), so the point of an index is the XOR of the points of its four bytes."""
    directions = []
    v = 1 << 31
    for _ in range(32):
        directions.append(v)
        v ^= v >> 1
    tables = np.zeros((4, 256), np.uint64)
    for byte in range(4):
        for value in range(256):
            r = 0
            for bit in range(8):
                if value >> bit & 1:
                    r ^= directions[8 * byte + bit]
            tables[byte, value] = r
    return tables


_PASCAL = _pascal_tables()
_BYTE = np.uint64(0xFF)


@kernel
def _sobol_pascal(index):
    """Sobol' dimension 2, 32 bits."""
    r = _PASCAL[0, index & _BYTE]
    r ^= _PASCAL[1, (index >> np.uint64(8)) & _BYTE]
    r ^= _PASCAL[2, (index >> np.uint64(16)) & _BYTE]
    r ^= _PASCAL[3, (index >> np.uint64(24)) & _BYTE]
    return r


@kernel
def block_seed(pixel_seed, block):
    """The 32-bit seed of one block of dimensions of one pixel."""
    return mix64(np.uint64(pixel_seed) + (np.uint64(block) + _ONE) * _GOLDEN) & _U32


@kernel
def sobol_sample(sample, seed, component):
    """Component 0 or 1 of point ``sample`` of the shuffled, scrambled (0,2)-sequence ``seed``."""
    seed = np.uint64(seed)
    # The shuffled index is reverse(LK(reverse(sample))), and van der Corput is its reversal: LK
    # of the reversed sample, with the two reversals between them cancelled
    shuffled = _laine_karras(reverse_bits32(np.uint64(sample) & _U32), seed)
    if component == 0:
        v = shuffled
    else:
        v = _sobol_pascal(reverse_bits32(shuffled))
    v = nested_uniform_scramble(v, mix64(seed + np.uint64(component) + _ONE) & _U32)
    return float(v) * _TWO_POW_M32
