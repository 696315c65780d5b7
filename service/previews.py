"""PNG previews of EXR objects for the dashboard, with the web process's memory bounded.

A small EXR file can hold a large image (418 KB for 8192x4096 pixels: ~700 MB to decode).
So (issue 21, item 3):

- the full image is decoded only in an upload checker child (:mod:`service.upload_check`,
  memory-capped), by :func:`decode_preview`, which refuses images over
  ``MATFORGE_PREVIEW_MAX_PIXELS`` from the header alone and sends back the thumbnail only:
  linear float32, at most :data:`PREVIEW_MAX_SIDE` pixels on its long side (strided, no
  filtering);
- the web process keeps that thumbnail (one decode per object, shared by concurrent
  requests), and each exposure is a tone mapping of the thumbnail, done in bands of rows
  so its float64 temporaries stay small;
- both caches are bounded in bytes.

The look is the one previews always had: :func:`evaluators.metrics.tonemap.tonemap` (ACES,
sRGB) of the strided thumbnail; tone mapping is per pixel, so banding changes no byte.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Generic, TypeVar

import numpy as np

from service.upload_check import CheckFailed, UploadChecker
from storage.errors import FormatError, TooLargeError

#: Longest side of a preview, pixels.
PREVIEW_MAX_SIDE = 1024
#: Rows tone-mapped at once (bounds the float64 temporaries: 64 x 1024 x 3 x 8 B = 1.5 MB).
BAND_ROWS = 64
EXR_MAGIC = b"\x76\x2f\x31\x01"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
#: What :meth:`PreviewMaker.pixels` reads from an object: an EXR's linear RGB, a PNG's
#: sRGB-encoded values in [0, 1], or the value in [0, 1] a magma-coloured PNG (a FLIP map)
#: encodes (:func:`evaluators.metrics.tonemap.magma_values`).
PIXEL_MAPS = ("linear", "srgb", "magma")

K = TypeVar("K")
V = TypeVar("V")


class ByteLRU(Generic[K, V]):
    """A thread-safe LRU bounded by the total size of its values (``size(value)`` bytes);
    a value larger than the whole budget is not kept."""

    def __init__(self, max_bytes: int, size: Callable[[V], int]) -> None:
        self.max_bytes = max_bytes
        self._size = size
        self._items: OrderedDict[K, V] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, key: K) -> V | None:
        with self._lock:
            value = self._items.get(key)
            if value is not None:
                self._items.move_to_end(key)
            return value

    def put(self, key: K, value: V) -> None:
        n = self._size(value)
        if n > self.max_bytes:
            return
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self._bytes -= self._size(old)
            self._items[key] = value
            self._bytes += n
            while self._bytes > self.max_bytes:
                _, dropped = self._items.popitem(last=False)
                self._bytes -= self._size(dropped)

    @property
    def nbytes(self) -> int:
        with self._lock:
            return self._bytes


def decode_preview(path: Path, name: str, max_side: int, max_pixels: int) -> np.ndarray:
    """Runs in a checker child: the EXR at ``path``, strided to at most ``max_side`` pixels
    on its long side, ``(h, w, 3)`` float32 linear RGB. ``FormatError`` naming ``name`` when
    it is not a readable RGB EXR, or has more than ``max_pixels`` pixels (read from the
    header, before any pixel is decoded)."""
    from storage.formats.exr import exr_header_info, read_exr

    info = exr_header_info(path, name)
    if info.width * info.height > max_pixels:
        raise FormatError(
            name,
            f"image of {info.width}x{info.height} pixels is too large to preview (the limit "
            f"is {max_pixels} pixels, MATFORGE_PREVIEW_MAX_PIXELS); download it instead",
        )
    rgb = read_exr(path, name)  # (H, W, 3) float32, linear
    return stride(rgb, max_side)


def decode_png_pixels(path: Path, name: str, max_side: int) -> np.ndarray:
    """Runs in a checker child: the PNG at ``path`` as ``(h, w, 3)`` float32 sRGB-encoded
    values in ``[0, 1]``, strided as :func:`decode_preview` strides EXRs (``FormatError``
    naming ``name`` when it is not a readable PNG)."""
    from storage.formats.png import read_png

    return stride(read_png(path, name), max_side)


def stride(rgb: np.ndarray, max_side: int) -> np.ndarray:
    """Every ``k``-th pixel of ``rgb`` in both directions, the smallest ``k`` that leaves at
    most ``max_side`` pixels on the long side (no filtering: values stay pixel values)."""
    step = max(1, -(-max(rgb.shape[:2]) // max_side))
    return np.ascontiguousarray(rgb[::step, ::step])


def tonemap_png(linear: np.ndarray, exposure: float) -> bytes:
    """The preview PNG of a linear ``(h, w, 3)`` thumbnail, ``exposure`` stops brighter,
    tone-mapped :data:`BAND_ROWS` rows at a time (the same bytes as all at once)."""
    from evaluators.metrics.tonemap import tonemap
    from storage.formats.png import write_png

    out = np.empty(linear.shape, np.uint8)
    for r in range(0, linear.shape[0], BAND_ROWS):
        out[r : r + BAND_ROWS] = tonemap(linear[r : r + BAND_ROWS], exposure=exposure)
    return write_png(None, out)  # sRGB, ACES


class PreviewMaker:
    """Previews of EXR objects by digest and exposure (see the module docstring).

    ``checker`` decodes; ``max_pixels`` is the largest image it may decode for a preview;
    ``cache_bytes`` bounds the thumbnails and the PNGs kept (half each). Thread-safe.
    """

    def __init__(
        self,
        checker: UploadChecker,
        *,
        max_pixels: int = 1 << 24,
        max_side: int = PREVIEW_MAX_SIDE,
        cache_bytes: int = 64 * 1024 * 1024,
    ) -> None:
        self.checker = checker
        self.max_pixels = max_pixels
        self.max_side = max_side
        self._linear: ByteLRU[str, np.ndarray] = ByteLRU(cache_bytes // 2, lambda a: a.nbytes)
        self._png: ByteLRU[str, bytes] = ByteLRU(cache_bytes // 2, len)
        self._failed: ByteLRU[str, FormatError] = ByteLRU(256, lambda e: 1)
        self._decoding: dict[str, threading.Lock] = {}
        self._lock = threading.Lock()
        #: Images decoded so far (one per object while it stays cached).
        self.decodes = 0

    def pixels(
        self, digest: str, values: str, source: Callable[[], tuple[Path, str]]
    ) -> np.ndarray:
        """The ``(h, w, 3)`` float32 pixel values of object ``digest`` that the compare
        view reads under the cursor and subtracts for its difference image, on the grid of
        its preview (an EXR's thumbnail is the one :meth:`png` tone-maps). ``values`` is one
        of :data:`PIXEL_MAPS`: ``"linear"`` for an EXR, ``"srgb"`` or ``"magma"`` for a PNG
        (``magma`` gives the mapped value in all three channels). ``FormatError`` when the
        object is not of that form."""
        if values not in PIXEL_MAPS:
            raise ValueError(f"values must be one of {PIXEL_MAPS}, got {values!r}")
        if values == "linear":
            return self._thumbnail(digest, source)
        return self._thumbnail(digest, source, values)

    def _thumbnail(
        self, digest: str, source: Callable[[], tuple[Path, str]], png: str = ""
    ) -> np.ndarray:
        return self._cached(f"{png}:{digest}" if png else digest, source, png)

    def png(self, digest: str, exposure: float, source: Callable[[], tuple[Path, str]]) -> bytes:
        """The PNG preview of object ``digest`` at ``exposure`` stops. ``source()`` gives the
        object's verified path and the name to show in errors; it is called only when the
        thumbnail is not cached. ``FormatError`` (422) when it cannot be previewed."""
        key = f"{digest}@{exposure:g}"
        png = self._png.get(key)
        if png is None:
            png = tonemap_png(self._thumbnail(digest, source), exposure)
            self._png.put(key, png)
        return png

    def _cached(self, digest: str, source: Callable[[], tuple[Path, str]], png: str) -> np.ndarray:
        linear = self._linear.get(digest)
        if linear is not None:
            return linear
        with self._lock:  # one decode per object: concurrent requests wait for it
            gate = self._decoding.setdefault(digest, threading.Lock())
        with gate:
            failed = self._failed.get(digest)
            if failed is not None:  # objects never change: neither does their refusal
                raise FormatError(failed.filename, failed.problem)
            linear = self._linear.get(digest)
            if linear is None:
                try:
                    linear = self._decode(*source(), png)
                    self._linear.put(digest, linear)
                except CheckFailed:  # a crash or a time-out may not happen again
                    raise
                except FormatError as exc:
                    self._failed.put(digest, exc)
                    raise
                finally:  # after the put: a later request finds the thumbnail
                    with self._lock:
                        self._decoding.pop(digest, None)
        return linear

    def _decode(self, path: Path, name: str, png: str = "") -> np.ndarray:
        with open(path, "rb") as fh:
            head = fh.read(8)
        if png and not head.startswith(PNG_MAGIC):
            raise FormatError(name, "not a PNG file; its pixel values are read as an image's")
        if not png and not head.startswith(EXR_MAGIC):
            raise FormatError(name, "not an OpenEXR file; previews exist for .exr artifacts only")
        try:
            if png:
                linear = self.checker.run(decode_png_pixels, path, name, self.max_side, label=name)
            else:
                linear = self.checker.run(
                    decode_preview, path, name, self.max_side, self.max_pixels, label=name
                )
        except TooLargeError:
            raise FormatError(
                name, "decoding it needs more memory than previews may use; download it instead"
            ) from None
        with self._lock:
            self.decodes += 1
        if png == "magma":
            from evaluators.metrics.tonemap import magma_values

            linear = np.repeat(magma_values(linear)[..., None], 3, axis=2)
        return linear
