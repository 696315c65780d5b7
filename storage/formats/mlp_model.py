"""The user MLP material formats ``matforge.mlp-brdf/1`` and ``matforge.mlp-btf/1``: parsing
and validation.

One JSON document names the whole model (one upload, one ``sha256``): the network's layers
as nested float lists, a BTF's latent textures as base64 float32 inside the document. The
format is documented in ``docs/formats.md`` and described by the JSON schemas in
``storage/formats/schemas/``; this module is the enforcement (shapes that chain, widths
that match the encodings, limits), shared by ``POST /api/artifacts`` (through
:func:`storage.formats.validate_json`), ``matforge import`` and the renderer
(:mod:`models.external.mlp`). The evaluation it describes is implemented by
:mod:`models.external.mlp` (numpy reference) and :mod:`models.external.fused` (Dr.Jit).

Document::

    {
      "format": "matforge.mlp-brdf/1" | "matforge.mlp-btf/1",
      "name": "optional label",
      "inputs": ["wi", "wo", {"type": "fourier", "input": "h", "frequencies": [1, 2]}, ...],
      "layers": [{"weight": [[...] * in] * out, "bias": [...] * out,
                  "activation": "relu"}, ...],
      "output": {"activation": "exp" | [one name per network output],
                 "combine": "network" | "sum" | "hybrid" | "analytic"},
      "analytic": null | {"kd": [r, g, b], "alpha": a, "eta": [r, g, b]},      # BRDF only
      "textures": [{"shape": [C, H, W], "dtype": "float32", "data": "<base64>"}], # BTF only
      "foreshortening": "included" | "apply",                                    # BTF only
      "metadata": {anything}
    }
"""

from __future__ import annotations

import base64
import binascii
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from storage.errors import FormatError

BRDF_FORMAT = "matforge.mlp-brdf/1"
BTF_FORMAT = "matforge.mlp-btf/1"
#: ``format`` -> ``kind``.
FORMATS = {BRDF_FORMAT: "brdf", BTF_FORMAT: "btf"}

#: Activation names (the same list as :data:`models.fused_mlp.ACTIVATIONS`; a test keeps
#: the two equal: storage imports nothing of ours).
ACTIVATIONS = ("identity", "relu", "leaky_relu", "sigmoid", "exp", "softplus", "tanh")
#: Direction encodings and their widths (see ``docs/formats.md``).
DIRECTION_INPUTS = {
    "wi": 3, "wo": 3, "wi.xy": 2, "wo.xy": 2, "h": 3, "d": 3,
    "cos_i": 1, "cos_o": 1, "cos_h": 1, "cos_d": 1,
}  # fmt: skip
#: Inputs only a BTF has: the patch coordinates.
BTF_INPUTS = {"uv": 2}
COMBINES = ("network", "sum", "hybrid", "analytic")
#: Network outputs per ``combine``.
COMBINE_OUTPUTS = {"network": 3, "sum": 3, "hybrid": 6, "analytic": 0}

#: Limits. The fused kernel unrolls every weight as a literal, so the network is small.
MAX_LAYERS = 32
MAX_WIDTH = 512
MAX_NETWORK_PARAMS = 1 << 16
MAX_FREQUENCIES = 32
MAX_TEXTURES = 8
MAX_TEXTURE_CHANNELS = 64
MAX_TEXTURE_SIDE = 8192
MAX_TEXTURE_VALUES = 1 << 24


@dataclass(frozen=True)
class Encoding:
    """One entry of ``inputs``: ``type`` (a :data:`DIRECTION_INPUTS` or :data:`BTF_INPUTS`
    name, ``"texture"`` or ``"fourier"``), ``input`` and ``frequencies`` (``fourier``),
    ``index`` (``texture``), and ``width``, the features it gives."""

    type: str
    width: int
    input: str | None = None
    frequencies: tuple[float, ...] = ()
    index: int | None = None


@dataclass(frozen=True)
class Layer:
    """One dense layer ``act(W x + b)``: ``weight`` ``(out, in)``, ``bias`` ``(out,)``,
    float32."""

    weight: np.ndarray
    bias: np.ndarray
    activation: str


@dataclass(frozen=True)
class Analytic:
    """The analytic part ``f_a`` (Lambert + GGX, as ``matforge.brdf-model/1``)."""

    kd: tuple[float, float, float]
    alpha: float
    eta: tuple[float, float, float]


