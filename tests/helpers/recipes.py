"""Run a recipe of ``scripts/`` at tiny sizes for the recipe tests, as ``matforge batch``
would (the file loaded and validated first), every step in this process."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import pytest

from service.cli.batch import Step, load_batch
from service.cli.batch_local import run_steps_in_process
from service.settings import Settings
from storage.artifacts import ArtifactStore
from storage.jobs import Job

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


def run_recipe(
    tmp_path_factory: pytest.TempPathFactory,
    recipe: str,
    shrink: Callable[[dict[str, Any]], dict[str, Any]],
    keep: Callable[[Iterable[Step]], list[Step]] | None = None,
    variables: dict[str, str] | None = None,
    data_dir: Path | None = None,
    **settings: Any,
) -> tuple[Settings, dict[str, Job]]:
    """The steps of ``scripts/<recipe>`` (those ``keep`` returns, default all), each spec
    passed through ``shrink``, run in order in a fresh data folder (or ``data_dir``; one
    pool process, plus ``settings`` overrides), the batch's ``vars`` set from
    ``variables``; returns the settings and each step's job by name."""
    folder = data_dir or tmp_path_factory.mktemp(Path(recipe).stem) / "data"
    conf = Settings.from_env({}).with_(data_dir=folder, pool_processes=1, **settings)
    steps = load_batch(SCRIPTS / recipe, variables=variables).steps
    chosen = list(steps) if keep is None else keep(steps)
    return conf, run_steps_in_process(chosen, conf, transform=shrink)


def artifact(settings: Settings, job: Job, name: str) -> bytes:
    """The bytes of ``job``'s artifact ``name``."""
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return ArtifactStore(settings.store_dir).read(digest)


def shrink_btf(spec: dict[str, Any]) -> dict[str, Any]:
    """A BTF recipe's step shrunk for the tests: ``generate.btf`` at the ``small``
    directions, 8 x 8 texels, 2 spp; ``train.btf`` at one epoch (Lafortune: 16 slices, 5
    iterations). Other steps unchanged."""
    params = dict(spec["params"])
    if spec["kind"] == "generate.btf":
        params.update(directions={"preset": "small"}, resolution=8, spp=2, shard_slices=12)
    if spec["kind"] == "train.btf":
        if params["model"] == "lafortune":
            params.update(lafortune_slices=16, lafortune_iterations=5)
        else:
            params.update(epochs=1, check_steps=16)
    return {**spec, "params": params}
