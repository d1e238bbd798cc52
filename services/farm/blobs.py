"""The blob store: bytes by key, for what is too large or too final for Redis (a finished job's
image, the EXR and the PNG at default exposure; the assets scenes reference, ``POST /api/assets``).

``BlobStore`` is the interface (``put``, ``get``, ``delete``, ``exists`` by key), with two
implementations, chosen by ``open_blob_store`` from where the settings say the store is:
``FileBlobStore``, a folder (``LUCENT_BLOB_DIR``, by default ``blobs/`` in the farm's data folder
``LUCENT_DATA_DIR``) shared by every API process and worker (a shared volume); ``S3BlobStore``, a
bucket of an S3-compatible object store (``LUCENT_BLOB_URL=s3://bucket/prefix``; the endpoint,
region and credentials from boto3's usual environment: ``AWS_ENDPOINT_URL_S3`` for MinIO or
another S3-compatible server, ``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``,
``AWS_DEFAULT_REGION``). boto3 is the optional extra ``s3``.

Keys are content addresses, ``sha256:<64 hex digits>`` of the bytes (``put_content``): the same
image written twice is stored once, a key never names a path, and a blob never changes under its
key. Who still uses a blob is counted in the job store (``JobStore.release_blobs``): two jobs of the
same scene and seed make the same image.
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

KEY = re.compile(r"sha256:([0-9a-f]{64})")
# s3://bucket[/prefix]: bucket names as S3 allows them (3-63 characters), a prefix of plain names
S3_URL = re.compile(r"s3://([a-z0-9][a-z0-9.-]{1,61}[a-z0-9])(?:/([A-Za-z0-9._/-]*))?")


def content_key(data: bytes) -> str:
    return "sha256:" + hashlib.sha256(data).hexdigest()


class BlobStore(Protocol):
    def put(self, key: str, data: bytes) -> None:
        """Store ``data`` under ``key`` (atomic: a reader sees all of it or nothing)."""

    def get(self, key: str) -> bytes | None:
        """The bytes under ``key``; None when there are none."""

    def delete(self, key: str) -> None:
        """Remove ``key``; nothing happens when it is absent."""

    def exists(self, key: str) -> bool: ...


def asset_reader(blobs: BlobStore) -> Callable[[str], bytes]:
    """``renderer.scene.files.AssetReader`` on the blob store: the bytes of an uploaded asset
    (``POST /api/assets``), ``KeyError`` for one not there."""

    def read(name: str) -> bytes:
        data = blobs.get(name) if KEY.fullmatch(name) else None
        if data is None:
            raise KeyError(name)
        return data

    return read


def put_content(blobs: BlobStore, data: bytes) -> str:
    """Store ``data`` under its content address, once; returns the key."""
    key = content_key(data)
    if not blobs.exists(key):
        blobs.put(key, data)
    return key


class FileBlobStore:
    """Blobs as files: ``sha256:abcd…`` is ``{root}/sha256/ab/abcd…`` (256 folders, so that no
    folder grows past a few thousand files before the store holds a million)."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)

    def path(self, key: str) -> Path:
        digest = _digest(key)
        return self.root / "sha256" / digest[:2] / digest

    def put(self, key: str, data: bytes) -> None:
        path = self.path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        # Written beside its place, then renamed over it: a reader never sees half a blob
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".put-")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def get(self, key: str) -> bytes | None:
        try:
            return self.path(key).read_bytes()
        except FileNotFoundError:
            return None

    def delete(self, key: str) -> None:
        self.path(key).unlink(missing_ok=True)

    def exists(self, key: str) -> bool:
        return self.path(key).is_file()


def _digest(key: str) -> str:
    m = KEY.fullmatch(key)
    if m is None:  # never a path or an object name from outside: only content addresses are keys
        raise ValueError(f"not a blob key: {key!r} (sha256:<64 hexadecimal digits>)")
    return m.group(1)


