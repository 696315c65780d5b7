"""Write ``docs/reference/cli.md``, the reference of the ``matforge`` command, from its
Typer/Click definitions (each command's help, arguments and options).

Run: ``.venv/bin/python scripts/cli_reference.py --write`` (without ``--write`` it prints
the page); ``tests/unit/service/test_docs_site.py`` fails when the page is stale.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import typer

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from service.cli.main import app

PAGE = Path(__file__).resolve().parent.parent / "docs" / "reference" / "cli.md"


def _param_row(p: Any) -> str:
    help_: str = getattr(p, "help", None) or ""
    if p.param_type_name == "argument":
        name = f"`{(p.metavar or p.name or '').upper()}`"
        kind = "argument" + ("" if p.required else " (optional)")
    else:
        name = ", ".join(f"`{o}`" for o in [*p.opts, *p.secondary_opts])
        flag = bool(getattr(p, "is_flag", False))
        kind = "flag" if flag else "option"
        if p.default not in (None, False, (), "") and not flag:
            help_ += f" Default: `{p.default}`."
    cell = " ".join(help_.split()).replace("|", "\\|")
    return f"| {name} | {kind} | {cell} |"


def _command(cmd: Any, path: str, out: list[str]) -> None:
    if hasattr(cmd, "commands"):
        for name in sorted(cmd.commands):
            sub = cmd.commands[name]
            if not sub.hidden:
                _command(sub, f"{path} {name}", out)
        return
    out.append(f"## `{path}`\n")
    text = (cmd.help or "").split("\f")[0].strip()
    if text:
        out.append(text + "\n")
    params = [p for p in cmd.params if not getattr(p, "hidden", False)]
    if params:
        out.append("| name | kind | description |")
        out.append("| --- | --- | --- |")
        out.extend(_param_row(p) for p in params)
        out.append("")


def cli_markdown() -> str:
    """The page: every command of ``matforge`` with its arguments and options."""
    root = typer.main.get_command(app)
    out = [
        "# CLI reference",
        "",
        "Generated from the command definitions by `scripts/cli_reference.py --write`; do not",
        "edit by hand. Every command also answers `--help`. Exit codes: 0 success, 1 a job",
        "failed, 2 bad input or usage, 3 server unreachable or refused.",
        "",
    ]
    _command(root, "matforge", out)
    return "\n".join(out).rstrip() + "\n"


if __name__ == "__main__":
    text = cli_markdown()
    if "--write" in sys.argv:
        PAGE.parent.mkdir(parents=True, exist_ok=True)
        PAGE.write_text(text, encoding="utf-8")
    else:
        sys.stdout.write(text)
