/* bondc's engine inside an FMU: one instance's state, integrated by bondc's CVODE driver (driver.c).

   The driver integrates with the model's frozen laws (the modes m held) and watches the switching
   functions of the located switches (bondc_driver_advance); at a possible crossing the driver finds
   the earliest crossing in the last step on its interpolant (bondc_driver_crossing, as the Python
   runtime's _Run.crossing does) and selects the modes after it (bondc_driver_select: the modes
   there and a probe ahead along their law, as _Run.restart_modes); this file fires the when
   clauses whose condition became true (as bondc_driver_pieces does). Where switches sit on their
   surfaces (modes that cycle, a coulomb friction at rest), Co-Simulation chooses the sliding set
   with the engine's bondc_sliding_set (filippov.c, as bondc simulate does) and integrates the
   Filippov combination with the driver (bondc_driver_slide, bondc_driver_slide_many) until its end
   (bondc_driver_slide_end). Model Exchange cannot hold a state on a surface: bondc fmu --kind me
   refuses, before building, a model whose switches may slide (see bondc.export.fmu). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bondc_model.h"
#include "driver.h"
#include "filippov.h"
#include "events.h"
#include "engine.h"

#define NS (BONDC_N_SWITCHES > 0 ? BONDC_N_SWITCHES : 1)
#define NX (BONDC_N_STATES > 0 ? BONDC_N_STATES : 1)
#define NP (BONDC_N_P > 0 ? BONDC_N_P : 1)
#define NW (BONDC_N_WHENS > 0 ? BONDC_N_WHENS : 1)
#define CAPACITY 256          /* steps of one batch of the driver */
#define MAX_STEPS 100000L     /* CVODE's steps between two restarts */
#define STALL_EVENTS 100000   /* events in one call without time advancing: the run is stalled */
#define SLIDING_CHECKS 1000   /* a sliding mode's exits are tested at least this often over the span */
#define MAX_HELD 8            /* switches a sliding mode holds at once, here (2^8 corners) */
#define MAX_CORNERS (1 << (BONDC_N_SWITCHES < MAX_HELD ? BONDC_N_SWITCHES : MAX_HELD))

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
    c->fired = (int *)zeros(NW, sizeof(int));
    c->firing_count = (int *)zeros(NW, sizeof(int));
    c->firings = (double *)zeros((size_t)NW * (size_t)bondc_zeno_firings(), sizeof(double));
    c->whens = (bondc_whens *)zeros(1, sizeof(bondc_whens));
    c->ts = (double *)zeros(CAPACITY, sizeof(double));
    c->ys = (double *)zeros((size_t)CAPACITY * NX, sizeof(double));
    c->slid = (int *)zeros(NS, sizeof(int));
    c->relevant = (int *)zeros(NS, sizeof(int));
    c->flips = (int *)zeros(NS, sizeof(int));
    c->cm = (double *)zeros((size_t)MAX_CORNERS * NS, sizeof(double));
    c->weights = (double *)zeros(MAX_CORNERS, sizeof(double));
    c->law = (bondc_law *)zeros(1, sizeof(bondc_law));
    c->candidates = (int *)zeros(NS, sizeof(int));
    c->held = (int *)zeros(NS, sizeof(int));
    c->others = (int *)zeros(NS, sizeof(int));
    c->scale = (double *)zeros(NX, sizeof(double));
    c->vertices = (double *)zeros(NS, sizeof(double));
    c->alpha = (double *)zeros(NS, sizeof(double));
    c->alphas = (double *)zeros((size_t)CAPACITY * NS, sizeof(double));
    c->exits = (double *)zeros(4 * (size_t)NS, sizeof(double));
    c->exits_old = (double *)zeros(2 * (size_t)NS, sizeof(double));
    c->drift = (double *)zeros(NS, sizeof(double));
    c->corner = (double *)zeros(NS, sizeof(double));
    c->out = (double *)zeros(BONDC_N_OUTPUTS, sizeof(double));
    if (!c->p || !c->x || !c->m || !c->watch || !c->signs || !c->band || !c->g_old || !c->g
        || !c->old || !c->f || !c->conditions || !c->after || !c->values || !c->ts
        || !c->ys || !c->slid || !c->relevant || !c->flips || !c->cm || !c->weights || !c->law || !c->candidates || !c->held || !c->others
        || !c->scale || !c->vertices || !c->alpha || !c->alphas || !c->exits || !c->exits_old || !c->drift
        || !c->corner || !c->out || !c->fired || !c->firing_count || !c->firings || !c->whens) {
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
    c->law->n = BONDC_N_STATES; c->law->switches = BONDC_N_SWITCHES; c->law->p = c->p;
    c->law->rhs = bondc_rhs; c->law->switching = bondc_switches; c->law->vertices = bondc_switch_vertices;
    c->whens->count = BONDC_N_WHENS; c->whens->target_start = bondc_when_target_start;
    c->whens->targets = bondc_when_targets;
    c->whens->conditions = bondc_when_conditions; c->whens->actions = bondc_when_actions;
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
    free(c->fired); free(c->firing_count); free(c->firings); free(c->whens);
    free(c->slid); free(c->relevant); free(c->flips); free(c->cm); free(c->weights); free(c->law); free(c->candidates); free(c->held);
    free(c->others); free(c->scale); free(c->vertices); free(c->alpha); free(c->alphas); free(c->exits);
    free(c->exits_old); free(c->drift); free(c->corner); free(c->out);
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
    c->holding = 0;
    c->chattering = 0;
    for (int k = 0; k < BONDC_N_SWITCHES; k++) { c->slid[k] = 0; c->vertices[k] = bondc_switch_vertices[k]; }
    for (int k = 0; k < BONDC_N_WHENS; k++) c->firing_count[k] = 0;
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
    c->t_stop = t_start + c->span;
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

/* The modes just after (t, x), from the guess c->old, into c->m (the driver's bondc_driver_select,
   filippov.c's bondc_select_modes, as bondc simulate chooses them): 0, 1 where they cycle (switches
   that chatter: a sliding mode; c->flips marks them), -1 where memory ran out. */
static int select_modes(bondc_fmu *c, double t, const double *x)
{
    return bondc_driver_select(c->d, t, x, c->old, bondc_switch_floor, c->probe, c->m, c->flips);
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

/* The failure of a run whose when clauses keep firing at one instant (as bondc simulate's) */
static int when_again(bondc_fmu *c)
{
    char text[500];
    int k = 0;
    while (k < BONDC_N_WHENS - 1 && !c->fired[k]) k++;
    snprintf(text, sizeof text, "when clauses kept firing at t=%.6g: after %d rounds at the same instant, %s "
             "became true again; make the conditions exclusive (a hysteresis band), or the statements move the "
             "state out of the condition", c->t, bondc_when_rounds(), bondc_when_labels[k]);
    return fail(c, text, c->t);
}

/* Note a firing of when clause k at c->t; where its firings accumulate (events.c's bondc_zeno), the
   run fails there, as bondc simulate's does: 1, else 0 */
static int zeno(bondc_fmu *c, int k)
{
    int keep = bondc_zeno_firings();
    double *times = c->firings + (size_t)k * keep;
    int count = c->firing_count[k];
    if (count == keep) {
        memmove(times, times + 1, sizeof(double) * (size_t)(keep - 1));
        count--;
    }
    times[count++] = c->t;
    c->firing_count[k] = count;
    double limit, ratio;
    if (!bondc_zeno(count, times, c->span, c->t_stop, &limit, &ratio)) return 0;
    char text[600];
    snprintf(text, sizeof text, "the events of '%s' accumulate at t=%.6g (Zeno behaviour): %d firings, each "
             "interval about %.3g times the one before, the last %.3g s; give the model a law for what follows",
             bondc_when_labels[k], limit, count, ratio, times[count - 1] - times[count - 2]);
    fail(c, text, c->t);
    return 1;
}

int bondc_fmu_event(bondc_fmu *c, int *changed)
{
    *changed = 0;
    if (c->failed) return -1;
    if (c->selected) return 0;
    if (!finite_all(c->x, BONDC_N_STATES)) return fail(c, "the state is not finite", c->t);
    memcpy(c->old, c->m, sizeof(double) * NS);
    c->holding = 0;
    int code = select_modes(c, c->t, c->x);
    if (code < 0) return fail(c, "out of memory", c->t);
    c->chattering = code > 0;
    if (!same_modes(c->old, c->m)) c->events++;
    /* the when clauses whose condition became true here (events.c, as bondc simulate fires them):
       their statements from the values just before, then the modes after them, round after round */
    if (BONDC_N_WHENS > 0) bondc_when_conditions(c->t, c->x, c->p, c->old, c->conditions);
    for (int round = 0; BONDC_N_WHENS > 0; round++) {
        int firing = bondc_when_round(c->whens, BONDC_N_STATES, c->t, c->x, c->p, c->conditions, c->m, c->after,
                                      c->x, c->fired, c->values);
        if (firing == 0) break;
        if (firing < 0) return fail(c, "a when clause made the state not finite", c->t);
        if (round == bondc_when_rounds()) return when_again(c);
        for (int k = 0; k < BONDC_N_WHENS; k++)
            if (c->fired[k] && zeno(c, k)) return -1;
        memcpy(c->conditions, c->after, sizeof(double) * NW);
        *changed = 1;
        c->events++;
        memcpy(c->old, c->m, sizeof(double) * NS);
        code = select_modes(c, c->t, c->x);
        if (code < 0) return fail(c, "out of memory", c->t);
        c->chattering = code > 0;
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

/* The FMU's failure for a driver batch's code (3: a law not finite at a trial point, 4: the state
   not finite, < 0: CVODE's flag), or 0 for the codes that go on */
static int driver_failed(bondc_fmu *c, int code, const char *where)
{
    if (code == 3) return fail(c, "a law is not finite at a trial point of CVODE", c->t);
    if (code == 4) return fail(c, "the state is not finite", c->t);
    if (code < 0) {
        char text[120];
        snprintf(text, sizeof text, "CVODE failed%s (flag %d)", where, code);
        return fail(c, text, c->t);
    }
    return 0;
}

/* The state at a sliding segment's end back on the held switches' surfaces where it drifted off
   (bondc_onto_surfaces, as bondc simulate's run loop does at a sliding segment's end): 1, -1 (memory) */
static int onto_surfaces(bondc_fmu *c, int held, int affine)
{
    for (int i = 0; i < BONDC_N_STATES; i++) c->scale[i] = c->atol + c->rtol * fabs(c->x[i]);
    if (bondc_onto_surfaces(c->law, bondc_switch_floor, c->t, c->x, c->m, c->held, held, affine, c->vertices,
                            c->alpha, c->probe, c->scale) < 0)
        return fail(c, "out of memory", c->t);
    return 1;
}

/* A Filippov sliding mode from (t, x), as bondc simulate's run loop makes it: the candidates (the
   switches that chatter, and those on their surfaces that are coulomb frictions or slid until now),
   the set that holds (bondc_consistent_sliding_set, which also chooses the other switches' modes along
   the sliding motion), then the
   combination integrated by the driver until it ends (a weight reaches 0 or 1, another switch
   crosses: bondc_driver_slide_end) or t_end. 0: nothing is held (c->m chosen), 1: the mode was
   integrated (c->t advanced), -1: failed. */
static int slide(bondc_fmu *c, double t_end)
{
    int count = 0, chattering = 0, n = BONDC_N_STATES;
    bondc_switches(c->t, c->x, c->p, c->m, c->g);
    for (int i = 0; i < n; i++) c->scale[i] = c->atol + c->rtol * fabs(c->x[i]);
    /* the candidates as bondc simulate finds them (bondc_sliding_candidates), every switch relevant */
    for (int k = 0; k < BONDC_N_SWITCHES; k++) {
        c->relevant[k] = 1;
        if (c->chattering && c->flips[k]) c->held[chattering++] = k;
    }
    count = bondc_sliding_candidates(c->law, bondc_switch_floor, bondc_switch_located, c->slid, c->relevant,
                                     c->vertices, c->t, c->x, c->m, c->held, chattering, c->scale, c->candidates);
    if (count < 0) return fail(c, "out of memory", c->t);
    for (int k = 0; k < BONDC_N_SWITCHES; k++) c->slid[k] = 0;
    if (!count) return 0;
    int affine = 0;
    int held = bondc_consistent_sliding_set(c->law, bondc_switch_floor, bondc_switch_located, NULL, NULL, c->t, c->x,
                                            c->m, c->candidates, count, c->probe, c->span, c->scale, c->vertices,
                                            c->held, c->alpha, &affine);
    if (held == -1) return fail(c, "out of memory", c->t);
    if (held == -2 || held > MAX_HELD) {
        char text[400];
        snprintf(text, sizeof text, "%d switches are on their surfaces at once (%s, ...) and their laws do not "
                 "combine linearly: the FMU holds at most %d", count, bondc_switch_labels[c->candidates[0]], MAX_HELD);
        return fail(c, text, c->t);
    }
    c->chattering = 0;
    if (held == 0) return 0;
    /* the corners: each held switch on its side at its vertex (filippov.h's order) */
    int corners = affine ? held + 1 : 1 << held;
    for (int q = 0; q < corners; q++) {
        double *row = c->cm + (long)q * NS;
        memcpy(row, c->m, sizeof(double) * NS);
        for (int i = 0; i < held; i++) {
            int plus = affine ? q == 1 + i : (q >> i) & 1;
            row[c->held[i]] = (plus ? 1.0 : -1.0) * c->vertices[c->held[i]];
        }
    }
    /* the other located switches end the mode where they cross, from where they start */
    int others = 0;
    for (int j = 0; j < c->watched; j++) {
        int k = c->watch[j], inside = 0;
        for (int i = 0; i < held; i++) inside |= c->held[i] == k;
        if (inside || c->m[k] == 0) continue;
        double drift = -c->m[k] * c->g[k];
        c->drift[others] = bondc_switch_floor[k] ? 0.0 : (drift > 0 ? drift : 0.0);
        c->others[others++] = k;
    }
    if (bondc_driver_start(c->d, c->t, c->x, c->m, t_end, c->rtol, c->atol, c->max_step, 0.0, MAX_STEPS) != 0)
        return fail(c, "CVODE could not start", c->t);
    if (held == 1) {
        bondc_driver_slide(c->d, c->held[0], c->cm + NS, c->cm, c->alpha[0], c->probe, others, c->others, c->drift);
    } else if (bondc_driver_slide_many(c->d, held, c->held, corners, affine, c->cm, c->alpha, c->probe, others,
                                       c->others, c->drift) != 0) {
        return fail(c, "out of memory", c->t);
    }
    double longest = c->span / SLIDING_CHECKS;
    if (c->max_step > 0 && c->max_step < longest) longest = c->max_step;
    bondc_driver_check(c->d, longest);
    int watched = 2 * held + others;
    bondc_driver_exits(c->d, c->t, c->x, c->exits_old);
    for (int j = 0; j < watched; j++)       /* at the edge of the sliding region: leaving counts from here */
        if (c->exits_old[j] < 0) c->exits_old[j] = 0.0;
    c->holding = held;
    c->corners = corners;
    for (int i = 0; i < held; i++) c->slid[c->held[i]] = 1;
    bondc_corner_weights(held, affine, c->alpha, c->weights);
    for (;;) {
        int steps = 0;
        double t_prev = c->t;
        int code = bondc_driver_slide_advance(c->d, CAPACITY, c->exits_old, c->exits, c->ts, c->ys, c->alphas,
                                              &steps, NULL, 0, NULL, 0, NULL, NULL, NULL);
        if (driver_failed(c, code, " in a sliding mode") != 0) return -1;
        int kept = code == 1 ? steps - 1 : steps;
        if (kept > 0) {
            t_prev = c->t = c->ts[kept - 1];
            memcpy(c->x, c->ys + (long)(kept - 1) * n, sizeof(double) * n);
            double *a = c->alphas + (long)(kept - 1) * held;
            for (int i = 0; i < held; i++) c->alpha[i] = a[i] < 0 ? 0.0 : (a[i] > 1 ? 1.0 : a[i]);
            bondc_corner_weights(held, affine, c->alpha, c->weights);
        }
        if (code == 2) return onto_surfaces(c, held, affine);
        if (code == 0) continue;
        /* a possible end in the last step (t_prev, t_new]: located as bondc simulate does */
        double t_new = c->ts[steps - 1], t_hit;
        const double *y_new = c->ys + (long)(steps - 1) * n;
        int ended = bondc_driver_slide_end(c->d, t_prev, t_new, c->exits_old, c->exits, longest, &t_hit);
        if (ended < 0) return fail(c, "out of memory", c->t);
        if (ended == 0) {
            if (t_hit == t_new) memcpy(c->x, y_new, sizeof(double) * n);
            else if (bondc_driver_dky(c->d, t_hit, 0, c->x) != 0)
                return fail(c, "CVODE could not interpolate to the end of a sliding mode", t_hit);
            c->t = t_hit;
            c->holding = 0;
            c->selected = 0;        /* the modes after it, at the next round */
            return onto_surfaces(c, held, affine);
        }
        c->t = t_new;
        memcpy(c->x, y_new, sizeof(double) * n);
        memcpy(c->exits_old, c->exits, sizeof(double) * watched);
        if (t_new >= t_end) return onto_surfaces(c, held, affine);
    }
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
        if (c->watched && t_end - c->t > 16 * EPS * fmax(fmax(fabs(c->t), fabs(t_end)), 1.0)) {
            int slid = slide(c, t_end);
            if (slid < 0) return -1;
            if (slid > 0) {
                c->selected = c->t >= t_end ? c->selected : 0;
                if (c->t > t_last) { t_last = c->t; stalled = 0; }
                else if (++stalled > STALL_EVENTS) return fail(c, "the run stalled: events without time advancing", c->t);
                continue;
            }
        }
        if (c->chattering) return chattering(c, c->t);
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
            if (driver_failed(c, code, "") != 0) return -1;
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
    if (!c->holding) {
        bondc_outputs(c->t, c->x, c->p, c->m, out);
        return;
    }
    /* in a sliding mode: the corners' outputs in its combination (the forces that hold) */
    for (int i = 0; i < BONDC_N_OUTPUTS; i++) out[i] = 0.0;
    for (int q = 0; q < c->corners; q++) {
        if (c->weights[q] == 0) continue;
        bondc_outputs(c->t, c->x, c->p, c->cm + (long)q * NS, c->out);
        for (int i = 0; i < BONDC_N_OUTPUTS; i++) out[i] += c->weights[q] * c->out[i];
    }
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
    if (c->chattering) return chattering(c, c->t);
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
