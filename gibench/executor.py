"""Where the cases of a run execute: in this process, in local worker
processes (``--jobs N``) or on a Dask distributed cluster
(``--executor dask://HOST:PORT``).

Whatever executes a case, its record comes back to the parent process, which
alone appends it to the results store and the history database: the stores
see one writer, in completion order.  Workers render references missing from
the store themselves; two workers installing the same entry are safe (the
store installs complete directories by rename, see
:mod:`references.reference`).

Notes
-----
Timings measured while several cases run at once share the CPU; with
``--jobs`` > 1 or a cluster, compare speed ratios only within one worker's
records, or rerun with ``--jobs 1`` for the timing table.

A remote Dask cluster's workers must import this checkout (same repository
path on every worker, or the package installed); references they render go
to *their* ``references/store``, so point ``--store`` at a shared directory.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Callable, Iterable, Iterator
from core.errors import GibenchError

__all__ = ["ExecutorError", "parse_executor", "map_unordered", "handshake"]



class ExecutorError(GibenchError, ValueError):
    """A malformed ``--executor`` or ``--jobs`` value, or an unreachable cluster."""



def parse_executor(spec: str | None, jobs: int = 1) -> tuple[str, object]:
    """``(kind, detail)`` for an executor spec: ``("serial", None)``,
    ``("processes", n)`` or ``("dask", "tcp://HOST:PORT")``."""
    if not isinstance(jobs, int) or jobs < 1:
        raise ExecutorError(f"--jobs must be a positive integer, got {jobs!r}")
    if spec in (None, "", "local"):
        return ("processes", jobs) if jobs > 1 else ("serial", None)
    if spec.startswith("dask://"):
        rest = spec[len("dask://"):]
        host, _, port = rest.rpartition(":")
        if not host or not port.isdigit():
            raise ExecutorError(f"--executor expects dask://HOST:PORT, got {spec!r}")
        return "dask", f"tcp://{host}:{port}"
    if spec.startswith("tcp://"):
        return "dask", spec
    raise ExecutorError(f"unknown --executor {spec!r} (use 'local' or dask://HOST:PORT)")


def _init_worker():
    # Local workers share the cores: numba's own threads per worker would oversubscribe.
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")


def map_unordered(fn: Callable, items: Iterable, *, kind: str = "serial", detail=None,
                  connect_timeout: float = 10.0) -> Iterator[tuple[int, object]]:
    """Yield ``(index, fn(item))`` as each item completes.

    ``fn`` must be a module-level function (it is pickled for process and
    Dask workers).  An exception raised by ``fn`` propagates (``fn`` is
    expected to catch per-item failures itself and return a record).
    """
    items = list(items)
    if kind == "serial":
        for i, it in enumerate(items):
            yield i, fn(it)
        return
    if kind == "processes":
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")      # no forked numba/LLVM state
        pool = ProcessPoolExecutor(max_workers=int(detail), mp_context=ctx,
                                   initializer=_init_worker)
        futures = {pool.submit(fn, it): i for i, it in enumerate(items)}
        try:
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
        except BaseException:
            # Ctrl-C or a failure: drop queued cases, do not wait for running ones.
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        pool.shutdown(wait=True)
        return
    if kind == "dask":
        try:
            from distributed import Client
            from distributed import as_completed as dask_as_completed
        except ImportError:
            raise ExecutorError("--executor dask://... needs dask[distributed] "
                                "(pip install 'dask[distributed]')") from None
        handshake(detail, connect_timeout)
        try:
            client = Client(detail, timeout=f"{connect_timeout}s", set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise ExecutorError(f"cannot reach the Dask scheduler at {detail}: {exc}") from None
        try:
            with client.as_current():
                yield from _dask_loop(client, fn, items, dask_as_completed)
        finally:
            client.close()
        return
    raise ExecutorError(f"unknown executor kind {kind!r}")


def handshake(address: str, timeout: float = 10.0) -> dict:
    """Ask the Dask scheduler at ``address`` who it is, all of it (TCP connect, the
    comm handshake, one ``identity`` request and its answer) under one deadline of
    ``timeout`` seconds; returns the scheduler's identity.  Raises
    :class:`ExecutorError` if nothing answers in time or the answer is not a Dask
    scheduler's (a port that accepts and never answers would otherwise hang the
    client's own connect, whose timeout does not cover the handshake)."""
    import asyncio

    from distributed.comm import connect

    async def ask():
        comm = await connect(address, timeout=timeout)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    try:
        reply = asyncio.run(asyncio.wait_for(ask(), timeout))
    except (TimeoutError, asyncio.TimeoutError):
        raise ExecutorError(f"the Dask scheduler at {address} did not answer within "
                            f"{timeout:g} s") from None
    except Exception as exc:                      # noqa: BLE001 - any failure to talk is the address's
        first = (str(exc).splitlines() or [type(exc).__name__])[0][:200]
        raise ExecutorError(f"cannot reach the Dask scheduler at {address}: {first}") from None
    if not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        raise ExecutorError(f"{address} answered, but not as a Dask scheduler")
    return reply


def _dask_loop(client, fn, items, dask_as_completed):
    futures = [client.submit(fn, it, pure=False) for it in items]
    index = {f.key: i for i, f in enumerate(futures)}
    try:
        for fut in dask_as_completed(futures):
            yield index[fut.key], fut.result()
    except BaseException:
        client.cancel(futures)
        raise
