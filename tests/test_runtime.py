"""bondc.runtime on its own: signals, parameters, and the integrator on hand-written models.

The models here are written by hand (no code generation), so these tests pin
the event machinery independently of bondc.codegen: a known crossing time, a
known-time step that must not be stepped across, and a sliding mode whose
Filippov solution is known exactly.
"""

import io
import math

import numpy as np
import pytest

from bondc import runtime


# ------------------------------------------------------------------ signals

def test_table_is_piecewise_linear_and_held_at_the_ends():
    ts, vs = (0.0, 1.0, 3.0), (0.0, 10.0, -10.0)
    assert float(runtime.table(0.5, ts, vs)) == 5.0
    assert float(runtime.table(2.0, ts, vs)) == 0.0
    assert float(runtime.table(-1.0, ts, vs)) == 0.0
    assert float(runtime.table(7.0, ts, vs)) == -10.0
    np.testing.assert_allclose(runtime.table(np.array([0.25, 1.0, 2.5]), ts, vs), [2.5, 10.0, -5.0])


def test_step_is_zero_before_and_one_from_its_time():
    assert runtime.step(0.0999999, 0.1) == 0.0
    assert runtime.step(0.1, 0.1) == 1.0
    np.testing.assert_array_equal(runtime.step(np.array([0.0, 0.1, 0.2]), 0.1), [0.0, 1.0, 1.0])


def test_csv_signal_uses_the_time_column_and_interpolates(tmp_path):
    path = tmp_path / "speed.csv"
    path.write_text("# measured\nomega,time,torque\n0,0,5\n10,1,6\n10,2,7\n")
    assert float(runtime.csv_signal(0.5, str(tmp_path), "speed.csv", "omega")) == 5.0
    assert float(runtime.csv_signal(5.0, str(tmp_path), "speed.csv", "torque")) == 7.0
    np.testing.assert_array_equal(runtime.csv_times(str(tmp_path), "speed.csv", "omega"), [0, 1, 2])


def test_csv_signal_without_time_column_uses_the_first(tmp_path):
    path = tmp_path / "f.csv"
    path.write_text("s,force\n0,0\n2,4\n")
    assert float(runtime.csv_signal(1.0, str(tmp_path), "f.csv", "force")) == 2.0


def test_csv_errors_name_the_problem(tmp_path):
    (tmp_path / "a.csv").write_text("t,x\n0,1\n")
    with pytest.raises(ValueError, match="no column 'y'.*columns: t, x"):
        runtime.load_csv(str(tmp_path / "a.csv"), "y")
    (tmp_path / "b.csv").write_text("t,x\n1,1\n0,2\n")
    with pytest.raises(ValueError, match="must not decrease"):
        runtime.load_csv(str(tmp_path / "b.csv"), "x")


# --------------------------------------------------------------- parameters

def test_param_array_accepts_none_dict_and_array():
    parameters = {"m": 2.0, "k": 800.0}
    np.testing.assert_array_equal(runtime.param_array(parameters), [2.0, 800.0])
    np.testing.assert_array_equal(runtime.param_array(parameters, {"k": 1}), [2.0, 1.0])
    np.testing.assert_array_equal(runtime.param_array(parameters, [3, 4]), [3.0, 4.0])
    with pytest.raises(KeyError, match="unknown parameter kk"):
        runtime.param_array(parameters, {"kk": 1})
    with pytest.raises(ValueError, match="2 entries"):
        runtime.param_array(parameters, [1.0])


def test_output_grid_includes_the_end():
    np.testing.assert_allclose(runtime.output_grid(0.0, 1.0, 0.25), [0, 0.25, 0.5, 0.75, 1.0])
    grid = runtime.output_grid(0.0, 1.0, 0.3)
    np.testing.assert_allclose(grid, [0, 0.3, 0.6, 0.9, 1.0])
    assert runtime.output_grid(0.0, 0.3, 0.1).size == 4


# ------------------------------------------------------- hand-written models

