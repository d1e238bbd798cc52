"""The import rule of docs/architecture.md ("Layers and the import rule"), checked on the source.

Every module of ``renderer/``, ``services/`` and ``worker/`` is parsed with ``ast``; every import,
at module level or inside a function, is an edge to the module of this tree it names. Two checks:
each edge goes to a layer the importer may use, and the graph has no cycle.

``LUCENT_LAYOUT_ROOT`` points the test at another checkout (e.g. one of main) to see what it finds.
"""

from __future__ import annotations

import ast
import os
from pathlib import Path

import pytest

ROOT = Path(os.environ.get("LUCENT_LAYOUT_ROOT") or Path(__file__).resolve().parents[1])
PACKAGES = ("renderer", "services", "worker")

# Each layer and the layers it may import (itself included). The command line (``lucent``, its
# HTTP client and the launcher that starts workers as subprocesses) sits above everything.
MAY_IMPORT = {
    "renderer": {"renderer"},
    "farm": {"renderer", "farm"},
    "api": {"renderer", "farm", "api"},
    "worker": {"renderer", "farm", "worker"},
    "cli": {"renderer", "farm", "api", "worker", "cli"},
}
CLI_MODULES = {"services", "services.cli", "services.client", "services.launcher"}


def layer(module: str) -> str:
    if module.split(".")[0] == "renderer":
        return "renderer"
    if module.split(".")[0] == "worker":
        return "worker"
    if module == "services.farm" or module.startswith("services.farm."):
        return "farm"
    if module in CLI_MODULES:
        return "cli"
    return "api"  # services.api and anything else under services/


