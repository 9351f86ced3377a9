/* ---- bondc's CVODE driver: integrates with the model's C functions, no Python per step ----

   bondc builds this file into a model's library wherever scikit-sundae's SUNDIALS libraries can be
   linked (bondc.runtime.load_native): after the model's own C text, with BONDC_INDEX_TYPE defined and
   each #include "..." of this folder replaced by that file's text, so that the text compiled (and
   hashed for the cache of built libraries) is one. The model's text comes first and defines the
   functions model.h declares. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sundials.h"   /* the SUNDIALS functions this driver calls */
#include "model.h"      /* the model's functions this driver calls */
#include "erk_api.h"    /* the table of functions of bondc's explicit stepper (erk.cpp, a library of its own) */
#include "driver.h"     /* this driver's functions, as Python calls them (through cffi) */
#include "filippov.c"   /* Filippov sliding: the sliding set, the corners' weights, the deadbands */
#include "events.c"     /* the when clauses: which fire, the state after them, Zeno */
#include "locate.c"     /* where values that stay positive first fail to: exits, dips */

struct bondc_driver {
    void *cvode;
    bondc_law law;      /* the model's laws as filippov.c calls them */
    /* the explicit stepper that integrates instead of CVODE (bondc_driver_explicit), or NULL */
    const bondc_erk_api *erk;
    void *erk_memory;
    SUNContext ctx;
    N_Vector y, work;
    SUNMatrix a;
    SUNLinearSolver ls;
    int n, switches, entries, banded, lower, upper, started, bad;
    double longest;     /* a sliding step longer than this goes back to the runtime (0: none) */
    const int *rows, *cols;
    double *p, *m, *g, *values, *gmid;
    double t_stop;
    /* a Filippov sliding mode on switch `slide` (-1: none), between the corners mp (side +) and
       mm (side -): see bondc_driver_slide */
    int slide, exits;
    const int *others;
    const double *drift;
    double *mp, *mm, *fp, *fm, *shifted, *extra;
    double probe, alpha;
    double *scratch, *ahead;    /* modes being found (driver_modes_at), those a probe ahead */
    /* a sliding mode on `held` > 1 switches `sliding`: the `corners` mode vectors cm (each
       d->switches long), affine (k + 1 corners) or multilinear (2^k): see bondc_driver_slide_many */
    int held, corners, affine;
    int *sliding;
    double *cm, *cf, *rates, *alphas, *weights, *newton, *delta, *kept;
    /* the unfrozen law (a chattering interval): the modes found again, from the last ones, at every
       evaluation (driver_modes_at with the floor switches `floors`): see bondc_driver_unfrozen_advance */
    int unfrozen;
    const int *floors;
};

/* Whether every value is finite: no exponent field all ones, tested on the bits (integer work the
   compiler vectorises; an isfinite per value that returns at the first failure was a tenth of an
   explicit run, which tests six evaluations a step) */
static int driver_finite(const double *v, int n)
{
    unsigned long long bad = 0;
    for (int i = 0; i < n; i++) {
        unsigned long long bits;
        memcpy(&bits, v + i, sizeof bits);
        bad |= (~bits & 0x7ff0000000000000ULL) == 0;
    }
    return !bad;
}

/* d g_slide / dt along the rate f in corner m: a central difference over the probe step
   (as _Run.switch_rate) */
static double slide_rate(bondc_driver *d, double t, const double *y, const double *f, const double *m)
{
    double h = d->probe;
    for (int i = 0; i < d->n; i++) d->shifted[i] = y[i] + h * f[i];
    bondc_switches(t + h, d->shifted, d->p, m, d->g);
    double ahead = d->g[d->slide];
    for (int i = 0; i < d->n; i++) d->shifted[i] = y[i] - h * f[i];
    bondc_switches(t - h, d->shifted, d->p, m, d->g);
    double behind = d->g[d->slide];
    return (ahead - behind) / (2 * h);
}

/* The sliding weight at (t, y), as _Run.solve_alpha for one switch: the alpha that makes
   alpha*rate+ + (1 - alpha)*rate- zero (not clipped), the last one where both rates are equal,
   NaN where a rate is not finite. Leaves the corners' right-hand sides in d->fp and d->fm. */
static double slide_alpha(bondc_driver *d, double t, const double *y)
{
    bondc_rhs(t, y, d->p, d->mp, d->fp);
    bondc_rhs(t, y, d->p, d->mm, d->fm);
    double rates[2] = {slide_rate(d, t, y, d->fm, d->mm), slide_rate(d, t, y, d->fp, d->mp)}, alpha;
    /* filippov.c's weight: corner 0 the minus side, 1 the plus side (one switch: no work space) */
    if (bondc_filippov_alpha_in(1, 0, rates, &d->alpha, &alpha, NULL) != 0) return NAN;
    if (isfinite(alpha)) d->alpha = alpha;
    return alpha;
}

static double clip01(double a) { return a < 0 ? 0.0 : (a > 1 ? 1.0 : a); }

/* The sliding weights at (t, y) of a mode on several switches, as _Run.solve_alpha: Newton's
   method from the last weights (clipped) on the rates of the sliding switches, multilinear in the
   weights (exactly linear in the affine combination). Leaves the corners' right-hand sides in
   d->cf and the weights of the corners (from the clipped alphas) in d->weights; d->alphas holds
   the new weights when they are finite. 0 on success, -1 where a rate or a weight is not finite or
   the system is singular. */
static int many_alphas(bondc_driver *d, double t, const double *y)
{
    int k = d->held, n = d->n;
    double h = d->probe;
    for (int c = 0; c < d->corners; c++) {
        const double *m = d->cm + (long)c * d->switches;
        double *f = d->cf + (long)c * n;
        bondc_rhs(t, y, d->p, m, f);
        for (int i = 0; i < n; i++) d->shifted[i] = y[i] + h * f[i];
        bondc_switches(t + h, d->shifted, d->p, m, d->g);
        for (int j = 0; j < k; j++) d->rates[c * k + j] = d->g[d->sliding[j]];
        for (int i = 0; i < n; i++) d->shifted[i] = y[i] - h * f[i];
        bondc_switches(t - h, d->shifted, d->p, m, d->g);
        for (int j = 0; j < k; j++) {
            double rate = (d->rates[c * k + j] - d->g[d->sliding[j]]) / (2 * h);
            if (!isfinite(rate)) return -1;
            d->rates[c * k + j] = rate;
        }
    }
    double *a = d->delta + k;       /* the weights being solved for (filippov.c's Newton iteration) */
    if (bondc_filippov_alpha_in(k, d->affine, d->rates, d->alphas, a, d->newton) != 0) return -1;
    for (int i = 0; i < k; i++) {
        if (!isfinite(a[i])) return -1;
        d->alphas[i] = a[i];
        d->delta[i] = clip01(a[i]);
    }
    bondc_corner_weights(k, d->affine, d->delta, d->weights);
    return 0;
}