def _namespace(**overrides):
    """A model with every name the runtime needs; tests replace the functions."""
    namespace = {
        "STATE_NAMES": ("x",), "OUTPUT_NAMES": ("y",), "VARIABLE_NAMES": ("y",), "VARIABLE_LAWS": ("y",),
        "PARAMETERS": {"a": 1.0}, "SWITCHES": (), "EVENT_SWITCHES": (), "DEFAULTS": {},
        "x0": lambda p: np.array([1.0]),
        "_rhs": lambda t, x, p, m: np.array([-p[0] * x[0]]),
        "_jac": lambda t, x, p, m: np.array([[-p[0]]]),
        "_switches": lambda t, x, p, m: np.zeros(0),
        "_outputs": lambda t, x, p, m: (2 * x[0],),
        "_variables": lambda t, x, p, m: (2 * x[0],),
        "_time_breaks": lambda p: [],
    }
    namespace.update(overrides)
    return namespace


def test_smooth_model_matches_the_exponential():
    result = runtime.simulate_model(_namespace(), 2.0, {"a": 3.0}, rtol=1e-9, atol=1e-12)
    assert result.complete
    np.testing.assert_allclose(result.states["x"], np.exp(-3.0 * result.t), rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(result.outputs["y"], 2 * result.states["x"])


def test_known_time_step_is_a_segment_boundary_not_stepped_across():
    # dx/dt = step(t, 0.5) written frozen: the mode of g = t - 0.5 selects 0 or 1
    model = _namespace(
        x0=lambda p: np.array([0.0]),
        _rhs=lambda t, x, p, m: np.array([1.0 if m[0] >= 0 else 0.0]),
        _jac=lambda t, x, p, m: np.zeros((1, 1)),
        SWITCHES=("step(t, 0.5)",), EVENT_SWITCHES=(),
        _switches=lambda t, x, p, m: np.array([t - 0.5]),
        _time_breaks=lambda p: [(0.5, "step(t, 0.5)", "step")],
    )
    result = runtime.simulate_model(model, 1.0, method="RK45")
    assert result.complete
    assert result.states["x"][-1] == pytest.approx(0.5, abs=1e-12)
    assert result.events == [(0.5, "step(t, 0.5) -> +1")]


def test_state_event_is_located_at_the_crossing():
    # x' = -1 while x > 0.3 (mode +1 of g = x - 0.3), then x' = -2: x reaches 0.3 at t = 0.7
    model = _namespace(
        _rhs=lambda t, x, p, m: np.array([-1.0 if m[0] > 0 else -2.0]),
        _jac=lambda t, x, p, m: np.zeros((1, 1)),
        SWITCHES=("if x > 0.3",), EVENT_SWITCHES=(0,),
        _switches=lambda t, x, p, m: np.array([x[0] - 0.3]),
    )
    result = runtime.simulate_model(model, 0.9, rtol=1e-10, atol=1e-12)
    assert result.complete
    (time, label), = result.events
    assert time == pytest.approx(0.7, abs=1e-12)
    assert label == "if x > 0.3 -> -1"
    assert result.states["x"][-1] == pytest.approx(0.3 - 2 * 0.2, abs=1e-10)


def test_sliding_mode_follows_the_filippov_solution():
    # x' = 0.5 - sign(x): x = 1 - t/2 until t = 2, then x stays 0 (Filippov: below 0 the law pushes
    # it back up at 1.5), where the equivalent sign, the weight that holds x' = 0, is 0.5
    model = _namespace(
        _rhs=lambda t, x, p, m: np.array([0.5 - m[0]]),
        _jac=lambda t, x, p, m: np.zeros((1, 1)),
        SWITCHES=("sign(x)",), EVENT_SWITCHES=(0,),
        _switches=lambda t, x, p, m: np.array([x[0]]),
        _outputs=lambda t, x, p, m: (m[0] + 0 * x[0],),
        _variables=lambda t, x, p, m: (m[0] + 0 * x[0],),
    )
    result = runtime.simulate_model(model, 3.0, dt=0.25)
    assert result.complete
    expected = np.maximum(1.0 - 0.5 * result.t, 0.0)
    np.testing.assert_allclose(result.states["x"], expected, atol=1e-8)
    starts = [time for time, label in result.events if label == "sliding on sign(x)"]
    assert starts == [pytest.approx(2.0, abs=1e-9)]
    assert all(time == pytest.approx(2.0, abs=1e-9) for time, _ in result.events)
    after = result.t > 2.0
    np.testing.assert_allclose(result.outputs["y"][after], 0.5, atol=1e-6)   # the Filippov sign
    np.testing.assert_array_equal(result.outputs["y"][result.t < 2.0], 1.0)
    assert result.stats["sliding_segments"] == 1


def test_variables_are_evaluated_when_first_read_and_follow_their_laws():
    """A run stores its states; the variables are evaluated from them when one is first read (once),
    and equal their laws there: y = 2 x = 2 exp(-3 t) on a smooth run, the Filippov sign (0.5 while
    sliding) on a sliding one. States and variables are read-only; a pickle holds plain arrays."""
    import pickle

    calls = []

    def counted(law):
        def variables(t, x, p, m):
            calls.append(t)
            return law(t, x, p, m)
        return variables

    result = runtime.simulate_model(_namespace(_variables=counted(lambda t, x, p, m: (2 * x[0],))), 2.0,
                                    {"a": 3.0}, rtol=1e-9, atol=1e-12)
    assert result.complete and not calls and not result.variables.evaluated
    assert list(result.variables) == ["y"] and "y" in result.variables and len(result.variables) == 1
    np.testing.assert_allclose(result.variables["y"], 2 * np.exp(-3.0 * result.t), rtol=1e-7, atol=1e-12)
    evaluated = len(calls)
    assert evaluated and result.variables.evaluated
    assert result.variables["y"] is result.variables["y"] and len(calls) == evaluated
    for array in (result.variables["y"], result.states["x"], result.t):
        with pytest.raises(ValueError):
            array[0] = 0.0
    copied = pickle.loads(pickle.dumps(result.variables))
    assert type(copied) is dict and np.array_equal(copied["y"], result.variables["y"])

    # the parameters of the run, even when the caller changes its array before the first read
    p = np.array([3.0])
    result = runtime.simulate_model(_namespace(_variables=lambda t, x, p, m: (p[0] * x[0],)), 2.0, p,
                                    rtol=1e-9, atol=1e-12)
    p[0] = 100.0
    np.testing.assert_allclose(result.variables["y"], 3.0 * np.exp(-3.0 * result.t), rtol=1e-7, atol=1e-12)

    calls.clear()
    sliding = _namespace(
        _rhs=lambda t, x, p, m: np.array([0.5 - m[0]]), _jac=lambda t, x, p, m: np.zeros((1, 1)),
        SWITCHES=("sign(x)",), EVENT_SWITCHES=(0,), _switches=lambda t, x, p, m: np.array([x[0]]),
        _outputs=lambda t, x, p, m: (m[0] + 0 * x[0],), _variables=counted(lambda t, x, p, m: (m[0] + 0 * x[0],)))
    result = runtime.simulate_model(sliding, 3.0, dt=0.25)
    assert result.stats["sliding_segments"] == 1 and not calls
    y = result.variables["y"]
    np.testing.assert_array_equal(y[result.t < 2.0], 1.0)
    np.testing.assert_allclose(y[result.t > 2.0], 0.5, atol=1e-6)
    np.testing.assert_array_equal(y, result.outputs["y"])


@pytest.mark.parametrize("method", ["RK45", "Radau", "BDF"])
def test_nonfinite_derivative_stops_the_run_and_names_the_variable(method):
    # y = sqrt(x - 0.5) with x = 1 - t: nan from t = 0.5
    model = _namespace(
        _rhs=lambda t, x, p, m: np.array([-1.0 + 0 * np.sqrt(x[0] - 0.5)]),
        _jac=lambda t, x, p, m: np.zeros((1, 1)),
        VARIABLE_NAMES=("root",), VARIABLE_LAWS=("sqrt(x - 0.5)",),
        _variables=lambda t, x, p, m: (np.sqrt(x[0] - 0.5),),
    )
    with np.errstate(invalid="ignore"):
        result = runtime.simulate_model(model, 1.0, method=method)
    assert not result.complete
    assert result.failure["variable"] == "root"
    assert result.failure["law"] == "sqrt(x - 0.5)"
    assert result.failure["time"] == pytest.approx(0.5, abs=1e-6)
    assert result.t[-1] <= 0.5 + 1e-12
    assert "became nan" in result.message


def test_write_csv_round_trips_exactly():
    result = runtime.simulate_model(_namespace(), 1.0, dt=0.1)
    buffer = io.StringIO()
    runtime.write_csv(result, buffer)
    lines = buffer.getvalue().splitlines()
    assert lines[0] == "t,y,x"
    data = np.loadtxt(io.StringIO(buffer.getvalue()), delimiter=",", skiprows=1)
    np.testing.assert_array_equal(data[:, 0], result.t)
    np.testing.assert_array_equal(data[:, 2], result.states["x"])


def test_the_rows_of_modes_are_grouped_as_numpy_unique_groups_them():
    from bondc.runtime import _unique_rows

    rng = np.random.default_rng(7)
    cases = [np.ones((5, 3)), np.array([[0.0, 1.0], [0.0, -1.0], [0.0, 1.0]]), np.array([[0.5, 1.0], [0.5, 2.0]])]
    for _ in range(200):
        rows = rng.integers(-2, 3, size=(int(rng.integers(1, 40)), int(rng.integers(1, 8)))).astype(float)
        rows[:, 0] *= 10.0 ** int(rng.integers(0, 12))          # floor modes can be large integers
        cases.append(rows)
    for rows in cases:
        unique, inverse = _unique_rows(rows)
        expected, _ = np.unique(rows, axis=0, return_inverse=True)
        assert np.array_equal(unique[inverse], rows)
        assert sorted(map(tuple, unique)) == sorted(map(tuple, expected))


def test_modes_at_a_point_are_the_fixed_point_with_and_without_nested_switches():
    """``m = sign(g(t, x, m))``: a switch whose function reads another switch's mode (a nested if)
    needs more passes; one that no switching function reads is settled by the first. Checked
    against a brute-force fixed point of every start over random points, for a chain of nested
    switches and for independent ones."""
    nested = lambda t, x, p, m: np.array([x[0], x[1] if m[0] > 0 else -x[1], x[2] * (1.0 if m[1] > 0 else -1.0)])
    independent = lambda t, x, p, m: np.array([x[0], x[1], x[2]])
    rng = np.random.default_rng(5)
    for switches, depends in ((nested, ((), (0,), (1,))), (independent, ((), (), ()))):
        model = runtime._Model(_namespace(STATE_NAMES=("a", "b", "c"), SWITCHES=("g0", "g1", "g2"),
                                          _switches=switches, SWITCH_DEPENDS=depends))
        assert model.modes_read_by_switches.tolist() == [bool(any(k in d for d in depends)) for k in range(3)]
        for _ in range(100):
            x = rng.normal(size=3)
            guess = rng.choice([-1.0, 1.0], 3)
            expected = guess.copy()
            for _ in range(10):          # brute force: iterate well past the nesting depth
                expected = np.sign(switches(0.0, x, None, expected))
            assert np.array_equal(runtime.modes_at(model, 0.0, x, None, guess), expected)


ROOT_FUNCTIONS = [
    (lambda x: x - 0.3, 0.0, 1.0),
    (lambda x: math.cos(x) - x, 0.0, 1.0),
    (lambda x: x ** 3 - 2.0 * x - 5.0, 2.0, 3.0),          # Wallis's cubic
    (lambda x: math.exp(x) - 1e-3, -10.0, 5.0),
    (lambda x: math.copysign(1.0, x - 1e-7), -1.0, 1.0),    # a jump: no root, a sign change
    (lambda x: -(x - 5e-9), 0.0, 1e-8),
]


@pytest.mark.parametrize("function, a, b", ROOT_FUNCTIONS)
def test_brentq_is_scipys_brentq_to_the_bit_with_or_without_scipy_optimize(function, a, b, monkeypatch):
    """The runtime calls scipy's compiled Brent solver without importing scipy.optimize (0.3 s);
    the roots are the public function's, and so they are when that module is not usable."""
    from scipy.optimize import brentq as scipy_brentq

    eps = np.finfo(float).eps
    expected = scipy_brentq(function, a, b, xtol=4 * eps, rtol=4 * eps)
    assert runtime._scipy_kernel("optimize", "_zeros", runtime._zeros_probe) is not None
    assert runtime.brentq(function, a, b, 4 * eps, 4 * eps) == expected
    monkeypatch.setattr(runtime.kernels, "_scipy_kernel", lambda *args: None)
    assert runtime.brentq(function, a, b, 4 * eps, 4 * eps) == expected


def test_brentq_refuses_a_bracket_without_a_sign_change_and_a_nan_as_scipy_does():
    eps = np.finfo(float).eps
    with pytest.raises(ValueError):
        runtime.brentq(lambda x: x * x + 1.0, -1.0, 1.0, 4 * eps, 4 * eps)
    with pytest.raises(ValueError):     # nan inside the bracket, at the first trial point
        runtime.brentq(lambda x: math.nan if 0.2 < x < 0.8 else x - 0.5, 0.0, 1.0, 4 * eps, 4 * eps)


def test_bracketed_roots_finds_every_brackets_root_at_once_as_brentq_does():
    """The switches of time are refined in all their brackets at once (a 20 kHz pwm has thousands):
    each root within brentq's tolerance of scipy's root for the same bracket, on the far side of
    the change (the function there has the sign of its value at the bracket's right end)."""
    from scipy.optimize import brentq as scipy_brentq

    eps = np.finfo(float).eps
    functions = [function for function, _, _ in ROOT_FUNCTIONS]
    a = np.array([a for _, a, _ in ROOT_FUNCTIONS])
    b = np.array([b for _, _, b in ROOT_FUNCTIONS])

    def values(times, rows):
        return np.array([functions[row](time) for time, row in zip(times, rows)])

    every = np.arange(len(functions))
    roots = runtime.bracketed_roots(values, a, b, values(a, every), values(b, every), 4 * eps, 4 * eps)
    for row, (function, lo, hi) in enumerate(ROOT_FUNCTIONS):
        expected = scipy_brentq(function, lo, hi, xtol=4 * eps, rtol=4 * eps)
        assert abs(roots[row] - expected) <= 2 * (4 * eps + 4 * eps * abs(expected)), row
        assert lo <= roots[row] <= hi
        assert np.sign(function(roots[row])) != np.sign(function(lo)), row


def test_bracketed_roots_takes_an_end_where_the_value_is_zero_and_the_right_end_past_a_nan():
    eps = np.finfo(float).eps
    line = lambda times, rows: times - 0.5                 # noqa: E731
    holed = lambda times, rows: np.where((times > 0.2) & (times < 0.8), np.nan, times - 0.5)     # noqa: E731
    roots = runtime.bracketed_roots(line, [0.5, 0.0], [1.0, 0.5], [0.0, -0.5], [0.5, 0.0], 4 * eps, 4 * eps)
    assert list(roots) == [0.5, 0.5]
    assert list(runtime.bracketed_roots(holed, [0.0], [1.0], [-0.5], [0.5], 4 * eps, 4 * eps)) == [1.0]


@pytest.mark.filterwarnings("ignore:The occurrence of roundoff error")      # scipy's, on sqrt(|x|)
@pytest.mark.parametrize("law, a, b, exact", [
    (lambda x: 3.0 * x * x, 0.0, 2.0, 8.0),
    (lambda x: np.sqrt(np.abs(x)), -1.0, 4.0, 2.0 / 3.0 + 16.0 / 3.0),
    (lambda x: 1.0 / (1.0 + x * x), -50.0, 50.0, 2.0 * math.atan(50.0)),
    (lambda x: x, 1.0, -1.0, 0.0),                          # reversed bounds
])
def test_quad_is_scipys_quad_without_importing_scipy_integrate(law, a, b, exact, monkeypatch):
    import scipy.integrate

    expected = scipy.integrate.quad(law, a, b, epsabs=1e-15, epsrel=1e-12, limit=500)[0]
    assert runtime._scipy_kernel("integrate", "_quadpack", runtime._quadpack_probe) is not None
    assert runtime.quad(law, a, b, epsabs=1e-15, epsrel=1e-12, limit=500) == expected
    assert runtime.quad(law, a, b, epsabs=1e-15, epsrel=1e-12, limit=500) == pytest.approx(exact, rel=1e-10, abs=1e-14)
    monkeypatch.setattr(runtime.kernels, "_scipy_kernel", lambda *args: None)
    assert runtime.quad(law, a, b, epsabs=1e-15, epsrel=1e-12, limit=500) == expected


# ------------------------------------------------------------------ nonlinear algebraic loops

def shockley_node(v_source, v_cap, r1=100.0, r3=50.0, i_s=1e-9, v_t=0.025):
    """The node voltage of exp_diode.bg, by bisection in plain floats (an independent reference):
    (V - v)/R1 = Is (exp(v/Vt) - 1) + (v - v_cap)/R3, whose left side falls and right side rises."""
    def kcl(v):
        return (v_source - v) / r1 - i_s * math.expm1(min(v / v_t, 700.0)) - (v - v_cap) / r3
    low, high = -1e3, 1e3
    for _ in range(200):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if kcl(middle) > 0 else (low, middle)
    return 0.5 * (low + high)


@pytest.mark.parametrize("v_source", [-20.0, 0.0, 10.0, 20.0])
def test_newton_search_solves_an_exponential_loop_far_from_its_guess(v_source):
    """The loop of exp_diode.bg in the form the equations stage writes it (unknown: r1's effort z,
    the diode's voltage V - z): from z = 0 the diode's exp((V - z)/Vt) is 1e173 at 10 V (hundreds
    of plain Newton steps, where MINPACK's hybr gives up) and overflows at 20 V. The search reaches
    the root that bisection finds, at reverse, zero and forward bias."""
    def residual(z):
        with np.errstate(over="ignore"):
            return np.array([-100.0 * (1e-9 * (np.exp((v_source - z[0]) / 0.025) - 1)
                                       + (v_source - z[0] - 2.0) / 50.0) + z[0]])

    found = runtime.newton_search(residual, (0.0,))
    expected = v_source - shockley_node(v_source, 2.0)
    assert found is not None
    assert found[0] == pytest.approx(expected, rel=1e-12, abs=1e-12)
    solved = runtime.solve_block(lambda z: tuple(residual(np.asarray(z))), 9001, (0.0,))
    assert solved[0] == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_minpack_alone_does_not_solve_the_exponential_loop():
    """Why solve_block has its second attempt: hybr from the guess stops far from the root at 10 V."""
    from scipy.optimize import root

    def residual(z):
        return np.array([-100.0 * (1e-9 * (np.exp((10.0 - z[0]) / 0.025) - 1) + (10.0 - z[0]) / 50.0) + z[0]])

    attempt = root(residual, np.zeros(1), method="hybr", options={"xtol": 1e-12})
    assert not (attempt.success and abs(residual(attempt.x)[0]) < 1e-6)


def test_newton_search_finds_two_unknowns_and_gives_up_without_a_root():
    """Two diodes in series with a resistor (unknowns: both diode voltages; the current is equal):
    the search meets the bisection of the series equation; z^2 + 1 = 0 has no real root: None."""
    def series(z):
        with np.errstate(over="ignore"):
            current = 1e-12 * (np.exp(z[0] / 0.025) - 1)
            return np.array([current - 1e-12 * (np.exp(z[1] / 0.025) - 1),
                             z[0] + z[1] + 10.0 * current - 5.0])

    found = runtime.newton_search(series, (0.0, 0.0))
    low, high = 0.0, 2.5        # each diode's voltage v: 2 v + 10 Is (exp(v/Vt) - 1) = 5
    for _ in range(200):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if 2 * middle + 1e-11 * math.expm1(middle / 0.025) < 5.0 else (low, middle)
    assert found == pytest.approx([low, low], rel=1e-12)
    assert runtime.newton_search(lambda z: np.array([z[0] ** 2 + 1.0]), (0.0,)) is None


def test_solve_block_does_not_take_minpacks_word_for_convergence():
    """Warm-started at the root of the diode loop with the diode off (V = -20 V, capacitor at
    5 V), the next call (capacitor at 19 V: the diode conducts) makes hybr report "converged" at
    its start, where the residual is 28. solve_block checks the residual and the Newton step it
    leaves, and finds the root that bisection finds."""
    point = {"v_cap": 5.0}

    def residual(z):
        with np.errstate(over="ignore"):
            return (-100.0 * (1e-9 * (np.exp((-20.0 - z[0]) / 0.025) - 1)
                              + (-20.0 - z[0] - point["v_cap"]) / 50.0) + z[0],)

    first = runtime.solve_block(residual, 9002, (0.0,))
    assert first[0] == pytest.approx(-20.0 - shockley_node(-20.0, 5.0), rel=1e-12)
    point["v_cap"] = 19.0
    second = runtime.solve_block(residual, 9002, (0.0,))
    assert second[0] == pytest.approx(-20.0 - shockley_node(-20.0, 19.0), rel=1e-12)
