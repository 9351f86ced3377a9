"""Version 2 details (issue 11, item 7): functions using a model's parameters, what ``check``
reports, equations printed in ``.bg`` syntax, LaTeX that keeps what the model says."""

import math
from pathlib import Path

import numpy as np
import pytest
import sympy

from bondc.cli import main
from bondc.equations import format_equations
from bondc.errors import BondcError, ModelError
from bondc.parse import parse_set_value
from bondc.pipeline import derive_file
from bondc.semantic import load
from bondc.pipeline import simulate_file as run
from bondc.symbolic import Translator

ROOT = Path(__file__).resolve().parent.parent
FLAGSHIP = ROOT / "models" / "electro_pneumatic_hybrid.bg"

SPRING_FN = """model F
  param k  = 800 [N/m]
  param m  = 2   [kg]
  param F0 = 10  [N]
  fn spring_force(x) = k*x
  param F_half = spring_force(0.005) [N]
  Se push : e = F0
  I mass : f = p/m
  C spring : e = spring_force(q)
  1 j
  push -> j
  j -> mass
  j -> spring
  output Fh [N] = F_half
  output Fs [N] = spring.e
end
"""


def test_a_function_inside_a_model_may_use_its_parameters(tmp_path):
    path = tmp_path / "f.bg"
    path.write_text(SPRING_FN)
    result = run(path, t_end=0.2, dt=0.05)
    assert result.outputs["Fh"][0] == pytest.approx(800 * 0.005)
    assert np.allclose(result.outputs["Fs"], 800 * result.states["spring.q"], rtol=1e-12)
    # an override of the parameter reaches what the function computes, in parameters and laws
    changed = run(path, t_end=0.2, dt=0.05, sets=["k=1000"])
    assert changed.outputs["Fh"][0] == pytest.approx(1000 * 0.005)
    assert np.allclose(changed.outputs["Fs"], 1000 * changed.states["spring.q"], rtol=1e-12)


def test_a_file_level_function_still_uses_only_its_arguments(tmp_path):
    text = SPRING_FN.replace("  fn spring_force(x) = k*x\n", "").replace("model F", "fn spring_force(x) = k*x\nmodel F")
    path = tmp_path / "f.bg"
    path.write_text(text)
    with pytest.raises(ModelError) as caught:
        load(path)
    assert any(d.code in ("E316", "E301") and d.span.line == 1 for d in caught.value.diagnostics)


def test_check_reports_a_law_that_cannot_be_inverted_and_the_states_kept(tmp_path, capsys):
    path = tmp_path / "e605.bg"
    # at a 0-junction with a capacitor the resistor is given its effort: its law must be solved for f
    path.write_text("model Friction\n  Sf pump : f = 2\n  R  friction : e = 3*abs(f)^1.5*sign(f)\n"
                    "  C  tank : e = q/0.5\n  0  node\n  pump -> node\n  node -> friction\n  node -> tank\nend\n")
    assert main(["check", str(path)]) == 1
    assert "E605" in capsys.readouterr().err
    # two rigidly coupled masses: 2 storage states, one of them in derivative causality
    path = tmp_path / "rigid.bg"
    path.write_text("model Rigid\n  param m = 2 [kg]\n  Se push : e = 1\n  I a : f = p/m\n  I b : f = p/m\n  1 j\n"
                    "  push -> j\n  j -> a\n  j -> b\nend\n")
    assert main(["check", str(path)]) == 0
    assert "2 states (1 kept by the equations)" in capsys.readouterr().out


def _as_sympy(text: str, symbols):
    """A right-hand side printed by ``bondc equations`` read back as a .bg expression."""
    expr = parse_set_value(f"x = {text}", "<printed>").value

    def name(n, node):
        return symbols[n]

    def ref(node):
        return symbols[node.dotted]

    return Translator(name, ref)(expr)


