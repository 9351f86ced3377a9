"""Writes docs/diagnostics.md: the explanations below, with the golden cases and their output.

Run ``python tests/golden/check/make_diagnostics_doc.py`` after ``pytest --update-golden``
changed a golden ``.txt``, or to edit an explanation (edit it here, not in the page).
``tests/test_golden_check.py`` fails when the page and the golden files disagree.
"""

from pathlib import Path

from bondc.errors import ParseError, render_all
from bondc.parse import parse_text
from bondc.source import Source

GOLDEN = Path(__file__).resolve().parent
ROOT = GOLDEN.parent.parent.parent

EXPLANATIONS: dict[str, tuple[str, str, str]] = {}  # code -> (title, what it means, how to fix it)


def d(code: str, title: str, meaning: str, fix: str) -> None:
    EXPLANATIONS[code] = (title, meaning, fix)


d("E100", "unexpected token", "The parser met a word or symbol the grammar does not allow at that place. The message says what it expected.", "Compare the statement with the forms in `docs/language.md`. A statement ends at the end of its line; to continue it, end the line with `,` or stay inside `( )` or `[ ]`.")
d("E101", "unexpected character", "A character that cannot start any token (for example `$`, `;`, `@`).", "Remove it. Names are letters, digits and `_`; comments start with `#`.")
d("E102", "unterminated string", "A `\"` opens a string that does not close on the same line.", "Close the string with `\"` on the same line; write `\\\"` for a quote inside it.")
d("E103", "unexpected end of file", "The file ends inside a statement or a block.", "Close every `model` and `experiment` block with `end`.")
d("E104", "keyword used as a name", "A keyword (`model end param input output state fn experiment import if then else and or not`) stands where a name is expected.", "Choose another name, e.g. `end_` for `end`.")
d("E199", "internal error while reading the model", "The parser accepted the text but bondc failed to build its syntax tree. This is a bug in bondc, not in the model.", "Report it with the model file.")

d("E201", "unknown unit", "A name in `[ ]` is not a unit bondc knows. Units are the SI base and derived units (m, g, s, K, A, mol, N, Pa, J, W, V, Ohm, F, H, C, Hz) with the prefixes n u m c k M G, and `rad deg rev rpm min h bar L l Nm`, and `1`. Every unknown name in a unit is reported, each at its position.", "Use the suggested spelling, or write the unit as a product: `N*m`, `kg*m^2`, `m/s^2`.")
d("E202", "non-coherent unit on a computed value", "A value that bondc computes in SI was given a unit that is not coherent SI (a unit with a scale factor: `ms`, `mm`, `rpm`, `bar`, `kN`). This applies to a parameter (or override, or setting) written as an expression of other parameters, to inputs, and to states: their value is in SI, so the unit can only declare it. A number written with a unit (`5 [mm]`) is different: it is converted.", "Write the coherent SI unit the hint suggests (`[s]` for `[ms]`, `[rad/s]` for `[rpm]`, `[Pa]` for `[bar]`), and convert constants inside the expression if needed (`2*t1 [s]`). Outputs may use any unit: they are shown in it.")
d("E203", "not a plain unit", "A unit contains a number other than `1` (`[2*m]`, `[1000*N]`): a unit is a product of unit names.", "Put the scale in the value: `2*x [m]`, or use a prefixed unit (`[kN]`).")
d("E204", "unit of the wrong kind", "An override (`param` in an experiment, or `--set`) has a unit that does not measure the same quantity as the parameter's declared unit, or a time setting (`t_end`, `max_step`, `cycle`, `first_step`, `dt`) has a unit that is not a time.", "Use a unit of the same kind (the hint gives the SI dimensions), or give a bare number: an override written without a unit is read in the parameter's declared unit.")

