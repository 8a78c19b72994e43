"""Options the long-running commands share: ``--quiet`` and ``--log FILE`` (for unattended runs)."""

from __future__ import annotations


def add_run_options(parser, *, log: bool = True) -> None:
    """Add ``--quiet`` (no progress bar, no summary: only errors) and ``--log FILE`` (JSON lines,
    one per scan, appended as each scan ends)."""
    parser.add_argument("--quiet", action="store_true", help="no progress bar and no summary, only errors")
    if log:
        parser.add_argument("--log", metavar="FILE",
                            help="append one JSON line per scan to FILE (status, timings, flags, errors)")


def open_log(args, *, inputs=()):
    """The RunLog of ``args.log`` (None without --log); the path is checked before any work."""
    from ..io.runlog import open_run_log

    return open_run_log(getattr(args, "log", None), inputs=inputs)
