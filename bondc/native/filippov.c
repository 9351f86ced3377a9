/* ---- the switches: their modes, and Filippov sliding (filippov.h) ----

   bondc's one implementation of the modes at a restart and of the choice of a sliding set: the
   Python run loop calls it through cffi (with the model's C functions, or its numpy functions
   called back), the CVODE driver and an FMU's engine call it directly. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "filippov.h"

#define BONDC_MAX_SLIDING 8     /* switches held at once in the multilinear combination (2^8 corners) */
#define BONDC_AFFINE_PAIRS 512  /* pairs of switches an affine combination is tested on, at most */

static double bondc_clip01(double a) { return a < 0 ? 0.0 : (a > 1 ? 1.0 : a); }

void bondc_corner_weights(int k, int affine, const double *alpha, double *w)
{
    if (affine) {
        double sum = 0.0;
        for (int i = 0; i < k; i++) sum += alpha[i];
        w[0] = 1.0 - sum;
        for (int i = 0; i < k; i++) w[1 + i] = alpha[i];
        return;
    }
    for (long c = 0; c < (1L << k); c++) {
        double product = 1.0;
        for (int i = 0; i < k; i++) product *= (c >> i) & 1 ? alpha[i] : 1.0 - alpha[i];
        w[c] = product;
    }
}

/* The minimum-norm least-squares solution x of a x = b (a k x k, row-major, destroyed), singular
   values below rcond of the largest dropped: one-sided Jacobi SVD (a's columns orthogonalised by
   plane rotations accumulated in v). 0, or -1 where memory ran out. */
static int bondc_least_squares(int k, double *a, const double *b, double rcond, double *x, double *v)
{
    for (int i = 0; i < k * k; i++) v[i] = 0.0;
    for (int i = 0; i < k; i++) v[i * k + i] = 1.0;
    for (int sweep = 0; sweep < 60; sweep++) {
        double off = 0.0;
        for (int p = 0; p < k - 1; p++) {
            for (int q = p + 1; q < k; q++) {
                double alpha = 0.0, beta = 0.0, gamma = 0.0;
                for (int r = 0; r < k; r++) {
                    double ap = a[r * k + p], aq = a[r * k + q];
                    alpha += ap * ap; beta += aq * aq; gamma += ap * aq;
                }
                if (gamma == 0.0 || fabs(gamma) <= 1e-15 * sqrt(alpha * beta)) continue;
                off = fmax(off, fabs(gamma) / sqrt(alpha * beta));
                double zeta = (beta - alpha) / (2.0 * gamma);
                double t = (zeta >= 0 ? 1.0 : -1.0) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
                double c = 1.0 / sqrt(1.0 + t * t), s = c * t;
                for (int r = 0; r < k; r++) {
                    double ap = a[r * k + p], aq = a[r * k + q];
                    a[r * k + p] = c * ap - s * aq; a[r * k + q] = s * ap + c * aq;
                    double vp = v[r * k + p], vq = v[r * k + q];
                    v[r * k + p] = c * vp - s * vq; v[r * k + q] = s * vp + c * vq;
                }
            }
        }
        if (off <= 1e-15) break;
    }
    double largest = 0.0;
    for (int j = 0; j < k; j++) {
        double norm = 0.0;
        for (int r = 0; r < k; r++) norm += a[r * k + j] * a[r * k + j];
        largest = fmax(largest, sqrt(norm));
    }
    for (int i = 0; i < k; i++) x[i] = 0.0;
    for (int j = 0; j < k; j++) {
        double norm = 0.0, projection = 0.0;
        for (int r = 0; r < k; r++) { norm += a[r * k + j] * a[r * k + j]; projection += a[r * k + j] * b[r]; }
        double sigma = sqrt(norm);
        if (!(sigma > rcond * largest) || sigma == 0.0) continue;
        double coefficient = projection / (sigma * sigma);     /* (u_j . b) / sigma_j, u_j = a_j / sigma_j */
        for (int i = 0; i < k; i++) x[i] += coefficient * v[i * k + j];
    }
    return 0;
}

size_t bondc_filippov_work(int k, int affine)
{
    return (size_t)(affine ? k + 1 : 1L << k) + 2 * (size_t)k * k + 2 * (size_t)k + 1;
}

int bondc_filippov_alpha_in(int k, int affine, const double *rates, const double *guess, double *alpha, double *work)
{
    for (int i = 0; i < k; i++) alpha[i] = guess ? bondc_clip01(guess[i]) : 0.5;
    if (k == 1) {       /* alpha*r+ + (1 - alpha)*r- = 0 (corner 1 the plus side, 0 the minus) */
        double plus = rates[1], minus = rates[0];
        if (!isfinite(plus) || !isfinite(minus)) { alpha[0] = NAN; return -1; }
        if (minus != plus) alpha[0] = minus / (minus - plus);
        return 0;
    }
    long corners = affine ? k + 1 : 1L << k;
    double *w = work, *jacobian = work + corners, *residual = jacobian + (long)k * k, *delta = residual + k;
    double *v = delta + k;
    int code = 0;
    for (int round = 0; round < (affine ? 3 : 20); round++) {
        bondc_corner_weights(k, affine, alpha, w);
        for (int j = 0; j < k; j++) {
            double sum = 0.0;
            for (long c = 0; c < corners; c++) sum += w[c] * rates[c * k + j];
            residual[j] = -sum;
        }
        /* jacobian[j][i]: d (rate of switch j) / d alpha_i */
        for (int i = 0; i < k; i++) {
            for (int j = 0; j < k; j++) {
                double sum = 0.0;
                if (affine) {
                    sum = rates[(1 + i) * k + j] - rates[j];
                } else {
                    for (long c = 0; c < corners; c++) {
                        double product = (c >> i) & 1 ? 1.0 : -1.0;
                        for (int q = 0; q < k; q++)
                            if (q != i) product *= (c >> q) & 1 ? alpha[q] : 1.0 - alpha[q];
                        sum += product * rates[c * k + j];
                    }
                }
                jacobian[j * k + i] = sum;
            }
        }
        for (int j = 0; j < k * k; j++)
            if (!isfinite(jacobian[j])) code = -1;
        for (int j = 0; j < k; j++)
            if (!isfinite(residual[j])) code = -1;
        if (code != 0) break;
        bondc_least_squares(k, jacobian, residual, 1e-12, delta, v);
        double step = 0.0;
        for (int i = 0; i < k; i++) { alpha[i] += delta[i]; step = fmax(step, fabs(delta[i])); }
        if (step <= 1e-13) break;
    }
    if (code != 0)
        for (int i = 0; i < k; i++) alpha[i] = NAN;
    return code;
}

