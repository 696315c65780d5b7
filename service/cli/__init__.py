"""``matforge``, the command-line client.

Submodules: :mod:`~service.cli.main` (the Typer app and the contract's commands),
:mod:`~service.cli.state` (settings, consoles, exit codes), :mod:`~service.cli.client` (the
typed REST client), :mod:`~service.cli.follow` (progress bars), :mod:`~service.cli.artifacts`
(``artifacts``, ``fetch``, ``import``), :mod:`~service.cli.store` (``store verify|gc``),
:mod:`~service.cli.batch` (batch files) and :mod:`~service.cli.results` (their tables).
"""

from service.cli.main import app, main

__all__ = ["app", "main"]
