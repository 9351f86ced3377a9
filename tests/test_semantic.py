"""The semantic stage: SI values, bonds and ports, overrides, and the diagnostics it collects."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import pytest

from bondc import ast, semantic
from bondc.errors import ModelError, UsageError
from bondc.evaluate import EvaluationError, evaluate
from bondc.parse import parse_set_value, parse_text

# The complete model of LANGUAGE.md section 10, shared with the language-example tests.
MSD = (Path(__file__).parent / "fixtures" / "language" / "s10_complete_model.bg").read_text(encoding="utf-8")


def write(tmp_path: Path, text: str, name: str = "m.bg") -> Path:
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(textwrap.dedent(text), encoding="utf-8")
    return path


def model(body: str, name: str = "M") -> str:
    """A model around ``body`` (dedented), with a force and a damper that use nothing else."""
    body = textwrap.indent(textwrap.dedent(body).strip("\n"), "  ")
    return f"model {name}\n{body}\nend\n"


def load(tmp_path: Path, text: str, **options):
    return semantic.load(write(tmp_path, text), **options)


def errors(tmp_path: Path, text: str, **options) -> list:
    with pytest.raises(ModelError) as info:
        load(tmp_path, text, **options)
    return info.value.diagnostics


SIMPLE = """\
MSe force : e = 10
R damper : e = 12*f
force -> damper
"""


# ------------------------------------------------------------------ SI values

def test_constants_with_units_are_converted_to_si(tmp_path):
    graph, _ = load(tmp_path, model("""
        param lead = 5.0 [mm]
        param n = 1000 [rpm]
        param P = 0.224 [MPa]
        param M = 31.7 [kg]
        param plain = 3
        param quarter = pi/4 [deg]
        MSe force : e = lead*n*P*M*plain*quarter
        R damper : e = 12*f
        force -> damper
    """))
    values = {name: p.value for name, p in graph.parameters.items()}
    assert values["lead"] == 0.005
    assert values["n"] == pytest.approx(104.7197551, abs=1e-7)
    assert values["P"] == 224000
    assert values["M"] == 31.7
    assert values["plain"] == 3
    assert values["quarter"] == pytest.approx(math.pi / 4 * math.pi / 180)
    lead = graph.parameters["lead"]
    assert (lead.unit_text, lead.display_factor) == ("mm", pytest.approx(0.001))
    assert lead.value / lead.display_factor == pytest.approx(5.0)


def test_computed_parameter_is_si_and_its_unit_must_be_coherent(tmp_path):
    graph, _ = load(tmp_path, model("""
        param D = 40 [mm]
        param d = 20 [mm]
        param Ar = pi/4*(D^2 - d^2) [m^2]
        MSe force : e = Ar
        R damper : e = 12*f
        force -> damper
    """))
    assert graph.parameters["Ar"].value == pytest.approx(math.pi / 4 * (0.04 ** 2 - 0.02 ** 2))
    assert graph.parameters["Ar"].display_factor == 1.0

    (diagnostic,) = errors(tmp_path, model("""
        param t1 = 0.5 [s]
        param t2 = 2*t1 [ms]
        MSe force : e = t2
        R damper : e = 12*f
        force -> damper
    """))
    assert diagnostic.code == "E202"
    assert "coherent" in diagnostic.message and "[ms]" in diagnostic.message
    assert "computed in SI" in diagnostic.hint and diagnostic.hint.endswith("write [s]")
    assert (diagnostic.span.line, diagnostic.span.column) == (3, 19)


@pytest.mark.parametrize("unit, suggestion", [("ms", "s"), ("kN*m", "N*m"), ("rpm", "rad/s"), ("L/min", "m^3/s"),
                                              ("mm^2", "m^2"), ("bar", "Pa"), ("g", "kg"), ("kg*mm/ms^2", "kg*m/s^2")])
def test_coherent_suggestion(unit, suggestion):
    assert semantic.coherent_suggestion(parse_set_value(f"x = 1 [{unit}]").unit) == suggestion


def test_input_units_must_be_coherent_outputs_may_use_any(tmp_path):
    graph, _ = load(tmp_path, model("""
        input w [rad/s] = 10
        Sf motor : f = w
        R load : e = 2*f
        motor -> load
        output P [kPa] = load.e
        output speed [rpm] = load.f
    """))
    assert graph.outputs["P"].display_factor == 1000
    assert graph.outputs["speed"].display_factor == pytest.approx(2 * math.pi / 60)
    assert graph.outputs["P"].unit_text == "kPa"
    (diagnostic,) = errors(tmp_path, model("""
        input w [rpm] = 10
        Sf motor : f = w
        R load : e = 2*f
        motor -> load
    """))
    assert diagnostic.code == "E202" and "input 'w'" in diagnostic.message and "[rad/s]" in diagnostic.hint


def test_unknown_and_numeric_units(tmp_path):
    found = errors(tmp_path, model("""
        param a = 1 [kgg]
        param b = 2 [2*m]
        MSe force : e = a*b
        R damper : e = 12*f
        force -> damper
    """))
    assert [(d.code, d.span.line, d.span.column) for d in found] == [("E201", 2, 16), ("E203", 3, 16)]
    assert found[0].hint == "did you mean 'kg'?"


# --------------------------------------------------------------- bonds, ports

def test_bonds_are_numbered_in_order_chains_left_to_right(tmp_path):
    graph, _ = load(tmp_path, model("""
        Se src : e = 1
        R r1 : e = f
        R r2 : e = 2*f
        R r3 : e = 3*f
        0 a
        1 b
        src -> a -> b -> r1
        mine: a -> r2
        b -> r3
        output x = b2.f + mine.e + b5.e
    """))
    assert [(b.number, b.tail, b.head, b.label) for b in graph.bonds] == [
        (1, "src", "a", None), (2, "a", "b", None), (3, "b", "r1", None), (4, "a", "r2", "mine"), (5, "b", "r3", None)]
    assert [b.name for b in graph.bonds] == ["b1", "b2", "b3", "mine", "b5"]
    assert graph.junctions["a"].bonds == (1, 2, 4)
    assert graph.elements["r2"].bonds == (4,)
    assert graph.elements["src"].port_signs == (-1,)
    assert graph.elements["r1"].port_signs == (1,)


TWO_PORT = """\
model M
  Sf motor : f = 10
  R load : e = 3*f
  TF screw : r = 0.5
{bonds}
end
"""


@pytest.mark.parametrize("bonds, ports, signs", [
    ("  motor -> screw\n  screw -> load", ((1, "head", "p1"), (2, "tail", "p2")), (1, 1)),
    ("  screw -> load\n  motor -> screw", ((2, "head", "p1"), (1, "tail", "p2")), (1, 1)),
    ("  motor -> screw.p2\n  screw.p1 -> load", ((2, "tail", "p1"), (1, "head", "p2")), (-1, -1)),
    ("  motor -> screw.p1\n  load -> screw", ((1, "head", "p1"), (2, "head", "p2")), (1, -1)),
    ("  screw.p2 -> motor\n  screw -> load", ((2, "tail", "p1"), (1, "tail", "p2")), (-1, 1)),
])
def test_two_port_port_assignment(tmp_path, bonds, ports, signs):
    graph, _ = load(tmp_path, TWO_PORT.format(bonds=bonds))
    screw = graph.elements["screw"]
    assert screw.bonds == (ports[0][0], ports[1][0])
    assert screw.port_signs == signs
    for number, side, port in ports:
        bond = graph.bond(number)
        assert (bond.head_port if side == "head" else bond.tail_port) == port


@pytest.mark.parametrize("bonds, message", [
    ("  motor -> screw\n  load -> screw", "both bonds of TF 'screw' point into it"),
    ("  screw -> motor\n  screw -> load", "both bonds of TF 'screw' point out of it"),
    ("  motor -> screw.p1\n  load -> screw.p1", "port p1 of 'screw' is used by two bonds (1 and 2)"),
    ("  motor -> screw.p3\n  screw -> load", "TF 'screw' has no port 'p3'"),
    ("  motor -> screw", "TF 'screw' has 1 bond; a two-port has exactly two"),
    ("  motor -> load.p1\n  motor -> screw -> load", "'load' is a one-port R and has no port 'p1'"),
])
def test_two_port_errors(tmp_path, bonds, message):
    found = errors(tmp_path, TWO_PORT.format(bonds=bonds))
    assert any(d.code == "E402" and message in d.message for d in found), found


def test_one_port_and_junction_bond_counts(tmp_path):
    found = errors(tmp_path, model("""
        MSe force : e = 10
        R damper : e = 12*f
        R spare : e = f
        0 j
        1 lonely
        force -> j -> damper
        j -> force
        lonely -> j
    """))
    assert [(d.code, d.message) for d in found] == [
        ("E401", "MSe 'force' has 2 bonds; a one-port element has exactly one"),
        ("E401", "R 'spare' has no bond"),
        ("E403", "junction 'lonely' has only one bond"),
    ]
    assert [r.label for r in found[0].related] == ["bond 1", "bond 3"]


# ------------------------------------------------------------------ overrides

OVERRIDES = model("""
    param lead = 5.0 [mm]
    param ratio = lead/(2*pi)
    param n = 1000 [rpm]
    input w [rad/s] = n
    Sf motor : f = w
    TF screw : r = ratio
    R load : e = 3*f
    motor -> screw -> load
    experiment fine
      t_end = 2 [s]
      max_step = 1 [ms]
      param lead = 2 [mm]
      input w [rad/s] = 50
    end
    experiment coarse
      t_end = 1 [min]
      param lead = 10
    end
