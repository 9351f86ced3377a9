"""Running a sweep's points: one after the other, in worker processes with a time limit per point,
or on a Dask cluster; each finished :class:`~bondc.analysis.sweep.table.SweepPoint` is handed back
as it comes, with the progress shown on stderr."""

from __future__ import annotations

import dataclasses
import logging
import statistics
import sys
import time
from typing import Callable

from bondc.analysis.sweep.grid import _usage
from bondc.analysis.sweep.point import _run_point, _Setup
from bondc.analysis.sweep.table import STATUSES, SweepPoint
from bondc import codes


#: Without --point-timeout: a point may take 20 times the median time of the points done so far,
#: at least this long [s]; before any point is done, FIRST_POINT_LIMIT.
MIN_POINT_LIMIT = 60.0


FIRST_POINT_LIMIT = 600.0


#: Not on a terminal, a progress line at most this often [s].
PLAIN_PROGRESS_EVERY = 10.0


def _run_all(setup: _Setup, tasks: list, jobs: int, report, point_timeout: float | None,
             on_done: Callable[[SweepPoint], None], executor: str = "local", scheduler: str | None = None) -> None:
    """Run every ``(index, values)`` task; ``on_done(point)`` in the main process as each finishes.

    ``point_timeout`` 0 runs the points one after the other in this process (no time limit);
    otherwise they run in ``jobs`` worker processes, and a point that takes longer than its limit
    (``point_timeout`` seconds, or None: 20 times the median of the points done so far, at least
    :data:`MIN_POINT_LIMIT`) is stopped and recorded as timed out. Ctrl-C and SIGTERM stop the
    workers at once; what finished has been handed to ``on_done``.
    """
    total = len(tasks)
    if executor == "dask":
        _run_dask(setup, tasks, jobs, report, point_timeout, on_done, scheduler)
        return
    if point_timeout == 0:
        for count, (index, values) in enumerate(tasks, 1):
            started = time.perf_counter()
            point = _run_point(setup, index, values)
            if any(d.code == codes.E813 for d in point.diagnostics):
                raise KeyboardInterrupt     # Ctrl-C stopped this point's run: stop the sweep, keep the rest
            point = dataclasses.replace(point, wall_time=time.perf_counter() - started)
            on_done(point)
            if report is not None:
                report(point, count, total)
        return
    workers = _Workers(setup, min(jobs, total))
    try:
        workers.run(tasks, point_timeout, on_done, report)
    finally:
        workers.stop()


def _timed_point(setup: _Setup, index: int, values: tuple) -> SweepPoint:
    """One point with its wall time (what a Dask worker runs)."""
    started = time.perf_counter()
    point = _run_point(setup, index, values)
    return dataclasses.replace(point, wall_time=time.perf_counter() - started)