static int driver_modes_at(bondc_driver *d, double t, const double *y, const double *guess, const int *floors,
                           double *out);

/* The segment's rates at (t, y) into out: the frozen law, the sliding mode's combination or the
   unfrozen law; -1 (d->bad set) where they are not finite: numpy's runtime takes over */
static int driver_rates(double t, const double *y, double *out, void *data)
{
    bondc_driver *d = (bondc_driver *)data;
    /* a time that is not finite: CVODE's step size overflowed (a derivative near the largest
       float); SUNDIALS would go on with nan forever */
    if (!isfinite(t)) { d->bad = 1; return -1; }
    if (d->slide >= 0) {
        double w = clip01(slide_alpha(d, t, y));
        for (int i = 0; i < d->n; i++) out[i] = (1 - w) * d->fm[i] + w * d->fp[i];
    } else if (d->held > 1) {
        if (many_alphas(d, t, y) != 0) { d->bad = 1; return -1; }
        for (int i = 0; i < d->n; i++) {
            double sum = 0.0;
            for (int c = 0; c < d->corners; c++) sum += d->weights[c] * d->cf[(long)c * d->n + i];
            out[i] = sum;
        }
    } else {
        if (d->unfrozen) driver_modes_at(d, t, y, d->m, d->floors, d->m);
        bondc_rhs(t, y, d->p, d->m, out);
        /* the explicit stepper finds a rate that is not finite in its error estimate, which every
           stage's rate enters (then it fails the step as this would): a test of every evaluation
           was a tenth of its run */
        if (d->erk) return 0;
    }
    if (!driver_finite(out, d->n)) { d->bad = 1; return -1; }
    return 0;
}

static int driver_rhs(sunrealtype t, N_Vector y, N_Vector ydot, void *data)
{
    return driver_rates(t, N_VGetArrayPointer(y), N_VGetArrayPointer(ydot), data);
}

/* One step of the segment's integrator towards d->t_stop, its state into d->y: 0, or CVODE's
   negative flag (the explicit stepper's failures as CVODE's: -8 a right-hand side that failed, -3
   a step size at rounding, -1 too many steps) */
static int driver_step(bondc_driver *d, double *t)
{
    if (d->erk) {
        int flag = d->erk->step(d->erk_memory, t, N_VGetArrayPointer(d->y));
        if (flag == -1) d->bad = 1;     /* a rate not finite at a trial point: numpy's runtime takes over */
        return flag == 0 ? 0 : (flag == -1 ? -8 : (flag == -3 ? -1 : -3));
    }
    int flag = CVode(d->cvode, d->t_stop, d->y, t, 2);
    return flag < 0 ? flag : 0;
}

/* The state at t inside the last step into d->work (the integrator's interpolant): 0 on success */
static int driver_interpolate(bondc_driver *d, double t)
{
    if (d->erk) return d->erk->dky(d->erk_memory, t, N_VGetArrayPointer(d->work));
    return CVodeGetDky(d->cvode, t, 0, d->work);
}

/* The length of the last step into h: 0 on success */
static int driver_last_step(bondc_driver *d, double *h)
{
    if (d->erk) { *h = d->erk->last_step(d->erk_memory); return 0; }
    return CVodeGetLastStep(d->cvode, h);
}

/* The Jacobian's entries (the pattern's order) at (t, y) into d->values, as the segment integrates:
   the frozen modes' law, a sliding mode's corners weighted as their right-hand sides, or the unfrozen
   law's modes found again: 0, -1 (d->bad = 2) where a weight or an entry is not finite */
static int driver_jac_values(bondc_driver *d, double t, const double *y)
{
    if (!isfinite(t)) { d->bad = 2; return -1; }
    if (d->slide >= 0) {        /* the corners' Jacobians, weighted as their right-hand sides */
        double w = clip01(slide_alpha(d, t, y));
        if (w != w) { d->bad = 2; return -1; }
        for (int k = 0; k < d->entries; k++) d->values[k] = 0.0;
        if (1 - w != 0) {
            bondc_jac(t, y, d->p, d->mm, d->extra);
            for (int k = 0; k < d->entries; k++) d->values[k] += (1 - w) * d->extra[k];
        }
        if (w != 0) {
            bondc_jac(t, y, d->p, d->mp, d->extra);
            for (int k = 0; k < d->entries; k++) d->values[k] += w * d->extra[k];
        }
    } else if (d->held > 1) {
        if (many_alphas(d, t, y) != 0) { d->bad = 2; return -1; }
        for (int k = 0; k < d->entries; k++) d->values[k] = 0.0;
        for (int c = 0; c < d->corners; c++) {
            if (d->weights[c] == 0) continue;
            bondc_jac(t, y, d->p, d->cm + (long)c * d->switches, d->extra);
            for (int k = 0; k < d->entries; k++) d->values[k] += d->weights[c] * d->extra[k];
        }
    } else {
        if (d->unfrozen) driver_modes_at(d, t, y, d->m, d->floors, d->m);
        bondc_jac(t, y, d->p, d->m, d->values);
    }
    if (!driver_finite(d->values, d->entries)) { d->bad = 2; return -1; }
    return 0;
}

