"""The performance history: every run's records in an embedded SQLite database.

Every ``gibench run``, ``check``, ``baseline`` and ``sweep`` stores one row per
result record (commit, date, machine, versions, suite, scene, algorithm,
label, parameters, transport, metrics, times) so that ``gibench history``
and the dashboard (:mod:`reports.dashboard`) can show each metric and time
across commits, as asv and Blender's benchmark pages do.  pytest-benchmark
JSON files (``.benchmarks/**/*.json``) are ingested into a second table.

Where it lives: ``reports/out/history.sqlite`` by default (``--history`` or
``$GIBENCH_HISTORY`` override it; a command given another ``--results`` file
uses ``history.sqlite`` beside it, so runs into a scratch directory stay out
of the main history).  ``reports/out/`` is git-ignored: the
database is a per-machine record (timings from different machines are not
comparable) and is *not* committed; the committed accuracy record is the CI
baseline (``suites/baselines/ci.json``).

Durability: the database runs in WAL mode; each record is inserted in its own
transaction (``with con:``), so a run killed at any point leaves the database
consistent with every record completed before the kill, and readers never see
a half-written record.  The schema carries a version (``PRAGMA
user_version``); opening a database of a newer version raises
:class:`HistoryError` rather than guessing.
"""

from __future__ import annotations

import json
import math
import os
import re
import sqlite3
from pathlib import Path

from core.errors import StoreError
from core.provenance import REPO_ROOT
from core.records import Record

__all__ = ["SCHEMA_VERSION", "DEFAULT_DB", "HistoryError", "default_db", "connect",
           "add_record", "add_records", "ingest_benchmarks", "query", "benchmark_rows",
           "format_table"]

