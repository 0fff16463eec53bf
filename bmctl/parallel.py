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

import os
from typing import Any, Callable, Sequence

import numpy as np

from .errors import InputError

Task = Any


def default_workers() -> int:
    """Worker processes of a local cluster: the CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


#: below this many ensemble members a local cluster is not worth starting
SMALL_MEMBERS = 4
#: ... nor below this much estimated CPU work (s): starting worker processes and importing bmctl
#: in each costs a few seconds
SMALL_CPU_S = 10.0


def auto_workers(members: int, cpu_s: float, workers: int | None = None, scheduler: str | None = None) -> int | None:
    """Worker count for :func:`client_for` when the user named none.

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
        ``workers`` when given (None with a scheduler); 0 (serial, in process) for a small ensemble
        (fewer than :data:`SMALL_MEMBERS` members or under :data:`SMALL_CPU_S` estimated CPU
        seconds); else the machine's CPUs, at most one per member.

    Examples
    --------
    >>> auto_workers(3, 600.0), auto_workers(64, 2.0), auto_workers(64, 600.0, workers=1)
    (0, 0, 1)
    """
    if scheduler is not None or workers is not None:
        return workers
    if members < SMALL_MEMBERS or cpu_s < SMALL_CPU_S:
        return 0
    return min(default_workers(), members)


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
        raise InputError(f"--workers: must be >= 0 (got {workers})")
    if scheduler is None and (workers is not None and workers <= 1):
        return None
    import distributed

    if scheduler is not None:
        try:
            return distributed.Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"--scheduler: cannot connect to {scheduler}: {exc}") from None
    n = default_workers() if workers is None else int(workers)
    if n <= 1:
        return None
    cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=processes,
                                       dashboard_address=":0", silence_logs=40)
    return distributed.Client(cluster)


def close_client(client) -> None:
    """Close a client from :func:`client_for` and the local cluster it started (None: nothing)."""
    if client is None:
        return
    cluster = getattr(client, "cluster", None)
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
