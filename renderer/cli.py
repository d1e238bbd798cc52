"""The ``lucent`` command line: render and validate scenes on this machine.

    lucent render SCENE.json -o OUT.{exr,png,pfm,npy} [--spp N] [--seed S] [--threads N]
    lucent validate SCENE.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def _load(path: str):
    from renderer.scene import SceneError, load_scene_file

    try:
        return load_scene_file(path)
    except SceneError as err:
        print(f"{path}: {len(err.errors)} error(s) to fix:", file=sys.stderr)
        for where, message in err.errors:
            print(f"  {where}: {message}", file=sys.stderr)
        return None
    except OSError as err:
        print(f"{path}: cannot read: {err.strerror or err}", file=sys.stderr)
        return None


def cmd_validate(args: argparse.Namespace) -> int:
    scene = _load(args.scene)
    if scene is None:
        return 1
    n_tris = sum(len(o.arrays()[1]) for o in scene.objects if o.type == "mesh")
    print(
        f"{args.scene}: ok — {scene.film.width}x{scene.film.height}, {scene.render.spp} spp, "
        f"{len(scene.materials)} materials, {len(scene.objects)} objects ({n_tris} triangles), "
        f"{len(scene.lights)} lights"
    )
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    from renderer.film.image_io import write_image

    out = Path(args.output)
    if out.suffix.lower() not in {".exr", ".png", ".pfm", ".npy"}:
        print(f"{out}: unsupported image type (use .exr, .png, .pfm or .npy)", file=sys.stderr)
        return 2
    scene = _load(args.scene)
    if scene is None:
        return 1
    if args.seed is not None:
        scene.render.seed = args.seed
    spp = args.spp if args.spp is not None else scene.render.spp
    if spp < 1:
        print("--spp must be >= 1", file=sys.stderr)
        return 2

    import numba
    from tqdm import tqdm

    from renderer.render import render_buffer
    from renderer.scene.compile import CompileError, compile_scene

    t0 = time.perf_counter()
    try:
        compiled = compile_scene(scene)
    except CompileError as err:
        print(f"{args.scene}: {err}", file=sys.stderr)
        return 1
    t_compile = time.perf_counter() - t0
    threads = args.threads or numba.config.NUMBA_NUM_THREADS
    print(
        f"{args.scene}: {compiled.width}x{compiled.height}, {spp} spp, "
        f"{compiled.info['primitives']} primitives, {compiled.info['lights']} lights, "
        f"{threads} threads (scene compiled in {t_compile:.2f} s)",
        file=sys.stderr,
    )
    total = compiled.width * compiled.height * spp
    with tqdm(total=total, unit="samples", unit_scale=True, disable=args.quiet,
              file=sys.stderr, smoothing=0.3) as bar:

        def progress(done: int, _total: int, _seconds: float) -> None:
            bar.update(done - bar.n)

        t0 = time.perf_counter()
        buf = render_buffer(compiled, spp, threads=threads, progress=progress)
        seconds = time.perf_counter() - t0
    write_image(out, buf.mean(), exposure=args.exposure, tonemap=args.tonemap)
    dropped = buf.total_dropped
    print(
        f"wrote {out}: {total / seconds:,.0f} samples/s over {seconds:.2f} s"
        f" (JIT compile or cache load included)"
        + (f"; {dropped} non-finite samples dropped" if dropped else ""),
        file=sys.stderr,
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lucent", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("render", help="render a scene on this machine")
    p.add_argument("scene", help="scene JSON file (scene format v1)")
    p.add_argument("-o", "--output", required=True, help="image file: .exr, .png, .pfm or .npy")
    p.add_argument("--spp", type=int, help="samples per pixel (default: the scene's render.spp)")
    p.add_argument("--seed", type=int, help="random seed (default: the scene's render.seed)")
    p.add_argument("--threads", type=int, help="render threads (default: all cores)")
    p.add_argument("--exposure", type=float, default=0.0,
                   help="PNG only: exposure in stops, the image is scaled by 2^EV (default 0)")
    p.add_argument("--tonemap", choices=["clamp", "reinhard", "aces"], default="clamp",
                   help="PNG only: tone map before sRGB encoding (default clamp)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("validate", help="check a scene and print the errors to fix")
    p.add_argument("scene", help="scene JSON file")
    p.set_defaults(func=cmd_validate)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
