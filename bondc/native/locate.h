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

/* The earliest crossing in the step (t_old, t_new] of the `watched` switches watch[j], as
   _Run.crossing finds it: values(t) gives all `switches` switching functions on the step's
   interpolant (the modes frozen); signs[j] is switch watch[j]'s mode, band[j] its deadband, old[j]
   and now[j] its values at the step's ends; floors[k] marks a switch whose mode is floor(g). A switch
   in mode +-1 crosses where m*g + band falls below 0 (the zero itself located where it lies in the
   step), a floor switch where g leaves [m, m + 1) by its band, one in mode 0 where |g| passes its
   band; where none changed sign at the step's ends, one that dips and comes back inside it
   (bondc_first_dip, then its surface). Returns j (the earliest, the first of equals), -1 where none
   crossed, -2 where memory ran out; the time into *t_event. */
int bondc_first_crossing(bondc_values_at values, void *context, int switches, int watched, const int *watch,
                         const int *floors, const double *signs, const double *band, const double *old,
                         const double *now, double t_old, double t_new, double *t_event);
