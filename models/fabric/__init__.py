"""The neural woven-fabric model of Chen, Wang & Wang 2024: the ``train.fabric`` job kind.

Submodules (imported explicitly by their users, not here, so that registering the kind does
not import torch):

- :mod:`models.fabric.encoding`: footprint normalisation and one-blob encoding (numpy,
  torch and Dr.Jit share it);
- :mod:`models.fabric.networks`: the ResNet-18 trunk, encoder, decoder, output mapping;
- :mod:`models.fabric.losses`: Eq. 9-11;
- :mod:`models.fabric.data`: a ``generate.fabric`` job's shards, maps and held-out split;
- :mod:`models.fabric.train`: SGD of Sec. 5.2, divergence guard;
- :mod:`models.fabric.portable`: ``model.json`` and ``model.pt``;
- :mod:`models.fabric.report`: ``metrics.json`` and ``curves.png``;
- :mod:`models.fabric.fused`: loading for rendering, the encoder per material, the decoder
  as one fused Dr.Jit kernel and its numpy reference;
- :mod:`models.fabric.kind`: params and registration; :mod:`models.fabric.runner`: the body.
"""

SUBMODULES: tuple[str, ...] = (
    "encoding",
    "networks",
    "losses",
    "data",
    "train",
    "portable",
    "report",
    "fused",
    "kind",
    "runner",
)
