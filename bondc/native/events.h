/* The when clauses in bondc's engine (events.c): which of them fire at an instant and the state after
   them, and when their firings accumulate (Zeno behaviour). One implementation, built three ways as
   filippov.c is: into a model's library with the CVODE driver (driver.c includes it), into an FMU's
   binary, and into the run loop's policy library (bondc.runtime.native.load_policy), which calls a
   numpy model's functions back. cffi's cdef reads this text: declarations and comments only, no
   preprocessor lines. It follows filippov.h, whose bondc_law_function it uses. */

/* A model's when clauses: `count` of them, clause k setting the states targets[target_start[k]] ...
   targets[target_start[k + 1] - 1]. `conditions` evaluates every clause's condition (not 0 where it
   holds), `actions` the new value of every clause's every target in that order (target_start[count]
   values), both at (t, x) with the parameters p and the modes m frozen. */
typedef struct bondc_whens {
    int count;
    const int *target_start, *targets;
    bondc_law_function conditions, actions;
} bondc_whens;

/* One round of the when clauses at time t and state y (n states): a clause fires where its condition
   was false before (`before`: the conditions as last evaluated, with the modes before this instant or
   after the previous round) and holds now, with the modes m (evaluated into `after`). The clauses that
   fire set their targets in the order written, every statement from the values just before (at y), into
   y_new (y elsewhere); fired[k] is 1 for a clause that fired, 0 else. `values`: target_start[count]
   values of work space. Returns how many fired (0: y_new is y), or -1 where the state after them is not
   finite. The next round's `before` is this round's `after`. */
int bondc_when_round(const bondc_whens *w, int n, double t, const double *y, const double *p, const double *before,
                     const double *m, double *after, double *y_new, int *fired, double *values);

/* The most rounds of when clauses at one instant: a clause that still fires after them makes another
   (or its own) condition true again, and the run stops there. */
int bondc_when_rounds(void);

/* The firings of one when clause accumulate (Zeno behaviour: a bouncing ball coming to rest) where its
   last bondc_zeno_firings() firing times (`times`, `count` of them, oldest first; fewer: no) came at
   intervals each at most 0.98 of the one before (geometric: the cycles of a frequency sweep shorten far
   more slowly), the last shorter than 1e-4 of the run's `span`, and the geometric limit of the intervals
   lies before the run's end t_end. Returns 1 then (*limit: that time, *ratio: the intervals' mean
   ratio), else 0. */
int bondc_zeno(int count, const double *times, double span, double t_end, double *limit, double *ratio);
int bondc_zeno_firings(void);
