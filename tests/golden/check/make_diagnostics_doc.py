"""Writes docs/diagnostics.md: every diagnostic code bondc can emit, with an example of each.

Run ``python tests/golden/check/make_diagnostics_doc.py`` after ``pytest --update-golden``
changed a golden ``.txt``, after a diagnostic's wording changed, or after an explanation changed
(explanations live in the package's registry, ``bondc/codes.py``; never edit the page). The tests fail when the page is stale:
``tests/test_golden_check.py`` and ``tests/test_golden_stages.py`` check that it quotes every
golden case, that every code in ``bondc/`` has a section, and that the page is what this
script writes.

Each section's examples come from, in this order:

* ``PARSE_EXAMPLES``: small inputs to the parser (E1xx);
* the golden cases of ``tests/golden/check/`` (E2xx-E5xx, W3xx: ``bondc check``) and of
  ``tests/golden/stages/`` (E6xx-E8xx, E94x: causality, equations, simulation, linearisation),
  quoted with their expected output;
* ``LIVE``: examples run here, each in a fresh temporary directory, for what a model cannot
  show -- data files, command-line arguments, the Python API. A ``Cli`` example runs the real
  ``bondc`` command line in-process and shows what it prints; an ``Api`` example executes its
  code as shown and renders the diagnostics it raises (or leaves in ``shown``).

The script stops with an error when an example does not show its code, or when ``bondc/``
emits a code that the registry (``bondc/codes.py``) lacks.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
import shlex
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from bondc.codes import CODES, STAGES, slug, stage_of
from bondc.errors import BondcError, ParseError, render_all
from bondc.parse import parse_text
from bondc.source import Source

GOLDEN = Path(__file__).resolve().parent
STAGES_GOLDEN = GOLDEN.parent / "stages"
ROOT = GOLDEN.parent.parent.parent
PAGE = ROOT / "docs" / "diagnostics.md"

#: code -> (title, what it means, how to fix it): the package's registry (bondc/codes.py)
EXPLANATIONS: dict[str, tuple[str, str, str]] = {code: (entry.title, entry.meaning, entry.fix)
                                                 for code, entry in CODES.items()}
# ================================================================== examples

PARSE_EXAMPLES = {
    "E100": "model M\n  param = 3\nend\n",
    "E101": "model M\n  param k = 3 $\nend\n",
    "E102": "model M\n  param k = 3 \"spring stiffness\nend\n",
    "E103": "model M\n  param k = 3\n",
    "E104": "model M\n  param end = 3\nend\n",
}


@dataclass
class Cli:
    """``bondc ...`` run in-process in a fresh directory holding ``files``; shows what it prints.

    ``stream``: "stderr" (diagnostics) or "stdout"; ``lines``: keep only the lines containing
    this text (for a warning inside a long report).
    """

    command: str
    files: dict[str, str] = field(default_factory=dict)
    stream: str = "stderr"
    lines: str | None = None
    note: str | None = None
    expect: str | None = None       # what the output must contain; default "[CODE]"


@dataclass
class Api:
    """Python code executed in a fresh directory holding ``files``; shows the diagnostics it raises
    (a BondcError) or leaves in a variable ``shown``."""

    code: str
    files: dict[str, str] = field(default_factory=dict)
    note: str | None = None


LIVE: dict[str, list] = {}


def live(code: str, *examples) -> None:
    LIVE.setdefault(code, []).extend(examples)


# -- files shared by the examples

SPIN = """model Spin
  param J = 2e-4 [kg*m^2]
  param b = 1e-3 [N*m*s]
  Se motor : e = 0.5
  I  rotor : f = p/J
  R  drag  : e = b*f
  1  shaft
  motor -> shaft
  shaft -> rotor
  shaft -> drag
  output omega [rad/s] = rotor.f
  output torque [N*m] = motor.e
  experiment run
    t_end = 1 [s]
  end
end
"""
SPIN_NO_TORQUE = SPIN.replace("  output torque [N*m] = motor.e\n", "")
LOOSE = """model Bounce
  Se push   : e = 10
  I  mass   : f = p/1
  C  spring : e = 1e4*q
  R  damper : e = 2*f
  1  j
  push -> j
  j -> mass
  j -> spring
  j -> damper
  experiment run
    t_end = 1 [s]
    rtol = 1e-2
    atol = 1e-3
  end
