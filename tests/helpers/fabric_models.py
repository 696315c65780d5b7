"""``model.json`` and ``model.pt`` of a random, tiny fabric network, for tests of the plumbing
(not of the learning): trained on :data:`TRAINED` and :data:`OTHER`, outputs pushed positive.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from materials.fabric.params import FabricParams, params_json
from models.fabric.networks import Architecture, build_network
from models.fabric.portable import checkpoint_bytes, to_portable


def record_of(params: FabricParams) -> dict:
    """A material's ``materials.json`` params record (the plugins' JSON form is the same)."""
    return json.loads(params_json(params))


TINY = Architecture(encoder_width=16, map_resolution=16, decoder_width=16)
TRAINED = FabricParams("twill_3x3", psi_deg=20.0, alpha=(0.3, 0.5), beta=0.8, w=0.7)
OTHER = FabricParams("plain", alpha=0.6, beta=0.4)


def write_model(root: Path) -> tuple[Path, Path, np.ndarray]:
    """``model.json`` and ``model.pt`` of a random network trained on TRAINED and OTHER."""
    net = build_network(TINY, 11).eval()
    with torch.no_grad():
        net.decoder.angular5.bias.copy_(torch.tensor([0.2, 0.1, 1.0, 0.5]))
    latents = np.random.default_rng(4).normal(size=(2, TINY.latent_dim)).astype(np.float32)
    records = [record_of(TRAINED), record_of(OTHER)]
    names, patterns = ["twill-a", "plain-b"], ["twill_3x3", "plain"]
    doc = to_portable(net, names, patterns, records, latents)
    js, pt = root / "model.json", root / "model.pt"
    js.write_text(json.dumps(doc))
    pt.write_bytes(checkpoint_bytes(net, names, records, latents))
    return js, pt, latents
