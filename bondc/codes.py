"""The registry of bondc's diagnostic codes: each code's severity, stage, title, what it means and
how to fix it -- the one place a code is explained.

``docs/diagnostics.md`` is generated from it (with an example of each code:
``tests/golden/check/make_diagnostics_doc.py``), and the language server links each diagnostic
to its section (:func:`anchor`). A code bondc emits must be here (the diagnostics page's test).

>>> CODES["E201"].title, CODES["E201"].severity, CODES["E201"].stage
('unknown unit', 'error', 'Units')
>>> anchor("E201")
'e201-unknown-unit'
"""

from __future__ import annotations

import re
from dataclasses import dataclass

SEVERITIES = {"E": "error", "W": "warning", "I": "information"}


@dataclass(frozen=True)
class Code:
    """One diagnostic code: ``E201``, its title, what it means and how to fix it."""

    code: str
    title: str
    meaning: str
    fix: str

    @property
    def severity(self) -> str:
        """From the code's letter (E915, a warning with an E code, says so in its message)."""
        return SEVERITIES[self.code[0]]

    @property
    def stage(self) -> str:
        return stage_of(self.code)


CODES: dict[str, Code] = {}


def d(code: str, title: str, meaning: str, fix: str) -> None:
    """Register ``code`` (the entries below, in the page's order within each stage)."""
    CODES[code] = Code(code, title, meaning, fix)


# ================================================================== the codes

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

d("E210", "dimensions differ", "A law, a sum, a comparison, the branches of an `if`, a declared output or input unit, a rate or an initial value combine quantities of known, different dimensions (the language reference, section 14): `e = k + q` with `k` in N/m, an output declared `[m/s]` bound to a force. The dimensions of the bonds' efforts and flows are inferred from the elements around them, through junctions and across TF/GY by the dimension of their ratio; a note points to the law that fixed a dimension the error uses. Numbers and parameters without a unit take whatever dimension makes the expression consistent; a quantity raised to a power that is not a constant rational (an empirical fit) is not checked; angles are dimensionless.", "Fix the law or the units of the parameters it uses; give a parameter its unit, or none if it is a fitted coefficient.")
d("E301", "undefined name", "A name that is not defined where it is used: a misspelt parameter, element, function or output, or an experiment/`--set` override of something that is not a parameter (or input). The hint offers the closest name in scope.", "Fix the spelling, or declare the name. Inside element laws `e` and `f` are the element's own effort and flow; elsewhere write `X.e`, `X.f`.")
d("E302", "duplicate name", "A name is defined twice. Elements, junctions, parameters, inputs, outputs, states, functions and bond labels share one namespace per model (file-level functions included); experiments, settings inside one experiment, overrides inside one experiment and a function's arguments each must also be unique. The error points at the second definition, with a note at the first.", "Rename one of the two.")
d("E303", "unknown element kind", "The first word of an element statement is not one of `Se Sf MSe MSf R C I TF GY MTF MGY`.", "Use the suggested kind (kinds are case-sensitive).")
d("E304", "recursive function", "A function calls itself, directly or through other functions. The message names the cycle.", "Functions are pure formulas evaluated by substitution; write the repetition out, or use an `if` expression.")
d("E305", "dependency cycle or forward reference", "A parameter uses a parameter defined below it (parameters are evaluated top to bottom), or a parameter uses itself, or an override (experiment `param`, `--set`) makes parameters depend on each other in a cycle, or inputs (or outputs) are defined in terms of each other in a cycle.", "Move the parameter that is used above the one that uses it; break the cycle.")
d("E306", "wrong arguments", "A call has the wrong number or shape of arguments: `abs sign sqrt exp log sin cos tan tanh atan` take 1, `atan2` 2, `min`/`max` at least 2, `step(t, t0)` 2, `csv(\"file\", \"column\")` 2, `table(t, [t0, ...], [v0, ...])` a value and two lists of the same length with at least two points and breakpoints that do not decrease; an `fn` takes as many as it declares.", "Write the call as shown in the hint.")
d("E307", "missing import", "`import \"path\"` names a file that does not exist (or cannot be read, or whose path is longer than the system allows), or a file that is not a model: its path does not end in `.bg`, or it is a link to a file that does not. Such a file is not read, and nothing of it is shown (a model may name any file, `/etc/passwd` too). The path is relative to the importing file.", "Fix the path; the hint shows where bondc looked.")
d("E308", "cyclic import", "Files import each other, directly or through other files. The message names the chain.", "Move what both files need into a third file that both import.")
d("E309", "model selection", "The file has no model, or several and no `--model` was given, or `--model` names a model the file (and its imports) does not have.", "Pass `--model NAME` with one of the listed models.")
d("E310", "CSV file or column", "`csv(\"file\", \"column\")` names a file that cannot be read (paths are relative to the model file), a file without a header line, or a column that the header does not have, or data rows the simulation could not read: a cell that is not a number, a time before the one above it (the row is counted with the header as row 1, blank lines and `#` comments left out; the message names the row and the column, and does not quote the row). A file that is not a CSV table (a header of two or more column names, then rows of as many numbers) is said to be none, and nothing of it is shown: a model may name any file (`/etc/passwd`, `/proc/self/environ`). The first column (or the column `t` or `time`) is time.", "Fix the path or the column name (the hint lists the columns), or the row the message names.")
d("E311", "cannot evaluate", "A constant (parameter, override, setting, initial value, table breakpoint) has no value: a logarithm or square root of a negative number, a division by zero, a negative number to a fractional power, or a result too large for a float (also a number whose value in SI is: `1e308 [kN/m]` is 1e311 N/m). Also a law, output or input that divides by parameters whose value is 0 (`f = p/m` with `m = 0`, outside an `if` that guards it): every evaluation would be inf or nan. The caret is under the sub-expression that failed; inside a function, a note points into its body.", "Fix the expression or the parameter values it uses. If the value comes from an experiment's overrides, a note names the experiment.")
d("E312", "unknown variable of a graph node", "A dotted reference names a variable the node does not have: `X.q` on an element without a state `q`, `X.p1.e` on a one-port, `X.e` on a two-port (name the port), `J.f` on a 0-junction or `J.e` on a 1-junction (a 0-junction has one common effort, a 1-junction one common flow), `bN.e` with no bond N, or a dotted reference on a parameter or input.", "Use one of the variables the hint lists; for the flow at a 0-junction use one bond's flow (`b3.f` or a label).")
d("E313", "string or list where a number is expected (or the reverse)", "A string appears in an arithmetic expression, a list outside `table(...)`, a `solver` that is not a string, `csv` arguments that are not strings, or `outputs` entries that are not names.", "Write numbers in expressions; quote the solver name (`solver = \"Radau\"`); write `outputs = [name1, name2]`.")
d("E314", "unknown experiment setting", "A setting inside `experiment ... end` is not one of `t_end solver rtol atol max_step cycle outputs first_step dt`.", "Use the suggested setting.")
d("E315", "reserved name", "`t` (time) and `pi` cannot be defined as names, and a function cannot take the name of a built-in.", "Choose another name.")
d("E316", "name not allowed here", "A name that exists but cannot be used where it is written: a parameter (a constant) using an input, `t` or a graph variable; an input (a signal of `t` and parameters) using a graph variable, output or state; a function body using anything but its arguments; `csv(...)` outside an input or law; an element or function used as a value. The hint says what the place may use.", "Pass the value as a function argument, move the expression into an output or element law, or use the element's variables (`X.e`, `X.f`).")
d("E317", "invalid setting value", "A setting has a value outside its range: an unknown solver (solvers are SUNDIALS `CVODE` (BDF, the default), `CVODE-BDF`, `CVODE-Adams`, `IDA` and the `scipy.integrate.solve_ivp` methods `RK45 RK23 DOP853 Radau BDF LSODA`), or a time or tolerance that is not positive.", "Use one of the listed solvers, or a positive value.")
d("E318", "unknown experiment", "`--experiment NAME` names an experiment the model does not have.", "Use one of the listed experiments.")
d("E319", "expansion too large",
  "Writing out what the model says would not end: `fn` functions that call the one before twice with "
  "different arguments (`f1(x) = f0(x + 1) + f0(2*x)`, ... `f20`: 2^20 bodies), or components that "
  "instantiate two (or more) of the one before at every level (2^40 copies). A function is expanded once "
  "per distinct arguments, so functions that call the one before twice with the same arguments "
  "(`f1(x) = f0(x) + f0(x)`) are fine at any depth. The limits: one expression (a parameter, a setting, an "
  "initial value, a law, an output) may write out 10 000 operations of function bodies, and all the "
  "constants of a model 1 000 000 (all its laws, 50 000), or ten per character of its files where that is "
  "more; a model may expand through its instances to 20 000 statements, or twenty per statement written in "
  "its files where that is more. The error is at the call (or instance) written in the model that goes "
  "beyond; `bondc check` stops there within seconds instead of running for hours.",
  "Compute the repeated part once: make it a parameter, an input or a model variable (`param y = f5(a)`, "
  "then use `y`), or simplify the functions; instantiate fewer components in each other.")