end
"""
MEASURED = "t,omega_meas\n0,0\n0.5,1210\n1,2150\n"
CATALOGUE_HEADER = "name,rated_torque,peak_torque,rated_speed,rated_power,rotor_inertia\n"
CATALOGUE = CATALOGUE_HEADER + "SV-750,2.39,7.16,3000,750,1.7e-4\nSV-1000M,3.18,9.55,3000,1000,6.5e-4\n"
FRICTION_HEADER = "velocity [m/s],torque [N*m],pressure [Pa]\n"
UP = "0.02,0.18626,224000\n0.05,0.24115,224000\n0.1,0.29269,224000\n"
DOWN = "-0.02,-0.10095,224000\n-0.05,-0.13446,224000\n-0.1,-0.16773,224000\n"
FRICTION = FRICTION_HEADER + UP + DOWN

# -- analyses and data files

live("E901", Cli("bondc fit-friction tests.csv", {"tests.csv": FRICTION_HEADER}))
live("E902", Cli("bondc fit-friction tests.csv", {"tests.csv": FRICTION.replace("velocity", "speed", 1)}))
live("E903", Cli("bondc fit-friction tests.csv", {"tests.csv": FRICTION.replace("0.24115", "n/a")}))
live("E904", Cli("bondc fit-friction tests.csv", {"tests.csv": FRICTION.replace("0.05,0.24115,224000",
                                                                                 "0.05,0.24115")}))
live("E905", Cli("bondc fit-friction test.csv", {"tests.csv": FRICTION}, note="The file is `tests.csv`."))
live("E906", Cli("bondc fit-friction tests.csv", {"tests.csv": FRICTION.replace("[m/s]", "[N]")}))
live("E910", Cli("bondc fit-friction tests.csv", {"tests.csv": FRICTION + "0,0.2,224000\n"}))
live("E911", Cli("bondc fit-friction tests.csv", {"tests.csv": FRICTION_HEADER + UP + DOWN.split("\n", 1)[1]}))
live("E912", Cli("bondc fit-friction tests.csv", {"tests.csv": FRICTION.replace("224000", "122675")},
                 note="The pressures are gauge pressures (absolute minus 101325 Pa), read as absolute."))
live("E913", Cli("bondc fit-friction tests.csv",
                 {"tests.csv": FRICTION_HEADER + "0.05,0.24115,224000\n" * 3 + DOWN}))
live("E914", Cli("bondc fit-friction tests.csv --lead 0", {"tests.csv": FRICTION}))
live("E915", Cli("bondc fit-friction tests.csv", {"tests.csv": FRICTION_HEADER
                 + "0.02,0.52950,60000\n0.05,0.58438,60000\n0.1,0.63592,60000\n"
                 + "-0.02,0.24228,60000\n-0.05,0.20878,60000\n-0.1,0.17551,60000\n"}, stream="stdout"))
live("E920", Cli("bondc simulate spin.bg --motors motors.csv",
                 {"spin.bg": SPIN, "motors.csv": CATALOGUE.replace("rotor_inertia", "rotor_inertai")}))
live("E921", Cli("bondc simulate spin.bg --motors motors.csv",
                 {"spin.bg": SPIN, "motors.csv": CATALOGUE.replace("2.39,7.16", "7.16,2.39")}))
live("E922", Cli("bondc simulate spin.bg --motors motors.csv",
                 {"spin.bg": SPIN, "motors.csv": CATALOGUE + "SV-750,2.4,7.2,3000,750,1.7e-4\n"}))
live("E923", Api("from bondc.analysis.motors import requirements\n"
                 "requirements([0.0, 0.5, 1.0], [0.2, 0.4], [100.0, 150.0, 200.0])"))
live("E924", Api("from bondc.analysis.motors import requirements\n"
                 "requirements([0.0, 0.5, 0.5], [0.2, 0.3, 0.4], [100.0, 150.0, 200.0])"))
live("E925", Api("from bondc.analysis.motors import requirements\n"
                 "requirements([0.0, 0.5, 1.0], [0.2, 0.3, 0.4], [100.0, 150.0, 200.0], cycle=(0.5, 2.0))"))
live("E928", Cli("bondc simulate spin.bg --motors motors.csv --inertia-ratio -5",
                 {"spin.bg": SPIN, "motors.csv": CATALOGUE}))
live("E973", Cli("bondc simulate spin.bg --ratio n=2,5", {"spin.bg": SPIN}))
live("E927", Cli("bondc simulate spin.bg --motors motors.csv", {"spin.bg": SPIN_NO_TORQUE, "motors.csv": CATALOGUE}))

_IMPORTS = ("from bondc import semantic\n"
            "from bondc.causality import assign_causality\n"
            "from bondc.equations import derive\n"
            "from bondc.simulate import simulate\n")
_SPIN_API = (_IMPORTS
             + "graph, _ = semantic.load(\"spin.bg\")\n"
             "ss = derive(assign_causality(graph))\n"
             "result = simulate(ss, graph.experiments[\"run\"])\n")


live("E804", Api(_IMPORTS
                 + "graph, _ = semantic.load(\"replay.bg\")\n"
                 "ss = derive(assign_causality(graph))\n"
                 "with open(\"push.csv\", \"w\") as data:       # edited after the check\n"
                 "    data.write(\"t,force\\n0,1\\n0.5,n/a\\n1,2\\n\")\n"
                 "simulate(ss, graph.experiments[\"run\"])\n",
                 {"replay.bg": "model Replay\n  input F [N] = csv(\"push.csv\", \"force\")\n  MSe push : e = F\n"
                               "  I   mass : f = p/2\n  push -> mass\n  experiment run\n    t_end = 1 [s]\n"
                               "  end\nend\n",
                  "push.csv": "t,force\n0,1\n0.5,1.5\n1,2\n"}))


_DRIVE = """model Drive
  input u [V] external    "drive voltage, supplied by the host"
  input w [V] = 0
  Se supply : e = u + w
  R  load   : e = 10*f
  C  c      : e = q/1e-3
  1  j
  supply -> j -> load
  j -> c
  experiment run
    t_end = 1 [s]
  end
