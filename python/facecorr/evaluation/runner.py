"""The one runner behind ``facecorr eval landmarks`` and ``facecorr eval registration``: the
paper's evaluation scans of a synthetic database, one job each, in spawned worker processes with
a progress bar."""

from __future__ import annotations

from pathlib import Path


def select_eval_records(records, split="test", level=4):
    """The paper's evaluation subset: the split's neutral scans and 6 expressions at ``level``."""
    return [r for r in records if r["split"] == split and (r["expression"] == "NE" or r["level"] == level)]


def write_report(out_dir, stem: str, markdown: str, table: list, columns: str, row_format: str, rows: list) -> None:
    """Write ``<stem>_table.md`` (``markdown``), ``<stem>_table.csv`` (header ``columns``, one
    ``row_format.format(**t)`` line per table row ``t``) and ``<stem>_per_scan.json`` (``rows``)
    into ``out_dir`` (created), each atomically."""
    from ..io.atomic import write_json, write_text

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / f"{stem}_table.md", markdown)
    write_text(out / f"{stem}_table.csv", columns + "\n" + "".join(row_format.format(**t) + "\n" for t in table))
    write_json(out / f"{stem}_per_scan.json", rows)


def run_on_eval_scans(db_dir, worker, make_job, *, workers=2, limit=None, split="test", desc="evaluating",
                      progress=True, on_row=None) -> list:
    """``[worker(make_job(k, record)) ...]`` over the evaluation scans of ``db_dir`` (in order).

    ``worker`` must be a module-level function that never raises (it returns a row with
    ``"ok"``); ``split`` selects the subjects ("test", "train", or a ``bu3dfe-ood`` database's
    "ood_test" / "ood_holdout"); ``limit`` keeps the first scans only; ``on_row(row)`` is called with each row as it
    comes (a run log). Raises FacecorrError if there are none.
    """
    from ..errors import FacecorrError
    from ..synth import load_index
    from ..threads import process_iter

    every = load_index(db_dir)
    records = select_eval_records(every, split=split)
    if limit:
        records = records[:limit]
    if not records:
        have = sorted({r["split"] for r in every})
        raise FacecorrError(f"{db_dir}: no {split} scans at the evaluation level (its splits: {', '.join(have)}; "
                            f"choose one with --split)")
    jobs = [make_job(k, r) for k, r in enumerate(records)]
    rows = []
    for row in process_iter(worker, jobs, workers=workers, desc=desc, progress=progress):
        rows.append(row)
        if on_row is not None:
            on_row(row)
    return rows
