"""The ``lucent`` command line: render scenes here, or run a farm, join it and submit jobs to it.

On this machine:

    lucent render SCENE.json -o OUT.{exr,png,pfm,npy} [--spp N] [--seed S] [--threads N]
                  [--denoise]
    lucent validate SCENE.json

On a farm (the code lives in ``services/`` and ``worker/``):

    lucent up [--host 127.0.0.1] [--port 8000] [--workers N] [--tags gpu,bigmem]
              [--kernel scalar|wavefront|gpu|packet]
    lucent worker --redis URL [--concurrency N] [--threads N] [--tags gpu,bigmem]
                  [--kernel scalar|wavefront|gpu|packet]
    lucent submit SCENE.json [--server URL] [--wait] [-o OUT.{exr,png,npy}]
    lucent demo [SCENE.json] [-o OUT ...]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

# Where `lucent up` serves the API by default (its --host and --port).
DEFAULT_SERVER = "http://127.0.0.1:8000"
# Processes serving the API in `lucent up` (uvicorn --workers): one process's event loop and GIL
# bound the status polls it answers (docs/performance.md, "Load").
API_PROCESSES = 2
# renderer.render.KERNELS, written out: the parser is built without importing the renderer
# (numba); tests/services/test_cli.py checks that the two agree
KERNELS = ("scalar", "wavefront", "gpu", "packet")
# What a cold compile of the kernels takes on a 2-core machine (docs/performance.md, "Start-up":
# `python -m bench.startup`).
COLD_COMPILE = "a minute on 2 cores"


def kernels_cached() -> bool:
    """Whether a worker warm-up already filled this renderer version's kernel cache."""
    from renderer import warm_marker

    return warm_marker().exists()


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

    out = Path(args.output)
    if out.suffix.lower() not in {".exr", ".png", ".pfm", ".npy"}:
        print(f"{out}: unsupported image type (use .exr, .png, .pfm or .npy)", file=sys.stderr)
        return 2
    scene = _load(args.scene)
    if scene is None:
        return 1
    if args.seed is not None:
        scene.render.seed = args.seed
    if args.sampler is not None:
        scene.render.sampler = args.sampler
    # (before the compile: auto chooses its method for the target)
    for field, value in _render_options(args).items():
        setattr(scene.render, field, value)
    spp = args.spp if args.spp is not None else scene.render.spp
    if spp < 1:
        print("--spp must be >= 1", file=sys.stderr)
        return 2
    if args.denoise:
        from renderer.film.denoise import MISSING, oidn_available

        if not oidn_available():
            print(MISSING, file=sys.stderr)
            return 2
    aovs = list(scene.film.aovs)
    if aovs and out.suffix.lower() != ".exr":
        print(f"film.aovs ({', '.join(aovs)}): layers are written to .exr outputs only; {out} "
              "gets the image alone", file=sys.stderr)
        aovs = []

    import numba
    from tqdm import tqdm

    from renderer.film.adaptive import AIM, PILOT, aim_reached, noise_target
    from renderer.materials.auto import describe_choice
    from renderer.render import render_buffer
    from renderer.scene.compile import CompileError, compile_scene
    from renderer.wavefront.cpu import unsupported

    t0 = time.perf_counter()
    try:
        compiled = compile_scene(scene)
    except CompileError as err:
        print(f"{args.scene}: {err}", file=sys.stderr)
        return 1
    t_compile = time.perf_counter() - t0
    for name, choice in compiled.info["auto"].items():
        print(f"auto chose {choice['method']} for {name!r}: "
              f"{describe_choice(choice['reason'], choice['expected_error'])}", file=sys.stderr)
    threads = args.threads or numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]
    samples = (f"{spp} spp" if compiled.target_error is None else
               f"target relMSE {compiled.target_error:g}, at most {spp} spp a pixel")
    print(
        f"{args.scene}: {compiled.width}x{compiled.height}, {samples}, "
        f"{compiled.info['primitives']} primitives, {compiled.info['lights']} lights, "
        f"{threads} threads (scene compiled in {t_compile:.2f} s)",
        file=sys.stderr,
    )
    if not _kernel_usable(args.kernel):
        return 1
    from renderer.packet import unsupported as packet_unsupported

    if args.kernel == "packet":
        # the default: say which kernel renders a scene the packet kernel leaves to the scalar one
        if (reason := packet_unsupported(compiled)) is not None:
            print(f"the packet kernel does not cover {reason}: the scalar kernel renders it",
                  file=sys.stderr)
    elif args.kernel != "scalar" and (reason := unsupported(compiled)) is not None:
        by = "the scalar kernel" if args.kernel == "wavefront" else "the GPU's path kernel"
        print(f"the wavefront stages do not cover {reason}: {by} renders it", file=sys.stderr)
    # (with a target, the pilot's samples until its plan says how many the loop will take)
    total = compiled.width * compiled.height * (spp if compiled.target_error is None
                                                else min(PILOT, spp))
    with tqdm(total=total, unit="samples", unit_scale=True, disable=args.quiet,
              file=sys.stderr, smoothing=0.3) as bar:

        def progress(done: int, planned: int, _seconds: float) -> None:
            if compiled.target_error is not None:
                # The loop's samples, not the cap's: the pilot's plan, raised to what a round
                # plans past it; the render's own total once it ends (done == planned)
                bar.total = done if done == planned else max(bar.total, planned)
                bar.refresh()
            bar.update(done - bar.n)

        def plan(mean_spp: float, expected: float) -> None:
            # (called only with a target)
            bar.total = max(round(mean_spp * compiled.width * compiled.height), bar.n)
            target = float(compiled.target_error or 0.0)
            bias = compiled.expected_bias
            if not aim_reached(expected, noise_target(target, bias)):
                # (spp caps the plan: say what it reaches, not the aim)
                bar.write(f"target relMSE {target:g}: after the pilot the allocation plans "
                          f"{mean_spp:.0f} spp a pixel on average, capped at {spp} (--spp or "
                          f"render.spp), for an expected relMSE of {expected + bias:.3g} by "
                          "the pilot's estimate: above the target, which more samples a pixel "
                          "would reach",
                          file=sys.stderr)
                return
            aim = (f"{AIM * target:.3g} ({AIM:g} × target)" if bias == 0.0 else
                   f"{AIM * noise_target(target, bias):.3g} from the samples' noise ({AIM:g} × "
                   f"{noise_target(target, bias):.3g}: the target less the bias auto's models "
                   f"may add, {bias:.3g})")
            if mean_spp < min(PILOT, spp):
                # (the loop stopped at the pilot's first look: those samples reach the aim)
                bar.write(f"target relMSE {target:g}: the pilot's first {mean_spp:.0f} spp a "
                          f"pixel already reach an expected relMSE of {aim}", file=sys.stderr)
                return
            bar.write(f"target relMSE {target:g}: after the pilot the allocation plans "
                      f"{mean_spp:.0f} spp a pixel on average (at most {spp}) to reach an "
                      f"expected relMSE of {aim}", file=sys.stderr)

        t0 = time.perf_counter()
        buf = render_buffer(compiled, spp, threads=threads, progress=progress,
                            kernel=args.kernel,
                            plan=plan if compiled.target_error is not None else None)
        seconds = time.perf_counter() - t0
    _write_render(args, out, compiled, buf, aovs, threads)
    from renderer.film.adaptive import stopping_error

    if compiled.target_error is not None:
        noise = stopping_error(buf)
        bias = compiled.expected_bias
        # (the frame's expected relMSE: the samples' noise and, at most, auto's models' bias)
        reached = noise + bias
        capped = reached > compiled.target_error and int(buf.count.max(initial=0)) >= spp
        parts = "" if bias == 0.0 else (f"; the samples' noise {noise:.3g} and the bias of "
                                        f"auto's models, at most {bias:.3g}")
        print(f"reached: expected relMSE {reached:.3g} (target "
              f"{compiled.target_error:g}{parts}), {buf.count.mean():.0f} spp a pixel on average "
              f"({int(buf.count.min())}–{int(buf.count.max())})"
              + (f"; pixels stopped at the most a pixel takes, {spp} spp (--spp or "
                 "render.spp): more reaches the target" if capped else ""), file=sys.stderr)
        total = int(buf.count.sum() + buf.dropped.sum())
    elif buf.count.size and int(buf.count.min()) >= 2:
        # (the same estimate from each pixel's own samples: what a target would stop on)
        print(f"expected relMSE {stopping_error(buf):.3g} (estimated from the samples' "
              f"variance{'; of the image before denoising' if args.denoise else ''})",
              file=sys.stderr)
    dropped = buf.total_dropped
    print(
        f"wrote {out}: {total / seconds:,.0f} samples/s over {seconds:.2f} s"
        f" (JIT compile or cache load included)"
        + (f"; {dropped} non-finite samples dropped" if dropped else ""),
        file=sys.stderr,
    )
    return 0