def modules(root: Path) -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def imports(module: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The modules of this tree that ``module`` imports, anywhere in its body."""
    is_package = path.name == "__init__.py"
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the importer's package upwards
                package = module.split(".")
                if not is_package:
                    package = package[:-1]
                package = package[: len(package) - (node.level - 1)]
                base = ".".join(package + ([base] if base else []))
            names.add(base)
            # ``from a.b import c`` imports the module a.b.c when there is one
            names.update(f"{base}.{alias.name}" for alias in node.names)
    targets = set()
    for name in names:
        parts = name.split(".")
        while parts and ".".join(parts) not in known:
            parts.pop()
        if parts and ".".join(parts) != module:
            targets.add(".".join(parts))
    return targets


def graph(root: Path) -> dict[str, set[str]]:
    known = modules(root)
    return {m: imports(m, p, known) for m, p in known.items()}


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_the_tree_has_modules():
    """A wrong root would find nothing and pass every check below."""
    found = modules(ROOT)
    assert "renderer.render" in found and "worker.tasks" in found, sorted(found)[:5]


def test_no_import_goes_upwards():
    wrong = [f"{m} ({layer(m)}) imports {t} ({layer(t)})"
             for m, targets in graph(ROOT).items() for t in sorted(targets)
             if layer(t) not in MAY_IMPORT[layer(m)]]
    assert not wrong, "\n".join(wrong)


def test_no_import_cycle():
    found = cycles(graph(ROOT))
    assert not found, "\n".join(" <-> ".join(c) for c in found)


@pytest.mark.parametrize(("edges", "expected"), [
    ({"a": {"b"}, "b": {"a"}, "c": {"a"}}, [["a", "b"]]),
    ({"a": {"b"}, "b": {"c"}, "c": set()}, []),
    ({"a": {"b"}, "b": {"c"}, "c": {"a"}}, [["a", "b", "c"]]),
])
def test_cycles_finds_what_is_there(edges, expected):
    assert cycles(edges) == expected


def test_layers_of_known_modules():
    assert layer("renderer.scene.compile") == "renderer"
    assert layer("services.farm.store") == "farm"
    assert layer("services.api.routes.jobs") == "api"
    assert layer("services.cli") == "cli"
    assert layer("worker.tasks") == "worker"
    assert "api" not in MAY_IMPORT["worker"] and "worker" not in MAY_IMPORT["api"]


# The job store's Redis client and key builders: only services/farm/store.py may use them.
STORE_INTERNALS = {"r", "k", "job_key", "acc_key", "pass_key"}


def assert_none(scan, which) -> None:
    """No module whose name ``which`` accepts has a hit of ``scan`` (the hits, if any, listed)."""
    found = [hit for m, path in modules(ROOT).items() if which(m) for hit in scan(path)]
    assert not found, "\n".join(found)


def store_internals_used(path: Path, root: Path = ROOT) -> list[str]:
    """``x.r``, ``x.k(...)``, ``x.job_key(...)``, … in a module: reaching around the store."""
    return [f"{path.relative_to(root)}:{node.lineno} .{node.attr}"
            for node in ast.walk(ast.parse(path.read_text(), str(path)))
            if isinstance(node, ast.Attribute) and node.attr in STORE_INTERNALS
            and not (isinstance(node.value, ast.Name) and node.value.id == "self")]


def test_only_the_store_touches_redis_keys():
    """Routes, tasks, the merge, the sweeper and the cost check call the store's methods; none
    of them reads or writes a Redis key itself (issue #26: "only the store touches Redis keys")."""
    assert_none(store_internals_used,
                lambda m: m.split(".")[0] in ("services", "worker") and m != "services.farm.store")


def test_store_internals_are_found(tmp_path):
    """The scan sees a use around the store, and not the store's own ``self.r``."""
    module = tmp_path / "m.py"
    module.write_text("def f(store):\n    return store.r.get(store.acc_key('j', 0))\n"
                      "class S:\n    def g(self):\n        return self.r\n")
    assert store_internals_used(module, tmp_path) == ["m.py:2 .r", "m.py:2 .acc_key"]


def bare_slots(path: Path, root: Path = ROOT) -> list[str]:
    """Subscripts of a material row by a number: ``mp[7]``, ``param[1:]``,
    ``S.mat_param[mat, 4]``, ``mat_param[:, 0]`` (a slot whose meaning the reader must look up)."""
    rows = {"mp", "mm", "param", "mat_param"}

    def name(node: ast.expr) -> str | None:
        if isinstance(node, ast.Name):
            return node.id
        return node.attr if isinstance(node, ast.Attribute) else None

    def numeric(node: ast.expr) -> bool:
        if isinstance(node, ast.Slice):
            return any(isinstance(b, ast.Constant) and b.value != 0
                       for b in (node.lower, node.upper))
        return isinstance(node, ast.Constant) and isinstance(node.value, int)

    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Subscript) and name(node.value) in rows:
            index = node.slice
            last = index.elts[-1] if isinstance(index, ast.Tuple) else index
            if numeric(last):
                found.append(f"{path.relative_to(root)}:{node.lineno} {ast.unparse(node)}")
    return found


def test_material_slots_have_names():
    """Every read or write of a material row's slot goes through a name its family's file
    defines (issue #26: "slot 7 means four different things by material kind")."""
    assert_none(bare_slots, lambda m: m.split(".")[0] == "renderer")


def test_bare_slots_are_found(tmp_path):
    module = tmp_path / "m.py"
    module.write_text("def f(S, mp, mat):\n    a = mp[7] + S.mat_param[mat, 4]\n"
                      "    return mp[ALBEDO], mp[1:], S.mat_param[mat, DENSITY], mp[:3]\n")
    assert bare_slots(module, tmp_path) == ["m.py:2 mp[7]", "m.py:2 S.mat_param[mat, 4]",
                                            "m.py:3 mp[1:]", "m.py:3 mp[:3]"]


def test_trace_path_reads_as_a_loop():
    """The path loop stays short: the methods live in their own files (issue #26: well under
    150 lines, from ~280 with the subsurface methods inline)."""
    source = (ROOT / "renderer" / "integrators" / "path.py").read_text()
    fn = next(node for node in ast.walk(ast.parse(source))
              if isinstance(node, ast.FunctionDef) and node.name == "trace_path")
    assert fn.end_lineno - fn.lineno + 1 < 150
    subsurface = {p.stem for p in (ROOT / "renderer" / "integrators" / "subsurface").glob("*.py")}
    assert {"volumetric", "single_scatter", "diffuse_entry", "backlight", "diffusion"} <= subsurface


def test_the_release_is_named_once():
    """The release a worker's heartbeat gives (``renderer.__version__``, docs/farm.md, upgrading
    a farm) is the package's (pyproject.toml's ``version``): a release that bumped one and not
    the other would show workers of two releases as one."""
    import tomllib

    import renderer

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["version"] == renderer.__version__
    # (nowhere else: the API's OpenAPI document and the workers' heartbeats read it)
    named = [f for d in ("renderer", "worker", "services") for f in (ROOT / d).rglob("*.py")
             if f'"{project["version"]}"' in f.read_text()]
    assert named == [ROOT / "renderer" / "__init__.py"], named