d("E330", "unknown library model", "An instance's kind is qualified with a library (`hydraulics.Orifice`) that has no such model, or no imported file has that library name. A library's name is its file name without `.bg`, or `NAME` for `import \"std:NAME\"`.", "Import the library at file level, or fix the model's name.")
d("E331", "ambiguous model name", "Two imported files define a model of the same name and an instance uses it unqualified.", "Qualify the name with its library: `hydraulics.Cylinder`.")
d("E332", "model instantiates itself", "A model contains an instance of itself, directly or through other models. The message names the chain.", "A component cannot contain itself; remove the instance.")
d("E333", "port not bonded inside", "A model declares `port NAME` but no bond inside the model uses it.", "Bond each port exactly once inside its model, e.g. `a -> j`.")
d("E334", "input without a value", "An input declared without `= expr` (a component's input) is not bound by the instance, or the model is run on its own.", "Bind it in the instance (`Motor m : u = v_supply`) or give it a default value.")
d("E335", "instance law that is not a binding", "An instance statement takes bindings `NAME = value [unit]`; an initial value `q(0) = ...`, a rate `der(...) = ...` or a `state` belongs to an element inside the component.", "Bind a parameter of the component that sets the initial value.")
d("E336", "unit on an input binding", "An instance binds an input to a signal expression; signals are computed in SI and take no unit.", "Write the expression in SI without a unit.")
d("E337", "unknown binding", "An instance binds a name that is neither a parameter nor an input of its model.", "Use one of the names the hint lists.")
d("E338", "bond between two ports", "A bond inside a model joins two of that model's own ports.", "Put a junction between them: `a -> j -> b`.")
d("E339", "port bonded twice", "A port is one bond through the boundary: inside, the port is used in exactly one bond, and outside `INSTANCE.PORT` is used in exactly one bond.", "Join the bonds at a junction inside (or outside) the component.")
d("E340", "bond to an instance without a port", "A bond names an instance (`valve`) instead of one of its ports (`valve.a`).", "Write `INSTANCE.PORT`; the hint lists the ports.")
d("E341", "unknown port", "`INSTANCE.PORT` names a port the instance's model does not declare.", "Use one of the ports the hint lists.")
d("E342", "port directions disagree", "The bond at a port outside and the bond at the same port inside must carry power the same way: into the component on both sides (outside the bond points to `INSTANCE.PORT`, inside it leaves the port) or out of it on both. The error points at the outside bond with a note at the inside one.", "Reverse one of the two bonds.")

d("E343", "instance port not bonded", "A port of a component instance is reached by no bond outside (`Damper d` declared, but no `v -> d.a`). Reported once per port at the instance; inside, the port is then taken as a boundary of zero effort so that the component's own elements are not reported as unbonded too.", "Bond the port once outside: `j -> d.a` (power into the component) or `d.a -> j`; or remove the instance.")

d("E344", "external input's default is not a constant",
  "An external input (`input u [V] external = default`, section 15) takes its signal from the host running the "
  "model; its default, used when nothing supplies it, is a constant: numbers, parameters, `pi` and functions. "
  "The default uses time `t`, an input, a state or `csv(...)`.",
  "Give a constant default (`external = V0`); a signal of time belongs to a plain input (`input u [V] = "
  "V0*step(t, 0.1)`), or supply it from the host (a table, a function of t, `--input u=FILE.csv`).")
d("E345", "external in an experiment",
  "An experiment's `input` replaces one of the model's inputs with a signal for that experiment; `external` "
  "is declared on the model's own input, not in an experiment.",
  "Write `external` on the model's input; in the experiment write `input u = ...` (the experiment's signal).")
d("I346", "external input without a source",
  "Information, not a problem: the model has an external input and nothing supplies it (`bondc check`, or "
  "`bondc simulate` without `--input`), so its default is used. Said once per input.",
  "Supply it when it matters: `bondc simulate --input u=drive.csv`, or `simulate(..., inputs={\"u\": "
  "(times, values)})` in Python.")
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

# -- causality (bondc/causality.py; E605 and W604 are reported by bondc/equations/)

d("E601", "causal conflict",
  "Two elements impose the same variable, so no causality satisfies both: two flow sources on one 1-junction "
  "(both set its common flow), two effort sources on one 0-junction, effort sources on both sides of a "
  "transformer, or a storage element squeezed between such constraints. The error points at the element whose "
  "causality could not be assigned; notes show the other element(s), the junction or two-port, and the bonds "
  "involved. Every conflict in the graph is reported, also beside errors in the laws (an undefined name, a "
  "missing law, dimensions): causality depends on the graph's structure only, so it is assigned while the laws "
  "are wrong (a resistor whose law has an error is tried in both causalities, and a conflict is reported only if "
  "both meet it). An error in the structure itself (an unknown kind, a bond to nothing, a name defined twice, a "
  "syntax error) is reported alone: the conflicts wait for it to be fixed.",
  "Remove one of the sources, or put what really sits between them in the graph: a resistor (a pipe, a "
  "contact) or a storage element (a compliance, an inertia). If both describe one physical source, keep one.")
d("W602", "storage element in derivative causality",
  "A `C` whose effort, or an `I` whose flow, is fixed by the rest of the graph: a capacitor across an effort "
  "source, two inertias rigidly joined by a transformer. Its state is not independent; the equations stage "
  "expresses it through the others (two geared inertias become one state with the combined inertia). Notes "
  "show what fixes it. Its initial value is ignored (W704). `bondc equations` lists it under \"eliminated "
  "states\", and a simulation's result still has it, computed from the other states at every point: a "
  "column after the states in the csv and the DataFrame (`sim.dependent_states`).",
  "Nothing, if the parts are rigidly coupled on purpose. Otherwise put the compliance (`C`) or inertia (`I`) "
  "that really separates them into the graph, e.g. a shaft stiffness between the two inertias.")
d("I603", "algebraic loop",
  "Information, not a problem: variables depend on each other in a cycle that passes through no storage "
  "element (typically resistors on both sides of a junction, as in a resistor ladder). The equations stage "
  "solves the loop: symbolically when it is linear, numerically otherwise (W604); E702 when it has no "
  "solution.",
  "Nothing needed. To avoid the loop, add a small storage element where the physics has one (a line "
  "capacitance, a mass), or write a resistor's law in the other form (`f = ...` instead of `e = ...`).")
d("W604", "nonlinear algebraic loop",
  "An algebraic loop (I603) whose equations are not linear in the loop's unknowns (a diode, a turbulent "
  "orifice, a friction law), so bondc cannot solve it symbolically. It is kept as an implicit equation and "
  "solved numerically at every evaluation of the state equations: in the compiled C code by Newton's method "
  "with the loop's analytic Jacobian, from its guesses, and where that does not converge in 50 steps (an "
  "exponential law far from its root moves one e-fold per step) by Newton's method again with a line search "
  "that halves or doubles the step on the largest residual, from the guesses or, where the residual overflows "
  "there, from the guesses plus 1, -1, 10, -10, ... 1000, -1000; where that fails too, by the numpy module "
  "(`scipy.optimize.root`, warm-started, then the same line search). A solution counts when its residual, "
  "or the Newton step it leaves, is at rounding level.",
  "Usually nothing: the run is slower, and where the solve fails its unknowns become nan and the run stops "
  "(E810). To remove the loop, add a small storage element, or give the resistor's law in the form the loop needs.")
