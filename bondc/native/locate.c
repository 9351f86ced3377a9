/* ---- where values that stay positive while nothing happens first fail to (locate.h) ---- */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "locate.h"

int bondc_may_dip(double left, double mid, double right)
{
    if ((left > 0 && mid <= 0) || (left >= 0 && mid < 0)) return 1;
    double curve = 2 * left + 2 * right - 4 * mid, slope = 4 * mid - 3 * left - right;
    double lowest = fmin(left, right);
    if (curve > 0) {
        double vertex = -slope / (2 * curve);
        if (vertex > 0 && vertex < 1) lowest = left + slope * vertex + curve * vertex * vertex;
    }
    return left > 0 && right > 0 && lowest - 0.5 * fabs(curve) < 0;
}

/* The earliest end between values left (at a) and right (at b), each located by the Illinois
   method on values(t); b + 1 where none. `scratch`: count values. */
static double locate_between(bondc_values_at values, void *context, int count, const double *left,
                             const double *right, double a, double b, double *scratch)
{
    const double eps = 2.220446049250313e-16;
    double hit = b + 1.0;
    int found = 0;
    for (int j = 0; j < count; j++) {
        if (!((left[j] > 0 && right[j] <= 0) || (left[j] >= 0 && right[j] < 0))) continue;
        double root;
        if (left[j] <= 0) {
            root = a;
        } else {
            double lo = a, hi = b, flo = left[j], fhi = right[j];
            int kept = 0;
            for (int i = 0; i < 200 && hi - lo > 4 * eps * fmax(fabs(lo), fabs(hi)) + 1e-300; i++) {
                double t = hi - fhi * (hi - lo) / (fhi - flo);
                if (!(t > lo && t < hi)) t = 0.5 * (lo + hi);
                values(context, t, scratch);
                double ft = scratch[j];
                if (ft != ft) { t = 0.5 * (lo + hi); values(context, t, scratch); ft = scratch[j]; }
                if (ft <= 0) { hi = t; fhi = ft; if (kept == -1) flo *= 0.5; kept = -1; }
                else { lo = t; flo = ft; if (kept == 1) fhi *= 0.5; kept = 1; }
                if (ft == 0) break;
            }
            root = hi;
        }
        if (!found || root < hit) { hit = root; found = 1; }
    }
    return found ? hit : b + 1.0;
}

/* The dip search on (a, b): `scratch` holds 2 * count values per level of the search (61 at most) */
static double dip_between(bondc_values_at values, void *context, int count, const double *left, const double *right,
                          double a, double b, int *budget, double *scratch)
{
    double middle_t = 0.5 * (a + b);
    if (*budget <= 0 || !(a < middle_t && middle_t < b)) return b + 1.0;
    (*budget)--;
    double *middle = scratch, *work = scratch + count, *rest = scratch + 2 * count;
    values(context, middle_t, middle);
    double hit = locate_between(values, context, count, left, middle, a, middle_t, work);
    if (hit <= middle_t) return hit;
    hit = locate_between(values, context, count, middle, right, middle_t, b, work);
    if (hit <= b) return hit;
    int dips = 0;
    for (int j = 0; j < count && !dips; j++) dips = bondc_may_dip(left[j], middle[j], right[j]);
    if (!dips) return b + 1.0;
    hit = dip_between(values, context, count, left, middle, a, middle_t, budget, rest);
    if (hit <= middle_t) return hit;
    return dip_between(values, context, count, middle, right, middle_t, b, budget, rest);
}

#define BONDC_DIP_BUDGET 60

int bondc_first_dip(bondc_values_at values, void *context, int count, double a, double b, const double *left,
                    const double *right, double *t_end)
{
    double *scratch = (double *)malloc(sizeof(double) * (size_t)(count > 0 ? count : 1) * 2 * (BONDC_DIP_BUDGET + 2));
    if (!scratch) return -1;
    int budget = BONDC_DIP_BUDGET;
    double hit = dip_between(values, context, count, left, right, a, b, &budget, scratch);
    free(scratch);
    if (hit <= b) { *t_end = hit; return 0; }
    return 1;
}

