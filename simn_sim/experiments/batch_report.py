"""A batch folder's reports: ``summary.md``, ``summary.csv`` and the plots, from its records."""

from __future__ import annotations

from pathlib import Path

from simn_sim.experiments.batch_files import RECORDS_FILE, read_records_lenient

__all__ = ["BATCH_METRICS", "write_reports"]

#: Metrics in summary.md / summary.csv (record field names).
BATCH_METRICS: tuple[str, ...] = (
    "success",
    "spl",
    "soft_spl",
    "collisions",
    "collisions_with_people",
    "path_length_m",
    "steps",
    "plan_ms_median",
    "wall_time_s",
)


def write_reports(out: str | Path, plots: bool = True) -> dict[str, Path]:
    """(Re)write ``summary.md``, ``summary.csv`` and the plots from the records in ``out``.

    Returns the written files by name. Records of every agent in the folder are summarised.
    """
    from simn_sim.experiments.stats import summarize, summary_markdown, write_summary_csv

    out = Path(out)
    recs, _ = read_records_lenient(out / RECORDS_FILE)
    files: dict[str, Path] = {}
    if not recs:
        return files
    rows = summarize(recs, BATCH_METRICS)
    n_err = sum(r.get("error") is not None for r in recs)
    md = [
        f"# Batch summary: {out.name}",
        "",
        f"{len(recs)} episode records; means with 95 % Student-t confidence intervals. "
        "Errored episodes count as failures (0) for success/spl/soft_spl and are left out of "
        "the other metrics.",
        "",
        summary_markdown(rows),
    ]
    if n_err:
        md += ["## Errors", ""]
        for r in recs:
            if r.get("error") is not None:
                first = str(r["error"]).splitlines()[0]
                md.append(f"- `{r['agent']}` `{r['episode_id']}`: {first}")
        md.append("")
    files["summary.md"] = out / "summary.md"
    files["summary.md"].write_text("\n".join(md))
    files["summary.csv"] = out / "summary.csv"
    write_summary_csv(rows, files["summary.csv"])
    if plots:
        from simn_sim.experiments.plots import plot_success_spl, plot_trajectories

        files["success_spl.png"] = plot_success_spl(rows, out / "success_spl.png")
        for p in plot_trajectories(out, recs):
            files[p.name] = p
    return files
