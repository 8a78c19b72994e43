"""The quality-control report of a batch: one self-contained HTML page (``facecorr report``).

:mod:`.collect` reads a ``facecorr batch`` output folder (results, thumbnails, failures.json; a
file it cannot use becomes a listed problem); :mod:`.page` writes the page (``page.html``,
``page.css``, ``page.js`` beside it): the summary and histograms, a sortable, filterable table
worst first with a thumbnail per scan, the failures and the problems.
"""

from __future__ import annotations

from pathlib import Path

from .collect import BatchReport, Failure, Problem, ScanRow, read_batch, worst_first
from .page import render_page

__all__ = ["BatchReport", "Failure", "Problem", "ScanRow", "build_report", "read_batch", "render_page", "worst_first"]

#: What ``-o`` may be called.
REPORT_SUFFIXES = (".html", ".htm")


def build_report(results_dir, output, *, title: str | None = None, workers: int = 2, progress: bool = True) -> BatchReport:
    """Read the batch folder ``results_dir`` and write its report to ``output`` (.html, atomically).

    Raises FacecorrError (before any work) for an output that cannot be written or is not .html,
    and for a folder without results (:func:`read_batch`). Returns what the page shows.
    """
    from ..errors import OutputError
    from ..io.atomic import check_output_paths, write_text

    output = Path(output)
    if output.suffix.lower() not in REPORT_SUFFIXES:
        raise OutputError(f"{output}: the report is a web page: name it .html")
    check_output_paths([("-o", output)])
    report = read_batch(results_dir, workers=workers, progress=progress)
    write_text(output, render_page(report, title=title))
    return report
