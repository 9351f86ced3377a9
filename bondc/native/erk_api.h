/* The table of functions of bondc's explicit Runge-Kutta stepper (erk.cpp, a library of its own, built
   once per machine): the CVODE driver (driver.c) gets its address from Python and calls it in place of
   CVODE's (bondc_driver_explicit). */
#ifndef BONDC_ERK_API_H
#define BONDC_ERK_API_H

typedef int (*bondc_erk_rhs)(double t, const double *y, double *dydt, void *data);
typedef struct {
    int version;
    void *(*create)(int n);
    void (*destroy)(void *stepper);
    int (*start)(void *stepper, bondc_erk_rhs rhs, void *data, double t0, const double *y0, double t_stop,
                 double rtol, double atol, double max_step, double first_step, long max_steps);
    int (*step)(void *stepper, double *t, double *y);
    int (*dky)(void *stepper, double t, double *out);
    double (*last_step)(void *stepper);
    void (*counts)(void *stepper, long *out);
} bondc_erk_api;

#endif
