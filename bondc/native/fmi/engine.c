/* bondc's engine inside an FMU: one instance's state, integrated by bondc's CVODE driver (driver.c).

   The driver integrates with the model's frozen laws (the modes m held) and watches the switching
   functions of the located switches (bondc_driver_advance); at a possible crossing the driver finds
   the earliest crossing in the last step on its interpolant (bondc_driver_crossing, as the Python
   runtime's _Run.crossing does) and selects the modes after it (bondc_driver_select: the modes
   there and a probe ahead along their law, as _Run.restart_modes); this file fires the when
   clauses whose condition became true (as bondc_driver_pieces does). A restart whose modes cycle
   (switches that chatter: a sliding mode) is an error: bondc fmu refuses, before building, a model
   whose switches may slide (see bondc.export.fmu). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bondc_model.h"
#include "driver.h"
#include "engine.h"

#define NS (BONDC_N_SWITCHES > 0 ? BONDC_N_SWITCHES : 1)
#define NX (BONDC_N_STATES > 0 ? BONDC_N_STATES : 1)
#define NP (BONDC_N_P > 0 ? BONDC_N_P : 1)
#define CAPACITY 256          /* steps of one batch of the driver */
#define MAX_STEPS 100000L     /* CVODE's steps between two restarts */
#define EVENT_ROUNDS 10       /* rounds of when clauses at one instant (as the runtime's _EVENT_ROUNDS) */
#define STALL_EVENTS 100000   /* events in one call without time advancing: the run is stalled */

static const double EPS = 2.220446049250313e-16;

static void *zeros(size_t count, size_t size)
{
    return calloc(count > 0 ? count : 1, size);
}

bondc_fmu *bondc_fmu_new(void)
{
    bondc_fmu *c = (bondc_fmu *)calloc(1, sizeof(bondc_fmu));
    if (!c) return NULL;
    c->p = (double *)zeros(NP, sizeof(double));
    c->x = (double *)zeros(NX, sizeof(double));
    c->m = (double *)zeros(NS, sizeof(double));
    c->watch = (int *)zeros(NS, sizeof(int));
    c->signs = (double *)zeros(NS, sizeof(double));
    c->band = (double *)zeros(NS, sizeof(double));
    c->g_old = (double *)zeros(NS, sizeof(double));
    c->g = (double *)zeros(NS, sizeof(double));
    c->old = (double *)zeros(NS, sizeof(double));
    c->f = (double *)zeros(NX, sizeof(double));
    c->conditions = (double *)zeros(BONDC_N_WHENS, sizeof(double));
    c->after = (double *)zeros(BONDC_N_WHENS, sizeof(double));
    c->values = (double *)zeros(BONDC_N_WHEN_TARGETS, sizeof(double));
    c->ts = (double *)zeros(CAPACITY, sizeof(double));
    c->ys = (double *)zeros((size_t)CAPACITY * NX, sizeof(double));
    if (!c->p || !c->x || !c->m || !c->watch || !c->signs || !c->band || !c->g_old || !c->g
        || !c->old || !c->f || !c->conditions || !c->after || !c->values || !c->ts
        || !c->ys) {
        bondc_fmu_free(c);
        return NULL;
    }
    /* the driver: CVODE with a dense or banded solver as the runtime chooses it for a small model */
    /* (a model without states: a driver of one state that stays 0, for the mode selection only) */
    c->d = bondc_driver_new(NX, BONDC_N_SWITCHES, BONDC_N_JACOBIAN, bondc_jacobian_rows,
                            bondc_jacobian_cols, 0, 0, 0, 0, c->p);
    if (!c->d) {
        bondc_fmu_free(c);
        return NULL;
    }
    for (int k = 0; k < BONDC_N_SWITCHES; k++)
        if (bondc_switch_located[k]) c->watch[c->watched++] = k;
    bondc_fmu_reset(c);
    bondc_fmu_setup(c, bondc_experiment[1], 0.0, bondc_experiment[0]);
    return c;
}

