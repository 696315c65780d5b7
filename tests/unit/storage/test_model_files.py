"""A JSON file enters the store only as a model file: an object whose ``format`` is one of
``MODEL_FORMATS``, told from at most its first bytes where that suffices.

References: the formats' writers' own constants (``models.*.portable.FORMAT``,
``storage.formats.mlp_model``); documents written here by hand, whose bytes past the part
that decides are made invalid on purpose, so a check that decoded them would say so.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from storage.errors import FormatError, TooLargeError
from storage.formats import MAX_JSON_BYTES, validate_file
from storage.formats.mlp_model import FORMATS
from storage.formats.model_files import HEAD_BYTES, MODEL_FORMATS, json_format

JUNK = "[" * 10 + "not json" * (HEAD_BYTES // 4)  # far past the head, invalid throughout


def test01_the_known_formats_are_their_writers() -> None:
    from models.brdf.portable import FORMAT as BRDF_MODEL
    from models.btf.portable import FORMAT as BTF_MODEL
    from models.fabric.portable import FORMAT as FABRIC_MODEL

    assert set(MODEL_FORMATS) == {*FORMATS, BRDF_MODEL, BTF_MODEL, FABRIC_MODEL}


def test02_a_json_of_no_known_format_is_refused_naming_the_file(tmp_path: Path) -> None:
    cases = {
        '{"format": "nope"}': "and this one has 'format' 'nope'",
        '{"name": "x"}': "and this one has no 'format'",
        "[1, 2]": "a JSON model file is an object with a 'format'",
        '{"format": 7}': "its 'format' is not a string (7)",
        "": "empty file",
    }
    for i, (text, says) in enumerate(cases.items()):
        path = tmp_path / f"f{i}.json"
        path.write_text(text)
        with pytest.raises(FormatError) as info:
            validate_file(path, "mine.json")
        assert str(info.value).startswith("mine.json: ") and says in str(info.value), info.value
    for fmt in MODEL_FORMATS:
        if fmt in FORMATS:
            continue  # the MLP formats are checked in full (tests/unit/models/external)
        path = tmp_path / "trained.json"
        path.write_text(f'{{"format": "{fmt}", "materials": []}}')
        assert validate_file(path, "trained.json") == "application/json"


def test03_an_unknown_format_is_refused_from_the_head_alone(tmp_path: Path) -> None:
    """``{"format": "other", "x": <invalid bytes to 8 MB>}``: refused for its format, not
    for its invalid JSON, so the document past the head was never decoded."""
    path = tmp_path / "big.json"
    path.write_text('{"format": "other", "x": ' + JUNK * 8)
    with pytest.raises(FormatError, match=r"^big\.json: not a model file: .*'format' 'other'"):
        validate_file(path, "big.json")


def test04_json_format_reads_at_most_the_head(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    # format after a small member (sorted keys put "analytic" first): found, junk unread
    path.write_text('{"analytic": {"kd": [1, 2, 3]}, "format": "matforge.mlp-brdf/1", "x": ' + JUNK)
    assert json_format(path, "m.json") == "matforge.mlp-brdf/1"
    # format only after a member longer than the head: undecided, not an error
    path.write_text('{"x": ' + JUNK + ', "format": "matforge.mlp-brdf/1"}')
    assert json_format(path, "m.json") is None
    # a document read whole is decided either way
    path.write_text('{"x": [1, 2], "format": "matforge.mlp-btf/1"}')
    assert json_format(path, "m.json") == "matforge.mlp-btf/1"
    path.write_text('{"x": [1, 2],, "format": "matforge.mlp-btf/1"}')
    with pytest.raises(
        FormatError, match=r"^m\.json: invalid JSON at line 1, column 14: Expecting property name"
    ):
        json_format(path, "m.json")


def test05_over_the_json_limit_is_413(tmp_path: Path) -> None:
    path = tmp_path / "huge.json"
    with path.open("wb") as f:
        f.truncate(MAX_JSON_BYTES + 1)  # sparse: nothing is read
    with pytest.raises(TooLargeError, match=r"^huge\.json: JSON document of 67108865 bytes"):
        validate_file(path, "huge.json")