def _run_dask(setup: _Setup, tasks: list, jobs: int, report, point_timeout: float | None, on_done,
              scheduler: str | None) -> None:
    """The points on a Dask cluster: an existing one (``scheduler``, ``tcp://host:8786``) or a
    ``LocalCluster`` of ``jobs`` worker processes. As many points are in flight as there are
    workers, so a point's time runs from when it was sent; one over its limit is recorded as timed
    out and released (on a cluster of its own the sweep closes it at the end, stopping such a point;
    on an existing cluster the worker finishes it in the background)."""
    try:
        from distributed import Client, LocalCluster, wait
    except ImportError:
        raise _usage(codes.E971, "--executor dask needs dask.distributed, which is not installed",
                     hint='pip install "dask[distributed]"') from None
    cluster = None
    try:
        if scheduler:
            client = Client(scheduler, timeout="10s")
        else:
            cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True, dashboard_address=None,
                                   silence_logs=logging.ERROR)
            client = Client(cluster)
    except (OSError, TimeoutError) as error:
        raise _usage(codes.E971, f"cannot reach the Dask scheduler {scheduler!r}: {error}",
                     hint="start one with 'dask scheduler' and workers with 'dask worker ADDRESS'") from None
    try:
        slots = max(1, len(client.scheduler_info().get("workers", {})) or jobs)
        pending = list(reversed(tasks))
        flying: dict = {}                 # future -> (index, values, sent)
        times: list[float] = []
        done, total = 0, len(tasks)
        while pending or flying:
            while pending and len(flying) < slots:
                index, values = pending.pop()
                flying[client.submit(_timed_point, setup, index, values, pure=False)] = (index, values,
                                                                                           time.monotonic())
            limit = point_timeout if point_timeout is not None else (
                FIRST_POINT_LIMIT if not times else max(MIN_POINT_LIMIT, 20.0 * statistics.median(times)))
            oldest = min(sent for _, _, sent in flying.values())
            try:
                finished_set, _ = wait(list(flying), timeout=max(0.05, min(oldest + limit - time.monotonic(), 1.0)),
                                       return_when="FIRST_COMPLETED")
            except TimeoutError:        # nothing finished within the wait
                finished_set = set()
            finished = []
            for future in finished_set:
                index, values, sent = flying.pop(future)
                try:
                    point = future.result()
                    times.append(point.wall_time or time.monotonic() - sent)
                except Exception as error:     # a worker lost, a value that does not pickle
                    point = SweepPoint(index, values, "failed", f"E968: the Dask task failed: "
                                                                f"{type(error).__name__}: {error}")
                finished.append(point)
            now = time.monotonic()
            for future, (index, values, sent) in list(flying.items()):
                if now - sent > limit:
                    del flying[future]
                    future.cancel()
                    finished.append(SweepPoint(index, values, "timed out",
                                               f"stopped after {limit:.3g} s (the limit per point; "
                                               "--point-timeout sets it)", wall_time=now - sent))
            for point in finished:
                done += 1
                on_done(point)
                if report is not None:
                    report(point, done, total)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _worker_main(setup: _Setup, connection) -> None:
    """A worker process: run the points it is sent, one at a time, until it is sent None."""
    _worker_signals()
    while True:
        try:
            task = connection.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        index, values = task
        started = time.perf_counter()
        point = _run_point(setup, index, values)
        point = dataclasses.replace(point, wall_time=time.perf_counter() - started)
        try:
            connection.send(point)
        except Exception as error:      # a value that does not pickle: send what can be sent
            connection.send(SweepPoint(index, values, "failed", f"E968: internal error: cannot send the result "
                                                                f"({type(error).__name__}: {error})",
                                       wall_time=point.wall_time))


