"""Submodels and ports (LANGUAGE.md section 11): flattening, diagnostics, and the flat equivalent.

A hierarchical model must mean exactly what the hand-flattened model means: the
same state equations (compared numerically at random points) and the same
trajectories. Malformed components are reported at the right line of the right
file, with the instance path.
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import sympy

from bondc.cli import main
from bondc.errors import ModelError
from bondc.equations import _display
from bondc.pipeline import derive_file
from bondc.semantic import load
from bondc.pipeline import simulate_file as run

FIXTURES = Path(__file__).parent / "fixtures" / "components"
MODELS = Path(__file__).parent.parent / "models"


def _rates(path, model=None):
    """The state equations of a model, fully expanded, as functions of named states and inputs."""
    ss = derive_file(path, model=model, cache=False).state_space
    expand = _display(ss)
    names = list(ss.state_names)
    symbols = [ss.symbol(n) for n in names]
    params = ss.parameter_values()
    functions = {}
    for name in names:
        expr = expand(ss.derivatives[name]).xreplace(params)
        functions[name] = sympy.lambdify([symbols, ss.time], expr, "numpy")
    return names, functions


# ------------------------------------------------------------ the section 11 example

def test_the_section_11_example_checks_and_simulates_to_the_closed_form():
    # Tank C = 1e-9 m^3/Pa filled through the orifice from p_s: with u = p_s - p,
    # du/dt = -(k/C)*sqrt(u), so sqrt(u) = sqrt(p_s) - k/(2C)*t, k = Cd*A*sqrt(2/rho).
    result = run(FIXTURES / "circuit.bg", t_end=4.0, dt=0.5)
    assert result.complete, result.message
    p_s, cap, k = 100e5, 1e-9, 0.7 * 2e-5 * math.sqrt(2 / 850)
    root = np.sqrt(p_s) - k / (2 * cap) * result.t
    pressure = result.states["tank.q"] / cap
    assert np.allclose(pressure, p_s - root ** 2, rtol=1e-5, atol=1.0)
    assert np.allclose(result.outputs["Q"], k * root, rtol=1e-5)
    assert np.allclose(result.outputs["valve.Q"], result.outputs["Q"])   # an instance's output, dotted


def test_a_hierarchical_model_has_the_state_equations_of_its_hand_flattened_version():
    names, hierarchical = _rates(FIXTURES / "circuit.bg")
    flat_names, flat = _rates(FIXTURES / "circuit_flat.bg")
    assert names == flat_names == ["tank.q"]
    rng = np.random.default_rng(7)
    for q, t in zip(rng.uniform(-0.02, 0.02, 50), rng.uniform(0, 5, 50)):
        assert hierarchical["tank.q"]([q], t) == pytest.approx(flat["tank.q"]([q], t), rel=1e-12)


def test_bindings_convert_units_and_the_rest_keep_their_defaults():
    graph, _ = load(FIXTURES / "circuit.bg")
    values = {name: p.value for name, p in graph.parameters.items()}
    assert values["valve.A"] == pytest.approx(2e-5)         # bound with a unit
    assert values["valve.Cd"] == pytest.approx(0.7)         # bound, a number in the declared unit
    assert values["valve.rho"] == pytest.approx(850)        # default
    assert [b.name for b in graph.bonds] == ["b1", "b2", "b3", "valve.b3"]
    assert set(graph.elements) == {"supply", "valve.loss", "tank"}


def test_set_reaches_a_parameter_inside_an_instance():
    result = run(FIXTURES / "circuit.bg", sets=["valve.A=1e-5 [m^2]"], t_end=0.5, dt=0.5)
    k = 0.7 * 1e-5 * math.sqrt(2 / 850)
    assert result.outputs["Q"][0] == pytest.approx(k * math.sqrt(100e5), rel=1e-9)


def test_check_on_a_file_with_a_component_and_a_model_checks_both(tmp_path, capsys):
    text = (FIXTURES / "lib" / "hydraulics.bg").read_text() + "\n" + \
        (FIXTURES / "circuit.bg").read_text().replace('import "lib/hydraulics.bg"', "")
    path = tmp_path / "both.bg"
    path.write_text(text)
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert "Orifice:" in out and "a component" in out and "Circuit:" in out
    # the runnable model is the one without ports
    assert run(path, t_end=0.1, dt=0.1).model == "Circuit"


# ------------------------------------------------------------ nesting, ports, references

NESTED = '''
model Pipe "a laminar restriction"
  port a, b
  param R_h = 1e9 [Pa*s/m^3]
  R loss : e = R_h*f
  1 j
  a -> j -> b
  j -> loss
  output Q [m^3/s] = loss.f
end

model TwoPipes "two pipes in series, passing ports straight through"
  port inlet, outlet
  param R_h = 1e9 [Pa*s/m^3]
  Pipe first : R_h = R_h
  Pipe second : R_h = 2*R_h
  inlet -> first.a
  first.b -> second.a
  second.b -> outlet
end

model Plant
  param p_s = 10 [bar]
  Se supply : e = p_s
  TwoPipes line : R_h = 3e9 [Pa*s/m^3]
  C tank : e = q/2e-12
  supply -> line.inlet
  line.outlet -> tank
  output Q [m^3/s] = line.first.loss.f
  output R2 [Pa*s/m^3] = line.second.R_h
  defaults
    rtol = 1e-9
    atol = 1e-18
  end
  experiment fill
    t_end = 0.05 [s]
  end
end
'''


def test_nested_instances_and_ports_passed_straight_through(tmp_path):
    # Series resistance 3e9 + 6e9 into a tank of 2e-12 m^3/Pa: p = p_s*(1 - exp(-t/(R*C))).
    path = tmp_path / "nested.bg"
    path.write_text(NESTED)
    result = run(path, dt=0.01)
    assert result.complete, result.message
    assert result.settings["rtol"] == 1e-9          # from the model's defaults
    tau = 9e9 * 2e-12
    expected = 10e5 * (1 - np.exp(-result.t / tau))
    assert np.allclose(result.states["tank.q"] / 2e-12, expected, rtol=1e-5, atol=1e-3 * 10e5 * 1e-3)
    assert np.allclose(result.outputs["Q"], (10e5 - expected) / 9e9, rtol=1e-4, atol=1e-12)
    assert result.outputs["R2"][0] == pytest.approx(6e9)
    graph, _ = load(path)
    assert set(graph.elements) == {"supply", "line.first.loss", "line.second.loss", "tank"}


def test_equations_and_csv_columns_use_dotted_names(tmp_path, capsys):
    path = tmp_path / "nested.bg"
    path.write_text(NESTED)
    assert main(["equations", str(path)]) == 0
    text = capsys.readouterr().out
    assert "line.first.R_h" in text and "line.second.R_h" in text
    out = tmp_path / "out.csv"
    assert main(["simulate", str(path), "--t-end", "0.01", "-o", str(out)]) == 0
    header = out.read_text().splitlines()[0].split(",")
    assert "line.first.Q [m^3/s]" in header and "tank.q [m^3]" in header and header[0] == "t [s]"


def test_the_same_text_gives_the_same_flat_model_and_code_twice(tmp_path):
    from bondc.codegen.emit import emit as generate_module

    path = tmp_path / "nested.bg"
    path.write_text(NESTED)
    first = generate_module(derive_file(path, cache=False).state_space)
    second = generate_module(derive_file(path, cache=False).state_space)
    assert first == second


# ------------------------------------------------------------ diagnostics

def _errors(tmp_path, text, name="m.bg", files=None):
    for file_name, file_text in (files or {}).items():
        (tmp_path / file_name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / file_name).write_text(file_text)
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(ModelError) as caught:
        load(path)
    return caught.value.diagnostics


PIPE = '''model Pipe
  port a, b
  param R_h = 1e9 [Pa*s/m^3]
  R loss : e = R_h*f
  1 j
  a -> j -> b
  j -> loss
end
'''


def _plant(*lines):
    return PIPE + "model Plant\n  Se s : e = 1\n  C tank : e = q\n" + "".join(f"  {line}\n" for line in lines) + "end\n"


@pytest.mark.parametrize("lines, code, line_number, text", [
    (["Pipe p", "s -> p.a", "p.c -> tank"], "E341", 14, "no port 'c'"),
    (["Pipe p", "s -> p.a", "tank -> p.b"], "E342", 14, "disagree on the power direction"),
    (["Pipe p", "s -> p.a", "p.b -> tank", "p.b -> tank"], "E339", 15, "bonded twice"),
    (["Pipe p : R_x = 2", "s -> p.a", "p.b -> tank"], "E337", 12, "no parameter or input 'R_x'"),
    (["Pipe p", "s -> p", "p.b -> tank"], "E340", 13, "bond one of its ports"),
    (["Pipe p : q(0) = 1", "s -> p.a", "p.b -> tank"], "E335", 12, "bindings"),
    (["Pipe p", "s -> p.a", "p.b -> tank", "output y = p.nothing.e"], "E312", 15, "has no 'nothing'"),
    (["input u [1] = t", "Pipe p : R_h = 1e9*u", "s -> p.a", "p.b -> tank"], "E316", 13,
     "the value of parameter 'R_h' in instance 'p' cannot use input 'u'"),
])
def test_malformed_instances_are_reported_at_the_instance(tmp_path, lines, code, line_number, text):
    diagnostics = _errors(tmp_path, _plant(*lines))
    found = [d for d in diagnostics if d.code == code]
    assert found, [(d.code, d.message) for d in diagnostics]
    assert found[0].span.line == line_number and found[0].span.file.endswith("m.bg")
    assert text in found[0].message


def test_an_instance_port_bonded_nowhere_is_one_error_at_the_instance(tmp_path):
    """A port no bond outside reaches is E343 at the instance, once per port, and nothing else:
    inside, the port is a boundary, so the component's own elements are not reported as
    unbonded in its file."""
    diagnostics = _errors(tmp_path, _plant("Pipe p", "0 n", "s -> n", "n -> p.a", "n -> tank"))
    assert [(d.code, d.span.line) for d in diagnostics] == [("E343", 12)]
    assert "port 'b' of instance 'p' is not bonded" in diagnostics[0].message
    both = _errors(tmp_path, _plant("Pipe p", "0 n", "s -> n", "n -> tank"))
    assert sorted(d.message for d in both) == ["port 'a' of instance 'p' is not bonded",
                                               "port 'b' of instance 'p' is not bonded"]


def test_a_port_drawn_the_wrong_way_is_one_error_and_its_element_inside_is_not_unbonded(tmp_path):
    """std:mechanics' Gravity takes power in at its port; bonded from the port outward, the
    model has one error, E342 at that bond: the weight inside is still bonded, so there is no
    E401 "has no bond" in the library's file."""
    text = ('import "std:mechanics"\nmodel Lift\n  Mass load : M = 3\n  Gravity weight : M = 3\n  1 j\n'
            '  j -> load.a\n  weight.a -> j\nend\n')
    diagnostics = _errors(tmp_path, text)
    assert [(d.code, d.span.line, d.span.file.endswith("m.bg")) for d in diagnostics] == [("E342", 7, True)]
    assert "'weight.a'" in diagnostics[0].message