void bondc_fmu_free(bondc_fmu *c)
{
    if (!c) return;
    if (c->d) bondc_driver_free(c->d);
    free(c->p); free(c->x); free(c->m); free(c->watch); free(c->signs); free(c->band); free(c->g_old);
    free(c->g); free(c->old); free(c->f); free(c->conditions);
    free(c->after); free(c->values); free(c->ts); free(c->ys);
    free(c);
}

void bondc_fmu_reset(bondc_fmu *c)
{
    for (int i = 0; i < BONDC_N_PARAMETERS; i++) c->p[i] = bondc_parameters[i].value;
    for (int i = 0; i < BONDC_N_INPUTS; i++) c->p[BONDC_N_PARAMETERS + i] = bondc_inputs[i].value;
    bondc_derive_parameters(c->p);
    for (int k = 0; k < BONDC_N_SWITCHES; k++) c->m[k] = 1.0;
    c->t = 0.0;
    c->failed = 0;
    c->events = 0;
    c->states_set = 0;
    c->message[0] = 0;
    bondc_x0(c->p, c->x);
    c->selected = 0;
}

void bondc_fmu_setup(bondc_fmu *c, double rtol, double t_start, double t_stop)
{
    /* the experiment's absolute tolerance, scaled as its relative one is */
    double given = bondc_experiment[1] > 0 ? bondc_experiment[1] : 1e-6;
    c->rtol = rtol > 0 ? rtol : given;
    c->atol = bondc_experiment[2] > 0 ? bondc_experiment[2] * (c->rtol / given) : 1e-8;
    c->max_step = bondc_experiment[3] > 0 ? bondc_experiment[3] : 0.0;
    c->t = t_start;
    c->span = t_stop > t_start ? t_stop - t_start : (bondc_experiment[0] > 0 ? bondc_experiment[0] : 1.0);
    /* as the runtime's probe: 1e-8 of the run's span */
    c->probe = 1e-8 * fmax(c->span, fabs(t_stop));
    c->selected = 0;
}

void bondc_fmu_parameters_changed(bondc_fmu *c, int state)
{
    bondc_derive_parameters(c->p);
    if (state) bondc_x0(c->p, c->x);
    c->selected = 0;
}

