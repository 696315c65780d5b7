"""``/api/artifacts``: download verified objects, upload files, EXR previews, pixel values.

Only a string matching ``^(sha256:)?[0-9a-f]{64}$`` ever becomes a path in the store (the
path parameter is pattern-checked, and :func:`storage.artifacts.check_digest` again), and the
bytes are re-hashed before the response starts: a corrupt object is a 500 error, never data.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, Query, Request, Response
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool

from jobapi.errors import SpecError
from service.deps import AuthDep, Digest, JobsDep, SettingsDep, StoreDep
from service.previews import PreviewMaker
from service.schemas import ErrorPublic, UploadPublic
from service.submission import import_file
from storage.artifacts import check_digest
from storage.errors import TooLargeError
from storage.formats import upload_name_pattern

router = APIRouter(prefix="/api/artifacts", tags=["artifacts"], dependencies=[AuthDep])

#: Media types a browser may show inline; everything else is sent as an attachment.
INLINE_TYPES = frozenset({"image/png", "application/json", "text/plain", "text/csv"})
_ERRORS: dict[int | str, dict[str, Any]] = {
    404: {"model": ErrorPublic, "description": "no such object"},
    422: {"model": ErrorPublic, "description": "not a sha256 digest"},
    500: {"model": ErrorPublic, "description": "the object is corrupt on disk"},
}
_BUSY: dict[int | str, dict[str, Any]] = {
    503: {
        "model": ErrorPublic,
        "description": "every file checker stayed busy; try again after `Retry-After` seconds",
        "headers": {"Retry-After": {"schema": {"type": "integer"}}},
    }
}


def _cache_headers(digest: str, private: bool) -> dict[str, str]:
    scope = "private" if private else "public"
    return {
        "ETag": f'"{digest}"',
        "Cache-Control": f"{scope}, max-age=31536000, immutable",
        "X-Content-Type-Options": "nosniff",
    }


def _not_modified(request: Request, digest: str) -> bool:
    tags = request.headers.get("if-none-match", "")
    return any(
        t.strip().strip('"').removeprefix("W/").strip('"') == digest for t in tags.split(",")
    )


@router.get(
    "/{digest}",
    response_class=FileResponse,
    responses={**_ERRORS, 200: {"description": "the bytes, verified against the digest"}},
    summary="Download an object",
)
def get_artifact(
    digest: Digest, request: Request, jobs: JobsDep, store: StoreDep, settings: SettingsDep
) -> Response:
    """The object's bytes, re-hashed against the digest before the first byte is sent. The
    media type and file name come from the job artifact or upload that recorded it; the
    ETag is the digest and the response may be cached forever (objects never change)."""
    d = check_digest(digest)
    headers = _cache_headers(d, private=bool(settings.token))
    if _not_modified(request, d) and store.exists(d):
        return Response(status_code=304, headers=headers)
    path = store.open_verified(d)
    record = jobs.find_digest(d)
    media_type = record.media_type if record else "application/octet-stream"
    filename = Path(record.name).name if record else d
    return FileResponse(
        path,
        media_type=media_type,
        filename=filename,
        headers=headers,
        content_disposition_type="inline" if media_type in INLINE_TYPES else "attachment",
    )


@router.get(
    "/{digest}/preview.png",
    response_class=Response,
    responses={
        **_ERRORS,
        **_BUSY,
        200: {"content": {"image/png": {}}, "description": "tone-mapped sRGB PNG"},
        422: {
            "model": ErrorPublic,
            "description": "not a sha256 digest, not an EXR, or too large to preview",
        },
    },
    summary="PNG preview of an EXR object",
)
def get_preview(
    digest: Digest,
    request: Request,
    jobs: JobsDep,
    store: StoreDep,
    settings: SettingsDep,
    exposure: Annotated[
        float, Query(ge=-16, le=16, description="exposure in stops (the compare view's slider)")
    ] = 0.0,
) -> Response:
    """A tone-mapped sRGB PNG of an EXR object (for the dashboard), at most 1024 pixels on
    its long side, `exposure` stops brighter. The image is decoded once, in a memory-capped
    child process, to a thumbnail that every exposure is made from; cached in memory. 422
    when the object is not an EXR, or has more than `MATFORGE_PREVIEW_MAX_PIXELS` pixels."""
    d = check_digest(digest)
    key = d if exposure == 0 else f"{d}@{exposure:g}"
    headers = _cache_headers(key + "-preview", private=bool(settings.token))
    previews: PreviewMaker = request.app.state.previews

    def source() -> tuple[Path, str]:
        path = store.open_verified(d)
        record = jobs.find_digest(d)
        return path, record.name if record else f"sha256:{d}"

    return Response(previews.png(d, exposure, source), media_type="image/png", headers=headers)


@router.get(
    "/{digest}/pixels",
    response_class=Response,
    responses={
        **_ERRORS,
        **_BUSY,
        200: {
            "content": {"application/octet-stream": {}},
            "description": "float32 little-endian RGB rows, top row first; the size is in "
            "the `X-Image-Width` and `X-Image-Height` headers",
        },
        422: {
            "model": ErrorPublic,
            "description": "not a sha256 digest, not an image of that form, or too large",
        },
    },
    summary="Pixel values of an image object",
)
def get_pixels(
    digest: Digest,
    request: Request,
    jobs: JobsDep,
    store: StoreDep,
    settings: SettingsDep,
    values: Annotated[
        Literal["linear", "srgb", "magma"],
        Query(
            description="`linear`: an EXR's linear RGB; `srgb`: a PNG's sRGB-encoded values "
            "in [0, 1]; `magma`: the value in [0, 1] a magma-coloured PNG (a FLIP error map) "
            "encodes, in all three channels"
        ),
    ] = "linear",
) -> Response:
    """The pixel values the compare view reads under the cursor and subtracts for its
    difference image: `(h, w, 3)` float32, on the grid of the object's preview (at most 1024
    pixels on the long side, every k-th pixel, unfiltered). Decoded once, in a memory-capped
    child process, and cached, as previews are."""
    d = check_digest(digest)
    headers = _cache_headers(f"{d}-pixels-{values}", private=bool(settings.token))
    previews: PreviewMaker = request.app.state.previews

    def source() -> tuple[Path, str]:
        path = store.open_verified(d)
        record = jobs.find_digest(d)
        return path, record.name if record else f"sha256:{d}"

    rgb = previews.pixels(d, values, source)
    h, w = rgb.shape[:2]
    headers.update({"X-Image-Width": str(w), "X-Image-Height": str(h), "X-Image-Values": values})
    body = np.ascontiguousarray(rgb, dtype="<f4").tobytes()
    return Response(body, media_type="application/octet-stream", headers=headers)


def _check_name(name: str) -> str:
    bad = set("/\\\x00") | {chr(c) for c in range(32)}
    if name in (".", "..") or any(ch in bad for ch in name):
        raise SpecError([("query.name", f"{name!r} is not a plain file name (no slashes)")])
    return name


@router.post(
    "",
    status_code=201,
    response_model=UploadPublic,
    summary="Upload a file",
    openapi_extra={
        "requestBody": {
            "required": True,
            "description": "the raw bytes of the file",
            "content": {
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"}}
            },
        }
    },
    responses={
        **_BUSY,
        413: {
            "model": ErrorPublic,
            "description": "over the upload size limit (a JSON model file over 64 MiB "
            "included), over its checking budget (time, or bytes its archive members "
            "inflate to), an archive whose images' headers sum to over "
            "MATFORGE_ARCHIVE_MPIX megapixels, or an ONNX graph with a tensor computed "
            "from constants only over the initialiser limit; `error` names what was over",
        },
        422: {
            "model": ErrorPublic,
            "description": "malformed file, or unknown type; `error` names the file",
        },
    },
)
async def upload(
    request: Request,
    jobs: JobsDep,
    store: StoreDep,
    settings: SettingsDep,
    name: Annotated[
        str,
        Query(
            min_length=1,
            max_length=255,
            description="file name; its extension selects the format check (`.exr`, "
            "`.binary`, ...; a compound ending first: `.btf.zip`, `.normal.png`), in any case",
            # The names with a format, stated in the schema (checked by the route and
            # `validate_file`, whose 422 names the file): a schema-valid name is never
            # refused for its name.
            json_schema_extra={"pattern": upload_name_pattern()},
        ),
    ],
) -> dict[str, Any]:
    """Stream the raw body to a temporary file (capped at `MATFORGE_MAX_UPLOAD_MB`), validate
    it by its format, and store it. Use the returned `ref` in job specs."""
    _check_name(name)
    limit = settings.max_upload_bytes
    fd, tmp_name = tempfile.mkstemp(dir=store.tmp, prefix="upload-", suffix=Path(name).suffix)
    tmp = Path(tmp_name)
    try:
        size = 0
        with os.fdopen(fd, "wb") as fh:
            async for chunk in request.stream():
                size += len(chunk)
                if size > limit:
                    raise TooLargeError(f"{name}: upload exceeds the limit of {limit} bytes")
                fh.write(chunk)
        checker = request.app.state.upload_checker
        record = await run_in_threadpool(
            import_file, tmp, jobs, store, name=name, max_bytes=limit, validate=checker.validate
        )
    finally:
        tmp.unlink(missing_ok=True)
    return {
        "digest": record.digest,
        "ref": f"sha256:{record.digest}",
        "size": record.size,
        "media_type": record.media_type,
        "name": record.name,
    }