def test_an_error_inside_a_component_points_into_its_file_and_names_the_instance_path(tmp_path):
    library = PIPE.replace("e = R_h*f", "e = R_h*f + undefined_name")
    text = ('import "lib/pipes.bg"\n'
            "model Line\n  port a, b\n  Pipe inner\n  a -> inner.a\n  inner.b -> b\nend\n"
            "model Plant\n  Se s : e = 1\n  C tank : e = q\n  Line line\n  s -> line.a\n  line.b -> tank\nend\n")
    diagnostics = _errors(tmp_path, text, files={"lib/pipes.bg": library})
    undefined = [d for d in diagnostics if d.code == "E301"]
    assert len(undefined) == 1
    span = undefined[0].span
    assert span.file.endswith("pipes.bg") and span.line == 4 and span.instance == "line.inner"
    from bondc.errors import render

    assert "in line.inner" in render(undefined[0])
    assert undefined[0].to_json()["instance"] == "line.inner"


@pytest.mark.parametrize("component, code, text", [
    ("model Pipe\n  port a, b\n  R loss : e = f\n  1 j\n  a -> j\n  j -> loss\nend\n", "E333", "not bonded"),
    ("model Pipe\n  port a, b\n  R loss : e = f\n  1 j\n  a -> j -> b\n  a -> loss\nend\n", "E339", "twice"),
    ("model Pipe\n  port a, b\n  a -> b\nend\n", "E338", "two ports"),
    ("model Pipe\n  port a, b\n  param b = 2\n  1 j\n  a -> j -> b\nend\n", "E302", "port"),
])
def test_malformed_components_are_reported_in_the_component(tmp_path, component, code, text):
    plant = "model Plant\n  Se s : e = 1\n  C tank : e = q\n  Pipe p\n  s -> p.a\n  p.b -> tank\nend\n"
    diagnostics = _errors(tmp_path, component + plant)
    found = [d for d in diagnostics if d.code == code]
    assert found and text in found[0].message, [(d.code, d.message) for d in diagnostics]
    assert found[0].span.line < component.count("\n") + 1       # inside the component's text


