"""Media types of artifact and upload files, by extension: the one table of them.

Both the job context (artifacts a kind writes) and :func:`storage.formats.validate_file`
(files a user uploads) take their media types from here.
"""

from __future__ import annotations

import mimetypes
from pathlib import Path

#: Extension (lower case, with the dot) -> media type, for the formats matforge writes.
MEDIA_TYPES: dict[str, str] = {
    ".exr": "image/x-exr",
    ".png": "image/png",
    ".json": "application/json",
    ".binary": "application/x-merl-binary",
    ".npz": "application/x-npz",
    ".pt": "application/x-pytorch",
    ".csv": "text/csv",
    ".txt": "text/plain",
    ".zip": "application/zip",
    ".btf": "application/x-ubo-btf",
    ".onnx": "application/x-onnx",
}


def media_type_for(name: str) -> str:
    """The media type of a file called ``name``, from its extension: ours first, then the
    system's table, else ``application/octet-stream``."""
    suffix = Path(name).suffix.lower()
    return MEDIA_TYPES.get(suffix) or mimetypes.guess_type(name)[0] or "application/octet-stream"