d("E606", "two-port ratio is zero",
  "A transformer's or gyrator's ratio `r` is 0 for every value of the parameters (`r = 0`, `r = 0/Ar`), and "
  "its causality gives it port 1's effort, so its equations divide by `r` (`p2.e = p1.e/r` for a "
  "transformer, `p2.f = p1.e/r` for a gyrator). The caret is under the ratio's law.",
  "Give the ratio the element has (a piston of area `Ar` is `r = 1/Ar`), or remove the two-port.")
d("E605", "law cannot be inverted",
  "Causality needs a law in the other form than the one written: a resistor in conductance causality "
  "(it receives the effort and must give the flow) with only `e = ...`, or a storage element in derivative "
  "causality whose state must be computed from its effort or flow. bondc inverts a law that is linear in the "
  "variable, and another law when `sympy` finds exactly one inverse that reproduces it; a nonlinear law that "
  "uses `abs`, `sign`, `min`, `max`, `if`, `table` or `step`, or that has several inverses, cannot be "
  "inverted. The caret is under the law.",
  "Give the other form too: an `R` may have both `e = ...` and `f = ...` (they must be inverses of each "
  "other). For a storage element, give an invertible law or add compliance or inertia so that it gets "
  "integral causality.")

# -- equations (bondc/equations/, bondc/symbolic.py)

d("E701", "expression cannot be translated",
  "The equations stage translates every law, rate, input, output, initial value and `when` clause to "
  "`sympy` and stops at what has no value: a divisor, a `mod` divisor or the base of a negative power that "
  "is 0 for every value of the variables once simplified (`q/(exp(q)*exp(-q) - 1)`, `log(b - b)`), a "
  "constant beyond a double's range (`q*1e309`), a constant with no real value (`sqrt(-1)`, `log(-2)`, "
  "`(-8)^(1/3)`: laws are evaluated as real numbers, so an odd root that keeps its sign is written "
  "`sign(x)*abs(x)^(1/3)`), or initial values that depend on each other in a cycle (functions that call "
  "one another so often that expanding them would not end are E319). Most other mistakes of "
  "this kind (an unknown name, a divisor written as `a - a`, a function that calls itself) are reported "
  "first by the semantic checks (E301, E302, E306, E311, E312, E313, E316). `bondc check` runs this stage "
  "too, so a model that passes it does not get E701 later.",
  "Rewrite the expression that the caret shows: the message says what has no value.")
d("E702", "singular algebraic loop",
  "The equations of an algebraic loop do not determine its unknowns: the loop's laws cancel each other, as "
  "with two resistances whose parallel combination is infinite (a negative resistance balancing a positive "
  "one), or two ideal paths in parallel with nothing on them. The error points at the first element or "
  "junction on the loop; notes show the others.",
  "Check the signs of the laws and the bond directions; put a resistor or storage element on one of two "
  "parallel ideal paths.")
d("E703", "derivative causality that cannot be eliminated",
  "A storage element in derivative causality (W602) whose state bondc cannot express through the other "
  "states: it has several states (a custom `C` with `state P, state T`), it feeds a nonlinear algebraic "
  "loop, its state depends on another eliminated element's rate, or eliminating it needs the time derivative "
  "of a signal that cannot be differentiated (a measured `csv(...)` signal). The message says which; only the "
  "last case has no source location.",
  "Add compliance or inertia so that the element gets integral causality (e.g. the source's internal "
  "resistance in front of a capacitor); for a measured signal, drive the element through a resistor.")
d("W704", "initial value ignored",
  "A storage element in derivative causality (W602) has an initial value, but its state follows from the "
  "other states, so the value given is not used.",
  "Remove the initial value, or give it to the element that is in integral causality (for two geared "
  "inertias, the motor's momentum sets the load's).")

# -- simulation (bondc/simulate.py, bondc/runtime/)

d("E801", "no end time",
  "`bondc simulate` (and `report`, `validate`, `sweep`) needs an end time: `--t-end`, or `t_end` in the "
  "experiment that runs. The model has no experiment, or its experiment has no `t_end`.",
  "Give `--t-end 2`, or add an experiment: `experiment run` / `t_end = 2 [s]` / `end`.")
d("E802", "unknown parameter override",
  "Python API only: `bondc.simulate.simulate(ss, overrides={...})` was given a name that is not a parameter "
  "of the model. (On the command line an unknown `--set` name is E301.)",
  "Use one of the parameters the hint lists; `StateSpace.parameters` names them.")
d("E803", "cannot start the simulation",
  "The runtime rejected the settings before integrating: an end time that is not after the start time "
  "(`--t-end 0` or a negative one); through the Python API, also output times that do not increase, an "
  "unknown solver or a parameter vector of the wrong size. (The experiment's own settings are checked "
  "earlier, as E317.)",
  "Give a positive `--t-end`; the message says which setting is wrong.")
d("E804", "measured signal unreadable at run time",
  "A `csv(\"file\", \"column\")` signal passed the checks (E310: the file, its header and its rows) but "
  "cannot be used when the run reads it: the file was changed after the model was checked, as when a run "
  "comes from the compile cache or, through the Python API, from a state space derived earlier. The message "
  "gives the file's absolute path and the row; it has no source location.",
  "Fix the row the message names; the time column (`t`, `time`, or else the first) must not decrease.")
d("E805", "no such input to supply",
  "`bondc simulate --input NAME=...` or the API's `inputs={NAME: ...}` names something that is not an input of "
  "the model.",
  "Use one of the external inputs the hint lists.")
d("E806", "input is not external",
  "A host tried to supply an input that the model computes itself (`input w [V] = ...`); only inputs "
  "declared `external` are supplied from outside (section 15).",
  "Declare the input `external` (with its constant default), or supply one of the external inputs the hint "
  "lists.")
d("E807", "external input's signal cannot be used",
  "The signal given for an external input cannot be used: an `--input` that is not `NAME=FILE.csv[:COLUMN]`, a "
  "file that is missing or not a CSV table, a column it does not have, a header unit of another dimension than "
  "the input's, times that decrease; through the API, a table whose times and values differ in length or hold "
  "nan, or a function that returns no number.",
  "Give a table of times (not decreasing) and values of one length, in SI, or a function of t; a file as "
  "`csv()` reads one: a header line (time first, units in brackets), then rows of numbers.")
d("E810", "a value became nan or inf",
  "The run stopped because a state, a variable or a state derivative became `nan` or `inf`. The message "
  "names the first non-finite variable in causal order, its law and the time; the caret is under that law, and "
  "the hint gives the states at that time. Everything computed before is kept (and written with `-o`); the "
  "command exits with status 1.",
  "A law was evaluated outside its domain: the square root or logarithm of a negative number (a tank that "
  "emptied, a pressure that went negative), a division by zero. Guard the law (`sqrt(max(q - 1, 0))`), or "
  "stop the experiment before the state leaves its physical range. Where the variable is an unknown of a "
  "nonlinear algebraic loop (W604) that was not solved at that state, the cause and hint say so instead: a law "
  "in the loop with an infinite slope (`sign(e)*sqrt(abs(e))` at zero flow), unknowns of very different sizes, "
  "or a loop with no solution there; a small storage element in the loop, or a law with a finite slope at "
  "zero, removes the difficulty.")
d("E811", "solver failure",
  "The ODE solver gave up: its step size became too small. The model is stiffer than the method can handle "
  "(an explicit solver on a stiff model), a variable grows without bound (here `x` reaches infinity at "
  "t = 1 s), or the right-hand side has a discontinuity bondc cannot see. Results up to that time are kept.",
  "For a stiff model use a stiff solver (`solver = \"CVODE\"`, the default, or `\"Radau\"`); for a "
  "variable that grows without bound, check its law or end the run before; otherwise check the laws near the "
  "time given, or loosen `rtol`/`atol`.")