@pytest.mark.parametrize("model", ["electro_pneumatic_hybrid.bg", "quarter_car.bg", "dc_motor_gear.bg"])
def test_equations_as_text_are_bg_expressions_that_mean_the_same(model):
    ss = derive_file(ROOT / "models" / model, cache=False).state_space
    text = format_equations(ss, "text")
    assert "**" not in text and "Abs(" not in text and "Piecewise" not in text
    symbols = {s.name: s for s in ss.symbols.values()}
    symbols.update({name: symbol for name, symbol in ss.symbols.items()})
    section = text.split("state equations\n")[1].split("\n\n")[0].splitlines()
    rng = np.random.default_rng(3)
    expand = __import__("bondc.equations", fromlist=["_display"])._display(ss)
    params = ss.parameter_values()
    for line, (name, expr) in zip(section, ss.derivatives.items()):
        left, right = line.strip().split(" = ", 1)
        assert left == f"der({name})"
        reread = _as_sympy(right, symbols).xreplace(params)
        original = expand(expr).xreplace(params)
        free = sorted(original.free_symbols | reread.free_symbols, key=str)
        f_original = sympy.lambdify(free, original, "numpy")
        f_reread = sympy.lambdify(free, reread, "numpy")
        for _ in range(20):
            point = rng.uniform(0.1, 2.0, len(free))
            with np.errstate(invalid="ignore"):     # numpy evaluates every branch of an if
                expected, got = f_original(*point), f_reread(*point)
            assert got == pytest.approx(expected, rel=1e-12, abs=1e-12, nan_ok=True), line


def test_equations_as_text_print_coulomb_and_numbers_as_a_model_writes_them(tmp_path):
    """``coulomb`` is the language's name (not sympy's class ``Coulomb``), and a number is the
    shortest text that reads back as the same double (0.1, 2.5e-7; not 0.100000000000000); the
    switches' labels, which events show, the same, and they name each bond variable by its element
    in the generated code itself (a module run on its own says what bondc simulate says)."""
    path = tmp_path / "slider.bg"
    path.write_text("model Slider\n  Se push : e = 0.7*step(t, 0.1)\n  I mass : f = p/2\n"
                    "  R friction : e = 2.5e-7*f + coulomb(f, 0.5, 0.6)\n  1 j\n  push -> j\n  j -> mass\n"
                    "  j -> friction\nend\n")
    ss = derive_file(path, cache=False).state_space
    text = format_equations(ss, "text")
    assert "coulomb(" in text and "Coulomb" not in text
    assert "0.7*step(t, 0.1)" in text and "1.25e-7*mass.p" in text and "00000" not in text
    from bondc.codegen.emit import emit

    source = emit(ss)
    assert "'step(t, 0.1) in push.e'" in source and "'coulomb(friction.f) in friction.e'" in source


def test_latex_keeps_table_breakpoints_and_multi_letter_names():
    ss = derive_file(FLAGSHIP, cache=False).state_space
    latex = format_equations(ss, "latex")
    assert r"\operatorname{table}\left(t;\ \left[0, t_{1}, t_{2}" in latex
    assert r"\mathit{Iz}" in latex and r"\kappa" in latex


@pytest.mark.parametrize("law, message", [("f = p/0", "division by zero"), ("f = p*0^(-1)", "negative power")])
def test_check_reports_a_law_that_divides_by_zero_at_its_position(tmp_path, capsys, law, message):
    path = tmp_path / "z.bg"
    path.write_text(f"model Z\n  Se s : e = 1\n  I mass : {law}\n  s -> mass\nend\n")
    assert main(["check", str(path)]) == 1
    err = capsys.readouterr().err
    assert "z.bg:3:" in err and message in err


@pytest.mark.parametrize("law, error", [("f = p/m", True), ("f = p/(2*m)", True), ("f = p/(m + 1)", False),
                                        ("f = if m > 0 then p/m else 0", False)])