int bondc_first_end(bondc_values_at values, void *context, int count, double t_old, double t_new, const double *old,
                    const double *now, double longest, double *t_end)
{
    long pieces = longest > 0 ? (long)fmin(ceil((t_new - t_old) / longest), 1e6) : 1;
    if (pieces < 1) pieces = 1;
    size_t size = (size_t)(count > 0 ? count : 1);
    double *work = (double *)malloc(sizeof(double) * size * (2 + 2 * (BONDC_DIP_BUDGET + 2)));
    if (!work) return -1;
    double *before = work, *after = work + size, *scratch = work + 2 * size;
    memcpy(before, old, sizeof(double) * (size_t)count);
    int code = 1;
    for (long i = 0; i < pieces; i++) {
        double a = i == 0 ? t_old : t_old + (t_new - t_old) * (double)i / (double)pieces;
        double b = i + 1 == pieces ? t_new : t_old + (t_new - t_old) * (double)(i + 1) / (double)pieces;
        if (i + 1 == pieces) memcpy(after, now, sizeof(double) * (size_t)count);
        else values(context, b, after);
        double hit = locate_between(values, context, count, before, after, a, b, scratch);
        if (hit > b) {
            int budget = BONDC_DIP_BUDGET;
            hit = dip_between(values, context, count, before, after, a, b, &budget, scratch);
        }
        if (hit <= b) { *t_end = hit; code = 0; break; }
        memcpy(before, after, sizeof(double) * (size_t)count);
    }
    free(work);
    return code;
}

/* One switch's test on the step, positive until it crossed (see bondc_first_crossing) */
typedef struct {
    bondc_values_at values;
    void *context;
    double *g;          /* all switching functions at the last time asked */
    int k, kind;        /* kind 0: sign*g + band; 1: floor, min(g - level, level + 1 - g) + band; 2: level - |g| */
    double sign, band, level;
} bondc_switch_test;

static double switch_test_at(bondc_switch_test *q, double t)
{
    q->values(q->context, t, q->g);
    double g = q->g[q->k];
    if (q->kind == 1) return fmin(g - q->level, q->level + 1.0 - g) + q->band;
    if (q->kind == 2) return q->level - fabs(g);
    return q->sign * g + q->band;
}

/* Where the test goes from > 0 (at a) to <= 0 (at b): the end of a bracket narrowed by the
   Illinois method to 4 eps on the side past the zero; b where the test does not change sign */
static double switch_test_root(bondc_switch_test *q, double a, double b)
{
    const double eps = 2.220446049250313e-16;
    double fa = switch_test_at(q, a), fb = switch_test_at(q, b);
    if (!(fa > 0) || !(fb <= 0)) return b;
    int kept = 0;
    for (int i = 0; i < 200 && b - a > 4 * eps * fmax(fabs(a), fabs(b)) + 1e-300; i++) {
        double t = b - fb * (b - a) / (fb - fa);
        if (!(t > a && t < b)) t = 0.5 * (a + b);
        double ft = switch_test_at(q, t);
        if (ft != ft) { t = 0.5 * (a + b); ft = switch_test_at(q, t); }
        if (ft <= 0) { b = t; fb = ft; if (kept == -1) fa *= 0.5; kept = -1; }
        else { a = t; fa = ft; if (kept == 1) fb *= 0.5; kept = 1; }
        if (ft == 0) break;
    }
    return b;
}

/* The watched switches' tests sign*g + band at t, for the dip search */
typedef struct {
    bondc_values_at values;
    void *context;
    double *g;
    int watched;
    const int *watch;
    const double *signs, *band;
} bondc_watched_values;

