"""Motor selection: requirements of analytic profiles, selection on a hand-made catalogue, errors."""

from __future__ import annotations

import doctest
import json
import math
from pathlib import Path

import numpy as np
import pytest

from bondc.analysis import motors
from bondc.analysis.motors import (
    CATALOGUE_COLUMNS,
    RPM,
    Motor,
    load_catalogue,
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


HAND_MADE = f"""# hand-made: BIG and SMALL pass; every other motor fails exactly one check
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
    peak power 150 W.
    """
    return requirements([0.0, 0.1, 0.1 + 1e-9, 1.0], [1.0, 1.0, 0.2, 0.2], [150.0] * 4)


def test_burst_cycle_numbers():
    need = burst_cycle()
    assert need.peak_torque == 1.0
    assert need.rms_torque == pytest.approx(math.sqrt(0.136), rel=1e-8)
    assert need.peak_power == pytest.approx(150.0)
    assert need.peak_speed_rpm == pytest.approx(1432.394, rel=1e-6)


def test_selection_on_hand_made_catalogue(hand_made):
    selection = select(burst_cycle(), hand_made)
    assert [c.motor.name for c in selection.qualified] == ["SMALL", "BIG"]  # 200 W before 700 W
    assert selection.best.motor.name == "SMALL"
    # Rejected ones follow, also by rated power then rated torque: 100 W, then 400 W at 0.3, 0.8, 1.0 N*m.
    assert [c.motor.name for c in selection] == ["SMALL", "BIG", "LOW-POWER", "HOT", "WEAK-PEAK", "SLOW"]
    reasons = {c.motor.name: c.reasons for c in selection}
    assert reasons == {
        "SMALL": (),
        "BIG": (),
        "WEAK-PEAK": ("peak torque 0.9 N*m < required peak torque 1 N*m",),
        "HOT": ("rated torque 0.3 N*m < required RMS torque 0.3688 N*m",),
        "SLOW": ("rated speed 1000 rpm < required peak speed 1432 rpm",),
        "LOW-POWER": ("rated power 100 W < required peak power 150 W",),
    }
    assert selection.best.margins == pytest.approx({
        "peak_torque": 1.5, "rms_torque": 0.5 / math.sqrt(0.136),
        "speed": 3000 / (150 / RPM), "power": 200 / 150})


def test_ties_in_power_sort_by_rated_torque(tmp_path):
    catalogue = load_catalogue(write(tmp_path, f"{HEADER}\nB,0.7,2,3000,200,1e-5\nA,0.64,2,3000,200,1e-5\n"
                                               f"C,0.1,0.3,3000,100,1e-6\n"))
    selection = select(requirements([0, 1], [0.05, 0.05], [10, 10]), catalogue)
    assert [c.motor.name for c in selection] == ["C", "A", "B"]


def test_inertia_ratio_is_a_warning_not_a_disqualifier(hand_made):
    selection = select(burst_cycle(), hand_made, load_inertia=2.0e-4)
    small = next(c for c in selection if c.motor.name == "SMALL")
    assert small.qualifies
    assert small.inertia_ratio == pytest.approx(20.0)
    assert [w.code for w in small.warnings] == ["E926"] and small.warnings[0].severity == "warning"
    big = next(c for c in selection if c.motor.name == "BIG")
    assert big.inertia_ratio == pytest.approx(2.0) and big.warnings == ()
    assert "load/rotor inertia ratio 20 is above 10" in selection.to_text()


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
    assert heavy.reasons[0] == "peak torque 3 N*m < required peak torque 4 N*m"
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
    assert diagnostic.hint == "the header must be exactly " + HEADER
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


def test_the_recommended_motor_passes_the_inertia_ratio_check_and_says_why():
    from pathlib import Path

    import numpy as np

    from bondc.analysis.motors import MAX_INERTIA_RATIO, load_catalogue, requirements, select

    catalogue = load_catalogue(Path(__file__).parent.parent / "models" / "data" / "motors.csv")
    t = np.linspace(0, 1, 201)
    need = requirements(t, 0.2 * np.sin(2 * np.pi * t), 100 * np.sin(2 * np.pi * t))
    plain = select(need, catalogue)
    smallest = plain.best
    assert plain.recommended is smallest and "the smallest that qualifies" in plain.recommendation()
    # a load 12 times the smallest motor's rotor inertia: it fails the ratio check, a bigger one does not
    load = 12 * smallest.motor.rotor_inertia
    checked = select(need, catalogue, load_inertia=load)
    chosen = checked.recommended
    assert checked.best.motor.name == smallest.motor.name and chosen.motor.name != smallest.motor.name
    assert load / chosen.motor.rotor_inertia <= MAX_INERTIA_RATIO
    assert all(load / c.motor.rotor_inertia > MAX_INERTIA_RATIO for c in checked.qualified
               if c.motor.rated_power < chosen.motor.rated_power)
    text = checked.to_text()
    assert f"smallest qualifying motor: {smallest.motor.name}" in text
    assert f"recommended: {chosen.motor.name}" in text and "inertia ratio of 12" in text
    assert checked.to_json()["recommended"] == chosen.motor.name
