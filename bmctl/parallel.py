"""Ensemble work on Dask: a local cluster by default, a running ``dask scheduler`` on request.

Two functions carry every ensemble (calibration's plant runs; later whatif ensembles,
identification experiments and the studies in ``benchmarks/``):

- :func:`client_for` opens the engine: ``None`` (in-process, serial) for 0 or 1 workers,
  a ``distributed.LocalCluster`` of worker processes (one thread each) sized to the machine,
  or a client of a running scheduler (``--scheduler tcp://host:8786``).
- :func:`ensemble_map` runs ``fn(task, rng)`` for every task. Task i gets the generator of
  ``numpy.random.SeedSequence(seed).spawn(n)[i]``; what crosses a process boundary is the
  seed sequence's plain data (entropy, spawn key), never a Generator. Results come back in
  task order, so the same seed gives the same results whatever the number of workers.

:func:`map_seeded` is the lower level: explicit seed sequences per task, e.g. common random
numbers (several tasks sharing one seed sequence).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from typing import Any, Callable, Sequence

import numpy as np

from .errors import InputError
from .naming import arg

Task = Any


def default_workers() -> int:
    """Worker processes of a local cluster: the CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


#: most local worker processes per CPU (:func:`cap_workers`): more only wait, each costs a process and its imports
WORKERS_PER_CPU = 4

#: below this many ensemble members a local cluster is not worth starting
SMALL_MEMBERS = 4
#: ... nor below this much estimated CPU work (s): starting worker processes and importing bmctl
#: in each costs a few seconds
SMALL_CPU_S = 10.0


def cap_workers(workers: int, members: int) -> int:
    """A worker count the user asked for, capped at one per ensemble member and at
    :data:`WORKERS_PER_CPU` per CPU (a worker beyond either only costs a process and its start).

    The results do not depend on the worker count (:func:`map_seeded`), so capping changes no number.

    Parameters
    ----------
    workers : int
        Asked for (``--workers``); a negative count is returned as given (:func:`client_for` refuses it).
    members : int
        Independent tasks that run side by side.

    Examples
    --------
    >>> cap_workers(24, 2), cap_workers(2, 100), cap_workers(0, 5)
    (2, 2, 0)
    >>> cap_workers(10**6, 10**6) == WORKERS_PER_CPU * default_workers()
    True
    """
    if workers < 0:
        return workers
    return min(int(workers), max(int(members), 0), WORKERS_PER_CPU * default_workers())


def auto_workers(members: int, cpu_s: float, workers: int | None = None, scheduler: str | None = None) -> int | None:
    """Worker count for :func:`client_for`: the user's, capped (:func:`cap_workers`), else one that pays.

    Parameters
    ----------
    members : int
        Independent tasks of the ensemble.
    cpu_s : float
        Estimated CPU seconds of all of them together.
    workers, scheduler : optional
        What the user asked for (``--workers``, ``--scheduler``); either one is kept as given.

    Returns
    -------
    int or None
        ``workers`` when given, at most one per member and :data:`WORKERS_PER_CPU` per CPU
        (:func:`cap_workers`; ``workers`` as given with a scheduler, whose workers are its own);
        0 (serial, in process) for a small ensemble (fewer than :data:`SMALL_MEMBERS` members
        or under :data:`SMALL_CPU_S` estimated CPU seconds); else the machine's CPUs, at most one
        per member.

    Examples
    --------
    >>> auto_workers(3, 600.0), auto_workers(64, 2.0), auto_workers(64, 600.0, workers=1)
    (0, 0, 1)
    >>> auto_workers(2, 1.0, workers=24)     # two plants: two workers, not 24
    2
    """
    if scheduler is not None:
        return workers
    if workers is not None:
        return cap_workers(workers, members)
    if members < SMALL_MEMBERS or cpu_s < SMALL_CPU_S:
        return 0
    return min(default_workers(), members)