static int watched_values_at(void *context, double t, double *out)
{
    bondc_watched_values *w = (bondc_watched_values *)context;
    int code = w->values(w->context, t, w->g);
    for (int j = 0; j < w->watched; j++) out[j] = w->signs[j] * w->g[w->watch[j]] + w->band[j];
    return code;
}

int bondc_first_crossing(bondc_values_at values, void *context, int switches, int watched, const int *watch,
                         const int *floors, const double *signs, const double *band, const double *old,
                         const double *now, double t_old, double t_new, double *t_event)
{
    double *g = (double *)malloc(sizeof(double) * (size_t)(switches > 0 ? switches : 1));
    double *ends = (double *)malloc(sizeof(double) * 3 * (size_t)(watched > 0 ? watched : 1));
    if (!g || !ends) { free(g); free(ends); return -2; }
    int found = -1, simple = 1, moved = 0;
    double best = t_new;
    for (int j = 0; j < watched; j++) simple &= !floors[watch[j]] && signs[j] != 0;
    if (simple) {
        /* the common step: no switch in mode +-1 went below its band; one may have dipped inside */
        double *before = ends, *after = ends + watched, *at = ends + 2 * watched;
        for (int j = 0; j < watched; j++) {
            before[j] = signs[j] * old[j] + band[j];
            after[j] = signs[j] * now[j] + band[j];
            moved |= after[j] < 0 || (after[j] == 0 && before[j] > 0);
        }
        if (!moved) {
            bondc_watched_values w = {values, context, g, watched, watch, signs, band};
            double hit;
            int code = t_old < t_new ? bondc_first_dip(watched_values_at, &w, watched, t_old, t_new, before, after, &hit)
                                     : 1;
            if (code < 0) { found = -2; goto done; }
            if (code == 0) {
                watched_values_at(&w, hit, at);
                int j = 0;      /* the lowest, as numpy's argmin: the first NaN, else the first least */
                for (int i = 1; i < watched && at[j] == at[j]; i++)
                    if (at[i] != at[i] || at[i] < at[j]) j = i;
                /* as a crossing at a step's end: the zero itself (no bias by the band) where it lies before */
                bondc_switch_test q = {values, context, g, watch[j], 0, signs[j], 0.0, 0.0};
                if (band[j] > 0 && t_old < hit && switch_test_at(&q, t_old) > 0 && switch_test_at(&q, hit) <= 0)
                    hit = switch_test_root(&q, t_old, hit);
                best = hit;
                found = j;
            }
            goto done;
        }
    }
    for (int j = 0; j < watched; j++) {
        int k = watch[j];
        double s = signs[j], b = band[j], root;
        bondc_switch_test q = {values, context, g, k, 0, s, b, 0.0};
        if (floors[k]) {
            double before = fmin(old[j] - s, s + 1.0 - old[j]) + b, after = fmin(now[j] - s, s + 1.0 - now[j]) + b;
            if (!(after < 0)) continue;
            if (before <= 0) root = t_old;
            else {      /* where g leaves [m, m + 1) itself: the band only decides whether it did */
                q.kind = 1; q.level = s; q.band = 0.0;
                root = switch_test_root(&q, t_old, t_new);
            }
        } else if (s != 0) {
            double before = s * old[j] + b, after = s * now[j] + b;
            if (!(after < 0 || (after == 0 && before > 0))) continue;
            if (before <= 0) root = t_old;
            else if (after == 0) root = t_new;
            else {
                /* the deadband decides whether it crossed; where the zero itself is in this step, the zero */
                q.band = s * old[j] > 0 ? 0.0 : b;
                root = switch_test_root(&q, t_old, t_new);
            }
        } else {
            if (!(isfinite(now[j]) && fabs(now[j]) > b && now[j] != 0)) continue;
            q.kind = 2;
            q.level = b > 0 ? b : 1e-6 * fabs(now[j]);
            root = switch_test_root(&q, t_old, t_new);
        }
        if (found < 0 || root < best) { best = root; found = j; }
    }
done:
    *t_event = best;
    free(g); free(ends);
    return found;
}
