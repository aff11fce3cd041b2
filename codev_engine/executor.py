"""One executor for the engine's independent tasks: serial, or on Dask distributed.

The engine's parallel workloads (design sweeps today) hand an :class:`Executor` a function
and a list of inputs and get the results back **in the inputs' order**, whatever ran them:
this process one after another (the default), a Dask ``LocalCluster`` of worker processes
on this machine (``workers=N``), or an existing Dask cluster (``scheduler="tcp://HOST:PORT"``,
or the environment variable ``CODEV_SCHEDULER``). The merge order is the inputs' order, never
the order of completion, so a result does not depend on the executor or the number of
workers.

Dask is imported when a cluster is first used, never by ``import codev_engine``. What is sent
to a worker is the task in memory: the function by reference (its module is imported on the
worker, which must have codev installed) and its arguments, pickled by Dask for the trip.
Nothing is ever unpickled from disk. A worker that dies mid-task (killed, out of memory) has
its tasks rerun by the scheduler on the other workers (Dask's ``allowed-failures``, 3 by
default); the client sees each result once. See docs/scale.md.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

__all__ = ["Executor", "SCHEDULER_ENV"]

#: the environment variable naming a running Dask scheduler (``tcp://HOST:PORT``)
SCHEDULER_ENV = "CODEV_SCHEDULER"
#: times a task the scheduler cancelled (it lost the task, or data the task needs, with a
#: worker) is submitted again by the client before the error is raised
RESUBMITS = 3


def result_resubmitting(future, resubmit: Callable[[], Any], stats: dict | None = None):
    """The result of a Dask ``future``; where the scheduler cancelled it (a worker that held
    it, or data it needs, died), ``resubmit()`` gives a new future for the same task (the
    tasks are pure functions of their inputs, which the client holds), up to
    ``RESUBMITS`` times.

    Parameters
    ----------
    future : distributed.Future
        The task.
    resubmit : callable
        ``resubmit() -> Future``: the same task again (scattering its data again if lost).
    stats : dict, optional
        ``stats["resubmitted"]`` counts the tasks submitted again.

    Returns
    -------
    tuple
        ``(result, future)``: the task's result and the future that gave it.
    """
    from distributed.client import FutureCancelledError

    for attempt in range(RESUBMITS + 1):
        try:
            return future.result(), future
        except FutureCancelledError:
            if attempt == RESUBMITS:
                raise
            if stats is not None:
                stats["resubmitted"] = stats.get("resubmitted", 0) + 1
            future = resubmit()
    raise AssertionError("unreachable")  # pragma: no cover


def scattered(client, data, future=None):
    """``data`` scattered to every worker (``broadcast``), or ``future`` when the cluster
    still holds it.

    Parameters
    ----------
    client : distributed.Client
    data : object
        What the tasks share (arrays, codev's own objects).
    future : distributed.Future, optional
        An earlier scatter of ``data``.

    Returns
    -------
    distributed.Future
    """
    if future is not None and future.status == "finished":
        return future
    # (in a list: one future for the whole of ``data``, a tuple included)
    return client.scatter([data], broadcast=True, hash=False)[0]


class Executor:
    """Runs independent tasks serially, on a local Dask cluster, or on a remote one.

    Parameters
    ----------
    workers : int, optional
        Start a Dask ``LocalCluster`` of this many worker processes (one thread each) on
        this machine. ``None`` (default) and no scheduler: run serially in this process.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://HOST:PORT``) to connect to instead;
        default the environment variable ``CODEV_SCHEDULER`` when ``workers`` is None.

    Attributes
    ----------
    kind : {"serial", "local", "cluster"}
        What runs the tasks.

    Raises
    ------
    ValueError
        Both ``workers`` and ``scheduler`` given, or ``workers < 1``.

    Notes
    -----
    The cluster is started (or connected to) on first use and stopped by :meth:`close`
    (or on leaving a ``with`` block); a remote cluster is left running. Local workers are
    spawned processes: a script that starts them needs the ``if __name__ == "__main__":``
    guard.

    Examples
    --------
    >>> with Executor(workers=2) as ex:                       # doctest: +SKIP
    ...     squares = ex.map(pow, [(1, 2), (2, 2), (3, 2)])
    """

    def __init__(self, *, workers: int | None = None, scheduler: str | None = None):
        if workers is not None and scheduler is not None:
            raise ValueError("give workers or scheduler, not both")
        if workers is not None and int(workers) < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        if workers is None and scheduler is None:
            scheduler = os.environ.get(SCHEDULER_ENV) or None
        self._workers = None if workers is None else int(workers)
        self._scheduler = scheduler
        self.kind = "cluster" if scheduler else ("local" if workers is not None else "serial")
        self._cluster = None
        self._client = None

    def __repr__(self) -> str:
        where = self._scheduler or (f"{self._workers} workers" if self._workers else "")
        return f"Executor({self.kind}{', ' + where if where else ''})"

    # -- the cluster -----------------------------------------------------------------------

    @property
    def client(self):
        """The Dask ``distributed.Client`` (started on first access); None when serial."""
        if self.kind == "serial":
            return None
        if self._client is None:
            from distributed import Client, LocalCluster

            if self.kind == "local":
                import dask

                # the event loops' tick monitor (a check for blocked loops) every second,
                # not every 20 ms: it cost this process ~3 % of a core while the workers
                # computed (the scheduler of a LocalCluster runs here, beside the client)
                with _interrupt_ignored(), warnings.catch_warnings(), dask.config.set(
                    {"distributed.admin.tick.interval": "1s"}
                ):
                    # the scheduler's HTTP routes (no dashboard) take another port when
                    # 8787 is taken, with a warning that is no news on a shared machine
                    warnings.filterwarnings("ignore", message="Port .* is already in use")
                    self._cluster = LocalCluster(
                        n_workers=self._workers,
                        threads_per_worker=1,
                        processes=True,
                        dashboard_address=None,
                        silence_logs=40,  # logging.ERROR: the nanny's restart notes stay quiet
                    )
                self._client = Client(self._cluster)
            else:
                self._client = Client(self._scheduler)
        return self._client

    def close(self) -> None:
        """Close the client and stop a local cluster (a remote one keeps running)."""
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- running tasks ---------------------------------------------------------------------

    def map(
        self,
        fn: Callable[..., Any],
        args: Iterable[Sequence[Any]],
        *,
        on_result: Callable[[int, Any], None] | None = None,
        cost: Sequence[float] | None = None,
        interrupt: Callable[[], None] | None = None,
    ) -> list[Any]:
        """Call ``fn(*a)`` for each ``a`` of ``args``; the results in the order of ``args``.

        Parameters
        ----------
        fn : callable
            A module-level function (sent to workers by reference).
        args : iterable of sequences
            The positional arguments of each call.
        on_result : callable, optional
            Called as ``on_result(i, result)`` in this process as each call finishes (in
            the order of completion on a cluster, of ``args`` when serial), for progress.
        cost : sequence of float, optional
            An estimate of each call's cost (any unit, one per call). On a cluster the
            calls are submitted, and prioritised, costliest first (ties in the order of
            ``args``): the longest calls start first and the short ones fill the gaps at the
            end (longest-processing-time-first scheduling), instead of one long call left
            for last while the other workers idle. The results and their order do not
            depend on it; serially it is ignored.
        interrupt : callable, optional
            Called between calls and, on a cluster, every 0.2 s while waiting for one: an
            exception it raises cancels the calls still running and propagates (serially
            the running call is not interrupted: pass the call its own check).

        Returns
        -------
        list
            ``[fn(*a) for a in args]``, in that order whatever the executor.

        Raises
        ------
        Exception
            The first exception a call raised (re-raised here, the other calls cancelled).
        """
        calls = [tuple(a) for a in args]
        if self.kind == "serial" or not calls:
            results = []
            for i, a in enumerate(calls):
                if interrupt is not None:
                    interrupt()
                results.append(fn(*a))
                if on_result is not None:
                    on_result(i, results[-1])
            return results
        from distributed import as_completed

        client = self.client
        order = list(range(len(calls)))
        priority = [0] * len(calls)
        if cost is not None:
            if len(cost) != len(calls):
                raise ValueError(f"cost: {len(cost)} values for {len(calls)} calls")
            order.sort(key=lambda i: -float(cost[i]))  # (stable: ties in the args' order)
            for rank, i in enumerate(order):
                priority[i] = len(calls) - rank  # (Dask runs higher priorities first)
        # pure=False: every call is its own task, even two equal designs (each is reported)
        futures = [None] * len(calls)
        for i in order:
            futures[i] = client.submit(fn, *calls[i], pure=False, priority=priority[i])
        index = {f.key: i for i, f in enumerate(futures)}
        results: list[Any] = [None] * len(calls)
        try:
            pending = as_completed(futures)
            while not pending.is_empty():
                if interrupt is not None:
                    interrupt()
                    if not pending.has_ready():
                        time.sleep(0.2)
                        continue
                for future in pending.next_batch(block=True):
                    i = index[future.key]
                    results[i] = future.result()
                    if on_result is not None:
                        on_result(i, results[i])
        except BaseException:
            client.cancel(futures)
            raise
        return results

    @property
    def workers(self) -> int:
        """Number of workers: 1 when serial, the cluster's current count otherwise."""
        if self.kind == "serial":
            return 1
        return len(self.client.scheduler_info(n_workers=-1)["workers"])


@contextlib.contextmanager
def _interrupt_ignored() -> Iterator[None]:
    """Ignore SIGINT while a local cluster starts (POSIX, main thread; elsewhere nothing).

    The nanny and worker processes it spawns inherit the ignored signal (an ignored signal
    stays ignored across ``exec``, and Python keeps it so): a Ctrl-C at the terminal, sent to
    the whole process group, then stops only this process, whose KeyboardInterrupt closes
    the cluster in order (workers killed by the signal instead log tracebacks as they die).
    A Ctrl-C during the start itself (a few seconds) is not seen.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