@dataclass(frozen=True)
class MlpDocument:
    """A parsed, checked MLP material document (arrays float32)."""

    kind: str
    name: str
    inputs: tuple[Encoding, ...]
    layers: tuple[Layer, ...]
    output_activations: tuple[str, ...]
    combine: str
    analytic: Analytic | None
    textures: tuple[np.ndarray, ...] = field(default=())
    foreshortening: str = "included"

    @property
    def n_inputs(self) -> int:
        """Features the first layer takes."""
        return sum(e.width for e in self.inputs)

    @property
    def param_count(self) -> int:
        """All parameters: weights, biases, texture values and the analytic part's 7."""
        net = sum(ly.weight.size + ly.bias.size for ly in self.layers)
        tex = sum(t.size for t in self.textures)
        return int(net + tex + (7 if self.analytic is not None else 0))


def texture_entry(texture: np.ndarray) -> dict[str, Any]:
    """The document entry of a ``(C, H, W)`` texture: base64 of little-endian float32,
    C order."""
    arr = np.ascontiguousarray(texture, dtype="<f4")
    if arr.ndim != 3:
        raise ValueError(f"a texture has shape (C, H, W), got {arr.shape}")
    return {
        "shape": list(arr.shape),
        "dtype": "float32",
        "data": base64.b64encode(arr.tobytes()).decode("ascii"),
    }


class _Fail(Exception):
    pass


def _need(cond: bool, message: str) -> None:
    if not cond:
        raise _Fail(message)


def _finite_numbers(value: Any, where: str, ndim: int) -> np.ndarray:
    if ndim == 2:
        _need(
            isinstance(value, list) and all(isinstance(r, list) for r in value) and bool(value),
            f"{where}: must be a non-empty list of lists of numbers",
        )
        _need(len({len(r) for r in value}) == 1, f"{where}: rows have different lengths")
    else:
        _need(
            isinstance(value, list) and bool(value), f"{where}: must be a non-empty list of numbers"
        )
    flat = value if ndim == 1 else [x for r in value for x in r]
    _need(
        all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in flat),
        f"{where}: must hold numbers only",
    )
    arr = np.asarray(value, dtype=np.float64)
    _need(bool(np.all(np.isfinite(arr))), f"{where}: must be finite")
    _need(bool(np.all(np.abs(arr) < 3.4e38)), f"{where}: values exceed float32's range")
    return arr.astype(np.float32)


def _encoding(entry: Any, k: int, kind: str, n_textures: int) -> Encoding:
    where = f"inputs[{k}]"
    simple = dict(DIRECTION_INPUTS)
    if kind == "btf":
        simple.update(BTF_INPUTS)
    if isinstance(entry, str):
        entry = {"type": entry}
    _need(isinstance(entry, dict), f"{where}: must be a name or an object with 'type'")
    t = entry.get("type")
    known = ", ".join([*simple, "fourier", *(["texture"] if kind == "btf" else [])])
    if t in simple:
        _need(set(entry) == {"type"}, f"{where}: {t!r} takes no other keys")
        return Encoding(type=t, width=simple[t])
    if t == "texture" and kind == "btf":
        _need(set(entry) <= {"type", "index"}, f"{where}: a texture input has 'index' only")
        index = entry.get("index", 0)
        _need(
            isinstance(index, int) and not isinstance(index, bool) and 0 <= index < n_textures,
            f"{where}: index must name one of the {n_textures} textures",
        )
        return Encoding(type="texture", width=-1, index=index)  # width set by the caller
    if t == "fourier":
        _need(
            set(entry) == {"type", "input", "frequencies"},
            f"{where}: a fourier input has exactly 'input' and 'frequencies'",
        )
        src = entry["input"]
        _need(src in simple, f"{where}.input: must be one of {', '.join(simple)}")
        freqs = entry["frequencies"]
        _need(
            isinstance(freqs, list) and 0 < len(freqs) <= MAX_FREQUENCIES,
            f"{where}.frequencies: must be a list of 1 to {MAX_FREQUENCIES} numbers",
        )
        f = _finite_numbers(freqs, f"{where}.frequencies", 1)
        _need(bool(np.all(np.abs(f) <= 1e4)), f"{where}.frequencies: |f| must be <= 1e4")
        return Encoding(
            type="fourier",
            width=2 * len(freqs) * simple[src],
            input=src,
            frequencies=tuple(float(x) for x in freqs),
        )
    raise _Fail(f"{where}: unknown input {t!r}; known: {known}")


