"""Parameter sweeps: a ``.bg`` file + ``--vary`` specs -> :class:`SweepResult` (one row per grid point).

The package's modules, in the order a sweep uses them: :mod:`~bondc.analysis.sweep.grid` (the
``--vary``/``--range`` texts -> axes and points), :mod:`~bondc.analysis.sweep.metrics` (what each
point measures), :mod:`~bondc.analysis.sweep.table` (the rows and the table), :mod:`~bondc.analysis.
sweep.point` (one point run), :mod:`~bondc.analysis.sweep.execute` (the points in worker processes
or on Dask), :mod:`~bondc.analysis.sweep.study` (the csv journal, resuming) and
:mod:`~bondc.analysis.sweep.run` (:func:`run_sweep`, the whole command).

:func:`run_sweep` is ``bondc sweep`` without argument parsing. Each ``vary``
text names a parameter and its values::

    "k=400,800,1600"          a list, in the parameter's declared unit (as --set)
    "lead=5,10 [mm]"          a list in the given unit (converted by bondc.units)
    "M=20:40:5 [kg]"          start:stop:count, count values from start to stop inclusive
    "k=100, 200:400:3"        items mix: 100, 200, 300, 400

Several specs make a full grid (the cartesian product, the first spec
varying slowest, rows ordered by grid index), at most :data:`MAX_RUNS` runs.

**How a point is run.** The model is loaded, checked, derived and compiled
once, with the base ``sets``. A point is then a vector of values (late
binding, ``path`` "bound"): the varied parameters in SI go to the compiled
module, which recomputes every parameter defined by others (the flagship's
``F_n0 = M*g - ...``, ``delta0``, ``theta0``); the file is not read again, so
editing it during a study changes nothing. When a varied parameter also sets
something the check fixes outside the compiled module (an experiment setting
such as ``max_step = h``, seen by loading the first and the last point), every
point loads the file again with its values as ``--set`` overrides ("fast"), so
units and validation follow exactly the ``--set`` rules; ``rederive=True``
also derives and compiles again for every point ("rederived"), for a model
whose derivation depends on parameter values (a nonlinear law inverted with
``sympy.solve`` keeps the branch that reproduces the law at the parameters'
values).

**What each point gives** (SI in :meth:`SweepResult.to_json` and the csv;
the text table shows the outputs' declared units):

* for every output: ``NAME.min``, ``NAME.max``, ``NAME.rms``, ``NAME.final``
  (and ``NAME.mean`` on request), from :func:`~bondc.analysis.stats.output_statistics`;
* for every output declared in a unit of power, over the experiment's first
  cycle: ``NAME.cycle_peak``, ``NAME.cycle_rms`` [W], ``NAME.cycle_energy``
  (net), ``NAME.cycle_energy_positive``, ``NAME.cycle_energy_negative`` [J]
  (:func:`~bondc.analysis.stats.power_statistics`);
* ``energy.residual``: the energy balance residual summed over the cycles
  [J], and ``energy.relative_residual``: its largest share of a cycle's
  throughput (:func:`~bondc.analysis.energy.energy_account`);
* when the model has an output ``torque`` and an output or input ``omega``
  or ``speed`` (:mod:`bondc.analysis.motor_report`), the motor
  requirements over the experiment's cycle: ``motor.peak_torque``,
  ``motor.rms_torque`` [N*m], ``motor.peak_speed`` [rad/s],
  ``motor.peak_power`` [W], ``motor.energy`` (net energy per cycle) [J].

``metrics`` selects columns (``torque.max``, ``x.final``,
``energy.residual``, ``x.*``, ``motor.*``); None takes them all (without
the means). Only what is selected is computed.

**Failures.** A point that cannot be loaded or whose run stops early (a law
that gives nan, a solver failure) gets ``status`` "failed", its message and
diagnostics, and the sweep goes on; :attr:`SweepResult.exit_code` is then 1.
A metric that cannot be computed for a point that ran (energy account, motor
profile) is nan with a warning, and the point is "incomplete".

**Running the points.** Points run in ``jobs`` worker processes (forked with
the base model compiled), each with a time limit (``point_timeout``, default
20 times the median point time, at least 60 s): a point over its limit is
killed with its worker and recorded as "timed out". ``point_timeout=0`` runs
them one after the other in this process. ``executor="dask"`` runs them on a
``dask.distributed`` cluster instead. Every point is computed the same way in
whichever process, so the result does not depend on ``jobs`` or the executor.
Rows are appended to the csv as points finish (flushed), Ctrl-C and SIGTERM
keep them, and running the same sweep again resumes: the points already in the
file (matched by their parameter values) are not run again. What they were
computed from (the text of the model file and its imports, the model,
experiment, --set values, t_end, dt and motor catalogue) is recorded beside a
csv table in ``<table>.csv.study`` and inside a json one; a resume with any of
these changed is E970, not a table mixing two studies. A sweep never rewrites
its file without the finished points it holds: a grid (or Latin hypercube)
that leaves out some of them is E970 too, and the file is left as it is; a
grid that holds them all extends the study. A row cut short by a killed run
is not a point, and runs again.

**Statuses.** "ok"; "failed" (it did not load, or its run stopped early);
"timed out"; "incomplete" (it ran, but a metric or the motor selection could
not be computed: never "ok" with nan).

Problems with the request are :class:`~bondc.errors.UsageError` with codes
E960 (a vary text that is not ``NAME=VALUES [unit]``, or an empty list),
E961 (not a parameter), E962 (a value that is not a finite number, a bad
``start:stop:count``), E963 (a unit bondc does not know, or of another
quantity than the parameter's), E964 (more than :data:`MAX_RUNS` runs),
E965 (an unknown metric), E966 (a parameter varied twice, or varied and
``--set``), E967 (jobs < 1, a negative time limit), E969 (an output file
that is not .csv or .json), E970 (an output file holding another sweep's
table, points this sweep would drop, or a file bondc did not write), E971 (Dask not installed, an unknown executor, an unreachable
scheduler). E968 is a failed point's diagnostic when it has none of its own
(the model file changed during the sweep, a worker process died, an
internal error).

>>> axis = parse_vary("M=20:40:5 [kg]")
>>> axis.name, axis.values, axis.unit
('M', (20.0, 25.0, 30.0, 35.0, 40.0), 'kg')
>>> parse_vary("k=100, 200:400:3").values
(100.0, 200.0, 300.0, 400.0)
>>> parse_vary("k=abc")
Traceback (most recent call last):
...
bondc.errors.UsageError: --vary 'k=abc': 'abc' is not a number
"""

