/* The switches in bondc's engine (filippov.c): their modes at a point and after a restart, and
   Filippov sliding (the weights of a sliding mode's corners and the choice of the switches that a
   sliding mode holds). One implementation, built three ways: into a
   model's library with the CVODE driver (driver.c includes it), into an FMU's binary, and alone once
   per machine (bondc.runtime.native.load_filippov) for runs whose laws are numpy functions, which
   it calls back. cffi's cdef reads this text: declarations and comments only, no preprocessor lines.

   The corners of a sliding mode on k switches: multilinear, 2^k of them, corner c with switch i on
   its plus side where bit i of c is set; affine, k + 1 of them, corner 0 with every switch on its
   minus side and corner 1 + i with switch i alone on its plus side (where the laws are affine in
   each switch's weight, as a friction force added to sums of forces is). */

/* A law to evaluate at time t and state x with the parameters p and the modes m frozen, into out */
typedef void (*bondc_law_function)(double t, const double *x, const double *p, const double *m, double *out);

/* The model's laws as the sliding functions call them: n states, `switches` switching functions */
typedef struct bondc_law {
    int n, switches;
    const double *p;
    bondc_law_function rhs;         /* the right-hand side, n values */
    bondc_law_function switching;   /* the switching functions, `switches` values */
    const double *vertices;         /* each switch's mode on its plus side: 1 (sign, if) or 2 (coulomb) */
} bondc_law;

/* The corners' weights w for the sliding weights alpha (k of them): affine, 1 - sum(alpha) and each
   alpha_i; multilinear, the product over i of alpha_i (plus side) or 1 - alpha_i (minus side). */
void bondc_corner_weights(int k, int affine, const double *alpha, double *w);

/* The weights alpha (k, not clipped) that make each sliding switch's rate zero, from the rates
   (corners x k: corner c's rate of switch j at c * k + j) and a guess (NULL: 1/2 each; clipped to
   [0, 1]): for one switch the root of the linear rate; else Newton's method (3 rounds affine, 20
   multilinear) with the minimum-norm least-squares step (singular values below 1e-12 of the largest
   dropped), so a switch whose rate does not depend on its own weight keeps its guess. 0, or -1
   where a rate or the Newton matrix is not finite (alpha then NaN). */
int bondc_filippov_alpha(int k, int affine, const double *rates, const double *guess, double *alpha);
/* The same with the caller's work space: bondc_filippov_work(k, affine) values (no allocation: the
   CVODE driver solves the weights at every evaluation of a sliding mode's rates) */
int bondc_filippov_alpha_in(int k, int affine, const double *rates, const double *guess, double *alpha, double *work);
size_t bondc_filippov_work(int k, int affine);

/* How far each switching function of `index` (count of them) moves when each state moves by its
   error tolerance scale[i] (atol + rtol*|y_i|), summed over the states: crossings shallower than
   that are integration noise. Not finite values give 0. 0, or -1 where memory ran out. */
int bondc_law_deadbands(const bondc_law *law, double t, const double *y, const double *m, const double *scale,
                        int count, const int *index, double *out);

/* Which of the `count` switches `candidates` a sliding mode holds at (t, y) (complementarity by an
   active set): a switch whose weight leaves [0, 1] cannot be held and takes that side in `modes`
   (updated in place); one whose own weight cannot stop its rate (a free clutch) moves on; a coulomb
   switch that its static limit cannot hold is tried between its sliding forces (its vertex 1 in
   `vertices`, which starts as law->vertices and is updated in place). `probe` is the time step of
   the rates' central differences, `span` the run's, `scale` each state's error tolerance. Returns
   the number of held switches (into `held`, their weights clipped into `alpha`, whether they
   combine affinely into *affine), -1 where memory ran out, -2 where more than 8 switches would be
   held whose laws do not combine affinely. */
int bondc_sliding_set(const bondc_law *law, double t, const double *y, double *modes, const int *candidates,
                      int count, double probe, double span, const double *scale, double *vertices, int *held,
                      double *alpha, int *affine);

/* The modes of the unfrozen law at (t, y): m = sign(g(t, y, m)) (floor(g) where floors[k]; 0 where g
   is NaN), iterated from `guess` until it repeats (at most switches + 1 passes: a nested switch's
   function reads the modes of the switches inside it). `scratch`: 2 * switches values. Returns 1
   where every switching function was finite, 0 where one was not. */
