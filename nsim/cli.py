"""The ``nsim`` command line: a thin click shell over the stages and the workspace.

Strings become configs and artifact references here; the work happens in
``nsim.stages.*.run``. User errors (:class:`~nsim.errors.NsimError`, click usage errors)
print one line to stderr and exit 2; ``nsim verify`` exits 1 when an artifact is damaged.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import click

from nsim import __version__
from nsim.commands import register_commands
from nsim.config import ConfigError
from nsim.context import DEVICE_CHOICES, RunContext
from nsim.errors import NsimError
from nsim.workspace.store import Store, default_root

log = logging.getLogger("nsim")


# ------------------------------------------------------------------------------- helpers
def _ctx(click_ctx: click.Context) -> RunContext:
    return click_ctx.find_root().obj.get()


def _inspect(click_ctx: click.Context) -> RunContext:
    """The context of a command that only looks: it creates no workspace and checks nothing on read."""
    return click_ctx.find_root().obj.get(create=False, checked=False)


def _human_size(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} GB"


def _age(created: str | None) -> str:
    if not created:
        return "?"
    try:
        t = time.mktime(time.strptime(created, "%Y-%m-%dT%H:%M:%SZ")) - time.timezone
    except ValueError:
        return "?"
    s = max(0.0, time.time() - t)
    for unit, span in (("d", 86400), ("h", 3600), ("m", 60)):
        if s >= span:
            return f"{s / span:.0f}{unit}"
    return f"{s:.0f}s"


# ------------------------------------------------------------------------------- root group
@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="nsim")
@click.option(
    "--workspace",
    "-w",
    type=click.Path(file_okay=False),
    default=None,
    help="Workspace root (default: $NSIM_WORKSPACE, else ./nsim-workspace).",
)
@click.option("--device", default="auto", show_default=True, help="Torch device: auto, cpu, cuda or cuda:N.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed for every random draw.")
@click.option("--progress/--no-progress", default=None, help="Progress bars (default: only on a terminal).")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
@click.pass_context
def cli(click_ctx: click.Context, workspace: str | None, device: str, seed: int, progress: bool | None, verbose: int):
    """nsim: a handheld video of a room in, a photorealistic robot simulator out."""
    logging.basicConfig(
        level=logging.WARNING - 10 * min(verbose, 2), format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr
    )
    if device.split(":")[0].lower() not in DEVICE_CHOICES:
        raise click.BadParameter(f"expected one of {', '.join(DEVICE_CHOICES)} or cuda:N, got {device!r}",
                                 param_hint="--device")
    if seed < 0:
        raise click.BadParameter(f"expected a seed >= 0, got {seed}", param_hint="--seed")
    root = Path(workspace) if workspace else default_root()
    click_ctx.obj = _LazyContext(root, device, seed, progress)


class _LazyContext:
    """Opens the workspace only when a command needs it (``nsim --help`` creates nothing)."""

    def __init__(self, root: Path, device: str, seed: int, progress: bool | None):
        self._args = (root, device, seed, progress)
        self._ctx: RunContext | None = None

    def get(self, create: bool = True, checked: bool = True) -> RunContext:
        if self._ctx is None:
            root, device, seed, progress = self._args
            store = Store(root, create=create, checked=checked)
            self._ctx = RunContext(store=store, device_spec=device, seed=seed, progress=progress)
        return self._ctx


# ------------------------------------------------------------------------------- workspace commands
@cli.command("ls")
@click.option("--kind", default=None, help="Only artifacts of this kind.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
@click.pass_context
def ls_cmd(click_ctx: click.Context, kind: str | None, as_json: bool):
    """List artifacts: kind, refs, id, size, age."""
    store = _inspect(click_ctx).store
    by_id: dict[str, list[str]] = {}
    for name, i in store.refs().items():
        by_id.setdefault(i, []).append(name)
    rows = []
    damaged = []
    for art in store.artifacts():
        try:
            m = art.manifest
        except NsimError as exc:
            damaged.append(str(exc))
            continue
        if kind and m["kind"] != kind:
            continue
        rows.append(
            {
                "kind": m["kind"],
                "stage": m["stage"],
                "refs": by_id.get(art.id, []),
                "id": art.id,
                "size_bytes": store.size_bytes(art),
                "created_utc": m.get("timing", {}).get("created_utc"),
            }
        )
    rows.sort(key=lambda r: (r["created_utc"] or "", r["id"]))
    if as_json:
        click.echo(json.dumps(rows, indent=1))
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"nsim workspace {store.root}", title_justify="left")
    for col in ("kind", "refs", "id", "size", "age"):
        table.add_column(col, no_wrap=col != "refs")
    for r in rows:
        table.add_row(r["kind"], ", ".join(r["refs"]), r["id"][:12], _human_size(r["size_bytes"]), _age(r["created_utc"]))
    Console(width=120 if not sys.stdout.isatty() else None).print(table)
    _warn_damage(store, damaged)


def _warn_damage(store: Store, damaged: list[str]) -> None:
    for line in damaged:
        click.echo(f"warning: {line}", err=True)
    for i in store.damaged_ids():
        click.echo(f"warning: object {i[:12]} has no manifest (an interrupted removal?); 'nsim gc' removes it "
                   "once no ref needs it", err=True)
    for name, i in store.broken_refs().items():
        click.echo(f"warning: ref {name} points at missing artifact {i[:12]}", err=True)
    for why in store.bad_refs().values():
        click.echo(f"warning: {why}", err=True)


@cli.command("show")
@click.argument("spec")
@click.option("--json", "as_json", is_flag=True, help="Print the manifest as JSON only.")
@click.pass_context
def show_cmd(click_ctx: click.Context, spec: str, as_json: bool):
    """Show an artifact's manifest and its lineage down to the capture."""
    store = _inspect(click_ctx).store
    art = store.get(store.resolve(spec))
    m = art.manifest
    if as_json:
        click.echo(json.dumps(m, indent=1))
        return
    from rich.console import Console
    from rich.tree import Tree

    con = Console()
    refs = [n for n, i in store.refs().items() if i == art.id]
    con.print(f"[bold]{m['kind']}[/bold] {art.id}")
    con.print(f"  stage      {m['stage']} v{m['stage_version']}   seed {m.get('seed')}")
    con.print(f"  refs       {', '.join(refs) or '-'}")
    con.print(f"  size       {_human_size(store.size_bytes(art))} in {len(m['files'])} files")
    timing = m.get("timing", {})
    con.print(f"  created    {timing.get('created_utc')} on {timing.get('host')} in {timing.get('wall_time_s')} s")
    con.print("  code       " + ", ".join(f"{k} {v}" for k, v in m["fingerprint"].items()))
    con.print("  config     " + json.dumps(m["config"], sort_keys=True), soft_wrap=True)
    if m.get("summary"):
        con.print("  summary    " + json.dumps(m["summary"], sort_keys=True), soft_wrap=True)

    def add(node: Tree, sub: dict[str, Any]) -> None:
        for name, child in sub["inputs"].items():
            add(node.add(f"{name}: {child['kind']} {child['id'][:12]} ({child['stage']})"), child)

    lin = store.lineage(art.id)
    tree = Tree(f"lineage: {lin['kind']} {lin['id'][:12]} ({lin['stage']})")
    add(tree, lin)
    con.print(tree)


