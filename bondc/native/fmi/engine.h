/* bondc's engine inside an FMU (engine.c): the model's C code (bondc_model.h, written by
   bondc.export.ccode) integrated by bondc's CVODE driver (driver.c), with the state of one FMU
   instance. The FMI wrappers (fmi2.c, fmi3.c) call these functions and nothing else of the model. */
#ifndef BONDC_FMU_ENGINE_H
#define BONDC_FMU_ENGINE_H

#include <stddef.h>

typedef struct bondc_fmu bondc_fmu;

struct bondc_fmu {
    double t;               /* the time the state x stands at */
    double rtol, atol, max_step, span, probe;
    double t_stop;          /* the run's end (the importer's stop time, else start + the experiment's t_end) */
    double *p;              /* the parameters, then the external inputs' values (bondc_model.h's p) */
    double *x;              /* the state */
    double *m;              /* the modes, valid at (t, x) where `selected` */
    int selected;           /* 0: the modes are selected again before anything is evaluated */
    int states_set;         /* the importer set the state (Model Exchange): not x0(p) at initialisation */
    int failed;
    long events;            /* mode changes and when clauses fired so far */
    char message[600];      /* why the last call failed */
    /* a Filippov sliding mode the state stands in (Co-Simulation): `holding` switches, the corners'
       mode vectors and weights, for the outputs (their combination); `slid` the switches the last
       sliding mode held; `chattering`: the modes selected last cycle (the switches slide) */
    int holding, corners, chattering;
    int *slid, *flips, *relevant;
    double *cm, *weights;
    /* work space */
    struct bondc_driver *d;
    struct bondc_law *law;
    struct bondc_whens *whens;
    int *fired, *firing_count;  /* the when clauses that fired last round; each one's firings kept */
    double *firings;            /* each clause's last bondc_zeno_firings() firing times (Zeno) */
    int *candidates, *held, *others;
    double *scale, *vertices, *alpha, *alphas, *exits, *exits_old, *drift, *corner, *out;
    int watched;
    int *watch;
    double *signs, *band, *g_old, *g, *f, *old, *conditions, *after, *values;
    double *ts, *ys;
};

bondc_fmu *bondc_fmu_new(void);
void bondc_fmu_free(bondc_fmu *c);
/* the default parameters and inputs, t = 0, the initial state x0(p) */
void bondc_fmu_reset(bondc_fmu *c);
/* tolerances of the integration (relative, absolute) and the run's span (the probe of mode selection) */
void bondc_fmu_setup(bondc_fmu *c, double rtol, double t_start, double t_stop);
/* p changed: the parameters computed from others again; with `state`, the initial state again */
void bondc_fmu_parameters_changed(bondc_fmu *c, int state);
/* select the modes at (t, x) where they are not (after a start, a jump of time, a parameter or input
   change) and fire the when clauses whose condition became true; *changed: x changed. 0 or -1 */
int bondc_fmu_event(bondc_fmu *c, int *changed);
/* Co-Simulation: integrate from t to t_end with CVODE (the driver), locating every crossing of a
   switching function and selecting the modes after it; 0 or -1 (message says why) */
int bondc_fmu_advance(bondc_fmu *c, double t_end);
void bondc_fmu_derivatives(bondc_fmu *c, double *out);
void bondc_fmu_outputs(bondc_fmu *c, double *out);
/* the event indicators: the located switches' switching functions with the current modes */
int bondc_fmu_indicator_count(void);
void bondc_fmu_indicators(bondc_fmu *c, double *out);

/* Model Exchange, what the importer asks (the same in FMI 2.0 and 3.0): 0, -1 where the engine
   failed (message says why), -2 where the call gives the wrong number of values */
/* the modes after an event the importer found, and the when clauses; *changed: x changed */
int bondc_fmu_event_update(bondc_fmu *c, int *changed);
int bondc_fmu_set_states(bondc_fmu *c, const double *x, size_t n);
int bondc_fmu_get_states(bondc_fmu *c, double *x, size_t n);
int bondc_fmu_get_derivatives(bondc_fmu *c, double *out, size_t n);
int bondc_fmu_get_indicators(bondc_fmu *c, double *out, size_t n);

#endif