static int driver_jac(sunrealtype t, N_Vector y, N_Vector fy, SUNMatrix jac, void *data,
                      N_Vector t1, N_Vector t2, N_Vector t3)
{
    bondc_driver *d = (bondc_driver *)data;
    (void)fy; (void)t1; (void)t2; (void)t3;
    if (driver_jac_values(d, t, N_VGetArrayPointer(y)) != 0) return -1;
    SUNMatZero(jac);
    for (int k = 0; k < d->entries; k++) {
        if (d->banded)
            SUNBandMatrix_Column(jac, d->cols[k])[d->rows[k] - d->cols[k]] = d->values[k];
        else
            SUNDenseMatrix_Column(jac, d->cols[k])[d->rows[k]] = d->values[k];
    }
    return 0;
}

/* Whether the segment integrates a sliding mode (whose weights change with the state: the corners'
   Jacobians weighted leave that out, and an implicit solver's Newton iteration can fail on them) */
int bondc_driver_sliding(bondc_driver *d)
{
    return d->slide >= 0 || d->held > 1;
}

/* The Jacobian's entries (the pattern's order) at (t, y) into out, as the segment integrates: for
   a stepper that is not CVODE (scipy's implicit solvers, bondc.runtime.steppers): 0, or -1 */
int bondc_driver_jac_entries(bondc_driver *d, double t, const double *y, double *out)
{
    if (driver_jac_values(d, t, y) != 0) return -1;
    for (int k = 0; k < d->entries; k++) out[k] = d->values[k];
    return 0;
}

bondc_driver *bondc_driver_new(int n, int switches, int entries, const int *rows, const int *cols,
                               int banded, int lower, int upper, int adams, double *p)
{
    bondc_driver *d = (bondc_driver *)calloc(1, sizeof(bondc_driver));
    if (!d) return NULL;
    d->n = n; d->switches = switches; d->entries = entries; d->rows = rows; d->cols = cols;
    d->banded = banded; d->lower = lower; d->upper = upper; d->p = p;
    d->law.n = n; d->law.switches = switches; d->law.p = p;
    d->law.rhs = bondc_rhs; d->law.switching = bondc_switches; d->law.vertices = NULL;
    d->m = (double *)calloc(switches + 1, sizeof(double));
    d->g = (double *)calloc(switches + 1, sizeof(double));
    d->values = (double *)calloc(entries + 1, sizeof(double));
    d->extra = (double *)calloc(entries + 1, sizeof(double));
    d->mp = (double *)calloc(switches + 1, sizeof(double));
    d->mm = (double *)calloc(switches + 1, sizeof(double));
    d->fp = (double *)calloc(n + 1, sizeof(double));
    d->fm = (double *)calloc(n + 1, sizeof(double));
    d->shifted = (double *)calloc(n + 1, sizeof(double));
    d->scratch = (double *)calloc(2 * (size_t)switches + 1, sizeof(double));      /* bondc_modes_at's */
    d->ahead = (double *)calloc(switches + 1, sizeof(double));
    d->gmid = (double *)calloc(switches + 1, sizeof(double));
    d->slide = -1;
    if (!d->m || !d->g || !d->values || !d->extra || !d->mp || !d->mm || !d->fp || !d->fm || !d->shifted
        || !d->scratch || !d->ahead || !d->gmid || SUNContext_Create(0, &d->ctx) != 0) return NULL;
    d->y = N_VNew_Serial(n, d->ctx);
    d->work = N_VNew_Serial(n, d->ctx);
    d->cvode = CVodeCreate(adams ? 1 : 2, d->ctx);
    if (!d->y || !d->work || !d->cvode) return NULL;
    if (banded < 0) return d;       /* the driver of an explicit stepper: no linear solver */
    /* Newton iteration (CVODE's default, for Adams too) needs a linear solver */
    d->a = banded ? SUNBandMatrix(n, upper, lower, d->ctx) : SUNDenseMatrix(n, n, d->ctx);
    d->ls = banded ? SUNLinSol_Band(d->y, d->a, d->ctx) : SUNLinSol_Dense(d->y, d->a, d->ctx);
    if (!d->a || !d->ls) return NULL;
    return d;
}

/* Integrate with the explicit stepper whose table is `api` (bondc_erk_table of erk.cpp's
   library) instead of CVODE, from the next start on: 0, -1 where it cannot be made */
int bondc_driver_explicit(bondc_driver *d, const void *api)
{
    const bondc_erk_api *table = (const bondc_erk_api *)api;
    if (!table || table->version != 1) return -1;
    void *memory = table->create(d->n);
    if (!memory) return -1;
    if (d->erk && d->erk_memory) d->erk->destroy(d->erk_memory);
    d->erk = table;
    d->erk_memory = memory;
    return 0;
}

/* Start (or restart) at (t0, y0) with modes m, towards t_stop. 0 on success. */
int bondc_driver_start(bondc_driver *d, double t0, const double *y0, const double *m, double t_stop,
                       double rtol, double atol, double max_step, double first_step, long max_steps)
{
    double *y = N_VGetArrayPointer(d->y);
    for (int i = 0; i < d->n; i++) y[i] = y0[i];
    for (int k = 0; k < d->switches; k++) d->m[k] = m[k];
    d->bad = 0;
    d->slide = -1;
    d->held = 0;
    d->unfrozen = 0;
    d->t_stop = t_stop;
    if (d->erk)
        return d->erk->start(d->erk_memory, driver_rates, d, t0, y, t_stop, rtol, atol, max_step, first_step,
                             max_steps);
    int flag;
    if (!d->started) {
        flag = CVodeInit(d->cvode, driver_rhs, t0, d->y);
        if (flag == 0) flag = CVodeSetUserData(d->cvode, d);
        if (flag == 0 && d->ls) flag = CVodeSetLinearSolver(d->cvode, d->ls, d->a);
        if (flag == 0 && d->ls) flag = CVodeSetJacFn(d->cvode, driver_jac);
        if (flag != 0) return flag;
        d->started = 1;
    } else if ((flag = CVodeReInit(d->cvode, t0, d->y)) != 0) {
        return flag;
    }
    if ((flag = CVodeSStolerances(d->cvode, rtol, atol)) != 0) return flag;
    if ((flag = CVodeSetMaxStep(d->cvode, max_step)) != 0) return flag;
    if ((flag = CVodeSetInitStep(d->cvode, first_step)) != 0) return flag;
    if ((flag = CVodeSetMaxNumSteps(d->cvode, max_steps)) != 0) return flag;
    return CVodeSetStopTime(d->cvode, t_stop);
}