# Primary rays a pixel for the albedo, normal and depth AOVs (renderer.film.aov): enough to
# antialias their edges, a small cost beside the image's samples
AOV_SPP = 8


def _write_render(args: argparse.Namespace, out: Path, compiled, buf, aovs: list[str],
                  threads: int) -> None:
    """Write the frame (and its AOV layers to an .exr); with ``--denoise``, the denoised frame
    to ``out`` and the noisy one beside it as ``<stem>_noisy<ext>``."""
    from renderer.film.aov import frame_aovs
    from renderer.film.image_io import write_exr_layers, write_image

    wanted = list(dict.fromkeys(aovs + (["albedo", "normal"] if args.denoise else [])))
    layers = frame_aovs(compiled, buf, wanted, spp=AOV_SPP, threads=threads) if wanted else {}
    layers_out = {name: layers[name] for name in aovs}
    beauty = buf.mean()

    def write(path: Path, image) -> None:
        if layers_out:
            write_exr_layers(path, image, layers_out)
        else:
            write_image(path, image, exposure=args.exposure, tonemap=args.tonemap)

    if args.denoise:
        from renderer.film.denoise import denoise

        t0 = time.perf_counter()
        clean = denoise(beauty, layers["albedo"], layers["normal"])
        noisy = out.with_name(f"{out.stem}_noisy{out.suffix}")
        write(noisy, beauty)
        print(f"denoised with Open Image Denoise in {time.perf_counter() - t0:.2f} s (the noisy "
              f"image: {noisy})", file=sys.stderr)
        beauty = clean
    write(out, beauty)
    if layers_out:
        print(f"{out}: layers {', '.join(layers_out)} beside the image", file=sys.stderr)


