/* Where values that stay positive while nothing happens first fail to (locate.c): a sliding mode's
   exits (its weights and 1 minus them, the other switches' distances to their surfaces), a switch
   that crosses and comes back within one step. One implementation, for the CVODE driver, an FMU's
   engine and the Python run loop (through cffi, with the values called back). cffi's cdef reads
   this text: declarations and comments only, no preprocessor lines. */

/* The `count` values at t into out: 0, or not 0 where they cannot be had (then they are NaN) */
typedef int (*bondc_values_at)(void *context, double t, double *out);

/* Whether a value positive at both ends of a step may dip below 0 inside it: it failed at the
   middle, or the parabola through (left, mid, right) comes within its curvature of 0 in between. */
int bondc_may_dip(double left, double mid, double right);

/* The earliest end inside the step (t_old, t_new] of values `old` at t_old and `now` at t_new: where
   one went from > 0 to <= 0 or from >= 0 to < 0, located on values(t) by the Illinois method to 4
   eps. The values are also tested every `longest` (0: only at the ends) and, between two tests, for
   a dip (bondc_may_dip, the halves searched in turn, at most 60 evaluations). 0 with *t_end, 1
   where nothing ends in the step, -1 where memory ran out. */
int bondc_first_end(bondc_values_at values, void *context, int count, double t_old, double t_new, const double *old,
                    const double *now, double longest, double *t_end);

/* Only the dip search of bondc_first_end, on (a, b) with values left and right positive at its
   ends: 0 with *t_end, 1 where none dips, -1 where memory ran out. */
int bondc_first_dip(bondc_values_at values, void *context, int count, double a, double b, const double *left,
                    const double *right, double *t_end);