def check_engine_args(workers: int | None, scheduler: str | None) -> None:
    """Refuse ``--workers`` given together with ``--scheduler``: the scheduler's own workers run the
    tasks, so a local worker count would do nothing.

    Parameters
    ----------
    workers : int or None
        ``--workers`` as given (None: not given).
    scheduler : str or None
        ``--scheduler`` as given (None: not given).

    Examples
    --------
    >>> check_engine_args(4, None); check_engine_args(None, "tcp://host:8786")
    >>> check_engine_args(0, "tcp://host:8786")
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: workers: sets the local Dask workers, which scheduler replaces
    """
    if workers is not None and scheduler is not None:
        raise InputError(f"{arg('workers')}: sets the local Dask workers, which {arg('scheduler')} replaces")


def client_for(scheduler: str | None = None, workers: int | None = None, processes: bool = True):
    """The engine for ensemble work.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running ``dask scheduler`` (e.g. ``tcp://10.0.0.5:8786``); its workers run
        the tasks (they need bmctl installed). ``workers`` is ignored then.
    workers : int, optional
        Local worker processes; default: the machine's CPUs. 0 or 1: no Dask at all, the tasks
        run serially in this process (returns None).
    processes : bool, optional
        Local workers as processes (default) or threads (tests).

    Returns
    -------
    distributed.Client or None
        Close it with ``client.close()`` (and its cluster with ``client.cluster.close()``), or use
        :func:`close_client`.
    """
    if scheduler is None and workers is not None and workers < 0:
        raise InputError(f"{arg('workers')}: must be >= 0 (got {workers})")
    if scheduler is None and (workers is not None and workers <= 1):
        return None
    import distributed

    if scheduler is not None:
        try:
            return _quiet_gather_stops(distributed.Client(scheduler, timeout="20s"))
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"{arg('scheduler')}: cannot connect to {scheduler}: {exc}") from None
    n = default_workers() if workers is None else int(workers)
    if n <= 1:
        return None
    return _local_client(n, processes)


def _local_client(n: int, processes: bool):
    """A client of a new local cluster of ``n`` workers, Ctrl-C held back while it starts (:func:`_sigint_held`).

    A Ctrl-C in the middle of the start would leave a half-started cluster that Dask's own exit
    handler then fails to close (a traceback after bmctl's one line, or a 10 s wait). The threads
    and worker processes started meanwhile inherit the hold: a terminal's Ctrl-C reaches the whole
    process group, and the workers leave it to this process, which closes them.
    """
    import distributed

    if processes:  # multiprocessing's resource tracker lifts the hold when it starts: started first, it stays out
        from multiprocessing import resource_tracker

        resource_tracker.ensure_running()
    cluster = client = None
    try:
        with _sigint_held():
            cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=processes,
                                               dashboard_address=":0", silence_logs=50)  # a task's error is
            # raised here, in one line; at 40 every worker also logged it with a traceback ("Compute Failed")
            client = _quiet_gather_stops(distributed.Client(cluster))
    except BaseException:
        _close_started(client, cluster)
        raise
    return client


