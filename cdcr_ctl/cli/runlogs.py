"""``cdcr-ctl export``: a run as CSV, Parquet and candump."""

from __future__ import annotations

from pathlib import Path

import click

from cdcr_ctl.cli.app import Ctx


@click.command("export")
@click.argument("run", type=click.Path(exists=True))
@click.option("--csv", "as_csv", is_flag=True, help="samples.csv + run.yaml + configs in OUT.")
@click.option("--parquet", "as_parquet", is_flag=True, help="OUT/samples.parquet (zstd).")
@click.option(
    "--can/--no-can",
    "with_can",
    default=True,
    show_default=True,
    help="Also the raw CAN traffic as OUT/can.log (candump -L; canplayer, python -m can.player).",
)
@click.option("--out", type=click.Path(file_okay=False), default=None, help="Default: RUN/export")
@click.pass_obj
def export_cmd(
    obj: Ctx, run: str, as_csv: bool, as_parquet: bool, with_can: bool, out: str | None
) -> None:
    """Export a run (directory or run.mcap) for spreadsheets, batch analysis and CAN replay."""
    if not (as_csv or as_parquet):
        raise click.UsageError("give --csv and/or --parquet")
    from cdcr_ctl.runlog import export as run_export
    from cdcr_ctl.runlog.reader import load_run

    r = load_run(run)
    out_dir = Path(out) if out else r.run_dir / "export"
    written: dict[str, str] = {}
    if as_csv:
        written["csv"] = str(run_export.export_csv(r, out_dir) / "samples.csv")
    if as_parquet:
        written["parquet"] = str(run_export.export_parquet(r, out_dir / run_export.PARQUET))
    if with_can:
        frames = run_export.can_messages(r)
        if frames:
            path = run_export.export_candump(frames, out_dir / run_export.CANDUMP_LOG)
            written["can"] = str(path)
            written["can_frames"] = str(len(frames))
    obj.emit({"rows": len(r), "source": str(r.samples_path), "warnings": r.warnings, **written})
