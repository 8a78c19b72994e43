"""`--quiet` and `--log FILE` of the long commands (batch, synth, eval): no bar and no summary,
only errors; one JSON line per scan, appended as each scan ends; a log that cannot be written is
refused before any work. (The Dask batch's log: tests/test_batch_dask.py.)"""

import json
import shutil
import subprocess
import sys

import pytest


def _lines(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "facecorr.cli", *map(str, args)], capture_output=True, text=True)


@pytest.fixture(scope="module")
def db(tmp_path_factory):
    """A synthetic database of 2 neutral scans (F0001 train, M0001 test), made with --quiet --log."""
    d = tmp_path_factory.mktemp("db")
    log = d.parent / f"{d.name}_synth.log"
    r = _cli("synth", d, "--subjects", "2", "--expressions", "NE", "--workers", "1", "--quiet", "--log", log)
    assert r.returncode == 0 and r.stdout == "" and r.stderr == "", r.stderr
    return d, log


def test_synth_logs_each_scan_quietly(db):
    d, log = db
    lines = _lines(log)
    index = json.loads((d / "index.json").read_text())["scans"]
    assert [ln["scan"] for ln in lines] == [r["scan"] for r in index]
    for ln in lines:
        assert ln["status"] == "ok" and ln["seconds"] > 0 and ln["vertices"] > 1000 and ln["faces"] > 1000
        assert (d / ln["scan"]).is_file() and ln["time"].endswith("+00:00")
    # without --quiet there is a bar and a summary
    r = _cli("synth", d.parent / "db_loud", "--subjects", "1", "--expressions", "NE", "--workers", "1")
    assert r.returncode == 0 and "synth" in r.stderr and "1 scans in" in r.stderr, r.stderr


def test_eval_registration_quiet_log(db, tmp_path):
    d, _ = db
    log = tmp_path / "eval.log"
    r = _cli("eval", "registration", d, "--out", tmp_path / "rep", "--workers", "1", "--quiet", "--log", log)
    assert r.returncode == 0, r.stderr
    assert r.stdout == "" and r.stderr == "", (r.stdout, r.stderr)
    (line,) = _lines(log)
    rows = json.loads((tmp_path / "rep" / "registration_per_scan.json").read_text())
    assert line["scan"] == rows[0]["scan"] and line["status"] == "ok"
    assert line["mhd"] == rows[0]["mhd"] and line["timings_s"] == rows[0]["timings_s"]
    assert set(line["landmark_errors"]) == set(rows[0]["landmark_errors"])


def test_eval_landmarks_log_appends_and_shows_a_bar(db, tmp_path):
    d, _ = db
    log = tmp_path / "lm.log"
    log.write_text(json.dumps({"scan": "earlier run"}) + "\n")
    r = _cli("eval", "landmarks", d, "--out", tmp_path / "rep", "--workers", "1", "--no-png", "--log", log)
    assert r.returncode == 0, r.stderr
    assert "eval landmarks" in r.stderr and r.stdout.strip(), (r.stdout, r.stderr)  # the bar, the table
    first, line = _lines(log)
    assert first == {"scan": "earlier run"}
    assert line["status"] == "ok" and set(line["errors"]) == set(line["confidence"]) and len(line["errors"]) == 8


def test_batch_quiet_log_and_a_log_that_cannot_be_written(tmp_path, capsys, monkeypatch):
    import importlib

    import numpy as np

    from facecorr.cli import main
    from facecorr.synth import generate_scan

    from test_cli import _fake_correspond

    monkeypatch.setattr(importlib.import_module("facecorr.pipeline.correspond"), "correspond", _fake_correspond)
    rec = generate_scan(tmp_path / "gen", subject=1, expression="NE", level=0, seed=5)
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(rec["scan"], src / "good.ply")
    (src / "broken.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\n")
    out, log = tmp_path / "out", tmp_path / "logs" / "batch.log"
    rc = main(["batch", str(src), str(out), "--workers", "1", "--quiet", "--log", str(log)])
    cap = capsys.readouterr()
    assert rc == 2 and cap.out == "", cap.out
    assert cap.err.rstrip("\n").splitlines() == [f"  {src / 'broken.ply'}: " + json.loads(
        (out / "failures.json").read_text())[0]["error"]], cap.err
    by_scan = {ln["scan"]: ln for ln in _lines(log)}
    good, bad = by_scan[str(src / "good.ply")], by_scan[str(src / "broken.ply")]
    res = json.loads((out / "good.json").read_text())
    assert good["status"] == "ok" and good["mhd"] == res["mhd"] and good["flags"] == res["flags"]
    assert good["coverage"] == res["coverage"] and good["timings_s"] == res["timings_s"] and good["seconds"] >= 0
    assert bad["status"] == "failed" and bad["error"].startswith("bad input:") and "mhd" not in bad
    assert np.isfinite(good["mhd"])
    # a log that is a folder: refused first, nothing done
    rc = main(["batch", str(src), str(tmp_path / "out2"), "--workers", "1", "--log", str(tmp_path)])
    cap = capsys.readouterr()
    assert rc == 2 and "--log" in cap.err and "is a folder" in cap.err and not (tmp_path / "out2").exists(), cap.err