def test_a_model_that_instantiates_itself_is_an_error(tmp_path):
    text = ("model A\n  port a\n  B inner\n  a -> inner.a\nend\n"
            "model B\n  port a\n  A inner\n  a -> inner.a\nend\n"
            "model Top\n  Se s : e = 1\n  A x\n  s -> x.a\nend\n")
    diagnostics = _errors(tmp_path, text)
    assert any(d.code == "E332" and "A -> B -> A" in d.message for d in diagnostics), \
        [(d.code, d.message) for d in diagnostics]


def test_an_unbound_input_without_default_is_an_error_at_the_instance(tmp_path):
    text = ("model Push\n  port a\n  input F [N]\n  Se s : e = F\n  s -> a\nend\n"
            "model Top\n  I m : f = p\n  Push push\n  push.a -> m\nend\n")
    diagnostics = _errors(tmp_path, text)
    found = [d for d in diagnostics if d.code == "E334"]
    assert found and found[0].span.line == 9 and "must bind input 'F'" in found[0].message


def test_two_imports_defining_one_name_need_the_library_name(tmp_path):
    files = {"one.bg": PIPE, "two.bg": PIPE}
    text = ('import "one.bg"\nimport "two.bg"\n'
            "model Top\n  Se s : e = 1\n  C tank : e = q\n  Pipe p\n  s -> p.a\n  p.b -> tank\nend\n")
    diagnostics = _errors(tmp_path, text, files=files)
    assert any(d.code == "E331" and "one.bg" in d.message and "two.bg" in d.message for d in diagnostics)
    qualified = text.replace("  Pipe p", "  two.Pipe p")
    path = tmp_path / "q.bg"
    path.write_text(qualified)
    graph, _ = load(path)
    assert "p.loss" in set(graph.elements)
    unknown = text.replace("  Pipe p", "  three.Pipe p")
    assert any(d.code == "E330" for d in _errors(tmp_path, unknown, name="u.bg"))