end
"""
_DRIVE_CSV = "t,u [V]\n0,0\n0.1,12\n1,12\n"
live("I346", Cli("bondc check drive.bg", {"drive.bg": _DRIVE}, lines="I346"))
live("E805", Cli("bondc simulate drive.bg --input v=drive.csv", {"drive.bg": _DRIVE, "drive.csv": _DRIVE_CSV}))
live("E806", Cli("bondc simulate drive.bg --input w=drive.csv", {"drive.bg": _DRIVE, "drive.csv": _DRIVE_CSV}))
live("E807", Cli("bondc simulate drive.bg --input u=drive.csv:volts", {"drive.bg": _DRIVE, "drive.csv": _DRIVE_CSV}),
     Api("import bondc\nbondc.simulate(\"drive.bg\", inputs={\"u\": ([0, 1, 0.5], [0, 12, 12])})",
         {"drive.bg": _DRIVE}))


def _with(imports: str, code: str) -> str:
    """``code`` with more import lines after the first ones."""
    return code.replace(_IMPORTS, _IMPORTS + imports, 1)


_ENERGY = "from bondc.analysis.energy import energy_account\n"
live("E930", Api(_with(_ENERGY, _SPIN_API.replace("result = ", "other_graph, _ = semantic.load(\"bounce.bg\")\n"
                                                  "other = derive(assign_causality(other_graph))\nresult = "))
                 + "energy_account(other, result)", {"spin.bg": SPIN, "bounce.bg": LOOSE}))
live("E931", Api(_with(_ENERGY, _SPIN_API.replace("simulate(ss, graph.experiments[\"run\"])",
                                                  "simulate(ss, graph.experiments[\"run\"], t_eval=[0.0])"))
                 + "energy_account(ss, result)", {"spin.bg": SPIN}))
live("E932", Api(_with(_ENERGY, _SPIN_API) + "energy_account(ss, result, cycle=0)", {"spin.bg": SPIN}))
live("E935", Api(_with(_ENERGY, _SPIN_API) + "energy_account(ss, result, cycle=1e-9)", {"spin.bg": SPIN}))
live("E933", Api(_with("from bondc.analysis.stats import power_statistics\n", _SPIN_API)
                 + "power_statistics(result, [\"power\"])", {"spin.bg": SPIN}))
_TINY = """model Tiny
  param m = 1e-320 [kg]
  Se push : e = 1
  I  mass : f = p/m
  push -> mass
  experiment run
    t_end = 1 [s]
  end