d("E812", "too many events",
  "A switch (`if`, `sign`, `step`, a `table` corner) changed mode more than 100000 times: the run stops "
  "instead of creeping on. Chattering that the sliding-mode and chattering guards absorb does not count "
  "(W820). Reaching the limit takes a long run; the example lowers it through the runtime's `max_events` "
  "argument to show the message. E812 also stops a run whose `when` clause fires ever faster towards an "
  "instant (Zeno behaviour: a bouncing ball coming to rest): the message gives the instant the firings "
  "accumulate at, the diagnostic points at the clause, and the bounces before it are kept. It also stops a "
  "run that stalls on a law continuous across its switch but infinitely steep there (a turbulent orifice's "
  "`sign(dp)*sqrt(abs(dp))` while the drop changes sign): such a switch is crossed, never held in a "
  "sliding mode, and the message names the law.",
  "Smooth the law near its switching surface (a narrow linear band around zero speed instead of "
  "`sign(v)`; a laminar band for an orifice: `if abs(dp) < dp_l then K*dp/sqrt(dp_l) else "
  "K*sign(dp)*sqrt(abs(dp))`), or simulate a shorter time. For Zeno behaviour, say in the model what happens after the "
  "accumulation instant: a discrete variable that a `when` clause sets once the rebound is negligible and "
  "that holds the ball on the floor.")
d("E813", "interrupted",
  "The run was interrupted (Ctrl-C, or SIGTERM). It cannot be triggered from a model. What was computed is "
  "kept and written with `-o`; the message gives the time the run got to; the command exits with status 130 "
  "(143 for SIGTERM), as the shell reports a program it stopped. The example interrupts a run from its "
  "progress callback.",
  "Nothing to fix; simulate a shorter time with `--t-end` if the run is too slow.")
d("E814", "too many points",
  "A run keeps every state, output and bond variable at every point; it stops when its result would exceed "
  "1 million points or 20 million numbers (about 1 GB with the recording and the analyses), and keeps what it "
  "computed up to there, marked incomplete. A `dt` that would give more points than that is refused before the "
  "run (E803).",
  "Report on a coarser grid (`--dt`, or `dt` in the experiment), or simulate a shorter time.")
d("E840", "no C form",
  "`bondc compile --target c` and `bondc fmu` print the model's laws as C. A law (or an output, an initial value, "
  "a when clause) that C cannot express has none: a measured `csv(...)` signal, read by bondc's Python runtime from "
  "its file, is the common case. The diagnostic points at the law that reads it.",
  "Give the signal as an external input (`input u [V] external`, LANGUAGE.md section 15): the FMU's importer, or "
  "the program that embeds the C code, supplies it.")
d("E841", "a switch that may slide cannot be exported as Model Exchange",
  "A Model Exchange FMU leaves the integration to the importer, whose integrator steps the model's laws and "
  "stops at its event indicators; it cannot hold the state on a switching surface (a Filippov sliding mode: a "
  "Coulomb friction that sticks, a relay that chatters). `bondc fmu --kind me` refuses, before building, a model "
  "with a located switch whose switching function reads a state whose rate reads that switch's own mode (the two "
  "sides' rates can then push the state onto the surface and hold it there). The diagnostic points at the first "
  "such switch's law, with notes at the others. Switches of time only (`step(t, t0)`), switches whose states' "
  "rates do not read their mode, and kinks (laws continuous across their switch: `abs`, `min`, `max`, a relief "
  "valve, an orifice's `sign(e)*sqrt(abs(e))`) export. A Co-Simulation FMU (the default) holds sliding modes "
  "with bondc's own engine inside.",
  "Export it as Co-Simulation (`--kind cs`, the default). For Model Exchange, make the law continuous across "
  "its switch (a kink needs no mode): a narrow linear band around zero speed instead of `sign(v)`, for instance.")
d("E843", "no compiler or no SUNDIALS for an FMU",
  "Building an FMU compiles C (bondc's compiler discovery: `$CC`, then `cc`/`gcc`/`clang`, then zig's from the "
  "ziglang package) and links scikit-sundae's SUNDIALS libraries (Linux x86-64 wheels), which the FMU carries. "
  "One of them was not found. It cannot be triggered from a model.",
  "Install scikit-sundae from a Linux x86-64 wheel, and a C compiler (or the ziglang package).")
d("E844", "the FMU's C code did not compile",
  "The C compiler failed on the FMU's sources (the model's C code, bondc's driver and FMI wrapper). This is a "
  "bug of bondc's export, not of the model; the message gives the compiler's first complaint. It cannot be "
  "triggered from a model.",
  "Report it with the model file; meanwhile simulate with `bondc simulate`.")
d("E815", "the run diverged",
  "A state grew beyond 1e30 in SI units, a magnitude no physical quantity of a machine reaches: the model is "
  "unstable (a negative damping or resistance, a positive feedback) or a law grows without bound. The run "
  "stops at that step and keeps what it computed, marked incomplete; the diagnostic points at the element "
  "that owns the state.",
  "Check the signs and values of the parameters that damp that state; `bondc linearize` shows the unstable "
  "eigenvalues (positive real part).")
d("W820", "chattering",
  "Switches changed mode faster than events can be located: they accumulate at an instant (a Zeno "
  "approach, like the twisting example, whose switching times shrink geometrically as it comes to rest), "
  "or several switches chatter in a way the Filippov treatment (any number of sliding switches at once) does "
  "not resolve. bondc integrated short intervals with the law unfrozen (modes recomputed at every "
  "evaluation); where the motion then sits on its switching surfaces it is held there as a sliding mode. The "
  "switching instants inside those intervals are not located: results there are as good as the solver's "
  "steps resolve them. The episodes are listed in the run's events. (Switches of time alone, a PWM or "
  "`if sin(2*pi*f*t) > c`, never chatter: their instants are found before integrating.)",
  "Nothing is wrong with the model when the switching really accumulates; for a tighter result there, lower "
  "`rtol`. For friction, a `coulomb(v, F_slide, F_static)` law sticks without chattering.")
d("W821", "output not finite",
  "An output (or a bond variable) is `nan` or `inf` from some time on, but the states are finite: its law is "
  "evaluated outside its domain, and nothing else uses it. The caret is under the output (or the law of the "
  "bond variable).",
  "Guard the output's law (`log(max(tank.q - 0.5, 1e-9))`), or end the run before it leaves its domain.")

# -- analyses and data files (bondc/analysis/)

d("E901", "no data rows",
  "`bondc fit-friction`, or a motor catalogue (`--motors`): the file is empty, or has a header but no data "
  "rows (lines starting with `#` are comments).",
  "Add the measured rows under the header.")
d("E902", "friction data column missing or repeated",
  "`bondc fit-friction` needs a velocity column (`v` or `velocity`), a torque column (`tau`, `τ` or "
  "`torque`) and a pressure column (`P` or `pressure`), named in any case, each optionally with a unit in "
  "brackets; other columns are ignored. A column is missing (the hint guesses which header cell was meant), "
  "or two columns hold the same quantity.",
  "Rename the header cell, e.g. `velocity [m/s],torque [N*m],pressure [Pa]`; separate columns with commas.")
d("E903", "not a number",
  "A data cell (friction data, motor catalogue) is empty, not a number, or not finite. The caret is under the "
  "cell.",
  "Write plain numbers (`0.05`, `2.24e5`); units belong in the header.")
d("E904", "wrong number of cells",
  "A row of a friction data file or a motor catalogue has more or fewer cells than the header (or, through "
  "the Python API, the columns given have different lengths).",
  "Look for a missing or extra comma in the row.")
d("E905", "data file cannot be read",
  "`bondc fit-friction` (or a motor catalogue) names a file that does not exist or cannot be read as UTF-8. "
  "`bondc fit-friction` exits with status 2.",
  "Fix the path; it is relative to the current directory.")
d("E906", "unit of a data column",
  "The unit in a friction data header (`velocity [mm/s]`) cannot be read, is unknown, or measures another "
  "quantity than the column (a velocity in `[N]`). Known units are converted to SI (`mm/s`, `MPa`, `kN*m`).",
  "Write a unit of the column's quantity: `m/s` (or `mm/s`), `N*m`, `Pa` (or `bar`, `kPa`); without a unit "
  "SI is assumed.")
d("E910", "zero velocity",
  "A friction test row has velocity 0, so the friction coefficient C = F/v is undefined.",
  "Friction is identified from steady motion: drop standstill rows.")
d("E911", "too few rows for a direction",
  "The power law C = a*|v|^b is fitted separately for upward (v > 0) and downward (v < 0) motion, each from "
  "at least 3 rows; a direction has fewer.",
  "Measure at three or more steady speeds in each direction.")