int bondc_modes_at(const bondc_law *law, const int *floors, double t, const double *y, const double *guess,
                   double *out, double *scratch);

/* The modes just after a restart at (t, y), from `guess`, into out, where the restart is simple: the
   modes there equal those a probe step ahead along their own law. 1 where it is, 0 where it is not
   (the modes there in out), -1 where `strict` and a switching function or the rate is not finite. */
int bondc_restart_modes(const bondc_law *law, const int *floors, double t, const double *y, const double *guess,
                        double probe, int strict, double *out);

/* The modes just after (t, y), as _Run.restart_modes chooses them: bondc_restart_modes, then the modes
   a probe ahead along the law they select, chosen again until they agree (0) or cycle (1: each law
   pushes the state back across another's surface, a sliding mode). Where they cycle, flips[k] marks
   the switches that flip within the cycle and `rows` (at most 10 x switches) holds the cycle's mode
   vectors, *row_count of them. -1 where memory ran out. */
int bondc_select_modes(const bondc_law *law, const int *floors, double t, const double *y, const double *guess,
                       double probe, double *out, int *flips, double *rows, int *row_count);

/* Which switches matter for the law the modes select (out[k] 1 where switch k does): 0, or not 0
   where it cannot say (then every switch matters) */
typedef int (*bondc_relevant_at)(void *context, const double *modes, int *out);

/* bondc_sliding_set, with the other switches' modes chosen just after (t, y) along the sliding motion
   itself (not along either side's law), as _Run.consistent_sliding_set: a located switch (`located`
   marks them) that matters (`relevant`, NULL: every one) and flips a probe ahead takes its new mode;
   one that flips back and forth joins the candidates. At most 16 rounds. Returns what
   bondc_sliding_set returns, for the last round. */
int bondc_consistent_sliding_set(const bondc_law *law, const int *floors, const int *located,
                                 bondc_relevant_at relevant, void *context, double t, const double *y, double *modes,
                                 const int *candidates, int count, double probe, double span, const double *scale,
                                 double *vertices, int *held, double *alpha, int *affine);

/* Near switch k's surface at (t, y) with the modes m: (1) whether the law is continuous across it,
   as a turbulent orifice's sign(dp)*sqrt(abs(dp)) is at dp = 0 (crossed, never held): the jump
   between its two sides' right-hand sides (each state over its tolerance scale), a deadband off the
   surface and 100 of them off, vanishes towards it (at most 0.3 of the far one); (2) whether the
   motion keeps to the surface (on it, g moves by less than its deadband over a thousandth of the
   run's span). The state is moved along g's gradient to the level asked. Neither for a switch of
   vertex != 1 (a coulomb friction's) or a floor switch, or where g's gradient is nil: 0. */
int bondc_continuous_across(const bondc_law *law, const int *floors, double vertex, double t, const double *y,
                            const double *m, int k, const double *scale);
int bondc_keeps_to(const bondc_law *law, const int *floors, double vertex, double t, const double *y,
                   const double *m, int k, const double *scale, double probe, double span);

/* The switches that may slide at (t, y) with the modes m, sorted, into out (returns how many): those
   of `chattering` (count of them) but floor switches, and the located switches that matter
   (`relevant`) on their surfaces (|g| within its deadband) that are coulomb frictions (vertex != 1)
   or slid until now (`slid`); but none whose law is continuous across its surface (`vertices`: each
   switch's vertex now). -1 where memory ran out. */
int bondc_sliding_candidates(const bondc_law *law, const int *floors, const int *located, const int *slid,
                             const int *relevant, const double *vertices, double t, const double *y, const double *m,
                             const int *chattering, int count, const double *scale, int *out);

/* The state at the end of a sliding mode on the `k` switches `held` (their corners at `vertices`,
   affine or multilinear, their weights `alpha`), back on their surfaces where they are still held
   there (as _Run.onto_surfaces): where they drifted off by more than their deadbands (at most 1e6 of
   them) while every weight is still inside (0, 1), the smallest correction, each state weighted by
   its tolerance `scale`, that makes every held g zero (one Newton step). y is corrected in place;
   returns 1 where it was, 0 where not, -1 where memory ran out. */
int bondc_onto_surfaces(const bondc_law *law, const int *floors, double t, double *y, const double *m,
                        const int *held, int k, int affine, const double *vertices, const double *alpha,
                        double probe, const double *scale);