""")


def test_experiment_overrides_recompute_dependent_parameters(tmp_path):
    graph, _ = load(tmp_path, OVERRIDES)
    assert graph.parameters["lead"].value == 0.005
    assert graph.parameters["ratio"].value == pytest.approx(0.005 / (2 * math.pi))
    assert isinstance(graph.inputs["w"].expr, ast.Name)

    graph, _ = load(tmp_path, OVERRIDES, experiment="fine")
    assert graph.parameters["lead"].value == 0.002
    assert graph.parameters["ratio"].value == pytest.approx(0.002 / (2 * math.pi))
    assert graph.inputs["w"].expr == ast.Num(50.0, "50")
    fine = graph.experiments["fine"]
    assert (fine.t_end, fine.max_step) == (2.0, 0.001)
    assert fine.parameters == {"lead": 0.002, "ratio": pytest.approx(0.002 / (2 * math.pi))}
    # A bare number overriding a parameter declared in mm is read in mm.
    assert graph.experiments["coarse"].parameters["lead"] == pytest.approx(0.01)
    assert graph.experiments["coarse"].t_end == 60.0

    first, _ = load(tmp_path, OVERRIDES, experiment=semantic.FIRST)
    assert first.parameters["lead"].value == 0.002


def test_set_overrides_win_and_recompute(tmp_path):
    graph, _ = load(tmp_path, OVERRIDES, experiment="fine", sets=[parse_set_value("lead=8")])
    assert graph.parameters["lead"].value == pytest.approx(0.008)
    assert graph.parameters["ratio"].value == pytest.approx(0.008 / (2 * math.pi))
    graph, _ = load(tmp_path, OVERRIDES, sets=[parse_set_value("lead=0.01 [m]"), parse_set_value("n = 2*60 [rad/s]")])
    assert graph.parameters["lead"].value == pytest.approx(0.01)
    assert graph.parameters["lead"].unit_text == "m"
    assert graph.parameters["n"].value == 120
    graph, _ = load(tmp_path, OVERRIDES, sets=[parse_set_value("n=1500")])
    assert graph.parameters["n"].value == pytest.approx(1500 * 2 * math.pi / 60)


def test_bad_overrides(tmp_path):
    found = errors(tmp_path, OVERRIDES, sets=[parse_set_value("leed=3"), parse_set_value("n=3 [kg]")])
    assert [d.code for d in found] == ["E301", "E204"]
    assert found[0].hint == "did you mean 'lead'?"
    found = errors(tmp_path, OVERRIDES, sets=[parse_set_value("lead=ratio*2*pi")])
    assert [d.code for d in found] == ["E305"]
    assert found[0].message == "parameter dependency cycle: lead -> ratio -> lead"


def test_unknown_experiment_lists_the_available_ones(tmp_path):
    (diagnostic,) = errors(tmp_path, OVERRIDES, experiment="fien")
    assert diagnostic.code == "E318"
    assert diagnostic.hint == "did you mean 'fine'?; its experiments: fine, coarse"


def test_experiment_settings(tmp_path):
    found = errors(tmp_path, model(f"""
        {SIMPLE.replace(chr(10), chr(10) + '        ')}
        output v = damper.f
        experiment run
          t_ned = 1 [s]
          solver = "Radua"
          max_step = 1 [mm]
          outputs = [v, w]
          rtol = "small"
        end
    """))
    assert [d.code for d in found] == ["E314", "E317", "E204", "E301", "E313"]
    graph, _ = load(tmp_path, model(f"""
        {SIMPLE.replace(chr(10), chr(10) + '        ')}
        output v = damper.f
        experiment run
          t_end = 2 [min]
          solver = "LSODA"
          rtol = 1e-6
          atol = 1e-9
          cycle = 500 [ms]
          outputs = [v]
          first_step = 1 [us]
          dt = 10 [ms]
        end
    """))
    run = graph.experiments["run"]
    assert (run.t_end, run.solver, run.rtol, run.atol, run.cycle, run.outputs) == (120, "LSODA", 1e-6, 1e-9, 0.5, ("v",))
    assert run.settings == {"first_step": pytest.approx(1e-6), "dt": pytest.approx(0.01)}


# ------------------------------------------------- collecting, suggestions

def test_three_mistakes_give_three_diagnostics_in_order(tmp_path):
    found = errors(tmp_path, model("""
        param b = 12 [N*s/m]
        MSe force : e = 10
        Rr damper : e = b*f
        C spring : e = 800*qq
        0 j
        force -> j -> spring
        j -> dampr
    """))
    assert [(d.code, d.span.line) for d in found] == [("E303", 4), ("E301", 5), ("E404", 8)]
    assert [d.hint.split(";")[0] for d in found] == ["did you mean 'R'?", "did you mean 'q'?", "did you mean 'damper'?"]


def test_duplicate_names_point_at_the_second_with_a_note_at_the_first(tmp_path):
    found = errors(tmp_path, model("""
        param k = 800 [N/m]
        MSe force : e = 10
        C k : e = 800*q
        force -> k
        fn k(x) = x
    """))
    assert [(d.code, d.span.line) for d in found] == [("E302", 4), ("E302", 6)]
    assert found[0].related[0].span.line == 2
    assert found[0].related[0].label == "first defined here, as a parameter"


def test_warnings_are_returned(tmp_path):
    graph, warnings = load(tmp_path, model("""
        param b = 12 [N*s/m]
        param unused = 3
        input F [N] = 10
        MSe force : e = 10
        R damper : e = b*f
        force -> damper
    """))
    assert [(w.code, w.severity) for w in warnings] == [("W301", "warning"), ("W302", "warning")]
    assert graph.parameters["unused"].value == 3


# --------------------------------------------------------------- references

@pytest.mark.parametrize("expr, code, text", [
    ("damper.q", "E312", "R 'damper' has no variable 'q'"),
    ("damper.p1.e", "E312", "'damper' is a one-port"),
    ("screw.e", "E312", "'screw' is a two-port"),
    ("j0.f", "E312", "'j0' is a 0-junction"),
    ("j1.e", "E312", "'j1' is a 1-junction"),
    ("b99.e", "E312", "there is no bond 99"),
    ("b.e", "E312", "'b' is a parameter"),
    ("nothing.e", "E301", "undefined name 'nothing'"),
    ("damper", "E316", "'damper' is an element, not a value"),
    ("spring.q + mass.p", None, None),
    ("j0.e + j1.f + b1.e + lbl.f + screw.p2.f", None, None),
])
def test_graph_references(tmp_path, expr, code, text):
    text_model = model(f"""
        param b = 1
        MSe force : e = 10*b
        R damper : e = 12*f
        C spring : e = 800*q
        I mass : f = p/2
        TF screw : r = 2
        R load : e = f
        0 j0
        1 j1
        force -> j0 -> damper
        j0 -> j1 -> spring
        lbl: j1 -> mass
        j0 -> screw -> load
        output o = {expr}
    """)
    if code is None:
        load(tmp_path, text_model)
        return
    (diagnostic,) = errors(tmp_path, text_model)
    assert diagnostic.code == code and text in f"{diagnostic.message} {diagnostic.hint}"


def test_element_laws_and_own_variables(tmp_path):
    found = errors(tmp_path, model("""
        MSe force : e = 10 + f
        R damper : e = 12*f, f = e/12
        R bad : f = 2*f
        C spring : e = 800*q + f
        I mass : f = p/2, x(0) = 1
        C chamber : state P [Pa], e = P
        0 j
        force -> j
        j -> damper
        j -> bad
        j -> spring
        j -> mass
        j -> chamber
    """))
    assert [(d.code, d.span.line) for d in found] == [("E506", 2), ("E506", 4), ("E506", 5), ("E504", 6), ("E504", 7)]
    assert found[3].message == "'x(...)' on 'mass' is neither an initial value nor a rate law"
    assert found[4].message == "state 'P' of 'chamber' has no rate law"


def test_custom_and_model_states(tmp_path):
    graph, _ = load(tmp_path, (Path(__file__).parent / "fixtures" / "language" / "s04_custom_state.bg").read_text())
    chamber = graph.elements["chamber"]
    (state,) = chamber.states
    assert (state.name, state.qualified, state.owner, state.unit_text) == ("P", "chamber.P", "chamber", "Pa")
    assert isinstance(state.rate, ast.Binary) and isinstance(state.initial, ast.Name)
    (mass_state,) = graph.elements["mass"].states
    assert (mass_state.qualified, mass_state.rate, mass_state.initial) == ("mass.p", None, None)
    (x,) = graph.model_states
    assert (x.name, x.owner, x.unit_text) == ("x", None, "m")
    assert [s.qualified for s in graph.states] == ["chamber.P", "mass.p", "x"]


def test_contexts(tmp_path):
    found = errors(tmp_path, model("""
        param a = t
        input F [N] = mass.f
        fn g(x) = x*a*F
        param c = sqrt(1, 2) + g(1, 2) + nope(1)
        MSe force : e = F + a + c + "text"
        I mass : f = p/2
        force -> mass
    """))
    assert [(d.code, d.span.line) for d in found] == [
        ("E316", 2), ("E316", 3), ("E316", 4), ("E306", 5), ("E306", 5), ("E301", 5), ("E313", 6)]
    # a function inside a model may use the model's parameters (a), not its signals (F)
    assert found[2].message == "function 'g' cannot use input 'F'"
    # an input that reads the graph (feedback, a first controller): the hint says where that goes
    assert found[1].message == "an input cannot use the graph variable 'mass.f'"
    assert "modulated source" in found[1].hint and "MSe" in found[1].hint


def test_recursive_functions(tmp_path):
    found = errors(tmp_path, "fn f(x) = f(x - 1)\n" + model("param a = f(2)\n" + SIMPLE + "output o = a\n"))
    assert [d.code for d in found] == ["E304"]
    assert found[0].message == "function 'f' calls itself: f -> f"


def test_evaluation_errors_point_at_the_failing_expression(tmp_path):
    found = errors(tmp_path, model("""
        param a = 1
        param b = log(a - 2)
        param c = 1/(a - 1)
        param d = 10^400
        MSe force : e = b + c + d
        R damper : e = 12*f
        force -> damper
    """))
    assert [(d.code, d.span.line, d.span.column) for d in found] == [("E311", 3, 13), ("E311", 4, 13), ("E311", 5, 13)]
    assert "log of -1" in found[0].message


def test_evaluate_walks_the_ast():
    value = evaluate(parse_set_value("x = if a > 1 and not (b == 2) then max(a, b, 7) else atan2(1, 1)").value,
                     {"a": 3.0, "b": 1.0})
    assert value == 7
    square = ast.FnDef("sq", ("x",), parse_set_value("y = x*x").value)
    assert evaluate(parse_set_value("x = sq(3) + table(1.5, [0, 1, 2], [0, 10, 20])").value, {}, {"sq": square}) == 24
    with pytest.raises(EvaluationError) as info:
        evaluate(parse_set_value("x = sqrt(-4)").value)
    assert info.value.diagnostic.code == "E311"


# --------------------------------------------------------------- files, models

def test_imports_missing_and_cyclic(tmp_path):
    write(tmp_path, "fn half(x) = x/2\n", "lib/util.bg")
    graph, _ = load(tmp_path, 'import "lib/util.bg"\n' + model(SIMPLE.replace("12*f", "half(f)")))
    assert "half" in graph.functions
    (missing,) = errors(tmp_path, 'import "lib/utl.bg"\n' + model(SIMPLE))
    assert missing.code == "E307" and "lib/utl.bg" in missing.message
    write(tmp_path, 'import "../m.bg"\nfn half(x) = x/2\n', "lib/util.bg")
    (cycle,) = errors(tmp_path, 'import "lib/util.bg"\n' + model(SIMPLE))
    assert cycle.code == "E308"
    assert cycle.message.endswith("/m.bg") and "/lib/util.bg -> " in cycle.message


def test_model_selection(tmp_path):
    two = model(SIMPLE, "Damper") + model(SIMPLE, "Other")
    (diagnostic,) = errors(tmp_path, two)
    assert diagnostic.code == "E309" and "Damper, Other" in diagnostic.hint
    graph, _ = load(tmp_path, two, model="Other")
    assert graph.name == "Other"
    (diagnostic,) = errors(tmp_path, two, model="Dampr")
    assert diagnostic.hint.startswith("did you mean 'Damper'?")
    (diagnostic,) = errors(tmp_path, "fn f(x) = x\n")
    assert diagnostic.code == "E309" and diagnostic.message.startswith("no model")


def test_io_errors_are_usage_errors(tmp_path):
    with pytest.raises(UsageError, match="no such file"):
        semantic.load(tmp_path / "absent.bg")
    with pytest.raises(UsageError, match="directory"):
        semantic.load(tmp_path)
    (tmp_path / "latin1.bg").write_bytes(b"model M\n  # caf\xe9\nend\n")
    with pytest.raises(UsageError, match="UTF-8"):
        semantic.load(tmp_path / "latin1.bg")


def test_csv_inputs(tmp_path):
    write(tmp_path, "time,omega\n0,0\n1,2\n", "data/w.csv")
    graph, _ = load(tmp_path, model("""
        input w [rad/s] = csv("data/w.csv", "omega")
        Sf motor : f = w
        R load : e = 2*f
        motor -> load
    """))
    assert isinstance(graph.inputs["w"].expr, ast.Call)
    (diagnostic,) = errors(tmp_path, model("""
        input w [rad/s] = csv("data/missing.csv", "omega")
        Sf motor : f = w
        R load : e = 2*f
        motor -> load
    """))
    assert diagnostic.code == "E310"


@pytest.mark.parametrize("rows, words", [
    ("0,0\n1,2\n0.5,3\n", "the time column must not decrease: row 4 has t = 0.5 after 1"),
    ("0,0\n# a comment\n1,abc\n", "row 3 has no number in column 'omega'"),
])
def test_a_csv_files_bad_data_rows_are_found_by_the_check_at_the_call(tmp_path, rows, words):
    # not only when a simulation reads them (E804, without a place in the model)
    write(tmp_path, "time,omega\n" + rows, "data/w.csv")
    (diagnostic,) = errors(tmp_path, model("""
        input w [rad/s] = csv("data/w.csv", "omega")
        Sf motor : f = w
        R load : e = 2*f
        motor -> load
    """))
    assert diagnostic.code == "E310" and words in diagnostic.message
    assert diagnostic.span.line == 2 and "increasing order" in diagnostic.hint


def test_a_csv_file_edited_between_two_checks_in_one_process_is_read_again(tmp_path):
    # an editor's server checks the same model again and again: the data rows as the file has them now
    text = model("""
        input w [rad/s] = csv("data/w.csv", "omega")
        Sf motor : f = w
        R load : e = 2*f
        motor -> load
    """)
    write(tmp_path, "time,omega\n0,1\n10,1\n", "data/w.csv")
    graph, _ = load(tmp_path, text)
    write(tmp_path, "time,omega\n0,1\n-1,1\n", "data/w.csv")
    (diagnostic,) = errors(tmp_path, text)
    assert diagnostic.code == "E310" and "must not decrease" in diagnostic.message


def test_build_takes_a_parsed_file():
    graph, warnings = semantic.build(parse_text(MSD, "msd.bg"), {})
    assert graph.summary()["bonds"] == 4 and warnings == []
    assert graph.experiments["step"].t_end == 2.0
    with pytest.raises(ModelError):
        semantic.build(parse_text(MSD.replace("b*f", "bb*f"), "msd.bg"), {})


def test_a_did_you_mean_carries_its_names_as_data(tmp_path):
    """The quick fix of the language server reads the names a hint offers from the diagnostic
    (Diagnostic.suggestions), not from the hint's text: an undefined name, an unknown unit, a
    variable an element lacks, a member an instance lacks."""
    path = tmp_path / "m.bg"
    path.write_text("model Part\n  port a\n  param A = 1 [m^2]\n  C c : e = q/A\n  a -> c\n  output Q [m] = c.q\nend\n"
                    "model M\n  param k = 800 [N/m]\n  param m = 2 [kgg]\n  Sf s : f = 1\n  C c : e = kk*q\n"
                    "  Part p\n  s -> p.a\n  output x [m] = c.qq\n  output y [m] = p.QQ\nend\n")
    with pytest.raises(ModelError) as caught:
        semantic.load(path, model="M")
    found = {d.code + ":" + d.message.split("'")[1]: d.suggestions for d in caught.value.diagnostics}
    assert found["E201:kgg"][0] == "kg"
    assert found["E301:kk"] == ("k",)
    assert found["E312:c"] == ("c.q",)                  # C 'c' has no variable 'qq'
    assert found["E312:p"] == ("Q",)                    # instance 'p' of 'Part' has no 'QQ'
    assert all(d.hint and f"'{d.suggestions[0]}'" in d.hint for d in caught.value.diagnostics if d.suggestions)
