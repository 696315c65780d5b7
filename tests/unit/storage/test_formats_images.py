"""EXR and PNG readers/writers and the upload dispatcher.

Oracles: round trips (write then read gives the pixels back, bit-exact for float32 EXR and
uint8 PNG), byte-identical rewrites, OpenEXR and Pillow themselves for foreign files, and
damaged files (truncated, garbage, wrong channels) that must raise ``FormatError`` naming
the file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from storage.errors import FormatError
from storage.formats import VALIDATORS, validate_file
from storage.formats.exr import exr_bytes, read_exr, validate_exr, write_exr
from storage.formats.png import read_png, write_png


@pytest.fixture
def rgb() -> np.ndarray:
    """A (5, 7, 3) float32 HDR image with values above 1 and one NaN."""
    img = np.random.default_rng(3).random((5, 7, 3)).astype(np.float32) * 8.0
    img[1, 2, 0] = np.nan
    return img


def test01_exr_round_trip_and_deterministic_bytes(tmp_path: Path, rgb: np.ndarray) -> None:
    write_exr(tmp_path / "a.exr", rgb)
    write_exr(tmp_path / "b.exr", rgb.copy())
    a, b = (tmp_path / "a.exr").read_bytes(), (tmp_path / "b.exr").read_bytes()
    assert a == b == exr_bytes(rgb)
    back = read_exr(tmp_path / "a.exr")
    assert back.dtype == np.float32 and back.shape == rgb.shape
    np.testing.assert_array_equal(back, rgb)  # NaN == NaN for assert_array_equal
    info = validate_exr(tmp_path / "a.exr")
    assert (info.width, info.height) == (7, 5) and {"R", "G", "B"} <= set(info.channels)


def test02_exr_foreign_layouts(tmp_path: Path, rgb: np.ndarray) -> None:
    # Half-float RGBA written by OpenEXR itself reads back as float32 RGB (alpha ignored).
    rgba = np.concatenate([rgb, np.ones_like(rgb[..., :1])], axis=-1).astype(np.float16)
    with OpenEXR.File(
        {"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage}, {"RGBA": rgba}
    ) as f:
        f.write(str(tmp_path / "half.exr"))
    back = read_exr(tmp_path / "half.exr")
    np.testing.assert_array_equal(back, rgba[..., :3].astype(np.float32))
    # A luminance-only EXR has no R, G, B channels.
    with OpenEXR.File(
        {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
        {"Y": rgb[..., 1].copy()},
    ) as f:
        f.write(str(tmp_path / "grey.exr"))
    with pytest.raises(FormatError, match=r"grey\.exr: needs R, G and B channels"):
        read_exr(tmp_path / "grey.exr")


def test03_damaged_exr_names_the_file(tmp_path: Path, rgb: np.ndarray) -> None:
    data = exr_bytes(np.tile(rgb, (40, 40, 1)))
    (tmp_path / "cut.exr").write_bytes(data[: len(data) // 2])
    (tmp_path / "junk.exr").write_bytes(b"this is not an image" * 20)
    (tmp_path / "header.exr").write_bytes(data[:40])
    for name in ("cut.exr", "junk.exr", "header.exr"):
        with pytest.raises(FormatError) as err:
            read_exr(tmp_path / name)
        assert name in str(err.value) and err.value.filename.endswith(name)
        with pytest.raises(FormatError, match=name):
            validate_file(tmp_path / name, name)
    with pytest.raises(FormatError, match="upload.exr"):
        read_exr(tmp_path / "junk.exr", name="upload.exr")


def test04_png_round_trip_and_deterministic_bytes(tmp_path: Path) -> None:
    img = np.random.default_rng(5).integers(0, 256, (6, 9, 3), dtype=np.uint8)
    data = write_png(tmp_path / "a.png", img)
    assert data == (tmp_path / "a.png").read_bytes() == write_png(None, img.copy())
    back = read_png(tmp_path / "a.png")
    assert back.dtype == np.float32 and back.shape == (6, 9, 3)
    np.testing.assert_array_equal(np.rint(back * 255).astype(np.uint8), img)
    with Image.open(tmp_path / "a.png") as pil:  # no metadata chunks were written
        assert pil.mode == "RGB" and not pil.info.get("dpi") and not getattr(pil, "text", {})
    # Grey and 16-bit grey PNGs written by Pillow read as three equal channels.
    Image.fromarray(img[..., 0]).save(tmp_path / "grey.png")
    np.testing.assert_array_equal(
        read_png(tmp_path / "grey.png")[..., 2], (img[..., 0] / 255.0).astype(np.float32)
    )
    wide = (np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000).astype(np.uint16)
    Image.fromarray(wide).save(tmp_path / "wide.png")
    np.testing.assert_allclose(read_png(tmp_path / "wide.png")[..., 0], wide / 65535.0, rtol=1e-6)
    with pytest.raises(ValueError, match="uint8"):
        write_png(None, img.astype(np.float32))


def test05_damaged_png_names_the_file(tmp_path: Path) -> None:
    data = write_png(None, np.full((64, 64, 3), 200, dtype=np.uint8))
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    (tmp_path / "junk.png").write_bytes(b"GIF89a not a png at all")
    for name in ("cut.png", "junk.png"):
        with pytest.raises(FormatError, match=name):
            read_png(tmp_path / name)


def test06_validate_file_dispatch(tmp_path: Path, rgb: np.ndarray) -> None:
    write_exr(tmp_path / "x.bin", rgb)  # the extension of ``name`` picks the format
    assert validate_file(tmp_path / "x.bin", "render.EXR") == "image/x-exr"
    write_png(tmp_path / "p", np.zeros((2, 2, 3), np.uint8))
    assert validate_file(tmp_path / "p", "preview.png") == "image/png"
    (tmp_path / "ok.json").write_text('{"format": "matforge.brdf-model/1", "a": [1, 2.5]}')
    assert validate_file(tmp_path / "ok.json", "ok.json") == "application/json"
    (tmp_path / "nan.json").write_text('{"a": NaN}')
    with pytest.raises(FormatError, match=r"nan\.json: invalid JSON"):
        validate_file(tmp_path / "nan.json", "nan.json")
    (tmp_path / "bad.json").write_text('{"a": ')
    with pytest.raises(FormatError, match=r"bad\.json: invalid JSON at line 1"):
        validate_file(tmp_path / "bad.json", "bad.json")
    with pytest.raises(FormatError) as err:
        validate_file(tmp_path / "ok.json", "notes.xyz")
    assert str(err.value) == (
        "notes.xyz: unsupported file type '.xyz'; known: " + ", ".join(sorted(VALIDATORS))
    )
    with pytest.raises(FormatError, match="no extension"):
        validate_file(tmp_path / "ok.json", "README")
    with pytest.raises(FormatError, match=r"fake\.png: not a PNG"):
        validate_file(tmp_path / "x.bin", "fake.png")