/* Up to `capacity` internal steps, each stored in ts/ys. After each step the watched switching
   functions are compared with their values at the step before (g_old, updated in place): a
   switch in mode `signs[j]` (+1/-1) may have crossed when signs[j]*g + band[j] < 0, one in mode 0 when
   |g| > band[j] (the step loop's own test then decides).
   Returns 0: capacity reached; 1: a possible crossing in the last stored step (g_old still holds
   the values before it); 2: t_stop reached; 3: a law was not finite at a trial point (nothing
   of the failed attempt is stored); 4: the state is not finite; < 0: CVODE's error flag.
   A run reported at the times t_eval (n_eval of them, increasing; NULL: none) also stores, after
   each step that is kept (no possible crossing in it, its state finite), the states at the report
   times t_eval[*eval_next] <= t of that step, from CVODE's interpolant of the step (CVodeGetDky; the
   step's own state at its end), into et/ey (*eval_count of them, at most eval_capacity). Where that
   buffer fills, the batch ends after that step, and the report times of that step still left (from
   *eval_next on) are the caller's to take from bondc_driver_dky before the next batch. */
static int report_step(bondc_driver *d, double t, const double *y, const double *t_eval, int n_eval,
                       int *eval_next, int eval_capacity, double *et, double *ey, int *eval_count);


/* Whether a watched switch in mode +-1 may cross twice inside the step just taken (to t), where it is
   on its side at both ends (g_old, d->g): its value at the step's middle (CVODE's interpolant) is
   past its band, or the parabola through the three comes within its curvature of it (as _may_dip).
   The runtime then looks (_Run.crossing). */
static int switch_dips(bondc_driver *d, double t, int watched, const int *watch, const double *signs,
                       const double *band, const double *g_old)
{
    double h = 0.0;
    if (driver_last_step(d, &h) != 0 || !(h > 0)) return 0;
    if (driver_interpolate(d, t - 0.5 * h) != 0) return 0;
    bondc_switches(t - 0.5 * h, N_VGetArrayPointer(d->work), d->p, d->m, d->gmid);
    for (int j = 0; j < watched; j++)
        if (signs[j] != 0 && bondc_may_dip(signs[j] * g_old[j] + band[j], signs[j] * d->gmid[watch[j]] + band[j],
                                     signs[j] * d->g[watch[j]] + band[j])) return 1;
    return 0;
}

int bondc_driver_advance(bondc_driver *d, int capacity, int watched, const int *watch, const double *signs,
                         const double *band, double *g_old, double *ts, double *ys, int *count,
                         const double *t_eval, int n_eval, int *eval_next, int eval_capacity, double *et,
                         double *ey, int *eval_count)
{
    double *y = N_VGetArrayPointer(d->y);
    *count = 0;
    if (eval_count) *eval_count = 0;
    for (int k = 0; k < capacity; k++) {
        double t;
        int flag = driver_step(d, &t);
        if (flag < 0) return d->bad ? 3 : flag;
        ts[k] = t;
        for (int i = 0; i < d->n; i++) ys[(long)k * d->n + i] = y[i];
        *count = k + 1;
        if (!driver_finite(y, d->n)) return 4;
        if (watched) {
            int crossed = 0;
            bondc_switches(t, y, d->p, d->m, d->g);
            for (int j = 0; j < watched; j++) {
                if (signs[j] == 0) {        /* mode 0 (g was 0): a possible crossing once |g| leaves its band */
                    if (fabs(d->g[watch[j]]) > band[j]) crossed = 1;
                    continue;
                }
                double before = signs[j] * g_old[j] + band[j], after = signs[j] * d->g[watch[j]] + band[j];
                if (after < 0 || (after == 0 && before > 0)) crossed = 1;
            }
            if (crossed || switch_dips(d, t, watched, watch, signs, band, g_old)) return 1;
            for (int j = 0; j < watched; j++) g_old[j] = d->g[watch[j]];
        }
        int full = report_step(d, t, y, t_eval, n_eval, eval_next, eval_capacity, et, ey, eval_count);
        if (t >= d->t_stop) return 2;
        if (full) return 0;
    }
    return 0;
}

/* The modes of the unfrozen law at (t, y) into out, as the runtime's modes_at finds them: from
   `guess`, m = sign(g(t, y, m)) (floor(g) for a floor switch, 0 where g is nan) until it repeats,
   at most switches + 1 passes. Returns 0 where a switching function was not finite in a pass. */
static int driver_modes_at(bondc_driver *d, double t, const double *y, const double *guess, const int *floors,
                           double *out)
{
    return bondc_modes_at(&d->law, floors, t, y, guess, out, d->scratch);
}

int bondc_deadbands(bondc_driver *d, double t, const double *y, const double *m, double rtol, double atol,
                    int count, const int *index, double *out);

/* A restart of bondc_driver_pieces at (t, y) from the modes `guess`, into m: the modes there, the
   same a probe ahead along their law, none of the `holding` switches `sticky` on its surface.
   Returns 0 where it is that simple, 1 where the runtime makes it. */
static int pieces_restart(bondc_driver *d, double t, const double *y, const double *guess, double *m,
                          const int *floors, double probe, int strict, double rtol, double atol, int holding,
                          const int *sticky, double *near)
{
    int n = d->n, switches = d->switches;
    if (!driver_modes_at(d, t, y, guess, floors, m) && strict) return 1;
    bondc_rhs(t, y, d->p, m, d->fp);
    if (!driver_finite(d->fp, n)) return 1;
    for (int q = 0; q < n; q++) d->shifted[q] = y[q] + probe * d->fp[q];
    if (!driver_modes_at(d, t + probe, d->shifted, m, floors, d->ahead) && strict) return 1;
    for (int k = 0; k < switches; k++)
        if (d->ahead[k] != m[k]) return 1;
    if (holding) {
        if (bondc_deadbands(d, t, y, m, rtol, atol, holding, sticky, near) != 0) return 1;
        bondc_switches(t, y, d->p, m, d->g);
        if (strict && !driver_finite(d->g, switches)) return 1;
        for (int j = 0; j < holding; j++)
            if (fabs(d->g[sticky[j]]) <= near[j]) return 1;
    }
    return 0;
}

