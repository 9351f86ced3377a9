/* The functions of bondc's CVODE driver (driver.c) that Python calls: bondc.runtime gives this text to
   cffi's cdef, which reads declarations and comments only (no preprocessor lines here). */
typedef struct bondc_driver bondc_driver;
bondc_driver *bondc_driver_new(int n, int switches, int entries, const int *rows, const int *cols,
                               int banded, int lower, int upper, int adams, double *p);
int bondc_driver_start(bondc_driver *d, double t0, const double *y0, const double *m, double t_stop,
                       double rtol, double atol, double max_step, double first_step, long max_steps);
int bondc_driver_advance(bondc_driver *d, int capacity, int watched, const int *watch, const double *signs,
                         const double *band, double *g_old, double *ts, double *ys, int *count,
                         const double *t_eval, int n_eval, int *eval_next, int eval_capacity, double *et,
                         double *ey, int *eval_count);
int bondc_driver_dky(bondc_driver *d, double t, int k, double *out);
int bondc_driver_jac_entries(bondc_driver *d, double t, const double *y, double *out);
int bondc_driver_sliding(bondc_driver *d);
int bondc_deadbands(bondc_driver *d, double t, const double *y, const double *m, double rtol, double atol,
                    int count, const int *index, double *out);
void bondc_driver_check(bondc_driver *d, double longest);
void bondc_driver_slide(bondc_driver *d, int k, const double *mp, const double *mm, double alpha, double probe,
                        int count, const int *others, const double *drift);
int bondc_driver_slide_many(bondc_driver *d, int k, const int *sliding, int corners, int affine, const double *cm,
                            const double *alphas, double probe, int count, const int *others, const double *drift);
int bondc_driver_slide_advance(bondc_driver *d, int capacity, double *old, double *exits, double *ts,
                               double *ys, double *alphas, int *count, const double *t_eval, int n_eval,
                               int *eval_next, int eval_capacity, double *et, double *ey, int *eval_count);
void bondc_driver_exits(bondc_driver *d, double t, const double *y, double *out);
int bondc_driver_slide_end(bondc_driver *d, double t_old, double t_new, const double *old, const double *now,
                           double longest, double *t_end);
int bondc_driver_unfrozen_advance(bondc_driver *d, int capacity, const int *floors, double *ts, double *ys,
                                  double *ms, int *count, const double *t_eval, int n_eval, int *eval_next,
                                  int eval_capacity, double *et, double *ey, int *eval_count);
void bondc_driver_counts(bondc_driver *d, long *out);
int bondc_driver_pieces(bondc_driver *d, int pieces, const double *t_stops, double t0, const double *y0,
                        const double *m0, const int *floors, int watched, const int *watch, const int *held,
                        int strict, double probe, double rtol, double atol, double max_step, double first_step,
                        int capacity, double *ts, double *ys, int *ends, double *modes, long *counts, int *partial,
                        double *g_left, int whens, const int *target_start, const int *targets, double *starts,
                        double *guesses);
void bondc_driver_free(bondc_driver *d);
int bondc_driver_explicit(bondc_driver *d, const void *api);
int bondc_when_native(void);
int bondc_driver_select(bondc_driver *d, double t, const double *y, const double *guess, const int *floors,
                        double probe, double *out, int *flips);
int bondc_driver_crossing(bondc_driver *d, int watched, const int *watch, const double *signs, const double *band,
                          const double *g_old, const int *floors, const double *m, double t_old, double t_new,
                          const double *y_new, double *g_new, double *t_event);
