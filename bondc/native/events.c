/* The when clauses in bondc's engine: see events.h. Included, as filippov.c is, by the CVODE driver
   (driver.c), an FMU's engine and the run loop's policy library (policy.c), after filippov.c. */
#include <math.h>
#include <stddef.h>

#include "events.h"

#define BONDC_WHEN_ROUNDS 10        /* rounds of when clauses at one instant */
#define BONDC_ZENO_FIRINGS 16       /* a clause firing this often with ever shorter intervals ... */
#define BONDC_ZENO_RATIO 0.98       /* ... each at most this times the one before ... */
#define BONDC_ZENO_INTERVAL 1e-4    /* ... the last shorter than this fraction of the run, accumulates */

int bondc_when_rounds(void)
{
    return BONDC_WHEN_ROUNDS;
}

int bondc_zeno_firings(void)
{
    return BONDC_ZENO_FIRINGS;
}

int bondc_when_round(const bondc_whens *w, int n, double t, const double *y, const double *p, const double *before,
                     const double *m, double *after, double *y_new, int *fired, double *values)
{
    int count = w->count, firing = 0;
    for (int q = 0; q < n; q++) y_new[q] = y[q];
    if (count == 0) return 0;
    w->conditions(t, y, p, m, after);
    for (int k = 0; k < count; k++) {
        fired[k] = after[k] != 0.0 && !(before[k] != 0.0);
        firing += fired[k];
    }
    if (!firing) return 0;
    w->actions(t, y, p, m, values);
    for (int k = 0; k < count; k++)
        if (fired[k])
            for (int j = w->target_start[k]; j < w->target_start[k + 1]; j++) y_new[w->targets[j]] = values[j];
    for (int q = 0; q < n; q++)
        if (!isfinite(y_new[q])) return -1;
    return firing;
}

int bondc_zeno(int count, const double *times, double span, double t_end, double *limit, double *ratio)
{
    if (count < BONDC_ZENO_FIRINGS) return 0;
    const double *last = times + count - BONDC_ZENO_FIRINGS;
    double first_gap = last[1] - last[0], gap = first_gap;
    if (!(first_gap > 0.0)) return 0;
    for (int i = 2; i < BONDC_ZENO_FIRINGS; i++) {
        double next = last[i] - last[i - 1];
        if (!(next > 0.0) || next > BONDC_ZENO_RATIO * gap) return 0;
        gap = next;
    }
    if (gap > BONDC_ZENO_INTERVAL * span) return 0;
    double r = pow(gap / first_gap, 1.0 / (BONDC_ZENO_FIRINGS - 2));
    double at = last[BONDC_ZENO_FIRINGS - 1] + gap * r / (1.0 - r);
    if (at >= t_end) return 0;
    *limit = at;
    *ratio = r;
    return 1;
}