d("E301", "undefined name", "A name that is not defined where it is used: a misspelt parameter, element, function or output, or an experiment/`--set` override of something that is not a parameter (or input). The hint offers the closest name in scope.", "Fix the spelling, or declare the name. Inside element laws `e` and `f` are the element's own effort and flow; elsewhere write `X.e`, `X.f`.")
d("E302", "duplicate name", "A name is defined twice. Elements, junctions, parameters, inputs, outputs, states, functions and bond labels share one namespace per model (file-level functions included); experiments, settings inside one experiment, overrides inside one experiment and a function's arguments each must also be unique. The error points at the second definition, with a note at the first.", "Rename one of the two.")
d("E303", "unknown element kind", "The first word of an element statement is not one of `Se Sf MSe MSf R C I TF GY MTF MGY`.", "Use the suggested kind (kinds are case-sensitive).")
d("E304", "recursive function", "A function calls itself, directly or through other functions. The message names the cycle.", "Functions are pure formulas evaluated by substitution; write the repetition out, or use an `if` expression.")
d("E305", "dependency cycle or forward reference", "A parameter uses a parameter defined below it (parameters are evaluated top to bottom), or a parameter uses itself, or an override (experiment `param`, `--set`) makes parameters depend on each other in a cycle, or inputs (or outputs) are defined in terms of each other in a cycle.", "Move the parameter that is used above the one that uses it; break the cycle.")
d("E306", "wrong arguments", "A call has the wrong number or shape of arguments: `abs sign sqrt exp log sin cos tan tanh atan` take 1, `atan2` 2, `min`/`max` at least 2, `step(t, t0)` 2, `csv(\"file\", \"column\")` 2, `table(t, [t0, ...], [v0, ...])` a value and two lists of the same length with at least two points and breakpoints that do not decrease; an `fn` takes as many as it declares.", "Write the call as shown in the hint.")
d("E307", "missing import", "`import \"path\"` names a file that does not exist (or cannot be read). The path is relative to the importing file.", "Fix the path; the hint shows where bondc looked.")
d("E308", "cyclic import", "Files import each other, directly or through other files. The message names the chain.", "Move what both files need into a third file that both import.")
d("E309", "model selection", "The file has no model, or several and no `--model` was given, or `--model` names a model the file (and its imports) does not have.", "Pass `--model NAME` with one of the listed models.")
d("E310", "CSV file or column", "`csv(\"file\", \"column\")` names a file that cannot be read (paths are relative to the model file), a file without a header line, or a column that the header does not have. The first column (or the column `t` or `time`) is time.", "Fix the path or the column name; the hint lists the columns.")
d("E311", "cannot evaluate", "A constant (parameter, override, setting, initial value, table breakpoint) has no value: a logarithm or square root of a negative number, a division by zero, a negative number to a fractional power, or a result too large for a float. The caret is under the sub-expression that failed; inside a function, a note points into its body.", "Fix the expression or the parameter values it uses. If the value comes from an experiment's overrides, a note names the experiment.")
d("E312", "unknown variable of a graph node", "A dotted reference names a variable the node does not have: `X.q` on an element without a state `q`, `X.p1.e` on a one-port, `X.e` on a two-port (name the port), `J.f` on a 0-junction or `J.e` on a 1-junction (a 0-junction has one common effort, a 1-junction one common flow), `bN.e` with no bond N, or a dotted reference on a parameter or input.", "Use one of the variables the hint lists; for the flow at a 0-junction use one bond's flow (`b3.f` or a label).")
d("E313", "string or list where a number is expected (or the reverse)", "A string appears in an arithmetic expression, a list outside `table(...)`, a `solver` that is not a string, `csv` arguments that are not strings, or `outputs` entries that are not names.", "Write numbers in expressions; quote the solver name (`solver = \"Radau\"`); write `outputs = [name1, name2]`.")
d("E314", "unknown experiment setting", "A setting inside `experiment ... end` is not one of `t_end solver rtol atol max_step cycle outputs first_step dt`.", "Use the suggested setting.")
d("E315", "reserved name", "`t` (time) and `pi` cannot be defined as names, and a function cannot take the name of a built-in.", "Choose another name.")
d("E316", "name not allowed here", "A name that exists but cannot be used where it is written: a parameter (a constant) using an input, `t` or a graph variable; an input (a signal of `t` and parameters) using a graph variable, output or state; a function body using anything but its arguments; `csv(...)` outside an input or law; an element or function used as a value. The hint says what the place may use.", "Pass the value as a function argument, move the expression into an output or element law, or use the element's variables (`X.e`, `X.f`).")
d("E317", "invalid setting value", "A setting has a value outside its range: an unknown solver (solvers are the `scipy.integrate.solve_ivp` methods `RK45 RK23 DOP853 Radau BDF LSODA`), or a time or tolerance that is not positive.", "Use one of the listed solvers, or a positive value.")
d("E318", "unknown experiment", "`--experiment NAME` names an experiment the model does not have.", "Use one of the listed experiments.")

