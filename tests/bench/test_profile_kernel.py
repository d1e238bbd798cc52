"""bench.profile_kernel: from a sample's address in JIT code to the source line it ran.

The perf run itself takes minutes (a compile of the renderer with line tables), so these tests
check each step on small inputs: the enclosing function of a line, the
address → line mapping through a real ELF object, and — in a fresh process — that the hooks keep
the objects numba loads, find where it loaded them, keep the release build's inlining, and file
the lines of a function numba inlined in its IR under that function's own file.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from bench.profile_kernel import attribute, enclosing_function, summarize

ROOT = Path(__file__).resolve().parents[2]
BVH = ROOT / "renderer" / "geometry" / "bvh.py"
needs_binutils = pytest.mark.skipif(
    shutil.which("addr2line") is None or shutil.which("nm") is None
    or shutil.which("readelf") is None,
    reason="needs binutils (addr2line, nm, readelf)")


def _line_of(path: Path, text: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if text in line)


def test_a_line_is_filed_under_the_function_that_holds_it():
    slab = _line_of(BVH, "return t0 if t0 <= t1 else INF")
    closest = _line_of(BVH, "t, u, v = intersect_prim(prim_kind[k], o, d, prim_geo[k])")
    assert enclosing_function(f"renderer/geometry/bvh.py:{slab}") == "geometry.bvh._slab"
    assert enclosing_function(f"renderer/geometry/bvh.py:{closest}") == \
        "geometry.bvh.intersect_closest"
    assert enclosing_function("renderer/geometry/bvh.py:?") == "renderer/geometry/bvh.py (no line)"


@needs_binutils
@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_addresses_map_to_source_lines_through_an_object_file(tmp_path):
    src = tmp_path / "two.c"
    src.write_text(textwrap.dedent("""\
        double first(double x) {
            return x * x + 1.0;
        }
        double second(double x) {
            return x / 3.0 - 2.0;
        }
        """))
    obj = tmp_path / "two.o"
    subprocess.run(["gcc", "-g", "-O1", "-c", str(src), "-o", str(obj)], check=True)
    offsets = {}
    for line in subprocess.run(["nm", str(obj)], capture_output=True, text=True,
                               check=True).stdout.splitlines():
        address, kind, name = line.split()
        if kind == "T":
            offsets[name] = int(address, 16)
    base = 0x7F0000000000
    samples = [base + offsets["first"]] * 3 + [base + offsets["second"]] * 2 + [0x1000]
    result = attribute(samples, [{"file": str(obj), "base": base, "size": 4096}])
    assert result["outside"] == 1
    by_line = summarize(result["lines"])["source line"]
    assert by_line["two.c:1"] + by_line["two.c:2"] == 3  # first's entry is its line 1 or 2
    assert by_line["two.c:4"] + by_line["two.c:5"] == 2


@needs_binutils
def test_the_hooks_find_the_jit_code_and_its_lines(tmp_path):
    (tmp_path / "helper.py").write_text(textwrap.dedent("""\
        from numba import njit


        @njit(inline="always")
        def bump(x):
            return x * x + 1.0


        @njit(debug=True, boundscheck=False, _dbg_extend_lifetimes=False)
        def half(x):
            return 0.5 * x
        """))
    (tmp_path / "main.py").write_text(textwrap.dedent("""\
        import json, subprocess, sys
        from pathlib import Path

        from bench.profile_kernel import _install_hooks, _loaded_objects

        stash = {}
        _install_hooks(stash)
        from numba import njit

        from helper import bump, half


        @njit(debug=True, boundscheck=False, _dbg_extend_lifetimes=False)
        def total(n):
            s = 0.0
            for i in range(n):
                s += bump(half(i))
            return s


        total(10)
        objects = _loaded_objects(stash, Path(sys.argv[1]))
        lib = total.overloads[total.signatures[0]].library
        address = lib.get_pointer_to_function(total.overloads[total.signatures[0]].fndesc
                                              .llvm_func_name)
        home = [o for o in objects if o["base"] <= address < o["base"] + o["size"]]
        lines = []
        if home:
            o = home[0]
            out = subprocess.run(["addr2line", "-e", o["file"]], capture_output=True,
                                 text=True, input="\\n".join(hex(k) for k in range(o["size"])))
            lines = sorted(set(out.stdout.split()))
        symbols = subprocess.run(["nm", "--defined-only", home[0]["file"]], capture_output=True,
                                 text=True).stdout.splitlines() if home else []
        half_code = [s for s in symbols if "6helper4half" in s and s.split()[1] in "TtWw"]
        print(json.dumps({"found": len(home), "lines": lines, "half_code": len(half_code)}))
        """))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=os.pathsep.join([str(tmp_path), str(ROOT)]))
    out = subprocess.run([sys.executable, str(tmp_path / "main.py"), str(tmp_path)],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert report["found"] == 1  # the object that holds `total`, and where it was loaded
    lines = report["lines"]
    # total's own lines, under main.py; bump's body, inlined by numba, under helper.py (numba
    # itself would file it as main.py:6)
    assert any(line.endswith("main.py:17") for line in lines), lines
    assert any(line.endswith("helper.py:6") for line in lines), lines
    assert not any(line.endswith("main.py:6") for line in lines), lines
    # numba's debug=True marks every function noinline; the hooks take that off again, so `half`
    # is inlined as in a release build and leaves no code of its own in total's object
    assert report["half_code"] == 0
