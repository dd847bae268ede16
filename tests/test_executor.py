"""Where cases execute: ``--jobs N`` (local processes) and ``--executor dask://HOST:PORT``
(a Dask ``LocalCluster`` here); records flow back to the parent, which alone writes
the results file and the history database."""

import shutil
import sqlite3

import pytest

from gibench import cli
from gibench.executor import ExecutorError, parse_executor
from core.provenance import REPO_ROOT
from reports.results import ResultStore

from _suites import raycast_suite

SCENES = ["spheres/lit_sphere.xml", "spheres/cyclic_overlap.xml"]


def test_parse_executor():
    assert parse_executor(None, 1) == ("serial", None)
    assert parse_executor(None, 3) == ("processes", 3)
    assert parse_executor("dask://10.0.0.2:8786") == ("dask", "tcp://10.0.0.2:8786")
    for bad in ("dask://nohost", "ray://x:1", "dask://:12"):
        with pytest.raises(ExecutorError):
            parse_executor(bad)
    with pytest.raises(ExecutorError, match="positive"):
        parse_executor(None, 0)


def _suite(tmp_path):
    return raycast_suite(tmp_path / "suite.toml", "exec", SCENES, spp=4, light_samples=4)


def _run(tmp_path, name, *extra):
    """One run of the suite against a copy of the repository's reference store under
    ``tmp_path``: the committed entries are read from it, and whatever a run would
    write (a re-render) stays in the copy."""
    store = tmp_path / "store"
    if not store.exists():
        shutil.copytree(REPO_ROOT / "references" / "store", store)
    results = tmp_path / name / "results.jsonl"
    db = tmp_path / name / "h.sqlite"
    rc = cli.main(["run", str(_suite(tmp_path)), "--results", str(results), "--history", str(db),
                   "--store", str(store), "--no-mitsuba-timing", "--no-progress", *extra])
    recs = ResultStore(results).load()
    rows = sqlite3.connect(db).execute("SELECT scene, metrics FROM results").fetchall()
    return rc, recs, rows


@pytest.mark.mitsuba
def test_jobs_and_dask_give_the_serial_results(tmp_path, mitsuba):
    from distributed import LocalCluster

    rc, serial, _ = _run(tmp_path, "serial")
    assert rc == 0
    want = {r.scene: r.metrics["relmse"] for r in serial}
    assert len(want) == len(SCENES)

    rc, recs, rows = _run(tmp_path, "jobs", "--jobs", "2")
    assert rc == 0 and len(rows) == len(SCENES)
    # Deterministic renders: the same metrics whichever process rendered them.
    assert {r.scene: r.metrics["relmse"] for r in recs} == want

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp",
                      dashboard_address=None) as cluster:
        addr = cluster.scheduler_address.replace("tcp://", "dask://")
        rc, recs, rows = _run(tmp_path, "dask", "--executor", addr)
    assert rc == 0 and len(rows) == len(SCENES)
    assert {r.scene: r.metrics["relmse"] for r in recs} == want


def test_unreachable_scheduler_is_a_clear_error():
    from gibench.executor import map_unordered

    # A refused port is retried by Dask's connect until the deadline, so whether the
    # error says "cannot reach" or "did not answer" depends on the host's timing: both
    # are one line naming the address.
    with pytest.raises(ExecutorError, match=r"(cannot reach the|the) Dask scheduler at "
                                            r"tcp://127\.0\.0\.1:9(:| did not answer)"):
        list(map_unordered(str, [1], kind="dask", detail="tcp://127.0.0.1:9", connect_timeout=1.0))


@pytest.mark.mitsuba
def test_reference_device_falls_back_to_llvm_without_a_gpu(tmp_path, monkeypatch, capsys, mitsuba):
    """CUDA references where a GPU works; here (no GPU) the fallback path: the entry is
    rendered with the LLVM variant and the manifest says so."""
    from references.reference import (CUDA_VARIANT, cuda_available, get_reference,
                                       reference_device_variant)

    assert reference_device_variant("llvm") is None
    with pytest.raises(ValueError, match="auto, cuda or llvm"):
        reference_device_variant("gpu")
    if cuda_available():
        pytest.skip("a working CUDA device: the fallback path cannot be exercised here")
    monkeypatch.setenv("GIBENCH_REFERENCE_DEVICE", "cuda")
    ref = get_reference(REPO_ROOT / "suites" / "vocabulary" / "defines.xml", transport="direct",
                        spp=8, passes=2, store=tmp_path, defines={"width": "16", "height": "12"})
    assert "CUDA variant does not work here" in capsys.readouterr().err
    assert ref.manifest["variant"] != CUDA_VARIANT and ref.manifest["variant"] == mitsuba.variant()
    assert ref.image.shape == (12, 16, 3)