def test_an_unknown_std_library_is_an_error_with_the_list(tmp_path):
    path = tmp_path / "m.bg"
    path.write_text('import "std:hydraulic"\nmodel M\n  C c : e = q\n  Se s : e = 1\n  s -> c\nend\n')
    with pytest.raises(ModelError) as caught:
        load(path)
    (error,) = [d for d in caught.value.diagnostics if d.code == "E307"]
    assert "std:hydraulics" in error.hint


def test_check_json_names_the_instance_path(tmp_path, capsys):
    library = PIPE.replace("e = R_h*f", "e = R_h*f + nope")
    path = tmp_path / "m.bg"
    path.write_text(library + "model Top\n  Se s : e = 1\n  C tank : e = q\n  Pipe p\n  s -> p.a\n  p.b -> tank\nend\n")
    assert main(["check", "--model", "Top", "--json", str(path)]) == 1
    data = json.loads(capsys.readouterr().out)
    assert [d["instance"] for d in data["diagnostics"] if d["code"] == "E301"] == ["p"]


# ------------------------------------------------------------ the flagship from components

@pytest.mark.slow
def test_the_component_flagship_gives_the_cycle_figures_of_the_flat_one():
    flat = run(MODELS / "electro_pneumatic_hybrid.bg")
    parts = run(MODELS / "electro_pneumatic_hybrid_components.bg")
    assert flat.complete and parts.complete
    # the trajectories, the one interpolated linearly at the other's steps: the two derivations print
    # the same laws in another order, the runs' steps part by rounding (the backlash is a kink, crossed
    # inside steps), and linear interpolation between 12 000 steps is good to a few 1e-4 (each run
    # is within 5e-4 N*m of an rtol 1e-10 run of the torque, interpolated so); the cycle figures below
    # are the design answer, and they agree to 1e-5
    for name in ("torque", "power", "x", "v", "F_nut", "mdot_valve"):
        a = np.interp(flat.t, parts.t, parts.outputs[name])
        scale = np.max(np.abs(flat.outputs[name]))
        assert np.max(np.abs(a - flat.outputs[name])) < 1e-3 * scale, name
    # the extremes at the steps: each run's lies up to 2.5e-4 inside an rtol 1e-10 run's (-0.34055 N*m,
    # the peak falls between steps), the two runs' within 5e-4 of each other
    for stat in (np.max, np.min):
        assert stat(parts.outputs["torque"]) == pytest.approx(stat(flat.outputs["torque"]), rel=5e-4)
    rms = [math.sqrt(np.trapezoid(r.outputs["torque"] ** 2, r.t) / r.t[-1]) for r in (flat, parts)]
    assert rms[1] == pytest.approx(rms[0], rel=1e-5)
    energy = [np.trapezoid(np.maximum(r.outputs["power"], 0), r.t) for r in (flat, parts)]
    assert energy[1] == pytest.approx(energy[0], rel=1e-5)