class S3BlobStore:
    """Blobs as objects of an S3-compatible bucket: ``sha256:abcd…`` is
    ``{prefix}sha256/ab/abcd…``, as in ``FileBlobStore``. A ``PutObject`` is atomic (a reader
    sees the old object, none, or all of the new one), so no temporary name is needed."""

    def __init__(self, bucket: str, prefix: str = "", client: Any = None):
        if client is None:
            import boto3  # the optional extra "s3"

            client = boto3.client("s3")
        self.client = client
        self.bucket = bucket
        self.prefix = prefix.strip("/") + "/" if prefix.strip("/") else ""

    def name(self, key: str) -> str:
        digest = _digest(key)
        return f"{self.prefix}sha256/{digest[:2]}/{digest}"

    def put(self, key: str, data: bytes) -> None:
        self.client.put_object(Bucket=self.bucket, Key=self.name(key), Body=data)

    def get(self, key: str) -> bytes | None:
        try:
            reply = self.client.get_object(Bucket=self.bucket, Key=self.name(key))
        except self.client.exceptions.NoSuchKey:
            return None
        return bytes(reply["Body"].read())

    def delete(self, key: str) -> None:
        # DeleteObject of a missing object succeeds: nothing happens when it is absent
        self.client.delete_object(Bucket=self.bucket, Key=self.name(key))

    def exists(self, key: str) -> bool:
        from botocore.exceptions import ClientError

        try:
            self.client.head_object(Bucket=self.bucket, Key=self.name(key))
        except ClientError as err:
            if err.response.get("Error", {}).get("Code") in ("404", "NoSuchKey", "NotFound"):
                return False
            raise
        return True


def open_blob_store(where: str | os.PathLike) -> BlobStore:
    """The blob store at ``where``: ``s3://bucket/prefix`` (``S3BlobStore``; one client per process
    and location, boto3's clients being thread-safe) or a folder (``FileBlobStore``)."""
    return _open_blob_store(os.fspath(where))


@functools.lru_cache(maxsize=8)
def _open_blob_store(where: str) -> BlobStore:
    if where.startswith("s3://"):
        m = S3_URL.fullmatch(where)
        if m is None:
            raise ValueError(f"not an S3 location: {where!r} (s3://bucket/prefix)")
        return S3BlobStore(m.group(1), m.group(2) or "")
    return FileBlobStore(where)


class AssetCache:
    """A worker's on-disk cache of assets in front of the blob store (a shared volume that may be
    a network filesystem): an asset is fetched once, kept in ``folder`` and read from there
    after; the least recently used are removed once the cache holds more than ``max_bytes``.
    The bytes are checked against their name wherever they come from (``load_scene`` does)."""

    def __init__(self, blobs: BlobStore, folder: str | os.PathLike, max_bytes: int):
        self.blobs = blobs
        self.folder = Path(folder)
        self.max_bytes = max_bytes
        self.fetched = 0  # assets read from the blob store (not the cache) by this process

    def read(self, name: str) -> bytes:
        m = KEY.fullmatch(name)
        if m is None:
            raise KeyError(name)
        cached = self.folder / m.group(1)
        try:
            data = cached.read_bytes()
            os.utime(cached)  # recently used
            return data
        except FileNotFoundError:
            pass
        data = asset_reader(self.blobs)(name)
        self.fetched += 1
        if 0 < len(data) <= self.max_bytes:
            self.folder.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=self.folder, prefix=".put-")
            try:
                with os.fdopen(fd, "wb") as f:
                    f.write(data)
                os.replace(tmp, cached)  # a reader never sees half an asset
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
            self._trim()
        return data

    def _trim(self) -> None:
        files = []
        for p in self.folder.iterdir():
            if p.is_file() and not p.name.startswith("."):
                st = p.stat()
                files.append((st.st_mtime, st.st_size, p))
        total = sum(size for _, size, _ in files)
        for _, size, path in sorted(files):
            if total <= self.max_bytes:
                break
            path.unlink(missing_ok=True)
            total -= size
