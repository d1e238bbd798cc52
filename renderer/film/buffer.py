"""Sample buffers: what a tile render returns and what the farm adds together.

A buffer covers a rectangle of the frame and holds, per pixel, the sum of the radiance of its
samples, the sum of their squares (for a variance estimate), the number of samples added, and the
number of samples dropped because their radiance was not finite. Buffers of the same pixels merge
by addition, in any order and any grouping: that is what makes a frame the same however it was
cut into tiles and passes.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np

# The first bytes of a serialized buffer (``SampleBuffer.to_bytes``), format 1.
MAGIC = b"LSB1\0\0\0\0"
_HEADER = len(MAGIC) + 16  # the magic, then x0, y0, height, width as int32


@dataclass
class SampleBuffer:
    x0: int
    y0: int
    sum: np.ndarray  # (h, w, 3) float64: Σ L
    sum_sq: np.ndarray  # (h, w, 3) float64: Σ L²
    count: np.ndarray  # (h, w) int64: samples added
    dropped: np.ndarray  # (h, w) int64: non-finite samples left out
    # (h, w) int64: path segments traced for the pixel's samples (their cost, which adaptive
    # sampling weighs); not serialized: None in a buffer read back by ``from_bytes``
    segments: np.ndarray | None = None

    @classmethod
    def empty(cls, x0: int, y0: int, width: int, height: int) -> SampleBuffer:
        return cls(
            x0=x0,
            y0=y0,
            sum=np.zeros((height, width, 3)),
            sum_sq=np.zeros((height, width, 3)),
            count=np.zeros((height, width), np.int64),
            dropped=np.zeros((height, width), np.int64),
            segments=np.zeros((height, width), np.int64),
        )

    @property
    def width(self) -> int:
        return self.sum.shape[1]

    @property
    def height(self) -> int:
        return self.sum.shape[0]

    def add(self, other: SampleBuffer) -> SampleBuffer:
        """Add ``other`` in place; its rectangle must lie inside this one (a tile into a frame)."""
        ox, oy = other.x0 - self.x0, other.y0 - self.y0
        if ox < 0 or oy < 0 or ox + other.width > self.width or oy + other.height > self.height:
            raise ValueError(
                f"buffer at ({other.x0}, {other.y0}) size {other.width}x{other.height} does not "
                f"fit in buffer at ({self.x0}, {self.y0}) size {self.width}x{self.height}"
            )
        window = (slice(oy, oy + other.height), slice(ox, ox + other.width))
        self.sum[window] += other.sum
        self.sum_sq[window] += other.sum_sq
        self.count[window] += other.count
        self.dropped[window] += other.dropped
        if self.segments is not None and other.segments is not None:
            self.segments[window] += other.segments
        else:
            self.segments = None  # a part without its cost: the whole has none
        return self

    def __add__(self, other: SampleBuffer) -> SampleBuffer:
        if (self.x0, self.y0, self.sum.shape) != (other.x0, other.y0, other.sum.shape):
            raise ValueError("only buffers of the same rectangle can be summed with +")
        return SampleBuffer.empty(self.x0, self.y0, self.width, self.height).add(self).add(other)

    @property
    def drawn(self) -> np.ndarray:
        """Samples drawn per pixel (h, w): those added and those dropped as non-finite."""
        return self.count + self.dropped

    def mean(self) -> np.ndarray:
        """The pixel estimates (h, w, 3) float32; pixels without samples are 0."""
        n = np.maximum(self.count, 1)[..., None]
        return (self.sum / n).astype(np.float32)

    def variance_of_mean(self) -> np.ndarray:
        """Unbiased estimate of the variance of each pixel's mean, (h, w, 3); inf below 2
        samples."""
        n = self.count[..., None].astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            mean = self.sum / n
            var = (self.sum_sq - n * mean * mean) / (n - 1.0)
            out = np.maximum(var, 0.0) / n
        return np.where(n >= 2, out, np.inf)

    @property
    def total_dropped(self) -> int:
        return int(self.dropped.sum())

    def to_bytes(self) -> bytes:
        """A compact, pickle-free serialization: a 24-byte header (``MAGIC``, then x0, y0,
        height, width as little-endian int32) and the four arrays' raw little-endian bytes, in
        the order sum, sum_sq (float64), count, dropped (int64).

        A farm task writes one and its merge reads two and writes one; numpy's ``.npz`` (a zip
        archive of .npy files) took 0.2-0.4 ms to write and 0.6-0.8 ms to read for a 32-px tile,
        ~2 ms of a task's ~6 ms in-task overhead; this format takes 6-17 us
        (``python -m bench.buffer_codec``).
        """
        h, w = self.height, self.width
        header = np.array([self.x0, self.y0, h, w], "<i4").tobytes()
        return b"".join((MAGIC, header,
                         np.ascontiguousarray(self.sum, "<f8").tobytes(),
                         np.ascontiguousarray(self.sum_sq, "<f8").tobytes(),
                         np.ascontiguousarray(self.count, "<i8").tobytes(),
                         np.ascontiguousarray(self.dropped, "<i8").tobytes()))

    @classmethod
    def from_bytes(cls, data: bytes) -> SampleBuffer:
        """Read ``to_bytes``'s format, or the ``.npz`` of earlier versions (still read: pass
        buffers and accumulations that a running farm stored before an upgrade). The arrays are
        writable copies. Raises ``ValueError`` for anything else, whatever its length."""
        if data[:2] == b"PK":  # a zip: the .npz format of earlier versions
            with np.load(io.BytesIO(data), allow_pickle=False) as z:
                x0, y0 = (int(v) for v in z["origin"])
                return cls(x0=x0, y0=y0, sum=z["sum"], sum_sq=z["sum_sq"], count=z["count"],
                           dropped=z["dropped"])
        if data[:len(MAGIC)] != MAGIC or len(data) < _HEADER:
            raise ValueError("not a sample buffer (bad magic or truncated header)")
        x0, y0, h, w = (int(v) for v in np.frombuffer(data, "<i4", 4, len(MAGIC)))
        if h < 0 or w < 0 or len(data) != _HEADER + 64 * h * w:
            raise ValueError(f"a sample buffer of {len(data)} bytes cannot hold {w}x{h} pixels")
        n = h * w
        # copies in native byte order: writable, the merger adds into them
        sums = np.frombuffer(data, "<f8", 6 * n, _HEADER).astype(np.float64)
        counts = np.frombuffer(data, "<i8", 2 * n, _HEADER + 48 * n).astype(np.int64)
        sums, counts = sums.reshape(2, h, w, 3), counts.reshape(2, h, w)
        return cls(x0=x0, y0=y0, sum=sums[0], sum_sq=sums[1], count=counts[0],
                   dropped=counts[1])
