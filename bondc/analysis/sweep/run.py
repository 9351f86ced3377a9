"""``bondc sweep`` without argument parsing: a ``.bg`` file + ``--vary`` texts -> :class:`SweepResult`.

:func:`run_sweep` checks the request, plans the grid (and the points a resumed study already has),
runs the rest (:mod:`~bondc.analysis.sweep.execute`) and writes the table."""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from bondc.analysis.sweep.execute import _progress_reporter, _run_all
from bondc.analysis.sweep.grid import MAX_RUNS, Axis, _check_axes, _usage, latin_hypercube, parse_range, parse_vary
from bondc.analysis.sweep.metrics import select_metrics
from bondc.analysis.sweep.point import _base, _BASES, _can_bind, _COUNTER, _Setup
from bondc.analysis.sweep.study import (
    _check_grid, _check_study, _described, _Journal, _key, _previous_points, _study, _write_study,
)
from bondc.analysis.sweep.table import SweepPoint, SweepResult
from bondc.pipeline import Checked, check_file, parse_sets
from bondc import codes


def run_sweep(path, *, model: str | None = None, experiment: str | None = None, sets: Sequence = (),
              vary: Sequence[str] = (), samples: int | None = None, ranges: Sequence[str] = (),
              seed: int | None = None, metrics: Sequence[str] | None = None, output=None, jobs: int = 1,
              t_end: float | None = None, dt: float | None = None, rederive: bool = False,
              progress: bool | Callable[[SweepPoint, int, int], None] = False,
              point_timeout: float | None = None, motors=None, executor: str = "local",
              scheduler: str | None = None, inertia_ratio: float | None = None) -> SweepResult:
    """``bondc sweep``: run the model at every point of the grid of ``vary`` (or at ``samples``
    Latin-hypercube points over ``ranges``, reproducible with ``seed``); see the module docstring.

    ``sets`` are ``--set`` texts or parsed ``ast.SetValue`` applied to every
    point; ``experiment`` None takes the first; ``t_end``/``dt`` override the
    experiment's; ``output`` a ``.csv`` (rows appended as points finish) or
    ``.json`` path. When ``output`` already holds points of the same sweep,
    they are kept and only the others run (resuming). ``point_timeout``:
    seconds a point may take (None: 20 times the median, at least 60 s; 0: no
    limit, points run in this process). ``motors``: a motor catalogue (csv);
    each point lists the motors that pass the sizing rules of ``bondc simulate --motors``,
    smallest (the point's choice) first; ``inertia_ratio`` is every motor's load/rotor
    inertia-ratio limit (default: the catalogue's, else 10). ``progress`` True shows progress
    on stderr, or is called as ``progress(point, done, total)``. ``executor``
    "local" runs ``jobs`` worker processes here; "dask" runs the points on a
    ``dask.distributed`` cluster: ``scheduler`` (``tcp://host:8786``) or a
    ``LocalCluster`` of ``jobs`` workers (the model file must be readable at
    the same path on every worker).

    Raises UsageError (E960-E967, E969, E970) for a bad request and the stage
    errors of loading or deriving the base model; a point that fails is
    recorded, not raised (:attr:`SweepResult.exit_code`). Ctrl-C and SIGTERM
    stop the sweep after writing every finished point; the exception raised
    carries the partial result as ``sweep_result``.
    """
    executor = _check_request(vary, samples, ranges, jobs, executor, scheduler, point_timeout, output)
    axes = _axes(vary, samples, ranges)
    parsed_sets = tuple(parse_sets(sets))
    # checked before anything is derived
    checked = check_file(path, model=model, experiment=experiment, sets=parsed_sets)
    plan = _plan(checked, path, model=model, experiment=experiment, sets=sets, axes=axes, metrics=metrics,
                 samples=samples, seed=seed, t_end=t_end, dt=dt, rederive=rederive, motors=motors,
                 inertia_ratio=inertia_ratio, point_timeout=point_timeout, executor=executor)
    done = _resumed(output, plan, axes, samples, seed)
    tasks = [(index, values) for index, values in enumerate(plan.grid) if index not in done]

    base = _base(plan.setup, checked)     # before any worker starts: forked workers inherit it
    setup = plan.setup
    if tasks and _can_bind(setup, base, plan.grid):
        setup = dataclasses.replace(setup, bound=True)
    table = dataclasses.replace(plan.table, warnings=base.notes)
    journal = None
    if output is not None and Path(output).suffix.lower() == ".csv":
        journal = _Journal(output, table.csv_header())
        _write_study(output, plan.table.settings["study"], _described(checked.graph, path, checked.experiment, axes,
                                                            plan.shown_units, setup.converters, table.metrics))
    report = _progress_reporter(progress, len(tasks))

    def on_done(point: SweepPoint) -> None:
        if not point.parameters:        # stopped before it loaded (timed out): its values in SI all the same
            point = dataclasses.replace(point, parameters={
                name: converter.to_si(value) for name, converter, value in zip(setup.names, setup.converters,
                                                                              point.values)})
        done[point.index] = point
        if journal is not None:
            journal.add(table.csv_row(point))

    try:
        if tasks:
            _run_all(setup, tasks, jobs, report, point_timeout, on_done, executor, scheduler)
    except KeyboardInterrupt as interrupt:
        result = _with_points(table, done.values())
        _finish(result, output, journal)
        interrupt.sweep_result = result         # type: ignore[attr-defined]
        raise
    finally:
        _BASES.pop(setup.key, None)
        if report is not None and hasattr(report, "close"):
            report.close()
    result = _with_points(table, done.values())
    _finish(result, output, journal)
    return result


