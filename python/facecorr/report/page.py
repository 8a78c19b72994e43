"""The report's one self-contained HTML page (:func:`render_page`) from a :class:`BatchReport`.

The page is ``page.html`` with ``page.css`` and ``page.js`` inlined, the pictures inlined as
base64 PNG, and the table written in the order it opens with (worst first): no network access,
and readable without JavaScript, which only sorts, filters and opens the larger picture.
"""

from __future__ import annotations

import base64
import html
import json
import math
import re
from importlib import resources

import numpy as np

from ..names import LANDMARK_NAMES
from .collect import BatchReport, ScanRow


def _asset(name: str) -> str:
    return resources.files(__package__).joinpath(name).read_text(encoding="utf-8")


def _fmt(v, digits: int = 2, scale: float = 1.0, suffix: str = "") -> str:
    return "–" if v is None else f"{v * scale:.{digits}f}{suffix}"


def _data_v(v) -> str:
    """The sort key of a cell (empty: no value, sorted last)."""
    return "" if v is None else f"{v:.6g}"


class Thresholds:
    """Where facecorr raises its flags (from the code's own defaults): the page marks worse values."""

    def __init__(self):
        from ..landmarks.predict import PredictOptions
        from ..pipeline.correspond import CorrespondOptions
        from ..registration.register import IMPLAUSIBLE_MHD_MM, IMPLAUSIBLE_RMS_MM

        self.mhd = IMPLAUSIBLE_MHD_MM
        self.rms = IMPLAUSIBLE_RMS_MM
        self.coverage = CorrespondOptions().min_coverage
        self.confidence = PredictOptions().low_confidence


def _flags_html(flags: list) -> str:
    """The flags as one chip a kind ("low_confidence ×8"), the details in its tooltip (and, for a
    lone flag, shortened beside it): a scan with 20 flags keeps a readable row."""
    kinds = {}
    for f in flags:
        kind, _, detail = f.partition(":")
        kinds.setdefault(kind, []).append(detail)
    out = []
    for kind, details in kinds.items():
        tip = html.escape("; ".join(f"{kind}:{d}" if d else kind for d in details))
        if len(details) > 1:
            extra = f"<small>×{len(details)}</small>"
        elif details[0]:
            d = details[0] if len(details[0]) <= 36 else details[0][:35] + "…"
            extra = f"<small>{html.escape(d)}</small>"
        else:
            extra = ""
        out.append(f'<span class="flag" title="{tip}">{html.escape(kind)}{extra}</span>')
    return "".join(out)


def _confidence_strip(row: ScanRow, th: Thresholds) -> str:
    cells = []
    for n in LANDMARK_NAMES:
        c = row.confidence.get(n)
        cls = "na" if c is None else ("bad" if c < th.confidence else "mid" if c < 0.7 else "ok")
        cells.append(f'<i class="{cls}" title="{html.escape(n)}: {_fmt(c)}"></i>')
    name, low = row.lowest_confidence
    label = "–" if low is None else f"{low:.2f} <small>{html.escape(name.replace('_', ' '))}</small>"
    return f'<span class="strip">{"".join(cells)}</span> {label}'


def _expression_html(row: ScanRow, k: int = 3) -> str:
    top = sorted(((w, n) for n, w in row.expression.items() if w >= 0.01), reverse=True)[:k]
    if not top:
        return '<span class="dim">all below 0.01</span>'
    return " ".join(f'<span class="ew">{html.escape(n)} <b>{w:.2f}</b></span>' for w, n in top)


