"""The generated module's C code: a :class:`~bondc.codegen.module._Emitter` -> the C source
of its right-hand side, Jacobian, switching functions and algebraic loops
(:class:`_NativeEmitter`, ``NATIVE_SOURCE``), or why it has none.
"""

from __future__ import annotations

from bondc.codegen.cprinter import LOOP_PRELUDE, PRELUDE, NativePrinter, c_name
from bondc.codegen.module import _INDENT, _Emitter
from bondc.codegen.printer import UnsupportedExpression
from bondc.runtime import LOOP_START_OFFSETS, UNIT_MARK


class _NativeEmitter(_Emitter):
    """The right-hand side, Jacobian and switching functions as C (``NATIVE_SOURCE``).

    Same plan, same statements and common subexpressions as the numpy functions, printed by
    :class:`~bondc.codegen.cprinter.NativePrinter` into three C functions of one signature::

        void bondc_rhs(double t, const double *x, const double *p, const double *m, double *out)

    ``bondc_jac`` writes the Jacobian's entries in JACOBIAN_PATTERN order. Every name is a C
    identifier made from the numpy module's (already sanitised) names; no model text is copied.
    A nonlinear algebraic loop is solved inside each function by Newton's method
    (:meth:`loop_lines`), and its sensitivities dz/dx by an LU solve (``LOOP_PRELUDE``).
    """

    def __init__(self, emitter: _Emitter):
        self.__dict__.update(emitter.__dict__)
        ss = self.plan.ss
        names = {}
        for index, (symbol, name) in enumerate(emitter.names.items()):
            if symbol in self.modes or symbol == ss.time:
                names[symbol] = name        # m[k], t
            else:
                names[symbol] = c_name(name, index)
        for symbol, source in self.aliases.items():      # a copy has its source's C name too
            names[symbol] = names[source]
        self.names = names

    time_line = ""          # C's t is a double: no line that makes it one

    def printer(self, extra_frozen=()):
        return NativePrinter(self.names)

    @staticmethod
    def assign_line(name: str, text: str) -> str:
        return f"const double {name} = {text};"

    #: Newton iterations of a nonlinear algebraic loop in C (from its guesses)
    LOOP_ITERATIONS = 50
    #: iterations of the loop's second attempt, Newton's method with a line search
    LOOP_SEARCHES = 100

    def statement_lines(self, statement, exprs, printer):
        if statement.kind == "assign":
            return [self.assign_line(self.names[statement.defines[0]], self.text(printer, exprs[0]))]
        if statement.kind == "block":
            return self.loop_lines(statement, printer)
        return self.loop_sensitivity_lines(statement, exprs, printer)

    def loop_lines(self, statement, printer) -> list:
        """A nonlinear algebraic loop R(z) = 0 solved in C by Newton's method with its analytic
        dR/dz, from its guesses at every call (no state kept between calls: a run never depends on
        the runs or calls before it). Converged: the Newton step is below 1e-12 of the unknowns'
        size.

        Where plain Newton does not converge in 50 iterations (an exponential law far from its
        root moves by one e-fold per step; a step that leaves a law's range), a second attempt
        starts again from the guesses with a line search on max |R|: a step that does not lower
        it is halved, and one that lowers it to more than a tenth is doubled while it keeps lowering
        it (``runtime.newton_search``, the same method in numpy). Where R is not finite at the
        guesses (a law's exponential overflows there), the search starts from the first of the
        guesses plus ``LOOP_START_OFFSETS`` (added to every unknown) where it is finite. Where
        dR/dz is singular or no step lowers the residual, and that is at rounding level (below
        1e-10 of the unknowns' size: a node floating between reverse-biased diodes), that is the
        root. Where the search fails otherwise (100 iterations), the unknowns are nan and the
        runtime evaluates that point with the numpy module."""
        unknowns = statement.defines
        size = len(unknowns)
        names = [self.names[u] for u in unknowns]
        residuals = statement.data["residuals"]
        slopes = statement.data["slopes"]       # dR/dz, row by row (from the Jacobian's plan)
        text = lambda expr: self.text(printer, expr)     # noqa: E731
        residual_texts = [text(r) for r in residuals]
        slope_texts = [text(slope) for slope in slopes]
        guesses = [f"    bondc_z[{i}] = {text(guess)};" for i, guess in enumerate(statement.data["guesses"])]

        def evaluate(into, indent, source="bondc_z"):      # the unknowns' names from `source`, R into `into`
            return ([f"{indent}{name} = {source}[{i}];" for i, name in enumerate(names)]
                    + [f"{indent}{into}[{i}] = {r};" for i, r in enumerate(residual_texts)])

        def factor(indent, singular="break;"):      # dR/dz at the unknowns' names, factorised
            return ([f"{indent}bondc_a[{i}] = {slope};" for i, slope in enumerate(slope_texts)]
                    + [f"{indent}if (bondc_lu({size}, bondc_a, bondc_piv) != 0) {singular}"])

        # the search's end where it cannot go on: a root if the residual is at rounding level
        at_rounding = (f"{{ double bondc_largest = 1.0; for (int i = 0; i < {size}; i++) "
                       "bondc_largest = fmax(bondc_largest, fabs(bondc_z[i])); "
                       "if (bondc_norm <= 1e-10 * bondc_largest) bondc_done = 1; break; }")

        lines = [f"/* algebraic loop {statement.data['number']}: Newton's method from its guesses */",
                 f"double {', '.join(names)};",
                 "{",
                 f"    double bondc_z[{size}], bondc_r[{size}], bondc_a[{size * size}];",
                 f"    int bondc_piv[{size}], bondc_done = 0;"]
        lines += guesses
        lines.append(f"    for (int bondc_k = 0; bondc_k < {self.LOOP_ITERATIONS}; bondc_k++) {{")
        lines += evaluate("bondc_r", "        ")
        lines += factor("        ")
        lines += [f"        bondc_lu_solve({size}, bondc_a, bondc_piv, bondc_r);",
                  "        double bondc_step = 0.0, bondc_size = 0.0;",
                  "        int bondc_finite = 1;",
                  f"        for (int i = 0; i < {size}; i++) {{",
                  "            bondc_z[i] -= bondc_r[i];",
                  "            if (!isfinite(bondc_z[i])) bondc_finite = 0;",
                  "            bondc_step = fmax(bondc_step, fabs(bondc_r[i]));",
                  "            bondc_size = fmax(bondc_size, fabs(bondc_z[i]));",
                  "        }",
                  "        if (!bondc_finite) break;",
                  "        if (bondc_step <= 1e-12 * (1.0 + bondc_size)) { bondc_done = 1; break; }",
                  "    }"]
        if self.LOOP_SEARCHES:
            offsets = ", ".join(f"{offset:g}" for offset in LOOP_START_OFFSETS)
            lines += ["    if (!bondc_done) {     /* again from the guesses, with a line search on max |R| */",
                      f"        static const double bondc_offsets[{len(LOOP_START_OFFSETS)}] = {{{offsets}}};",
                      f"        double bondc_d[{size}], bondc_t[{size}], bondc_q[{size}], bondc_b[{size}];",
                      "        double bondc_norm = INFINITY;",
                      "        /* from the first of guesses + offset where R is finite */",
                      f"        for (int bondc_o = 0; bondc_o < {len(LOOP_START_OFFSETS)} && !isfinite(bondc_norm); bondc_o++) {{"]
            lines += ["        " + line[:-1] + " + bondc_offsets[bondc_o];" for line in guesses]
            lines += evaluate("bondc_r", "            ")
            lines += ["            bondc_norm = 0.0;",
                      f"            for (int i = 0; i < {size}; i++) bondc_norm = fmax(bondc_norm, fabs(bondc_r[i]));",
                      "            if (bondc_norm != bondc_norm) bondc_norm = INFINITY;",
                      "        }",
                      f"        for (int bondc_k = 0; bondc_k < {self.LOOP_SEARCHES} && isfinite(bondc_norm); bondc_k++) {{"]
            lines += [f"            {name} = bondc_z[{i}];" for i, name in enumerate(names)]
            lines += factor("            ", at_rounding)
            lines += [f"            for (int i = 0; i < {size}; i++) bondc_d[i] = bondc_r[i];",
                      f"            bondc_lu_solve({size}, bondc_a, bondc_piv, bondc_d);",
                      "            double bondc_step = 0.0, bondc_size = 0.0;",
                      f"            for (int i = 0; i < {size}; i++) {{",
                      "                bondc_step = fmax(bondc_step, fabs(bondc_d[i]));",
                      "                bondc_size = fmax(bondc_size, fabs(bondc_z[i] - bondc_d[i]));",
                      "            }",
                      "            if (!isfinite(bondc_step)) break;",
                      "            if (bondc_step <= 1e-12 * (1.0 + bondc_size)) {",
                      f"                for (int i = 0; i < {size}; i++) bondc_z[i] -= bondc_d[i];",
                      "                bondc_done = 1;",
                      "                break;",
                      "            }",
                      "            double bondc_alpha = 1.0, bondc_best = 0.0, bondc_least = bondc_norm;",
                      "            int bondc_shrunk = 0;",
                      "            for (int bondc_s = 0; bondc_s < 60; bondc_s++) {",
                      f"                for (int i = 0; i < {size}; i++) bondc_t[i] = bondc_z[i] - bondc_alpha * bondc_d[i];"]
            lines += evaluate("bondc_q", "                ", "bondc_t")
            lines += ["                double bondc_tried = 0.0;",
                      f"                for (int i = 0; i < {size}; i++) bondc_tried = fmax(bondc_tried, fabs(bondc_q[i]));",
                      "                if (bondc_tried < bondc_least) {      /* false for nan */",
                      "                    bondc_best = bondc_alpha;",
                      "                    bondc_least = bondc_tried;",
                      f"                    for (int i = 0; i < {size}; i++) bondc_b[i] = bondc_q[i];",
                      "                    if (!bondc_shrunk && (bondc_alpha > 1.0 || bondc_tried > 0.1 * bondc_norm)) { bondc_alpha *= 2.0; continue; }",
                      "                    break;",
                      "                }",
                      "                if (bondc_best > 0.0) break;",
                      "                bondc_alpha *= 0.5;",
                      "                bondc_shrunk = 1;",
                      "            }",
                      f"            if (!(bondc_best > 0.0)) {at_rounding}",
                      f"            for (int i = 0; i < {size}; i++) {{",
                      "                bondc_z[i] -= bondc_best * bondc_d[i];",
                      "                bondc_r[i] = bondc_b[i];",
                      "            }",
                      "            bondc_norm = bondc_least;",
                      "        }",
                      "    }"]
        lines.append(f"    if (!bondc_done) for (int i = 0; i < {size}; i++) bondc_z[i] = NAN;")
        lines += [f"    {name} = bondc_z[{i}];" for i, name in enumerate(names)]
        lines.append("}")
        return lines

    def loop_sensitivity_lines(self, statement, exprs, printer) -> list:
        """dz/dx = -(dR/dz)^-1 dR/dx of an algebraic loop, for the columns the Jacobian reads (nan
        where dR/dz is singular)."""
        number, size = statement.data["number"], statement.data["size"]
        rz, rx = exprs[: size * size], exprs[size * size:]
        columns = sorted({j for _, j in statement.data["rx_keys"]})
        where = {j: q for q, j in enumerate(columns)}
        count = len(columns)
        table = f"bondc_dz{number}"
        lines = [f"/* algebraic loop {number}: dz/dx = -(dR/dz)^-1 dR/dx */",
                 f"double {table}[{max(size * count, 1)}];",
                 "{",
                 f"    double bondc_a[{size * size}], bondc_b[{max(size * count, 1)}];",
                 f"    int bondc_piv[{size}];"]
        lines += [f"    bondc_a[{i}] = {self.text(printer, value)};" for i, value in enumerate(rz)]
        lines.append(f"    for (int i = 0; i < {max(size * count, 1)}; i++) bondc_b[i] = 0.0;")
        lines += [f"    bondc_b[{i * count + where[j]}] = -({self.text(printer, value)});"
                  for (i, j), value in zip(statement.data["rx_keys"], rx)]
        lines += [f"    if (bondc_lu({size}, bondc_a, bondc_piv) != 0) {{",
                  f"        for (int i = 0; i < {max(size * count, 1)}; i++) {table}[i] = NAN;",
                  "    } else {",
                  f"        for (int q = 0; q < {count}; q++) {{",
                  f"            double bondc_column[{size}];",
                  f"            for (int i = 0; i < {size}; i++) bondc_column[i] = bondc_b[i * {count} + q];",
                  f"            bondc_lu_solve({size}, bondc_a, bondc_piv, bondc_column);",
                  f"            for (int i = 0; i < {size}; i++) {table}[i * {count} + q] = bondc_column[i];",
                  "        }",
                  "    }",
                  "}"]
        for symbol in statement.defines:
            l, j = statement.data["cells"][symbol]
            lines.append(self.assign_line(self.names[symbol], f"{table}[{l * count + where[j]}]"))
        return lines


    def c_function(self, name, statements, finals) -> str:
        lines, texts, used = self.body(statements, finals)
        out = [f"void {name}(double t, const double *x, const double *p, const double *m, double *out)", "{",
               f"{_INDENT}(void)t; (void)x; (void)p; (void)m;"]
        out += [_INDENT + line for line in self.unpack(used) + lines]
        out += [f"{_INDENT}out[{k}] = {text};" for k, text in enumerate(texts)]
        return "\n".join(out + ["}"])

    def c_when_functions(self) -> list:
        """``bondc_when_conditions`` (each when clause's condition with the modes m: held where not 0) and
        ``bondc_when_actions`` (the new values of every clause's targets, clause after clause, from
        the values at (t, x)), as the numpy module's ``_when_conditions`` and ``_when_action_k``;
        ``bondc_when_native`` says whether they are (0: a statement C cannot print, or no clause)."""
        plan = self.plan
        conditions = [condition for _, condition, _ in plan.events]    # held where not 0 (bool())
        values = [value for _, _, actions in plan.events for _, value in actions]
        native = 1 if plan.events else 0
        try:
            parts = [self.c_function("bondc_when_conditions", plan.statements, conditions),
                     self.c_function("bondc_when_actions", plan.statements, values)]
        except UnsupportedExpression:
            parts, native = [self.c_function("bondc_when_conditions", [], []),
                             self.c_function("bondc_when_actions", [], [])], 0
        return parts + [f"int bondc_when_native(void) {{ return {native}; }}"]

    @staticmethod
    def c_points(name: str, n: int, size: int) -> str:
        """``name`` at ``count`` points: ``x`` holds each point's ``n`` states in a row, ``out``
        each point's ``size`` values in a row."""
        return "\n".join([
            f"void {name}_at(int count, const double *t, const double *x, const double *p, const double *m, double *out)",
            "{",
            f"{_INDENT}for (int j = 0; j < count; j++)",
            f"{_INDENT}{_INDENT}{name}(t[j], x + (long)j * {n}, p, m, out + (long)j * {size});",
            "}"])

    def native_source(self) -> tuple:
        """(C source, "") or ("", why the model has no native code)."""
        plan = self.plan
        pattern = sorted(plan.jacobian_entries, key=lambda key: (key[1], key[0]))
        # a model with a nonlinear algebraic loop is evaluated point by point (its loop solved at
        # each): its functions also over many points in one call (``<name>_at``)
        n = len(plan.derivatives)
        at = (lambda name, size: "\n\n" + self.c_points(name, n, size)) if plan.blocks else (lambda name, size: "")
        switches = [s.g for s in plan.switches]
        try:
            parts = [PRELUDE + (LOOP_PRELUDE if plan.blocks else ""),
                     self.c_function("bondc_rhs", plan.statements, plan.derivatives) + at("bondc_rhs", n),
                     self.c_function("bondc_jac", plan.jacobian_statements,
                                     [plan.jacobian_entries[key] for key in pattern]),
                     self.c_function("bondc_switches", plan.statements, switches)
                     + at("bondc_switches", len(switches))]
        except UnsupportedExpression as error:
            return "", str(error)
        parts += self.c_when_functions()
        if plan.blocks:
            # its outputs and variables in C too (the loop solved there), where C can print them
            outputs, variables = [expr for _, expr in plan.outputs], [symbol for _, symbol, _ in plan.variables]
            try:
                parts += [self.c_function("bondc_outputs", plan.statements, outputs)
                          + at("bondc_outputs", len(outputs)),
                          self.c_function("bondc_variables", plan.statements, variables)
                          + at("bondc_variables", len(variables))]
            except UnsupportedExpression:
                pass
        # each function may be compiled on its own (runtime._native_units: a large model's
        # functions are built in parallel); the prelude comes first in every unit
        return ("\n\n" + UNIT_MARK).join(parts) + "\n", ""


def native_source(emitter: _Emitter) -> tuple[str, str]:
    """(C source, "") of ``emitter``'s model, or ("", why it has none): :meth:`_NativeEmitter.native_source`."""
    return _NativeEmitter(emitter).native_source()