def test_an_unsaved_buffer_is_checked_with_its_imports_from_disk(tmp_path):
    # what an editor does: the text on screen, not the file on disk; imports resolve beside the file
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "hydraulics.bg").write_text((FIXTURES / "lib" / "hydraulics.bg").read_text())
    path = tmp_path / "circuit.bg"
    path.write_text("model Stale\nend\n")
    buffer = (FIXTURES / "circuit.bg").read_text().replace("Cd = 0.7", "Cd = 0.65")
    graph, _ = load(path, text=buffer)
    assert graph.name == "Circuit" and graph.parameters["valve.Cd"].value == 0.65
    with pytest.raises(ModelError) as caught:
        load(path, text=buffer.replace("valve.b -> n", "valve.c -> n"))
    (error,) = [d for d in caught.value.diagnostics if d.code == "E341"]
    assert error.span.file == str(path) and error.span.line == 12


def test_the_checked_model_keeps_every_declaration_and_use_of_its_names():
    # one scope, on the flat model: the equations resolve through it and editors look up names in it
    graph, _ = load(FIXTURES / "circuit.bg")
    scope = graph.scope
    area = scope.declarations["valve.A"]
    assert area.category == "parameter" and area.span.file.endswith("hydraulics.bg") and area.span.instance == "valve"
    assert [u.span.line for u in scope.uses_of("valve.A")] == [6]          # in the orifice law, its own file
    assert scope.category("valve.Q") == "output" and scope.category("p_s") == "parameter"
    circuit = (FIXTURES / "circuit.bg").read_text().splitlines()
    line = next(n for n, text in enumerate(circuit, 1) if "output Q" in text)
    column = circuit[line - 1].index("valve.Q") + 1
    assert scope.at(str(FIXTURES / "circuit.bg"), line, column + 6).name == "valve.Q"
    assert {u.span.line for u in scope.uses_of("p_s")} == {7}              # Se supply : e = p_s


def test_the_firings_of_a_components_when_clauses_name_the_instance(tmp_path):
    """Two thermostat rooms from one component (tau = R C = 500 s, T(0) = 290 K, ambient 280 K):
    room r1 (100 W, T_set 300 K) first switches off at 301 K, 500 ln(40/29) s; r2 (120 W, 295 K) at
    296 K, 500 ln(50/44) s. Each firing names its instance's own names."""
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "thermo.bg").write_text('''model Room "a room heated by an on/off heater"
  port amb
  param C_th = 1000 [J/K]
  param P = 100 [W]
  param T_set = 300 [K]
  param hyst = 1 [K]
  discrete on [1] = 1
  MSf heater : f = P*on
  C air : state T [K], T(0) = 290, der(T) = f/C_th, e = T
  R wall : f = e/0.5
  0 n
  1 l
  heater -> n
  n -> air
  n -> l
  l -> wall
  l -> amb
  when air.e > T_set + hyst then on = 0 end
  when air.e < T_set - hyst then on = 1 end
end
''')
    path = tmp_path / "rooms.bg"
    path.write_text('''import "lib/thermo.bg"
model Rooms
  Room r1 : P = 100
  Room r2 : P = 120, T_set = 295
  Se ambient : e = 280
  0 a
  r1.amb -> a
  r2.amb -> a
  a -> ambient
  experiment day
    t_end = 300 [s]
    rtol = 1e-10
    atol = 1e-8
  end
end
''')
    result = run(path)
    assert result.complete, result.message
    first = {}
    for time, label in result.events:
        first.setdefault(label, time)
    assert first["when r1.air.e > r1.T_set + r1.hyst"] == pytest.approx(500 * math.log(40 / 29), rel=1e-7)
    assert first["when r2.air.e > r2.T_set + r2.hyst"] == pytest.approx(500 * math.log(50 / 44), rel=1e-7)
    assert {label.split(".")[0] for label in first if label.startswith("when ")} == {"when r1", "when r2"}


