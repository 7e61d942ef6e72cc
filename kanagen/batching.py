"""Many datasets at once: one estimation per dataset on Dask workers, results in SQLite.

The parent process reads each dataset, sends the spec's text and the measures to a worker
(so workers need kanagen but not the files), and writes each outcome to the results
database as it arrives — one writer, one transaction per dataset (:mod:`kanagen.resultsdb`).
A few datasets per worker are in flight at a time, so a killed run loses at most those.
Workers are local processes by default (nothing to start) or those of a
``dask.distributed`` scheduler; each runs one dataset at a time with single-threaded BLAS
(Dask's nanny sets ``OMP_NUM_THREADS=1`` and the like), so a worker is a core.
"""

from __future__ import annotations

import glob
import logging
import os
import time
import uuid
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from .dataio import DataError, read_measures
from .fitjob import FitOptions, read_sigmas, resolve_channel, run_job
from .modelspec.limits import DEFAULT, Limits
from .resultsdb import ResultsDB, Row, claim_owner, encode

_IN_FLIGHT = 2  # datasets sent ahead per worker thread: busy workers, little lost on a kill


@dataclass(frozen=True)
class Outcome:
    """What became of one dataset (given to the progress callback)."""

    dataset: str
    status: str  # "ok", "no model" or "error"
    model: str | None
    message: str
    seconds: float | None  # estimation time (wall) on the worker
    cpu_seconds: float | None = None  # CPU time of the worker's process for it


@dataclass(frozen=True)
class BatchSummary:
    """The counts of a batch run."""

    datasets: int  # matched
    skipped: int  # already in the database (resumed), or taken by another run on it
    ok: int  # estimated now, a model found
    no_model: int  # estimated now, no model (or not converged)
    errors: int  # failed now
    seconds: float  # wall time of the run
    workers: int
    db: str

    @property
    def estimated(self) -> int:
        return self.ok + self.no_model + self.errors

    def __str__(self) -> str:
        text = (f"{self.datasets} dataset(s): {self.estimated} estimated now ({self.ok} with a "
                f"model, {self.no_model} without, {self.errors} failed), {self.skipped} "
                f"already in {self.db}; {self.seconds:.1f} s")
        if self.workers:
            text += (f", {self.estimated / max(self.seconds, 1e-9):.3g} dataset(s)/s on "
                     f"{self.workers} worker(s)")
        return text


def batch(spec: str | Path, datasets: str | Iterable[str | Path], *, db: str | Path,
          channel: str | None = None, workers: int | None = None, scheduler: str | None = None,
          retry_errors: bool = False, progress: Callable[[Outcome], None] | None = None,
          on_start: Callable[[int, int], None] | None = None,
          options: FitOptions | None = None, backend: str | None = None,
          limits: Limits = DEFAULT, **fit_options) -> BatchSummary:
    """Estimate every dataset with the same spec and options; results go to ``db``.

    Parameters
    ----------
    spec : path of a YAML spec, or the name of a shipped family.
    datasets : a glob pattern (``"scenes/*.csv"``, ``**`` recursive) or a list of paths.
        A dataset's name in the database is its path as matched or given.
    db : path of the SQLite results database (created when missing).
    channel : the channel of the data files (default: the spec's only one).
    workers : local worker processes (default: the CPUs available); ignored with
        ``scheduler``.
    scheduler : address of a ``dask.distributed`` scheduler (``tcp://host:8786``) whose
        workers run the estimations (they need kanagen installed, not the data files).
    retry_errors : estimate again the datasets whose earlier run failed.
    progress : called with an :class:`Outcome` as each dataset finishes.
    on_start : called with (datasets to estimate, datasets skipped) before the first one.
    options : FitOptions, or the same as keywords (``max_samples=500, sigma=0.5, ...``;
        ``scale`` defaults to each model's χ² quantile, ``adaptive`` to True).
    backend : ``"compiled"``, ``"numpy"`` or ``"casadi"``, default :func:`kanagen.load`'s
        (each worker loads; a compiled family is compiled once, by this process, into the
        shared cache). The same
        estimates whatever the backend: not part of what a re-run resumes on.
    limits : what reading the spec may cost (:class:`kanagen.modelspec.Limits`), in the
        parent and on every worker.

    Returns
    -------
    BatchSummary

    Re-running the same call skips the datasets already recorded for the same spec (hash)
    and options; a dataset that fails (unreadable, bad values, a crash) is recorded with its
    error and the run goes on. Local workers are processes: a script that calls this must
    guard its entry point with ``if __name__ == "__main__":``.

    Examples
    --------
    >>> summary = kanagen.batch("examples/conic_lattice.yaml", "scenes/*.csv",
    ...                         db="results.sqlite", workers=2)  # doctest: +SKIP
    >>> kanagen.read_results("results.sqlite", as_frame=True)  # doctest: +SKIP
    """
    from . import load

    started = time.perf_counter()
    if options is None:
        options = FitOptions(**fit_options)
    elif fit_options:
        raise ValueError("give options= or option keywords, not both")
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    paths = _expand(datasets)
    spec_text, source = _spec_source(spec)
    fam = load(spec, backend=backend, limits=limits)
    backend = fam.backend  # the workers load what this process could (compiled, cached)
    channel = resolve_channel(fam, channel)
    options.check(fam)
    key = options.key(channel)
    components = fam.channel(channel).components
    counts = {"ok": 0, "no model": 0, "error": 0, "elsewhere": 0}
    owner = claim_owner()
    with ResultsDB(db) as store:
        done = store.done(fam.sha256, key, retry_errors)
        todo = [p for p in paths if p not in done]
        if on_start is not None:
            on_start(len(todo), len(paths) - len(todo))

        def record(path: str, status: str, message: str, out: dict | None = None) -> None:
            out = out or {}
            encoded = out.get("encoded") or encode(None)
            store.write(Row(path, fam.sha256, key, fam.name, channel, status, encoded,
                            message, out.get("seconds")))
            counts[status] += 1
            if progress is not None:
                progress(Outcome(path, status, encoded.model, message, out.get("seconds"),
                                 out.get("cpu")))

        def jobs() -> Iterator[tuple]:
            for path in todo:
                # another run on the same database may have taken it (or done it) since
                if not store.claim(path, fam.sha256, key, owner, retry_errors):
                    counts["elsewhere"] += 1
                    continue
                try:
                    X = read_measures(path, components, channel)
                    if X.ndim != 2 or X.shape[0] == 0:
                        raise DataError(f"{path}: no measures for channel {channel!r}")
                    sigmas = read_sigmas(path, options, channel)
                except Exception as exc:  # any unreadable dataset: recorded, the run goes on
                    record(path, "error", str(exc) if isinstance(exc, DataError)
                           else f"{path}: cannot read data: {type(exc).__name__}")
                    continue
                yield path, X, sigmas

        task = (spec_text, source, channel, options.to_dict(), backend, limits)
        try:
            with _client(workers, scheduler, bool(todo)) as (client, slots):
                for path, out in _run(client, slots, task, jobs()):
                    if "error" in out:
                        record(path, "error", out["error"], out)
                    else:
                        record(path, "ok" if out["found"] else "no model",
                               out["stop_reason"], out)
        finally:
            store.release(owner)
    return BatchSummary(len(paths), len(paths) - len(todo) + counts["elsewhere"], counts["ok"],
                        counts["no model"], counts["error"], time.perf_counter() - started,
                        slots, str(db))