end
"""
live("E934", Cli("bondc simulate tiny.bg", {"tiny.bg": _TINY}, lines="[E934]"))
live("W930", Cli("bondc simulate bounce.bg", {"bounce.bg": LOOSE}, stream="stdout", lines="[W930]",
                 note="Of the energy account `bondc simulate` prints, only its last line is shown here."))

# -- frequency response

_CUBIC = """model CubicSpring
  param m  = 1   [kg]
  param k1 = 100 [N/m]
  param k3 = 1e4 [N/m^3]
  param b  = 4   [N*s/m]
  param F0 = 10  [N]
  input F [N] = F0
  MSe force  : e = F
  I   mass   : f = p/m
  C   spring : e = k1*q + k3*q^3
  R   damper : e = b*f
  1   j
  force -> j
  j -> mass
  j -> spring
  j -> damper
  output x [m] = spring.q
  output v [m/s] = mass.f
end
"""
# the same mass, on a linear spring with dry friction, at rest: on the friction's switch
_STUCK = (_CUBIC.replace("CubicSpring", "StuckFriction").replace("  param k3 = 1e4 [N/m^3]\n", "")
          .replace("input F [N] = F0", "input F [N] = 0").replace("e = k1*q + k3*q^3", "e = k1*q")
          .replace("e = b*f", "e = b*f + coulomb(f, F0/2)"))
_BODE = "bondc bode spring.bg "
live("E942", Cli(_BODE + "--output xx", {"spring.bg": _CUBIC}))
live("E943", Cli(_BODE + "--input k1 --output x", {"spring.bg": _CUBIC}))
live("E944", Cli(_BODE + "--output x --from 100 --to 10", {"spring.bg": _CUBIC}),
     Cli(_BODE + "--output x --from '3 [m]'", {"spring.bg": _CUBIC}))
live("E945", Cli(_BODE + "--output x --points 1", {"spring.bg": _CUBIC}))
live("E946", Cli(_BODE + "--output x --verify", {"spring.bg": _CUBIC}))
live("E947", Cli(_BODE + "--output x -o bode.png", {"spring.bg": _CUBIC}))
live("W942", Cli("bondc bode stuck.bg --output x --points 5", {"stuck.bg": _STUCK}, lines="W942"))
live("W943", Cli(_BODE + "--output x --at equilibrium --verify --amplitude 8", {"spring.bg": _CUBIC},
                 lines="W943", note="A sine almost as large as the force itself moves the mass far along the "
                                    "hardening spring."))
# and on a spring whose force grows as the root of its extension, which has no value in compression
_ROOT = (_CUBIC.replace("CubicSpring", "RootSpring").replace("  param k3 = 1e4 [N/m^3]\n", "")
         .replace("param k1 = 100 [N/m]", "param k1 = 100 [N/m^0.5]")
         .replace("e = k1*q + k3*q^3", "e = k1*sqrt(q), q(0) = 0.01"))
live("W944", Cli("bondc bode root.bg --output x --at equilibrium --verify --amplitude 100", {"root.bg": _ROOT},
                 lines="run at 0.7667 Hz", note="A sine of 100 N against 10 N pulls the spring into compression, "
                                            "where sqrt(q) has no value; the runs at the other frequencies stop "
                                            "the same way."))

# -- sweeps

_SWEEP = "bondc sweep spin.bg "
live("E960", Cli(_SWEEP + "--vary J", {"spin.bg": SPIN}))
live("E961", Cli(_SWEEP + "--vary j=1e-4,2e-4", {"spin.bg": SPIN}))
live("E962", Cli(_SWEEP + "--vary J=1e-4:4e-4:1", {"spin.bg": SPIN}))
live("E963", Cli(_SWEEP + "--vary 'J=1,2 [kg]'", {"spin.bg": SPIN}))
live("E964", Cli(_SWEEP + "--vary J=1e-4:4e-4:400 --vary b=1e-4:1e-3:400", {"spin.bg": SPIN}))
live("E965", Cli(_SWEEP + "--vary J=1e-4,2e-4 --metric omgea.max", {"spin.bg": SPIN}))
live("E966", Cli(_SWEEP + "--vary J=1e-4 --vary J=2e-4", {"spin.bg": SPIN}))
live("E967", Cli(_SWEEP + "--vary J=1e-4 --jobs 0", {"spin.bg": SPIN}))
live("E969", Cli(_SWEEP + "--vary J=1e-4,2e-4 -o results.txt", {"spin.bg": SPIN}))
live("E970", Cli(_SWEEP + "--vary J=1e-4,4e-4 --metric omega.final -o study.csv",
                 {"spin.bg": SPIN,
                  "study.csv": "index,J [kg*m^2],omega.final [rad/s],status,message,wall_time [s]\n"
                               "0,0.0001,499.99,ok,,0.02\n1,0.0002,496.63,ok,,0.02\n"},
                 note="`study.csv` is the table of an earlier `--vary J=1e-4,2e-4`."))

# -- calibration

_FIT_TIMES = [i / 10 for i in range(11)]
FIT_DATA = "t,omega_meas\n" + "".join(f"{t:g},{2000 * (1 - math.exp(-t / 0.4)):.5g}\n" for t in _FIT_TIMES)
_FIT = "bondc fit spin.bg --data measured.csv "
SPIN_STEP = SPIN.replace("  experiment run\n", "  param h = 1 [ms]\n  experiment run\n    max_step = h\n")
PRODUCT = """model RC
  param a = 100 [Ohm]
  param b = 10 [1]
  Se source : e = 10
  R  r      : e = a*b*f
  C  cap    : e = q/1e-3
  1  loop
  source -> loop
  loop -> r
  loop -> cap
  output v [V] = cap.e
  experiment charge
    t_end = 5 [s]
  end