def test_a_misspelt_or_ambiguous_component_kind_is_one_error_with_the_right_suggestion(tmp_path):
    text = '''import "std:hydraulics"
import "std:pneumatics"
import "std:mechanics"
model A
  Cylinder cyl
  Mas body : M = 2
  mechanics.Mas body2 : M = 2
end
'''
    errors = _errors(tmp_path, text)
    assert [(d.code, d.span.line) for d in errors] == [("E331", 5), ("E303", 6), ("E330", 7)]
    assert errors[1].hint.startswith("did you mean 'Mass'?")
    assert errors[2].hint.startswith("did you mean 'mechanics.Mass'?") and "import" not in errors[2].hint


RELAY_CHARGER = """import "std:electrical"
model RelayCharger "a relay switches the supply of an RC circuit between 10 V and 0 V at 6 V and 3 V"
  discrete u [V] = 10
  SOURCE
  Resistor r : R = 1000 [Ohm]
  Capacitor c : C = 1e-3 [F]
  1 loop
  OUT -> loop
  loop -> r.a
  loop -> c.a
  when c.v > 6 then u = 0 end
  when c.v < 3 then u = 10 end
  output v [V] = c.v
  experiment run
    t_end = 5 [s]
  end
end
"""


def _relay(tmp_path, source, out):
    path = tmp_path / f"relay_{out.replace('.', '_')}.bg"
    path.write_text(RELAY_CHARGER.replace("SOURCE", source).replace("OUT", out))
    return path


def test_a_component_input_bound_to_a_discrete_variable_is_the_bare_source_to_the_bit(tmp_path):
    """Section 11 of the reference: an instance's input takes any signal expression of the outer
    model, and section 12: discrete variables may be used in any expression. Binding a controller's
    held output to VoltageSource was E316 ('an input cannot use discrete variable'); the instance's
    input is now a named expression of the outer model, and the run is the one with a bare Se."""
    ours = run(_relay(tmp_path, "VoltageSource src : u = u", "src.a"))
    bare = run(_relay(tmp_path, "Se src : e = u", "src"))
    assert ours.complete and bare.complete
    np.testing.assert_array_equal(ours.t, bare.t)
    np.testing.assert_array_equal(ours.outputs["v"], bare.outputs["v"])
    assert set(np.unique(ours.outputs["src.u"])) == {0.0, 10.0}
    # the relay: charging through RC = 1 s from 0 to 6 V, then discharging from 6 to 3 V
    firings = [time for time, label in ours.events if label.startswith("when")]
    assert firings[0] == pytest.approx(-math.log(1 - 0.6), abs=1e-5)
    assert firings[1] - firings[0] == pytest.approx(math.log(2), abs=1e-5)


def test_a_component_input_bound_to_a_current_instead_of_a_voltage_is_a_dimension_error(tmp_path):
    with pytest.raises(ModelError) as excinfo:
        derive_file(_relay(tmp_path, "VoltageSource src : u = r.i", "src.a"), cache=False)
    assert any(d.code == "E210" for d in excinfo.value.diagnostics), excinfo.value.diagnostics


NESTED_DRIVER = """import "std:electrical"
model Driver "a voltage source inside a component, driven through the component's own input"
  port out
  input v_cmd [V]
  VoltageSource vs : u = v_cmd
  vs.a -> out
end

model Nested "the outer model binds the component's input to a discrete variable"
  discrete cmd [V] = 10
  Driver drv : v_cmd = cmd
  Resistor r : R = 1000 [Ohm]
  Capacitor c : C = 1e-3 [F]
  1 loop
  drv.out -> loop
  loop -> r.a
  loop -> c.a
  when c.v > 6 then cmd = 0 end
  when c.v < 3 then cmd = 10 end
  output v [V] = c.v
  experiment run
    t_end = 5 [s]
  end
end
"""


def test_an_input_bound_to_a_discrete_variable_reaches_a_source_inside_a_nested_component(tmp_path):
    """The outer binding made the Driver's input a named expression, but the VoltageSource inside it,
    bound to that input, stayed an input and was E316 ('an input cannot use output drv.v_cmd')."""
    path = tmp_path / "nested.bg"
    path.write_text(NESTED_DRIVER)
    ours = run(path)
    bare = run(_relay(tmp_path, "Se src : e = u", "src"))
    assert ours.complete and bare.complete
    np.testing.assert_array_equal(ours.t, bare.t)
    np.testing.assert_array_equal(ours.outputs["v"], bare.outputs["v"])
