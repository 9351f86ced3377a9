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
