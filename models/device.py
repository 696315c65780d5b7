"""The torch device of a training kind: its ``device`` param (:data:`jobapi.params.Device`)
resolved at job start, and recorded for the manifest."""

from __future__ import annotations

import torch

from jobapi.context import JobContext
from jobapi.errors import JobFailed


def pick_device(choice: str, ctx: JobContext | None = None, field: str = "device") -> str:
    """``"cpu"`` or ``"cuda"`` for the param ``choice``: ``auto`` takes cuda when torch sees
    a CUDA device, else cpu. ``cuda`` on a machine where torch sees none fails the job,
    naming ``params.<field>`` and the worker's torch build (the ``+cpu`` wheel never sees
    one: ``make setup TORCH=cuda``). With ``ctx``, the device goes into the manifest."""
    available = torch.cuda.is_available()
    if choice == "auto":
        device = "cuda" if available else "cpu"
    elif choice == "cuda" and not available:
        raise JobFailed(
            f"params.{field}: 'cuda' was asked for but torch {torch.__version__} sees no CUDA "
            "device on this worker; use 'auto' or 'cpu', or a worker with a GPU and a CUDA "
            "build of torch (make setup TORCH=cuda)"
        )
    elif choice in ("cpu", "cuda"):
        device = choice
    else:
        raise JobFailed(f"params.{field}: unknown device {choice!r}; use auto, cpu or cuda")
    if ctx is not None:
        ctx.use_device(device)
    return device
