/* ---- bondc's explicit Runge-Kutta stepper: Boost.Odeint's Dormand-Prince 5(4) pair and its
   continuous extension, its steps controlled as scipy's RK45 controls them (so that a model's C code
   and its numpy code, which runs scipy's RK45, take the same steps); a C table of functions
   (bondc_erk_api) that bondc's driver calls in place of CVODE's ---- */
#include <algorithm>
#include <cfloat>
#include <cmath>
#include <vector>
#include <boost/numeric/odeint/stepper/controlled_runge_kutta.hpp>
#include <boost/numeric/odeint/stepper/runge_kutta_dopri5.hpp>

extern "C" {
#include "erk_api.h"
const bondc_erk_api *bondc_erk_table(void);
}

namespace {

namespace odeint = boost::numeric::odeint;
typedef std::vector<double> state;

struct rhs_failed {};

/* scipy's error norm: the root mean square of the error estimate over atol + rtol*max(|y|, |y_new|),
   y_new the step's end (try_step's output, which the checker reads) */
struct rk45_error_checker {
    typedef double value_type;
    typedef double time_type;
    const state *x_new;
    double atol, rtol;

    template <class Algebra, class State, class Deriv, class Err, class Time>
    double error(Algebra &, const State &x_old, const Deriv &, Err &x_err, Time) const
    {
        double sum = 0.0;
        const std::size_t n = x_old.size();
        for (std::size_t i = 0; i < n; i++) {
            double w = x_err[i] / (atol + rtol * std::max(std::fabs(x_old[i]), std::fabs((*x_new)[i])));
            sum += w * w;
        }
        double norm = n ? std::sqrt(sum / n) : 0.0;
        /* a rate not finite at one of the step's trial points (every stage's rate enters the
           estimate or the state at the step's end): the step fails, as the caller's finiteness test
           of each rate would fail it */
        if (!std::isfinite(norm)) throw rhs_failed();
        return norm == 1.0 ? std::nextafter(1.0, 2.0) : norm;   /* scipy accepts below 1 only */
    }
};

/* scipy's step size factors: 0.9 err^(-1/5), at most 10 after an accepted step (10 where err is 0),
   at least 0.2 after a rejected one (the caller keeps a step that follows a rejection from growing) */
struct rk45_step_adjuster {
    typedef double time_type;
    typedef double value_type;

    double decrease_step(double dt, double error, int) const { return dt * std::max(0.2, 0.9 * std::pow(error, -0.2)); }
    double increase_step(double dt, double error, int) const
    {
        return dt * (error == 0.0 ? 10.0 : std::min(10.0, 0.9 * std::pow(error, -0.2)));
    }
    bool check_step_size_limit(double) { return true; }
    double get_max_dt() { return 0.0; }
};

typedef odeint::runge_kutta_dopri5<state> dopri5;
typedef odeint::controlled_runge_kutta<dopri5, rk45_error_checker, rk45_step_adjuster> controlled;

struct stepper {
    int n;
    state x, dxdt, x_new, dxdt_new, x_old, dxdt_old, dense;
    controlled control;
    double t = 0.0, t_old = 0.0, dt = 0.0, t_stop = 0.0, max_step = 0.0, atol = 1e-9, rtol = 1e-6;
    long evaluations = 0, steps = 0, rejected = 0, max_steps = 0;
    bondc_erk_rhs rhs = nullptr;
    void *data = nullptr;

    explicit stepper(int size)
        : n(size), x(size), dxdt(size), x_new(size), dxdt_new(size), x_old(size), dxdt_old(size), dense(size),
          control(rk45_error_checker{&x_new, 1e-9, 1e-6}) {}
};

struct model_system {
    stepper *s;

