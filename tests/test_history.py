"""The SQLite history (gibench/history.py), ``gibench history`` and the dashboard page."""

import json
import math
import sqlite3

import pytest

from gibench import cli
from gibench.history import (SCHEMA_VERSION, HistoryError, add_record, benchmark_rows, connect,
                             ingest_benchmarks, query)
from reports.dashboard import render_dashboard, write_dashboard
from core.records import Record


def _rec(run, commit, created, relmse, own, *, scene="spheres/lit_sphere", algo="raycast"):
    return Record.from_json({"run_id": run, "suite": "t", "commit": commit, "created": created,
            "machine": {"host": "h", "cpu": "c"}, "versions": {"numpy": "2"}, "scene": scene,
            "algorithm": algo, "label": "cfg", "transport": "direct", "params": {"spp": 16},
            "metrics": {"relmse": relmse, "psnr": math.inf, "ztest": {"passed": True, "fraction": 1.0},
                        "conventions": {"x": "y"}},
            "time": {"own_median_s": own, "own_times_s": [own], "ratio": 2.0}, "error": None})


def test_schema_wal_roundtrip_and_filters(tmp_path):
    db = tmp_path / "h.sqlite"
    con = connect(db)
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert con.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    add_record(con, _rec("r1", "aaa", "2026-01-01T00:00:00", 1e-3, 0.5))
    add_record(con, _rec("r2", "bbb", "2026-01-02T00:00:00", 2e-3, 0.4))
    add_record(con, _rec("r2", "bbb", "2026-01-02T00:00:00", 2e-3, 0.4))        # duplicate: ignored
    add_record(con, _rec("r2", "bbb", "2026-01-02T00:00:01", 5e-2, 0.1, scene="cornell/box",
                         algo="radiosity"))
    rows = query(con, scene="lit_sphere")
    assert [(r["commit"], r["metrics"]["relmse"]) for r in rows] == [("aaa", 1e-3), ("bbb", 2e-3)]
    assert rows[0]["metrics"]["psnr"] == "inf" and rows[0]["metrics"]["ztest_passed"] == 1.0
    assert "own_times_s" not in rows[0]["times"] and rows[0]["times"]["own_median_s"] == 0.5
    assert [r["scene"] for r in query(con, algorithm="radio")] == ["cornell/box"]
    assert query(con, metric="no_such_metric") == []
    con.close()
    # Reopening keeps everything; a newer schema is refused with a clear message.
    assert len(query(connect(db))) == 3
    raw = sqlite3.connect(db)
    raw.execute(f"PRAGMA user_version={SCHEMA_VERSION + 1}")
    raw.commit()
    raw.close()
    with pytest.raises(HistoryError, match="newer"):
        connect(db)
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not a database" * 100)
    with pytest.raises(HistoryError, match="not a usable SQLite database"):
        connect(junk)


def _bench_json(path, commit, created, median):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({
        "machine_info": {"node": "h", "cpu": {"brand_raw": "c"}},
        "commit_info": {"id": commit * 5, "dirty": False},
        "datetime": created,
        "benchmarks": [{"group": "intersect", "name": "bench_slabs[f32]",
                        "fullname": "benchmarks/bench_intersect.py::bench_slabs[f32]",
                        "stats": {"median": median, "mean": median, "stddev": 0.0, "rounds": 5}},
                       {"group": "raycast", "name": "bench_raycast",
                        "fullname": "benchmarks/bench_raycast.py::bench_raycast",
                        "stats": {"median": 2 * median, "mean": 2 * median, "stddev": 0.0,
                                  "rounds": 3}}]}))


def test_benchmark_ingestion_and_dashboard(tmp_path):
    con = connect(tmp_path / "h.sqlite")
    bench = tmp_path / ".benchmarks" / "Linux-CPython-3.11-64bit"
    _bench_json(bench / "0001_aaaa.json", "aaaa", "2026-01-01T00:00:00", 0.01)
    _bench_json(bench / "0002_bbbb.json", "bbbb", "2026-01-02T00:00:00", 0.02)
    (bench / "notes.json").write_text('{"something": "else"}')             # not pytest-benchmark
    assert ingest_benchmarks(con, tmp_path / ".benchmarks") == 4
    assert ingest_benchmarks(con, tmp_path / ".benchmarks") == 0             # idempotent
    # --benchmark-json rewrites one file per run: a glob picks it up, a rerun adds rows.
    single = tmp_path / "out" / "bench_x.json"
    _bench_json(single, "cccc", "2026-01-03T00:00:00", 0.03)
    assert ingest_benchmarks(con, tmp_path / "out" / "bench*.json") == 2
    _bench_json(single, "dddd", "2026-01-04T00:00:00", 0.04)
    assert ingest_benchmarks(con, tmp_path / "out" / "bench*.json") == 2
    rows = benchmark_rows(con)
    assert {(r["commit"], r["group"], r["median_s"]) for r in rows} >= {
        ("aaaaaaaaaaaa", "intersect", 0.01), ("bbbbbbbbbbbb", "raycast", 0.04)}
    add_record(con, _rec("r1", "aaa", "2026-01-01T00:00:00", 1e-3, 0.5))
    add_record(con, _rec("r2", "bbb", "2026-01-02T00:00:00", 2e-3, 0.4))
    page = render_dashboard(query(con), rows)
    assert page.count("<img class='plot'") == 3                 # one scene, two benchmark groups
    assert len(rows) == 8
    assert "spheres/lit_sphere" in page and "alt='benchmarks intersect'" in page
    empty = render_dashboard([], [])
    assert "No results" in empty and "No benchmark JSON" in empty
    out = write_dashboard(query(con), benchmark_rows(con), tmp_path / "d" / "dashboard.html")
    assert out.read_text().startswith("<!DOCTYPE html>")


def test_history_cli_prints_table(tmp_path, capsys):
    db = tmp_path / "h.sqlite"
    con = connect(db)
    add_record(con, _rec("r1", "aaa111", "2026-01-01T00:00:00", 1.5e-3, 0.5))
    add_record(con, _rec("r2", "bbb222", "2026-01-02T00:00:00", 2.5e-3, 0.25, scene="cornell/box"))
    con.close()
    assert cli.main(["history", "--history", str(db), "--scene", "lit"]) == 0
    out = capsys.readouterr().out
    assert "aaa111" in out and "0.0015" in out and "bbb222" not in out
    assert cli.main(["history", "--history", str(db), "--metric", "own_median_s"]) == 0
    out = capsys.readouterr().out
    assert "bbb222" in out and "0.25" in out
    assert cli.main(["dashboard", "--history", str(db), "--out", str(tmp_path / "d.html"),
                     "--benchmarks", str(tmp_path / "none")]) == 0
    assert (tmp_path / "d.html").is_file()