def _texture(entry: Any, k: int) -> np.ndarray:
    where = f"textures[{k}]"
    _need(isinstance(entry, dict), f"{where}: must be an object with shape, dtype, data")
    _need(set(entry) == {"shape", "dtype", "data"}, f"{where}: keys are shape, dtype, data")
    _need(entry["dtype"] == "float32", f"{where}.dtype: must be 'float32'")
    shape = entry["shape"]
    _need(
        isinstance(shape, list)
        and len(shape) == 3
        and all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in shape),
        f"{where}.shape: must be [C, H, W] of positive integers",
    )
    c, h, w = shape
    _need(c <= MAX_TEXTURE_CHANNELS, f"{where}: at most {MAX_TEXTURE_CHANNELS} channels")
    _need(max(h, w) <= MAX_TEXTURE_SIDE, f"{where}: at most {MAX_TEXTURE_SIDE} texels a side")
    _need(c * h * w <= MAX_TEXTURE_VALUES, f"{where}: more than {MAX_TEXTURE_VALUES} values")
    data = entry["data"]
    _need(isinstance(data, str), f"{where}.data: must be a base64 string")
    _need(len(data) == 4 * math.ceil(4 * c * h * w / 3), f"{where}.data: wrong length for {shape}")
    try:
        raw = base64.b64decode(data, validate=True)
    except (binascii.Error, ValueError):
        raise _Fail(f"{where}.data: not valid base64") from None
    _need(len(raw) == 4 * c * h * w, f"{where}.data: {len(raw)} bytes, expected {4 * c * h * w}")
    arr = np.frombuffer(raw, dtype="<f4").reshape(c, h, w).astype(np.float32)
    _need(bool(np.all(np.isfinite(arr))), f"{where}.data: must be finite")
    return arr


def _analytic(value: Any) -> Analytic:
    _need(isinstance(value, dict), "analytic: must be an object {kd, alpha, eta} or null")
    _need(set(value) == {"kd", "alpha", "eta"}, "analytic: keys are exactly kd, alpha, eta")
    kd = _finite_numbers(value["kd"], "analytic.kd", 1)
    eta = _finite_numbers(value["eta"], "analytic.eta", 1)
    _need(kd.shape == (3,) and bool(np.all(kd >= 0)), "analytic.kd: must be 3 numbers >= 0")
    _need(eta.shape == (3,) and bool(np.all(eta >= 1)), "analytic.eta: must be 3 numbers >= 1")
    a = value["alpha"]
    _need(
        isinstance(a, (int, float)) and not isinstance(a, bool) and 1e-4 <= a <= 1.0,
        "analytic.alpha: must be a number in [1e-4, 1]",
    )
    return Analytic(
        kd=tuple(float(x) for x in value["kd"]),  # type: ignore[arg-type]
        alpha=float(a),
        eta=tuple(float(x) for x in value["eta"]),  # type: ignore[arg-type]
    )


def _layers(value: Any) -> tuple[Layer, ...]:
    _need(isinstance(value, list), "layers: must be a list")
    _need(len(value) <= MAX_LAYERS, f"layers: at most {MAX_LAYERS}")
    out: list[Layer] = []
    total = 0
    for k, ly in enumerate(value):
        where = f"layers[{k}]"
        _need(isinstance(ly, dict), f"{where}: must be an object {{weight, bias, activation}}")
        _need(
            set(ly) == {"weight", "bias", "activation"},
            f"{where}: keys are weight, bias, activation",
        )
        _need(
            ly["activation"] in ACTIVATIONS, f"{where}.activation: one of {', '.join(ACTIVATIONS)}"
        )
        # Cheap size checks before any array is built.
        rows = ly["weight"]
        _need(isinstance(rows, list) and 0 < len(rows) <= MAX_WIDTH,
              f"{where}.weight: 1 to {MAX_WIDTH} rows")  # fmt: skip
        cols = len(rows[0]) if isinstance(rows[0], list) else 0
        _need(0 < cols <= MAX_WIDTH * 4, f"{where}.weight: rows of 1 to {MAX_WIDTH * 4} numbers")
        total += len(rows) * (cols + 1)
        _need(total <= MAX_NETWORK_PARAMS, f"layers: more than {MAX_NETWORK_PARAMS} parameters")
        w = _finite_numbers(rows, f"{where}.weight", 2)
        b = _finite_numbers(ly["bias"], f"{where}.bias", 1)
        _need(b.shape == (w.shape[0],), f"{where}.bias: {b.size} values for {w.shape[0]} rows")
        if out:
            _need(
                w.shape[1] == out[-1].weight.shape[0],
                f"{where}.weight: takes {w.shape[1]} inputs but layers[{k - 1}] gives "
                f"{out[-1].weight.shape[0]}",
            )
        out.append(Layer(w, b, ly["activation"]))
    return tuple(out)


_KEYS = {
    "brdf": {"format", "name", "inputs", "layers", "output", "analytic", "metadata"},
    "btf": {"format", "name", "inputs", "layers", "output", "textures", "foreshortening",
            "metadata"},
}  # fmt: skip