    void operator()(const state &x, state &dxdt, double t) const
    {
        s->evaluations++;
        if (s->rhs(t, x.data(), dxdt.data(), s->data) != 0) throw rhs_failed();
    }
};

double scaled_rms(const stepper *s, const state &v)
{
    double sum = 0.0;
    for (int i = 0; i < s->n; i++) {
        double w = v[i] / (s->atol + s->rtol * std::fabs(s->x[i]));
        sum += w * w;
    }
    return s->n ? std::sqrt(sum / s->n) : 0.0;
}

/* The first step as scipy's select_initial_step chooses it (Hairer, Norsett and Wanner, Solving
   ODEs I, II.4): from the sizes of y0, f0 and of f's change over an Euler step */
double first_step_size(stepper *s, double span)
{
    double d0 = scaled_rms(s, s->x), d1 = scaled_rms(s, s->dxdt);
    double h0 = (d0 < 1e-5 || d1 < 1e-5) ? 1e-6 : 0.01 * d0 / d1;
    h0 = std::min(h0, span);
    for (int i = 0; i < s->n; i++) s->x_new[i] = s->x[i] + h0 * s->dxdt[i];
    model_system{s}(s->x_new, s->dxdt_new, s->t + h0);
    for (int i = 0; i < s->n; i++) s->dense[i] = s->dxdt_new[i] - s->dxdt[i];
    double d2 = scaled_rms(s, s->dense) / h0;
    double h1 = (d1 <= 1e-15 && d2 <= 1e-15) ? std::max(1e-6, h0 * 1e-3)
                                              : std::pow(0.01 / std::max(d1, d2), 1.0 / 5.0);
    return std::min(std::min(100.0 * h0, h1), span);
}

/* ten spacings of the floats at t: scipy's smallest step */
double min_step(double t) { return 10.0 * std::fabs(std::nextafter(t, HUGE_VAL) - t); }

void *create(int n)
{
    try {
        return new stepper(n);
    } catch (...) {
        return nullptr;
    }
}

void destroy(void *memory) { delete static_cast<stepper *>(memory); }

/* Start (or restart) at (t0, y0) towards t_stop: 0, -1 where the right-hand side failed, -2 where
   the first step cannot be chosen. The counts start again from 0, as CVodeReInit's do. */
int start(void *memory, bondc_erk_rhs rhs, void *data, double t0, const double *y0, double t_stop, double rtol,
          double atol, double max_step, double first_step, long max_steps)
{
    stepper *s = static_cast<stepper *>(memory);
    s->rhs = rhs; s->data = data;
    s->t = s->t_old = t0; s->t_stop = t_stop;
    s->rtol = rtol; s->atol = atol;
    s->max_step = max_step > 0 ? max_step : HUGE_VAL;
    s->max_steps = max_steps;
    s->evaluations = s->steps = s->rejected = 0;
    s->control = controlled(rk45_error_checker{&s->x_new, atol, rtol});
    std::copy(y0, y0 + s->n, s->x.begin());
    try {
        model_system{s}(s->x, s->dxdt, t0);
        s->dt = first_step > 0 ? first_step : first_step_size(s, t_stop - t0);
    } catch (rhs_failed &) {
        return -1;
    } catch (...) {
        return -2;
    }
    if (!(s->dt > 0) || !std::isfinite(s->dt)) return -2;
    s->x_old = s->x; s->dxdt_old = s->dxdt;
    return 0;
}

/* One accepted step, never past t_stop (the last one ends on it exactly), as scipy's RK45 takes
   it: 0, -1 where the right-hand side failed at a trial point (nothing of that attempt is kept),
   -2 where the step size fell below scipy's smallest, -3 after max_steps attempts rejected in a
   row (CVODE's limit of work for one return), -4 at t_stop already */
int step(void *memory, double *t_out, double *y_out)
{
    stepper *s = static_cast<stepper *>(memory);
    if (!(s->t < s->t_stop)) return -4;
    double smallest = min_step(s->t);
    double h = s->dt > s->max_step ? s->max_step : (s->dt < smallest ? smallest : s->dt);
    bool rejected = false;
    for (long attempts = 0;; attempts++) {
        if (h < smallest) return -2;
        if (s->max_steps > 0 && attempts >= s->max_steps) return -3;
        double t_new = s->t + h;
        bool last = t_new > s->t_stop;
        if (last) { t_new = s->t_stop; h = t_new - s->t; }
        double t = s->t, proposed = h;
        odeint::controlled_step_result result;
        try {
            result = s->control.try_step(model_system{s}, s->x, s->dxdt, t, s->x_new, s->dxdt_new, proposed);
        } catch (rhs_failed &) {
            return -1;
        } catch (...) {
            return -2;
        }
        if (result == odeint::success) {
            s->x_old.swap(s->x); s->dxdt_old.swap(s->dxdt);
            s->x.swap(s->x_new); s->dxdt.swap(s->dxdt_new);
            s->t_old = s->t;
            s->t = last ? s->t_stop : t_new;
            s->dt = rejected ? std::min(proposed, h) : proposed;
            s->steps++;
            *t_out = s->t;
            std::copy(s->x.begin(), s->x.end(), y_out);
            return 0;
        }
        s->rejected++;
        rejected = true;
        h = proposed;
    }
}

/* The state at t inside the last step, from the pair's continuous extension (order 4) */
int dky(void *memory, double t, double *out)
{
    stepper *s = static_cast<stepper *>(memory);
    if (t == s->t || s->t == s->t_old) {
        std::copy(s->x.begin(), s->x.end(), out);
        return 0;
    }
    s->control.stepper().calc_state(t, s->dense, s->x_old, s->dxdt_old, s->t_old, s->x, s->dxdt, s->t);
    std::copy(s->dense.begin(), s->dense.end(), out);
    return 0;
}

double last_step(void *memory)
{
    stepper *s = static_cast<stepper *>(memory);
    return s->t - s->t_old;
}

/* evaluations of the right-hand side, steps and rejected steps since the last start */
void counts(void *memory, long *out)
{
    stepper *s = static_cast<stepper *>(memory);
    out[0] = s->evaluations; out[1] = s->steps; out[2] = s->rejected;
}

const bondc_erk_api table = {1, create, destroy, start, step, dky, last_step, counts};

}   // namespace

const bondc_erk_api *bondc_erk_table(void) { return &table; }