int bondc_filippov_alpha(int k, int affine, const double *rates, const double *guess, double *alpha)
{
    double *work = (double *)malloc(sizeof(double) * bondc_filippov_work(k, affine));
    if (!work) return -1;
    int code = bondc_filippov_alpha_in(k, affine, rates, guess, alpha, work);
    free(work);
    return code;
}

int bondc_law_deadbands(const bondc_law *law, double t, const double *y, const double *m, const double *scale,
                        int count, const int *index, double *out)
{
    int n = law->n;
    double *base = (double *)malloc(sizeof(double) * (size_t)(law->switches > 0 ? law->switches : 1));
    double *moved = (double *)malloc(sizeof(double) * (size_t)(law->switches > 0 ? law->switches : 1));
    double *shifted = (double *)malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    if (!base || !moved || !shifted) { free(base); free(moved); free(shifted); return -1; }
    for (int j = 0; j < count; j++) out[j] = 0.0;
    law->switching(t, y, law->p, m, base);
    memcpy(shifted, y, sizeof(double) * (size_t)n);
    for (int i = 0; i < n; i++) {
        shifted[i] = y[i] + scale[i];
        law->switching(t, shifted, law->p, m, moved);
        shifted[i] = y[i];
        for (int j = 0; j < count; j++) out[j] += fabs(moved[index[j]] - base[index[j]]);
    }
    for (int j = 0; j < count; j++)
        if (!isfinite(out[j])) out[j] = 0.0;
    free(base); free(moved); free(shifted);
    return 0;
}

/* ---- the sliding set */

typedef struct {
    const bondc_law *law;
    double t, probe;
    const double *y;
    int k, affine;
    long corners;
    const int *sliding;
    double *cm;         /* the corners' mode vectors (corners x switches) */
    double *values;     /* the right-hand side at each corner (corners x n) */
    double *rates;      /* each sliding switch's rate at each corner (corners x k) */
    double *shifted, *g, *g2, *corner;
} bondc_corners;

/* The corners' mode vectors for the modes m and the sliding switches, each taking its vertex on
   its side (as _Run.sliding_corners) */
static void corners_modes(bondc_corners *s, const double *m, const double *vertices)
{
    int count = s->law->switches;
    for (long c = 0; c < s->corners; c++) {
        double *row = s->cm + c * count;
        memcpy(row, m, sizeof(double) * (size_t)count);
        for (int i = 0; i < s->k; i++) {
            int plus = s->affine ? c == 1 + i : (int)((c >> i) & 1);
            row[s->sliding[i]] = (plus ? 1.0 : -1.0) * vertices[s->sliding[i]];
        }
    }
}

/* The right-hand side at (t, y) in corner m into f, and the sliding switches' rates along it into
   rates: central differences over the probe step (as _Run.switch_rate) */
static void corner_rates(bondc_corners *s, double t, const double *y, const double *m, double *f, double *rates)
{
    const bondc_law *law = s->law;
    double h = s->probe;
    law->rhs(t, y, law->p, m, f);
    for (int i = 0; i < law->n; i++) s->shifted[i] = y[i] + h * f[i];
    law->switching(t + h, s->shifted, law->p, m, s->g);
    for (int i = 0; i < law->n; i++) s->shifted[i] = y[i] - h * f[i];
    law->switching(t - h, s->shifted, law->p, m, s->g2);
    for (int j = 0; j < s->k; j++) rates[j] = (s->g[s->sliding[j]] - s->g2[s->sliding[j]]) / (2 * h);
}

static void corners_rates(bondc_corners *s, double t, const double *y)
{
    for (long c = 0; c < s->corners; c++)
        corner_rates(s, t, y, s->cm + c * s->law->switches, s->values + c * s->law->n, s->rates + c * s->k);
}

/* Whether the right-hand side is affine in the sliding switches' weights (as _Run.affine_holds):
   the corners with every pair of switches (at most BONDC_AFFINE_PAIRS, spread over all) and with
   every switch on its plus side give what the k + 1 corners predict, to rounding */
