"""Unit resolution: conversions to SI checked against hand-computed values."""

from fractions import Fraction
import math

import pytest

from bondc.ast import Unit, UnitFactor
from bondc.source import Source
from bondc.units import (
    DIMENSIONLESS,
    SIUnit,
    compatible,
    lookup,
    resolve,
    suggest,
)


def unit(text: str, *factors: tuple[str, object]) -> Unit:
    """An ast.Unit as the parser would flatten it: unit("N*m/rad", ("N", 1), ("m", 1), ("rad", -1))."""
    return Unit(factors=tuple(UnitFactor(name, Fraction(exp)) for name, exp in factors), text=text)


def ok(u: Unit) -> SIUnit:
    si, diagnostics = resolve(u)
    assert diagnostics == []
    assert si is not None
    return si


# Dimension vectors over (m, kg, s, A, K, mol, cd, rad), written out by hand.
def dims(m=0, kg=0, s=0, A=0, K=0, mol=0, cd=0, rad=0):
    return tuple(Fraction(x) for x in (m, kg, s, A, K, mol, cd, rad))


# ------------------------------------------------------- conversions from §3

def test_millimetre_value_to_si():
    si = ok(unit("mm", ("mm", 1)))
    assert si.to_si(5.0) == 0.005
    assert si.dims == dims(m=1)


def test_rpm_value_to_si():
    si = ok(unit("rpm", ("rpm", 1)))
    assert si.to_si(1000) == pytest.approx(104.71975511965977, rel=1e-15)
    assert si.dims == dims(s=-1, rad=1)
    assert si.dimension_text() == "rad/s"


def test_megapascal_value_to_si():
    si = ok(unit("MPa", ("MPa", 1)))
    assert si.to_si(0.224) == pytest.approx(224000.0, rel=1e-15)
    assert si.dims == dims(kg=1, m=-1, s=-2)


def test_kilopascal_and_bar():
    assert ok(unit("kPa", ("kPa", 1))).to_si(101.325) == pytest.approx(101325.0, rel=1e-15)
    bar = ok(unit("bar", ("bar", 1)))
    assert bar.factor == 1e5
    assert bar.to_si(6) == 600000.0
    assert ok(unit("mbar", ("mbar", 1))).factor == 100.0
    assert compatible(bar, lookup("Pa"))


def test_degree_and_revolution():
    deg = ok(unit("deg", ("deg", 1)))
    assert deg.factor == pytest.approx(math.pi / 180, rel=1e-15)
    assert deg.to_si(180) == pytest.approx(math.pi, rel=1e-15)
    assert deg.dims == dims(rad=1)
    assert lookup("rev").to_si(1) == pytest.approx(2 * math.pi, rel=1e-15)


def test_litre_is_a_thousandth_of_a_cubic_metre():
    for name in ("L", "l"):
        litre = ok(unit(name, (name, 1)))
        assert litre.factor == 1e-3
        assert litre.dims == dims(m=3)
    assert lookup("mL").factor == pytest.approx(1e-6, rel=1e-15)
    assert lookup("ml").factor == pytest.approx(1e-6, rel=1e-15)


def test_time_units():
    assert lookup("min").to_si(2) == 120.0
    assert lookup("h").to_si(1.5) == 5400.0
    assert lookup("ms").to_si(20) == 0.02
    assert lookup("us").factor == pytest.approx(1e-6, rel=1e-15)
    assert lookup("ns").factor == pytest.approx(1e-9, rel=1e-15)


def test_from_si_inverts_to_si():
    for name in ("mm", "rpm", "MPa", "deg", "L", "h", "uF"):
        si = lookup(name)
        assert si.from_si(si.to_si(3.7)) == pytest.approx(3.7, rel=1e-14)
    assert lookup("mm").from_si(0.005) == 5.0


# ------------------------------------------------------------ compound units

def test_newton_metre_per_radian_is_coherent_with_torque_dims():
    si = ok(unit("N*m/rad", ("N", 1), ("m", 1), ("rad", -1)))
    assert si.is_coherent
    assert si.dims == dims(kg=1, m=2, s=-2, rad=-1)
    assert compatible(si, ok(unit("N*m", ("N", 1), ("m", 1))))
    assert compatible(si, lookup("Nm"))
    assert si.text == "N*m/rad"


