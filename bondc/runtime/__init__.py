"""What bondc-generated modules run on: signals, switching modes, events, integration.

Takes a *model*: a generated module's namespace (its ``globals()``, the module itself, or any
object) with the names ``bondc.codegen`` writes (see :mod:`bondc.runtime.run`), and returns a
:class:`Result` from :func:`simulate_model`. Every name of the package's modules is importable
as ``bondc.runtime.X``.

The modules, one job each, in the order each imports only earlier ones (``MODULES``):

- ``kernels``: scipy's Brent root finder and QUADPACK without importing scipy; lazy scipy modules.
- ``signals``: ``table``, ``step``, measured csv signals (the one data-file reader), external inputs.
- ``loops``: nonlinear algebraic loops (hybr, then Newton from the guesses).
- ``adapter``: the model adapter (:class:`_Model`), parameters, the modes of recorded points,
  :func:`evaluate`.
- ``results``: :class:`Result`, :class:`LazyRows`, the one writer of result files (:func:`result_bytes`:
  csv, npz, parquet, each with its columns' units; :func:`write_result`), the result's size limits,
  the typed failure of a run (:class:`RunFailure`, carried by ``_Stop``), the result builder
  (``_ResultBuilder``) and the diagnosis of a failure (``_Diagnosis``).
- ``native``: bondc's C and C++ sources (``bondc/native``), compiler discovery (zig as the
  fallback), the SUNDIALS link, the build cache, :func:`attach_native`, :func:`load_policy`.
- ``policy``: the run loop's policy, whose one implementation is C (``bondc/native/policy.c``:
  ``filippov.c`` and ``locate.c``, the texts the CVODE driver and an FMU's engine include too):
  the modes at a restart, crossing location (humps inside a step too), the end of a sliding mode,
  the candidates and sliding set (Filippov's weights, affine holds, coulomb limits), the return
  onto the surfaces, the deadbands (:class:`SlidingLaw` gives them the model's laws).
- ``solvers``: CVODE, IDA, DOPRI5, scipy's methods (:func:`solver_class`), finite-difference
  Jacobians, and the run's choice of solver (``_SolverChoice``).
- ``steppers``: scipy's solvers (``Radau``, ``BDF``, ``LSODA``, ``RK45``, ...) as steppers of the C
  driver (the table of ``bondc/native/erk_api.h`` filled with callbacks), so that a run with any of
  them takes its crossings, sliding modes and restarts from the driver's C functions.
- ``driver``: bondc's C driver of CVODE (:class:`_NativeDriver`) and the segments a run integrates
  with it (``_DriverSegments``).
- ``events``: the known switching times and the roots of switches of time (``_KnownTimes``),
  crossings and restarts (through ``policy``), when clauses, Zeno (``_EventLocation``).
- ``sliding``: sliding segments and their recording, holding at a stall, through ``policy``
  (``_Sliding``).
- ``run``: the run specification (:class:`RunSpec`), :func:`simulate_model` and the step loop
  (:class:`_Run`).

Typed values between the parts: :func:`simulate_model` settles a frozen :class:`RunSpec` once and
gives it to ``_Run``; a run that stops early raises ``_Stop`` with a frozen :class:`RunFailure`
(``Result.run_failure``; ``Result.failure`` is its dict, as it always was).

``_Run`` is the step loop. Its *collaborators* are objects with an interface of their own, made
from the model, the parameters and the span, reading nothing else of the run: ``_KnownTimes``
(the breaks and switch-of-time roots before the run), ``_ResultBuilder`` (what the run recorded
made into a :class:`Result`), ``_Diagnosis`` (which quantity became non-finite, which state
diverged) and ``_NativeDriver`` (the C driver). Four parts are *mixins* of ``_Run`` instead, each
in the module of its job: ``_EventLocation`` (crossings, restart modes, when clauses, Zeno),
``_Sliding``, ``_DriverSegments`` and ``_SolverChoice``. Each of them reads and updates most of
the run's state (the current solver and its dense output, the modes and the switches watched, the
recorded blocks, the events, the counts in ``stats``, the sliding and chattering bookkeeping) and
calls the others back (a sliding segment locates crossings, records points and hands over to the
C driver; the driver hands back to the step loop, which restarts through the event part), so as
collaborators each would need the whole run as its argument. The mixins share no names, so their
order does not matter.

A standalone generated module (``bondc compile --standalone``, and what ``bondc simulate`` runs
in-process) carries the text of these modules in ``MODULES`` order, each with its imports of the
others commented out (``bondc.codegen.emit.runtime_source``): one namespace, as one file was
before. So no two modules define the same name, and none rebinds another's global (the layout
test checks both).
"""