def _check_request(vary: Sequence[str], samples: int | None, ranges: Sequence[str], jobs: int, executor: str,
                   scheduler: str | None, point_timeout: float | None, output: Any) -> str:
    """E960, E967, E969, E971 for a request that cannot be run; the executor to run it on."""
    if not vary and not samples:
        raise _usage(codes.E960, "nothing to vary", hint='give --vary, e.g. --vary "k=400,800,1600", or --samples N '
                                                    'with --range NAME=LOW:HIGH')
    if vary and (samples or ranges):
        raise _usage(codes.E960, "give either --vary (a grid) or --samples with --range (a Latin hypercube)")
    if samples is not None and (not isinstance(samples, int) or samples < 1 or not ranges):
        raise _usage(codes.E960, "--samples needs a whole number >= 1 and at least one --range NAME=LOW:HIGH")
    if not isinstance(jobs, int) or jobs < 1:
        raise _usage(codes.E967, f"jobs must be a whole number >= 1, got {jobs!r}")
    if executor not in ("local", "dask"):
        raise _usage(codes.E971, f"unknown executor {executor!r}", hint="choose local or dask")
    if scheduler and executor != "dask":
        executor = "dask"           # --scheduler means a Dask cluster
    if point_timeout is not None and not point_timeout >= 0:
        raise _usage(codes.E967, f"--point-timeout must be a number of seconds >= 0 (0: no limit), got {point_timeout!r}")
    if output is not None and Path(output).suffix.lower() not in (".csv", ".json"):
        raise _usage(codes.E969, f"cannot write '{output}': give a .csv or .json file")
    if output is not None:
        from bondc.io import check_output

        check_output(output, "the sweep table")
    return executor


def _axes(vary: Sequence[str], samples: int | None, ranges: Sequence[str]) -> list[Axis]:
    """The axes of the grid (``vary``) or of the Latin hypercube (``ranges``); E964 for too many runs."""
    axes = [parse_range(text) for text in ranges] if samples else [parse_vary(text) for text in vary]
    runs = samples if samples else math.prod(len(axis.values) for axis in axes)
    if runs > MAX_RUNS:
        shape = f" ({' x '.join(str(len(axis.values)) for axis in axes)})" if len(axes) > 1 and not samples else ""
        raise _usage(codes.E964, f"the sweep has {runs} runs{shape}; at most {MAX_RUNS} are allowed",
                     hint="use fewer values, or split the sweep")
    return axes