def cmd_up(args: argparse.Namespace) -> int:
    """The farm on this machine: Redis (embedded unless REDIS_URL), workers and the API."""

    from services.launcher import LocalFarm

    if not _kernel_usable(args.kernel):
        return 1
    farm = LocalFarm(args.host, args.port, args.workers, os.environ.get("REDIS_URL") or None,
                     threads=args.threads, api_processes=args.api_processes,
                     tags=args.tags, kernel=args.kernel)
    try:
        farm.start(serve_in_thread=False)
        print(f"Lucent farm at {farm.url} (API docs {farm.url}/docs); Redis {farm.redis_url}"
              f"{' (embedded)' if farm.redis else ''}; {farm.workers} worker processes, "
              f"{farm.api_processes} API process(es). "
              "Ctrl-C stops everything.", file=sys.stderr, flush=True)
        farm.serve_forever()  # returns on SIGINT or SIGTERM
    finally:
        farm.stop()
        print("Lucent farm stopped.", file=sys.stderr)
    return 0


def _kernel_usable(kernel: str | None) -> bool:
    """``--kernel gpu`` only where a CUDA GPU is seen; else say why (False). The check initialises
    CUDA in this process, which is not one a worker's pool forks from (``lucent worker`` execs
    Celery, ``lucent up`` starts it as a child)."""
    if kernel != "gpu":
        return True
    from renderer.wavefront import gpu_missing

    missing = gpu_missing()
    if missing is not None:
        print(f"--kernel gpu: {missing}", file=sys.stderr)
    return missing is None