end
"""
RC_DATA = "t,v\n" + "".join(f"{t / 2:g},{10 * (1 - math.exp(-t / 2 / 1.5)):.6g}\n" for t in range(11))
_SQRT = ("model Sqrt\n  param c = 2 [s]\n  Se s : e = sqrt(c - t)\n  I m : f = p\n  s -> m\n"
         "  output y = m.p\n  experiment run\n    t_end = 1 [s]\n  end\nend\n")
_SQRT_DATA = "t,y\n" + "".join(f"{t / 10:g},{(2 / 3) * (0.6 ** 1.5 - (0.6 - t / 10) ** 1.5):.6g}\n"
                                for t in range(6)) + "0.6,0.31\n"
live("E880", Cli(_FIT + "--compare omega --estimate b", {"spin.bg": SPIN, "measured.csv": FIT_DATA}))
live("E881", Cli(_FIT + "--compare omega=omega_meas --estimate b=1e-4", {"spin.bg": SPIN, "measured.csv": FIT_DATA}))
live("E882", Cli(_FIT + "--compare omega=omega_meas --estimate j", {"spin.bg": SPIN, "measured.csv": FIT_DATA}))
live("E883", Cli(_FIT + "--compare omega=omega_meas --estimate h=0.5:5", {"spin.bg": SPIN_STEP,
                                                                          "measured.csv": FIT_DATA}))
live("E884", Cli(_FIT + "--compare omega=omega_meas --estimate b=1e-3:1e-4",
                 {"spin.bg": SPIN, "measured.csv": FIT_DATA}))
live("E885", Cli(_FIT + "--compare omega=omega_meas --estimate b=2e-3:1e-2",
                 {"spin.bg": SPIN, "measured.csv": FIT_DATA}))
live("E886", Cli(_FIT + "--compare omega=omega_mes --estimate b", {"spin.bg": SPIN, "measured.csv": FIT_DATA}))
live("E887", Cli(_FIT + "--compare speed=omega_meas --estimate b", {"spin.bg": SPIN, "measured.csv": FIT_DATA}))
live("E888", Cli(_FIT + "--compare omega=omega_meas --estimate b --estimate b=1e-4:1e-2",
                 {"spin.bg": SPIN, "measured.csv": FIT_DATA}))
live("E889", Cli("bondc fit spin.bg --compare omega=omega_meas --data measured.csv --estimate b",
                 {"spin.bg": SPIN, "measured.csv": FIT_DATA}))
live("E890", Cli(_FIT + "--compare omega=omega_meas --estimate b --write spin.bg",
                 {"spin.bg": SPIN, "measured.csv": FIT_DATA}))
live("E891", Cli("bondc fit sqrt.bg --data y.csv --compare y=y --estimate c=0.1:3",
                 {"sqrt.bg": _SQRT.replace("param c = 2", "param c = 0.5"), "y.csv": _SQRT_DATA}))
live("E892", Cli(_FIT + "--compare omega=omega_meas --estimate J=0:1e-3", {"spin.bg": SPIN, "measured.csv": FIT_DATA}))
live("W880", Cli("bondc fit rc.bg --data v.csv --compare v=v --estimate a=1:1000 --estimate b=0.1:100",
                 {"rc.bg": PRODUCT, "v.csv": RC_DATA}, lines="W88"))
live("W881", Cli("bondc fit rc.bg --data v.csv --compare v=v --estimate a=1:1000 --estimate b=0.1:100",
                 {"rc.bg": PRODUCT, "v.csv": RC_DATA}, lines="W88"))
live("W882", Cli(_FIT + "--compare omega=omega_meas --estimate b=2.6e-4:1e-2 --estimate J",
                 {"spin.bg": SPIN, "measured.csv": FIT_DATA}, lines="W882"))
live("W883", Cli(_FIT + "--compare omega=omega_meas --estimate b --estimate J --max-evaluations 1",
                 {"spin.bg": SPIN, "measured.csv": FIT_DATA}, lines="W883"))
live("W884", Cli("bondc fit sqrt.bg --data y.csv --compare y=y --estimate c=0.1:3",
                 {"sqrt.bg": _SQRT, "y.csv": _SQRT_DATA}, lines="W884"))

# -- validation

_VALIDATE = "bondc validate spin.bg --data measured.csv --compare omega=omega_meas"
live("E950", Cli(_VALIDATE.replace("measured.csv", "measurd.csv"), {"spin.bg": SPIN, "measured.csv": MEASURED}))
live("E951", Cli(_VALIDATE, {"spin.bg": SPIN, "measured.csv": MEASURED.replace("1210", "")}))
live("E952", Cli(_VALIDATE, {"spin.bg": SPIN, "measured.csv": MEASURED.replace("\n1,", "\n0.5,")}))
live("E953", Cli(_VALIDATE.replace("omega_meas", "omega_measured"), {"spin.bg": SPIN, "measured.csv": MEASURED}))
live("E954", Cli(_VALIDATE.replace("omega=", "speed="), {"spin.bg": SPIN, "measured.csv": MEASURED}))
live("E955", Cli(_VALIDATE + ":nrmse=5%", {"spin.bg": SPIN, "measured.csv": MEASURED}))
live("E956", Cli(_VALIDATE, {"spin.bg": SPIN, "measured.csv": "t,omega_meas\n5,2300\n6,2310\n"}))
live("E957", Cli(_VALIDATE, {"spin.bg": SPIN, "measured.csv": MEASURED.replace("0.5,1210", "0.5,1210,3")}))
live("E958", Cli(_VALIDATE, {"spin.bg": SPIN, "measured.csv": MEASURED.replace("omega_meas", "omega_meas [N*m]")}))

# -- simulation (what a model cannot show)

live("E802", Api(_SPIN_API.replace("result = simulate(ss, graph.experiments[\"run\"])",
                                   "simulate(ss, graph.experiments[\"run\"], overrides={\"damping\": 2e-3})"),
                 {"spin.bg": SPIN}))
_PWM = """model Pwm
  input u = step(sin(2*pi*1000*t), 0)
  MSf heater : f = 2*u
  C   tank   : e = q/1
  R   loss   : f = e/1
  0   node
  heater -> node
  node -> tank
  node -> loss