@contextlib.contextmanager
def _sigint_held():
    """Hold Ctrl-C back in the block and hand it to Python's handler (``KeyboardInterrupt``) when the block ends.

    In the main thread: SIGINT is only noted while the block runs, and blocked in this thread, so
    the threads and processes the block starts inherit the block (a terminal's Ctrl-C, which
    reaches the whole process group, is left to this process). Elsewhere the block runs as it is.

    Examples
    --------
    >>> with _sigint_held():
    ...     pass
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)
    hit = []
    if callable(previous):  # Python's to handle (not ignored, not the OS default): noted, raised after
        signal.signal(signal.SIGINT, lambda signum, frame: hit.append(signum))
    mask = hasattr(signal, "pthread_sigmask")
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if mask else None
    try:
        yield
    finally:
        if mask:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)  # a Ctrl-C held back is noted here
        if callable(previous):
            signal.signal(signal.SIGINT, previous)
    if hit:
        previous(signal.SIGINT, None)  # Python's default handler raises KeyboardInterrupt


def _quiet_gather_stops(client):
    """``client`` with its event loop silent about the gathers a Ctrl-C stopped.

    A gather that Ctrl-C stops leaves Dask's watch tasks ending in ``AllExit`` (its own signal to
    stop early); asyncio would print each as "Task exception was never retrieved" with a traceback
    after bmctl's one line. Every other exception of the loop is reported as before.
    """
    from distributed.client import AllExit

    loop = getattr(getattr(client, "loop", None), "asyncio_loop", None)
    if loop is not None:
        def handler(lp, context):
            if not isinstance(context.get("exception"), AllExit):
                lp.default_exception_handler(context)

        loop.call_soon_threadsafe(loop.set_exception_handler, handler)
    return client


def _close_started(client, cluster) -> None:
    """Close what :func:`_local_client` had started when it was stopped."""
    if client is not None:
        close_client(client)
    elif cluster is not None:
        cluster.close()


def close_client(client) -> None:
    """Close a client from :func:`client_for` and the local cluster it started (None: nothing)."""
    if client is None:
        return
    cluster = getattr(client, "cluster", None)
    with _sigint_held():  # a Ctrl-C in Dask's close waits 10 s for the close it stopped: it comes after
        client.close()
        if cluster is not None:
            cluster.close()


def seed_sequences(seed: int | np.random.SeedSequence, n: int) -> list[np.random.SeedSequence]:
    """``SeedSequence(seed).spawn(n)``: one independent stream per task."""
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    return ss.spawn(n)


def _plain(ss: np.random.SeedSequence) -> tuple:
    return (ss.entropy, tuple(int(k) for k in ss.spawn_key))


def _call(fn: Callable, task: Task, plain_seed: tuple):
    entropy, key = plain_seed
    return fn(task, np.random.default_rng(np.random.SeedSequence(entropy, spawn_key=key)))


def map_seeded(fn: Callable[[Task, np.random.Generator], Any], tasks: Sequence[Task],
               seeds: Sequence[np.random.SeedSequence], client=None,
               progress: Callable[[int], None] | None = None) -> list:
    """``[fn(task, default_rng(seed)) for task, seed in zip(tasks, seeds)]``, on ``client`` if given.

    Parameters
    ----------
    fn : callable
        ``fn(task, rng) -> result``; a module-level function (it is pickled to the workers).
    tasks : sequence
        Plain-data task descriptions.
    seeds : sequence of numpy.random.SeedSequence
        One per task (tasks may share one: common random numbers).
    client : distributed.Client, optional
        None: serial, in this process.
    progress : callable, optional
        Called with 1 as each task finishes (e.g. ``tqdm.update``).

    Returns
    -------
    list
        Results in task order.
    """
    if len(tasks) != len(seeds):
        raise ValueError(f"map_seeded: {len(tasks)} tasks but {len(seeds)} seeds")
    plain = [_plain(s) for s in seeds]
    if client is None:
        out = []
        for task, ps in zip(tasks, plain):
            out.append(_call(fn, task, ps))
            if progress is not None:
                progress(1)
        return out
    from distributed import as_completed

    futures = client.map(_call, [fn] * len(tasks), list(tasks), plain, pure=False)
    if progress is not None:
        for _ in as_completed(futures):
            progress(1)
    return client.gather(futures)


def ensemble_map(fn: Callable[[Task, np.random.Generator], Any], tasks: Sequence[Task],
                 seed: int | np.random.SeedSequence, client=None,
                 progress: Callable[[int], None] | None = None) -> list:
    """Run ``fn(task_i, rng_i)`` for every task, rng_i from ``SeedSequence(seed).spawn(n)[i]``.

    Parameters
    ----------
    fn : callable
        ``fn(task, rng) -> result``, a module-level function.
    tasks : sequence
        Plain-data task descriptions.
    seed : int or numpy.random.SeedSequence
        The user's seed.
    client : distributed.Client, optional
        From :func:`client_for`; None runs serially in this process.
    progress : callable, optional
        Called with 1 per finished task.

    Returns
    -------
    list
        Results in task order; identical for any number of workers.

    Examples
    --------
    >>> def draw(task, rng):
    ...     return float(rng.normal(task))
    >>> a = ensemble_map(draw, [0.0, 10.0], seed=1)
    >>> a == ensemble_map(draw, [0.0, 10.0], seed=1)
    True
    """
    return map_seeded(fn, tasks, seed_sequences(seed, len(tasks)), client, progress)