def test_a_law_dividing_by_a_parameter_that_is_zero_is_an_error_unless_guarded(tmp_path, law, error):
    path = tmp_path / "m.bg"
    path.write_text(f"model M\n  param m = 0 [kg]\n  Se s : e = 1\n  I mass : {law}\n  s -> mass\nend\n")
    if not error:
        load(path)
        return
    with pytest.raises(ModelError) as caught:
        load(path)
    (problem,) = caught.value.diagnostics
    assert problem.code == "E311" and problem.span.line == 4 and "m = 0" in problem.message
    # and a --set that makes it zero, in a model that is fine as written
    path.write_text(path.read_text().replace("param m = 0", "param m = 2"))
    load(path)
    from bondc.pipeline import parse_sets

    with pytest.raises(ModelError):
        load(path, sets=parse_sets(["m=0"]))


def test_the_section_12_example_simulates_its_relay_and_its_bouncing_ball():
    result = run(ROOT / "tests" / "fixtures" / "language" / "s12_discrete_events.bg", t_end=3.0)
    assert result.complete
    whens = [(time, label) for time, label in result.events if label.startswith("when")]
    impacts = [time for time, label in whens if "h_ball" in label]
    first = (2 * 1 / 9.81) ** 0.5                       # dropped from 1 m
    assert impacts[:2] == pytest.approx([first, first + 2 * 0.8 * first], rel=1e-6)   # restitution 0.8


RELAY = """model Relay
  param T0 = 15 [K]
  param T_on = 19 [K]
  input T_set [K] = 18 + step(t, 10)
  Se heat : e = 1000*heater
  C room : e = q/1e4, q(0) = T0*1e4
  R loss : e = 100*f
  1 j
  heat -> j
  j -> room
  j -> loss
  output T_room [K] = room.e
  discrete heater [1] = if room.q/1e4 < T_set then 1 else 0
  discrete level [1] = heater + 1
  when T_room > T_on then heater = 0 end
end
"""


CHAINED = """
model Chained
  param x0 = 3 [1]
  param tau = 1 [s]
  discrete a [1] = b + c
  discrete b [1] = 2*c
  discrete c [1] = x0 + 1
  state x [1] : der(x) = (a - x)/tau, x(0) = x0
  experiment run
    t_end = 1 [s]
  end
end
"""


def test_initial_values_that_use_later_ones_are_resolved_in_dependency_order(tmp_path):
    path = tmp_path / "chained.bg"
    path.write_text(CHAINED)
    result = run(path)
    # by hand: c = x0 + 1 = 4, b = 2c = 8, a = b + c = 12; x relaxes from 3 towards 12
    assert [result.states[name][0] for name in ("c", "b", "a")] == [4.0, 8.0, 12.0]
    assert result.states["x"][-1] == pytest.approx(12 - 9 * math.exp(-1.0), rel=1e-5)


def test_initial_values_in_a_cycle_are_reported_at_the_declaration(tmp_path):
    path = tmp_path / "cycle.bg"
    path.write_text(CHAINED.replace("discrete b [1] = 2*c", "discrete b [1] = 2*a"))
    with pytest.raises(BondcError) as caught:
        derive_file(path, cache=False)
    (diagnostic,) = caught.value.diagnostics
    assert diagnostic.code == "E701" and "'a' depends on itself" in diagnostic.message
    assert diagnostic.span.line == 5 and diagnostic.hint


@pytest.mark.parametrize("start, heater", [(15, 1.0), (20, 0.0)])
def test_a_discrete_initial_value_uses_inputs_and_initial_states_at_t_0(tmp_path, start, heater):
    path = tmp_path / "relay.bg"
    path.write_text(RELAY)
    result = run(path, t_end=5000.0, sets=[f"T0={start}"])
    assert result.states["heater"][0] == heater and result.states["level"][0] == heater + 1
    if heater:
        # heated from 15 K: T = 1000 - 985*exp(-t/1e6) reaches T_on = 19 K at t = 1e6*ln(985/981),
        # where the when clause (a condition on an output) switches the heater off
        (switch,) = [time for time, label in result.events if label == "when T_room > T_on"]
        assert switch == pytest.approx(1e6 * math.log(985 / 981), rel=5e-5)     # default rtol 1e-6
        assert result.states["heater"][-1] == 0.0
