"""File formats matforge reads and writes, with validation.

:func:`validate_file` is what ``matforge import`` and ``POST /api/artifacts`` call before a
user's file enters the store: it dispatches on the file name's extension through
:data:`VALIDATORS` and returns the media type to record. To support a new format (the MERL
``.binary`` tables, dataset shards), write ``storage/formats/<format>.py`` with a validator
``(path, name) -> None`` that raises :class:`FormatError`, and add one entry below.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from storage.errors import FormatError, TooLargeError
from storage.formats.btf_folder import validate_btf_archive
from storage.formats.exr import validate_exr
from storage.formats.media import MEDIA_TYPES
from storage.formats.merl import validate_merl
from storage.formats.mlp_model import is_mlp_document, parse_mlp_document
from storage.formats.model_files import MODEL_FORMATS, json_format, not_a_model
from storage.formats.normal_map import validate_normal_map
from storage.formats.npz import validate_npz
from storage.formats.onnx import validate_onnx
from storage.formats.png import validate_png
from storage.formats.ubo_btf import validate_ubo_btf
from storage.formats.zip_budget import check_inflated_size

#: The largest JSON document accepted by :func:`validate_json`, in bytes.
MAX_JSON_BYTES = 64 * 1024 * 1024


def validate_json(path: Path, name: str) -> None:
    """Check that ``path`` holds one UTF-8 JSON document (RFC 8259: no NaN or Infinity)
    that is a model file: an object whose ``format`` is one of
    :data:`storage.formats.model_files.MODEL_FORMATS`. An unknown ``format`` near the start
    is refused before the document is decoded (:func:`~storage.formats.model_files.json_format`).

    A document in a user MLP material format (``matforge.mlp-brdf/1``,
    ``matforge.mlp-btf/1``) is also checked against it (:mod:`storage.formats.mlp_model`).
    Over :data:`MAX_JSON_BYTES`: :class:`TooLargeError`.
    """
    try:
        size = path.stat().st_size
        if size > MAX_JSON_BYTES:
            raise TooLargeError(
                f"{name}: JSON document of {size} bytes exceeds the limit of {MAX_JSON_BYTES} bytes"
            )
        fmt = json_format(path, name)
        if fmt is not None and fmt not in MODEL_FORMATS:
            raise not_a_model(fmt, name)
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise FormatError(name, f"cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise FormatError(name, f"not UTF-8 text (byte {exc.start})") from None

    def _no_constants(token: str) -> None:
        raise ValueError(f"{token} is not valid JSON")

    try:
        doc = json.loads(text, parse_constant=_no_constants)
    except json.JSONDecodeError as exc:
        raise FormatError(
            name, f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from None
    except (ValueError, RecursionError) as exc:
        raise FormatError(name, f"invalid JSON: {exc}") from None
    fmt = doc.get("format") if isinstance(doc, dict) else None
    if not isinstance(fmt, str) or fmt not in MODEL_FORMATS:
        raise not_a_model(fmt, name)
    if is_mlp_document(doc):
        parse_mlp_document(doc, name)


@dataclass(frozen=True)
class FileFormat:
    """A format known to :func:`validate_file`: its media type and validator
    ``validate(path, name)``; a format of many images (an archive) has ``pixel_cap`` set and
    its validator also takes ``max_pixels``, the cap on all its images' decoded pixels; a
    zip archive (``zipped``) may be given a cap on the bytes its members inflate to."""

    media_type: str
    validate: Callable[..., object]
    pixel_cap: bool = False
    zipped: bool = False


#: Extension (lower case, with the dot) → format. Extend here for new formats.
VALIDATORS: dict[str, FileFormat] = {
    ".exr": FileFormat(MEDIA_TYPES[".exr"], validate_exr),
    ".png": FileFormat(MEDIA_TYPES[".png"], validate_png),
    ".json": FileFormat(MEDIA_TYPES[".json"], validate_json),
    ".binary": FileFormat(MEDIA_TYPES[".binary"], validate_merl),
    ".npz": FileFormat(MEDIA_TYPES[".npz"], validate_npz, zipped=True),
    ".btf": FileFormat(MEDIA_TYPES[".btf"], validate_ubo_btf, pixel_cap=True),
    ".onnx": FileFormat(MEDIA_TYPES[".onnx"], validate_onnx),
}
#: Compound endings checked before the extension: a normal map is an image with a meaning.
COMPOUND_VALIDATORS: dict[str, FileFormat] = {
    ".normal.exr": FileFormat(MEDIA_TYPES[".exr"], validate_normal_map),
    ".normal.png": FileFormat(MEDIA_TYPES[".png"], validate_normal_map),
    ".btf.zip": FileFormat(MEDIA_TYPES[".zip"], validate_btf_archive, pixel_cap=True, zipped=True),
}


def format_for(name: str) -> tuple[str, FileFormat] | None:
    """The format :func:`validate_file` checks a file called ``name`` as: its ending (a key
    of :data:`COMPOUND_VALIDATORS`, else of :data:`VALIDATORS`) and the format; ``None``
    for an unsupported name."""
    lower = name.lower()
    for end, compound in COMPOUND_VALIDATORS.items():
        if lower.endswith(end):
            return end, compound
    suffix = Path(name).suffix.lower()
    fmt = VALIDATORS.get(suffix)
    return (suffix, fmt) if fmt is not None else None


def _any_case(text: str) -> str:
    """``text`` as a regular expression that matches it in any ASCII case."""
    return "".join(f"[{c.lower()}{c.upper()}]" if c.isalpha() else "\\" + c for c in text)


def upload_name_pattern() -> str:
    """The names :func:`validate_file` knows a format for, as one regular expression (read
    alike by ECMA-262 and Python, matched whole): a plain name (no ``/``, ``\\`` or control
    characters) ending in a compound ending, or in an extension after at least one other
    character (``.png`` alone is a hidden file with no extension); any case."""
    plain = r"[^/\\\x00-\x1f]"
    compound = "|".join(_any_case(end) for end in sorted(COMPOUND_VALIDATORS))
    suffixes = "|".join(_any_case(ext[1:]) for ext in sorted(VALIDATORS))
    return f"^(?:{plain}*(?:{compound})|{plain}+\\.(?:{suffixes}))$"


def validated_as(name: str, media_type: str) -> str | None:
    """The ending (``".btf.zip"``, ``".png"``, ...) of the format an upload recorded as
    ``name`` with ``media_type`` was validated as when it was stored (the record of
    :func:`validate_file`'s answer), or ``None`` when the record is not one it gives."""
    found = format_for(name)
    if found is None or found[1].media_type != media_type:
        return None
    return found[0]


def validate_file(
    path: Path,
    name: str,
    *,
    max_archive_pixels: int | None = None,
    max_inflated_bytes: int | None = None,
    inflate_budget: str = "",
) -> str:
    """Validate a user's file and return its media type.

    Parameters
    ----------
    path
        Where the bytes are (for an upload, a temporary file).
    name
        The user's file name: its extension picks the format, and error messages name it.
    max_archive_pixels
        For archives of images (``.btf.zip``) and Bonn ``.btf`` files: the most pixels all
        its slices may decode to, summed from the headers before any is decoded (default:
        the format's own, :data:`storage.formats.btf_folder.MAX_ARCHIVE_PIXELS`).
    max_inflated_bytes
        For zip archives (``.btf.zip``, ``.npz``): the most bytes all their members may
        inflate to, summed from the zip directory before anything is inflated
        (:func:`~storage.formats.zip_budget.check_inflated_size`); ``inflate_budget`` says
        in the error what that budget is made of.

    Raises
    ------
    FormatError
        Unsupported extension, or the bytes are not a valid file of that format.
    TooLargeError
        An archive whose images decode to more than ``max_archive_pixels``, or whose
        members inflate to more than ``max_inflated_bytes``.
    """
    found = format_for(name)
    if found is None:
        suffix = Path(name).suffix.lower()
        known = ", ".join(sorted(VALIDATORS))
        shown = f"'{suffix}'" if suffix else "(no extension)"
        raise FormatError(name, f"unsupported file type {shown}; known: {known}")
    fmt = found[1]
    if fmt.zipped and max_inflated_bytes is not None:
        check_inflated_size(Path(path), name, max_inflated_bytes, inflate_budget)
    if fmt.pixel_cap and max_archive_pixels is not None:
        fmt.validate(Path(path), name, max_pixels=max_archive_pixels)
    else:
        fmt.validate(Path(path), name)
    return fmt.media_type


__all__ = [
    "COMPOUND_VALIDATORS",
    "VALIDATORS",
    "FileFormat",
    "FormatError",
    "format_for",
    "upload_name_pattern",
    "validate_file",
    "validated_as",
    "validate_json",
]
