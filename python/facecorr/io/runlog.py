"""The run log of an unattended run (``--log FILE``): JSON lines, one object per scan.

Unlike a result file, a log is not written atomically: each line is appended and flushed as its
scan ends, so a run that is killed keeps the lines of every scan it finished, and a resumed run
appends to the same file.
"""

from __future__ import annotations

import json
import math
from datetime import datetime, timezone
from pathlib import Path

__all__ = ["RunLog", "open_run_log"]


def _finite(obj):
    """``obj`` with non-finite floats as None (JSON has no NaN; a log line must stay parseable)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


class RunLog:
    """A JSON-lines log opened for appending; :meth:`write` adds one line and flushes it.

    Every line gets ``"time"``: the UTC time it was written (ISO 8601, seconds)."""

    def __init__(self, path):
        from ..errors import OutputError

        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.path, "a", encoding="utf-8")
        except OSError as e:
            raise OutputError(f"{self.path}: cannot write the log: {e.strerror or e}") from None

    def write(self, record: dict) -> None:
        """Append ``record`` (a JSON-serialisable dict) as one line, flushed."""
        line = {**_finite(record), "time": datetime.now(timezone.utc).isoformat(timespec="seconds")}
        self._fh.write(json.dumps(line, separators=(",", ":")) + "\n")
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def open_run_log(path, *, inputs=()) -> RunLog | None:
    """A :class:`RunLog` on ``path`` (None: no log). Checked first like any output (OutputError:
    a folder, a parent that is a file, no permission, one of ``inputs``)."""
    if path is None:
        return None
    from .atomic import check_output_paths

    check_output_paths([("--log", Path(path))], inputs=inputs)
    return RunLog(path)