static int affine_holds(bondc_corners *s)
{
    const bondc_law *law = s->law;
    int n = law->n, k = s->k, count = law->switches;
    double *scale = (double *)calloc((size_t)(n > 0 ? n : 1), sizeof(double));
    double *predicted = (double *)malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    double *actual = (double *)malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    int holds = 1;
    if (!scale || !predicted || !actual) { holds = -1; goto done; }
    for (int i = 0; i < n; i++) {
        double largest = 0.0, spread = 0.0;
        for (long c = 0; c <= k; c++) largest = fmax(largest, fabs(s->values[c * n + i]));
        for (long c = 1; c <= k; c++) spread = fmax(spread, fabs(s->values[c * n + i] - s->values[i]));
        scale[i] = largest + spread * k;
    }
    long pairs = (long)k * (k - 1) / 2, stride = (pairs + BONDC_AFFINE_PAIRS - 1) / BONDC_AFFINE_PAIRS;
    if (stride < 1) stride = 1;
    /* the tests: every stride-th pair (in the order i < j), then all switches on their plus side */
    long pair = 0;
    for (int i = 0; i < k && holds == 1; i++) {
        for (int j = i + 1; j < k && holds == 1; j++, pair++) {
            if (pair % stride) continue;
            memcpy(s->corner, s->cm, sizeof(double) * (size_t)count);
            s->corner[s->sliding[i]] = s->cm[(1 + i) * count + s->sliding[i]];
            s->corner[s->sliding[j]] = s->cm[(1 + j) * count + s->sliding[j]];
            law->rhs(s->t, s->y, law->p, s->corner, actual);
            for (int r = 0; r < n; r++) {
                predicted[r] = s->values[r] + (s->values[(1 + i) * n + r] - s->values[r])
                               + (s->values[(1 + j) * n + r] - s->values[r]);
                if (!(fabs(actual[r] - predicted[r]) <= 1e-9 * scale[r] + 1e-300)) holds = 0;
            }
        }
    }
    if (holds == 1) {
        memcpy(s->corner, s->cm, sizeof(double) * (size_t)count);
        for (int i = 0; i < k; i++) s->corner[s->sliding[i]] = s->cm[(1 + i) * count + s->sliding[i]];
        law->rhs(s->t, s->y, law->p, s->corner, actual);
        for (int r = 0; r < n; r++) {
            double sum = s->values[r];
            for (int i = 0; i < k; i++) sum += s->values[(1 + i) * n + r] - s->values[r];
            if (!(fabs(actual[r] - sum) <= 1e-9 * scale[r] + 1e-300)) holds = 0;
        }
    }
done:
    free(scale); free(predicted); free(actual);
    return holds;
}

/* The corners of the sliding set at (t, y), their right-hand sides and rates (as
   _Run.held_corners): the affine combination for three switches or more where the laws combine so,
   else the multilinear one. 0, -1 (memory), -2 (more than BONDC_MAX_SLIDING switches, not affine). */
static int held_corners(bondc_corners *s, const double *m, const double *vertices)
{
    int k = s->k;
    if (k > 2) {
        s->affine = 1;
        s->corners = k + 1;
        corners_modes(s, m, vertices);
        corners_rates(s, s->t, s->y);
        int holds = affine_holds(s);
        if (holds < 0) return -1;
        if (holds) return 0;
        if (k > BONDC_MAX_SLIDING) return -2;
    }
    s->affine = 0;
    s->corners = 1L << k;
    corners_modes(s, m, vertices);
    corners_rates(s, s->t, s->y);
    return 0;
}

/* A coulomb switch that its static limit cannot hold may still be held between its sliding forces
   (its vertex 1): whether that is tried now (as _Run.relax_static_limit) */
static int relax_static_limit(const bondc_law *law, double *vertices, int switch_index)
{
    if (law->vertices[switch_index] != 1.0 && vertices[switch_index] != 1.0) {
        vertices[switch_index] = 1.0;
        return 1;
    }
    return 0;
}

static void remove_at(int *list, int *k, int at)
{
    for (int i = at; i < *k - 1; i++) list[i] = list[i + 1];
    (*k)--;
}

