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
