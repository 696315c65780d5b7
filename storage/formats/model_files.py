"""JSON model files: which formats they may be, and a document's ``format`` read from at
most its first bytes.

A JSON file enters the store only as a model file (``docs/formats.md``): an object whose
``format`` is one of :data:`MODEL_FORMATS`. :func:`json_format` reads the top-level
``format`` of a document from at most ``max_bytes`` of it, decoding only the members before
it, so telling what a file is costs a bounded amount of memory and time whatever its size
(the web process checks a model ref this way at submission).

This module imports nothing of ours but :mod:`storage.errors` and
:mod:`storage.formats.mlp_model` (storage imports nothing above it: the trained models'
formats are spelled here, and a test keeps them equal to their writers' constants).
"""

from __future__ import annotations

import json
from pathlib import Path

from storage.errors import FormatError
from storage.formats.mlp_model import BRDF_FORMAT, BTF_FORMAT

#: ``format`` -> what it is: the JSON documents a user may import or upload.
MODEL_FORMATS: dict[str, str] = {
    BRDF_FORMAT: "your BRDF network (matforge.export.brdf_mlp)",
    BTF_FORMAT: "your neural BTF (matforge.export.btf_mlp)",
    "matforge.brdf-model/1": "a trained BRDF model (train.brdf model.json)",
    "matforge.btf-model/1": "a trained BTF model (train.btf model.json)",
    "matforge.fabric-model/1": "a trained fabric model (train.fabric model.json)",
}
#: Bytes :func:`json_format` reads by default.
HEAD_BYTES = 256 * 1024
_WS = " \t\r\n"


def _no_constants(token: str) -> None:
    raise ValueError(f"{token} is not valid JSON")


def not_a_model(fmt: object, name: str) -> FormatError:
    """The error of a JSON file whose ``format`` (``None``: it has none) is not known."""
    shown = "no 'format'" if fmt is None else f"'format' {fmt!r:.80}"
    return FormatError(
        name,
        f"not a model file: a JSON file must be one of matforge's model formats "
        f"({', '.join(MODEL_FORMATS)}; docs/formats.md), and this one has {shown}",
    )


def _text_of(head: bytes, whole: bool, name: str) -> str:
    if head.startswith(b"\xef\xbb\xbf"):
        head = head[3:]
    try:
        return head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if whole or exc.start < len(head) - 3:  # not a character cut by the head's end
            raise FormatError(name, f"not UTF-8 text (byte {exc.start})") from None
        return head[: exc.start].decode("utf-8")


def json_format(path: Path, name: str, *, max_bytes: int = HEAD_BYTES) -> str | None:
    """The top-level ``format`` string of the JSON document in ``path``, read from at most
    its first ``max_bytes`` bytes; ``None`` when those bytes end before a ``format`` member
    (or inside one). Only the members up to ``format`` are decoded.

    Raises :class:`FormatError` naming ``name`` when those bytes show the file is no model
    file: not a JSON object, invalid JSON (in a document read whole), a ``format`` that is
    not a string, or a whole document without one.
    """
    with open(path, "rb") as fh:
        head = fh.read(max_bytes + 1)
    whole = len(head) <= max_bytes
    text = _text_of(head[:max_bytes], whole, name)
    decoder = json.JSONDecoder(parse_constant=_no_constants)

    def skip(i: int) -> int:
        while i < len(text) and text[i] in _WS:
            i += 1
        return i

    i = skip(0)
    if whole and i == len(text):
        raise FormatError(name, "empty file, not a JSON model file")
    if i < len(text) and text[i] != "{":
        raise FormatError(name, "not a model file: a JSON model file is an object with a 'format'")
    i += 1
    try:
        while True:
            i = skip(i)
            if i < len(text) and text[i] == "}":
                break
            if i < len(text) and text[i] != '"':
                raise json.JSONDecodeError("Expecting property name", text, i)
            key, i = decoder.raw_decode(text, i)
            i = skip(i)
            if i >= len(text) or text[i] != ":":
                raise json.JSONDecodeError("Expecting ':' delimiter", text, i)
            value, i = decoder.raw_decode(text, skip(i + 1))
            if key == "format":
                if not isinstance(value, str):
                    raise FormatError(
                        name, f"not a model file: its 'format' is not a string ({value!r:.60})"
                    )
                return value
            i = skip(i)
            if i < len(text) and text[i] == ",":
                i += 1
            elif i < len(text) and text[i] == "}":
                break
            else:
                raise json.JSONDecodeError("Expecting ',' delimiter", text, i)
    except json.JSONDecodeError as exc:
        if not whole:
            return None  # the head ends inside a member: undecided
        raise FormatError(
            name, f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from None
    except (ValueError, RecursionError) as exc:
        raise FormatError(name, f"invalid JSON: {exc}") from None
    if not whole:
        return None
    raise not_a_model(None, name)