int bondc_sliding_set(const bondc_law *law, double t, const double *y, double *modes, const int *candidates,
                      int count, double probe, double span, const double *scale, double *vertices, int *held,
                      double *alpha, int *affine)
{
    int n = law->n, switches = law->switches, k = count, code = 0;
    size_t nn = (size_t)(n > 0 ? n : 1), ns = (size_t)(switches > 0 ? switches : 1);
    size_t nk = (size_t)(count > 0 ? count : 1);
    /* the most corners: the multilinear 2^k up to BONDC_MAX_SLIDING switches, the affine k + 1 */
    size_t most = (size_t)count + 1;
    if (count <= BONDC_MAX_SLIDING && (1UL << count) > most) most = 1UL << count;
    bondc_corners s;
    memset(&s, 0, sizeof s);
    s.law = law; s.t = t; s.y = y; s.probe = probe;
    int *sliding = (int *)malloc(sizeof(int) * nk);
    s.cm = (double *)malloc(sizeof(double) * most * ns);
    s.values = (double *)malloc(sizeof(double) * most * nn);
    s.rates = (double *)malloc(sizeof(double) * most * nk);
    s.shifted = (double *)malloc(sizeof(double) * nn);
    s.g = (double *)malloc(sizeof(double) * ns);
    s.g2 = (double *)malloc(sizeof(double) * ns);
    s.corner = (double *)malloc(sizeof(double) * ns);
    double *a = (double *)malloc(sizeof(double) * nk);
    double *ahead = (double *)malloc(sizeof(double) * nk);
    double *clipped = (double *)malloc(sizeof(double) * nk);
    double *w = (double *)malloc(sizeof(double) * most);
    double *at = (double *)malloc(sizeof(double) * nn);
    double *f = (double *)malloc(sizeof(double) * nn);
    double *rates_ahead = (double *)malloc(sizeof(double) * most * nk);
    double *residual = (double *)malloc(sizeof(double) * nk);
    double *nil = (double *)malloc(sizeof(double) * nk);
    if (!sliding || !s.cm || !s.values || !s.rates || !s.shifted || !s.g || !s.g2 || !s.corner || !a || !ahead
        || !clipped || !w || !at || !f || !rates_ahead || !residual || !nil) { code = -1; goto done; }
    if (count > 0) memcpy(sliding, candidates, sizeof(int) * (size_t)count);
    for (int j = 0; j < switches; j++) vertices[j] = law->vertices[j];
    s.sliding = sliding;
    *affine = 0;
    while (k > 0) {
        s.k = k;
        int corners_code = held_corners(&s, modes, vertices);
        if (corners_code != 0) { code = corners_code; goto done; }
        long corners = s.corners;
        if (k > 1) {
            /* a switch whose sides give the same right-hand side (a free clutch: both its limits 0)
               holds nothing; among others it would only bend their weights' least squares */
            int free_at = -1;
            for (int i = 0; i < k && free_at < 0; i++) {
                int same = 1;
                if (s.affine) {
                    for (int r = 0; r < n && same; r++) same = s.values[(1 + i) * n + r] == s.values[r];
                } else {
                    for (long c = 0; c < corners && same; c++) {
                        if ((c >> i) & 1) continue;
                        for (int r = 0; r < n && same; r++)
                            same = s.values[c * n + r] == s.values[(c | (1L << i)) * n + r];
                    }
                }
                if (same) free_at = i;
            }
            if (free_at >= 0) {
                int index = sliding[free_at];
                law->switching(t, y, law->p, modes, s.g);
                modes[index] = s.g[index] >= 0 ? 1.0 : -1.0;
                remove_at(sliding, &k, free_at);
                continue;
            }
        }
        bondc_filippov_alpha(k, s.affine, s.rates, NULL, a);
        int finite = 1, edge = 0;
        for (int i = 0; i < k; i++) {
            finite &= isfinite(a[i]) != 0;
            edge |= fmin(a[i], 1.0 - a[i]) < 1e-6;
        }
        if (!finite) break;
        if (edge) {
            /* at the edge (a holding force at its limit, as at the instant a sliding segment ended):
               decide by where the weights go just after t */
            double h = probe;
            for (int i = 0; i < k; i++) clipped[i] = bondc_clip01(a[i]);
            bondc_corner_weights(k, s.affine, clipped, w);
            for (int r = 0; r < n; r++) {
                double sum = 0.0;
                for (long c = 0; c < corners; c++) sum += w[c] * s.values[c * n + r];
                at[r] = y[r] + h * sum;
            }
            int ahead_finite = 1;
            for (long c = 0; c < corners; c++)
                corner_rates(&s, t + h, at, s.cm + c * switches, f, rates_ahead + c * k);
            bondc_filippov_alpha(k, s.affine, rates_ahead, a, ahead);
            for (int i = 0; i < k; i++) ahead_finite &= isfinite(ahead[i]) != 0;
            if (ahead_finite)
                for (int i = 0; i < k; i++)
                    if (fmin(a[i], 1.0 - a[i]) < 1e-6) a[i] = ahead[i];
        }
        for (int i = 0; i < k; i++) clipped[i] = bondc_clip01(a[i]);
        bondc_corner_weights(k, s.affine, clipped, w);
        /* a rate that would move g by less than its deadband over a millionth of the run is nil (a
           surface whose own rate is a state held at zero by the others: second-order sliding) */
        if (bondc_law_deadbands(law, t, y, modes, scale, k, sliding, nil) != 0) { code = -1; goto done; }
        int worst = -1;
        double worst_ratio = -1.0, worst_residual = 0.0;
        for (int j = 0; j < k; j++) {
            double sum = 0.0, largest = 0.0;
            for (long c = 0; c < corners; c++) {
                sum += w[c] * s.rates[c * k + j];
                largest = fmax(largest, fabs(s.rates[c * k + j]));
            }
            residual[j] = sum;
            double bound = fmax(1e-8 * largest, fmax(nil[j] / (1e-6 * span), 1e-300));
            if (fabs(sum) > bound) {
                /* the worst as numpy's argmax picks it: the first NaN ratio, else the first largest */
                double ratio = fabs(sum) / largest;
                if (worst < 0 || (worst_ratio == worst_ratio && (ratio != ratio || ratio > worst_ratio))) {
                    worst = j;
                    worst_ratio = ratio;
                }
            }
        }
        if (worst >= 0) {
            /* no weight stops it (its own law does not act on it: a free clutch): it moves on */
            worst_residual = residual[worst];
            if (relax_static_limit(law, vertices, sliding[worst])) continue;
            modes[sliding[worst]] = worst_residual > 0 ? 1.0 : -1.0;
            remove_at(sliding, &k, worst);
            continue;
        }
        double violation = -INFINITY;
        for (int i = 0; i < k; i++) {
            double v = fmax(a[i] - 1.0, -a[i]);
            if (v > violation) { violation = v; worst = i; }
        }
        if (violation <= 1e-9) {
            for (int i = 0; i < k; i++) { held[i] = sliding[i]; alpha[i] = bondc_clip01(a[i]); }
            *affine = s.affine;
            code = k;
            goto done;
        }
        /* the force needed to hold it exceeds its limit: it leaves towards that side */
        if (relax_static_limit(law, vertices, sliding[worst])) continue;
        modes[sliding[worst]] = a[worst] > 1.0 ? 1.0 : -1.0;
        remove_at(sliding, &k, worst);
    }
    code = 0;
done:
    free(sliding); free(s.cm); free(s.values); free(s.rates); free(s.shifted); free(s.g); free(s.g2);
    free(s.corner); free(a); free(ahead); free(clipped); free(w); free(at); free(f); free(rates_ahead);
    free(residual); free(nil);
    return code;
}