def _row_html(i: int, row: ScanRow, th: Thresholds) -> str:
    name, low = row.lowest_confidence
    text = " ".join([row.name] + row.flags).lower()
    if row.picture is not None:
        src = "data:image/png;base64," + base64.b64encode(row.picture).decode("ascii")
        pic = f'<div class="thumb"><img src="{src}" alt="" loading="lazy" decoding="async"></div>'
    else:
        pic = '<div class="thumb none">no picture</div>'

    def num(v, bad, digits=2, scale=1.0, suffix=""):
        cls = ' class="num bad"' if v is not None and bad(v) else ' class="num"'
        return f'<td{cls} data-v="{_data_v(v)}">{_fmt(v, digits, scale, suffix)}</td>'

    cells = [
        f'<td class="pic">{pic}</td>',
        f'<td class="name" data-v="{html.escape(row.name)}">{html.escape(row.name)}</td>',
        f'<td class="flags" data-v="{len(row.flags)}">{_flags_html(row.flags)}</td>',
        num(row.mhd, lambda v: v > th.mhd),
        num(row.fit_rms, lambda v: v > th.rms),
        num(row.coverage, lambda v: v < th.coverage, 0, 100.0, " %"),
        f'<td class="lm" data-v="{_data_v(low)}">{_confidence_strip(row, th)}</td>',
        f'<td class="expr">{_expression_html(row)}</td>',
        num(row.seconds, lambda v: False, 1),
    ]
    flagged = ' class="flagged"' if row.flags else ""
    return f'<tr data-i="{i}" data-text="{html.escape(text)}"{flagged}>{"".join(cells)}</tr>'


def _details(row: ScanRow) -> dict:
    """What the larger view shows besides the picture (JSON for page.js)."""
    lms = []
    for n in LANDMARK_NAMES:
        p = row.landmarks.get(n)
        ok = isinstance(p, list) and len(p) == 3 and all(
            isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in p)
        lms.append([n, [round(float(c), 3) for c in p] if ok else None, row.confidence.get(n)])
    expr = sorted(([n, round(w, 3)] for n, w in row.expression.items() if w >= 0.005), key=lambda e: -e[1])
    return {"name": row.name, "units": row.units, "mhd": row.mhd, "rms": row.fit_rms, "coverage": row.coverage,
            "seconds": row.seconds, "flags": row.flags, "notes": row.notes, "source": row.picture_source,
            "landmarks": lms, "expression": expr}


def _histograms(report: BatchReport, th: Thresholds) -> str:
    from ..render import histogram_png

    rows = report.rows

    def values(get):
        return np.array([np.nan if get(r) is None else get(r) for r in rows], dtype=np.float64)

    specs = [
        (values(lambda r: r.mhd), "MHD [mm]", "modified Hausdorff distance", [(th.mhd, "implausible")]),
        (values(lambda r: r.fit_rms), "fit RMS [mm]", "RMS of the model fit", [(th.rms, "implausible")]),
        (values(lambda r: None if r.coverage is None else 100 * r.coverage), "coverage [%]",
         "template with scan under it", [(100 * th.coverage, "flagged below")]),
        (values(lambda r: r.lowest_confidence[1]), "confidence", "least confident landmark", [(th.confidence, "flagged below")]),
    ]
    out = []
    for v, xlabel, title, marks in specs:
        finite = v[np.isfinite(v)]
        note = ""
        if xlabel in ("MHD [mm]", "fit RMS [mm]") and len(finite):
            # a few wild results must not squash the rest into one bar: the tail goes into the last bin
            upper = max(1.2 * marks[0][0], float(np.percentile(finite, 99)) * 1.1)
            beyond = int(np.sum(finite > upper))
            if beyond:
                finite = np.minimum(finite, upper)
                note = f" ({beyond} beyond {upper:.1f})"
        png = histogram_png(finite, xlabel=xlabel, title=title + note, thresholds=marks)
        out.append(f'<figure><img src="data:image/png;base64,{base64.b64encode(png).decode("ascii")}" '
                   f'alt="histogram of {html.escape(xlabel)}" width="320" height="190"></figure>')
    return "".join(out)


