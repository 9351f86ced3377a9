"""Motor selection: requirements of analytic profiles, selection on a hand-made catalogue, errors."""

from __future__ import annotations

import doctest
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from bondc.analysis import motors
from bondc.analysis.motors import (
    CATALOGUE_COLUMNS,
    RPM,
    Motor,
    load_catalogue,
    judge,
    reflected_inertia,
    requirements,
    select,
)
from bondc.errors import DataError

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "models" / "data" / "motors.csv"
HEADER = ",".join(CATALOGUE_COLUMNS)


def write(tmp_path, text, name="motors.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def error_of(call, *args, **kwargs) -> DataError:
    with pytest.raises(DataError) as info:
        call(*args, **kwargs)
    return info.value


def codes(error: DataError) -> list[str]:
    return [d.code for d in error.diagnostics]


def sine_cycle(tau0=0.5, omega0=100.0, period=2.0, samples=4001):
    t = np.linspace(0.0, period, samples)
    return t, tau0 * np.sin(2 * np.pi * t / period), np.full(t.shape, omega0)


# ------------------------------------------------------------ requirements

def test_module_docstring_examples_run():
    result = doctest.testmod(motors)
    assert result.failed == 0 and result.attempted > 0


def test_sine_torque_at_constant_speed():
    """tau = tau0*sin(2*pi*t/T), omega = omega0 over one period T.

    RMS = tau0/sqrt(2); power tau0*omega0*sin(...) gives positive and
    regenerative energy tau0*omega0*T/pi each and net 0.
    """
    tau0, omega0, period = 0.5, 100.0, 2.0
    req = requirements(*sine_cycle(tau0, omega0, period))
    assert req.peak_torque == pytest.approx(tau0, rel=1e-6)
    assert req.peak_torque_positive == pytest.approx(tau0, rel=1e-6)
    assert req.peak_torque_negative == pytest.approx(-tau0, rel=1e-6)
    # The trapezoid rule on sin^2 over whole periods on a uniform grid is exact.
    assert req.rms_torque == pytest.approx(tau0 / math.sqrt(2), rel=1e-12)
    assert req.peak_speed == pytest.approx(omega0)
    assert req.peak_speed_rpm == pytest.approx(omega0 * 60 / (2 * math.pi))
    assert req.peak_power == pytest.approx(tau0 * omega0, rel=1e-6)
    assert req.peak_power_motoring == pytest.approx(tau0 * omega0, rel=1e-6)
    assert req.peak_power_regenerative == pytest.approx(tau0 * omega0, rel=1e-6)
    half = tau0 * omega0 * period / math.pi  # 31.83 J
    assert req.energy_positive == pytest.approx(half, rel=1e-6)
    assert req.energy_regenerative == pytest.approx(half, rel=1e-6)
    assert req.energy_net == pytest.approx(0.0, abs=1e-9)
    assert (req.t_start, req.t_end, req.duration) == (0.0, period, period)


def test_torque_and_speed_in_phase_only_motor():
    t = np.linspace(0.0, 1.0, 2001)
    req = requirements(t, 0.4 * np.sin(2 * np.pi * t), 50.0 * np.sin(2 * np.pi * t))
    assert req.energy_positive == pytest.approx(0.4 * 50.0 / 2, rel=1e-6)  # integral of sin^2 = T/2
    assert req.energy_regenerative == 0.0
    assert req.peak_power_regenerative == 0.0
    assert req.peak_speed == pytest.approx(50.0, rel=1e-6)


def test_energy_split_exactly_at_zero_crossing():
    """Two samples, power from -0.5 to +0.5 W: the trapezoid alone would say 0 and 0."""
    req = requirements([0.0, 1.0], [-0.5, 0.5], [1.0, 1.0])
    assert req.energy_positive == pytest.approx(0.125, abs=1e-15)
    assert req.energy_regenerative == pytest.approx(0.125, abs=1e-15)
    assert req.energy_net == pytest.approx(0.0, abs=1e-15)
    assert req.rms_torque == pytest.approx(0.5)  # trapezoid of 0.25 and 0.25


def test_cycle_window_interpolates_its_ends():
    """A 4 s record of two periods; a one-period window whose ends fall between samples."""
    tau0, omega0, period = 0.5, 100.0, 2.0
    t = np.linspace(0.0, 2 * period, 8001)  # 0.5 ms steps
    torque, speed = tau0 * np.sin(2 * np.pi * t / period), np.full(t.shape, omega0)
    req = requirements(t, torque, speed, cycle=(0.30025, 2.30025))
    assert (req.t_start, req.t_end) == (0.30025, 2.30025)
    assert req.rms_torque == pytest.approx(tau0 / math.sqrt(2), rel=1e-6)
    assert req.energy_net == pytest.approx(0.0, abs=1e-6)
    half = requirements(t, torque, speed, cycle=(0.0, period / 2))
    assert half.energy_regenerative == 0.0
    assert half.energy_positive == pytest.approx(tau0 * omega0 * period / math.pi, rel=1e-6)


def test_reflected_inertia_of_the_flagship():
    r = 5e-3 / (2 * math.pi)
    assert reflected_inertia(31.7, 5e-3) == pytest.approx(31.7 * r * r)
    assert reflected_inertia(31.7, 5e-3, shaft_inertia=4.06e-5) == pytest.approx(31.7 * r * r + 4.06e-5)


# ------------------------------------------------------------- catalogue

def test_shipped_catalogue_loads():
    catalogue = load_catalogue(SHIPPED)
    assert 8 <= len(catalogue) <= 12
    powers = [motor.rated_power for motor in catalogue]
    assert min(powers) == 50 and max(powers) == 1000
    by_name = {motor.name: motor for motor in catalogue}
    assert by_name["SV-400"] == Motor("SV-400", 1.27, 3.82, 3000, 400, 0.26e-4)
    for motor in catalogue:  # rated power = rated torque * rated speed, within catalogue rounding
        assert motor.rated_torque * motor.rated_speed_rad_s == pytest.approx(motor.rated_power, rel=0.01)
        assert motor.peak_torque >= motor.rated_torque
        assert 0.025e-4 <= motor.rotor_inertia <= 1.5e-4


HAND_MADE = f"""# hand-made: BIG, SMALL and LOW-POWER pass; every other motor fails exactly one rule
{HEADER}
BIG,2.0,6.0,3000,700,1.0e-4
WEAK-PEAK,0.8,0.9,3000,400,0.5e-4
SMALL,0.5,1.5,3000,200,0.1e-4
HOT,0.3,3.0,3000,400,0.5e-4
SLOW,1.0,3.0,1000,400,0.5e-4
LOW-POWER,1.0,3.0,3000,100,0.5e-4
"""


@pytest.fixture
def hand_made(tmp_path):
    return load_catalogue(write(tmp_path, HAND_MADE))


def burst_cycle():
    """1.0 N*m for 0.1 s then 0.2 N*m for 0.9 s, at 150 rad/s (1432.4 rpm).

    Peak torque 1.0 N*m, RMS sqrt(1.0*0.1 + 0.04*0.9) = sqrt(0.136) = 0.3688 N*m,
    peak power 150 W, RMS speed 150 rad/s.
    """
    return requirements([0.0, 0.1, 0.1 + 1e-9, 1.0], [1.0, 1.0, 0.2, 0.2], [150.0] * 4)


BURST_RPM = 150 / RPM          # 1432.39 rpm
BURST_RMS = math.sqrt(0.136)   # 0.36878 N*m


def test_burst_cycle_numbers():
    need = burst_cycle()
    assert need.peak_torque == 1.0
    assert need.rms_torque == pytest.approx(BURST_RMS, rel=1e-8)
    assert need.peak_power == pytest.approx(150.0)
    assert need.peak_speed_rpm == pytest.approx(1432.394, rel=1e-6)
    assert need.rms_speed_rpm == pytest.approx(1432.394, rel=1e-6)


def test_selection_on_hand_made_catalogue(hand_made):
    selection = select(burst_cycle(), hand_made)
    # LOW-POWER's rated 100 W is below the cycle's peak 150 W: information, not a rule
    assert [c.motor.name for c in selection.qualified] == ["LOW-POWER", "SMALL", "BIG"]
    assert selection.best.motor.name == "LOW-POWER"
    # rejected ones follow, also by rated power then rated torque: 400 W at 0.3, 0.8, 1.0 N*m
    assert [c.motor.name for c in selection] == ["LOW-POWER", "SMALL", "BIG", "HOT", "WEAK-PEAK", "SLOW"]
    failed = {c.motor.name: [check.rule for check in c.failed] for c in selection}
    assert failed == {"LOW-POWER": [], "SMALL": [], "BIG": [], "WEAK-PEAK": ["peak_torque"],
                      "HOT": ["rms_torque"], "SLOW": ["speed"]}
    reasons = {c.motor.name: c.reasons for c in selection if c.reasons}
    assert reasons == {
        "WEAK-PEAK": ("its peak torque at 1432 rpm is 0.9 N·m, below the cycle's 1 N·m",),
        "HOT": ("its continuous torque at the RMS speed 1432 rpm is 0.3 N·m, below the cycle's RMS torque "
                "0.369 N·m",),
        "SLOW": ("its top speed 1000 rpm is below the cycle's 1432 rpm",),
    }
    small = next(c for c in selection if c.motor.name == "SMALL")
    margins = small.margins
    assert margins["peak_torque"] == pytest.approx(1.5)
    assert margins["rms_torque"] == pytest.approx(0.5 / BURST_RMS)
    assert margins["speed"] == pytest.approx(3000 / BURST_RPM)
    assert margins["power"] == pytest.approx(200 / 150)
    assert margins["inertia_ratio"] is None             # no load inertia: the rule was not applied
    assert small.check("inertia_ratio").passed is None
    assert small.check("power").passed is None          # information
    # SLOW runs above its rated 1000 rpm only in the speed rule: the torque rules read its envelope
    # at its top speed (1000 rpm), so they pass; its speed margin is 1000/1432
    slow = next(c for c in selection if c.motor.name == "SLOW")
    assert slow.margins["speed"] == pytest.approx(1000 / BURST_RPM)
    assert slow.check("peak_torque").passed and slow.check("rms_torque").available == pytest.approx(
        1.0 * 1000 / BURST_RPM)


ENVELOPE = f"""{HEADER},max_speed,max_inertia_ratio
FW,0.5,1.5,1000,52,0.1e-4,3000,
FW2,0.6,2.0,1000,63,0.1e-4,3000,30
"""


def test_envelopes_above_the_rated_speed_and_the_catalogue_inertia_limit(tmp_path):
    """Above its rated 1000 rpm a motor's envelopes fall as constant power: at 1432.39 rpm FW offers
    1.5*1000/1432.39 = 1.0472 N*m peak (>= 1.0) and 0.5*1000/1432.39 = 0.3491 N*m continuous
    (< 0.3688 RMS); FW2 0.6*0.69813 = 0.4189 N*m continuous. A load of 2e-4 kg*m^2 is 20 rotors:
    FW's limit is the default 10, FW2's catalogue limit 30."""
    catalogue = load_catalogue(write(tmp_path, ENVELOPE))
    fw, fw2 = catalogue
    assert fw.max_speed == 3000 and fw.max_inertia_ratio is None and fw2.max_inertia_ratio == 30
    selection = select(burst_cycle(), catalogue, load_inertia=2e-4)
    by_name = {c.motor.name: c for c in selection}
    peak = by_name["FW"].check("peak_torque")
    assert peak.available == pytest.approx(1.5 * 1000 / BURST_RPM) and peak.passed
    assert peak.speed == pytest.approx(BURST_RPM)
    assert by_name["FW"].check("rms_torque").available == pytest.approx(0.5 * 1000 / BURST_RPM)
    assert [c.rule for c in by_name["FW"].failed] == ["rms_torque", "inertia_ratio"]
    assert by_name["FW"].check("inertia_ratio").available == 10
    assert by_name["FW2"].qualifies
    assert by_name["FW2"].check("inertia_ratio").required == pytest.approx(20.0)
    assert by_name["FW2"].check("inertia_ratio").headroom == pytest.approx(1 - 20 / 30)
    assert by_name["FW2"].check("speed").available == 3000      # the top speed, not the rated speed
    # the command line's limit is every motor's: 15 rejects FW2 (20 > 15) despite its catalogue 30
    strict = {c.motor.name: c for c in select(burst_cycle(), catalogue, load_inertia=2e-4, inertia_limit=15)}
    assert [c.rule for c in strict["FW2"].failed] == ["inertia_ratio"]
    assert strict["FW2"].reasons == ("its load/rotor inertia ratio is 20, above 15",)


def test_the_worst_instant_of_the_peak_envelope_is_not_always_the_peak_torque(tmp_path):
    """1.0 N*m at 500 rpm, then 0.8 N*m at 2000 rpm; a motor rated 1000 rpm with a 1.2 N*m peak
    offers 1.2 N*m at 500 rpm but 1.2*1000/2000 = 0.6 N*m at 2000 rpm: it fails there."""
    catalogue = load_catalogue(write(tmp_path, f"{HEADER},max_speed\nM,0.5,1.2,1000,52,1e-5,3000\n"))
    rpm = np.array([500.0, 500.0, 2000.0, 2000.0]) * RPM
    need = requirements([0.0, 0.5, 0.5 + 1e-9, 1.0], [1.0, 1.0, 0.8, 0.8], rpm)
    assert need.peak_torque == 1.0
    check = judge(catalogue[0], need).check("peak_torque")
    assert (check.required, check.available, check.passed) == (pytest.approx(0.8), pytest.approx(0.6), False)
    assert check.speed == pytest.approx(2000.0)


VERDICT = f"""{HEADER}
A,0.5,1.5,3000,100,1e-5
B,0.5,1.5,3000,200,4e-5
C,0.3,3.0,3000,300,1e-4
"""


def test_the_verdict_is_complete_sentences_with_each_rules_figures(tmp_path):
    """B: peak 1.0 of 1.5 N*m (1 - 1/1.5 = 33 %), RMS 0.36878 of 0.5 N*m at 1432 rpm (26 %),
    speed 1432 of 3000 rpm (52 %), load 2e-4 over B's 4e-5 = ratio 5 of 10 (50 %); A (1e-5) is
    smaller but its ratio is 20; C fails RMS (0.3 < 0.369)."""
    catalogue = load_catalogue(write(tmp_path, VERDICT))
    selection = select(burst_cycle(), catalogue, load_inertia=2e-4)
    assert selection.best.motor.name == "B"
    assert selection.verdict() == (
        "B is the smallest motor that qualifies: peak torque 1 of 1.5 N·m at 1432 rpm (33 % margin), "
        "RMS torque 0.369 of 0.5 N·m at 1432 rpm RMS speed (26 % margin), top speed 1432 of 3000 rpm "
        "(52 % margin), load/rotor inertia ratio 5 of 10 (50 % margin). "
        "A is smaller but its load/rotor inertia ratio is 20, above 10.")
    assert selection.to_json()["verdict"] == selection.verdict()
    # the terminal's text ends with the same paragraph (wrapped, never inside "52 %")
    text = selection.to_text()
    assert " ".join(text.split("\n\n")[-1].split()) == selection.verdict()
    # unknown load inertia: said, with why, instead of an inertia check
    unknown = select(burst_cycle(), catalogue, unknown_inertia="the model has no masses")
    assert unknown.best.motor.name == "A"
    assert unknown.verdict() == (
        "A is the smallest motor that qualifies: peak torque 1 of 1.5 N·m at 1432 rpm (33 % margin), "
        "RMS torque 0.369 of 0.5 N·m at 1432 rpm RMS speed (26 % margin), top speed 1432 of 3000 rpm "
        "(52 % margin); the load inertia is unknown (the model has no masses), so no inertia-ratio check "
        "was made.")
    # none qualifies: the largest and why
    heavy = requirements([0.0, 1.0], [4.0, 4.0], [150.0, 150.0])
    none = select(heavy, catalogue, load_inertia=2e-4)
    assert none.best is None
    # C: 3 N*m peak and 0.3 N*m continuous against 4 N*m; ratio 2e-4/1e-4 = 2 passes
    assert none.verdict() == ("No motor of the catalogue qualifies: the largest, C, fails because its "
                                     "peak torque at 1432 rpm is 3 N·m, below the cycle's 4 N·m, and its "
                                     "continuous torque at the RMS speed 1432 rpm is 0.3 N·m, below the "
                                     "cycle's RMS torque 4 N·m.")


def test_E928_inertia_limit_must_be_positive(hand_made):
    for bad in (-1, 0, float("nan"), "ten"):
        error = error_of(select, burst_cycle(), hand_made, inertia_limit=bad)
        assert codes(error) == ["E928"]


def test_E921_maximum_speed_below_rated_and_optional_cells(tmp_path):
    error = error_of(load_catalogue, write(tmp_path, f"{HEADER},max_speed\nA,1,2,3000,300,1e-5,2000\n"))
    assert codes(error) == ["E921"]
    assert error.diagnostics[0].message == "line 2: maximum speed 2000 rpm is below the rated speed 3000 rpm"
    error = error_of(load_catalogue, write(tmp_path, f"{HEADER},max_inertia_ratio\nA,1,2,3000,300,1e-5,-3\n"))
    assert error.diagnostics[0].message == "line 2, column 'max_inertia_ratio': -3 must be positive (1)"
    # an empty optional cell is "not given"; a missing required column is E920
    motor, = load_catalogue(write(tmp_path, f"{HEADER},max_speed\nA,1,2,3000,300,1e-5,\n"))
    assert motor.max_speed is None and motor.top_speed == 3000
    error = error_of(load_catalogue, write(tmp_path, "name,rated_torque,peak_torque,rated_speed,rotor_inertia\n"
                                                     "A,1,2,3000,1e-5\n"))
    assert codes(error) == ["E920"] and "missing 'rated_power'" in error.diagnostics[0].message


def test_ties_in_power_sort_by_rated_torque(tmp_path):
    catalogue = load_catalogue(write(tmp_path, f"{HEADER}\nB,0.7,2,3000,200,1e-5\nA,0.64,2,3000,200,1e-5\n"
                                               f"C,0.1,0.3,3000,100,1e-6\n"))
    selection = select(requirements([0, 1], [0.05, 0.05], [10, 10]), catalogue)
    assert [c.motor.name for c in selection] == ["C", "A", "B"]


def test_rotor_inertia_adds_torque_when_asked(tmp_path):
    """omega = alpha*t with no load torque: the motor must supply J_rotor*alpha itself."""
    alpha = 2000.0  # rad/s^2
    catalogue = load_catalogue(write(tmp_path, f"{HEADER}\nLIGHT,1,3,3000,400,1e-5\nHEAVY,1,3,3000,400,2e-3\n"))
    t = np.linspace(0.0, 0.05, 51)
    need = requirements(t, np.zeros_like(t), alpha * t)
    assert [c.qualifies for c in select(need, catalogue)] == [True, True]  # nothing to do without inertia
    selection = select(need, catalogue, include_rotor_inertia=True)
    heavy = next(c for c in selection if c.motor.name == "HEAVY")
    assert not heavy.qualifies  # 2e-3 * 2000 = 4 N*m > 3 N*m peak
    # 4 N*m at every instant (the speed named is one of them)
    assert re.fullmatch(r"its peak torque at \d+ rpm is 3 N·m, below the cycle's 4 N·m", heavy.reasons[0])
    light = next(c for c in selection if c.motor.name == "LIGHT")
    assert light.margins["peak_torque"] == pytest.approx(3 / (1e-5 * alpha))


def test_text_and_json(hand_made):
    selection = select(requirements(*sine_cycle()), hand_made, load_inertia=1e-4)
    text = selection.to_text()
    assert "RMS torque" in text and "motors that qualify" in text and "motors that do not qualify" in text
    data = json.loads(json.dumps(selection.to_json(), allow_nan=False))
    assert data["best"] == selection.best.motor.name
    assert len(data["candidates"]) == len(hand_made)
    assert data["requirements"]["rms_torque"] == pytest.approx(0.5 / math.sqrt(2))
    still = select(requirements([0, 1], [0.1, 0.1], [0, 0]), hand_made)  # zero speed: no speed/power margin
    assert still.best.margins["speed"] is None and still.best.margins["power"] is None
    json.dumps(still.to_json(), allow_nan=False)
    assert isinstance(selection, list)


# ------------------------------------------------------------------ errors

def test_E920_header_must_be_exact(tmp_path):
    error = error_of(load_catalogue, write(tmp_path, "name,rated_torq,peak_torque,rated_speed,rated_power,"
                                                     "rotor_inertia\nX,1,2,3000,300,1e-5\n"))
    assert codes(error) == ["E920"]
    diagnostic = error.diagnostics[0]
    assert "missing 'rated_torque'" in diagnostic.message
    assert "'rated_torq' (did you mean 'rated_torque'?)" in diagnostic.message
    assert diagnostic.hint.startswith("the header must start with " + HEADER)
    reordered = "name,peak_torque,rated_torque,rated_speed,rated_power,rotor_inertia\n"
    error = error_of(load_catalogue, write(tmp_path, reordered + "X,2,1,3000,300,1e-5\n"))
    assert "different order" in error.diagnostics[0].message


def test_E921_values_out_of_range(tmp_path):
    text = f"{HEADER}\nA,-1,2,3000,300,1e-5\nB,2,1,3000,300,1e-5\n,1,2,3000,300,1e-5\nC,1,2,3000,300,0\n"
    error = error_of(load_catalogue, write(tmp_path, text))
    assert codes(error) == ["E921"] * 4
    messages = [d.message for d in error.diagnostics]
    assert messages[0] == "line 2, column 'rated_torque': -1 must be positive (N*m)"
    assert messages[1] == "line 3: peak torque 1 N*m is below the rated torque 2 N*m"
    assert messages[2] == "line 4: the motor has no name"
    assert messages[3] == "line 5, column 'rotor_inertia': 0 must be positive (kg*m^2)"


def test_E922_duplicate_name(tmp_path):
    error = error_of(load_catalogue, write(tmp_path, f"{HEADER}\nA,1,2,3000,300,1e-5\nA,1,2,3000,300,1e-5\n"))
    assert codes(error) == ["E922"]
    assert error.diagnostics[0].message == "line 3: motor 'A' is already listed on line 2"


def test_E903_E904_E901_catalogue_cells_and_empty(tmp_path):
    error = error_of(load_catalogue, write(tmp_path, f"{HEADER}\nA,1,two,3000,300,1e-5\nB,1,2,3000\n"))
    assert codes(error) == ["E903", "E904"]
    assert error.diagnostics[0].message == "line 2, column 'peak_torque': 'two' is not a number"
    assert codes(error_of(load_catalogue, write(tmp_path, ""))) == ["E901"]
    assert codes(error_of(load_catalogue, write(tmp_path, HEADER + "\n"))) == ["E901"]
    assert codes(error_of(load_catalogue, tmp_path / "missing.csv")) == ["E905"]


def test_E923_profile_arrays():
    error = error_of(requirements, [0, 1, 2], [1, 2], [1, 2, 3])
    assert codes(error) == ["E923"] and error.diagnostics[0].message == "torque has 2 samples; time has 3"
    error = error_of(requirements, [0, 1, 2], [1, float("nan"), 2], [1, 2, 3])
    assert error.diagnostics[0].message == "torque has 1 non-finite sample (first at index 1: nan)"
    assert codes(error_of(requirements, [0.0], [1.0], [1.0])) == ["E923"]
    assert codes(error_of(requirements, [[0, 1]], [[1, 1]], [[1, 1]])) == ["E923"]
    assert codes(error_of(requirements, ["a", "b"], [1, 1], [1, 1])) == ["E923"]


def test_E924_time_must_increase():
    error = error_of(requirements, [0, 1, 1, 2], [1, 1, 1, 1], [1, 1, 1, 1])
    assert codes(error) == ["E924"]
    assert error.diagnostics[0].message == "time is not strictly increasing: t[1] = 1 s, t[2] = 1 s"


def test_E925_cycle_window():
    t, torque, speed = sine_cycle()
    assert codes(error_of(requirements, t, torque, speed, cycle=(1.0, 1.0))) == ["E925"]
    error = error_of(requirements, t, torque, speed, cycle=(0.5, 3.0))
    assert error.diagnostics[0].message == "the cycle window 0.5..3 s is outside the record 0..2 s"
    assert codes(error_of(requirements, t, torque, speed, cycle=(1.0,))) == ["E925"]


def test_E914_negative_load_inertia(hand_made):
    error = error_of(select, requirements(*sine_cycle()), hand_made, load_inertia=-1e-5)
    assert codes(error) == ["E914"]


def test_the_inertia_ratio_is_a_rule_on_the_shipped_catalogue():
    """A load 12 times the smallest qualifying motor's rotor: that motor is rejected on its ratio, and
    the choice is the smallest whose ratio is within 10."""
    catalogue = load_catalogue(SHIPPED)
    t = np.linspace(0, 1, 201)
    need = requirements(t, 0.2 * np.sin(2 * np.pi * t), 100 * np.sin(2 * np.pi * t))
    smallest = select(need, catalogue).best
    load = 12 * smallest.motor.rotor_inertia
    checked = select(need, catalogue, load_inertia=load)
    chosen = checked.best
    assert chosen.motor.name != smallest.motor.name
    assert load / chosen.motor.rotor_inertia <= 10
    rejected = next(c for c in checked if c.motor.name == smallest.motor.name)
    assert not rejected.qualifies and [c.rule for c in rejected.failed] == ["inertia_ratio"]
    assert f"{smallest.motor.name} is smaller but its load/rotor inertia ratio is 12, above 10." in checked.verdict()
    assert checked.to_json()["best"] == chosen.motor.name