d("E401", "one-port element without exactly one bond", "An `Se Sf MSe MSf R C I` element has no bond, or two or more. Notes list each bond.", "Connect it with exactly one bond; where several bonds meet, put a 0- or 1-junction and connect the element to it.")
d("E402", "two-port ports", "A `TF`/`GY`/`MTF`/`MGY` does not have exactly two bonds; or both its bonds point into it (or both out of it) and its ports are not named; or one port is used by both bonds; or a port name other than `p1`/`p2`; or a port name on a one-port or junction. Without port names, the bond pointing in is `p1` and the one leaving is `p2`.", "Name the ports: `a -> screw.p1` and `b -> screw.p2`; use `p1`/`p2` only on two-ports.")
d("E403", "junction with fewer than two bonds", "A 0- or 1-junction has no bond or only one: it joins nothing.", "Connect it or remove it.")
d("E404", "bond endpoint is not an element or junction", "A bond names something that is not an element or junction (a misspelling, or a parameter).", "Use the suggested name.")
d("E405", "bond from a node to itself", "Both ends of a bond are the same element or junction.", "Connect two different nodes.")
d("E406", "label on a chain", "A bond label (`b9: A -> B`) stands before a chain of several bonds; a label names one bond.", "Put the labelled bond on its own line.")
d("E407", "unknown junction kind", "A junction statement starts with a number other than 0 or 1.", "Use 0 (common effort) or 1 (common flow).")

d("E501", "law not allowed for the kind", "An element has a law its kind does not take (`r = ...` on a C, `e = ...` on an Sf), or a model-level state has a law other than `der(x) = ...` and `x(0) = ...`.", "Use the laws the hint lists for the kind (`Se/MSe: e`, `Sf/MSf: f`, `R: e and/or f`, `C: e`, `I: f`, two-ports: `r`).")
d("E502", "missing law", "An element lacks the law its kind needs: `e = ...` for a C or an effort source, `f = ...` for an I or a flow source, `e = ...` or `f = ...` for an R, `r = ...` for a two-port.", "Add the law.")
d("E503", "duplicate law", "An element gives the same law twice (`e = ...` twice, two initial values or rate laws for one state, a state declared twice); a note points at the first.", "Keep one.")
d("E504", "initial value or rate of an unknown state", "`x(0) = ...` or `der(x) = ...` names a state the element does not have; or `der(q)`/`der(p)` is given for a storage element's default state (its rate is its flow/effort); or a custom state has no `der(...)` law; or a law `NAME(arg) = ...` that is neither `state(0)` nor `der(state)`; or an element without states has such a law.", "Write `q(0) = ...` for a C's default state and `p(0) = ...` for an I's; declare custom states with `state X [unit]` and give each `der(X) = ...`.")
d("E505", "states on an element that cannot have them", "`state X` is declared on an element that is not a storage element (only C and I have states), or a state is called `e` or `f`, or a model-level state declares further states.", "Use a model-level `state x : der(x) = ...` for an integrated quantity that is not an energy store.")
d("E506", "an element law uses a variable it cannot", "An element law uses one of the element's own variables that it is not a function of: a law using the variable it defines (`e = ... e ...`), a C's effort law or an I's flow law using the port's flow/effort (they are functions of the state), or a source's law using its own port variables (a source is independent of its load).", "Write the law in terms of what the hint lists: a C's `e` in terms of its states, an R's `e` in terms of `f` (or the reverse); for a load-dependent source use an R.")

d("W301", "unused parameter", "A parameter is not used by any law, input, output, state, setting or other parameter.", "Remove it or use it.")
d("W302", "unused input", "An input is not used by any law, output, or other input.", "Remove it or use it (e.g. `MSe src : e = F`).")
d("W303", "name hidden inside element laws", "A parameter, input, output or state is called `e` or `f`, or a parameter or input is called like a storage element's state: inside element laws that name means the element's own variable, so the model-level name cannot be used there.", "Rename it if you need it in a law.")
d("W304", "resistor or store drawn with its bond leaving it", "An `R`, `C` or `I` element's bond points away from it. Its `e` and `f` follow the half-arrow, so `e*f` is the power it delivers: `e = b*f` then makes a resistor a source, and `der(q) = f` fills a capacitor while it discharges. The model still compiles as written.", "Draw the bond towards the element (`j -> tank`), which is what the law assumes.")
d("W305", "a label that is another bond's default name", "A bond is labelled `b<N>` while bond number N has no label of its own. `b<N>.e` then means the labelled bond (labels win), and bond N is called `bond<N>` in equations, CSV columns and reports.", "Choose a label that does not look like a bond number (`b9_`, `motor_bond`).")

PARSE_EXAMPLES = {
    "E100": "model M\n  param = 3\nend\n",
    "E101": "model M\n  param k = 3 $\nend\n",
    "E102": "model M\n  param k = 3 \"spring stiffness\nend\n",
    "E103": "model M\n  param k = 3\n",
    "E104": "model M\n  param end = 3\nend\n",
}

