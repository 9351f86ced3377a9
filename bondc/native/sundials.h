/* The part of SUNDIALS 7's API that bondc's CVODE driver (driver.c) calls, declared here: scikit-sundae's
   wheels ship SUNDIALS' libraries (which the model's library links) but not its headers.
   BONDC_INDEX_TYPE is SUNDIALS' sunindextype as those libraries were built (bondc reads it from
   scikit-sundae's configuration and defines it before the driver's text). */
#ifndef BONDC_SUNDIALS_H
#define BONDC_SUNDIALS_H

#ifndef BONDC_INDEX_TYPE
#define BONDC_INDEX_TYPE long long     /* SUNDIALS' default (int64_t), for editors: bondc always defines it */
#endif

typedef double sunrealtype;
typedef BONDC_INDEX_TYPE sunindextype;
typedef struct _generic_N_Vector *N_Vector;
typedef struct _generic_SUNMatrix *SUNMatrix;
typedef struct _generic_SUNLinearSolver *SUNLinearSolver;
typedef struct SUNContext_ *SUNContext;
typedef int (*CVRhsFn)(sunrealtype, N_Vector, N_Vector, void *);
typedef int (*CVLsJacFn)(sunrealtype, N_Vector, N_Vector, SUNMatrix, void *, N_Vector, N_Vector, N_Vector);

extern int SUNContext_Create(int comm, SUNContext *ctx);
extern int SUNContext_Free(SUNContext *ctx);
extern N_Vector N_VNew_Serial(sunindextype n, SUNContext ctx);
extern void N_VDestroy(N_Vector v);
extern sunrealtype *N_VGetArrayPointer(N_Vector v);
extern SUNMatrix SUNDenseMatrix(sunindextype m, sunindextype n, SUNContext ctx);
extern SUNMatrix SUNBandMatrix(sunindextype n, sunindextype mu, sunindextype ml, SUNContext ctx);
extern sunrealtype *SUNDenseMatrix_Column(SUNMatrix a, sunindextype j);
extern sunrealtype *SUNBandMatrix_Column(SUNMatrix a, sunindextype j);
extern int SUNMatZero(SUNMatrix a);
extern void SUNMatDestroy(SUNMatrix a);
extern SUNLinearSolver SUNLinSol_Dense(N_Vector y, SUNMatrix a, SUNContext ctx);
extern SUNLinearSolver SUNLinSol_Band(N_Vector y, SUNMatrix a, SUNContext ctx);
extern int SUNLinSolFree(SUNLinearSolver s);
extern void *CVodeCreate(int lmm, SUNContext ctx);
extern int CVodeInit(void *mem, CVRhsFn f, sunrealtype t0, N_Vector y0);
extern int CVodeReInit(void *mem, sunrealtype t0, N_Vector y0);
extern int CVodeSStolerances(void *mem, sunrealtype rtol, sunrealtype atol);
extern int CVodeSetUserData(void *mem, void *data);
extern int CVodeSetMaxNumSteps(void *mem, long mxsteps);
extern int CVodeSetInitStep(void *mem, sunrealtype h);
extern int CVodeSetMaxStep(void *mem, sunrealtype h);
extern int CVodeSetStopTime(void *mem, sunrealtype t);
extern int CVodeSetLinearSolver(void *mem, SUNLinearSolver ls, SUNMatrix a);
extern int CVodeSetJacFn(void *mem, CVLsJacFn jac);
extern int CVode(void *mem, sunrealtype tout, N_Vector yout, sunrealtype *tret, int itask);
extern int CVodeGetDky(void *mem, sunrealtype t, int k, N_Vector dky);
extern int CVodeGetLastStep(void *mem, sunrealtype *hlast);
extern int CVodeGetNumRhsEvals(void *mem, long *n);
extern int CVodeGetNumJacEvals(void *mem, long *n);
extern int CVodeGetNumLinSolvSetups(void *mem, long *n);
extern void CVodeFree(void **mem);

#endif