SCHEMA_VERSION = 1
DEFAULT_DB = REPO_ROOT / "reports" / "out" / "history.sqlite"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS results (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    run_id TEXT NOT NULL,
    command TEXT,
    suite TEXT,
    commit_id TEXT,
    created TEXT,
    machine TEXT,       -- JSON
    versions TEXT,      -- JSON
    scene TEXT,
    algorithm TEXT,
    label TEXT,
    transport TEXT,
    params TEXT,        -- JSON
    metrics TEXT,       -- JSON (scalar metrics; ztest flattened to ztest_passed / ztest_fraction)
    times TEXT,         -- JSON (own_median_s, mitsuba_median_s, ratio, ...)
    error TEXT,
    kind TEXT,
    UNIQUE (run_id, scene, algorithm, label, transport, params, kind)
);
CREATE INDEX IF NOT EXISTS results_scene ON results (scene, algorithm);
CREATE TABLE IF NOT EXISTS benchmarks (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    source TEXT NOT NULL,      -- the JSON file it came from
    commit_id TEXT,
    created TEXT,
    machine TEXT,
    name TEXT NOT NULL,
    grp TEXT,
    median_s REAL,
    mean_s REAL,
    stddev_s REAL,
    rounds INTEGER,
    UNIQUE (source, name, created)
);
"""



class HistoryError(StoreError):
    """A history database that cannot be used (newer schema, not a database)."""



def default_db() -> Path:
    env = os.environ.get("GIBENCH_HISTORY")
    return Path(env) if env else DEFAULT_DB


def connect(path=None) -> sqlite3.Connection:
    """Open (creating if needed) the history database at ``path`` in WAL mode."""
    path = Path(path) if path is not None else default_db()
    if path.is_dir():
        raise HistoryError(f"{path}: is a directory, not a history database file")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        con = sqlite3.connect(path, timeout=30.0)
    except (OSError, sqlite3.Error) as exc:
        raise HistoryError(f"{path}: cannot open the history database ({exc})") from None
    try:
        con.execute("PRAGMA journal_mode=WAL")
        con.execute("PRAGMA synchronous=NORMAL")
        version = con.execute("PRAGMA user_version").fetchone()[0]
    except sqlite3.DatabaseError as exc:
        con.close()
        raise HistoryError(f"{path}: not a usable SQLite database ({exc})") from None
    if version > SCHEMA_VERSION:
        con.close()
        raise HistoryError(f"{path}: schema version {version} is newer than this gibench's "
                           f"{SCHEMA_VERSION}; use a newer gibench or another --history file")
    try:
        with con:
            con.executescript(_SCHEMA)
            con.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
        _check_tables(con, path)
    except (sqlite3.Error, HistoryError) as exc:
        con.close()
        if isinstance(exc, HistoryError):
            raise
        raise HistoryError(f"{path}: not a usable history database ({exc})") from None
    return con


def _check_tables(con: sqlite3.Connection, path: Path) -> None:
    """Refuse a database whose ``results``/``benchmarks`` tables are not gibench's
    (another program's table of the same name): every column of the schema must be there."""
    for table in ("results", "benchmarks"):
        have = {row[1] for row in con.execute(f"PRAGMA table_info({table})")}
        want = set(re.findall(r"^\s+(\w+) (?:INTEGER|TEXT|REAL)",
                              _SCHEMA.split(f"CREATE TABLE IF NOT EXISTS {table} (")[1].split(");")[0],
                              re.M))
        missing = sorted(want - have)
        if missing:
            raise HistoryError(f"{path}: its '{table}' table is not gibench's (no column "
                               f"{', '.join(missing)}); use another --history file")


def _finite(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None if math.isnan(x) else ("inf" if x > 0 else "-inf")
    return x


def _scalar_metrics(metrics: dict | None) -> dict:
    out = {}
    for k, v in (metrics or {}).items():
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            out[k] = _finite(float(v))
    z = (metrics or {}).get("ztest")
    if isinstance(z, dict):
        out["ztest_passed"] = 1.0 if z.get("passed") else 0.0
        if isinstance(z.get("fraction"), (int, float)):
            out["ztest_fraction"] = float(z["fraction"])
    return out


def _times(t: dict | None) -> dict:
    return {k: _finite(v) for k, v in (t or {}).items()
            if isinstance(v, (int, float, str)) and not isinstance(v, bool) and k != "own_times_s"}


def _dumps(x) -> str:
    return json.dumps(x, sort_keys=True, default=str)


def add_record(con: sqlite3.Connection, record: Record, *, command: str = "run") -> None:
    """Insert one result record in its own transaction (a duplicate is ignored)."""
    with con:
        con.execute(
            "INSERT OR IGNORE INTO results (run_id, command, suite, commit_id, created, machine, "
            "versions, scene, algorithm, label, transport, params, metrics, times, error, kind) "
            "VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
            (record.run_id, command, record.suite, record.commit,
             record.created, _dumps(record.machine), _dumps(record.versions),
             record.scene, record.algorithm, record.label,
             record.transport, _dumps(record.params),
             _dumps(_scalar_metrics(record.metrics)), _dumps(_times(record.time)),
             record.error, record.kind))


def add_records(con, records, *, command: str = "run") -> int:
    n = 0
    for r in records:
        if r.kind in ("case", "ladder"):
            add_record(con, r, command=command)
            n += 1
    return n


def ingest_benchmarks(con: sqlite3.Connection, root) -> int:
    """Ingest every pytest-benchmark JSON file under ``root`` (a file, a directory such
    as ``.benchmarks/`` from ``--benchmark-autosave``, or a glob such as
    ``reports/out/bench*.json`` from ``--benchmark-json``); returns how many
    benchmark rows were new (a file rewritten by a later run adds its rows again:
    rows are keyed by file, benchmark and the run's date).

    Any ``benchmarks/bench_*.py`` that pytest-benchmark saved is accepted: the
    file's ``benchmarks`` list gives name, group and stats; ``commit_info`` and
    ``datetime`` give commit and date.  Files that are not pytest-benchmark
    JSON are skipped.
    """
    import glob

    root = Path(root)
    if root.is_file():
        files = [root]
    elif root.is_dir():
        files = sorted(root.rglob("*.json"))
    else:                                   # a glob pattern, e.g. reports/out/bench*.json
        files = sorted(Path(p) for p in glob.glob(str(root)) if Path(p).is_file())
    new = 0
    for f in files:
        try:
            data = json.loads(f.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(data, dict) or not isinstance(data.get("benchmarks"), list):
            continue
        commit = (data.get("commit_info") or {}).get("id")
        if commit and (data.get("commit_info") or {}).get("dirty"):
            commit = f"{commit[:12]}+dirty"
        elif commit:
            commit = commit[:12]
        created = data.get("datetime")
        mach = _dumps({k: (data.get("machine_info") or {}).get(k)
                       for k in ("node", "cpu", "machine", "system")})
        with con:
            for b in data["benchmarks"]:
                st = b.get("stats") or {}
                cur = con.execute(
                    "INSERT OR IGNORE INTO benchmarks (source, commit_id, created, machine, name, grp, "
                    "median_s, mean_s, stddev_s, rounds) VALUES (?,?,?,?,?,?,?,?,?,?)",
                    (str(f.resolve()), commit, created, mach, b.get("fullname") or b.get("name"),
                     b.get("group"), st.get("median"), st.get("mean"), st.get("stddev"),
                     st.get("rounds")))
                new += cur.rowcount
    return new


def query(con, *, metric: str | None = None, scene: str | None = None,
          algorithm: str | None = None, limit: int | None = None) -> list[dict]:
    """Result rows (oldest first), each with ``metrics``/``times``/``params`` decoded;
    ``metric`` keeps rows that have it; ``scene``/``algorithm`` filter by substring."""
    sql = ("SELECT id, run_id, command, suite, commit_id, created, machine, scene, algorithm, label, "
           "transport, params, metrics, times, error, kind FROM results WHERE 1=1")
    args: list = []
    if scene:
        sql += " AND scene LIKE ?"
        args.append(f"%{scene}%")
    if algorithm:
        sql += " AND algorithm LIKE ?"
        args.append(f"%{algorithm}%")
    sql += " ORDER BY created, id"
    rows = []
    for r in con.execute(sql, args):
        row = dict(zip(("id", "run_id", "command", "suite", "commit", "created", "machine", "scene",
                        "algorithm", "label", "transport", "params", "metrics", "times", "error",
                        "kind"), r))
        for k in ("machine", "params", "metrics", "times"):
            row[k] = json.loads(row[k]) if row[k] else {}
        if metric and metric not in row["metrics"] and metric not in row["times"]:
            continue
        rows.append(row)
    return rows[-limit:] if limit else rows


def benchmark_rows(con) -> list[dict]:
    cols = ("source", "commit", "created", "machine", "name", "group", "median_s", "mean_s",
            "stddev_s", "rounds")
    return [dict(zip(cols, r)) for r in con.execute(
        "SELECT source, commit_id, created, machine, name, grp, median_s, mean_s, stddev_s, rounds "
        "FROM benchmarks ORDER BY created, id")]


def format_table(rows: list[dict], metric: str = "relmse") -> str:
    """A plain-text table: one line per row, the metric and own / Mitsuba times."""
    head = f"{'date':<20} {'commit':<18} {'scene':<28} {'algorithm / label':<36} {metric:>11} {'own ms':>9} {'ratio':>7}"
    lines = [head, "-" * len(head)]
    for r in rows:
        v = r["metrics"].get(metric, r["times"].get(metric))
        t = r["times"].get("own_median_s")
        ratio = r["times"].get("ratio")
        lines.append(f"{str(r['created'])[:19]:<20} {str(r['commit'])[:18]:<18} "
                     f"{str(r['scene'])[:28]:<28} {(str(r['algorithm']) + ' / ' + str(r['label']))[:36]:<36} "
                     f"{(f'{v:.4g}' if isinstance(v, (int, float)) else str(v)):>11} "
                     f"{(f'{t * 1e3:.1f}' if isinstance(t, (int, float)) else '—'):>9} "
                     f"{(f'{ratio:.2f}' if isinstance(ratio, (int, float)) else '—'):>7}")
    return "\n".join(lines)
