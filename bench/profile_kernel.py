"""Where a render's time goes inside the JIT code: a sampling profile by source line, with perf.

    .venv/bin/python -m bench.profile_kernel [--scene examples/cornell_box.json] [--seconds 10]
                                             [--top 25] [--frequency 999]

numba's machine code is invisible to Python's profilers, and ``perf`` finds no symbols for it
(it lives in anonymous memory the JIT mapped). This script renders the scene for ``--seconds``
under ``perf record -e cpu-clock`` (a software clock: it needs no hardware counters, which this
VM lacks) and maps every sample that falls in JIT code to its source line itself:

- the renderer is compiled once more, in a cache folder of its own (the release cache is not
  touched), with line tables: numba's ``debug=True``, minus the two things it changes besides
  (it marks every function ``noinline`` and turns bounds checks on), so the code is the release
  code; its size is printed beside the release build's to show it;
- numba's object-code hooks keep the ELF object of every library the JIT loads, and the address
  it loaded each at (from a symbol it defines), so a sample's address becomes an offset into an
  object file, and ``addr2line`` on that file gives its source line (the innermost inlined one);
- LLVM inlines the ``inline_kernel`` functions (``renderer/jit.py``), and their lines keep their
  own file (DWARF's inlined frames). Code that numba inlines in its own IR (``inline="always"``,
  which the renderer no longer uses) has its lines filed under the caller's file (a line of
  ``bvh.py`` reads as the same line number of ``path.py``); the child process gives those lines
  their own file again.

Prints the share of samples by source line (the innermost inlined frame) and by the Python
function that holds the line (the innermost frame's: there is no inclusive "time under
trace_path's shadow ray" figure). Needs Linux
``perf`` (Debian: ``apt-get install linux-perf``) and binutils' ``addr2line``, and
``/proc/sys/kernel/perf_event_paranoid`` ≤ 2 or root. docs/performance.md ("Where the time
goes") records what it found.
"""

from __future__ import annotations

import argparse
import ast
import collections
import functools
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


# --- the child: render under perf with line tables, and record where each object was loaded ------


def _install_hooks(stash: dict) -> None:
    """Before numba creates its codegen: keep every object file it compiles or loads from cache,
    compile with line tables but release code, and file IR-inlined lines under their own file."""
    from numba.core import codegen, debuginfo, lowering

    lib = codegen.CPUCodeLibrary
    compiled, getbuffer = lib._object_compiled_hook.__func__, lib._object_getbuffer_hook.__func__

    def on_compiled(cls, module, buf):
        stash[module.name] = buf
        return compiled(cls, module, buf)

    def on_getbuffer(cls, module):
        buf = getbuffer(cls, module)
        if buf:
            stash[module.name] = buf
        return buf

    lib._object_compiled_hook = classmethod(on_compiled)
    lib._object_getbuffer_hook = classmethod(on_getbuffer)

    pre_lower = lowering.BaseLower.pre_lower

    def release_inlining(self):
        pre_lower(self)  # numba adds noinline with full debug info; the release build has none
        self.builder.function.attributes.discard("noinline")

    lowering.BaseLower.pre_lower = release_inlining

    lower_inst = lowering.Lower.lower_inst

    def note_file(self, inst):
        self.debuginfo._lucent_file = self.loc.filename
        return lower_inst(self, inst)

    lowering.Lower.lower_inst = note_file

    def location(self, line):
        scope = self.subprograms[-1]
        path = getattr(self, "_lucent_file", None)
        if path and path != self.filepath:
            blocks = self.__dict__.setdefault("_lucent_blocks", {})
            key = (id(scope), path)
            if key not in blocks:
                difile = self.module.add_debug_info("DIFile", {
                    "directory": os.path.dirname(path), "filename": os.path.basename(path)})
                blocks[key] = self.module.add_debug_info("DILexicalBlockFile", {
                    "scope": scope, "file": difile, "discriminator": 0})
            scope = blocks[key]
        return self.module.add_debug_info("DILocation", {"line": line, "column": 1,
                                                         "scope": scope})

    debuginfo.DIBuilder._di_location = location


def _text_size(path: str) -> int:
    out = subprocess.run(["readelf", "-SW", path], capture_output=True, text=True,
                         check=True).stdout
    size = 0
    for line in out.splitlines():
        m = re.search(r"\]\s+(\.l?text)\s+\S+\s+\S+\s+\S+\s+([0-9a-f]+)", line)
        if m:
            size += int(m.group(2), 16)
    return size


def _loaded_objects(stash: dict, out: Path) -> list[dict]:
    """Write each kept object and find where the JIT put its code: symbol address − offset."""
    from numba.core.registry import cpu_target

    engine = cpu_target.target_context.codegen()._engine._ee
    objects = []
    for i, (name, buf) in enumerate(stash.items()):
        path = out / f"object{i}.o"
        path.write_bytes(buf)
        syms = subprocess.run(["nm", "--defined-only", str(path)], capture_output=True,
                              text=True, check=True).stdout.splitlines()
        bases = set()
        for line in syms:
            parts = line.split()
            if len(parts) == 3 and parts[1] == "T":
                address = engine.get_function_address(parts[2])
                if address:
                    bases.add(address - int(parts[0], 16))
        if len(bases) == 1:  # one text section, found through every symbol alike
            objects.append({"file": str(path), "library": name, "base": bases.pop(),
                            "size": _text_size(str(path))})
    return objects