end
"""
_RUNTIME = ("from bondc import semantic\n"
            "from bondc.causality import assign_causality\n"
            "from bondc.equations import derive\n"
            "from bondc.simulate import _result, compile_model   # _result: what simulate() makes of a raw run\n"
            "graph, _ = semantic.load(\"{file}\")\n"
            "ss = derive(assign_causality(graph))\n"
            "module = compile_model(ss)    # the module `bondc compile` writes\n")
live("E812", Api(_RUNTIME.format(file="pwm.bg")
                 + "raw = module[\"simulate_model\"](module[\"_MODEL\"], 1.0, max_events=20)\n"
                   "shown = _result(ss, None, module, raw, {}).diagnostics", {"pwm.bg": _PWM}))


live("E813", Api(_RUNTIME.format(file="spin.bg")
                 + "def progress(t):             # what Ctrl-C does during a run\n"
                   "    if t > 0.5:\n"
                   "        raise KeyboardInterrupt\n"
                   "raw = module[\"simulate_model\"](module[\"_MODEL\"], 1.0, progress=progress)\n"
                   "shown = _result(ss, None, module, raw, {}).diagnostics", {"spin.bg": SPIN}))

# -- command line and files

live("E001", Cli("bondc simulate --t-end 2"), Cli("bondc report spin.bg --compare omega=omega_meas", {"spin.bg": SPIN}))
live("E002", Cli("bondc check spin.gb", {"spin.bg": SPIN}))
# -- export: C code and FMUs

_RC_CSV = """model RC
  param R  = 1000 [Ohm]
  param C0 = 1e-3 [F]
  input u [V] = csv("drive.csv", "u")   "the drive, measured"
  Se supply : e = u
  R  r      : e = R*f
  C  c      : e = q/C0
  1  j
  supply -> j -> r
  j -> c
  output v [V] = c.e