from __future__ import annotations

from bondc.analysis.sweep.execute import FIRST_POINT_LIMIT, MIN_POINT_LIMIT, PLAIN_PROGRESS_EVERY
from bondc.analysis.sweep.grid import MAX_RUNS, Axis, _resolve_unit, latin_hypercube, parse_range, parse_vary
from bondc.analysis.sweep.metrics import (
    CYCLE_STATISTICS, DEFAULT_OUTPUT_STATISTICS, ENERGY_METRICS, MOTOR_METRICS, MOTOR_RULES, OUTPUT_STATISTICS,
    Metric, select_metrics,
)
from bondc.analysis.sweep.run import run_sweep
from bondc.analysis.sweep.study import study_file
from bondc.analysis.sweep.table import STATUSES, SweepPoint, SweepResult

__all__ = ["run_sweep", "parse_vary", "parse_range", "latin_hypercube", "select_metrics", "study_file", "Axis",
           "Metric", "SweepPoint", "SweepResult", "MAX_RUNS", "STATUSES", "MIN_POINT_LIMIT", "FIRST_POINT_LIMIT",
           "PLAIN_PROGRESS_EVERY", "OUTPUT_STATISTICS", "DEFAULT_OUTPUT_STATISTICS", "ENERGY_METRICS",
           "CYCLE_STATISTICS", "MOTOR_METRICS", "MOTOR_RULES", "_resolve_unit"]
