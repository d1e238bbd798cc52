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
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)  # shifts
_ONE = np.uint64(1)
_TWO_POW_M53 = 1.0 / 9007199254740992.0


@kernel
def mix64(z):
    """SplitMix64's output function: a bijective 64-bit avalanche mix."""
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@kernel
def pixel_key(seed, pixel):
    """The key every sample of one pixel starts from (``sample_key``'s first two mixes): a
    kernel that draws many samples of a pixel mixes it once."""
    return mix64(mix64(np.uint64(seed) + _GOLDEN) ^ np.uint64(pixel))


@kernel
def key_of_sample(key_of_pixel, sample):
    """``sample_key`` from the pixel's ``pixel_key``."""
    return mix64(key_of_pixel ^ (np.uint64(sample) * _GOLDEN + _ONE))


@kernel
def sample_key(seed, pixel, sample):
    """The key of one sample: pixel is the global pixel index y·width + x, sample is global too."""
    return key_of_sample(pixel_key(seed, pixel), sample)


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
# Laine–Karras hash multipliers (Burley's constants)
_LK = tuple(np.uint64(m) for m in (0x6C50B47C, 0xB82F1E52, 0xC7AFE638, 0x8D22F6E6))
# bit reversal: swap bits, pairs, nibbles, bytes, halves (mask, shift)
_B = tuple(np.uint64(m) for m in (0x55555555, 0x33333333, 0x0F0F0F0F, 0x00FF00FF, 0x0000FFFF))
_SH = (np.uint64(1), np.uint64(2), np.uint64(4), np.uint64(8), np.uint64(16))
_TWO_POW_M32 = 1.0 / 4294967296.0


@kernel
def reverse_bits32(x):
    x = ((x >> _SH[0]) & _B[0]) | ((x & _B[0]) << _SH[0])
    x = ((x >> _SH[1]) & _B[1]) | ((x & _B[1]) << _SH[1])
    x = ((x >> _SH[2]) & _B[2]) | ((x & _B[2]) << _SH[2])
    x = ((x >> _SH[3]) & _B[3]) | ((x & _B[3]) << _SH[3])
    return ((x >> _SH[4]) & _B[4]) | ((x & _B[4]) << _SH[4])


@kernel
def _laine_karras(x, seed):
    x = (x + seed) & _U32
    x ^= (x * _LK[0]) & _U32
    x ^= (x * _LK[1]) & _U32
    x ^= (x * _LK[2]) & _U32
    x ^= (x * _LK[3]) & _U32
    return x


@kernel
def nested_uniform_scramble(x, seed):
    """An Owen scramble of the 32-bit binary fraction x (Laine–Karras hash, Burley's form)."""
    return reverse_bits32(_laine_karras(reverse_bits32(x), seed))


def _byte_tables(images: list[int]) -> np.ndarray:
    """A linear map over GF(2) of 32-bit values, given the image of each bit, as four byte tables:
    the image of x is the XOR of its four bytes' entries."""
    tables = np.zeros((4, 256), np.uint64)
    for byte in range(4):
        for value in range(256):
            r = 0
            for bit in range(8):
                if value >> bit & 1:
                    r ^= images[8 * byte + bit]
            tables[byte, value] = r
    return tables


def _pascal_directions() -> list[int]:
    """Sobol' dimension 2's direction numbers: the generator matrix (the Pascal matrix mod 2),
    column i the image of bit i of the index."""
    directions = []
    v = 1 << 31
    for _ in range(32):
        directions.append(v)
        v ^= v >> 1
    return directions


def _reverse32(x: int) -> int:
    return int(f"{x:032b}"[::-1], 2)


# x ↦ reverse(pascal(reverse(x))), Sobol' dimension 2 between two bit reversals: the scrambled
# value of the second component is reverse(LK(reverse(pascal(reverse(shuffled))))), and this map
# takes the shuffled index straight to the scramble's input (two of the four bit reversals gone,
# the values the same bit for bit). Bit i of x is bit 31 − i of reverse(x).
_PASCAL_REVERSED = _byte_tables([_reverse32(v) for v in reversed(_pascal_directions())])
_BYTE = np.uint64(0xFF)


@kernel
def _linear_map(tables, x):
    """The linear map ``tables`` (``_byte_tables``) of the 32-bit value x."""
    r = tables[0, x & _BYTE]
    r ^= tables[1, (x >> np.uint64(8)) & _BYTE]
    r ^= tables[2, (x >> np.uint64(16)) & _BYTE]
    r ^= tables[3, (x >> np.uint64(24)) & _BYTE]
    return r


@kernel
def block_seed(pixel_seed, block):
    """The 32-bit seed of one block of dimensions of one pixel."""
    return mix64(np.uint64(pixel_seed) + (np.uint64(block) + _ONE) * _GOLDEN) & _U32


@kernel
def scramble_seed(seed, component):
    """The 32-bit seed of the point scramble of one component of the block with this seed."""
    return mix64(np.uint64(seed) + np.uint64(component) + _ONE) & _U32


@kernel
def sobol_block_seeds(pixel_seed, out):
    """Fill out (blocks, 3) with each block's seeds for one pixel: the index shuffle's
    (``block_seed``) and the point scrambles' of components 0 and 1 (``scramble_seed``), so a
    sample's values cost no hashing of seeds (``sobol_value``)."""
    for b in range(out.shape[0]):
        s = block_seed(pixel_seed, b)
        out[b, 0] = s
        out[b, 1] = scramble_seed(s, 0)
        out[b, 2] = scramble_seed(s, 1)


@kernel
def sobol_value(sample, seed, scramble, component):
    """``sobol_sample`` with the block's scramble seed of this component given."""
    # The shuffled index is reverse(LK(reverse(sample))), and van der Corput is its reversal: LK
    # of the reversed sample, with the two reversals between them cancelled. The nested uniform
    # scramble then takes the reversed value
    shuffled = _laine_karras(reverse_bits32(np.uint64(sample) & _U32), np.uint64(seed))
    if component == 0:
        y = reverse_bits32(shuffled)
    else:
        y = _linear_map(_PASCAL_REVERSED, shuffled)
    return float(reverse_bits32(_laine_karras(y, np.uint64(scramble)))) * _TWO_POW_M32


@kernel
def sobol_sample(sample, seed, component):
    """Component 0 or 1 of point ``sample`` of the shuffled, scrambled (0,2)-sequence ``seed``."""
    return sobol_value(sample, seed, scramble_seed(seed, component), component)

