"""BTF models (Xu et al., "Real-Time Neural Materials on Mobile VR"): networks, training, the
Lafortune baseline.

Submodules:

- :mod:`~models.btf.networks`: neural textures, the modified NeuMIP (25 wide; 128 wide as
  the teacher "NeuMIP Max") and the coarse-to-fine student (Sec. 4.1, Eq. 3-4);
- :mod:`~models.btf.data`: a BTF dataset (``generate.btf`` / ``import.btf`` job) as slices;
- :mod:`~models.btf.train`: Adam + ReduceLROnPlateau, one slice per step, distillation
  (Sec. 4.3-4.4, Eq. 5);
- :mod:`~models.btf.lafortune`: the 4-lobe Lafortune baseline fitted per texel by
  Levenberg-Marquardt (Sec. 5.3, Eq. 6-7);
- :mod:`~models.btf.portable`: ``model.json`` + ``textures.npz``;
- :mod:`~models.btf.fused`: the fused Dr.Jit inference (coarse MLP once per 2 x 2 block);
- :mod:`~models.btf.kind`, :mod:`~models.btf.runner`: the ``train.btf`` job kind.
"""

SUBMODULES: tuple[str, ...] = (
    "networks", "data", "train", "lafortune", "portable", "fused", "kind", "runner",
)  # fmt: skip