/* Known pieces of a run in one call: piece i ends at the known break t_stops[i] (or the run's end)
   and starts where piece i - 1 ended (piece 0 at (t0, y0) with the modes m0). Every start after the
   first is a restart as the runtime's restart_modes and sliding_candidates make it, where it is that
   simple: the modes at the break from those before (modes_at), the same a probe ahead along their
   law (else the switches would chatter there), and none of the `watched` switches marked in `held`
   (those that can stick: a coulomb friction) on its surface (|g| within its deadband); any other
   restart is left to the caller. Each piece is then started as bondc_driver_start starts a segment
   and stepped as bondc_driver_advance steps one watching the `watched` switches `watch` (every
   switch the run locates as an event: a superset of those a segment watches), with their signs,
   values and bands as the runtime's segment computes them. Every step is stored in ts/ys (at most
   `capacity` in all), ends[i] the count stored when piece i ended, modes + i*switches its modes,
   counts + 3*i its counts (bondc_driver_counts). Returns the number of pieces done: it stops before
   a piece whose restart is not that simple or that fails (a CVODE error, a law or the state not
   finite: its steps are not kept, the caller integrates it its own way), and inside one that does
   not fit in what is left of the buffer or in which a watched switch may cross: then partial[0]
   steps of it follow the pieces done in ts/ys, partial[1] is bondc_driver_advance's code (0 or 1),
   g_left the values of the watched switches it left (before that last step for code 1, at it for
   0), and CVODE stands at its last step, for the caller to go on from there. With `strict` (a model
   with an algebraic loop, whose runtime takes numpy's values where C's are not finite) a restart
   or a piece's start where a switching function or the right-hand side is not finite is left to
   the caller too. */
void bondc_driver_counts(bondc_driver *d, long *out);
int bondc_deadbands(bondc_driver *d, double t, const double *y, const double *m, double rtol, double atol,
                    int count, const int *index, double *out);

int bondc_driver_pieces(bondc_driver *d, int pieces, const double *t_stops, double t0, const double *y0,
                        const double *m0, const int *floors, int watched, const int *watch, const int *held,
                        int strict, double probe, double rtol, double atol, double max_step, double first_step,
                        int capacity, double *ts, double *ys, int *ends, double *modes, long *counts, int *partial,
                        double *g_left, int whens, const int *target_start, const int *targets, double *starts,
                        double *guesses)
{
    int stored = 0, done = 0, n = d->n, switches = d->switches;
    partial[0] = 0;
    partial[1] = -1;
    double t = t0;
    const double *y = y0;
    double *work = (double *)calloc(4 * (size_t)watched + 1, sizeof(double));
    int *sticky = (int *)calloc((size_t)watched + 1, sizeof(int));
    if (!work || !sticky) { free(work); free(sticky); return 0; }
    double *signs = work, *band = work + watched, *g_old = work + 2 * watched, *near = work + 3 * watched;
    int holding = 0;
    for (int j = 0; j < watched; j++)
        if (held[j]) sticky[holding++] = watch[j];
    bondc_whens clauses = {whens, target_start, targets, bondc_when_conditions, bondc_when_actions};
    double *conditions = (double *)calloc(3 * (size_t)whens + 1, sizeof(double));
    double *values = (double *)calloc((size_t)(whens ? target_start[whens] : 0) + 1, sizeof(double));
    int *fired = (int *)calloc((size_t)whens + 1, sizeof(int));
    if (!conditions || !values || !fired) {
        free(work); free(sticky); free(conditions); free(values); free(fired);
        return 0;
    }
    double *before = conditions, *after = conditions + whens, *again = conditions + 2 * whens;
    for (int k = 0; k < switches; k++) modes[k] = m0[k];
    for (int q = 0; q < n; q++) starts[q] = y0[q];
    for (int i = 0; i < pieces; i++, done++) {
        double *m = modes + (long)i * switches;
        if (i > 0) {
            double *guess = guesses + (long)i * switches;
            for (int k = 0; k < switches; k++) guess[k] = m[k - switches];
            if (pieces_restart(d, t, y, guess, m, floors, probe, strict, rtol, atol, holding, sticky, near)) break;
            if (whens) {
                /* the when clauses whose condition became true here (events.c, as the runtime fires
                   them): their statements from the values just before, then the restart after them;
                   a restart where a clause fires again is left to the runtime */
                double *start = starts + (long)i * n;
                bondc_when_conditions(t, y, d->p, guess, before);
                int firing = bondc_when_round(&clauses, n, t, y, d->p, before, m, after, start, fired, values);
                if (firing < 0) break;
                if (firing) {
                    for (int k = 0; k < switches; k++) guess[k] = m[k];
                    if (pieces_restart(d, t, start, guess, m, floors, probe, strict, rtol, atol, holding, sticky,
                                       near)) break;
                    if (bondc_when_round(&clauses, n, t, start, d->p, after, m, again, d->shifted, fired, values))
                        break;
                    y = start;
                }
            }
            if (y != starts + (long)i * n)
                for (int q = 0; q < n; q++) starts[(long)i * n + q] = y[q];
        }
        if (watched) {
            if (bondc_deadbands(d, t, y, m, rtol, atol, watched, watch, band) != 0) break;
            bondc_switches(t, y, d->p, m, d->g);
            if (strict && !driver_finite(d->g, switches)) break;
            for (int j = 0; j < watched; j++) {
                double g = d->g[watch[j]], drift = -m[watch[j]] * g;
                signs[j] = m[watch[j]];
                g_old[j] = g;
                band[j] += drift != drift ? drift : (drift > 0.0 ? drift : 0.0);   /* np.maximum(0, drift) */
            }
        }
        double first = first_step > t_stops[i] - t ? 0.0 : first_step;
        if (bondc_driver_start(d, t, y, m, t_stops[i], rtol, atol, max_step, first, 100000) != 0) break;
        int count = 0;
        int code = bondc_driver_advance(d, capacity - stored, watched, watch, signs, band, g_old, ts + stored,
                                        ys + (long)stored * n, &count, NULL, 0, NULL, 0, NULL, NULL, NULL);
        if (code != 2) {
            if ((code == 0 || code == 1) && count > 0) {
                partial[0] = count;
                partial[1] = code;
                for (int j = 0; j < watched; j++) g_left[j] = g_old[j];
            }
            break;
        }
        bondc_driver_counts(d, counts + 3L * i);
        stored += count;
        ends[i] = stored;
        t = ts[stored - 1];
        y = ys + (long)(stored - 1) * n;
    }
    free(work);
    free(sticky);
    free(conditions);
    free(values);
    free(fired);
    return done;
}

