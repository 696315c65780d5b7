"""Small ``generate.fabric`` and ``train.fabric`` params shared by the fabric tests."""

DATASET = {"preset": "small", "queries_per_material": 640, "shard_queries": 320,
           "samples": 64, "map_resolution": 32}  # fmt: skip
TINY = {"encoder_width": 16, "map_resolution": 32, "decoder_width": 32, "steps": 600,
        "holdout": 0.15}  # fmt: skip
