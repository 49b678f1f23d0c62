"""Sweeps: one function over many jobs (seeds × robots × variants), on this machine's cores or on a cluster.

A sweep is a list of independent jobs :math:`j_1, \\dots, j_n`, each a tuple of arguments, and one top-level
function :math:`f`; the sweep returns :math:`[f(*j_1), \\dots, f(*j_n)]`, **in the order of the jobs**, whoever
ran them. Every random step of :math:`f` takes its seed from the job, so a result depends only on its job, never on
the process or machine that computed it: a sweep's numbers are the same serial, on two cores, or on a cluster.

Two engines do the work (no job runner of our own):

* `joblib <https://joblib.readthedocs.io>`_ on this machine: ``n_jobs`` worker processes (loky backend; default
  all cores); ``n_jobs=1`` runs the jobs one after the other in this process (no pickling, easiest to debug);
* `dask.distributed <https://distributed.dask.org>`_ on a cluster: ``scheduler="tcp://HOST:8786"`` sends every job
  to the scheduler as one task (``Client.map``), any worker runs it, ``Client.gather`` returns the results in the
  order of the futures, i.e. of the jobs. The workers need this package (same versions: ``pip install -c
  constraints.txt -e ".[sweep]"``), the data folder (``$FASTSLAM_EDU_DATA``) and, for a benchmark's own
  functions, the repository's ``benchmarks/`` folder on their ``PYTHONPATH``.

Both need the extra ``sweep`` (``pip install -e ".[sweep]"``); they are imported only when a sweep runs.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable, Sequence
from functools import partial

#: Seconds to wait for a dask scheduler before giving up (an address nobody listens on fails after this).
CONNECT_TIMEOUT_S = 10.0


class SweepError(RuntimeError):
    """A sweep that cannot start (bad ``n_jobs``, an unreachable scheduler): the message is one line."""


def default_n_jobs() -> int:
    """All cores of this machine (``os.cpu_count()``, at least 1)."""
    return max(1, os.cpu_count() or 1)


def check_n_jobs(n_jobs: int | None) -> int:
    """``n_jobs`` as a positive int (``None`` → all cores); anything else is a :class:`SweepError`."""
    if n_jobs is None:
        return default_n_jobs()
    if isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs < 1:
        raise SweepError(f"jobs must be a whole number >= 1 (got {n_jobs!r})")
    return n_jobs


def apply_to(function: Callable, job: tuple):
    """``function(*job)``: one job of a sweep."""
    return function(*job)


def run_local(function: Callable, jobs: Sequence[tuple], n_jobs: int) -> list:
    """:math:`[f(*j) \\text{ for } j \\text{ in jobs}]` with joblib on ``n_jobs`` processes (1: in this process)."""
    from joblib import Parallel, delayed

    return Parallel(n_jobs=n_jobs)(delayed(function)(*job) for job in jobs)


def run_on_cluster(function: Callable, jobs: Sequence[tuple], scheduler: str) -> list:
    """:math:`[f(*j) \\text{ for } j \\text{ in jobs}]` on the dask.distributed cluster whose scheduler listens at
    ``scheduler`` (e.g. ``"tcp://10.0.0.5:8786"``), one task per job, results in the order of the jobs."""
    from distributed import Client

    try:
        client = Client(scheduler, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, ValueError, TypeError) as error:  # refused, timed out, or not an address at all
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise SweepError(f"cannot reach the dask scheduler at {scheduler!r} "
                         f"(within {CONNECT_TIMEOUT_S:.0f} s): {reason}") from None
    with client:
        # pure=False: every job is its own task even if two jobs were equal (no result shared by key)
        futures = client.map(partial(apply_to, function), list(jobs), pure=False)
        return client.gather(futures)


def run_sweep(function: Callable, jobs: Sequence[tuple], n_jobs: int | None = None,
              scheduler: str | None = None) -> list:
    """Map a top-level ``function`` over ``jobs`` (tuples of its arguments): ``[function(*job) for job in jobs]``.

    Parameters
    ----------
    function : callable
        A module-level function (the workers import or unpickle it); its randomness must come from its arguments.
    jobs : sequence of tuple
        One tuple of positional arguments per call, e.g. ``(dataset, robot, seed, params)``.
    n_jobs : int, optional
        Processes on this machine (joblib); ``None``: all cores; ``1``: serially, in this process.
    scheduler : str, optional
        Address of a dask.distributed scheduler; the cluster's workers run the jobs (``n_jobs`` must then be
        ``None``: the cluster decides how many run at once).

    Returns
    -------
    list
        The results, in the order of ``jobs``, identical whichever engine ran them.
    """
    jobs = [tuple(job) for job in jobs]
    if scheduler is not None:
        if n_jobs is not None:
            raise SweepError(f"give jobs ({n_jobs}) or a scheduler ({scheduler!r}), not both: "
                             "on a cluster its workers set how many jobs run at once")
        return run_on_cluster(function, jobs, scheduler)
    return run_local(function, jobs, check_n_jobs(n_jobs))


def positive_int(text: str) -> int:
    """An argparse ``type`` for counts (``--jobs``, ``--particles``, ...): a whole number >= 1, or one line."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r} (expected a positive integer)") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1 (got {value}): expected a positive integer")
    return value


def add_sweep_options(parser: argparse.ArgumentParser) -> None:
    """The options every sweeping benchmark takes: ``--jobs N`` and ``--scheduler ADDRESS``."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--jobs", type=positive_int, default=None, metavar="N",
                       help=f"processes on this machine (joblib; default all cores, here {default_n_jobs()}; "
                            "1: serially in this process)")
    group.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="run the jobs on a dask.distributed cluster, e.g. tcp://HOST:8786 (extra 'sweep')")