/* After bondc_driver_start (with the segment's modes): slide on switch k between the corners
   mp (its side +) and mm (side -), starting from the weight alpha (the last one, used where both
   rates are equal); probe: the step of the rates' central differences. The exits watched by
   bondc_driver_slide_advance are alpha, 1 - alpha and m[j]*g[j] + drift[j] of the `count` switches
   `others` (drift: how far a switch starts on the far side of its surface). */
/* The longest sliding step whose exits are only tested at its end (0: every step): a longer one ends
   bondc_driver_slide_advance as a possible exit (1), for the runtime to test inside it. */
void bondc_driver_check(bondc_driver *d, double longest)
{
    d->longest = longest;
}

void bondc_driver_slide(bondc_driver *d, int k, const double *mp, const double *mm, double alpha, double probe,
                        int count, const int *others, const double *drift)
{
    for (int j = 0; j < d->switches; j++) { d->mp[j] = mp[j]; d->mm[j] = mm[j]; }
    d->slide = k; d->alpha = alpha; d->probe = probe; d->exits = count; d->others = others; d->drift = drift;
    d->held = 0;
}

/* After bondc_driver_start (with the segment's modes): slide on the `k` > 1 switches `sliding`
   between the `corners` mode vectors cm (corners x d->switches, in the order of _Run.sliding_corners:
   affine, all minus then each switch alone on its plus side; else bit i of the corner's number the
   side of switch i), starting from the weights alphas; probe, others and drift as for
   bondc_driver_slide. The exits are the k alphas, the k (1 - alpha)s and those of `others`. 0 on
   success, -1 when out of memory. */
int bondc_driver_slide_many(bondc_driver *d, int k, const int *sliding, int corners, int affine, const double *cm,
                            const double *alphas, double probe, int count, const int *others, const double *drift)
{
    free(d->sliding); free(d->cm); free(d->cf); free(d->rates); free(d->alphas); free(d->weights);
    free(d->newton); free(d->delta); free(d->kept);
    d->sliding = (int *)calloc(k, sizeof(int));
    d->cm = (double *)calloc((long)corners * d->switches + 1, sizeof(double));
    d->cf = (double *)calloc((long)corners * d->n + 1, sizeof(double));
    d->rates = (double *)calloc((long)corners * k, sizeof(double));
    d->alphas = (double *)calloc(k, sizeof(double));
    d->weights = (double *)calloc(corners, sizeof(double));
    d->newton = (double *)calloc(bondc_filippov_work(k, affine), sizeof(double));     /* its work space */
    d->delta = (double *)calloc(2 * k, sizeof(double));
    d->kept = (double *)calloc(k, sizeof(double));
    d->held = 0;
    if (!d->sliding || !d->cm || !d->cf || !d->rates || !d->alphas || !d->weights || !d->newton || !d->delta
        || !d->kept) return -1;
    for (int i = 0; i < k; i++) { d->sliding[i] = sliding[i]; d->alphas[i] = alphas[i]; }
    for (long i = 0; i < (long)corners * d->switches; i++) d->cm[i] = cm[i];
    d->held = k; d->corners = corners; d->affine = affine;
    d->slide = -1; d->probe = probe; d->exits = count; d->others = others; d->drift = drift;
    return 0;
}

/* The exits (2k + count values, see bondc_driver_slide and bondc_driver_slide_many) at (t, y);
   returns the weight alpha (one switch), or 0 (NaN where the weights are not found) for several,
   whose weights are left in d->alphas. */
static double slide_exits(bondc_driver *d, double t, const double *y, double *exits)
{
    int k = d->held > 1 ? d->held : 1;
    double alpha = 0.0;
    if (d->held > 1) {
        if (many_alphas(d, t, y) != 0) alpha = NAN;
        for (int i = 0; i < k; i++) {
            exits[i] = alpha == alpha ? d->alphas[i] : NAN;
            exits[k + i] = 1.0 - exits[i];
        }
    } else {
        alpha = slide_alpha(d, t, y);
        exits[0] = alpha; exits[1] = 1.0 - alpha;
    }
    if (d->exits) {
        bondc_switches(t, y, d->p, d->m, d->g);
        for (int j = 0; j < d->exits; j++)
            exits[2 * k + j] = d->m[d->others[j]] * d->g[d->others[j]] + d->drift[j];
    }
    return alpha;
}

/* The sliding mode's exits at t inside the last step, on CVODE's interpolant (locate.h's values) */
static int driver_slide_values(void *context, double t, double *out)
{
    bondc_driver *d = (bondc_driver *)context;
    if (driver_interpolate(d, t) != 0) {
        int watched = 2 * (d->held > 1 ? d->held : 1) + d->exits;
        for (int j = 0; j < watched; j++) out[j] = NAN;
        return -1;
    }
    slide_exits(d, t, N_VGetArrayPointer(d->work), out);
    return 0;
}

/* After bondc_driver_slide_advance returned 1 (a possible end in its last step (t_old, t_new], the
   exits `old` before it and `now` at its end): the end of the sliding mode in that step
   (bondc_first_end on the interpolant), into *t_end (0), or 1 where the mode goes on past t_new;
   the exits are tested every `longest` (0: only at the ends). -1 where memory ran out. */
int bondc_driver_slide_end(bondc_driver *d, double t_old, double t_new, const double *old, const double *now,
                           double longest, double *t_end)
{
    int watched = 2 * (d->held > 1 ? d->held : 1) + d->exits;
    return bondc_first_end(driver_slide_values, d, watched, t_old, t_new, old, now, longest, t_end);
}

/* The exits of the sliding mode (see bondc_driver_slide) at (t, y), into out (2 + count values). */
void bondc_driver_exits(bondc_driver *d, double t, const double *y, double *out)
{
    slide_exits(d, t, y, out);
}