def _parse(doc: Any) -> MlpDocument:
    _need(isinstance(doc, dict), "must be a JSON object")
    kind = FORMATS.get(str(doc.get("format")))
    _need(kind is not None, f"format must be one of {', '.join(FORMATS)}")
    assert kind is not None
    extra = sorted(set(doc) - _KEYS[kind])
    _need(not extra, f"unknown key {extra[0] if extra else ''!r} for {doc['format']}")
    for key in ("inputs", "layers", "output"):
        _need(key in doc, f"{key}: this key is required")
    name = doc.get("name", "")
    _need(isinstance(name, str) and len(name) <= 200, "name: must be a string of <= 200 chars")
    textures: tuple[np.ndarray, ...] = ()
    if kind == "btf":
        tex = doc.get("textures", [])
        _need(isinstance(tex, list) and len(tex) <= MAX_TEXTURES,
              f"textures: a list of at most {MAX_TEXTURES}")  # fmt: skip
        textures = tuple(_texture(t, k) for k, t in enumerate(tex))
        _need(
            sum(t.size for t in textures) <= MAX_TEXTURE_VALUES,
            f"textures: more than {MAX_TEXTURE_VALUES} values in all",
        )
    raw_inputs = doc["inputs"]
    _need(isinstance(raw_inputs, list) and len(raw_inputs) <= 64, "inputs: a list of <= 64 entries")
    inputs = []
    for k, e in enumerate(raw_inputs):
        enc = _encoding(e, k, kind, len(textures))
        if enc.type == "texture":
            assert enc.index is not None
            enc = Encoding(type="texture", width=int(textures[enc.index].shape[0]), index=enc.index)
        inputs.append(enc)
    layers = _layers(doc["layers"])
    out = doc["output"]
    _need(isinstance(out, dict) and set(out) <= {"activation", "combine"},
          "output: an object with 'activation' and 'combine'")  # fmt: skip
    combine = out.get("combine", "network")
    _need(combine in COMBINES, f"output.combine: one of {', '.join(COMBINES)}")
    analytic = None
    if kind == "brdf" and doc.get("analytic") is not None:
        analytic = _analytic(doc["analytic"])
    if kind == "btf":
        _need(combine == "network", "output.combine: a BTF's value is its network's ('network')")
        fs = doc.get("foreshortening", "included")
        _need(fs in ("included", "apply"), "foreshortening: 'included' or 'apply'")
    else:
        fs = "included"
    _need(
        (analytic is not None) == (combine != "network"),
        f"analytic: combine {combine!r} "
        + ("needs an analytic part" if combine != "network" else "takes no analytic part"),
    )
    n_out = COMBINE_OUTPUTS[combine]
    if combine == "analytic":
        _need(not layers, "layers: combine 'analytic' has no network (layers: [])")
        _need(out.get("activation") in (None, "identity"), "output.activation: no network")
        acts: tuple[str, ...] = ()
    else:
        _need(bool(layers), "layers: the network needs at least one layer")
        n_in = sum(e.width for e in inputs)
        _need(
            layers[0].weight.shape[1] == n_in,
            f"layers[0].weight: takes {layers[0].weight.shape[1]} inputs but the inputs give "
            f"{n_in}",
        )
        _need(
            layers[-1].weight.shape[0] == n_out,
            f"layers[{len(layers) - 1}]: gives {layers[-1].weight.shape[0]} outputs; combine "
            f"{combine!r} takes {n_out}",
        )
        act = out.get("activation", "identity")
        acts = tuple([act] * n_out) if isinstance(act, str) else tuple(act)
        _need(
            isinstance(act, (str, list))
            and len(acts) == n_out
            and all(a in ACTIVATIONS for a in acts),
            f"output.activation: a name or {n_out} names of {', '.join(ACTIVATIONS)}",
        )
    return MlpDocument(
        kind=kind, name=name, inputs=tuple(inputs), layers=layers, output_activations=acts,
        combine=combine, analytic=analytic, textures=textures, foreshortening=fs,
    )  # fmt: skip


def parse_mlp_document(doc: Any, name: str) -> MlpDocument:
    """The checked :class:`MlpDocument` of a parsed JSON document; :class:`FormatError`
    naming ``name`` (the file) and the problem otherwise."""
    try:
        return _parse(doc)
    except _Fail as exc:
        raise FormatError(name, f"not a valid MLP model: {exc}") from None
    except (KeyError, TypeError, IndexError, ValueError) as exc:
        raise FormatError(name, f"not a valid MLP model ({type(exc).__name__}: {exc})") from None


def is_mlp_document(doc: Any) -> bool:
    """Whether a parsed JSON document claims one of the MLP formats."""
    return isinstance(doc, dict) and doc.get("format") in FORMATS
