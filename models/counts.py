"""Costs that do not depend on the machine: multiply-adds and bytes read per evaluation.

Beside its time (``ns_per_eval``, which depends on the machine, its load and the runtime),
every model states two counts, the same rule for a built-in model, a user's JSON MLP and an
ONNX graph, so that a chart can put either on its cost axis:

``macs_per_eval``
    Multiply-adds of the model's dense layers (matrix products) per evaluation, as the
    renderer's kernel runs them: a layer of ``n_in`` inputs and ``n_out`` outputs costs
    ``n_in * n_out``, so a ``W x D`` MLP (``D`` hidden layers of width ``W``) with ``I``
    inputs and ``O`` outputs costs ``I W + (D - 1) W^2 + W O`` (:func:`mlp_macs`). Inputs
    that are per-material constants (a latent code) are folded into the first layer's bias
    and cost nothing per evaluation. Encodings, activations, texture filtering and an
    analytic part are elementwise work, not counted here; a model without a network
    (an analytic BRDF, a table) has 0.
``bytes_per_eval``
    Bytes one evaluation reads, float32 counted as 4: every weight and bias (each is read
    once per evaluation, whether from memory or as a literal in the kernel's code), the
    analytic part's parameters, and of a texture or a table only what one lookup reads
    (a bilinear lookup of a ``C``-channel texture: ``4 C`` values).

:func:`models.external.onnx_mlp.graph_counts` counts an ONNX graph by the same rule from its
nodes and the shapes ONNX shape inference gives them.
"""

from __future__ import annotations

from collections.abc import Iterable

#: Bytes per float32 value.
FLOAT_BYTES = 4
#: Texels read by a bilinear lookup.
BILINEAR_TAPS = 4
#: Floats of the analytic Lambert + GGX part: ``kd`` (3), ``eta`` (3), ``alpha``.
ANALYTIC_FLOATS = 7


#: A MERL table as the ``merl_table`` BSDF reads it: eight RGB bins of float32 per lookup
#: (the interpolation of :mod:`evaluators.render.bsdfs.merl_table`), no network.
MERL_TABLE_BYTES_PER_EVAL = 8 * 3 * FLOAT_BYTES


def mlp_macs(n_in: int, width: int, depth: int, n_out: int) -> int:
    """Multiply-adds of a ``width x depth`` MLP: ``I W + (D - 1) W^2 + W O`` (0 when
    ``depth`` is 0: no network)."""
    if depth <= 0 or width <= 0:
        return 0
    return n_in * width + (depth - 1) * width * width + width * n_out


def mlp_params(n_in: int, width: int, depth: int, n_out: int) -> int:
    """Weights and biases of that MLP: its multiply-adds plus ``D W + O`` biases."""
    if depth <= 0 or width <= 0:
        return 0
    return mlp_macs(n_in, width, depth, n_out) + depth * width + n_out


def dense_counts(shapes: Iterable[tuple[int, int]]) -> tuple[int, int]:
    """``(macs, bytes)`` of dense layers of ``(n_in, n_out)`` shapes: ``sum(in * out)``
    multiply-adds, and 4 bytes per weight and bias."""
    macs = params = 0
    for n_in, n_out in shapes:
        macs += n_in * n_out
        params += n_in * n_out + n_out
    return macs, FLOAT_BYTES * params


def counts(macs: int, bytes_read: int) -> dict[str, int]:
    """The two fields as a cost record carries them."""
    return {"macs_per_eval": int(macs), "bytes_per_eval": int(bytes_read)}


def merl_table_counts() -> dict[str, int]:
    """The counts of a MERL table (:data:`MERL_TABLE_BYTES_PER_EVAL`, 0 multiply-adds)."""
    return counts(0, MERL_TABLE_BYTES_PER_EVAL)


__all__ = ["counts", "merl_table_counts", "dense_counts", "mlp_macs", "mlp_params"]