def test_kilogram_square_metre():
    si = ok(unit("kg*m^2", ("kg", 1), ("m", 2)))
    assert si.factor == 1.0
    assert si.dims == dims(kg=1, m=2)
    assert si.dimension_text() == "kg*m^2"


def test_metre_per_second_squared():
    si = ok(unit("m/s^2", ("m", 1), ("s", -2)))
    assert si.is_coherent
    assert si.dims == dims(m=1, s=-2)
    assert si.dimension_text() == "m/s^2"


def test_newton_dimension_text():
    assert lookup("N").dimension_text() == "kg*m/s^2"
    assert lookup("Pa").dimension_text() == "kg/(m*s^2)"
    assert DIMENSIONLESS.dimension_text() == "1"


def test_per_second_and_radian_per_second_are_compatible_but_distinct():
    per_second = ok(unit("1/s", ("1", 1), ("s", -1)))
    rad_per_second = ok(unit("rad/s", ("rad", 1), ("s", -1)))
    assert compatible(per_second, rad_per_second)
    assert per_second.dims != rad_per_second.dims
    assert per_second.dimension_text() == "1/s"
    assert rad_per_second.dimension_text() == "rad/s"
    assert compatible(per_second, lookup("Hz"))
    assert not compatible(per_second, lookup("s"))


def test_dimensionless_one():
    one = ok(unit("1", ("1", 1)))
    assert one.factor == 1.0
    assert one.dims == dims()
    assert one.is_dimensionless
    assert lookup("rad").is_dimensionless
    assert not lookup("m").is_dimensionless


def test_coherence():
    assert ok(unit("m^2", ("m", 2))).is_coherent
    assert ok(unit("m/s", ("m", 1), ("s", -1))).is_coherent
    assert not ok(unit("ms", ("ms", 1))).is_coherent
    assert not lookup("rpm").is_coherent
    assert not lookup("g").is_coherent
    assert lookup("kg").is_coherent


def test_prefixed_powers_are_exact():
    # 1 cm^3 = 1e-6 m^3 and 1 km^2 = 1e6 m^2 exactly, with no float drift.
    assert ok(unit("cm^3", ("cm", 3))).factor == 1e-6
    assert ok(unit("km^2", ("km", 2))).factor == 1e6
    assert ok(unit("mm^2", ("mm", 2))).to_si(50) == 5e-5


def test_fractional_exponent():
    si = ok(unit("m^(1/2)", ("m", Fraction(1, 2))))
    assert si.dims == dims(m=Fraction(1, 2))
    assert si.dimension_text() == "m^(1/2)"
    assert ok(unit("mm^(1/2)", ("mm", Fraction(1, 2)))).factor == pytest.approx(math.sqrt(1e-3))


def test_electrical_units():
    assert lookup("kOhm").factor == 1e3
    assert lookup("MOhm").factor == 1e6
    assert lookup("mA").factor == 1e-3
    assert lookup("uF").factor == pytest.approx(1e-6, rel=1e-15)
    assert lookup("nF").factor == pytest.approx(1e-9, rel=1e-15)
    assert lookup("mH").dims == dims(kg=1, m=2, s=-2, A=-2)
    # V = W/A; Ohm = V/A; F = C/V; H = Wb/A; T = Wb/m^2; S = 1/Ohm.
    V, W, A = lookup("V"), lookup("W"), lookup("A")
    assert (W / A).dims == V.dims
    assert (V / A).dims == lookup("Ohm").dims
    assert (lookup("C") / V).dims == lookup("F").dims
    assert (lookup("Wb") / A).dims == lookup("H").dims
    assert (lookup("Wb") / lookup("m") ** 2).dims == lookup("T").dims
    assert (DIMENSIONLESS / lookup("Ohm")).dims == lookup("S").dims
    assert (lookup("J") / lookup("s")).dims == W.dims


def test_ambiguous_looking_names():
    assert lookup("min").dims == dims(s=1) and lookup("min").factor == 60.0
    assert lookup("m").dims == dims(m=1)
    assert lookup("h").factor == 3600.0
    assert lookup("T").dims == dims(kg=1, s=-2, A=-1)
    assert lookup("C").dims == dims(s=1, A=1)
    assert lookup("cd").dims == dims(cd=1) and lookup("cd").factor == 1.0
    assert lookup("mol").dims == dims(mol=1) and lookup("mol").factor == 1.0
    assert lookup("Pa").factor == 1.0
    assert lookup("nm").factor == pytest.approx(1e-9) and lookup("nm").dims == dims(m=1)
    assert lookup("mS").dims == lookup("S").dims
    assert lookup("kN").factor == 1000.0
    assert lookup("GPa").factor == 1e9
    assert lookup("kW").factor == 1000.0