class _Workers:
    """Worker processes with a time limit per point: a point over its limit is killed with its
    worker, recorded as timed out, and a new worker takes the next point."""

    def __init__(self, setup: _Setup, count: int):
        import multiprocessing

        methods = multiprocessing.get_all_start_methods()
        # fork: a worker starts with the base model already compiled in this process
        self.context = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
        self.setup = setup
        self.count = max(count, 1)
        self.idle: list = []
        self.busy: dict = {}            # connection -> (process, index, values, started)
        self.times: list[float] = []

    def _start(self):
        parent, child = self.context.Pipe()
        process = self.context.Process(target=_worker_main, args=(self.setup, child), daemon=True)
        process.start()
        child.close()
        return process, parent

    def limit(self, point_timeout: float | None) -> float:
        if point_timeout is not None:
            return point_timeout
        if not self.times:
            return FIRST_POINT_LIMIT
        return max(MIN_POINT_LIMIT, 20.0 * statistics.median(self.times))

    def run(self, tasks: list, point_timeout, on_done, report) -> None:
        from multiprocessing.connection import wait

        pending = list(reversed(tasks))
        total, done = len(tasks), 0
        self.idle = [self._start() for _ in range(min(self.count, total))]
        while pending or self.busy:
            while self.idle and pending:
                process, connection = self.idle.pop()
                index, values = pending.pop()
                connection.send((index, values))
                self.busy[connection] = (process, index, values, time.monotonic())
            limit = self.limit(point_timeout)
            now = time.monotonic()
            next_deadline = min(started + limit for _, _, _, started in self.busy.values())
            ready = wait(list(self.busy), timeout=max(0.0, min(next_deadline - now, 1.0)))
            finished = []
            for connection in ready:
                process, index, values, started = self.busy.pop(connection)
                try:
                    point = connection.recv()
                    self.idle.append((process, connection))
                    self.times.append(point.wall_time or (time.monotonic() - started))
                except (EOFError, OSError):
                    code = process.exitcode
                    process.join(timeout=1)
                    point = SweepPoint(index, values, "failed",
                                       f"E968: the worker process running this point died (exit code {code})",
                                       wall_time=time.monotonic() - started)
                    self.idle.append(self._start())
                finished.append(point)
            now = time.monotonic()
            for connection, (process, index, values, started) in list(self.busy.items()):
                if now - started > limit:
                    del self.busy[connection]
                    process.kill()
                    process.join(timeout=5)
                    connection.close()
                    finished.append(SweepPoint(
                        index, values, "timed out", f"stopped after {limit:.3g} s (the limit per point; "
                                                    "--point-timeout sets it)", wall_time=now - started))
                    if pending:
                        self.idle.append(self._start())
            for point in finished:
                done += 1
                on_done(point)
                if report is not None:
                    report(point, done, total)

    def stop(self) -> None:
        """Stop every worker now (Ctrl-C, SIGTERM, an error, or the end)."""
        for process, connection in self.idle:
            try:
                connection.send(None)
            except (OSError, ValueError):
                pass
        for process, *_ in list(self.busy.values()):
            process.kill()
        for process, connection in self.idle + [(v[0], k) for k, v in self.busy.items()]:
            process.join(timeout=2)
            if process.is_alive():
                process.kill()
                process.join(timeout=2)
            connection.close()
        self.idle, self.busy = [], {}


def _worker_signals() -> None:
    """In a worker: Ctrl-C (sent to the whole process group) is the parent's to handle, and
    SIGTERM ends the worker at once (the parent kills its workers when it stops)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


class _Progress:
    """Progress on stderr: a tqdm bar on a terminal (points done and failed, rate, ETA); elsewhere
    (CI logs) a plain line at most every :data:`PLAIN_PROGRESS_EVERY` seconds and at the end."""

    def __init__(self, total: int, stream=None, terminal: bool | None = None):
        self.stream = stream or sys.stderr
        self.total = total
        self.counts = {status: 0 for status in STATUSES}
        self.started = time.monotonic()
        self.last = self.started
        if terminal is None:
            try:
                terminal = self.stream.isatty()
            except (AttributeError, ValueError):
                terminal = False
        self.bar = None
        if terminal:
            from tqdm import tqdm

            self.bar = tqdm(total=total, file=self.stream, unit="point", desc="sweep", leave=False,
                            dynamic_ncols=True)

    def _states(self) -> str:
        return ", ".join(f"{n} {status}" for status, n in self.counts.items() if n and status != "ok")

    def __call__(self, point: SweepPoint, done: int, total: int) -> None:
        self.counts[point.status] = self.counts.get(point.status, 0) + 1
        if self.bar is not None:
            self.bar.update(1)
            states = self._states()
            if states:
                self.bar.set_postfix_str(states, refresh=False)
            return
        now = time.monotonic()
        if now - self.last >= PLAIN_PROGRESS_EVERY or done == total:
            self.last = now
            rate = done / max(now - self.started, 1e-9)
            left = (total - done) / rate if rate > 0 else float("nan")
            states = self._states()
            print(f"sweep: {done}/{total} points" + (f" ({states})" if states else "")
                  + f", {rate:.3g} points/s" + (f", about {left:.0f} s left" if done < total else ""),
                  file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _progress_reporter(progress, total: int):
    if callable(progress):
        return progress
    if not progress:
        return None
    return _Progress(total)
