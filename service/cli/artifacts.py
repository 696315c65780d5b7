"""``matforge artifacts``, ``fetch`` and ``import``: from the server, or from a local store
when ``--data-dir`` is given.

Refs are ``job:<job-id>/<artifact-name>`` or ``sha256:<64 hex>``. Fetched bytes are always
verified against their digest before any reaches the destination (see
:mod:`service.cli.fetch_output`)."""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from functools import partial
from pathlib import Path
from typing import Any

import typer
from rich.table import Table
from rich.text import Text

from service.cli.client import BadInput
from service.cli.fetch_output import (
    Fill,
    Write,
    check_subfolders,
    write_stream,
    write_verified,
)
from service.cli.state import out_console, print_json, print_line, state_of
from storage.errors import FormatError, IntegrityError, NotFoundError
from storage.formats.btf_folder import pack_folder

JsonOpt = typer.Option(False, "--json", help="Print one JSON document on stdout.")
LocalOpt = typer.Option(
    None,
    "--data-dir",
    show_default=False,
    help="Use the local store in this data directory, not the server.",
)
_CHUNK = 1 << 20


def human_size(size: int) -> str:
    value = float(size)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if value < 1024 or unit == "GiB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1024
    return f"{size} B"


def artifacts_table(arts: list[dict[str, Any]]) -> Table:
    """A Rich table of artifact records: name, size, media type, digest."""
    table = Table(title="artifacts")
    for col in ("name", "size", "media type", "digest"):
        table.add_column(col, justify="right" if col == "size" else "left", overflow="fold")
    for a in arts:
        table.add_row(
            Text(str(a.get("name"))),
            human_size(int(a.get("size") or 0)),
            Text(str(a.get("media_type"))),
            Text(f"sha256:{a.get('digest')}"),
        )
    return table


def open_local(data_dir: Path, *, create: bool = False) -> tuple[Any, Any]:
    """``(JobStore, ArtifactStore)`` of a data directory; ``NotFoundError`` (exit 2) when it
    holds no matforge data and ``create`` is false."""
    from service.settings import Settings
    from storage.artifacts import ArtifactStore
    from storage.jobs import JobStore

    settings = Settings(data_dir=data_dir)
    if not create and not settings.db_path.is_file():
        raise NotFoundError(
            f"{data_dir}: not a matforge data directory (no "
            f"{settings.db_path.name}); check --data-dir"
        )
    return JobStore(settings.db_path), ArtifactStore(settings.store_dir)


def parse_ref(ref: str) -> tuple[str | None, str | None, str | None]:
    """``(job_id, artifact name, digest)`` of a ``job:`` or ``sha256:`` ref; the unused
    parts are ``None``. Raises :class:`BadInput` for anything else."""
    from jobapi.params import JOB_REF, SHA_REF
    from service.specs import SHORT_JOB_REF

    m = JOB_REF.match(ref)
    if m:
        return m["job"], m["name"], None
    m = SHORT_JOB_REF.match(ref)
    if m and m["rest"] and JOB_REF.match(f"job:{'0' * 32}{m['rest']}"):
        return m["job"], m["rest"][1:], None
    m = SHA_REF.match(ref)
    if m:
        return None, None, m["digest"]
    raise BadInput(
        f"not an artifact reference: {ref!r}; expected 'job:<job-id or prefix>/<name>' or "
        "'sha256:<64 lowercase hex>'"
    )


def parse_many(ref: str) -> tuple[str, str] | None:
    """``(job id or prefix, glob)`` when ``ref`` names several artifacts of one job
    (``job:ID``: all of them; ``job:ID/<glob>`` with ``*``, ``?`` or ``[``), else ``None``."""
    import re

    m = re.fullmatch(r"job:([0-9a-f]{1,32})(?:/(.*))?", ref)
    if m is None:
        return None
    pattern = m[2]
    if not pattern:
        return m[1], "*"
    return (m[1], pattern) if any(c in pattern for c in "*?[") else None


def _directory(output_arg: str) -> Path:
    """The directory several artifacts go to: an existing one, or one the path ends in
    ``/`` asks for (created); :class:`BadInput` otherwise."""
    output = Path(output_arg)
    if output.is_dir():
        return output
    if output_arg.endswith(("/", os.sep)) and not output.exists():
        output.mkdir(parents=True)
        return output
    raise BadInput(
        f"-o {output_arg}: several artifacts go to a directory: give an existing one, or end "
        "the path in / to create it"
    )