def test_prefixes_not_allowed_on_fixed_units():
    for name in ("mrad", "krpm", "kmin", "kh", "kbar", "kNm", "kdeg", "Mrev"):
        assert lookup(name) is None, name


# -------------------------------------------------------------- diagnostics

def test_unknown_unit_reports_e201_at_its_span_with_suggestion():
    src = Source("m.bg", "param M = 31.7 [kgg]\n")
    span = src.span(16, 19)
    u = Unit(factors=(UnitFactor("kgg", Fraction(1), span),), text="kgg")
    si, diagnostics = resolve(u)
    assert si is None
    assert len(diagnostics) == 1
    d = diagnostics[0]
    assert (d.severity, d.code, d.message) == ("error", "E201", "unknown unit 'kgg'")
    assert d.span == span
    assert d.hint == "did you mean 'kg'?"


@pytest.mark.parametrize("name", ["degC", "celsius", "degF"])
def test_a_temperature_scale_with_an_offset_is_refused_with_kelvin_not_deg_times_coulomb(name):
    # 'deg*C' would read as degrees times coulombs: 20 [deg*C] is 0.349, silently
    _, (diagnostic,) = resolve(unit(name, (name, 1)))
    assert diagnostic.code == "E201" and "deg*C" not in diagnostic.hint
    assert "temperature scale with an offset" in diagnostic.hint and "293.15 [K]" in diagnostic.hint


def test_all_unknown_units_reported_together():
    u = unit("kgg*Mpa/sec", ("kgg", 1), ("m", 1), ("Mpa", 1), ("sec", -1))
    si, diagnostics = resolve(u)
    assert si is None
    assert [d.message for d in diagnostics] == [
        "unknown unit 'kgg'", "unknown unit 'Mpa'", "unknown unit 'sec'"]
    assert all(d.code == "E201" for d in diagnostics)
    assert "'kg'" in diagnostics[0].hint
    assert diagnostics[1].hint.startswith("did you mean 'MPa'")
    assert diagnostics[2].hint == "did you mean 's'?"


@pytest.mark.parametrize("typed, expected", [
    ("kgg", "kg"),
    ("Mpa", "MPa"),
    ("KG", "kg"),
    ("kohm", "kOhm"),
    ("hz", "Hz"),
    ("sec", "s"),
    ("rmp", "rpm"),
    ("kWh", "kW*h"),
    ("Nmm", "N*mm"),
    ("kNm", "kN*m"),
    ("mrad", "rad"),
])
def test_suggest(typed, expected):
    assert suggest(typed) == expected


def test_no_suggestion_still_explains():
    assert suggest("xyzzy") is None
    _, diagnostics = resolve(unit("xyzzy", ("xyzzy", 1)))
    assert diagnostics[0].hint and "rpm" in diagnostics[0].hint


def test_prefix_on_fixed_unit_hint_says_so():
    _, diagnostics = resolve(unit("krpm", ("krpm", 1)))
    assert "cannot be used with 'rpm'" in diagnostics[0].hint


def test_valid_names_need_no_suggestion():
    assert ok(unit("Nm", ("Nm", 1))).dims == dims(kg=1, m=2, s=-2)
    assert lookup("unknown") is None
    assert lookup("kg").text == "kg"


@pytest.mark.parametrize("text", ["N*m*rad/s", "kW", "J/kg/K", "kg*m^2", "m/s^2", "N*s/m", "Pa", "m^-1",
                                  "a/b*c", "rpm", "N * m / rad", "bar^+2"])
def test_the_statistics_unit_reader_reads_simple_units_as_the_parser_does(text):
    from bondc.analysis.stats import _simple_unit
    from bondc.parse import parse_set_value

    expected = parse_set_value(f"_u = 1 [{text}]").unit
    got = _simple_unit(text)
    assert [(f.name, f.exponent) for f in got.factors] == [(f.name, f.exponent) for f in expected.factors]


@pytest.mark.parametrize("text", ["1/s", "(N*m)/s", "m^(1/2)", "N*m/", "*N", "m^0.5"])
def test_anything_else_goes_to_the_parser(text):
    from bondc.analysis.stats import _simple_unit

    assert _simple_unit(text) is None