d("E912", "friction coefficient not positive",
  "For a row, the friction force from eq. 17, F = 2*pi/lead*tau + (P - P_atm)*A - M*g, does not oppose the "
  "motion, so C = F/v is zero or negative and cannot be fitted in log space. Usual causes: gauge pressure read "
  "as absolute, a sign convention different from bondc's (v and tau positive upward), or wrong "
  "`--lead`/`--area`/`--mass`.",
  "Pass `--patm 0` for gauge pressure; check the signs and the rig's parameters.")
d("E913", "exponent cannot be fitted",
  "All rows of one direction are at the same speed, so the exponent b is undetermined; or the nonlinear "
  "least-squares refinement did not converge.",
  "Measure at two or more different speeds in each direction (three or more: E911).")
d("E914", "invalid rig parameter",
  "A parameter of `bondc fit-friction` is not a finite number, or has the wrong sign: `--lead` and `--area` "
  "must be positive, `--mass`, `--gravity` and `--patm` at least 0.",
  "Give the rig's values in SI: `--lead 0.005` (m per revolution), `--area 2.63e-3` (m^2).")
d("E915", "pressure not above atmospheric (warning)",
  "A warning, despite its `E` code: the median chamber pressure is not above `--patm` (101325 Pa by "
  "default). bondc reads the pressure as absolute and uses (P - P_atm)*A, so data logged as gauge pressure "
  "give a wrong piston force. The fit is still made and printed, with this warning after it.",
  "For gauge data pass `--patm 0`; if the chamber really is below atmospheric, ignore it.")
d("E920", "motor catalogue header",
  "A motor catalogue (`--motors FILE`) must start with exactly the header "
  "`name,rated_torque,peak_torque,rated_speed,rated_power,rotor_inertia` (units N*m, N*m, rpm, W, kg*m^2); "
  "the optional columns `max_speed` (rpm) and `max_inertia_ratio` may follow, in any order. The message lists "
  "missing, unexpected and repeated columns, with a guess for a misspelt one.",
  "Write the six columns exactly as the hint shows, in that order, then any optional ones.")
d("E921", "motor catalogue value out of range",
  "A catalogue row has no name, a value that is not positive, a peak torque below the rated torque, or a "
  "maximum speed below the rated speed. An empty cell in an optional column means the catalogue gives no "
  "value for that motor.",
  "Fix the row; if the two torque columns are swapped, swap them back.")
d("E922", "motor listed twice",
  "Two catalogue rows have the same motor name.",
  "Remove the duplicate or rename one of them.")
d("E923", "motor profile samples",
  "Python API (`bondc.analysis.motors.requirements`, `select`): the time, torque and speed arrays have "
  "different lengths, fewer than 2 samples, non-finite values or more than one dimension; or rotor inertia "
  "was to be added to requirements built without a profile. `bondc simulate --motors` builds the profile from "
  "the run, so there it appears only when the `torque` or speed output is not finite.",
  "Pass the samples at the same instants, all finite.")
d("E924", "motor profile time not increasing",
  "Python API (`requirements`): the time samples are not strictly increasing. A simulated run always is.",
  "Sort the samples and drop repeated instants.")
d("E925", "motor cycle window",
  "Python API (`requirements(..., cycle=(t_start, t_end))`): the window is not two numbers, is empty, or "
  "lies outside the record. (`bondc simulate --motors` takes the window from the experiment's `cycle`, "
  "clipped to the run.)",
  "Give t_start < t_end inside the record.")
d("E926", "inertia ratio above 10 (retired)",
  "No longer emitted. It was a warning under a motor whose load/rotor inertia ratio was above 10; the ratio "
  "is now one of the sizing rules, so such a motor does not qualify and the verdict says why (\"SV-100 is "
  "smaller but its load/rotor inertia ratio is 11.9, above 10.\"). The code is kept so that it is not reused.",
  "Nothing: see the verdict of `bondc simulate --motors`; the limit is set with `--inertia-ratio` or the "
  "catalogue's `max_inertia_ratio` column.")
d("E927", "no torque or speed signal for motor selection",
  "`bondc simulate --motors` (and `report --motors`) sizes the motor from an output named `torque` and an "
  "output or input named `omega` (or `speed`); the model lacks one of them. The run itself is unaffected: the error "
  "is printed and the selection is left out.",
  "Add the outputs, e.g. `output torque [N*m] = coupling.e` and `output omega [rad/s] = rotor.f`.")
d("E928", "inertia-ratio limit not positive",
  "`--inertia-ratio` (of `simulate`, `report`, `validate` and `sweep`), or `inertia_limit` of the Python API "
  "(`bondc.analysis.motors.select`, `judge`), is not a positive number. It is the largest load/rotor inertia "
  "ratio a motor may have; the command stops before any work.",
  "Give a positive number, e.g. `--inertia-ratio 10` (the default when neither it nor the catalogue's "
  "`max_inertia_ratio` is given).")
d("E930", "result of another model",
  "Python API (`bondc.analysis.energy.energy_account(ss, result)`): the simulation result's states are not "
  "the model's, i.e. it was simulated from another StateSpace.",
  "Pass the StateSpace the result was simulated from.")
d("E931", "no time span",
  "Python API (`energy_account`): the result has fewer than two time points, so there is no energy to "
  "account. (`bondc simulate` skips the account for such a run.)",
  "Simulate past the start time.")
d("E932", "cycle length not positive",
  "Python API (`energy_account(..., cycle=...)`, `power_statistics`): the cycle length is not a positive "
  "number of seconds. (An experiment's `cycle` setting is checked as E317.)",
  "Give the cycle length in seconds, > 0, or None for the whole run.")
d("E933", "no such output",
  "Python API (`bondc.analysis.stats.power_statistics(result, names)`): a name is not an output of the "
  "simulation result.",
  "Use one of the outputs the hint lists.")
d("E934", "power not finite",
  "A power in the energy account is `inf` or `nan` from some time on (a bond variable that is not finite, "
  "W821): there is no meaningful account, so `bondc simulate` prints this instead of the tables. The "
  "example's mass of 1e-320 kg makes its velocity `p/m` infinite at once.",
  "Fix the law W821 names: a division by a parameter that is zero or tiny, or a state outside its range.")
d("E935", "too many cycles",
  "The energy and power analysis splits the run into cycles of the experiment's `cycle` length; a run that "
  "spans more than 10 000 of them is refused before any window is made (a cycle given in the wrong unit, "
  "1e-9 s, would be billions).",
  "Check the cycle length (seconds) in the experiment, or analyse a shorter run.")
d("W930", "energy balance does not close",
  "After a run, bondc accounts the energy of every element per cycle; for a cycle, the sources' net energy "
  "differs from dissipated + stored + net work in by more than 1e-6 of the energy throughput. The residual is "
  "the simulation's accumulated error. `bondc simulate` prints it as the last line of the energy account "
  "(`--json`: in `energy.diagnostics`, with the hint). Where a state spans so little over the run that "
  "`atol` resolves it more than ten times more coarsely than `rtol` asks (a hydraulic chamber's volume in m^3, "
  "about 1e-6, at the default atol of 1e-9), the hint names that state and the atol that resolves it: "
  "tightening `rtol` alone changes nothing then. Where an `R`, `C` or `I` element is drawn with its bond "
  "leaving it ([W304](#w304-resistor-or-store-drawn-with-its-bond-leaving-it)), the hint names it instead: a "
  "law written for power in then makes energy from nothing, and no tolerance closes the balance.",
  "Tighten `rtol` and `atol` in the experiment; `atol` to the value the hint gives where it names a state; "
  "draw the bond towards an element the hint names.")
d("W931", "two-port does not conserve power",
  "A transformer's or gyrator's work in at its two ports does not sum to zero over a cycle. bondc writes the "
  "two-port equations so that p1.e*p1.f = p2.e*p2.f holds exactly, so this is an internal consistency check of "
  "the energy account: it cannot be triggered from a model, and seeing it means a bug in bondc.",
  "Report it with the model file.")
d("W932", "energy account covers part of the run",
  "A run reported on a grid (`--dt`, `dt` in the experiment) is accounted from the same run at the solver's own "
  "steps, repeated without the grid. Where that repetition stops before the run's end (it would record over a "
  "million steps: E814), the energy account, its power cycles and its balance cover only the time up to there; "
  "the account is marked incomplete and its last cycle partial, and the message gives the time and why.",
  "Shorten the run, or loosen `rtol`/`atol` so that the solver takes fewer steps; a model that chatters on a "
  "switch may need its law written continuously (a kink, LANGUAGE.md section 7).")
