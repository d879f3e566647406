"""``nsim simulate``: one scenario, or a sweep of them."""

from __future__ import annotations

import click

from nsim.commands.common import report_artifact, resolve_config, run_context, stage_options


@click.command("simulate")
@stage_options("simulate")
@click.option(
    "--scenario",
    "--trajectory",
    "scenario_file",
    default=None,
    help="Scenario file (JSON or YAML), e.g. nsim/configs/scenarios/spot_run.json.",
)
@click.option(
    "--sweep",
    "sweep_file",
    default=None,
    help="Sweep file (YAML): seeds x crowd sizes x behaviours x controllers over a scenario.",
)
@click.option(
    "--summary",
    "summary_file",
    default=None,
    help="Sweep only: also write the summary here (.json, else Markdown).",
)
@click.option(
    "--engine",
    type=click.Choice(["local", "ray"]),
    default="local",
    show_default=True,
    help="Sweep only: who runs the cells.",
)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Sweep only: parallel workers (local: a process pool).",
)
@click.option(
    "--address",
    default=None,
    help="Sweep only, --engine ray: a cluster to join ('auto', HOST:6379 or ray://HOST:10001).",
)
@click.option(
    "--robot-trajectory",
    default=None,
    help="Drive the robot along this path instead of the scenario's: a TUM file, a recording "
    "(nsim import-log; its odometry frame taken as the world) or a registration (nsim register-log).",
)
@click.pass_context
def command(
    click_ctx,
    preset,
    config_file,
    overrides,
    force,
    tag,
    scenario_file,
    sweep_file,
    summary_file,
    engine,
    workers,
    address,
    robot_trajectory,
):
    """Simulate humans reacting to the robot: a trajectory artifact per scenario."""
    from nsim.stages import simulate

    if (scenario_file is None) == (sweep_file is None):
        raise click.UsageError("give exactly one of --scenario FILE or --sweep FILE")
    if scenario_file is not None and (summary_file or engine != "local" or workers != 1 or address):
        raise click.UsageError("--summary, --engine, --workers and --address apply to --sweep only")
    if robot_trajectory is not None and sweep_file is not None:
        raise click.UsageError("--robot-trajectory applies to --scenario only (a sweep's scenario names its own)")
    cfg = resolve_config(simulate.Config, "simulate", preset, config_file, overrides)
    ctx = run_context(click_ctx, force)
    if scenario_file is not None:
        sc = simulate.load_scenario(scenario_file, store=ctx.store, robot_trajectory=robot_trajectory)
        out = simulate.run(simulate.Inputs(sc), cfg, ctx)
        report_artifact(ctx, out.trajectory, out.cache_hit, tag)
        return
    from nsim.crowd.run_output import controller_table_markdown, sweep_table_markdown
    from nsim.crowd.sweep import load_sweep

    spec, scenario_path = load_sweep(sweep_file)
    rows = simulate.run_sweep(spec, scenario_path, cfg, ctx, engine=engine, address=address, workers=workers)
    if tag:
        for k, r in enumerate(rows):
            ctx.store.set_ref(f"{tag}/{k}", r["trajectory"])
    table = sweep_table_markdown(rows)
    if len(spec.controllers) > 1:
        table += "\n" + controller_table_markdown(rows)
    click.echo(table, nl=False)
    cached = sum(r["cache_hit"] for r in rows)
    click.echo(f"sweep: {len(rows)} trajectories ({cached} cached)", err=True)
    if summary_file:
        from pathlib import Path

        path = Path(summary_file)
        if path.suffix.lower() == ".json":
            import json

            path.write_text(json.dumps({"sweep": str(sweep_file), "rows": rows}, indent=1) + "\n")
        else:
            path.write_text(f"# nsim simulate --sweep {sweep_file}\n\n" + table)
