"""``matforge store verify`` and ``matforge store gc``: maintenance of a local store.

``verify`` re-hashes every object, checks that every object the job store refers to exists,
and exits 1 when any is corrupt or missing, listing them with the jobs' artifacts they back;
with ``--repair`` it restores them where it can
(:mod:`service.repair`) and exits 1 only if some could not be. ``gc`` removes objects no
job, manifest, shard or upload refers to (``JobStore.referenced_digests``) once they are
older than the grace period, and the work directories that killed workers left in
``<data>/scratch``; it is a dry run unless ``--no-dry-run`` is given.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from service.cli.artifacts import human_size, open_local
from service.cli.state import EXIT_JOB_FAILED, err_console, error, print_json, state_of
from storage.scratch import collect_scratch

store_app = typer.Typer(
    help="Maintain a local store: verify objects, collect garbage.", no_args_is_help=True
)

JsonOpt = typer.Option(False, "--json", help="Print one JSON document on stdout.")
DataDirOpt = typer.Option(
    None,
    "--data-dir",
    show_default=False,
    help="Data directory (default: MATFORGE_DATA or ./matforge-data).",
)


@store_app.command("verify")
def verify(
    ctx: typer.Context,
    data_dir: Path | None = DataDirOpt,
    repair: bool = typer.Option(
        False,
        "--repair",
        help="Restore corrupt objects: from a good copy under --source, else by re-running "
        "the job that produced them; report what cannot be repaired.",
    ),
    sources: list[Path] = typer.Option(
        [],
        "--source",
        show_default=False,
        help="A file or folder to search for good copies (e.g. the originals of uploads); "
        "may be repeated.",
    ),
    as_json: bool = JsonOpt,
) -> None:
    """Re-hash every object in the store and check that every object a job, upload or
    manifest refers to exists; exit 1 if any is (still) corrupt or missing."""
    settings = state_of(ctx).settings_for(data_dir)
    jobs, store = open_local(settings.data_dir)
    with err_console.status(f"verifying {settings.store_dir}"):
        report = store.verify_all(jobs.referenced_digests())
    damaged: list[dict[str, Any]] = []
    for digest, problem in [(d, "corrupt") for d in report.corrupt] + [
        (d, "missing") for d in report.missing
    ]:
        rec = jobs.find_digest(digest)
        damaged.append({"digest": digest, "name": rec.name if rec else None, "problem": problem})
    if repair and damaged:
        from service.repair import repair as repair_objects

        (settings.data_dir / "scratch").mkdir(parents=True, exist_ok=True)
        with err_console.status(f"repairing {len(damaged)} object(s)"):
            outcomes = repair_objects(
                [item["digest"] for item in damaged], jobs, store, settings, sources
            )
        for item, outcome in zip(damaged, outcomes, strict=True):
            item.update(repaired=outcome.repaired, how=outcome.how)
    left = [item for item in damaged if not item.get("repaired")]
    if as_json:
        doc = {
            "checked": report.checked,
            "ok": not left,
            "corrupt": [i for i in damaged if i["problem"] == "corrupt"],
            "missing": [i for i in damaged if i["problem"] == "missing"],
        }
        print_json({**doc, "stray": report.stray})
    else:
        fixed = len(damaged) - len(left)
        problems = [
            f"{n} {word}"
            for n, word in ((len(report.corrupt), "CORRUPT"), (len(report.missing), "MISSING"))
            if n
        ]
        status = "all intact" if report.ok else ", ".join(problems)
        print(
            f"checked {report.checked} objects in {settings.store_dir}: {status}"
            + (f", {fixed} repaired" if repair and damaged else "")
        )
        for item in damaged:
            if item.get("repaired"):
                print(f"repaired sha256:{item['digest']}: {item['how']}")
        for path in report.stray:
            print(f"stray file (not a digest name): {path}")
    for item in left:
        what = "corrupt" if item["problem"] == "corrupt" else "missing (referenced, not on disk)"
        error(
            f"{what} object sha256:{item['digest']}"
            + (f" ({item['name']})" if item["name"] else "")
            + (f": not repaired: {item['how']}" if "how" in item else "")
        )
    if left:
        raise typer.Exit(EXIT_JOB_FAILED)


@store_app.command("gc")
def gc(
    ctx: typer.Context,
    data_dir: Path | None = DataDirOpt,
    grace_hours: float | None = typer.Option(
        None,
        "--grace-hours",
        min=0.0,
        show_default=False,
        help="Keep unreferenced objects younger than "
        "this (default: MATFORGE_GC_GRACE_HOURS "
        "or 24).",
    ),
    dry_run: bool = typer.Option(
        True, "--dry-run/--no-dry-run", help="Only report what would be removed."
    ),
    as_json: bool = JsonOpt,
) -> None:
    """Remove unreferenced objects older than the grace period (dry run by default)."""
    settings = state_of(ctx).settings_for(data_dir)
    jobs, store = open_local(settings.data_dir)
    grace = settings.gc_grace_seconds if grace_hours is None else grace_hours * 3600.0
    report = store.gc(jobs.referenced_digests(), grace, dry_run=dry_run)
    scratch = collect_scratch(settings.data_dir / "scratch", jobs.running, dry_run=dry_run)
    if as_json:
        print_json(
            {
                "dry_run": report.dry_run,
                "removed": report.removed,
                "bytes_freed": report.bytes_freed,
                "kept_referenced": report.kept_referenced,
                "kept_recent": report.kept_recent,
                "scratch_removed": scratch.removed,
                "scratch_bytes_freed": scratch.bytes_freed,
            }
        )
        return
    verb = "would remove" if dry_run else "removed"
    print(
        f"{verb} {len(report.removed)} objects ({human_size(report.bytes_freed)}); kept "
        f"{report.kept_referenced} referenced and {report.kept_recent} younger than "
        f"{grace / 3600:g} h"
    )
    print(
        f"{verb} {len(scratch.removed)} stale work directories of killed workers "
        f"({human_size(scratch.bytes_freed)}); kept {scratch.kept_active} of running jobs"
    )
    if dry_run and (report.removed or scratch.removed):
        err_console.print(
            "dry run: nothing was removed; pass --no-dry-run to remove them",
            markup=False,
            highlight=False,
        )