def cmd_worker(args: argparse.Namespace) -> int:
    """Join a farm: a Celery worker node (replaces this process)."""

    from services.launcher import worker_command, worker_env

    extra = {"LUCENT_WORKER_TAGS": ",".join(args.tags)} if args.tags else {}
    if not _kernel_usable(args.kernel):
        return 1
    if args.kernel is not None:
        extra["LUCENT_WORKER_KERNEL"] = args.kernel
    env = worker_env(args.redis, args.threads, extra)
    cmd = worker_command(args.concurrency, args.name, args.loglevel)
    os.execvpe(cmd[0], cmd, env)
    return 0  # not reached


def cmd_submit(args: argparse.Namespace) -> int:

    from services.client import submit_and_wait

    options = {k: v for k, v in (("name", args.name), ("tile_size", args.tile_size),
                                 ("spp_per_pass", args.spp_per_pass),
                                 ("max_spp_per_pass", args.max_spp_per_pass),
                                 ("priority", args.priority)) if v is not None}
    if args.tags:
        options["tags"] = list(args.tags)
    frames = _frames(args)
    if isinstance(frames, int):
        return frames
    if frames is not None:
        options["frames"] = frames
    return submit_and_wait(args.scene, args.server, token=os.environ.get("LUCENT_API_TOKEN"),
                           wait=args.wait, outputs=[args.output] if args.output else [],
                           quiet=args.quiet, options=options, render=_render_options(args))


def cmd_demo(args: argparse.Namespace) -> int:
    """``lucent up`` on a free port, one scene submitted and waited for, images written, stop."""

    from services.client import submit_and_wait
    from services.launcher import LocalFarm, free_port

    outputs = args.output or ["out/cornell_box.png", "out/cornell_box.exr"]
    if not kernels_cached():
        # The workers compile before they take the first pass; without a word the progress bar
        # would sit at 0 % all that time.
        print(f"compiling the renderer, first run only, about {COLD_COMPILE} "
              "(the kernels are cached for later runs)...", file=sys.stderr)
    with LocalFarm(port=free_port(), workers=args.workers,
                   redis_url=os.environ.get("REDIS_URL") or None, quiet=True) as farm:
        print(f"Lucent farm at {farm.url} with {farm.workers} worker processes", file=sys.stderr)
        return submit_and_wait(args.scene, farm.url, wait=True, outputs=outputs,
                               quiet=args.quiet)


def _frames(args: argparse.Namespace) -> list | int | None:
    """``--sweep PATH=V1,V2,...`` or ``--frames patches.json`` as the job's ``frames``; an exit
    code when they cannot be read."""
    import json

    from services.client import sweep_values
    from services.farm.frames import sweep_patches

    if args.sweep and args.frames:
        print("give --sweep or --frames, not both", file=sys.stderr)
        return 2
    if args.sweep:
        field, eq, values = args.sweep.partition("=")
        if not eq or not field:
            print("--sweep is PATH=V1,V2,... (e.g. materials.wax.density=1,2,4,8)",
                  file=sys.stderr)
            return 2
        return sweep_patches(field, sweep_values(values))
    if args.frames:
        try:
            return json.loads(Path(args.frames).read_text())
        except (OSError, ValueError) as err:
            print(f"{args.frames}: {err}", file=sys.stderr)
            return 1
    return None