def child(scene_path: str, seconds: float, out: Path) -> None:
    stash: dict = {}
    _install_hooks(stash)
    import renderer.jit as jit

    jit.JIT_OPTIONS.update(debug=True, boundscheck=False, _dbg_extend_lifetimes=False)
    from renderer.render import _as_compiled, render_tile

    cs = _as_compiled(json.loads(Path(scene_path).read_text()))
    render_tile(cs, 0, 0, cs.width, cs.height, 0, 1)  # compile, or load from the cache
    objects = _loaded_objects(stash, out)
    start = time.perf_counter()
    spp = 0
    while time.perf_counter() - start < seconds:
        render_tile(cs, 0, 0, cs.width, cs.height, spp, 2)
        spp += 2
    (out / "objects.json").write_text(json.dumps({
        "objects": objects, "paths": cs.width * cs.height * spp,
        "seconds": time.perf_counter() - start}))


# --- the parent: run the child under perf, then attribute the samples ----------------------------


def _short(location: str) -> str:
    path, _, line = location.partition(":")
    line = line.split(" ")[0]
    try:
        path = str(Path(path).resolve().relative_to(ROOT))
    except ValueError:
        path = Path(path).name
    return f"{path}:{line}"


@functools.cache
def _functions_in(path: str) -> list[tuple[int, int, str]]:
    try:
        tree = ast.parse((ROOT / path).read_text())
    except (OSError, SyntaxError):
        return []
    return [(node.lineno, node.end_lineno, node.name) for node in ast.walk(tree)
            if isinstance(node, ast.FunctionDef)]


def enclosing_function(location: str) -> str:
    """The innermost Python function whose source holds file:line (numba's IR inlining leaves no
    frame for the function it inlined, but its lines keep their file and number)."""
    path, _, line = location.partition(":")
    if not line.isdigit():
        return f"{path} (no line)"
    best = None
    for first, last, name in _functions_in(path):
        if first <= int(line) <= last and (best is None or first > best[0]):
            best = (first, name)
    return f"{path.removeprefix('renderer/').removesuffix('.py').replace('/', '.')}." \
           f"{best[1]}" if best else path


def attribute(samples: list[int], objects: list[dict]) -> dict:
    """Map sample addresses to source lines (file:line of the innermost inlined frame, which is
    what the line table holds) and count them; samples outside every object are counted apart."""
    offsets: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    outside = 0
    for ip in samples:
        for o in objects:
            if o["base"] <= ip < o["base"] + o["size"]:
                offsets[o["file"]][ip - o["base"]] += 1
                break
        else:
            outside += 1
    lines: collections.Counter = collections.Counter()
    for path, counts in offsets.items():
        keys = sorted(counts)
        out = subprocess.run(["addr2line", "-e", path], input="\n".join(hex(k) for k in keys),
                             capture_output=True, text=True, check=True).stdout.splitlines()
        for key, location in zip(keys, out, strict=True):
            lines[_short(location)] += counts[key]
    return {"lines": lines, "outside": outside}


def summarize(lines: collections.Counter) -> dict[str, collections.Counter]:
    """Samples by source line, and by the Python function that holds that line."""
    by_function: collections.Counter = collections.Counter()
    for location, n in lines.items():
        by_function[enclosing_function(location)] += n
    return {"source line": lines, "function (the line's own, inlined or not)": by_function}


@functools.cache
def _file_lines(path: str) -> list[str]:
    try:
        return (ROOT / path).read_text().splitlines()
    except OSError:
        return []


def _source(location: str) -> str:
    path, _, line = location.partition(":")
    try:
        return _file_lines(path)[int(line) - 1].strip()[:70]
    except (ValueError, IndexError):
        return ""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default=str(ROOT / "examples" / "cornell_box.json"))
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--frequency", type=int, default=999, help="samples a second a thread")
    parser.add_argument("--keep", metavar="DIR", help="keep perf.data, the objects and their "
                        "load addresses (objects.json) in DIR, for objdump or perf report")
    parser.add_argument("--child", nargs=3, metavar=("SCENE", "SECONDS", "OUT"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child[0], float(args.child[1]), Path(args.child[2]))
        return 0
    for tool in ("perf", "addr2line", "readelf", "nm"):
        if shutil.which(tool) is None:
            print(f"bench.profile_kernel needs {tool} on PATH", file=sys.stderr)
            return 2
    import renderer  # noqa: F401  (sets NUMBA_CACHE_DIR, keyed by the renderer's sources)

    env = dict(os.environ, NUMBA_CACHE_DIR=os.environ["NUMBA_CACHE_DIR"] + "-lines")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        subprocess.run(["perf", "record", "-q", "-e", "cpu-clock", "-F", str(args.frequency),
                        "-o", str(out / "perf.data"), "--", sys.executable, "-m",
                        "bench.profile_kernel", "--child", args.scene, str(args.seconds),
                        str(out)], check=True, env=env, cwd=ROOT,
                       stderr=subprocess.DEVNULL)
        script = subprocess.run(["perf", "script", "-i", str(out / "perf.data"), "-F", "ip"],
                                capture_output=True, text=True, check=True).stdout
        info = json.loads((out / "objects.json").read_text())
        samples = [int(s, 16) for s in script.split()]
        result = attribute(samples, info["objects"])
        if args.keep:
            shutil.copytree(out, args.keep, dirs_exist_ok=True)
    lines = result["lines"]
    total = sum(lines.values())
    print(f"{args.scene}: {info['paths'] / info['seconds'] / 1e6:.2f} M paths/s with line "
          f"tables; {len(samples)} samples, {total} in the renderer's JIT code "
          f"({100 * total / max(1, len(samples)):.0f} %: the rest is start-up and compile)")
    for title, counter in summarize(lines).items():
        print(f"\nby {title}:")
        acc = 0
        for key, n in counter.most_common(args.top):
            acc += n
            text = _source(key) if ":" in key else ""
            print(f"{100 * n / total:6.2f} % {100 * acc / total:6.1f} %  {key:42s} {text}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