/* bondc_driver_advance for a sliding mode: each stored step also stores its weight alpha (not
   clipped). After each step the exits are compared with `old` (2 + count values, updated in
   place): an entry that went from > 0 to <= 0, or from >= 0 to < 0, is a possible end of the
   sliding mode. Returns 0: capacity reached; 1: a possible end in the last stored step (`old`
   still holds the values before it), or a step longer than d->longest (bondc_driver_check), in
   which the runtime looks for one; 2: t_stop reached; 3: a law was not finite at a trial
   point; 4: the state or the combination at a step is not finite; < 0: CVODE's error flag. The
   report points of a run reported at t_eval as bondc_driver_advance stores them (the caller takes
   the weights of the combination there). */
/* The report points t_eval[*eval_next] <= t of the step just taken, into et/ey; 1 where the buffer
   filled first (the rest of that step's are the caller's, from bondc_driver_dky). */
static int report_step(bondc_driver *d, double t, const double *y, const double *t_eval, int n_eval,
                       int *eval_next, int eval_capacity, double *et, double *ey, int *eval_count)
{
    while (t_eval && *eval_next < n_eval && t_eval[*eval_next] <= t) {
        if (*eval_count >= eval_capacity) return 1;
        double te = t_eval[*eval_next];
        const double *source = y;
        if (te != t) {
            driver_interpolate(d, te);
            source = N_VGetArrayPointer(d->work);
        }
        et[*eval_count] = te;
        for (int i = 0; i < d->n; i++) ey[(long)*eval_count * d->n + i] = source[i];
        (*eval_count)++;
        (*eval_next)++;
    }
    return 0;
}

/* Whether an exit of the sliding mode may dip below 0 inside the step just taken, whose middle is
   `middle`, where it is positive at both ends (left, right): a push passing a static limit for less
   than a step. The exits at the middle (into mid, from CVODE's interpolant) change sign from an end,
   or the parabola through the three comes within its curvature of 0 (_may_dip): the runtime looks
   (_Run.sliding_dip). The weights kept for the next step are those of its end, as without the test. */
static int slide_dips(bondc_driver *d, double middle, const double *left, const double *right, double *mid,
                      int watched)
{
    double alpha = d->alpha;
    int held = d->held > 1 ? d->held : 0;
    for (int i = 0; i < held; i++) d->kept[i] = d->alphas[i];
    int dip = 0;
    if (driver_interpolate(d, middle) == 0) {
        slide_exits(d, middle, N_VGetArrayPointer(d->work), mid);
        for (int j = 0; j < watched && !dip; j++) dip = bondc_may_dip(left[j], mid[j], right[j]);
    }
    d->alpha = alpha;
    for (int i = 0; i < held; i++) d->alphas[i] = d->kept[i];
    return dip;
}

int bondc_driver_slide_advance(bondc_driver *d, int capacity, double *old, double *exits, double *ts,
                               double *ys, double *alphas, int *count, const double *t_eval, int n_eval,
                               int *eval_next, int eval_capacity, double *et, double *ey, int *eval_count)
{
    double *y = N_VGetArrayPointer(d->y);
    if (eval_count) *eval_count = 0;
    int held = d->held > 1 ? d->held : 1;
    int watched = 2 * held + d->exits;
    *count = 0;
    for (int k = 0; k < capacity; k++) {
        double t;
        int flag = driver_step(d, &t);
        if (flag < 0) return d->bad ? 3 : flag;
        if (!driver_finite(y, d->n)) return 4;
        double alpha = slide_exits(d, t, y, exits);
        if (d->held > 1) {
            if (alpha != alpha) return 4;
            for (int i = 0; i < d->n; i++) {
                double sum = 0.0;
                for (int c = 0; c < d->corners; c++) sum += d->weights[c] * d->cf[(long)c * d->n + i];
                if (!isfinite(sum)) return 4;
            }
            for (int i = 0; i < held; i++) alphas[(long)k * held + i] = d->alphas[i];
        } else {
            double w = clip01(alpha);
            for (int i = 0; i < d->n; i++)
                if (!isfinite((1 - w) * d->fm[i] + w * d->fp[i])) return 4;
            alphas[k] = alpha;
        }
        ts[k] = t;
        for (int i = 0; i < d->n; i++) ys[(long)k * d->n + i] = y[i];
        *count = k + 1;
        for (int j = 0; j < watched; j++)
            if ((old[j] > 0 && exits[j] <= 0) || (old[j] >= 0 && exits[j] < 0)) return 1;
        double h = 0.0;
        if (driver_last_step(d, &h) == 0 && h > 0) {
            /* a long step: the runtime looks for an exit inside it too */
            if (d->longest > 0 && h > d->longest) return 1;
            if (slide_dips(d, t - 0.5 * h, old, exits, exits + watched, watched)) return 1;
        }
        for (int j = 0; j < watched; j++) old[j] = exits[j];
        int full = report_step(d, t, y, t_eval, n_eval, eval_next, eval_capacity, et, ey, eval_count);
        if (t >= d->t_stop) return 2;
        if (full) return 0;
    }
    return 0;
}

/* Integrate the unfrozen law of the segment just started (bondc_driver_start): the modes found again
   at every evaluation of the right-hand side and the Jacobian, from the last ones, as the runtime's
   unfrozen_interval finds them. Up to `capacity` steps, each stored in ts/ys with its modes (found at
   the step's end) in ms, and its report points (t_eval, as bondc_driver_advance stores them).
   Returns 0: capacity reached (or the report buffer full); 2: t_stop reached; 3: a law was not finite
   at a trial point; 4: the state, or its rate at the step's end, is not finite (that step is not
   stored); < 0: CVODE's error flag. */
