"""Every code block of the language reference parses and checks.

``tests/fixtures/language/`` holds each block of the reference (sections 2 to
13) as a model: the block verbatim, wrapped in a model that declares the names
it uses, with placeholders (``...statements...``, ``then ... else ...``) filled
in. The complete model of section 10 is there exactly as the reference prints
it. Each must parse and check with no errors.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bondc import semantic
from bondc.parse import parse_file

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "language"
EXAMPLES = sorted(FIXTURES.glob("*.bg"))


def test_every_section_has_examples():
    sections = {path.name[:3] for path in EXAMPLES}
    assert sections == {f"s{n:02d}" for n in range(2, 14)}


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_example_parses(path):
    parse_file(path)


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_example_checks(path):
    graph, warnings = semantic.load(path)
    assert not [w for w in warnings if w.is_error]
    for experiment in graph.experiments:
        semantic.load(path, experiment=experiment)


def test_complete_model_of_section_10():
    graph, warnings = semantic.load(FIXTURES / "s10_complete_model.bg", experiment="step")
    assert warnings == []
    assert graph.name == "MassSpringDamper"
    assert [(b.number, b.tail, b.head) for b in graph.bonds] == [
        (1, "force", "j"), (2, "j", "mass"), (3, "j", "spring"), (4, "j", "damper")]
    assert {name: p.value for name, p in graph.parameters.items()} == {"m": 2.0, "k": 800.0, "b": 12.0}
    assert [s.qualified for s in graph.states] == ["mass.p", "spring.q"]
    assert graph.experiments["step"].t_end == 2.0
    assert graph.outputs["x"].unit_text == "m"


def test_section_9_experiment_settings():
    graph, _ = semantic.load(FIXTURES / "s09_experiments.bg", experiment="cycle")
    cycle = graph.experiments["cycle"]
    assert (cycle.t_end, cycle.solver, cycle.rtol, cycle.atol, cycle.max_step, cycle.cycle, cycle.outputs) == (
        3.6, "Radau", 1e-6, 1e-9, 0.001, 3.6, ("torque", "power"))


def test_section_3_parameters_in_si():
    graph, _ = semantic.load(FIXTURES / "s03_parameters.bg")
    values = {name: p.value for name, p in graph.parameters.items()}
    assert values["lead"] == 0.005
    assert values["n"] == pytest.approx(104.7197551)
    assert values["Ar"] == pytest.approx(3.141592653589793 / 4 * (0.04 ** 2 - 0.02 ** 2))


def test_section_13_experiments_inherit_the_defaults():
    graph, _ = semantic.load(FIXTURES / "s13_builtins_defaults.bg", experiment="cycle")
    cycle = graph.experiments["cycle"]
    assert (cycle.solver, cycle.rtol, cycle.cycle, cycle.t_end) == ("Radau", 1e-6, 4.2, 4.2)


def test_section_11_instance_names_are_dotted():
    graph, _ = semantic.load(FIXTURES / "s11_submodels.bg")
    assert set(graph.elements) == {"supply", "valve.loss", "tank"}
    assert graph.parameters["valve.A"].value == 2e-5 and graph.parameters["valve.Cd"].value == 0.7