def fetch_many(
    ctx: typer.Context,
    many: tuple[str, str],
    output: str,
    data_dir: Path | None,
    as_json: bool,
) -> None:
    """Fetch every artifact of job ``many[0]`` whose name matches the glob ``many[1]`` into
    the directory ``output`` (names kept, sub-folders made; each verified, atomic)."""
    import fnmatch

    if output == "-":
        raise BadInput("-o -: several artifacts cannot go to stdout; give a directory")
    job_id, pattern = many
    local = state_of(ctx).local_dir(data_dir)
    written: list[dict[str, Any]] = []

    def chosen(arts: list[dict[str, Any]], full_id: str) -> list[dict[str, Any]]:
        got = [a for a in arts if fnmatch.fnmatchcase(str(a["name"]), pattern)]
        if not got:
            names = ", ".join(str(a["name"]) for a in arts) or "none"
            raise NotFoundError(f"job {full_id}: no artifact matches {pattern!r} (it has: {names})")
        return got

    def dest_of(name: str) -> Path:
        rel = Path(name)
        if rel.is_absolute() or ".." in rel.parts:
            raise FormatError(name, "an artifact name that leaves the directory")
        check_subfolders(out_dir, rel)
        dest = out_dir / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        return dest

    if local is not None:
        from storage.job_queries import resolve_job_id

        jobs, store = open_local(local)
        full = resolve_job_id(jobs, job_id)
        arts = chosen([a.public() for a in jobs.artifacts(full)], full)
        out_dir = _directory(output)
        for a in arts:
            src = store.path(a["digest"])
            if not src.is_file():
                raise NotFoundError(f"no object sha256:{a['digest']} in the store at {local}")
            dest = dest_of(str(a["name"]))
            size = write_verified(dest, local_fill(src, a["digest"]), mode=default_file_mode())
            written.append(
                {"name": a["name"], "digest": a["digest"], "size": size, "path": str(dest)}
            )
    else:
        with state_of(ctx).client() as client:
            full = str(client.get(job_id)["id"]) if len(job_id) < 32 else job_id
            arts = chosen(client.artifacts(full), full)
            out_dir = _directory(output)
            for a in arts:
                dest = dest_of(str(a["name"]))
                size = client.fetch(str(a["digest"]), dest, mode=default_file_mode())
                written.append(
                    {"name": a["name"], "digest": a["digest"], "size": size, "path": str(dest)}
                )
    if as_json:
        print_json(written)
    else:
        for w in written:
            print_line(w["path"])


def destination(out: Path, name: str) -> Path:
    """``out`` itself, or ``out/<basename of name>`` when ``out`` is a directory."""
    return out / Path(name).name if out.is_dir() else out


def local_fill(src: Path, digest: str) -> Fill:
    """A :data:`~service.cli.fetch_output.Fill` of a local object: its bytes, hashed on the
    way; ``IntegrityError`` after the last chunk when they do not match ``digest``."""

    def fill(write: Write) -> int:
        h, size = hashlib.sha256(), 0
        with open(src, "rb") as fh:
            for chunk in iter(lambda: fh.read(_CHUNK), b""):
                h.update(chunk)
                size += len(chunk)
                write(chunk)
        if h.hexdigest() != digest:
            raise IntegrityError(
                f"object sha256:{digest} is corrupt on disk (digest mismatch); nothing was "
                "written; run 'matforge store verify'"
            )
        return size

    return fill


def default_file_mode() -> int:
    """The mode a new file gets under the user's umask (``0o666 & ~umask``): fetched files
    are written through a private temporary file (0600), then given this mode."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def artifacts(
    ctx: typer.Context,
    job_id: str = typer.Argument(..., metavar="ID", help="Job id (or a unique prefix)."),
    as_json: bool = JsonOpt,
    data_dir: Path | None = LocalOpt,
) -> None:
    """List a job's artifacts: name, digest, size, media type."""
    from storage.job_queries import resolve_job_id

    local = state_of(ctx).local_dir(data_dir)
    if local is not None:
        jobs, _ = open_local(local)
        job = jobs.get(resolve_job_id(jobs, job_id))
        arts = [a.public() for a in job.artifacts]
    else:
        with state_of(ctx).client() as client:
            arts = client.artifacts(job_id)
    if as_json:
        print_json(arts)
    elif arts:
        out_console().print(artifacts_table(arts))
    else:
        print_line(f"job {job_id} has no artifacts")