end
"""
_SLIDE = """model Slide "a block pushed against Coulomb friction"
  param M   = 1 [kg]
  param F_c = 2 [N]
  param F0  = 1 [N]
  Se push     : e = F0
  I  block    : f = p/M
  R  friction : e = F_c*sign(f)
  1  j
  push -> j
  j -> block
  j -> friction
  output v [m/s] = block.f
end
"""
live("E840", Cli("bondc compile rc.bg --target c -o rc_c", {"rc.bg": _RC_CSV, "drive.csv": "t [s],u [V]\n0,0\n1,5\n"}))
live("E841", Cli("bondc fmu slide.bg --kind me", {"slide.bg": _SLIDE}))
live("E003", Cli("bondc simulate spin.bg -o results/spin.csv", {"spin.bg": SPIN}))
live("E003", Cli("bondc compile spin.bg -o spin.bg", {"spin.bg": SPIN}))
live("E007", Cli("bondc check spin.bg --set b=", {"spin.bg": SPIN}))

# ================================================================== the page

HEADER = """# Diagnostics

Every problem bondc reports has a stable code, a message, the place in the
source it is about (`file:line:column`, the line and a caret), notes at related
places, and a hint. One run reports every problem it can find, sorted by
position. `bondc check --json` prints the same diagnostics as JSON
(`Diagnostic.to_json()`). Control characters in what a diagnostic quotes (a
model line, a data file's column names) are shown as escapes (`\\x1b`, with the
caret under them), never sent to the terminal; of a file that is not a model
or a CSV table, nothing is quoted.

A code's letter is its severity: `E` an error, `W` a warning, `I` information
(one warning has an `E` code: E915; E926 is retired). Errors stop the command with
exit status 1, or 2 when the command line is at fault (a bad option, a file that
cannot be read, a bad `--set` value); warnings and information are printed and
the command goes on.

This page lists every code bondc can emit, by stage, each with what it means,
an example and how to fix it. The examples are the golden test cases of
`tests/golden/check/` (a first line `# check: --model M` gives the options the
case is checked with) and `tests/golden/stages/` (a first line `# bondc simulate`
gives the command), small inputs to the parser, commands run on small data
files, and calls of the Python API for the codes only the API raises; the
output is exactly what bondc prints for them, on stderr unless said otherwise.
A few codes cannot be triggered from a model or a command (internal guards);
their sections say so and describe the situation instead. This page is
generated by `tests/golden/check/make_diagnostics_doc.py` from the
registry of codes in `bondc/codes.py`; edit the explanations there.
"""


def _block(text: str) -> str:
    return f"```\n{text.rstrip()}\n```\n"


def _golden_examples(code: str) -> list[str]:
    out = []
    for path in sorted(GOLDEN.glob(f"{code}_*.bg")):
        out.append(f"`{path.name}`:\n\n" + _block(path.read_text(encoding="utf-8")) + "\n"
                   + _block(path.with_suffix(".txt").read_text(encoding="utf-8")))
    for path in sorted(STAGES_GOLDEN.glob(f"{code}_*.bg")):
        text = path.read_text(encoding="utf-8")
        command = shlex.split(text.splitlines()[0].lstrip("#"))
        shown = " ".join([*command[:2], path.name, *(shlex.quote(word) for word in command[2:])])
        part = f"`{path.name}`:\n\n" + _block(text) + "\n"
        for data in re.findall(r'csv\("([^"]+)"', text):
            part += f"`{data}`:\n\n" + _block((STAGES_GOLDEN / data).read_text(encoding="utf-8")) + "\n"
        part += _block(f"$ {shown}\n" + path.with_suffix(".txt").read_text(encoding="utf-8"))
        out.append(part)
    return out


def _parse_example(code: str) -> str:
    text = PARSE_EXAMPLES[code]
    try:
        parse_text(text, "m.bg")
    except ParseError as error:
        if error.diagnostics[0].code != code:
            raise SystemExit(f"the {code} example gives {error.diagnostics[0].code}")
        rendered = render_all(error.diagnostics, {"m.bg": Source("m.bg", text)})
        return "`m.bg`:\n\n" + _block(text) + "\n" + _block(rendered)
    raise SystemExit(f"the {code} example parses")


@contextlib.contextmanager
def _workspace(files: dict[str, str]):
    """A fresh temporary directory holding ``files``, as the current directory."""
    before = Path.cwd()
    with tempfile.TemporaryDirectory() as folder:
        for name, text in files.items():
            (Path(folder) / name).write_text(text, encoding="utf-8")
        os.chdir(folder)
        try:
            yield Path(folder)
        finally:
            os.chdir(before)


def _run(example) -> str:
    """What the example shows: the command's output, or the diagnostics the code raises (the
    temporary folder it ran in written ``/path/to/``)."""
    with _workspace(example.files) as folder:
        return _shown(example).replace(str(folder) + os.sep, "/path/to/")


def _shown(example) -> str:
    """The command's output, or the diagnostics the code raises, in the current folder."""
    if isinstance(example, Cli):
        from bondc.cli import main

        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            main(shlex.split(example.command)[1:])
        text = (err if example.stream == "stderr" else out).getvalue()
        if example.lines is not None:
            text = "\n".join(line for line in text.splitlines() if example.lines in line)
        return text.rstrip()
    namespace: dict = {}
    try:
        exec(compile(example.code, "<example>", "exec"), namespace)  # noqa: S102 - the page's own examples
    except BondcError as error:
        return render_all(error.diagnostics, error.sources)
    return render_all(namespace["shown"])