# Every name of every module, as ``bondc.runtime.X`` (the generated modules import them; a
# standalone module carries the modules' text instead: ``bondc.codegen.emit.runtime_source``).
from bondc.runtime.kernels import (  # noqa: F401
    RUNTIME_VERSION, _EPS, _LazyModule, _integrate, _optimize, _quadpack_probe, _scipy_kernel, _zeros_probe, brentq,
    quad
)
from bondc.runtime.signals import (  # noqa: F401
    CsvError, InputError, MAX_DATA_BYTES, _CSV_CACHE, _call_input, _input_number, _with_inputs, as_time,
    csv_columns, csv_header, csv_rows, csv_signal, csv_times, external_inputs, external_signal, external_times,
    first_decrease, header_cell, load_csv, open_data, stack, step, table
)
from bondc.runtime.loops import (  # noqa: F401
    LOOP_START_OFFSETS, _BLOCK_SOLUTIONS, _ModeReader, _READING_MODES, _ReadingModes, _at_rounding, _newton_step,
    newton_search, solve_block, solve_loop
)
from bondc.runtime.adapter import (  # noqa: F401
    _MEMOS, _MODEL_NAMES, _Model, _PATTERNS, _columns_by_mode, _model_memo, evaluate, mode_values, modes_at,
    param_array, pattern_arrays
)
from bondc.runtime.policy import (  # noqa: F401
    SlidingLaw, TooManyHeld, _LAW_SIGNATURE, _doubles, _is_affine, _locate, _values_callback, corner_weights,
    filippov_alpha, first_crossing, first_dip, first_end, when_rounds, zeno, zeno_firings
)
from bondc.runtime.results import (  # noqa: F401
    DIVERGED, LazyRows, MAX_POINTS, MAX_VALUES, Result, RunFailure, _CountedBlocks, _Deferred, _Diagnosis,
    _ResultBuilder, _Stalled, _Stop, _evaluate_columns, _unique_rows, max_points, write_csv,
    RESULT_FORMATS, _header_cell, column_name, result_bytes, shown_columns, result_format, write_result
)
from bondc.runtime.native import (  # noqa: F401
    Compiler, UNIT_MARK, _COMPILERS, _COMPILER_PROBES, _ERK_FLAGS, _ERK_LOADED, _NATIVE_AT_FUNCTIONS,
    _NATIVE_BY_TEXT, _NATIVE_FILES, _NATIVE_FLAGS, _NATIVE_FUNCTIONS, _NATIVE_LIBRARIES, _NATIVE_NOTES,
    _NATIVE_OPTIMIZE, _NATIVE_PENDING, _NATIVE_POINT_FUNCTIONS, _NATIVE_READ, _NATIVE_SPLIT_FROM, _NativeBuild,
    _SUNDIALS_PARTS, _SYSTEM_COMPILERS, _ZIG_FLAGS, _POLICY_FLAGS, _POLICY_LOADED, NativeUnavailable, _build_erk, _build_native, _engine_library, _choose_compiler, _discard_pending,
    _link_flags, _native_plan, _native_units, _native_variants, _probe_compiler, _sundials_link, _zig,
    attach_native, cache_dir, compiler_label, find_compiler, load_erk, load_native, load_policy, native_build_text, native_file,
    native_text, native_turned_off, start_native
)
from bondc.runtime.solvers import (  # noqa: F401
    CVODE, CVODE_Adams, CvodeSolver, DEFAULT_SOLVER, DOPRI5, IDA, SOLVER_NAMES, _CREEP, _CREEP_STEPS,
    _CVODE_METHODS, _FiniteJacobian, _IMPLICIT, _METHODS, _NotFinite, _SUNDIALS_FOUND, _SolverChoice,
    _UNFROZEN_STEPS, _all_finite, _creeping, difference_jacobian, solver_class, stiff_solver,
    sundials_available
)
from bondc.runtime.steppers import (  # noqa: F401
    _DENSE_UP_TO, _RatesFailed, _STEPPER_DRIVERS, _STEPPER_TABLES, _StepperRun, _StepperTable, _TAKE_JACOBIAN,
    _driver_jacobian, register_stepper_driver, stepper_table
)
from bondc.runtime.driver import (  # noqa: F401
    _DriverSegments, _DriverStep, _NativeDriver, _Piece
)
from bondc.runtime.events import (  # noqa: F401
    _EventLocation, _HIDDEN_LEVELS, _HIDDEN_SPLIT, _HIDDEN_VALUES, _KnownTimes, _hidden_changes, _zero_touches,
    bracketed_roots
)
from bondc.runtime.sliding import (  # noqa: F401
    SLIDING_CHECKS, _MAX_HELD, _MAX_SLIDING, _Sliding
)
from bondc.runtime.run import (  # noqa: F401
    RunSpec, _PADDING, _Run, _STALL_FRACTION, _STALL_RESTARTS, _padded, output_grid, simulate_model
)


#: The modules in the order a standalone module carries them (each imports only earlier ones).
MODULES = ('kernels', 'signals', 'loops', 'adapter', 'results', 'native', 'policy', 'solvers', 'steppers', 'driver', 'events', 'sliding', 'run')