def _cards(report: BatchReport) -> str:
    n_ok, n_failed = len(report.rows), len(report.failures)
    flagged = sum(1 for r in report.rows if r.flags)
    total = n_ok + n_failed
    items = [("scans", total, ""), ("registered", n_ok, ""), ("failed", n_failed, "bad" if n_failed else ""),
             ("flagged", flagged, "warn" if flagged else ""), ("problems", len(report.problems), "bad" if report.problems else "")]
    out = "".join(f'<div class="card {cls}"><b>{v}</b>{html.escape(k)}</div>' for k, v, cls in items)
    mhd = [r.mhd for r in report.rows]
    cov = [r.coverage for r in report.rows if r.coverage is not None]
    if mhd:
        out += (f'<div class="card"><b>{np.median(mhd):.2f} mm</b>median MHD</div>'
                + (f'<div class="card"><b>{100 * np.median(cov):.0f} %</b>median coverage</div>' if cov else ""))
    return out


def _flag_kinds(report: BatchReport) -> str:
    counts = {}
    for r in report.rows:
        for kind in {f.partition(":")[0] for f in r.flags}:
            counts[kind] = counts.get(kind, 0) + 1
    if not counts:
        return '<p class="dim">No result is flagged.</p>'
    chips = "".join(f'<button type="button" class="kind" data-filter="{html.escape(k)}">{html.escape(k)} <b>{n}</b></button>'
                    for k, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
    return f'<p class="kinds">Flags (scans with each; click to filter): {chips}</p>'


def _failures(report: BatchReport) -> str:
    if not report.failures:
        return '<h2>Failures</h2><p class="dim">No scan failed (no failures.json).</p>'
    rows = "".join(f"<tr><td>{html.escape(f.scan)}</td><td>{html.escape(f.error)}</td></tr>" for f in report.failures)
    n = len(report.failures)
    return (f"<h2>Failures <small>{n} scan{'s' if n != 1 else ''} without a result (failures.json)</small></h2>"
            f'<table class="plain"><thead><tr><th>scan</th><th>error</th></tr></thead><tbody>{rows}</tbody></table>')


def _problems(report: BatchReport) -> str:
    if not report.problems:
        return ""
    rows = "".join(f"<tr><td>{html.escape(p.path)}</td><td>{html.escape(p.message)}</td></tr>" for p in report.problems)
    n = len(report.problems)
    return (f"<h2>Problems <small>{n} file{'s' if n != 1 else ''} of the folder the report could not use</small></h2>"
            f'<table class="plain"><thead><tr><th>file</th><th>problem</th></tr></thead><tbody>{rows}</tbody></table>')


def _legend() -> str:
    from ..render import DISTANCE_RANGE_MM, distance_colours

    stops = distance_colours(np.linspace(0.0, DISTANCE_RANGE_MM, 12))
    css = ", ".join("#%02x%02x%02x" % tuple(int(round(255 * c)) for c in rgb) for rgb in stops)
    return (f'<span class="legend">template coloured by its distance to the scan: 0 '
            f'<span class="bar" style="background: linear-gradient(to right, {css})"></span> '
            f'{DISTANCE_RANGE_MM:g} mm or more</span>')


def render_page(report: BatchReport, title: str | None = None) -> str:
    """The report's HTML (a str): summary, histograms, the table (worst first), failures, problems."""
    import datetime

    from .._core import __version__

    th = Thresholds()
    title = title or f"facecorr report: {report.root.resolve().name}"
    when = datetime.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    meta = (f"{html.escape(str(report.root.resolve()))} · {len(report.rows)} results · "
            f"facecorr {html.escape(__version__)} · {html.escape(when)}")
    details = json.dumps([_details(r) for r in report.rows], separators=(",", ":"), allow_nan=False)
    parts = {
        "title": html.escape(title),
        "meta": meta,
        "css": _asset("page.css"),
        "js": _asset("page.js"),
        "cards": _cards(report),
        "flag_kinds": _flag_kinds(report),
        "histograms": _histograms(report, th) if report.rows else "",
        "legend": _legend(),
        "rows": "".join(_row_html(i, r, th) for i, r in enumerate(report.rows)),
        "n_rows": str(len(report.rows)),
        "failures": _failures(report),
        "problems": _problems(report),
        "details": details.replace("</", "<\\/"),  # no "</script>" inside the script element
    }
    # one pass over the template: a scan named "{{rows}}" stays text
    return re.sub(r"\{\{(\w+)\}\}", lambda m: parts[m.group(1)], _asset("page.html"))
