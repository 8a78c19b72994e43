"""`facecorr report`: the per-vertex distances it colours by, the thumbnails `batch --png` writes,
reading a batch folder (bad files are problems, not crashes), the page's content, and the page in a
real headless Chromium (every row rendered, sorting and filtering by real clicks, the larger
picture, a screenshot)."""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from facecorr.geometry.mesh import Mesh
from facecorr.geometry.spatial import closest_point_on_triangles
from facecorr.names import LANDMARK_NAMES
from facecorr.pipeline.correspond import DISTANCE_STEP_MM, decode_distances, encode_distances

from headless_chromium import Browser, find_chromium


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "facecorr.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=600)


def _one_error_line(stderr: str) -> str:
    lines = [l for l in stderr.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("facecorr: error:"), stderr
    return lines[0]


# --- the distances -------------------------------------------------------------------------------

def _wavy_grid(n=25, spacing=2.0):
    x, y = np.meshgrid(np.arange(n) * spacing, np.arange(n) * spacing)
    z = 3.0 * np.sin(x / 9.0) * np.cos(y / 7.0)
    v = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    k = np.arange(n * n).reshape(n, n)
    a, b, c, d = k[:-1, :-1].ravel(), k[:-1, 1:].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel()
    return v, np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])


def test_surface_distance_matches_brute_force_and_is_bounded_by_the_vertex_distance():
    """The results' ``surface_distance`` (``Mesh.surface.closest``, k = 1, in Rust) against every
    triangle's closest point (numpy, brute force)."""
    from scipy.spatial import cKDTree

    v, f = _wavy_grid()
    surface = Mesh(v, f).surface

    def surface_distance(points):
        return surface.closest(np.ascontiguousarray(points, dtype=np.float64), 1)[3]

    rng = np.random.default_rng(0)
    # points near the surface (normal offsets up to 1.5 mm) and beyond its border
    near = v[rng.integers(len(v), size=300)] + rng.normal(scale=0.6, size=(300, 3))
    beyond = np.column_stack([rng.uniform(-8, -1, 60), rng.uniform(0, 48, 60), rng.normal(size=60)])
    p = np.concatenate([near, beyond])
    nn_d = cKDTree(v).query(p)[0]
    got = surface_distance(p)
    pairs = np.repeat(np.arange(len(p)), len(f))
    d_all, _ = closest_point_on_triangles(p[pairs], np.tile(v[f], (len(p), 1, 1)))
    truth = d_all.reshape(len(p), len(f)).min(axis=1)
    assert (got >= truth - 1e-9).all() and (got <= nn_d + 1e-12).all()
    exact = np.isclose(got, truth, rtol=0, atol=1e-9)
    assert exact.all(), exact.mean()  # the walk to neighbouring triangles finds every closest point here
    assert exact[300:].all()  # beyond the border: the closest point is on the border's triangles
    # on the surface it is 0 (to rounding) while the nearest vertex is up to ~1.4 mm away
    bary = rng.dirichlet(np.ones(3), size=200)
    tri = rng.integers(len(f), size=200)
    on = np.einsum("kj,kjd->kd", bary, v[f[tri]])
    d_on = surface_distance(on)
    assert np.max(d_on) < 1e-9, np.max(d_on)
    assert np.median(cKDTree(v).query(on)[0]) > 0.3


def test_distances_pack_into_a_byte_each_in_the_scans_units():
    d = np.array([0.0, 0.011, 0.5, 1.234, 5.1, 40.0, np.nan])
    packed = encode_distances(d, to_mm=10.0)  # a scan in cm
    assert packed["encoding"] == "uint8-base64" and packed["step"] == pytest.approx(DISTANCE_STEP_MM / 10)
    back = decode_distances(json.loads(json.dumps(packed))) * 10.0
    np.testing.assert_allclose(back[:5], d[:5], atol=DISTANCE_STEP_MM / 2 + 1e-12)
    assert back[5] == back[6] == pytest.approx(255 * DISTANCE_STEP_MM)  # saturated: far, or unknown
    for bad in (None, [], {"encoding": "float"}, {"encoding": "uint8-base64", "step": 0, "data": ""},
                {"encoding": "uint8-base64", "step": 0.02, "data": "not base64!"}):
        with pytest.raises(ValueError):
            decode_distances(bad)


