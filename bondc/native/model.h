/* The model's functions that bondc's CVODE driver (driver.c) calls. bondc's code generation writes them
   (bondc.codegen.emit) in the model's C text, which comes before the driver's in the model's library
   (bondc.runtime: _NATIVE_FUNCTIONS). Each evaluates at time t and state x, with the parameters p and
   the modes m frozen, into out: the derivatives, the Jacobian's entries (JACOBIAN_PATTERN's order),
   the switching functions, the when clauses' conditions, and the new values of their targets. */
#ifndef BONDC_MODEL_H
#define BONDC_MODEL_H

void bondc_rhs(double t, const double *x, const double *p, const double *m, double *out);
void bondc_jac(double t, const double *x, const double *p, const double *m, double *out);
void bondc_switches(double t, const double *x, const double *p, const double *m, double *out);
void bondc_when_conditions(double t, const double *x, const double *p, const double *m, double *out);
void bondc_when_actions(double t, const double *x, const double *p, const double *m, double *out);

#endif
