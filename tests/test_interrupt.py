"""Killing a run (SIGKILL, SIGINT) mid-way leaves the results file, the SQLite history
and the reference store consistent, and a rerun completes.

The run renders its references into a fresh store (few spp, small scenes), so the
kill can land in a reference render, an own render or a store write.
"""

import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
import warnings

import pytest

from core.provenance import REPO_ROOT
from reports.results import ResultStore

from _suites import raycast_suite

SCENES = ["vocabulary/defines.xml", "spheres/cyclic_overlap.xml", "spheres/interpenetrating.xml",
          "spheres/coplanar.xml"]
# The CUDA probe (test_executor.py covers the fallback) would add a child process per run.
ENV = dict(os.environ, GIBENCH_REFERENCE_DEVICE="llvm")


def _suite(tmp_path):
    return raycast_suite(tmp_path / "suite.toml", "interrupt", SCENES, spp=4, light_samples=1,
                         reference_spp=8, reference_passes=2)


def _cmd(tmp_path):
    return [sys.executable, "-m", "gibench.cli", "run", str(_suite(tmp_path)),
            "--results", str(tmp_path / "out" / "results.jsonl"),
            "--history", str(tmp_path / "h.sqlite"), "--store", str(tmp_path / "store"),
            "--no-mitsuba-timing", "--no-progress"]


def _start_and_interrupt(tmp_path, sig):
    results = tmp_path / "out" / "results.jsonl"
    before = len(results.read_text().splitlines()) if results.exists() else 0
    proc = subprocess.Popen(_cmd(tmp_path), cwd=REPO_ROOT, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if results.exists() and len(results.read_text().splitlines()) > before:
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be interrupted:\n" + proc.stdout.read()
    time.sleep(0.3)                      # into the next case
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=60)
    return proc.returncode, out


def _as_from_a_terminal():
    """Give the child the default SIGINT disposition, as a shell in a terminal does.  A
    command started in the background by a shell without job control (``cmd &`` in a
    script, as CI runners and batch jobs may start the tests) inherits SIGINT *ignored*,
    and Python then installs no KeyboardInterrupt handler: the signal would be lost by
    design, not by the run."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupt_at_case(tmp_path, sig, case):
    """Start a run and send ``sig`` as soon as its progress line ``[case/N]`` is printed
    (unbuffered output read line by line): cases ``case``..N are still to do."""
    env = dict(ENV, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(_cmd(tmp_path), cwd=REPO_ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, preexec_fn=_as_from_a_terminal)
    seen = []
    for line in proc.stdout:
        seen.append(line)
        if f"[{case}/" in line:
            proc.send_signal(sig)
            break
    assert seen and f"[{case}/" in seen[-1], "the run ended before case %d:\n%s" % (case, "".join(seen))
    rest, _ = proc.communicate(timeout=60)
    return proc.returncode, "".join(seen) + rest


def _assert_consistent(tmp_path, *, complete=False):
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # no malformed line in the results file
        recs = ResultStore(tmp_path / "out" / "results.jsonl").load()
    con = sqlite3.connect(tmp_path / "h.sqlite")
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    rows = set(con.execute("SELECT run_id, scene FROM results"))
    # The database receives each record after the results file: never more than it.
    assert rows <= {(r.run_id, r.scene) for r in recs}
    # Every reference entry present is complete and valid (partial renders stay in
    # hidden .tmp-* directories the store ignores).
    from references.reference import _load_entry

    for d in (tmp_path / "store").glob("[0-9a-f]*"):
        key = json.loads((d / "manifest.json").read_text())["key"]
        _load_entry(d, key)
    if complete:
        last = recs[-1].run_id
        assert len([r for r in recs if r.run_id == last]) == len(SCENES)
        assert not any(r.error for r in recs if r.run_id == last)
    return recs


@pytest.mark.mitsuba
@pytest.mark.slow
def test_kill_and_interrupt_leave_stores_consistent(tmp_path, mitsuba):
    rc, out = _start_and_interrupt(tmp_path, signal.SIGKILL)
    assert rc == -signal.SIGKILL, out
    n_killed = len(_assert_consistent(tmp_path))
    assert 1 <= n_killed < len(SCENES)

    # The killed run left some references stored, and with them the rest of a run can
    # take less than any fixed pause (own renders of a few ms): the store is emptied,
    # and the signal goes out when the run announces its second case.
    shutil.rmtree(tmp_path / "store")
    rc, out = _interrupt_at_case(tmp_path, signal.SIGINT, 2)
    assert rc == 130 and "interrupted" in out, out
    _assert_consistent(tmp_path)

    done = subprocess.run(_cmd(tmp_path), cwd=REPO_ROOT, env=ENV, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    _assert_consistent(tmp_path, complete=True)