d("E940", "no equilibrium",
  "`bondc linearize --at equilibrium` looks for a state where every rate is zero, starting from the initial "
  "state with the inputs held at `--time`, and found none: some rate stays away from zero (a constant force "
  "on a free mass, an integrator fed a constant), or the search ran away.",
  "Linearise at the initial state (`--at initial`, the default), or change the inputs so that an equilibrium "
  "exists.")
d("E941", "derivative cannot be evaluated",
  "`bondc linearize` evaluates the partial derivatives of the state equations at the operating point, and one "
  "is not a finite number there (`zoo` is sympy's complex infinity, or inf or nan as a number): e.g. d/dq "
  "sqrt(q) at q = 0, a turbulent orifice at zero pressure difference. The message shows the derivative, or "
  "names the state equation and the variable. Also where the state equations themselves have no value at the "
  "operating point (a division by zero there), and where a nonlinear algebraic loop (W604) has no solution found at the operating "
  "point (hybr from the last solution and from the guesses, then Newton's method with a line search): the "
  "message names the loop.",
  "Linearise at another point (another initial value, or `--at equilibrium`), or make the law smooth at the "
  "operating point.")
d("E942", "no such input or output",
  "`bondc bode`: a `--input` or `--output` names nothing the model has (the hint names the closest input or "
  "output and lists them), or the model has several inputs or outputs and none was chosen, or it has none at "
  "all (a frequency response needs an `input` to excite and an `output` to measure).",
  "Give the name as the model declares it (`--input F --output x`), or declare the signal: `input F [N] = ...` "
  "used in a source's law, `output x [m] = spring.q`.")
d("E943", "not an input (or not an output)",
  "`bondc bode`: the name given to `--input` is a parameter, an output, a state or an element, not an `input`; "
  "or the name given to `--output` is an input, a parameter or a state, not an `output`. The linear model's "
  "columns are the inputs and its rows the outputs.",
  "Excite an input and measure an output. To excite a parameter, make it an input (`input F [N] = F0`) used in "
  "the law; to measure a state, declare `output x [m] = spring.q`.")
d("E944", "bad frequency or range",
  "`bondc bode`: `--from` or `--to` is not a number with an optional unit of frequency (`0.5`, `\"10 [rad/s]\"`, "
  "`\"2 [kHz]\"`, `\"600 [rpm]\"`), is not positive (the frequency axis is logarithmic), or `--from` is not below "
  "`--to`.",
  "Give positive frequencies in Hz, or with a unit of frequency in brackets, the lower one with `--from`.")
d("E945", "bad number of frequencies",
  "`bondc bode --points N`: N is not a whole number from 2 to 100000.",
  "Give a whole number; the default is 400 frequencies spaced logarithmically.")
d("E946", "cannot verify",
  "`bondc bode --verify` simulates the nonlinear model with a small sine on the input around the operating "
  "point and compares the steady oscillation of the output with the linear prediction. That needs an operating "
  "point at rest (the default initial point of a model that moves there is not one), a linear model without a "
  "growing mode (else nothing settles), and a positive `--amplitude` in a unit of the input.",
  "Verify at an equilibrium (`--at equilibrium`) that is stable; give `--amplitude` as a positive number in the "
  "input's unit, or with a unit of its dimension (`--amplitude \"0.1 [N]\"`).")
d("E947", "unknown output kind",
  "`bondc bode -o FILE`: the file's extension says what to write, and it is not `.csv` (the table, units in the "
  "header), `.svg` (the plot) or `.html` (a page with the plots and margins).",
  "Name the file with one of these extensions.")
d("W942", "operating point on a switch",
  "`bondc bode`: a switching function of the model's laws (an `if` comparison, the speed of a `coulomb` "
  "friction, the argument of `sign` or `abs`, a table breakpoint) that depends on a state or an input is zero "
  "at the operating point: a friction stuck at zero speed, a valve at its opening pressure, a backlash at its "
  "edge. The law has a kink or a jump there and the linear model takes the slope of one side only, so the "
  "response holds for motion to that side (a stuck friction is not a viscous damper).",
  "Linearise where the law is smooth (another `--time`, another initial state, `--at equilibrium`), and check "
  "the response with `--verify`.")
d("W943", "linear prediction does not hold",
  "`bondc bode --verify`: at a verified frequency the simulated model's amplitude or phase differs from the "
  "linear prediction by more than 0.5 dB or 5 degrees. The model is not linear over the sine's amplitude there, "
  "or the operating point sits on a switch (W942).",
  "Verify with a smaller `--amplitude`; if the difference stays, the linearisation does not describe the "
  "machine at that frequency.")
d("W944", "verification run incomplete",
  "`bondc bode --verify`: the simulation at one frequency stopped before its end (the message says where and "
  "why), so that frequency has no simulated value.",
  "Verify with a smaller `--amplitude`, or look at the model's behaviour with `bondc simulate`.")

d("E960", "--vary not understood",
  "`bondc sweep`: a `--vary` is not `NAME=VALUES [unit]` (no `=`, a name that is not a name, no values, an "
  "empty value between commas), or no `--vary` is given.",
  "Write e.g. `--vary \"k=400,800,1600\"`, `--vary \"M=20:40:5 [kg]\"` (start:stop:count).")
d("E961", "--vary of something that is not a parameter",
  "`bondc sweep`: the name before `=` is not a parameter of the model (inputs and elements cannot be "
  "varied).",
  "Use one of the parameters the hint lists (names are case-sensitive).")
d("E962", "--vary value",
  "`bondc sweep`: a value is not a finite number, or a range is not `start:stop:count` with a whole count "
  ">= 2 (both ends are included).",
  "Write numbers (`400,800`) or a range (`20:40:5` gives 20, 25, 30, 35, 40).")
d("E963", "--vary unit",
  "`bondc sweep`: the unit in `[ ]` is empty, unknown, or measures another quantity than the parameter's "
  "declared unit (the same rule as `--set`, E204).",
  "Give the values in the parameter's unit (leave out `[ ]`) or in a unit of the same kind.")
d("E964", "too many runs",
  "`bondc sweep`: the grid (the product of the numbers of values of every `--vary`), or `--samples`, has more "
  "than 100000 runs. It is checked before the grid is made.",
  "Use fewer values, or split the sweep into several.")
d("E965", "unknown metric",
  "`bondc sweep --metric`: not a column the sweep can compute. Columns are `OUTPUT.min .max .mean .rms "
  ".final` (or `OUTPUT.*`), `energy.residual`, `energy.relative_residual`, and `motor.*` when the model has "
  "an output `torque` and an output or input `omega`/`speed`.",
  "Use a column the hint suggests or lists.")
d("E966", "parameter varied twice",
  "`bondc sweep`: the same parameter is given in two `--vary`, or both varied and fixed with `--set`.",
  "Give all its values in one `--vary`, and drop the `--set`.")
d("E967", "--jobs",
  "`bondc sweep --jobs`: the number of points run in parallel is not a whole number >= 1.",
  "Give `--jobs 1` (the default) or more.")
d("E968", "a sweep point failed without a diagnostic of its own",
  "`bondc sweep`: a point failed for a reason that is not a diagnostic of the model (a point whose model "
  "fails to load or whose run stops reports that diagnostic instead, e.g. E810): the model file changed on "
  "disk while the sweep ran, a worker process died (`--jobs`), or an internal error occurred. It is reported "
  "per point, and the sweep goes on (exit status 1). It cannot be triggered from a model.",
  "Do not edit the model during a sweep; rerun with `--jobs 1`; report an internal error with the model.")
d("E969", "sweep output file",
  "`bondc sweep -o FILE`: the file name does not end in `.csv` or `.json`.",
  "Name the output `results.csv` (SI values) or `results.json`.")