@cli.command("verify")
@click.argument("specs", nargs=-1)
@click.option("--rebuild", is_flag=True,
              help="Recompute each artifact from its inputs; when the digests differ, compare the files "
                   "against the tolerances of the artifact's kind.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, allow_dash=True), default=None,
              help="Also write a JSON report to this file ('-': stdout, instead of the text lines).")
@click.pass_context
def verify_cmd(click_ctx: click.Context, specs: tuple[str, ...], rebuild: bool, json_path: str | None):
    """Re-hash artifacts (all by default); exit 1 naming the file on any mismatch.

    With --rebuild, a rebuild whose digests differ passes when every file is within the tolerances of
    its kind (nsim/workspace/compare.py) and fails naming the file and the figure; an artifact made from
    files the workspace does not hold (and no longer finds) is listed as SKIPPED, with the reason.
    """
    if json_path not in (None, "-"):  # before any work: a report with nowhere to go is an error now, not at the end
        folder = Path(json_path).resolve().parent
        if not folder.is_dir() or not os.access(folder, os.W_OK):
            raise NsimError(f"--json {json_path}: {folder} is not a folder this user can write to")
    ctx = _inspect(click_ctx)
    store = ctx.store
    ids = [store.resolve(s) for s in specs] if specs else sorted(store.all_ids() + store.damaged_ids())
    say = (lambda line: None) if json_path == "-" else click.echo
    report: list[dict[str, Any]] = []
    bad = 0
    for art_id in ids:
        problems = store.verify(art_id)
        entry: dict[str, Any] = {"id": art_id, "kind": None, "stage": None, "rebuilt": None, "identical": None,
                                 "within_tolerance": not problems, "files": []}
        report.append(entry)
        if problems:
            bad += 1
            entry["corrupt"] = [str(p) for p in problems]
            for p in problems:
                say(f"CORRUPT {art_id[:12]} {p}")
            continue
        m = store.get(art_id).manifest
        entry.update(kind=m["kind"], stage=m["stage"])
        if not rebuild:
            say(f"ok      {art_id[:12]}")
            continue
        from nsim.stages import stage_module
        from nsim.workspace.compare import compare_artifacts

        mod = stage_module(m["stage"])
        try:
            rebuilt = mod.rebuild(m, RunContext(store, ctx.device_spec, m.get("seed") or 0, force=True,
                                                progress=ctx.progress))
        except NsimError as exc:  # made from files the workspace does not hold: say so, go on with the others
            entry.update(within_tolerance=None, error=f"cannot rebuild: {exc}")
            say(f"SKIPPED {art_id[:12]} cannot rebuild: {exc}")
            continue
        entry.update(rebuilt=rebuilt, identical=rebuilt == art_id)
        if rebuilt == art_id:
            say(f"ok      {art_id[:12]} rebuilt identically")
            continue
        new = store.get(rebuilt)
        comparison = compare_artifacts(store.get(art_id).path, new.path, m["kind"], m["files"], new.manifest["files"])
        worst = comparison.worst()
        entry.update(within_tolerance=comparison.within, files=[d.to_dict() for d in comparison.deltas],
                     worst=str(worst) if worst is not None else None)
        for d in comparison.deltas:
            say(f"  {d}")
        verdict = "WITHIN " if comparison.within else "DIFFERS"
        say(f"{verdict} {art_id[:12]} rebuilt as {rebuilt[:12]}: {comparison.summary()}")
        bad += not comparison.within
    if json_path is not None:
        with click.open_file(json_path, "w") as f:
            json.dump({"artifacts": report, "ok": not bad}, f, indent=1, allow_nan=False)
            f.write("\n")
    if bad:
        raise SystemExit(1)


