"""``/api/assets``: files that scenes reference (meshes, texture and environment images),
uploaded once and named by the SHA-256 of their bytes.

``POST /api/assets`` takes the file's bytes as the body (any content type), at most
``LUCENT_MAX_ASSET_BYTES``; with ``?sha256=<hex>`` (what the client computed) a body whose hash
differs (truncated, corrupted on the way) is refused. The bytes must be a kind of file a scene
reads (``renderer.scene.files.sniff``: OBJ, PLY, PNG, EXR, PFM, HDR). The answer names the
asset, ``{"asset": "sha256:<hex>", ...}``: the reference to put in a scene. The bytes go to the
blob store (``services.farm.blobs``), once whatever the number of uploads.

``GET /api/assets/{sha256}`` returns them; ``HEAD`` says whether the farm has them (a client
uploads only what it lacks). A scene's references are checked when its job is submitted
(``services.farm.jobs.check_scene``): an unknown asset is a 422 naming the field.
"""

from __future__ import annotations

import re
from typing import Annotated

from fastapi import APIRouter, HTTPException, Path, Query, Request, Response, status
from starlette.concurrency import run_in_threadpool

from renderer.scene.files import sniff
from services.api.deps import BlobsDep, SettingsDep
from services.farm.blobs import content_key, put_content

router = APIRouter(prefix="/assets", tags=["assets"])

_HEX = re.compile(r"[0-9a-f]{64}")
_KINDS = (".obj", ".ply", ".png", ".exr", ".pfm", ".hdr")


def _key(name: str) -> str:
    """``sha256:<hex>`` or ``<hex>`` -> the blob key; 404 for anything else (never a path)."""
    digest = name.removeprefix("sha256:")
    if not _HEX.fullmatch(digest):
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            detail="not an asset name (sha256:<64 hexadecimal digits>)")
    return "sha256:" + digest


@router.post("", status_code=status.HTTP_201_CREATED, responses={
    413: {"description": "over LUCENT_MAX_ASSET_BYTES"},
    422: {"description": "not a kind of file a scene reads, or `sha256` does not match"}})
async def upload_asset(request: Request, blobs: BlobsDep, settings: SettingsDep,
                       sha256: Annotated[str | None, Query(
                           pattern=r"^(sha256:)?[0-9a-f]{64}$",
                           description="the SHA-256 the client computed: a body whose hash "
                                       "differs is refused")] = None) -> dict:
    data = await request.body()  # at most max_asset_bytes (services.api.guards.BodyLimit)
    key = content_key(data)
    if sha256 is not None and key != "sha256:" + sha256.removeprefix("sha256:"):
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, detail=[{
            "loc": ["query", "sha256"], "type": "value_error",
            "msg": f"the body's SHA-256 is {key}, not {sha256}: truncated or corrupt upload "
                   f"({len(data)} bytes received)"}])
    kind = sniff(data)
    if kind not in _KINDS:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, detail=[{
            "loc": ["body"], "type": "value_error",
            "msg": "not a kind of file a scene reads (OBJ, PLY, PNG, EXR, PFM, HDR)"}])
    await run_in_threadpool(put_content, blobs, data)
    return {"asset": key, "bytes": len(data), "kind": kind.lstrip(".")}


AssetName = Annotated[str, Path(description="sha256:<hex> or <hex>")]


@router.head("/{name}", responses={404: {"description": "no such asset"}})
def has_asset(name: AssetName, blobs: BlobsDep) -> Response:
    """200 when the farm has the asset (a client uploads only what it lacks), else 404."""
    key = _key(name)
    if not blobs.exists(key):
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no asset {key}")
    return Response(status_code=status.HTTP_200_OK)


@router.get("/{name}", responses={
    200: {"content": {"application/octet-stream": {}}}, 404: {"description": "no such asset"}})
def get_asset(name: AssetName, blobs: BlobsDep) -> Response:
    key = _key(name)
    data = blobs.get(key)
    if data is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no asset {key}")
    return Response(content=data, media_type="application/octet-stream",
                    headers={"ETag": f'"{key}"', "Cache-Control": "max-age=31536000, immutable"})