int bondc_driver_unfrozen_advance(bondc_driver *d, int capacity, const int *floors, double *ts, double *ys,
                                  double *ms, int *count, const double *t_eval, int n_eval, int *eval_next,
                                  int eval_capacity, double *et, double *ey, int *eval_count)
{
    double *y = N_VGetArrayPointer(d->y);
    d->unfrozen = 1;
    d->floors = floors;
    *count = 0;
    if (eval_count) *eval_count = 0;
    for (int k = 0; k < capacity; k++) {
        double t;
        int flag = driver_step(d, &t);
        if (flag < 0) return d->bad ? 3 : flag;
        if (!driver_finite(y, d->n)) return 4;
        driver_modes_at(d, t, y, d->m, floors, d->m);
        bondc_rhs(t, y, d->p, d->m, d->fp);
        if (!driver_finite(d->fp, d->n)) return 4;
        ts[k] = t;
        for (int i = 0; i < d->n; i++) ys[(long)k * d->n + i] = y[i];
        for (int j = 0; j < d->switches; j++) ms[(long)k * d->switches + j] = d->m[j];
        *count = k + 1;
        int full = report_step(d, t, y, t_eval, n_eval, eval_next, eval_capacity, et, ey, eval_count);
        if (t >= d->t_stop) return 2;
        if (full) return 0;
    }
    return 0;
}

/* _Run.deadbands in C: for each of the `count` switches `index`, the sum over the states i of
   |g(y + scale_i e_i) - g(y)|, scale_i = atol + rtol*|y_i| (0 where not finite); 0 on success. */
int bondc_deadbands(bondc_driver *d, double t, const double *y, const double *m, double rtol, double atol,
                    int count, const int *index, double *out)
{
    double *scale = (double *)calloc(d->n + 1, sizeof(double));
    if (!scale) return -1;
    for (int i = 0; i < d->n; i++) scale[i] = atol + rtol * fabs(y[i]);
    int code = bondc_law_deadbands(&d->law, t, y, m, scale, count, index, out);
    free(scale);
    return code;
}

/* y(t) (k = 0) or its derivative (k = 1) inside the last step. */
int bondc_driver_dky(bondc_driver *d, double t, int k, double *out)
{
    int flag = d->erk ? (k == 0 ? driver_interpolate(d, t) : -1) : CVodeGetDky(d->cvode, t, k, d->work);
    double *w = N_VGetArrayPointer(d->work);
    for (int i = 0; i < d->n; i++) out[i] = w[i];
    return flag;
}

void bondc_driver_counts(bondc_driver *d, long *out)
{
    if (d->erk) {       /* evaluations since the stepper was made: the caller takes differences */
        long counts[3];
        d->erk->counts(d->erk_memory, counts);
        out[0] = counts[0]; out[1] = 0; out[2] = 0;
        return;
    }
    CVodeGetNumRhsEvals(d->cvode, &out[0]);
    out[1] = 0; out[2] = 0;
    if (d->ls) {
        CVodeGetNumJacEvals(d->cvode, &out[1]);
        CVodeGetNumLinSolvSetups(d->cvode, &out[2]);
    }
}

void bondc_driver_free(bondc_driver *d)
{
    if (!d) return;
    if (d->erk && d->erk_memory) d->erk->destroy(d->erk_memory);
    if (d->cvode) CVodeFree(&d->cvode);
    if (d->ls) SUNLinSolFree(d->ls);
    if (d->a) SUNMatDestroy(d->a);
    if (d->y) N_VDestroy(d->y);
    if (d->work) N_VDestroy(d->work);
    if (d->ctx) SUNContext_Free(&d->ctx);
    free(d->m); free(d->g); free(d->values); free(d->extra); free(d->mp); free(d->mm);
    free(d->fp); free(d->fm); free(d->shifted); free(d->scratch); free(d->ahead); free(d->gmid);
    free(d->sliding); free(d->cm); free(d->cf); free(d->rates); free(d->alphas); free(d->weights);
    free(d->newton); free(d->delta); free(d->kept); free(d);
}

/* ---- the crossing after a possible one, and the modes after it: what an FMU's engine
   (bondc/native/fmi/engine.c) does with bondc_driver_advance's code 1, in C for any caller */

/* The modes just after (t, y) from `guess` into out (bondc_select_modes): 0 where they agree a probe
   ahead, 1 where they cycle (flips marks the switches that flip: a sliding mode), -1 when out of
   memory. */
int bondc_driver_select(bondc_driver *d, double t, const double *y, const double *guess, const int *floors,
                        double probe, double *out, int *flips)
{
    int rows = 0;
    double *cycle = (double *)malloc(sizeof(double) * 10 * (size_t)(d->switches + 1));
    if (!cycle) return -1;
    int code = bondc_select_modes(&d->law, floors, t, y, guess, probe, out, flips, cycle, &rows);
    free(cycle);
    return code;
}

/* The switching functions with the modes q->m at t inside the last step (t_old, t_new], on CVODE's
   interpolant (y_new itself at t_new): locate.h's values for bondc_first_crossing */
typedef struct {
    bondc_driver *d;
    double t_old, t_new;
    const double *y_new, *m;
} driver_step_switches;

static int driver_switches_at(void *context, double t, double *out)
{
    driver_step_switches *q = (driver_step_switches *)context;
    const double *y = q->y_new;
    if (t != q->t_new) {
        driver_interpolate(q->d, t < q->t_old ? q->t_old : (t > q->t_new ? q->t_new : t));
        y = N_VGetArrayPointer(q->d->work);
    }
    bondc_switches(t, y, q->d->p, q->m, out);
    return 0;
}

/* The earliest crossing in the last step (t_old, t_new] of the `watched` switches `watch` (modes m,
   their signs, bands and values before the step g_old, as bondc_driver_advance watched them):
   bondc_first_crossing on the step's interpolant. Its switch, or -1 where none crossed; its time
   into *t_event; the switching functions at the step's end (y_new) into g_new. */
int bondc_driver_crossing(bondc_driver *d, int watched, const int *watch, const double *signs, const double *band,
                          const double *g_old, const int *floors, const double *m, double t_old, double t_new,
                          const double *y_new, double *g_new, double *t_event)
{
    bondc_switches(t_new, y_new, d->p, m, g_new);
    double *now = (double *)malloc(sizeof(double) * (size_t)(watched > 0 ? watched : 1));
    if (!now) { *t_event = t_new; return -1; }
    for (int j = 0; j < watched; j++) now[j] = g_new[watch[j]];
    driver_step_switches q = {d, t_old, t_new, y_new, m};
    int j = bondc_first_crossing(driver_switches_at, &q, d->switches, watched, watch, floors, signs, band, g_old, now,
                                 t_old, t_new, t_event);
    free(now);
    bondc_switches(t_new, y_new, d->p, m, g_new);
    return j >= 0 ? watch[j] : -1;
}