/* ---- the modes */

static int bondc_same(const double *a, const double *b, int n)
{
    for (int i = 0; i < n; i++)
        if (a[i] != b[i]) return 0;
    return 1;
}

static int bondc_all_finite(const double *v, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

int bondc_modes_at(const bondc_law *law, const int *floors, double t, const double *y, const double *guess,
                   double *out, double *scratch)
{
    int count = law->switches, finite = 1;
    double *g = scratch, *next = scratch + count;
    for (int k = 0; k < count; k++) out[k] = guess[k];
    for (int pass = 0; pass <= count; pass++) {
        law->switching(t, y, law->p, out, g);
        if (!bondc_all_finite(g, count)) finite = 0;
        int same = 1;
        for (int k = 0; k < count; k++) {
            double value = g[k];
            double m = value != value ? 0.0 : (floors[k] ? floor(value) : (value > 0 ? 1.0 : (value < 0 ? -1.0 : 0.0)));
            if (m != out[k]) same = 0;
            next[k] = m;
        }
        if (same) return finite;
        for (int k = 0; k < count; k++) out[k] = next[k];
    }
    return finite;
}

/* (the work space of the restart: the rate, the state a probe ahead, the modes there, scratch) */
static int bondc_restart_into(const bondc_law *law, const int *floors, double t, const double *y, const double *guess,
                              double probe, int strict, double *out, double *work)
{
    int n = law->n, count = law->switches;
    double *rate = work, *shifted = work + n, *ahead = work + 2 * n, *scratch = work + 2 * n + count;
    if (!bondc_modes_at(law, floors, t, y, guess, out, scratch) && strict) return -1;
    law->rhs(t, y, law->p, out, rate);
    if (!bondc_all_finite(rate, n)) return strict ? -1 : 1;
    for (int i = 0; i < n; i++) shifted[i] = y[i] + probe * rate[i];
    if (!bondc_modes_at(law, floors, t + probe, shifted, out, ahead, scratch) && strict) return -1;
    for (int k = 0; k < count; k++)
        if (ahead[k] != out[k]) return 0;
    return 1;
}

int bondc_restart_modes(const bondc_law *law, const int *floors, double t, const double *y, const double *guess,
                        double probe, int strict, double *out)
{
    double *work = (double *)malloc(sizeof(double) * (size_t)(2 * law->n + 3 * law->switches + 1));
    if (!work) return -1;
    int code = bondc_restart_into(law, floors, t, y, guess, probe, strict, out, work);
    free(work);
    return code;
}

int bondc_select_modes(const bondc_law *law, const int *floors, double t, const double *y, const double *guess,
                       double probe, double *out, int *flips, double *rows, int *row_count)
{
    enum { ROUNDS = 8 };
    int count = law->switches, n = law->n;
    *row_count = 0;
    for (int k = 0; k < count; k++) flips[k] = 0;
    if (count == 0) return 0;
    double *work = (double *)malloc(sizeof(double) * (size_t)(2 * n + 3 * count + 1));
    double *seen = (double *)malloc(sizeof(double) * (size_t)(ROUNDS + 2) * count);
    double *ahead = (double *)malloc(sizeof(double) * (size_t)count);
    int code = 1, rounds = 1, first = 0;
    if (!work || !seen || !ahead) { code = -1; goto done; }
    if (bondc_restart_into(law, floors, t, y, guess, probe, 0, out, work) == 1) { code = 0; goto done; }
    memcpy(seen, out, sizeof(double) * (size_t)count);
    double *rate = work, *shifted = work + n, *scratch = work + 2 * n + count;
    for (int round = 0; code == 1 && round < ROUNDS; round++) {
        law->rhs(t, y, law->p, out, rate);
        if (!bondc_all_finite(rate, n)) { code = 0; break; }    /* as restart_modes: that law stands */
        for (int i = 0; i < n; i++) shifted[i] = y[i] + probe * rate[i];
        bondc_modes_at(law, floors, t + probe, shifted, out, ahead, scratch);
        if (bondc_same(ahead, out, count)) { code = 0; break; }
        int repeated = -1;
        for (int r = 0; r < rounds && repeated < 0; r++)
            if (bondc_same(ahead, seen + (long)r * count, count)) repeated = r;
        memcpy(out, ahead, sizeof(double) * (size_t)count);
        if (repeated >= 0) { first = repeated; break; }
        memcpy(seen + (long)rounds * count, ahead, sizeof(double) * (size_t)count);
        rounds++;
    }
    if (code == 1) {
        /* the switches that flip within the cycle, from its first repeated row (all rows where none
           repeated), as _Run.restart_modes names them */
        for (int r = first; r < rounds; r++) {
            memcpy(rows + (long)(r - first) * count, seen + (long)r * count, sizeof(double) * (size_t)count);
            for (int k = 0; k < count; k++)
                if (seen[(long)r * count + k] != seen[(long)first * count + k]) flips[k] = 1;
        }
        *row_count = rounds - first;
    }
done:
    free(work); free(seen); free(ahead);
    return code;
}

/* ---- the sliding set with the other switches' modes along the sliding motion */

int bondc_consistent_sliding_set(const bondc_law *law, const int *floors, const int *located,
                                 bondc_relevant_at relevant, void *context, double t, const double *y, double *modes,
                                 const int *candidates, int count, double probe, double span, const double *scale,
                                 double *vertices, int *held, double *alpha, int *affine)
{
    int n = law->n, switches = law->switches, code = 0;
    size_t ns = (size_t)(switches > 0 ? switches : 1), nn = (size_t)(n > 0 ? n : 1);
    int *chosen = (int *)malloc(sizeof(int) * ns);
    int *flipped = (int *)calloc(ns, sizeof(int));
    int *matters = (int *)malloc(sizeof(int) * ns);
    int *changed = (int *)malloc(sizeof(int) * ns);
    double *corner = (double *)malloc(sizeof(double) * ns);
    double *ahead = (double *)malloc(sizeof(double) * ns);
    double *scratch = (double *)malloc(sizeof(double) * 2 * ns);
    size_t most = (size_t)1 << (switches < BONDC_MAX_SLIDING ? switches : BONDC_MAX_SLIDING);
    double *w = (double *)malloc(sizeof(double) * (most > ns + 1 ? most : ns + 1));     /* the corners' weights */
    double *f = (double *)malloc(sizeof(double) * nn);
    double *slope = (double *)calloc(nn, sizeof(double));
    double *at = (double *)malloc(sizeof(double) * nn);
    if (!chosen || !flipped || !matters || !changed || !corner || !ahead || !scratch || !w || !f || !slope || !at) {
        code = -1;
        goto done;
    }
    int k = count;
    if (count > 0) memcpy(chosen, candidates, sizeof(int) * (size_t)count);
    for (int round = 0; round < 2 * BONDC_MAX_SLIDING; round++) {
        code = bondc_sliding_set(law, t, y, modes, chosen, k, probe, span, scale, vertices, held, alpha, affine);
        if (code <= 0) break;
        /* the sliding motion's rate: the corners' right-hand sides in its combination */
        long corners = *affine ? code + 1 : 1L << code;
        bondc_corner_weights(code, *affine, alpha, w);
        for (int i = 0; i < n; i++) slope[i] = 0.0;
        for (long c = 0; c < corners; c++) {
            if (w[c] == 0) continue;
            memcpy(corner, modes, sizeof(double) * ns);
            for (int i = 0; i < code; i++) {
                int plus = *affine ? c == 1 + i : (int)((c >> i) & 1);
                corner[held[i]] = (plus ? 1.0 : -1.0) * vertices[held[i]];
            }
            law->rhs(t, y, law->p, corner, f);
            for (int i = 0; i < n; i++) slope[i] += w[c] * f[i];
        }
        for (int i = 0; i < n; i++) at[i] = y[i] + probe * slope[i];
        bondc_modes_at(law, floors, t + probe, at, modes, ahead, scratch);
        for (int j = 0; j < switches; j++) matters[j] = 1;
        if (relevant && relevant(context, modes, matters) != 0)
            for (int j = 0; j < switches; j++) matters[j] = 1;
        int changes = 0;
        for (int j = 0; j < switches; j++) {
            if (!located[j] || !matters[j] || ahead[j] == modes[j]) continue;
            int candidate = 0;
            for (int i = 0; i < k && !candidate; i++) candidate = chosen[i] == j;
            if (!candidate) changed[changes++] = j;
        }
        if (!changes) break;
        for (int i = 0; i < changes; i++) {
            int j = changed[i];
            if (flipped[j] && k < switches) {
                chosen[k++] = j;
            } else {
                modes[j] = ahead[j];
                flipped[j] = 1;
            }
        }
    }
done:
    free(chosen); free(flipped); free(matters); free(changed); free(corner); free(ahead); free(scratch); free(w);
    free(f); free(slope); free(at);
    return code;
}

/* ---- the candidates of a sliding mode */

/* g_k's gradient over the states (each over its tolerance scale), its squared norm, g_k and its
   deadband at (t, y); 0 where they are not finite or the gradient is nil */
typedef struct {
    double *gradient, *g, *moved, *shifted, *plus, *minus, *fp, *fm;
    double norm, g0, band;
} bondc_near;

static void near_free(bondc_near *q)
{
    free(q->gradient); free(q->g); free(q->moved); free(q->shifted); free(q->plus); free(q->minus); free(q->fp);
    free(q->fm);
}

/* 1 where switch k can be looked at near its surface (q filled), 0 where not, -1 (memory) */
static int near_surface(const bondc_law *law, const int *floors, double vertex, double t, const double *y,
                        const double *m, int k, const double *scale, bondc_near *q)
{
    int n = law->n, count = law->switches;
    size_t nn = (size_t)(n > 0 ? n : 1), ns = (size_t)(count > 0 ? count : 1);
    memset(q, 0, sizeof *q);
    if (vertex != 1.0 || floors[k]) return 0;
    q->gradient = (double *)malloc(sizeof(double) * nn);
    q->g = (double *)malloc(sizeof(double) * ns);
    q->moved = (double *)malloc(sizeof(double) * ns);
    q->shifted = (double *)malloc(sizeof(double) * nn);
    q->plus = (double *)malloc(sizeof(double) * ns);
    q->minus = (double *)malloc(sizeof(double) * ns);
    q->fp = (double *)malloc(sizeof(double) * nn);
    q->fm = (double *)malloc(sizeof(double) * nn);
    if (!q->gradient || !q->g || !q->moved || !q->shifted || !q->plus || !q->minus || !q->fp || !q->fm) return -1;
    law->switching(t, y, law->p, m, q->g);
    q->g0 = q->g[k];
    memcpy(q->shifted, y, sizeof(double) * (size_t)n);
    double band = 0.0, norm = 0.0;
    for (int j = 0; j < n; j++) {
        q->shifted[j] = y[j] + scale[j];
        law->switching(t, q->shifted, law->p, m, q->moved);
        q->shifted[j] = y[j];
        double difference = q->moved[k] - q->g0;
        band += fabs(difference);
        q->gradient[j] = difference / scale[j];
        norm += q->gradient[j] * q->gradient[j];
    }
    q->band = isfinite(band) ? band : 0.0;
    q->norm = norm;
    if (!(isfinite(norm) && norm > 0 && isfinite(q->g0) && q->band > 0)) return 0;
    memcpy(q->plus, m, sizeof(double) * (size_t)count);
    memcpy(q->minus, m, sizeof(double) * (size_t)count);
    q->plus[k] = 1.0;
    q->minus[k] = -1.0;
    return 1;
}

/* the state moved along g's gradient to where g has the value `level`, into q->shifted */
static void near_level(const bondc_law *law, const double *y, const bondc_near *q, double level)
{
    for (int j = 0; j < law->n; j++) q->shifted[j] = y[j] + (level - q->g0) * q->gradient[j] / q->norm;
}

static double near_jump(const bondc_law *law, double t, const double *y, const double *scale, bondc_near *q,
                        double level)
{
    near_level(law, y, q, level);
    law->rhs(t, q->shifted, law->p, q->plus, q->fp);
    law->rhs(t, q->shifted, law->p, q->minus, q->fm);
    double largest = 0.0;
    for (int j = 0; j < law->n; j++) {
        double jump = fabs(q->fp[j] - q->fm[j]) / scale[j];
        if (jump != jump) return NAN;
        largest = fmax(largest, jump);
    }
    return largest;
}

int bondc_continuous_across(const bondc_law *law, const int *floors, double vertex, double t, const double *y,
                            const double *m, int k, const double *scale)
{
    bondc_near q;
    int code = near_surface(law, floors, vertex, t, y, m, k, scale, &q), continuous = 0;
    if (code == 1) {
        double near = near_jump(law, t, y, scale, &q, q.band), far = near_jump(law, t, y, scale, &q, 100.0 * q.band);
        continuous = isfinite(near) && isfinite(far) && far > 0 && near <= 0.3 * far;
    }
    near_free(&q);
    return code < 0 ? -1 : continuous;
}

int bondc_keeps_to(const bondc_law *law, const int *floors, double vertex, double t, const double *y,
                   const double *m, int k, const double *scale, double probe, double span)
{
    bondc_near q;
    int code = near_surface(law, floors, vertex, t, y, m, k, scale, &q), keeps = 0;
    if (code == 1) {
        /* on the surface, g's rate along the plus side's law (central difference over the probe) */
        near_level(law, y, &q, 0.0);
        double *at = q.gradient;        /* (the gradient is not needed any more) */
        memcpy(at, q.shifted, sizeof(double) * (size_t)law->n);
        law->rhs(t, at, law->p, q.plus, q.fp);
        double h = probe;
        for (int j = 0; j < law->n; j++) q.shifted[j] = at[j] + h * q.fp[j];
        law->switching(t + h, q.shifted, law->p, q.plus, q.g);
        double ahead = q.g[k];
        for (int j = 0; j < law->n; j++) q.shifted[j] = at[j] - h * q.fp[j];
        law->switching(t - h, q.shifted, law->p, q.plus, q.g);
        double rate = (ahead - q.g[k]) / (2 * h);
        keeps = isfinite(rate) && fabs(rate) * 1e-3 * span <= q.band;
    }
    near_free(&q);
    return code < 0 ? -1 : keeps;
}

int bondc_sliding_candidates(const bondc_law *law, const int *floors, const int *located, const int *slid,
                             const int *relevant, const double *vertices, double t, const double *y, const double *m,
                             const int *chattering, int count, const double *scale, int *out)
{
    int switches = law->switches, found = 0;
    size_t ns = (size_t)(switches > 0 ? switches : 1);
    int *mark = (int *)calloc(ns, sizeof(int));
    double *g = (double *)malloc(sizeof(double) * ns);
    double *band = (double *)malloc(sizeof(double) * ns);
    int *index = (int *)malloc(sizeof(int) * ns);
    if (!mark || !g || !band || !index) { found = -1; goto done; }
    for (int i = 0; i < count; i++)
        if (!floors[chattering[i]]) mark[chattering[i]] = 1;      /* an integer mode cannot slide */
    int keep = 0;
    for (int k = 0; k < switches; k++)
        if (located[k] && !mark[k] && (law->vertices[k] != 1.0 || slid[k]) && relevant[k]) index[keep++] = k;
    if (keep) {
        /* on the surface: |g| within its deadband (the integration noise of the state) */
        law->switching(t, y, law->p, m, g);
        if (bondc_law_deadbands(law, t, y, m, scale, keep, index, band) != 0) { found = -1; goto done; }
        for (int i = 0; i < keep; i++)
            if (fabs(g[index[i]]) <= band[i]) mark[index[i]] = 1;
    }
    for (int k = 0; k < switches; k++) {
        if (!mark[k]) continue;
        int continuous = bondc_continuous_across(law, floors, vertices[k], t, y, m, k, scale);
        if (continuous < 0) { found = -1; goto done; }
        if (!continuous) out[found++] = k;
    }
done:
    free(mark); free(g); free(band); free(index);
    return found;
}

/* ---- back onto the surfaces at a sliding mode's end */

/* Solve the k x k system a x = b (a row-major, destroyed; b becomes x) by Gaussian elimination with
   partial pivoting: 0, or -1 where a pivot is not above `tiny` times the largest entry (0: where one
   is 0, as LAPACK's gesv finds a system singular) */
static int bondc_solve(int k, double *a, double *b, double tiny)
{
    double largest = 0.0;
    for (int i = 0; i < k * k; i++) largest = fmax(largest, fabs(a[i]));
    if (!(largest > 0)) return -1;
    for (int col = 0; col < k; col++) {
        int pivot = col;
        for (int r = col + 1; r < k; r++)
            if (fabs(a[r * k + col]) > fabs(a[pivot * k + col])) pivot = r;
        if (!(fabs(a[pivot * k + col]) > tiny * largest)) return -1;
        if (pivot != col) {
            for (int c = 0; c < k; c++) { double x = a[col * k + c]; a[col * k + c] = a[pivot * k + c]; a[pivot * k + c] = x; }
            double x = b[col]; b[col] = b[pivot]; b[pivot] = x;
        }
        for (int r = col + 1; r < k; r++) {
            double factor = a[r * k + col] / a[col * k + col];
            if (factor == 0) continue;
            for (int c = col; c < k; c++) a[r * k + c] -= factor * a[col * k + c];
            b[r] -= factor * b[col];
        }
    }
    for (int r = k - 1; r >= 0; r--) {
        double sum = b[r];
        for (int c = r + 1; c < k; c++) sum -= a[r * k + c] * b[c];
        b[r] = sum / a[r * k + r];
    }
    return 0;
}

int bondc_onto_surfaces(const bondc_law *law, const int *floors, double t, double *y, const double *m,
                        const int *held, int k, int affine, const double *vertices, const double *alpha,
                        double probe, const double *scale)
{
    int n = law->n, switches = law->switches, code = 0;
    if (k <= 0) return 0;
    for (int i = 0; i < k; i++)
        if (floors[held[i]]) return 0;
    size_t nn = (size_t)(n > 0 ? n : 1), ns = (size_t)(switches > 0 ? switches : 1), nk = (size_t)k;
    long corners = affine ? k + 1 : 1L << k;
    bondc_corners s;
    memset(&s, 0, sizeof s);
    s.law = law; s.t = t; s.y = y; s.probe = probe; s.k = k; s.affine = affine; s.corners = corners;
    s.sliding = held;
    s.cm = (double *)malloc(sizeof(double) * (size_t)corners * ns);
    s.values = (double *)malloc(sizeof(double) * (size_t)corners * nn);
    s.rates = (double *)malloc(sizeof(double) * (size_t)corners * nk);
    s.shifted = (double *)malloc(sizeof(double) * nn);
    s.g = (double *)malloc(sizeof(double) * ns);
    s.g2 = (double *)malloc(sizeof(double) * ns);
    double *g = (double *)malloc(sizeof(double) * ns), *band = (double *)malloc(sizeof(double) * nk);
    double *weights = (double *)malloc(sizeof(double) * nk), *jacobian = (double *)malloc(sizeof(double) * nk * nn);
    double *normal = (double *)malloc(sizeof(double) * nk * nk), *multipliers = (double *)malloc(sizeof(double) * nk);
    double *moved = (double *)malloc(sizeof(double) * ns), *corrected = (double *)malloc(sizeof(double) * nn);
    if (!s.cm || !s.values || !s.rates || !s.shifted || !s.g || !s.g2 || !g || !band || !weights || !jacobian
        || !normal || !multipliers || !moved || !corrected) { code = -1; goto done; }
    law->switching(t, y, law->p, m, g);
    if (bondc_law_deadbands(law, t, y, m, scale, k, held, band) != 0) { code = -1; goto done; }
    int off = 0, far = 0;
    for (int i = 0; i < k; i++) {
        double value = g[held[i]];
        if (!isfinite(value)) goto done;
        off |= fabs(value) > band[i];
        far |= fabs(value) > 1e6 * band[i];
    }
    if (!off || far) goto done;
    /* the weights now: at a break-away (one at 0 or 1) the switch leaves its surface here */
    corners_modes(&s, m, vertices);
    corners_rates(&s, t, y);
    bondc_filippov_alpha(k, affine, s.rates, alpha, weights);
    for (int i = 0; i < k; i++)
        if (!isfinite(weights[i]) || fmin(weights[i], 1.0 - weights[i]) <= 1e-6) goto done;
    /* the held g's Jacobian over the states, each over its tolerance */
    memcpy(s.shifted, y, sizeof(double) * (size_t)n);
    for (int j = 0; j < n; j++) {
        s.shifted[j] = y[j] + scale[j];
        law->switching(t, s.shifted, law->p, m, moved);
        s.shifted[j] = y[j];
        for (int i = 0; i < k; i++) jacobian[(long)i * n + j] = (moved[held[i]] - g[held[i]]) / scale[j];
    }
    /* (J W J^T) multipliers = -g, W = scale^2; the correction W J^T multipliers */
    for (int a = 0; a < k; a++) {
        for (int b = 0; b < k; b++) {
            double sum = 0.0;
            for (int j = 0; j < n; j++)
                sum += jacobian[(long)a * n + j] * (scale[j] * scale[j]) * jacobian[(long)b * n + j];
            normal[a * k + b] = sum;
        }
        multipliers[a] = -g[held[a]];
    }
    if (bondc_solve(k, normal, multipliers, 0.0) != 0) goto done;
    for (int j = 0; j < n; j++) {
        double sum = 0.0;
        for (int i = 0; i < k; i++) sum += jacobian[(long)i * n + j] * multipliers[i];
        corrected[j] = y[j] + (scale[j] * scale[j]) * sum;
        if (!isfinite(corrected[j])) goto done;
    }
    memcpy(y, corrected, sizeof(double) * (size_t)n);
    code = 1;
done:
    free(s.cm); free(s.values); free(s.rates); free(s.shifted); free(s.g); free(s.g2); free(g); free(band);
    free(weights); free(jacobian); free(normal); free(multipliers); free(moved); free(corrected);
    return code;
}