# --- the thumbnail -------------------------------------------------------------------------------

def _png(data: bytes):
    from PIL import Image

    im = Image.open(io.BytesIO(data))
    return im, np.asarray(im.convert("RGB")).astype(int)


def test_thumbnail_colours_the_template_by_distance_and_draws_the_landmarks(t, tmp_path):
    from facecorr.render import DISTANCE_RANGE_MM, THUMBNAIL_PANEL, is_thumbnail_png, thumbnail_png

    v = np.asarray(t.vertices, dtype=np.float64)
    far_side = v[:, 0] > np.median(v[:, 0])  # the template's +x half: 5 mm off, the rest on the scan
    dist = np.where(far_side, 2 * DISTANCE_RANGE_MM, 0.0)
    lms = v[np.asarray(t.landmark_ids)]
    data = thumbnail_png(v, t.faces, dist, t, landmarks=lms)
    im, rgb = _png(data)
    w, h = THUMBNAIL_PANEL
    assert im.size == (2 * w, h) and im.mode == "P" and len(data) < 40_000
    (tmp_path / "t.png").write_bytes(data)
    assert is_thumbnail_png(tmp_path / "t.png")
    (tmp_path / "other.png").write_bytes(_plain_png())
    assert not is_thumbnail_png(tmp_path / "other.png") and not is_thumbnail_png(tmp_path / "missing.png")
    right = rgb[:, w:]
    red = (right[..., 0] > right[..., 2] + 60)
    blue = (right[..., 2] > right[..., 0] + 60)
    # +x is to the right in the front view: red on the right half of the panel, blue on the left
    assert red[:, w // 2 + 10:].sum() > 20 * red[:, : w // 2 - 10].sum() + 500
    assert blue[:, : w // 2 - 10].sum() > 20 * blue[:, w // 2 + 10:].sum() + 500
    left = rgb[:, :w]
    dots = (left[..., 0] > 200) & (left[..., 1] < 60) & (left[..., 2] < 60)
    assert dots.sum() >= 8 * 15, dots.sum()  # 8 dots of ~35 pixels
    skin = (np.abs(left - np.array([217, 199, 184])).max(axis=2) < 40)
    assert skin.sum() > 0.2 * w * h
    # no distances: the template in grey, no distance colour
    _, grey = _png(thumbnail_png(v, t.faces, None, t))
    g = grey[:, w:]
    assert (np.abs(g[..., 0] - g[..., 2]) < 45).all()


def _plain_png() -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGB", (8, 8), "white").save(buf, format="PNG")
    return buf.getvalue()


# --- a small batch -------------------------------------------------------------------------------

N_REAL = 2


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """A real `facecorr batch --png` on two synthetic scans and a broken one, then made into a
    folder with every case: copies of the results with other numbers (some flagged, one in a
    sub-folder, one without its PNG, one with a stale PNG), an unreadable JSON, a JSON that is
    not a result. Returns (folder, expected rows {name: (mhd, n_flags)})."""
    from facecorr.synth import generate_scan

    root = tmp_path_factory.mktemp("report")
    src = root / "in"
    src.mkdir()
    for k, (subject, expr, level) in enumerate([(1, "NE", 0), (2, "HA", 4)][:N_REAL]):
        rec = generate_scan(root / "gen", subject=subject, expression=expr, level=level, seed=11)
        shutil.copy(rec["scan"], src / f"real{k}.ply")
    (src / "broken.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\n")
    out = root / "out"
    r = run_cli("batch", src, out, "--workers", "2", "--png")
    assert r.returncode == 2 and f"{N_REAL} registered" in r.stdout and "1 failed" in r.stdout, (r.stdout, r.stderr)
    expected = {}
    for k in range(N_REAL):
        d = json.loads((out / f"real{k}.json").read_text())
        expected[f"real{k}"] = (d["mhd"], len(d["flags"]))
    base = json.loads((out / "real0.json").read_text())
    edits = {  # name: (mhd, coverage, flags)
        "copy_far": (7.5, 0.55, ["low_coverage:55% of the template has scan under it", "implausible_fit:mhd_7.5mm"]),
        "copy_flagged": (0.9, 0.91, ["low_confidence:nose_tip"]),
        "sub/copy_good": (0.5, 0.97, []),
        "copy_no_png": (2.5, 0.88, []),
        "copy_stale_png": (1.5, 0.90, []),
    }
    for name, (mhd, cov, flags) in edits.items():
        dst = out / name
        dst.parent.mkdir(exist_ok=True)
        shutil.copy(out / "real0.ply", dst.with_suffix(".ply"))
        if name == "copy_stale_png":  # a picture older than its result: an earlier run's
            shutil.copy(out / "real1.png", dst.with_suffix(".png"))
            os.utime(dst.with_suffix(".png"), (time.time() - 3600,) * 2)
        (dst.with_suffix(".json")).write_text(json.dumps({**base, "mhd": mhd, "coverage": cov, "flags": flags}))
        if name not in ("copy_no_png", "copy_stale_png"):
            shutil.copy(out / "real0.png", dst.with_suffix(".png"))
        expected[name] = (mhd, len(flags))
    (out / "garbage.json").write_text('{"units": "mm", "landmarks_regis')
    shutil.copy(out / "real0.ply", out / "garbage.ply")
    (out / "notes.json").write_text(json.dumps({"comment": "not a result"}))
    return out, expected


def test_batch_png_is_the_thumbnail_and_the_json_has_distances_and_fit_rms(batch, t):
    from facecorr.render import is_thumbnail_png

    out, _ = batch
    for k in range(N_REAL):
        png = out / f"real{k}.png"
        assert is_thumbnail_png(png) and png.stat().st_size < 40_000
        data = json.loads((out / f"real{k}.json").read_text())
        d = decode_distances(data["surface_distance"])
        assert d.shape == (len(t.vertices),)
        # to the surface, never farther than to the nearest vertex (the MHD's terms), and ~0 where
        # the template lies on the scan
        assert d.mean() <= data["mhd"] + DISTANCE_STEP_MM / 2 and np.median(d) < 0.3, (d.mean(), data["mhd"])
        assert 0 < data["fit_rms"] < 1.5


def _rows_in_page(page: str) -> list:
    return re.findall(r'<td class="name" data-v="([^"]*)">', page)


def test_report_reads_the_folder_worst_first_with_failures_and_problems(batch, tmp_path):
    from facecorr.report import build_report

    out, expected = batch
    html_path = tmp_path / "r.html"
    rep = build_report(out, html_path, workers=1, progress=False)
    names = [r.name for r in rep.rows]
    assert sorted(names) == sorted(expected)
    want = sorted(expected, key=lambda n: (-expected[n][1], -expected[n][0], n))
    assert names == want
    sources = {r.name: r.picture_source for r in rep.rows}
    assert sources["copy_no_png"] == sources["copy_stale_png"] == "rendered"
    assert all(sources[n] == "batch" for n in expected if n not in ("copy_no_png", "copy_stale_png"))
    assert [f.scan.endswith("broken.ply") for f in rep.failures] == [True]
    problems = {p.path: p.message for p in rep.problems}
    assert set(problems) == {"garbage.json", "notes.json"}, problems
    assert problems["garbage.json"].startswith("not JSON") and "not a result" in problems["notes.json"]
    page = html_path.read_text()
    assert _rows_in_page(page) == want  # the table is written worst first: readable without JavaScript
    assert "broken PLY file" in page and "garbage.json" in page
    # self-contained: every picture inlined, nothing fetched from elsewhere
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)|url\(\s*["']?https?:|@import|<link\b""", page, re.I)
    srcs = re.findall(r'<img[^>]*\ssrc="([^"]*)"', page)
    assert len(srcs) == len(expected) + 4 and all(s.startswith("data:image/png;base64,") for s in srcs)


def test_report_cli_refuses_bad_folders_and_outputs_in_one_line(tmp_path, batch, capsys):
    from facecorr.cli import main

    out, expected = batch
    (tmp_path / "empty").mkdir()
    (tmp_path / "d.html").mkdir()
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "a.json").write_text("{not json")
    for args, what in [((tmp_path / "missing", "-o", tmp_path / "r.html"), "not a folder"),
                       ((tmp_path / "empty", "-o", tmp_path / "r.html"), "no results"),
                       ((tmp_path / "junk", "-o", tmp_path / "r.html"), "a.json"),
                       ((out, "-o", tmp_path / "r.txt"), "name it .html"),
                       ((out, "-o", tmp_path / "d.html"), "is a folder"),
                       ((out, "-o", tmp_path / "r.html", "--workers", "0"), "--workers")]:
        rc = main(["report", *map(str, args)])
        err = capsys.readouterr().err
        assert rc == 2, (args, err)
        line = _one_error_line(err)
        assert what in line and "Traceback" not in err, (what, line)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.html", "empty", "junk"]
    assert main(["report", str(out), "-o", str(tmp_path / "ok.html"), "--workers", "1"]) == 0
    msg = capsys.readouterr().out
    assert f"{len(expected)} results" in msg and "1 failures, 2 problems; 2 thumbnails rendered" in msg, msg
    # the command itself runs as a program too
    r = run_cli("report", out, "-o", tmp_path / "ok2.html", "--title", "QC <run 1>")
    assert r.returncode == 0 and (tmp_path / "ok2.html").stat().st_size > 50_000, r.stderr
    assert "<title>QC &lt;run 1&gt;</title>" in (tmp_path / "ok2.html").read_text()


# --- in a real browser ---------------------------------------------------------------------------

#: The screenshot the Chromium test leaves for a person to look at (also in the test's tmp folder).
SCREENSHOT_ENV = "FACECORR_REPORT_SCREENSHOT"


@pytest.fixture(scope="module")
def chromium():
    path = find_chromium()
    if path is None:
        pytest.skip("headless Chromium not installed: `apt-get install chromium` (Debian) runs the browser test")
    return path


def test_report_in_headless_chromium(batch, chromium, tmp_path):
    from facecorr.report import build_report

    out, expected = batch
    page_path = tmp_path / "report.html"
    build_report(out, page_path, workers=1, progress=False)
    col = {"name": 2, "flags": 3, "mhd": 4, "coverage": 6}  # 1-based columns of the table

    def column(page, c):
        return page.evaluate(f"Array.from(document.querySelectorAll('#results tbody tr'))"
                             f".filter(tr => !tr.hidden).map(tr => tr.cells[{c - 1}].dataset.v)")

    with Browser(chromium) as b:
        page = b.new_page(1400, 2400)
        seconds = page.navigate(page_path.as_uri(), ready="document.documentElement.dataset.ready === '1'")
        assert seconds < 10, seconds
        # every row rendered, each thumbnail decoded (the page is tall enough for lazy images);
        # the browser decodes them after the page's script has run: on a loaded machine (the
        # whole suite on 2 cores) a moment later, so wait for them, up to 10 s
        decoded = "Array.from(document.querySelectorAll('#results tbody tr .thumb img')).every(i => i.naturalWidth > 0)"
        deadline = time.monotonic() + 10.0
        while not page.evaluate(decoded) and time.monotonic() < deadline:
            time.sleep(0.05)
        rows = page.evaluate("Array.from(document.querySelectorAll('#results tbody tr')).map(tr => "
                             "[tr.cells[1].dataset.v, tr.getBoundingClientRect().height, "
                             "(tr.querySelector('.thumb img') || {}).naturalWidth || 0])")
        assert sorted(r[0] for r in rows) == sorted(expected)
        assert all(r[1] > 50 and r[2] == 400 for r in rows), rows
        worst_first = [r[0] for r in rows]
        # sorting by real clicks on the headers: MHD largest first, then smallest first
        page.click(f"#results thead th:nth-child({col['mhd']})")
        mhd = [float(v) for v in column(page, col["mhd"])]
        assert mhd == sorted(mhd, reverse=True) and len(mhd) == len(expected)
        page.click(f"#results thead th:nth-child({col['mhd']})")
        assert [float(v) for v in column(page, col["mhd"])] == sorted(mhd)
        assert page.evaluate(f"document.querySelector('#results thead th:nth-child({col['mhd']})').className") == "sorted asc"
        page.click(f"#results thead th:nth-child({col['coverage']})")  # worst (lowest) first
        cov = [float(v) for v in column(page, col["coverage"])]
        assert cov == sorted(cov) and cov[0] == pytest.approx(0.55)
        page.click(f"#results thead th:nth-child({col['name']})")
        assert column(page, col["name"]) == sorted(expected)
        page.click(f"#results thead th:nth-child({col['flags']})")  # back to the page's order
        assert column(page, col["name"]) == worst_first
        # filtering: flagged only, then a text
        page.click("#flagged-only")
        flagged = sorted(n for n, (_, k) in expected.items() if k)
        assert sorted(column(page, col["name"])) == flagged
        page.click("#flagged-only")
        page.type_text("#filter", "low_coverage")
        assert column(page, col["name"]) == ["copy_far"]
        assert page.evaluate("document.getElementById('shown').textContent") == f"1 of {len(expected)} shown"
        page.evaluate("(() => { const f = document.getElementById('filter'); f.value = '';"
                      " f.dispatchEvent(new Event('input')); })()")
        assert len(column(page, col["name"])) == len(expected)
        # a row opens the larger picture (the same image), Esc closes it
        page.click("#results tbody tr:nth-child(1) td.name")
        assert page.evaluate("document.getElementById('viewer').hidden") is False
        assert page.evaluate("document.getElementById('viewer-title').textContent") == worst_first[0]
        assert page.evaluate("document.getElementById('viewer-img').decode().then(() => "
                             "document.getElementById('viewer-img').naturalWidth)") == 400
        assert page.evaluate("document.getElementById('viewer-img').src === "
                             "document.querySelector('#results tbody tr .thumb img').src")
        page.click("#next")
        assert page.evaluate("document.getElementById('viewer-title').textContent") == worst_first[1]
        viewer_png = page.screenshot(tmp_path / "viewer.png")
        page.press("Escape", key_code=27)
        assert page.evaluate("document.getElementById('viewer').hidden") is True
        page.resize(1400, 1000)
        page.evaluate("window.scrollTo(0, 0)")
        shot = page.screenshot(tmp_path / "report.png", full_page=True)
    im, rgb = _png(shot)
    assert im.format == "PNG" and im.size[0] == 1400 and im.size[1] > 1000
    assert (rgb.std(axis=(0, 1)) > 20).all()  # not a blank page
    assert _png(viewer_png)[0].size == (1400, 2400)
    if os.environ.get(SCREENSHOT_ENV):
        shutil.copy(tmp_path / "report.png", os.environ[SCREENSHOT_ENV])
        shutil.copy(tmp_path / "viewer.png", Path(os.environ[SCREENSHOT_ENV]).with_name("viewer.png"))