def _live_example(code: str, example, seen: dict) -> str:
    """The example's files (a file already shown on the page is referred to), code or command, and output.

    ``seen`` maps (file name, text) to the link of the section that showed it first.
    """
    output = _run(example)
    if (getattr(example, "expect", None) or f"[{code}]") not in output:
        raise SystemExit(f"the {code} example does not show {code}:\n{output}")
    part = ""
    for name, text in example.files.items():
        if (name, text) in seen:
            part += f"`{name}` is the file shown under {seen[name, text]}.\n\n"
        else:
            seen[name, text] = f"[{code}](#{slug(code + ' ' + EXPLANATIONS[code][0])})"
            part += f"`{name}`:\n\n" + _block(text) + "\n"
    note = f"{example.note}\n\n" if example.note else ""
    if isinstance(example, Cli):
        where = "It prints on stdout:\n\n" if example.stream == "stdout" else ""
        part += note + where + _block(f"$ {example.command}\n{output}")
    else:
        part += _block(example.code) + "\n" + note + _block(output)
    return part


def _examples(code: str, seen: dict) -> list[str]:
    out = [_parse_example(code)] if code in PARSE_EXAMPLES else []
    out += _golden_examples(code)
    out += [_live_example(code, example, seen) for example in LIVE.get(code, ())]
    return out


def emitted_codes() -> set[str]:
    """Every code written in bondc's source: registered (``d("E601", ...)``) or named (``codes.E601``)."""
    codes = set()
    for path in (ROOT / "bondc").rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        codes |= set(re.findall(r'"([EWI][0-9]{3})"', text)) | set(re.findall(r"\bcodes\.([EWI][0-9]{3})\b", text))
    return codes


def render_page() -> str:
    """The text of docs/diagnostics.md."""
    missing = emitted_codes() - set(EXPLANATIONS)
    if missing:
        raise SystemExit(f"codes without an explanation (add d(...) for them): {', '.join(sorted(missing))}")
    by_stage: dict[str, list[str]] = {title: [] for title, _ in STAGES}
    for code in EXPLANATIONS:
        by_stage[stage_of(code)].append(code)
    out = [HEADER, "## Contents\n", "| stage | codes | module |", "| --- | --- | --- |"]
    for title, modules in STAGES:
        links = " ".join(f"[{code}](#{slug(code + ' ' + EXPLANATIONS[code][0])})" for code in by_stage[title])
        out.append(f"| [{title}](#{slug(title)}) | {links} | {modules} |")
    out.append("")
    seen: dict = {}
    for title, _ in STAGES:
        out.append(f"# {title}\n")
        for code in by_stage[title]:
            heading, meaning, fix = EXPLANATIONS[code]
            out.append(f"## {code} {heading}\n\n{meaning}\n")
            out += _examples(code, seen)
            out.append(f"**Fix:** {fix}\n")
    return "\n".join(out).replace("\n\n\n", "\n\n")


def main() -> None:
    """Write docs/diagnostics.md."""
    PAGE.write_text(render_page(), encoding="utf-8")


if __name__ == "__main__":
    main()
