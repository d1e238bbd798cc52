"""The blob store: finished jobs' images and scenes, written once, read by the API.

``BlobStore`` is the interface: bytes under a key, a key being a relative path of lowercase
letters, digits, ``.``, ``_``, ``-`` and ``/`` (``jobs/<id>/image.exr``). ``FileBlobStore`` keeps
them in a folder (``LUCENT_BLOB_DIR``, by default ``blobs/`` in the farm's data folder): each blob
is written to a temporary file in its folder, flushed to disk and renamed into place, so a reader
sees the whole blob or none, and several API processes may share the folder (a shared volume).

An S3-compatible store would implement the same four methods (``put`` as one PUT, ``delete`` as a
listing and a batch delete). None is provided: there is no S3-compatible server here to test
one against, and the farm ships nothing it has not tested.

Keys of a job (``services.farm.archive``):

===============================  ============================================================
``jobs/<id>/image.exr``          the image, linear float32 (what ``image.exr`` serves)
``jobs/<id>/image.png``          the image as ``image.png`` serves it by default (exposure 0,
                                 clamp)
``jobs/<id>/scene.json``         the scene as submitted
``jobs/<id>/resume.npz``         a failed or cancelled job's merged samples and passes, for a
                                 retry to carry on from
===============================  ============================================================
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Protocol

_KEY = re.compile(r"[a-z0-9._-]+(/[a-z0-9._-]+)*")


class BlobStore(Protocol):
    def put(self, key: str, data: bytes) -> int:
        """Store ``data`` under ``key`` (replacing what was there); returns its size."""
        ...

    def get(self, key: str) -> bytes | None:
        """The blob, or None when there is none."""
        ...

    def size(self, key: str) -> int | None:
        ...

    def delete(self, key: str) -> None:
        """Delete the blob ``key``, or every blob whose key starts with ``key/`` (nothing
        there: no error)."""
        ...


def check_key(key: str) -> str:
    if not _KEY.fullmatch(key) or any(part in (".", "..") for part in key.split("/")):
        raise ValueError(f"not a blob key: {key!r}")
    return key


class FileBlobStore:
    """Blobs as files under ``root``."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)

    def _path(self, key: str) -> Path:
        return self.root / check_key(key)

    def put(self, key: str, data: bytes) -> int:
        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            raise
        return len(data)

    def get(self, key: str) -> bytes | None:
        try:
            return self._path(key).read_bytes()
        except FileNotFoundError:
            return None

    def size(self, key: str) -> int | None:
        try:
            return self._path(key).stat().st_size
        except FileNotFoundError:
            return None

    def delete(self, key: str) -> None:
        path = self._path(key)
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