d("E970", "sweep output holds another sweep",
  "`bondc sweep -o FILE` resumes from the points already in FILE, and never rewrites FILE without them. It "
  "refuses, and leaves FILE (and `FILE.study`) byte for byte as they are, when FILE holds a table with other "
  "columns (other varied parameters or metrics, or a `motors` column where this sweep has none) or cannot be "
  "read as a sweep table (not text, a row bondc does not write, a json that is not a sweep's); when FILE holds "
  "finished points that are not points of this sweep (a `--vary` grid that leaves some of them out, other "
  "`--samples`, `--range` or `--seed`, or a Latin hypercube without `--seed`, which draws other points every "
  "run): running it would drop them; or when its points were computed from something else than this sweep's: "
  "a model file or import whose text changed since, or another model, experiment, `--set`, `t_end`, `dt` or "
  "motor catalogue (recorded in `FILE.study` beside a csv table, inside a json one). A grid that holds every "
  "point already in FILE extends the study: they are kept and only the new points run. A row cut short by a "
  "killed run is not a point: it runs again.",
  "To resume, give the same `--vary` (or a grid that holds its points), or the same `--samples`, `--range` "
  "and `--seed`, as the run that wrote FILE; otherwise write to another file (`-o`), or delete FILE to start "
  "the study again.")
d("E972", "not a sweep table",
  "`bondc report --sweep FILE`: FILE cannot be read, or is not the csv `bondc sweep -o` wrote (its header "
  "starts with `index` and has a `status` column).",
  "Give the table the sweep wrote.")
d("E973", "ratio study without a catalogue",
  "`--ratio NAME=VALUES` (of `simulate` and `report`) shows how the smallest qualifying motor changes with the "
  "transmission ratio, so it needs the motor catalogue to choose from; the command stops before any run.",
  "Add `--motors CATALOGUE.csv`, or vary the parameter with `bondc sweep --vary NAME=VALUES` to see its metrics "
  "without a motor choice.")
d("E971", "sweep executor",
  "`--executor dask` (or `--scheduler`) needs `dask.distributed`, which is not installed; or the scheduler "
  "given with `--scheduler` cannot be reached; or the executor is neither `local` nor `dask`.",
  "`pip install \"dask[distributed]\"`; start a scheduler with `dask scheduler` and workers with "
  "`dask worker ADDRESS`, and pass the address the scheduler prints.")

# -- calibration (bondc/analysis/fit.py, bondc/analysis/fit_write.py)

d("E880", "fit comparison not understood",
  "A `bondc fit --compare` is not `OUT=COLUMN[:weight=W]`: no `=`, a name that is not a signal name, "
  "something after `:` other than `weight=W`, or a weight that is not a positive number. (A fit takes no "
  "tolerances; `bondc validate` does.)",
  "Write e.g. `--compare torque=tau_meas` or `--compare P=P_meas:weight=2`.")
d("E881", "estimate not understood",
  "An `--estimate` is not `NAME` or `NAME=LOW:HIGH [unit]`: bounds that are not two numbers separated by "
  "`:`, a bound that is not a finite number, an empty unit, a unit without bounds, or a unit that measures "
  "another quantity than the parameter.",
  "Write `--estimate b`, `--estimate b=5:30` (bounds in the parameter's declared unit; an empty bound is "
  "open: `b=0:`) or `--estimate \"Ae=5:50 [mm^2]\"`.")
d("E882", "estimated parameter unknown",
  "An `--estimate` names no parameter of the model (the hint suggests the closest and lists them). A "
  "component's parameters are named with dots (`valve.Ae`).",
  "Use a parameter's name as `bondc check --json` or the report lists it.")
d("E883", "parameter cannot be estimated",
  "A fit gives the compiled model new parameter values at each evaluation, without deriving it again. "
  "This parameter cannot be given that way: its value sets an experiment setting (`t_end = T`, "
  "`max_step = h`, `cycle`), which is fixed before a run starts, or changes what the model's equations "
  "are derived from.",
  "Estimate a parameter that only enters the equations; fix this one with `--set`. To fit a setting, "
  "run `bondc sweep` over it.")
d("E884", "estimate bounds reversed",
  "An `--estimate NAME=LOW:HIGH` has LOW at or above HIGH.",
  "Give LOW < HIGH.")
d("E885", "start value outside the bounds",
  "The value the fit starts from (the model's, after the experiment and `--set`) is outside the "
  "`--estimate` bounds.",
  "Widen the bounds, or give a start inside them with `--set NAME=VALUE`.")
d("E886", "fit column missing",
  "A `--compare OUT=COLUMN` names a column the data set's CSV does not have (the hint lists them).",
  "Use a column name of the data file's header.")
d("E887", "fit signal missing",
  "A `--compare OUT=COLUMN` names a signal the model's run does not record (the hint lists the outputs).",
  "Use an output, a state (`mass.p`) or a bond variable (`b3.e`); or add an output to the model.")
d("E888", "parameter estimated twice",
  "Two `--estimate` name the same parameter.",
  "Give it once, with its bounds.")
d("E889", "fit data sets",
  "The data sets of `bondc fit` are not complete: a `--compare` before any `--data` (each `--data` starts a "
  "data set; the `--experiment` and `--compare` after it belong to it), a data set without `--compare`, two "
  "`--experiment` in one data set, no `--data` or no `--estimate`, data and run that share fewer than two "
  "samples, fewer samples than parameters, or `--max-evaluations` below 1.",
  "Write `--data up.csv --experiment up --compare x=x_meas --data down.csv --experiment down --compare "
  "x=x_meas`, each data set with its comparisons after it.")
d("E890", "fitted model cannot be written",
  "`bondc fit --write FILE`: the file is the model or a data file, is not a `.bg` file, exists and was not "
  "written by `bondc fit` (its first line says so), is in another folder than a model that reads files by "
  "relative paths (`import`, `csv()`), or an estimated parameter belongs to a component, so that the copy "
  "of the model file cannot hold its value.",
  "Give a new `.bg` path beside the model; for a component's parameter, give the fitted value with `--set`.")
d("E891", "model fails at the start values",
  "The run of a data set's experiment stops early (or gives values that are not finite) at the values the "
  "fit starts from, so there is nothing to improve on.",
  "Start from values with which `bondc simulate` runs the model, with `--set`.")
d("E892", "bound the model rejects",
  "The model does not accept an estimated parameter at one of its bounds (a divisor that becomes 0, a "
  "value its checks refuse): the fit would try it.",
  "Give bounds inside the values the model accepts (e.g. a mass above 0).")
d("W880", "estimates cannot be told apart",
  "Two estimates correlate beyond 0.99: the data determines a combination of them (a product, a sum), "
  "not each one; their intervals are wide and the values arbitrary along that combination.",
  "Fix one of them with `--set`, or add data (another signal, another experiment) that separates them.")
d("W881", "Jacobian singular",
  "A direction of the parameters changes no residual (the Jacobian's singular value is below 1e-6 of the "
  "largest): the parameters named cannot be determined from this data; their standard errors and "
  "intervals are infinite.",
  "Fix all but one of them with `--set`, or add data that tells them apart.")
d("W882", "estimate on its bound",
  "The fit ended with a parameter on its bound: the best value may lie beyond it, and its interval "
  "(computed as if it were free) is not meaningful.",
  "Widen the bounds if the values beyond are physical; otherwise check the model and the data.")
d("W883", "fit not converged",
  "The optimiser stopped at its evaluation limit before its tolerances were met; `bondc fit` reports the "
  "values it reached and exits with status 1.",
  "Raise `--max-evaluations`, or start nearer the solution with `--set`.")
d("W884", "runs failed during the fit",
  "At some trial values the model's run stopped early; the optimiser treated them as a poor fit and "
  "stepped back.",
  "Bounds that keep the parameters where the model runs make the fit faster and surer.")

# -- validation against measured data (bondc/analysis/validate.py)

d("E950", "measured data file",
  "`bondc validate --data FILE` (and `report --data`): the file does not exist, cannot be read, is empty or "
  "has a header but no data rows.",
  "Fix the path (relative to the current directory) or the file: a header line such as `t,omega` and then "
  "rows of numbers.")
d("E951", "measured value not a number",
  "A cell of the measured data is empty, not a number, or not finite. The caret is under the cell.",
  "Write a number in every cell; remove incomplete rows.")
d("E952", "measured time not increasing",
  "The time column (`t` or `time`, else the first column) of the measured data must increase strictly; the "
  "caret is under the first value that does not.",
  "Sort the rows by time and drop repeated instants.")
d("E953", "measured column missing",
  "A `--compare OUT=COLUMN` names a column the measured data does not have.",
  "Use the column name of the data file's header (the hint suggests the closest).")