@dataclass(frozen=True)
class _Plan:
    """A checked request: what every point needs, the points, and the table without its rows."""

    setup: _Setup
    grid: list[tuple[float, ...]]
    keys: list[tuple[Any, ...]]         # each point's parameter values in SI (as a resumed file has them)
    shown_units: tuple[str | None, ...]
    table: SweepResult                  # no points yet


def _plan(checked: Checked, path: Any, *, model: str | None, experiment: str | None, sets: Sequence[Any],
          axes: list[Axis], metrics: Sequence[str] | None, samples: int | None, seed: int | None,
          t_end: float | None, dt: float | None, rederive: bool, motors: Any, inertia_ratio: float | None,
          point_timeout: float | None, executor: str) -> _Plan:
    """The request checked against the model (its axes, metrics, end time, motor catalogue), its
    points, and what the study is computed from (``settings``)."""
    graph, chosen = checked.graph, checked.experiment
    shown_units, si_units, converters = _check_axes(graph, axes, checked.sets)
    chosen_metrics = select_metrics(graph, metrics)
    end = t_end if t_end is not None else chosen.t_end if chosen is not None else None
    if end is None:
        raise _usage(codes.E801, "no end time for the simulation", hint="give --t-end, or set t_end in the experiment")
    if motors is not None:
        from bondc.analysis.motors import load_catalogue

        load_catalogue(motors)          # a bad catalogue is an error now, not at every point
    from bondc.analysis.motors import check_inertia_limit

    inertia_ratio = check_inertia_limit(inertia_ratio)
    setup = _Setup(key=(os.getpid(), next(_COUNTER)), path=str(path), model=model,
                   experiment=experiment, sets=checked.sets, names=tuple(axis.name for axis in axes),
                   units=tuple(axis.unit for axis in axes), converters=tuple(converters),
                   metrics=tuple(m.name for m in chosen_metrics), t_end=t_end, dt=dt, rederive=rederive,
                   motors=str(motors) if motors is not None else None,
                   inertia_ratio=inertia_ratio)
    grid = latin_hypercube(axes, samples, seed) if samples else list(itertools.product(*(axis.values for axis in axes)))
    names = [axis.name for axis in axes]
    keys = [_key({n: c.to_si(v) for n, c, v in zip(names, converters, values)}, names) for values in grid]
    settings: dict[str, Any] = {"t_end": end, "dt": dt,
                                "rederive": rederive, "point_timeout": point_timeout, "executor": executor}
    if samples:
        settings.update(samples=samples, seed=seed)
    settings["study"] = _study(graph, model, experiment, sets, settings["t_end"], dt, motors, inertia_ratio)
    table = SweepResult(model=graph.name, experiment=chosen.name if chosen is not None else None,
                        file=str(path), axes=tuple(axes),
                        axis_units=tuple(shown_units), axis_si_units=tuple(si_units), metrics=chosen_metrics,
                        points=(), settings=settings, total=len(grid), motors=motors is not None)
    return _Plan(setup, grid, keys, tuple(shown_units), table)


def _resumed(output: Any, plan: _Plan, axes: list[Axis], samples: int | None, seed: int | None
             ) -> dict[int, SweepPoint]:
    """The points ``output`` holds already (a sweep resumed), by grid index; E970 when they are
    another study's, or points this grid would drop."""
    if output is None:
        return {}
    table = plan.table
    previous = _previous_points(output, table.csv_header(), axes, table.metrics, table.motors)
    if previous:
        _check_study(output, table.settings["study"])
        _check_grid(output, previous, plan.keys, axes, samples, seed)
    return {index: dataclasses.replace(previous[key], index=index, values=values)
            for index, (key, values) in enumerate(zip(plan.keys, plan.grid)) if key in previous}


def _with_points(table: SweepResult, points: Iterable[SweepPoint]) -> SweepResult:
    """``table`` with ``points`` as its rows, in grid order."""
    return dataclasses.replace(table, points=tuple(sorted(points, key=lambda p: p.index)))


def _finish(result: SweepResult, output, journal) -> None:
    """Close the journal and write the whole table in grid order (atomically)."""
    if journal is not None:
        journal.close()
    if output is not None:
        result.write(output)