def fetch(
    ctx: typer.Context,
    ref: str = typer.Argument(
        ..., help="job:<job-id or unique prefix>/<artifact-name> or sha256:<hex>."
    ),
    output_arg: str = typer.Option(
        ...,
        "--output",
        "-o",
        help="File to write (or an existing directory: the artifact's name is used), "
        "or - for stdout; for a whole job (job:ID) or a glob (job:ID/*.png), a directory "
        "(created if the path ends in /).",
    ),
    data_dir: Path | None = LocalOpt,
    as_json: bool = JsonOpt,
) -> None:
    """Download an artifact's bytes (verified against its digest) to a file or stdout.

    ``job:ID`` (a whole job) or ``'job:ID/*.png'`` (a glob over its artifact names, quoted
    for the shell) fetch every matching artifact into the directory ``-o``, each under its
    own name, each verified and written atomically; one path per line is printed.

    A file is written atomically once verified, with the mode your umask gives new files.
    A FIFO or a terminal is written in place (never replaced), and so is stdout (``-o -``),
    once the bytes were verified; a digest mismatch exits 1 with nothing written. Block
    devices and sockets are refused (exit 2). A symbolic link is never written through or
    replaced: one to a FIFO or a terminal is written in place, any other (a dangling one
    too) is refused (exit 2), and so is a link among the sub-folders of a whole job's.
    """
    # A str, not a Path: a trailing "/" (a directory to create) must survive.
    output = Path(output_arg)
    to_stdout = output_arg == "-"
    if to_stdout and as_json:
        raise BadInput("--json and -o - both write to stdout; use one of them")
    many = parse_many(ref)
    if many is not None:
        fetch_many(ctx, many, output_arg, data_dir, as_json)
        return
    job_id, name, digest = parse_ref(ref)
    local = state_of(ctx).local_dir(data_dir)
    if local is not None:
        from storage.job_queries import resolve_job_id

        jobs, store = open_local(local)
        if job_id is not None and name is not None:
            digest = jobs.artifact(resolve_job_id(jobs, job_id), name).digest
        assert digest is not None
        src = store.path(digest)
        if not src.is_file():
            raise NotFoundError(f"no object sha256:{digest} in the store at {local}")
        if to_stdout:
            write_stream(local_fill(src, digest), sys.stdout.buffer)
            return
        dest = destination(output, name or digest)
        size = write_verified(dest, local_fill(src, digest), mode=default_file_mode())
    else:
        with state_of(ctx).client() as client:
            if job_id is not None and name is not None:
                digest = str(client.artifact(job_id, name)["digest"])
            assert digest is not None
            if to_stdout:
                client.fetch_to(digest, sys.stdout.buffer)
                return
            dest = destination(output, name or digest)
            size = client.fetch(digest, dest, mode=default_file_mode())
    if as_json:
        print_json({"ref": ref, "digest": digest, "size": size, "path": str(dest)})
    else:
        print_line(str(dest))


def import_(
    ctx: typer.Context,
    path: Path = typer.Argument(
        ..., help="File to import (a MERL .binary, an .exr, ...), or a folder of BTF slices."
    ),
    name: str | None = typer.Option(
        None, "--name", show_default=False, help="Name to record (default: the file's name)."
    ),
    as_json: bool = JsonOpt,
    data_dir: Path | None = LocalOpt,
) -> None:
    """Validate a file's format and put it in the store; prints its sha256: ref.

    A directory of BTF slices (images plus angles.csv or angles.json) is packed into
    ``<directory>.btf.zip`` first, for ``import.btf``.
    """
    if path.is_dir():
        with tempfile.TemporaryDirectory(prefix="matforge-pack-") as tmp:
            packed = Path(tmp) / f"{path.resolve().name}.btf.zip"
            try:
                pack_folder(path, packed)
            except FormatError as exc:
                raise BadInput(str(exc)) from None
            import_(ctx, packed, name, as_json, data_dir)
        return
    if not path.is_file():
        raise BadInput(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    st = state_of(ctx)
    local = st.local_dir(data_dir)
    if local is not None:
        from service.submission import import_file

        jobs, store = open_local(local, create=True)
        from storage.formats import validate_file

        rec = import_file(
            path, jobs, store, name=name, max_bytes=st.settings.max_upload_bytes,
            validate=partial(validate_file, max_archive_pixels=st.settings.archive_max_pixels),
        )  # fmt: skip
        doc: dict[str, Any] = {**rec.public(), "ref": f"sha256:{rec.digest}"}
    else:
        with st.client() as client:
            doc = client.upload(path, name)
        doc.setdefault("ref", f"sha256:{doc.get('digest')}")
    if as_json:
        print_json(doc)
    else:
        print_line(str(doc["ref"]))


def register(app: typer.Typer) -> None:
    """Add ``artifacts``, ``fetch`` and ``import`` to the app."""
    app.command("artifacts")(artifacts)
    app.command("fetch")(fetch)
    app.command("import")(import_)