def _expand(datasets) -> list[str]:
    if isinstance(datasets, str | Path):
        pattern = str(datasets)
        paths = sorted(p for p in glob.glob(pattern, recursive=True) if os.path.isfile(p))
        if not paths:
            raise ValueError(f"no data file matches {pattern!r}")
        return paths
    paths = list(dict.fromkeys(str(p) for p in datasets))
    if not paths:
        raise ValueError("no dataset given")
    return paths


def _spec_source(spec) -> tuple[str | None, str]:
    """(YAML text, source) of a spec file; (None, name) for a shipped family."""
    path = Path(spec)
    if path.suffix in (".yaml", ".yml") or path.exists():
        try:
            return path.read_text(encoding="utf-8"), str(spec)
        except OSError as exc:
            raise ValueError(f"{spec}: cannot read the spec: {exc.strerror}") from None
    return None, str(spec)


@contextmanager
def _client(workers: int | None, scheduler: str | None, needed: bool):
    """A dask.distributed client and its number of worker threads (slots)."""
    if not needed:  # nothing to estimate: start nothing
        yield None, 0
        return
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ImportError("kanagen batch needs dask.distributed: pip install "
                          "'kanagen[batch]'") from None
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=30)
        except OSError as exc:
            raise ValueError(f"cannot reach the scheduler at {scheduler}: {exc}") from None
        with client:
            yield client, max(1, sum(client.nthreads().values()))
        return
    workers = workers or len(os.sched_getaffinity(0))
    # the scheduler serves HTTP in any case: on a free port, not one another cluster holds
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=":0", silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client:
        yield client, workers


def _run(client, slots: int, task: tuple, jobs: Iterator[tuple]):
    """Yield ``(dataset, outcome)`` as datasets finish, keeping ``_IN_FLIGHT`` per slot
    submitted."""
    if client is None:
        return
    from distributed import as_completed

    running = as_completed()
    names = {}
    run_id = uuid.uuid4().hex[:8]

    def submit() -> None:
        for path, X, sigmas in jobs:
            future = client.submit(estimate_dataset, *task, X, path, sigmas, pure=False,
                                   key=f"kanagen-{run_id}-{len(names)}")
            names[future.key] = path
            running.add(future)
            return

    for _ in range(_IN_FLIGHT * slots):
        submit()
    for future in running:
        path = names[future.key]
        try:
            out = future.result()
        except Exception as exc:  # the worker died (dask retried it): record, go on
            out = {"error": f"worker failed: {type(exc).__name__}: {exc}"}
        future.release()
        yield path, out
        submit()


def estimate_dataset(spec_text: str | None, source: str, channel: str, options: dict,
                     backend: str, limits: Limits, X: np.ndarray, dataset: str,
                     sigmas: np.ndarray | None = None) -> dict:
    """One dataset on a worker: its record encoded for the database (``"encoded"``,
    ``"found"``, ``"stop_reason"``) or ``"error"``, with ``"seconds"`` (wall) and ``"cpu"``
    (the process's CPU time); never raises (a dataset's failure is its outcome)."""
    started, cpu = time.perf_counter(), time.process_time()
    try:
        fam = _family(spec_text, source, backend, limits)
        rec = run_job(fam, X, channel, FitOptions(**options), spec=source, data=dataset,
                      sigmas=sigmas)
        out = {"encoded": encode(rec), "found": rec["found"],
               "stop_reason": rec.get("stop_reason") or ""}
    except Exception as exc:  # recorded as the dataset's error; the run goes on
        out = {"error": f"{type(exc).__name__}: {exc}"}
    return {**out, "seconds": time.perf_counter() - started, "cpu": time.process_time() - cpu}


@lru_cache(maxsize=8)
def _family(spec_text: str | None, source: str, backend: str, limits: Limits):
    """The family on a worker, loaded once per process."""
    from . import load, load_text

    return load(source, backend=backend, limits=limits) if spec_text is None else \
        load_text(spec_text, source, backend=backend, limits=limits)
