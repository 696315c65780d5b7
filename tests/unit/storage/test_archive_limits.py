"""Bounded decoding of slice archives (issue 21, item 1): the pixels of all of an archive's
images are summed from their headers and capped before any is decoded, PNG slices decode
through a table (no float64 copies of the image), and a shard is written one slice at a
time with the same bytes as before."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from storage.errors import TooLargeError
from storage.formats import validate_file
from storage.formats.btf import shard_bytes, write_shard
from storage.formats.btf_folder import SliceFolder, archive_pixels, srgb_to_linear
from storage.formats.png import read_png


def slice_zip(path: Path, n: int, size: tuple[int, int], mode: str = "1") -> Path:
    """A ``.btf.zip`` of ``n`` PNG slices of ``size`` ``(W, H)`` in Pillow ``mode``."""
    rng = np.random.default_rng(5)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        rows = ["file,theta_i,phi_i,theta_o,phi_o"]
        for k in range(n):
            w, h = size
            if mode == "I;16":
                img = Image.fromarray(rng.integers(0, 65536, (h, w), dtype=np.uint16))
            else:
                img = Image.fromarray(rng.integers(0, 256, (h, w, 3), dtype=np.uint8)).convert(mode)
            buf = io.BytesIO()
            img.save(buf, format="PNG")
            zf.writestr(f"s{k}.png", buf.getvalue())
            rows.append(f"s{k}.png,{10 * k},0,{5 * k},90")
        zf.writestr("angles.csv", "\n".join(rows) + "\n")
    return path


def test01_pixel_cap_names_the_member_and_the_sizes(tmp_path: Path) -> None:
    z = slice_zip(tmp_path / "three.btf.zip", 3, (256, 128))
    assert archive_pixels(z, "three.btf.zip") == 3 * 256 * 128
    with pytest.raises(TooLargeError) as err:
        archive_pixels(z, "three.btf.zip", max_pixels=50_000)
    msg = str(err.value)
    assert msg.startswith("three.btf.zip: s1.png:"), msg  # 2 x 32768 crosses 50000
    assert "98304 pixels" in msg and "50000 pixels" in msg and "256x128" in msg, msg
    # The upload validator applies the cap it is given, and the format's default otherwise.
    with pytest.raises(TooLargeError, match="s1.png"):
        validate_file(z, "three.btf.zip", max_archive_pixels=50_000)
    assert validate_file(z, "three.btf.zip") == "application/zip"


def test02_attack_archive_is_refused_from_its_headers(tmp_path: Path) -> None:
    """Three 1-bit 8192 x 4096 PNGs: a few kilobytes that decode to 1.2 GB as float32.
    Refused under the default cap (64 Mpix) without decoding a pixel (nothing large is
    allocated: each image is made from a 4 MB 1-bit plane); it used to pass (201)."""
    z = tmp_path / "bomb.btf.zip"
    with zipfile.ZipFile(z, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        buf = io.BytesIO()
        Image.new("1", (8192, 4096)).save(buf, format="PNG")
        for k in range(3):
            zf.writestr(f"s{k}.png", buf.getvalue())
        zf.writestr("angles.csv", "file,theta_i,phi_i,theta_o,phi_o\n"
                    + "".join(f"s{k}.png,{10 * k},0,0,0\n" for k in range(3)))  # fmt: skip
    assert z.stat().st_size < 64 * 1024
    with pytest.raises(TooLargeError, match=r"bomb.btf.zip: s1.png: .* 100663296 pixels"):
        validate_file(z, "bomb.btf.zip")


@pytest.mark.parametrize("mode", ["1", "L", "RGB", "P", "I;16"])
def test03_png_table_decoding_matches_float64_arithmetic(tmp_path: Path, mode: str) -> None:
    """The values read_png has always returned (float64 level / top, rounded once to
    float32) and the sRGB decode of them, now through a table."""
    z = slice_zip(tmp_path / "m.btf.zip", 1, (17, 9), mode)
    with zipfile.ZipFile(z) as zf:
        (tmp_path / "s0.png").write_bytes(zf.read("s0.png"))
    with Image.open(tmp_path / "s0.png") as img:
        if mode == "I;16":
            grey = np.asarray(img, dtype=np.float64) / 65535.0
            ref = np.repeat(grey[..., None], 3, axis=-1).astype(np.float32)
        else:
            ref = (np.asarray(img.convert("RGB"), dtype=np.float64) / 255.0).astype(np.float32)
    got = read_png(tmp_path / "s0.png")
    assert got.dtype == np.float32 and np.array_equal(got, ref)
    with SliceFolder(z, "m.btf.zip") as folder:
        folder.check_images()
        lin = folder.read(folder.entries[0])
    assert np.array_equal(lin, srgb_to_linear(ref))


@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test04_streamed_shard_has_the_bytes_of_shard_bytes(dtype: str) -> None:
    rng = np.random.default_rng(1)
    n, h, w = 3, 5, 7
    rgb = rng.random((n, h, w, 3), dtype=np.float32)
    wi = np.tile([0.0, 0.0, 1.0], (n, 1))
    wo = np.tile([0.6, 0.0, 0.8], (n, 1))
    stderr = np.full(n, np.nan, np.float32)
    buf = io.BytesIO()
    write_shard(buf, wi, wo, iter(rgb), (h, w), stderr, dtype)
    assert buf.getvalue() == shard_bytes(wi, wo, rgb, stderr, dtype)
    with pytest.raises(ValueError, match="slice 2"):
        write_shard(io.BytesIO(), wi, wo, iter(rgb[:2].tolist() + [rgb[0, :4]]), (h, w), stderr)


def test05_a_member_inflating_past_any_image_is_refused_before_extraction(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A deflate bomb member is refused from the zip directory (the limit is lowered here
    so that the test writes kilobytes, not the 513 MiB of the real one)."""
    from storage.formats import btf_folder

    z = slice_zip(tmp_path / "z.btf.zip", 2, (64, 64), "RGB")
    monkeypatch.setattr(btf_folder, "MAX_MEMBER_BYTES", 1000)
    with pytest.raises(btf_folder.FormatError, match=r"z.btf.zip: s0.png: inflates to \d+ bytes"):
        archive_pixels(z, "z.btf.zip")
