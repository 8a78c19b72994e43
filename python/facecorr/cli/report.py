"""CLI: ``facecorr report`` (the quality-control page of a batch's results)."""

from __future__ import annotations

from pathlib import Path


def add_commands(sub) -> None:
    p = sub.add_parser("report", help="one self-contained HTML page to check a batch's results",
                       description="Read the output folder of `facecorr batch` and write one HTML file (pictures "
                                   "inlined, no network needed): counts and histograms of MHD, fit RMS, coverage "
                                   "and landmark confidence; a table of the scans, worst first, sortable and "
                                   "filterable, with a thumbnail each (the batch's --png, else rendered here); "
                                   "the failures; the files that could not be read.")
    p.add_argument("results", help="output folder of `facecorr batch`")
    p.add_argument("-o", "--output", required=True, help="the page to write (.html)")
    p.add_argument("--title", help="the page's title (default: 'facecorr report: FOLDER')")
    p.add_argument("--workers", type=int, default=2, help="processes rendering the thumbnails the batch did not write "
                   "(default 2)")
    p.set_defaults(func=cmd_report)


def cmd_report(args) -> int:
    from ..errors import FacecorrError
    from ..report import build_report

    if args.workers < 1:
        raise FacecorrError(f"--workers must be at least 1, got {args.workers}")
    out = Path(args.output)
    rep = build_report(args.results, out, title=args.title, workers=args.workers)
    rendered = sum(1 for r in rep.rows if r.picture_source == "rendered")
    flagged = sum(1 for r in rep.rows if r.flags)
    print(f"{out}: {len(rep.rows)} results ({flagged} flagged), {len(rep.failures)} failures, "
          f"{len(rep.problems)} problems; {rendered} thumbnails rendered, {out.stat().st_size / 1e6:.1f} MB")
    return 0