static int finite_all(const double *v, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

static int fail(bondc_fmu *c, const char *message, double t)
{
    snprintf(c->message, sizeof c->message, "%s (t = %.17g)", message, t);
    c->failed = 1;
    return -1;
}

static int same_modes(const double *a, const double *b)
{
    for (int k = 0; k < BONDC_N_SWITCHES; k++)
        if (a[k] != b[k]) return 0;
    return 1;
}

/* The modes just after (t, x), from the guess c->old, into c->m (the driver's bondc_driver_select:
   bondc_driver_restart, then the modes a probe ahead until they agree, as _Run.restart_modes): 0,
   1 where they cycle (switches that chatter: a sliding mode), -1 where memory ran out. */
static int select_modes(bondc_fmu *c, double t, const double *x)
{
    return bondc_driver_select(c->d, t, x, c->old, bondc_switch_floor, c->probe, c->m);
}

static int chattering(bondc_fmu *c, double t)
{
    int k = 0;
    for (; k < BONDC_N_SWITCHES; k++)
        if (c->m[k] != c->old[k]) break;
    char text[400];
    snprintf(text, sizeof text, "the switch %s changes mode again at once: the state would slide on its "
             "surface (a sliding mode), which this FMU cannot integrate",
             k < BONDC_N_SWITCHES ? bondc_switch_labels[k] : "of the model");
    return fail(c, text, t);
}

int bondc_fmu_event(bondc_fmu *c, int *changed)
{
    *changed = 0;
    if (c->failed) return -1;
    if (c->selected) return 0;
    if (!finite_all(c->x, BONDC_N_STATES)) return fail(c, "the state is not finite", c->t);
    memcpy(c->old, c->m, sizeof(double) * NS);
    int code = select_modes(c, c->t, c->x);
    if (code < 0) return fail(c, "out of memory", c->t);
    if (code > 0) return chattering(c, c->t);
    if (!same_modes(c->old, c->m)) c->events++;
    /* the when clauses whose condition became true here: their statements from the values just
       before, then the modes after them (as bondc_driver_pieces and _Run.fire_when_clauses) */
    for (int round = 0; BONDC_N_WHENS > 0 && round < EVENT_ROUNDS; round++) {
        bondc_when_conditions(c->t, c->x, c->p, c->old, c->conditions);
        bondc_when_conditions(c->t, c->x, c->p, c->m, c->after);
        int firing = 0;
        for (int k = 0; k < BONDC_N_WHENS; k++)
            if (c->after[k] != 0 && !(c->conditions[k] != 0)) firing = 1;
        if (!firing) break;
        bondc_when_actions(c->t, c->x, c->p, c->m, c->values);
        for (int k = 0; k < BONDC_N_WHENS; k++)
            if (c->after[k] != 0 && !(c->conditions[k] != 0))
                for (int j = bondc_when_target_start[k]; j < bondc_when_target_start[k + 1]; j++)
                    c->x[bondc_when_targets[j]] = c->values[j];
        if (!finite_all(c->x, BONDC_N_STATES)) return fail(c, "a when clause made the state not finite", c->t);
        *changed = 1;
        c->events++;
        memcpy(c->old, c->m, sizeof(double) * NS);
        code = select_modes(c, c->t, c->x);
        if (code < 0) return fail(c, "out of memory", c->t);
        if (code > 0) return chattering(c, c->t);
    }
    c->selected = 1;
    return 0;
}

/* Start a segment at (t, x) with the modes m: the watched switches' signs, values and deadbands
   (as bondc_driver_pieces makes them), and CVODE started towards t_end */
static int start_segment(bondc_fmu *c, double t_end)
{
    if (c->watched) {
        if (bondc_deadbands(c->d, c->t, c->x, c->m, c->rtol, c->atol, c->watched, c->watch, c->band) != 0)
            return fail(c, "out of memory", c->t);
        bondc_switches(c->t, c->x, c->p, c->m, c->g);
        for (int j = 0; j < c->watched; j++) {
            double g = c->g[c->watch[j]], drift = -c->m[c->watch[j]] * g;
            c->signs[j] = c->m[c->watch[j]];
            c->g_old[j] = g;
            c->band[j] += drift != drift ? drift : (drift > 0.0 ? drift : 0.0);
        }
    }
    if (bondc_driver_start(c->d, c->t, c->x, c->m, t_end, c->rtol, c->atol, c->max_step, 0.0, MAX_STEPS) != 0)
        return fail(c, "CVODE could not start", c->t);
    return 0;
}

int bondc_fmu_advance(bondc_fmu *c, double t_end)
{
    long stalled = 0;
    double t_last = c->t;
    if (BONDC_N_STATES == 0) {      /* nothing to integrate: the modes at t_end */
        int changed;
        c->t = t_end;
        c->selected = 0;
        return bondc_fmu_event(c, &changed);
    }
    while (c->t < t_end) {
        int changed;
        if (bondc_fmu_event(c, &changed) != 0) return -1;
        if (t_end - c->t <= 16 * EPS * fmax(fmax(fabs(c->t), fabs(t_end)), 1.0)) {
            /* a sliver too short for CVODE: one Euler step (as the runtime) */
            bondc_rhs(c->t, c->x, c->p, c->m, c->f);
            for (int i = 0; i < BONDC_N_STATES; i++) c->x[i] += (t_end - c->t) * c->f[i];
            c->t = t_end;
            break;
        }
        if (start_segment(c, t_end) != 0) return -1;
        for (;;) {
            int count = 0;
            double t_before = c->t;
            int code = bondc_driver_advance(c->d, CAPACITY, c->watched, c->watch, c->signs, c->band, c->g_old,
                                            c->ts, c->ys, &count, NULL, 0, NULL, 0, NULL, NULL, NULL);
            if (code == 3) return fail(c, "a law is not finite at a trial point of CVODE", c->t);
            if (code == 4) return fail(c, "the state is not finite", c->t);
            if (code < 0) {
                char text[120];
                snprintf(text, sizeof text, "CVODE failed (flag %d)", code);
                return fail(c, text, c->t);
            }
            int kept = code == 1 ? count - 1 : count;
            if (kept > 0) {
                c->t = c->ts[kept - 1];
                memcpy(c->x, c->ys + (long)(kept - 1) * BONDC_N_STATES, sizeof(double) * BONDC_N_STATES);
            }
            if (code == 2) break;
            if (code == 0) continue;
            /* code 1: a possible crossing in the last step (t_old, t_new] */
            double t_old = kept > 0 ? c->t : t_before, t_new = c->ts[count - 1], t_event;
            const double *y_new = c->ys + (long)(count - 1) * BONDC_N_STATES;
            /* the earliest crossing in it, on CVODE's interpolant (the driver's bondc_driver_crossing,
               as _Run.crossing finds it) */
            int k = bondc_driver_crossing(c->d, c->watched, c->watch, c->signs, c->band, c->g_old,
                                          bondc_switch_floor, c->m, t_old, t_new, y_new, c->g, &t_event);
            if (k < 0) {        /* no crossing: the step stands */
                c->t = t_new;
                memcpy(c->x, y_new, sizeof(double) * BONDC_N_STATES);
                for (int j = 0; j < c->watched; j++) c->g_old[j] = c->g[c->watch[j]];
                if (t_new >= t_end) break;
                continue;
            }
            if (t_event == t_new) {
                memcpy(c->x, y_new, sizeof(double) * BONDC_N_STATES);
            } else if (bondc_driver_dky(c->d, t_event, 0, c->x) != 0) {
                return fail(c, "CVODE could not interpolate to a crossing", t_event);
            }
            c->t = t_event;
            c->selected = 0;        /* the modes after the crossing, at the next round */
            break;
        }
        if (c->t > t_last) { t_last = c->t; stalled = 0; }
        else if (++stalled > STALL_EVENTS) return fail(c, "the run stalled: events without time advancing", c->t);
    }
    /* a crossing at t_end: its modes are selected at the next step, so that the outputs at t_end are
       those just before it (the left limit, as bondc simulate reports an event's instant) */
    return 0;
}

void bondc_fmu_derivatives(bondc_fmu *c, double *out)
{
    bondc_rhs(c->t, c->x, c->p, c->m, out);
}

void bondc_fmu_outputs(bondc_fmu *c, double *out)
{
    bondc_outputs(c->t, c->x, c->p, c->m, out);
}

int bondc_fmu_indicator_count(void)
{
    int count = 0;
    for (int k = 0; k < BONDC_N_SWITCHES; k++) count += bondc_switch_located[k] != 0;
    return count;
}

void bondc_fmu_indicators(bondc_fmu *c, double *out)
{
    if (!c->watched) return;
    bondc_switches(c->t, c->x, c->p, c->m, c->g);
    for (int j = 0; j < c->watched; j++) out[j] = c->g[c->watch[j]];
}

/* ---- Model Exchange */

int bondc_fmu_event_update(bondc_fmu *c, int *changed)
{
    c->selected = 0;
    return bondc_fmu_event(c, changed);
}

int bondc_fmu_set_states(bondc_fmu *c, const double *x, size_t n)
{
    if (n != BONDC_N_STATES) return -2;
    if (n) memcpy(c->x, x, sizeof(double) * n);
    c->states_set = 1;
    return 0;
}

int bondc_fmu_get_states(bondc_fmu *c, double *x, size_t n)
{
    if (n != BONDC_N_STATES) return -2;
    if (n) memcpy(x, c->x, sizeof(double) * n);
    return 0;
}

int bondc_fmu_get_derivatives(bondc_fmu *c, double *out, size_t n)
{
    int changed;
    if (n != BONDC_N_STATES) return -2;
    if (bondc_fmu_event(c, &changed) != 0) return -1;
    bondc_fmu_derivatives(c, out);
    return 0;
}

int bondc_fmu_get_indicators(bondc_fmu *c, double *out, size_t n)
{
    int changed;
    if ((int)n != bondc_fmu_indicator_count()) return -2;
    if (bondc_fmu_event(c, &changed) != 0) return -1;
    bondc_fmu_indicators(c, out);
    return 0;
}