d("E954", "not a simulated signal",
  "A `--compare OUT=COLUMN` names a signal the simulation does not record. Signals are the outputs, states "
  "(`mass.p`), inputs and bond variables (`b3.e`, or a bond label).",
  "Use the name of an output (or add one: `output omega [rad/s] = rotor.f`).")
d("E955", "comparison not understood",
  "A `--compare` is not `OUT=COLUMN[:metric=value,...]`: no `=`, a name that is not a signal name, an unknown "
  "metric (`nrmse rmse maxabs r2`), a tolerance that is not a number, negative, twice given, or `r2` above 1.",
  "Write e.g. `--compare omega=omega_meas:nrmse=0.05,r2=0.95`; without tolerances, `nrmse=0.05` applies.")
d("E956", "simulation and measurement do not overlap",
  "The simulated and measured time ranges share fewer than two simulated samples, so nothing can be "
  "compared: usually the data is in another time unit (ms) or starts later than the run ends.",
  "Check the experiment's `t_end` (or `--t-end`) and that the time column is in seconds.")
d("E957", "measured data header or row shape",
  "The measured data's header has an empty or repeated column name, names a unit bondc does not know (`P [barr]`), or a row has more or fewer cells than the "
  "header.",
  "Give every column a unique name; look for a missing or extra comma in the row.")
d("E958", "measured column of another quantity",
  "A comparison pairs a signal with a measured column whose header gives a unit of another quantity: an output "
  "declared in rad/s with a column in N*m, a force with a column in kg. (A column without a unit is taken as "
  "SI: W954.)",
  "Compare the signal with the column that measures it, or fix the unit in the column's header.")
d("W954", "measured column without a unit", "`bondc validate` compares a measured column whose header gives no unit with an output declared in a unit that is not SI (`[kPa]`, `[bar]`, `[mm]`, `[rpm]`): the column is taken as SI, as the language reference says, but the data may well be in the output's unit.", "Give the column's unit in its header, e.g. `P [kPa]`; values are converted.")

# -- command line and files

d("E000", "error without a specific code",
  "The code of an error raised with a bare message. Every error bondc reports to a user has a specific code, "
  "so E000 cannot be triggered; seeing it means a bug in bondc.",
  "Report it with the command line and the model file.")
d("E001", "command-line usage",
  "The command line is not understood: a missing argument, an unknown option, an option's value of the wrong "
  "type, or options that need each other (`--compare` without `--data`). The command exits with status 2.",
  "See `bondc COMMAND --help`.")
d("E002", "model file cannot be read",
  "The `.bg` file named on the command line does not exist, is a directory, or is not UTF-8 text. The "
  "command exits with status 2. (A file named by `import` is E307; a `csv(...)` file, E310.)",
  "Check the path (relative to the current directory); save the model as UTF-8.")
d("E003", "output path cannot be written",
  "An output file (`-o`, `--junit`) is checked before any work: its folder must exist and be writable, and "
  "bondc replaces only regular files — never a folder, a symbolic link, a named pipe or a device — and never "
  "one of the command's inputs: the model file, a file it imports, a data file its `csv(...)` calls read, or "
  "the files of `--data`, `--motors`, `--sweep` (`bondc compile -o m.bg m.bg` would replace the model). The "
  "command exits with status 2 and computes nothing. (A report's or JUnit file's folder is created when missing.)",
  "Give the path of a new file or of a regular file to replace, in a folder you may write; create the folder "
  "first (`mkdir -p`).")
d("E004", "output could not be written",
  "Writing the output failed after the computation (a full disk, a folder removed meanwhile). The file at the "
  "path is left as it was, and the content is written to a file in the system's temporary folder, which the "
  "message names, so the results are not lost.",
  "Free some space or choose another folder, then copy the kept file there (or run again).")

d("E005", "expression nested too deeply",
  "One expression is a chain of many thousands of terms (`1 + 1 + ... + 1`, generated text): the parser and "
  "the translation to sympy follow it one level per term. Sums of a few thousand terms are fine; beyond "
  "what Python's call depth allows (20 000 levels) the command stops with this error instead of a traceback.",
  "Split the expression: name parts of it with `param` or write them as `fn` definitions.")
d("E006", "document too large to analyse",
  "`bondc lsp`: an open document has more than 20 000 lines or 1 000 000 characters. The language server "
  "checks a buffer as you type on one analysis thread, a newer edit superseding the check in flight, "
  "so it does not analyse one that large (a model of 20 000 lines takes seconds to check, and one of "
  "millions of lines would hold that thread for minutes and the memory of its syntax tree); it shows "
  "this one diagnostic at the top of the document instead, and hover, "
  "definitions, completion and formatting give nothing for it. Every other document is served as "
  "before, and the document is analysed again once an edit brings it under the limits.",
  "Run `bondc check FILE` on the file, or split it into files that import each other.")
d("E007", "--set value is not NAME=VALUE",
  "A `--set` option's text does not read as `NAME=VALUE [unit]`: no `=`, nothing after it, or a value that "
  "is not an expression. The command exits with status 2 and computes nothing. Every other problem with a "
  "`--set` value is reported with its own code at the `--set` text (`--set #1` is the first `--set`): a name "
  "that is not a parameter or a value naming something undefined (`--set k=abc`) is E301, a unit of another "
  "quantity E204, a value that cannot be evaluated E311; as the command line is at fault, these too exit "
  "with status 2.",
  "Write `--set k=800` (the value in the parameter's declared unit), `--set \"k=0.8 [kN/m]\"` (quote a value "
  "with a unit or spaces), or an expression of the model's parameters, `--set \"b=2*J\"`.")


# ================================================================== stages

# Each code is also a name of this module (``codes.E201 == "E201"``): raise sites write
# ``codes.E201``, so a code that is not registered here fails where the module is read
# (tests/test_codes.py checks every ``codes.X`` in the package), never as a typo in a string.
globals().update({_code: _code for _code in CODES})


def __getattr__(name: str) -> str:
    """A code that is not registered: an AttributeError that says so (and tells mypy that
    ``codes.E201`` is a ``str``)."""
    raise AttributeError(f"bondc.codes has no code {name!r}: register it with d(...)")


STAGES = (  # (title, modules), in the order of the page
    ("Syntax", "`bondc/parse.py`"),
    ("Units", "`bondc/units.py`, `bondc/semantic/`"),
    ("Names, expressions, files and experiments", "`bondc/semantic/`, `bondc/evaluate.py`"),
    ("Graph structure", "`bondc/semantic/`"),
    ("Element laws and states", "`bondc/semantic/`"),
    ("Causality", "`bondc/causality.py`, `bondc/equations/`"),
    ("Equations", "`bondc/equations/`, `bondc/symbolic.py`"),
    ("Simulation", "`bondc/simulate.py`, `bondc/runtime/`"),
    ("Analyses and data files", "`bondc/analysis/`"),
    ("Validation against measured data", "`bondc/analysis/validate.py`"),
    ("Export: C code and FMUs", "`bondc/export/`"),
    ("Calibration", "`bondc/analysis/fit.py`, `bondc/analysis/fit_write.py`"),
    ("Command line and files", "`bondc/cli.py`, `bondc/commands.py`, `bondc/io.py`, `bondc/errors.py`"),
)


def stage_of(code: str) -> str:
    """The stage a code belongs to, by its number (W304 is about the graph; the other W3xx about names)."""
    number = int(code[1:])
    if code == "W304":
        return "Graph structure"
    if number < 100:
        return "Command line and files"
    if 950 <= number < 960:
        return "Validation against measured data"
    if 840 <= number < 860:
        return "Export: C code and FMUs"
    if 880 <= number < 900:
        return "Calibration"
    by_hundred = {1: "Syntax", 2: "Units", 3: "Names, expressions, files and experiments", 4: "Graph structure",
                  5: "Element laws and states", 6: "Causality", 7: "Equations", 8: "Simulation",
                  9: "Analyses and data files"}
    return by_hundred[number // 100]


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchor(code: str) -> str:
    """The anchor of ``code``'s section on docs/diagnostics.md (``e201-unknown-unit``); the code
    alone, lower case, for a code the registry lacks."""
    entry = CODES.get(code)
    return slug(f"{code} {entry.title}") if entry is not None else code.lower()
