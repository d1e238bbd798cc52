"""Encoding and decoding one tile's sample buffer: the raw format of ``SampleBuffer.to_bytes``
against numpy's ``.npz``, the format before it (still read by ``from_bytes``).

    .venv/bin/python -m bench.buffer_codec [--tile 32] [--repeats 2000]
"""

from __future__ import annotations

import argparse
import io
import time

import numpy as np

from renderer.film.buffer import SampleBuffer


def npz_bytes(buf: SampleBuffer) -> bytes:
    out = io.BytesIO()
    np.savez(out, origin=np.array([buf.x0, buf.y0]), sum=buf.sum, sum_sq=buf.sum_sq,
             count=buf.count, dropped=buf.dropped)
    return out.getvalue()


def per_call_ms(fn, repeats: int) -> float:
    t0 = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - t0) / repeats * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tile", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=2000)
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    buf = SampleBuffer.empty(0, 0, args.tile, args.tile)
    buf.sum[:] = rng.random(buf.sum.shape)
    buf.sum_sq[:] = rng.random(buf.sum.shape)
    buf.count[:] = 8
    raw, npz = buf.to_bytes(), npz_bytes(buf)
    print(f"{args.tile}x{args.tile} tile, per call, mean of {args.repeats}:")
    print(f"  raw: {len(raw)} bytes, write {per_call_ms(buf.to_bytes, args.repeats):.3f} ms, "
          f"read {per_call_ms(lambda: SampleBuffer.from_bytes(raw), args.repeats):.3f} ms")
    print(f"  npz: {len(npz)} bytes, write {per_call_ms(lambda: npz_bytes(buf), args.repeats):.3f}"
          f" ms, read {per_call_ms(lambda: SampleBuffer.from_bytes(npz), args.repeats):.3f} ms")


if __name__ == "__main__":
    main()
