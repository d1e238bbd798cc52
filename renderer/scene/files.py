"""File references (scene format v1.1, "Files: paths and assets"): where a scene reads a file.

Wherever a scene names a file (a mesh, a texture image, an environment image) the value is a
**file reference** (``schema.FileRef``):

- a string: a path, relative to the scene file's folder; only the command line reads paths (a
  server must never open a path that a request names), so ``load_scene`` refuses them unless
  called with ``allow_paths=True``;
- ``{"asset": "sha256:<64 hex digits>"}``: an asset uploaded to the farm before, content addressed
  by the SHA-256 of its bytes. Its bytes come from the ``assets`` reader given to ``load_scene``:
  the farm passes one on its blob store; the command line reads the local asset folder
  (``local_assets``: ``LUCENT_ASSET_DIR``, else ``~/.cache/lucent/assets``, one file per asset
  named by its hex digest). The bytes are checked against the digest whoever supplies them.

``FileSource.read(ref, where)`` returns the bytes and a label for messages (the resolved path or
the asset's name), or the errors as ``(JSON path, message)`` pairs. What kind of file it is comes
from the bytes (``sniff``), so an asset needs no name: the extension of a path is only checked to
agree with them.
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from renderer.scene.schema import ASSET_PATTERN, AssetRef

AssetReader = Callable[[str], bytes]
"""``reader("sha256:<hex>")`` -> the bytes of that asset; ``KeyError`` for an unknown one."""

Errors = list[tuple[str, str]]

ASSET_DIR_ENV = "LUCENT_ASSET_DIR"

# The kinds of file a scene reads, told by their first bytes. OBJ has no signature: it is text
# whose first non-blank, non-comment line starts with a keyword of the format.
_MAGIC = (
    (b"\x89PNG\r\n\x1a\n", ".png"),
    (b"\x76\x2f\x31\x01", ".exr"),
    (b"PF\n", ".pfm"),
    (b"Pf\n", ".pfm"),
    (b"PF\r\n", ".pfm"),
    (b"Pf\r\n", ".pfm"),
    (b"#?RADIANCE", ".hdr"),
    (b"#?RGBE", ".hdr"),
    (b"ply\n", ".ply"),
    (b"ply\r\n", ".ply"),
)
_OBJ_KEYWORDS = re.compile(rb"^\s*(v|vt|vn|vp|f|o|g|s|mtllib|usemtl|l|p)\s", re.MULTILINE)
_KINDS = {kind for _, kind in _MAGIC} | {".obj"}
# Extensions that name the same kind.
_ALIASES = {".rgbe": ".hdr", ".pic": ".hdr"}


def sniff(data: bytes) -> str:
    """The kind of a file from its bytes: ``.png``, ``.exr``, ``.pfm``, ``.hdr``, ``.ply``,
    ``.obj``, or ``""`` when it is none of them."""
    for magic, kind in _MAGIC:
        if data.startswith(magic):
            return kind
    head = data[:4096]
    if b"\x00" not in head:
        for line in head.splitlines():
            stripped = line.strip()
            if not stripped or stripped.startswith(b"#"):
                continue
            return ".obj" if _OBJ_KEYWORDS.match(line + b" ") else ""
    return ""


def digest(data: bytes) -> str:
    """The asset name of ``data``: ``"sha256:<hex>"``."""
    return "sha256:" + hashlib.sha256(data).hexdigest()


def local_asset_dir() -> Path:
    """The command line's asset folder: ``LUCENT_ASSET_DIR``, else ``~/.cache/lucent/assets``."""
    configured = os.environ.get(ASSET_DIR_ENV)
    if configured:
        return Path(configured).expanduser()
    return Path.home() / ".cache" / "lucent" / "assets"


def local_assets(folder: Path | None = None) -> AssetReader:
    """A reader on a local folder of assets, one file per asset named by its hex digest."""
    root = local_asset_dir() if folder is None else folder

    def read(name: str) -> bytes:
        if not re.fullmatch(ASSET_PATTERN, name):
            raise KeyError(name)
        try:
            return (root / name.removeprefix("sha256:")).read_bytes()
        except FileNotFoundError:
            raise KeyError(name) from None

    return read


def store_local_asset(data: bytes, folder: Path | None = None) -> str:
    """Write ``data`` into the local asset folder (atomically) and return its asset name."""
    root = local_asset_dir() if folder is None else folder
    name = digest(data)
    target = root / name.removeprefix("sha256:")
    if not target.exists():
        root.mkdir(parents=True, exist_ok=True)
        partial = target.with_suffix(f".part{os.getpid()}")
        partial.write_bytes(data)
        os.replace(partial, target)
    return name


@dataclass(frozen=True)
class FileSource:
    """Where a scene's files come from: paths (the command line only) and assets."""

    allow_paths: bool = False
    base_dir: Path | None = None
    """Relative paths are resolved against it (else the working directory)."""
    assets: AssetReader | None = None
    """None: asset references are refused (this process has no asset store)."""

    def read(self, ref: str | AssetRef, where: str, kinds: tuple[str, ...]) -> (
        tuple[bytes, str, str] | Errors
    ):
        """``(bytes, kind, label)`` of the file ``ref`` names, or the errors. ``where`` is the JSON
        path of the reference; ``kinds`` the kinds the field accepts (``(".obj", ".ply")``); the
        label names the file in later messages (the resolved path, or the asset name)."""
        if isinstance(ref, AssetRef):
            data_or_errors = self._read_asset(ref.asset, f"{where}.asset")
            field, label = f"{where}.asset", ref.asset
        else:
            data_or_errors, label = self._read_path(ref, where)
            field = where
        if isinstance(data_or_errors, list):
            return data_or_errors
        data = data_or_errors
        kind = sniff(data)
        ext = "" if isinstance(ref, AssetRef) else Path(ref).suffix.lower()
        ext = _ALIASES.get(ext, ext)
        if not kind and ext in kinds:
            kind = ext  # no signature found (an OBJ that opens oddly): its reader will judge
        if kind not in kinds:
            accepted = ", ".join(k.lstrip(".").upper() for k in kinds)
            found = f"a {kind.lstrip('.').upper()} file" if kind else "not a file of a known kind"
            return [(field, f"{label}: {found}; expected {accepted}")]
        if ext in _KINDS and ext != kind:
            return [(field, f"{label}: its content is {kind.lstrip('.').upper()}, not {ext}")]
        return data, kind, label

    def _read_asset(self, name: str, where: str) -> bytes | Errors:
        if self.assets is None:
            return [(where, f"{name}: assets cannot be read here (no asset store)")]
        try:
            data = self.assets(name)
        except KeyError:
            return [(where, f"unknown asset {name} (upload it first: POST /api/assets)")]
        except OSError as exc:
            return [(where, f"{name}: cannot be read ({exc.strerror or exc})")]
        if digest(data) != name:
            return [(where, f"{name}: the stored bytes do not match their SHA-256")]
        return data

    def _read_path(self, ref: str, where: str) -> tuple[bytes | Errors, str]:
        if not self.allow_paths:  # the schema refuses paths first; a backstop
            return [(where, "file paths are accepted only by the command line")], ref
        path = Path(ref).expanduser()
        if not path.is_absolute():
            path = (self.base_dir if self.base_dir is not None else Path.cwd()) / path
        try:
            return path.read_bytes(), str(path.resolve())
        except OSError as exc:
            return [(where, f"cannot read {str(path)!r}: {exc.strerror or exc}")], str(path)