@cli.command("gc")
@click.option("--dry-run", is_flag=True, help="Only list what would be removed.")
@click.option("--grace", "grace_s", type=click.FloatRange(min=0.0), default=3600.0, show_default=True,
              help="Never remove an object younger than this many seconds.")
@click.pass_context
def gc_cmd(click_ctx: click.Context, dry_run: bool, grace_s: float):
    """Remove artifacts that no ref, running process or recent publish keeps; stale cache entries; debris."""
    report = _inspect(click_ctx).store.gc(dry_run=dry_run, grace_s=grace_s)
    verb = "would remove" if dry_run else "removed"
    for i in report.restored:
        click.echo(f"kept object {i[:12]} (a ref or a running process took it during this gc)")
    for i in report.objects:
        click.echo(f"{verb} object {i[:12]}")
    for t in report.tmp:
        click.echo(f"{verb} tmp/{t}")
    click.echo(
        f"{verb} {len(report.objects)} objects ({_human_size(report.bytes_freed)}), "
        f"{len(report.actions)} cache entries, {len(report.tmp)} tmp entries; "
        f"kept {report.kept_young} younger than {grace_s:g} s and {report.kept_leased} held by running processes"
    )


@cli.command("tag")
@click.argument("spec")
@click.argument("name")
@click.option("--delete", is_flag=True, help="Delete the ref NAME instead (SPEC is ignored).")
@click.pass_context
def tag_cmd(click_ctx: click.Context, spec: str, name: str, delete: bool):
    """Point the ref NAME (e.g. scene/lab) at an artifact."""
    store = _inspect(click_ctx).store
    if delete:
        store.delete_ref(name)
        click.echo(f"deleted ref {name}")
        return
    art_id = store.resolve(spec)
    store.set_ref(name, art_id)
    click.echo(f"{name} -> {art_id[:12]}")


# ------------------------------------------------------------------------------- stages
# Each stage's command lives in nsim/commands/<stage>_command.py (a thin shell over nsim.stages.<stage>).
register_commands(cli)


# ------------------------------------------------------------------------------- entry point
def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point: one-line errors with exit 2, verify failures exit 1."""
    try:
        cli.main(args=list(argv) if argv is not None else None, prog_name="nsim", standalone_mode=False)
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        return 130
    except click.ClickException as exc:
        hint = ""
        if exc.ctx is not None and isinstance(exc, click.UsageError):
            hint = f" (see '{exc.ctx.command_path} --help')"
        click.echo(f"error: {exc.format_message()}{hint}", err=True)
        return 2
    except (NsimError, ConfigError) as exc:
        click.echo(f"error: {exc}", err=True)
        return 2
    except KeyboardInterrupt:
        click.echo("interrupted", err=True)
        return 130
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