def _tags(text: str) -> tuple[str, ...]:
    """``--tags gpu,bigmem``, checked as the settings check ``LUCENT_WORKER_TAGS``."""
    from services.farm.pools import MAX_WORKER_TAGS, parse_tags

    try:
        tags = parse_tags(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    if len(tags) > MAX_WORKER_TAGS:
        raise argparse.ArgumentTypeError(f"at most {MAX_WORKER_TAGS} tags")
    return tags


def _target_error(text: str) -> float | str:
    """``--target-error``: a relMSE > 0, or ``none`` (the scene's target dropped: uniform
    sampling at the spp), as ``render.target_error`` takes it."""
    if text.strip().lower() == "none":
        return "none"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number or none") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: the target must be a relMSE > 0, or none")
    return value


def _render_options(args: argparse.Namespace) -> dict:
    """The scene's ``render`` fields the command line sets (``render`` and ``submit``):
    ``target_error`` from ``--target-error`` where given, None for ``none``."""
    if args.target_error is None:
        return {}
    return {"target_error": None if args.target_error == "none" else args.target_error}


def build_parser() -> argparse.ArgumentParser:
    from renderer import __version__

    parser = argparse.ArgumentParser(prog="lucent", description=__doc__.split("\n\n")[0])
    # (the release a worker's heartbeat gives: GET /api/workers, the dashboard's Workers page)
    parser.add_argument("--version", action="version", version=f"lucent {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("render", help="render a scene on this machine")
    p.add_argument("scene", help="scene JSON file (scene format v1)")
    p.add_argument("-o", "--output", required=True, help="image file: .exr, .png, .pfm or .npy")
    p.add_argument("--spp", type=int, help="samples per pixel (default: the scene's render.spp)")
    p.add_argument("--seed", type=int, help="random seed (default: the scene's render.seed)")
    p.add_argument("--sampler", choices=["independent", "sobol"],
                   help="random numbers of a sample (default: the scene's render.sampler)")
    p.add_argument("--target-error", type=_target_error, metavar="T",
                   help="render to this expected relMSE of the frame, adaptively, --spp then "
                        "the most a pixel takes; none: the spp everywhere (default: the "
                        "scene's render.target_error)")
    p.add_argument("--threads", type=int, help="render threads (default: all cores)")
    p.add_argument("--kernel", choices=KERNELS, default="packet",
                   help="packet (default): 16 paths at once in the CPU's vector lanes, for "
                        "flat scenes of diffuse and grey single_scatter materials lit by "
                        "emitting surfaces; the scalar kernel renders the others; scalar: one "
                        "path at a time, every method; wavefront: batches of paths stage by "
                        "stage, surface materials only (others fall back to scalar); gpu: on "
                        "this machine's CUDA GPU, every scene (the stages where they cover it)")
    p.add_argument("--exposure", type=float, default=0.0,
                   help="PNG only: exposure in stops, the image is scaled by 2^EV (default 0)")
    p.add_argument("--tonemap", choices=["clamp", "reinhard", "aces"], default="clamp",
                   help="PNG only: tone map before sRGB encoding (default clamp)")
    p.add_argument("--denoise", action="store_true",
                   help="denoise with Intel Open Image Denoise (pyoidn), guided by albedo and "
                        "normal AOVs; the noisy image is kept beside it as <stem>_noisy<ext>")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("validate", help="check a scene and print the errors to fix")
    p.add_argument("scene", help="scene JSON file")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("up", help="run a farm on this machine: Redis, workers and the API")
    p.add_argument("--host", default="127.0.0.1", help="address the API listens on")
    p.add_argument("--port", type=int, default=8000, help="port of the API (default 8000)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (default: one per core, measured fastest)")
    p.add_argument("--threads", type=int, default=1, help="numba threads per worker process")
    p.add_argument("--tags", type=_tags, default=None,
                   help="the worker node's pool tags, comma-separated (default: "
                        "LUCENT_WORKER_TAGS): it also takes the jobs that require them")
    p.add_argument("--kernel", choices=KERNELS, default=None,
                   help="the kernel the worker node renders with (default: "
                        "LUCENT_WORKER_KERNEL, else packet: 16 paths in the vector lanes where "
                        "it covers the scene, the scalar kernel elsewhere); gpu: on this "
                        "machine's CUDA GPU")
    p.add_argument("--api-processes", type=int, default=API_PROCESSES,
                   help=f"processes serving the API (default {API_PROCESSES}; 1 serves it in "
                        "this process): the status polls one process answers are bounded by "
                        "its event loop (docs/performance.md, Load)")
    p.set_defaults(func=cmd_up)

    p = sub.add_parser("worker", help="join a farm as a Celery worker node")
    p.add_argument("--redis", required=True, help="the farm's Redis, e.g. redis://host:6379/0")
    p.add_argument("--concurrency", type=int, default=None,
                   help="worker processes (default: one per core)")
    p.add_argument("--threads", type=int, default=1, help="numba threads per worker process")
    p.add_argument("--name", help="Celery node name (default celery@HOST)")
    p.add_argument("--loglevel", default="INFO", help="Celery log level (default INFO)")
    p.add_argument("--tags", type=_tags, default=None,
                   help="pool tags, comma-separated, e.g. gpu,bigmem (default: "
                        "LUCENT_WORKER_TAGS): the node takes untagged jobs and those whose "
                        "tags it has all of")
    p.add_argument("--kernel", choices=KERNELS, default=None,
                   help="the kernel the node renders with (default: LUCENT_WORKER_KERNEL, else "
                        "packet: 16 paths in the vector lanes where it covers the scene, the "
                        "scalar kernel elsewhere); gpu: on this host's CUDA GPU (every scene), "
                        "refused where none is seen; tag such a node gpu")
    p.set_defaults(func=cmd_worker)

    p = sub.add_parser("submit", help="submit a scene to a farm")
    p.add_argument("scene", help="scene JSON file (mesh files are sent inline)")
    p.add_argument("--server", default=os.environ.get("LUCENT_SERVER") or DEFAULT_SERVER,
                   help=f"the farm's URL (default: $LUCENT_SERVER, else {DEFAULT_SERVER}, "
                        "the address of `lucent up`)")
    p.add_argument("--wait", action="store_true", help="wait for the job, with a progress bar")
    p.add_argument("-o", "--output", help="write the image when done (.exr, .png or .npy)")
    p.add_argument("--name", help="the job's name on the dashboard (default: none)")
    p.add_argument("--tile-size", type=int, help="tile edge in pixels (default: the planner's)")
    p.add_argument("--spp-per-pass", type=int, help="samples of the first pass (default 8)")
    p.add_argument("--max-spp-per-pass", type=int,
                   help="the largest pass: passes grow up to it (LUCENT_PASS_GROWTH) "
                        "(default 64)")
    p.add_argument("--priority", type=int, help="0-9, 9 runs first (default 0)")
    p.add_argument("--target-error", type=_target_error, metavar="T",
                   help="the job renders to this expected relMSE of the frame, its tiles' "
                        "passes adaptive, the scene's spp then the most a pixel takes; none: "
                        "the spp everywhere (default: the scene's render.target_error)")
    p.add_argument("--sweep", metavar="PATH=V1,V2,...",
                   help="one frame a value of a scene field, e.g. materials.wax.density=1,2,4,8 "
                        "(-o then writes OUT_0000.png, OUT_0001.png, ...)")
    p.add_argument("--frames", metavar="PATCHES.json",
                   help="a JSON list of RFC 6902 JSON Patches, one a frame")
    p.add_argument("--tags", type=_tags, default=None,
                   help="worker tags the job requires, comma-separated (only nodes with all "
                        "of them render it)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_submit)

    p = sub.add_parser("demo", help="start a farm, render one scene on it, write images, stop")
    p.add_argument("scene", nargs="?", default="examples/cornell_box.json",
                   help="scene JSON file (default examples/cornell_box.json)")
    p.add_argument("-o", "--output", action="append",
                   help="image to write (repeatable; default out/cornell_box.png and .exr)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (default: one a core)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