HEADER = """# Diagnostics

Every problem bondc reports has a stable code, a message, the place in the
source it is about (`file:line:column`, the line and a caret), notes at related
places, and a hint. One run reports every problem it can find, sorted by
position. `bondc check --json` prints the same diagnostics as JSON
(`Diagnostic.to_json()`).

| range | stage | module |
| --- | --- | --- |
| E0xx | command line and files | `bondc/cli.py`, `bondc/semantic.py` |
| E1xx | syntax | `bondc/parse.py` |
| E2xx | units | `bondc/units.py`, `bondc/semantic.py` |
| E3xx, W3xx | names, expressions, files, experiments | `bondc/semantic.py`, `bondc/evaluate.py` |
| E4xx | graph structure: bonds, ports, junctions | `bondc/semantic.py` |
| E5xx | element laws and states | `bondc/semantic.py` |
| E6xx, W6xx, I6xx | causality | `bondc/causality.py` |
| E7xx, W7xx | equations | `bondc/equations.py`, `bondc/symbolic.py` |
| E9xx | data files and analyses | `bondc/analysis/` |

Errors stop the command (exit status 1); warnings (`W...`) are printed and the
command goes on. A file that cannot be read at all (missing, a directory, not
UTF-8) is a usage error (exit status 2), with no code of its own beyond E000.

The examples below are the golden test cases of `tests/golden/check/` (and, for
syntax errors, small inputs to the parser); the output is exactly what bondc
prints for them. This page is generated by
`tests/golden/check/make_diagnostics_doc.py`; edit the explanations there.
"""

LATER_STAGES = """
# Later stages

These codes are reported by the causality, equation and analysis stages; their
modules' docstrings and tests describe them in detail.

| code | meaning |
| --- | --- |
| E000 | a usage error without a more specific code (e.g. a model file that cannot be read) |
| E001 | bad command-line arguments |
| E601 | causal conflict: sources (or storage elements) that cannot all hold, e.g. two Sf on one 1-junction |
| W602 | a storage element in derivative causality: its state follows from the others' |
| I603 | an algebraic loop (no storage element in between); the equations stage solves it |
| W604 | nonlinear algebraic loop, solved numerically |
| E605 | a law that must be inverted for the assigned causality cannot be inverted |
| E701 | an expression the equation stage cannot translate |
| E702 | a singular algebraic loop |
| E703 | a storage element in derivative causality that cannot be eliminated |
| W704 | an initial value ignored because its element is in derivative causality |
| E9xx | data files and analyses (friction fit, motor data): unreadable or malformed data, failed fits |
"""

SECTIONS = {"E1": "Syntax (E1xx)", "E2": "Units (E2xx)", "E3": "Names, expressions, files and experiments (E3xx)",
            "E4": "Graph structure (E4xx)", "E5": "Element laws and states (E5xx)", "W3": "Warnings (W3xx)"}


def _examples(code: str) -> list[tuple[str, str, str]]:
    """(file name, model text, rendered diagnostics) for one code."""
    examples = []
    if code in PARSE_EXAMPLES:
        text = PARSE_EXAMPLES[code]
        try:
            parse_text(text, "m.bg")
        except ParseError as error:
            assert error.diagnostics[0].code == code, code
            examples.append(("m.bg", text, render_all(error.diagnostics, {"m.bg": Source("m.bg", text)})))
        else:
            raise SystemExit(f"the {code} example parses")
    for path in sorted(GOLDEN.glob(f"{code}_*.bg")):
        examples.append((path.name, path.read_text(encoding="utf-8"),
                         path.with_suffix(".txt").read_text(encoding="utf-8").rstrip("\n")))
    return examples


def main() -> None:
    """Write docs/diagnostics.md."""
    out = [HEADER]
    section = None
    for code, (title, meaning, fix) in EXPLANATIONS.items():
        if SECTIONS[code[:2]] != section:
            section = SECTIONS[code[:2]]
            out.append(f"\n# {section}\n")
        out.append(f"## {code} {title}\n\n{meaning}\n")
        for name, text, rendered in _examples(code):
            out.append(f"`{name}`:\n\n```\n{text.rstrip()}\n```\n\n```\n{rendered}\n```\n")
        out.append(f"**Fix:** {fix}\n")
    out.append(LATER_STAGES)
    page = "\n".join(out).replace("\n\n\n", "\n\n")
    (ROOT / "docs" / "diagnostics.md").write_text(page, encoding="utf-8")


if __name__ == "__main__":
    main()
