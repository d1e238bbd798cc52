"""The web dashboard: its static files at ``/``, and the read-only things it offers besides jobs.

- ``GET /`` is ``services/dashboard/index.html``; ``/dashboard/*`` its scripts and styles (plain
  files, no build step).
- ``GET /api/examples`` and ``GET /api/examples/{name}``: the repository's example scenes, for the
  Submit page. The list is an allow-list built once when the app is created, from the JSON files
  directly in ``examples/``; a request names an entry of that list and never a path, so nothing
  outside it can be read. Scenes that reference mesh files are left out (the API refuses paths).
- ``GET /api/figures`` and ``GET /dashboard/figures/{name}``: the method-comparison figures under
  ``docs/images/methods/`` (same allow-list rule), for the Speed vs accuracy page.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fastapi import APIRouter, HTTPException, Request, status
from fastapi.responses import FileResponse
from pydantic import BaseModel

ROOT = Path(__file__).resolve().parents[3]
STATIC_DIR = Path(__file__).resolve().parents[2] / "dashboard"
EXAMPLES_DIR = ROOT / "examples"
FIGURES_DIR = ROOT / "docs" / "images" / "methods"
# bench/accuracy.py's error-against-time charts and bench/failure_map.py's map
CHARTS_DIR = ROOT / "docs" / "images" / "accuracy"
CHART_PREFIX = "accuracy-"

# The largest example offered: the Submit page loads it into a text area.
MAX_EXAMPLE_BYTES = 1024 * 1024


@dataclass(frozen=True)
class Example:
    name: str
    path: Path
    width: int
    height: int
    spp: int
    bytes: int


def _references_files(scene: dict[str, Any]) -> bool:
    return any(isinstance(o, dict) and "path" in o for o in scene.get("objects", []))


def find_examples(folder: Path = EXAMPLES_DIR) -> dict[str, Example]:
    """The allow-list: name (file stem) -> example, for every scene directly in ``folder`` that
    parses, is small enough and references no mesh file."""
    found: dict[str, Example] = {}
    if not folder.is_dir():
        return found
    for path in sorted(folder.glob("*.json")):
        if not path.is_file() or path.stat().st_size > MAX_EXAMPLE_BYTES:
            continue
        try:
            scene = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(scene, dict) or _references_files(scene):
            continue
        film, render = scene.get("film", {}), scene.get("render", {})
        found[path.stem] = Example(path.stem, path, int(film.get("width", 0)),
                                   int(film.get("height", 0)), int(render.get("spp", 0)),
                                   path.stat().st_size)
    return found


def find_figures(folder: Path = FIGURES_DIR, charts: Path = CHARTS_DIR) -> dict[str, Path]:
    """The allow-list of figures: file name -> path, PNGs directly in ``folder``, and the
    benchmark's charts in ``charts`` under the name ``accuracy-<file>``."""
    found: dict[str, Path] = {}
    if folder.is_dir():
        found |= {p.name: p for p in sorted(folder.glob("*.png")) if p.is_file()}
    if charts.is_dir():
        found |= {CHART_PREFIX + p.name: p for p in sorted(charts.glob("*.png")) if p.is_file()}
    return found


class ExamplePublic(BaseModel):
    name: str
    width: int
    height: int
    spp: int
    bytes: int


class ExamplesPublic(BaseModel):
    data: list[ExamplePublic]
    count: int


class FigurePublic(BaseModel):
    name: str
    url: str
    grid: bool
    chart: bool = False


class FiguresPublic(BaseModel):
    data: list[FigurePublic]
    count: int


# --- /api (behind the token when one is set) ----------------------------------------------------
api_router = APIRouter(tags=["dashboard"])


@api_router.get("/examples", response_model=ExamplesPublic)
def list_examples(request: Request):
    """The example scenes the Submit page offers (those that reference no mesh file)."""
    examples: dict[str, Example] = request.app.state.examples
    data = [ExamplePublic(name=e.name, width=e.width, height=e.height, spp=e.spp, bytes=e.bytes)
            for e in examples.values()]
    return ExamplesPublic(data=data, count=len(data))


@api_router.get("/examples/{name}")
def get_example(name: str, request: Request) -> dict[str, Any]:
    """One example scene, by its name in the list (never a path)."""
    example = request.app.state.examples.get(name)
    if example is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no example {name!r}")
    return json.loads(example.path.read_text())


@api_router.get("/figures", response_model=FiguresPublic)
def list_figures(request: Request):
    """The method-comparison figures in docs/images/methods/ (the benchmark's charts once they
    exist); ``grid`` marks the comparison grid."""
    figures: dict[str, Path] = request.app.state.figures
    data = [FigurePublic(name=n, url=f"/dashboard/figures/{n}", grid=n.endswith("_grid.png"),
                         chart=n.startswith(CHART_PREFIX))
            for n in figures]
    return FiguresPublic(data=data, count=len(data))


# --- the pages (open: static files, no farm data) -----------------------------------------------
page_router = APIRouter(tags=["dashboard"], include_in_schema=False)


@page_router.get("/")
def index() -> FileResponse:
    return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-cache"})


@page_router.get("/dashboard/figures/{name}")
def get_figure(name: str, request: Request) -> FileResponse:
    path = request.app.state.figures.get(name)
    if path is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no figure {name!r}")
    return FileResponse(path, media_type="image/png")
