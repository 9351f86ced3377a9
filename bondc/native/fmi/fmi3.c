/* bondc's FMI 3.0 wrapper (Co-Simulation and Model Exchange) around its engine (engine.c).

   Value references (modelDescription.xml, written by bondc.export.fmu, lists the same): 0 is the
   time; vr - 1 is laid out as in fmi2.c: the parameters, the external inputs, the states, their
   derivatives, the outputs, then (Model Exchange) the event indicators. Every variable is a
   Float64. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "bondc_model.h"
#include "engine.h"

#define VR_INPUTS BONDC_N_PARAMETERS
#define VR_STATES (BONDC_N_PARAMETERS + BONDC_N_INPUTS)
#define VR_DERIVATIVES (VR_STATES + BONDC_N_STATES)
#define VR_OUTPUTS (VR_DERIVATIVES + BONDC_N_STATES)
#define VR_END (VR_OUTPUTS + BONDC_N_OUTPUTS)

typedef struct {
    bondc_fmu *engine;
    fmi3InstanceEnvironment environment;
    fmi3LogMessageCallback log;
    int logging, initialized, model_exchange;
    double *buffer;     /* the derivatives, the outputs, the event indicators */
} instance;

static fmi3Status failed(instance *c)
{
    if (c->log) c->log(c->environment, fmi3Error, "logStatusError", c->engine->message);
    return fmi3Error;
}

/* the status of an engine call: 0 OK, -1 failed (said), else the wrong number of values */
static fmi3Status status(instance *c, int code)
{
    return code == 0 ? fmi3OK : (code == -1 ? failed(c) : fmi3Error);
}

static void complain(instance *c, const char *text)
{
    if (c->log) c->log(c->environment, fmi3Error, "logStatusError", text);
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance i, fmi3Boolean loggingOn, size_t n, const fmi3String categories[])
{
    (void)n; (void)categories;
    ((instance *)i)->logging = loggingOn;
    return fmi3OK;
}

static instance *new_instance(fmi3InstanceEnvironment environment, fmi3LogMessageCallback log, int logging)
{
    instance *c = (instance *)calloc(1, sizeof(instance));
    if (!c) return NULL;
    c->buffer = (double *)calloc(BONDC_N_STATES + BONDC_N_OUTPUTS + BONDC_N_SWITCHES + 1, sizeof(double));
    c->engine = bondc_fmu_new();
    if (!c->buffer || !c->engine) {
        free(c->buffer); bondc_fmu_free(c->engine); free(c);
        return NULL;
    }
    c->environment = environment;
    c->log = log;
    c->logging = logging;
    return c;
}

static int token_is_ours(fmi3String token, fmi3InstanceEnvironment environment, fmi3LogMessageCallback log)
{
    if (token && strcmp(token, BONDC_FMU_GUID) == 0) return 1;
    if (log) log(environment, fmi3Error, "logStatusError", "the instantiation token is not this FMU's");
    return 0;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    (void)instanceName; (void)resourcePath; (void)visible;
#ifdef BONDC_FMU_ME
    if (!token_is_ours(instantiationToken, instanceEnvironment, logMessage)) return NULL;
    instance *c = new_instance(instanceEnvironment, logMessage, loggingOn);
    if (c) c->model_exchange = 1;
    return c;
#else
    (void)instantiationToken; (void)loggingOn;
    if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                               "this FMU was built for Co-Simulation only (bondc fmu --kind)");
    return NULL;
#endif
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate)
{
    (void)instanceName; (void)resourcePath; (void)visible; (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables; (void)nRequiredIntermediateVariables; (void)intermediateUpdate;
#ifdef BONDC_FMU_ME
    (void)instantiationToken; (void)loggingOn; (void)eventModeUsed;
    if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                               "this FMU was built for Model Exchange only (bondc fmu --kind)");
    return NULL;
#else
    if (!token_is_ours(instantiationToken, instanceEnvironment, logMessage)) return NULL;
    if (eventModeUsed) {
        if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                                   "this FMU has no event mode (hasEventMode is false)");
        return NULL;
    }
    return new_instance(instanceEnvironment, logMessage, loggingOn);
#endif
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError", "this FMU is for Co-Simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance i)
{
    instance *c = (instance *)i;
    if (!c) return;
    bondc_fmu_free(c->engine);
    free(c->buffer);
    free(c);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance i, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    instance *c = (instance *)i;
    bondc_fmu_setup(c->engine, toleranceDefined ? tolerance : 0.0, startTime,
                    stopTimeDefined ? stopTime : startTime + bondc_experiment[0]);
    bondc_fmu_parameters_changed(c->engine, 1);
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance i)
{
    instance *c = (instance *)i;
    int changed;
    bondc_fmu_parameters_changed(c->engine, !c->engine->states_set);
    if (bondc_fmu_event(c->engine, &changed) != 0) return failed(c);
    c->initialized = 1;
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance i) { return ((instance *)i)->model_exchange ? fmi3OK : fmi3Error; }
fmi3Status fmi3Terminate(fmi3Instance i) { (void)i; return fmi3OK; }

fmi3Status fmi3Reset(fmi3Instance i)
{
    instance *c = (instance *)i;
    bondc_fmu_reset(c->engine);
    c->initialized = 0;
    return fmi3OK;
}

fmi3Status fmi3GetFloat64(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues)
{
    instance *c = (instance *)i;
    bondc_fmu *e = c->engine;
    int derivatives = 0, outputs = 0, indicators = 0, changed;
    if (nValues != nvr) return fmi3Error;
    for (size_t k = 0; k < nvr; k++) {
        if (vr[k] > VR_END + (c->model_exchange ? bondc_fmu_indicator_count() : 0)) return fmi3Error;
        derivatives |= vr[k] > VR_DERIVATIVES && vr[k] <= VR_OUTPUTS;
        outputs |= vr[k] > VR_OUTPUTS && vr[k] <= VR_END;
        indicators |= vr[k] > VR_END;
    }
    /* Model Exchange: the modes of the event the importer found. Co-Simulation: the modes the last
       step ended with (a crossing at its end is the next step's: the outputs are its left limit) */
    if (c->model_exchange && (derivatives || outputs || indicators) && bondc_fmu_event(e, &changed) != 0)
        return failed(c);
    if (derivatives) bondc_fmu_derivatives(e, c->buffer);
    if (outputs) bondc_fmu_outputs(e, c->buffer + BONDC_N_STATES);
    if (indicators) bondc_fmu_indicators(e, c->buffer + BONDC_N_STATES + BONDC_N_OUTPUTS);
    for (size_t k = 0; k < nvr; k++) {
        if (vr[k] == 0) { values[k] = e->t; continue; }
        fmi3ValueReference r = vr[k] - 1;
        if (r < VR_STATES) values[k] = e->p[r];
        else if (r < VR_DERIVATIVES) values[k] = e->x[r - VR_STATES];
        else if (r < VR_OUTPUTS) values[k] = c->buffer[r - VR_DERIVATIVES];
        else values[k] = c->buffer[BONDC_N_STATES + r - VR_OUTPUTS];     /* an output, an indicator */
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 values[],
                          size_t nValues)
{
    instance *c = (instance *)i;
    bondc_fmu *e = c->engine;
    int parameters = 0;
    if (nValues != nvr) return fmi3Error;
    for (size_t k = 0; k < nvr; k++) {
        if (vr[k] == 0 || vr[k] > VR_STATES) { complain(c, "this variable cannot be set"); return fmi3Error; }
        fmi3ValueReference r = vr[k] - 1;
        if (r < VR_INPUTS) {
            if (bondc_parameter_derived[r]) { complain(c, "a parameter computed from others cannot be set"); return fmi3Error; }
            if (e->p[r] != values[k]) parameters = 1;
        } else if (e->p[r] != values[k] && !c->model_exchange) {
            e->selected = 0;        /* an input changed between steps: the modes again (as fmi2.c) */
        }
        e->p[r] = values[k];
    }
    if (parameters) bondc_fmu_parameters_changed(e, !c->initialized);
    return fmi3OK;
}

fmi3Status fmi3DoStep(fmi3Instance i, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    instance *c = (instance *)i;
    (void)noSetFMUStatePriorToCurrentPoint;
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    if (communicationStepSize < 0) return fmi3Error;
    c->engine->t = currentCommunicationPoint;
    int code = bondc_fmu_advance(c->engine, currentCommunicationPoint + communicationStepSize);
    *lastSuccessfulTime = c->engine->t;
    return code == 0 ? fmi3OK : failed(c);
}

fmi3Status fmi3EnterStepMode(fmi3Instance i) { (void)i; return fmi3OK; }

/* ---- what this FMU does not have: no variables of other types, no clocks, no FMU state, no
   partial derivatives, no Scheduled Execution */

#define NO_VALUES(name, type) \
    fmi3Status name(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, type values[], size_t n) \
    { (void)i; (void)vr; (void)values; (void)n; return nvr ? fmi3Error : fmi3OK; }
NO_VALUES(fmi3GetFloat32, fmi3Float32)
NO_VALUES(fmi3GetInt8, fmi3Int8)
NO_VALUES(fmi3GetUInt8, fmi3UInt8)
NO_VALUES(fmi3GetInt16, fmi3Int16)
NO_VALUES(fmi3GetUInt16, fmi3UInt16)
NO_VALUES(fmi3GetInt32, fmi3Int32)
NO_VALUES(fmi3GetUInt32, fmi3UInt32)
NO_VALUES(fmi3GetInt64, fmi3Int64)
NO_VALUES(fmi3GetUInt64, fmi3UInt64)
NO_VALUES(fmi3GetBoolean, fmi3Boolean)
NO_VALUES(fmi3GetString, fmi3String)
NO_VALUES(fmi3SetFloat32, const fmi3Float32)
NO_VALUES(fmi3SetInt8, const fmi3Int8)
NO_VALUES(fmi3SetUInt8, const fmi3UInt8)
NO_VALUES(fmi3SetInt16, const fmi3Int16)
NO_VALUES(fmi3SetUInt16, const fmi3UInt16)
NO_VALUES(fmi3SetInt32, const fmi3Int32)
NO_VALUES(fmi3SetUInt32, const fmi3UInt32)
NO_VALUES(fmi3SetInt64, const fmi3Int64)
NO_VALUES(fmi3SetUInt64, const fmi3UInt64)
NO_VALUES(fmi3SetBoolean, const fmi3Boolean)
NO_VALUES(fmi3SetString, const fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, size_t sizes[],
                         fmi3Binary values[], size_t n)
{ (void)i; (void)vr; (void)sizes; (void)values; (void)n; return nvr ? fmi3Error : fmi3OK; }
fmi3Status fmi3SetBinary(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, const size_t sizes[],
                         const fmi3Binary values[], size_t n)
{ (void)i; (void)vr; (void)sizes; (void)values; (void)n; return nvr ? fmi3Error : fmi3OK; }
fmi3Status fmi3GetClock(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[])
{ (void)i; (void)vr; (void)values; return nvr ? fmi3Error : fmi3OK; }
fmi3Status fmi3SetClock(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock values[])
{ (void)i; (void)vr; (void)values; return nvr ? fmi3Error : fmi3OK; }
fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance i, fmi3ValueReference vr, size_t *n)
{ (void)i; (void)vr; (void)n; return fmi3Error; }
fmi3Status fmi3GetVariableDependencies(fmi3Instance i, fmi3ValueReference dependent, size_t a[],
                                       fmi3ValueReference b[], size_t c[], fmi3DependencyKind d[], size_t n)
{ (void)i; (void)dependent; (void)a; (void)b; (void)c; (void)d; (void)n; return fmi3Error; }
fmi3Status fmi3GetFMUState(fmi3Instance i, fmi3FMUState *s) { (void)i; (void)s; return fmi3Error; }
fmi3Status fmi3SetFMUState(fmi3Instance i, fmi3FMUState s) { (void)i; (void)s; return fmi3Error; }
fmi3Status fmi3FreeFMUState(fmi3Instance i, fmi3FMUState *s) { (void)i; (void)s; return fmi3Error; }
fmi3Status fmi3SerializedFMUStateSize(fmi3Instance i, fmi3FMUState s, size_t *size)
{ (void)i; (void)s; (void)size; return fmi3Error; }
fmi3Status fmi3SerializeFMUState(fmi3Instance i, fmi3FMUState s, fmi3Byte bytes[], size_t size)
{ (void)i; (void)s; (void)bytes; (void)size; return fmi3Error; }
fmi3Status fmi3DeserializeFMUState(fmi3Instance i, const fmi3Byte bytes[], size_t size, fmi3FMUState *s)
{ (void)i; (void)bytes; (void)size; (void)s; return fmi3Error; }
fmi3Status fmi3GetDirectionalDerivative(fmi3Instance i, const fmi3ValueReference u[], size_t nu,
                                        const fmi3ValueReference k[], size_t nk, const fmi3Float64 seed[],
                                        size_t ns, fmi3Float64 sensitivity[], size_t nsens)
{ (void)i; (void)u; (void)nu; (void)k; (void)nk; (void)seed; (void)ns; (void)sensitivity; (void)nsens; return fmi3Error; }
fmi3Status fmi3GetAdjointDerivative(fmi3Instance i, const fmi3ValueReference u[], size_t nu,
                                    const fmi3ValueReference k[], size_t nk, const fmi3Float64 seed[],
                                    size_t ns, fmi3Float64 sensitivity[], size_t nsens)
{ (void)i; (void)u; (void)nu; (void)k; (void)nk; (void)seed; (void)ns; (void)sensitivity; (void)nsens; return fmi3Error; }
fmi3Status fmi3EnterConfigurationMode(fmi3Instance i) { (void)i; return fmi3Error; }
fmi3Status fmi3ExitConfigurationMode(fmi3Instance i) { (void)i; return fmi3Error; }
fmi3Status fmi3GetIntervalDecimal(fmi3Instance i, const fmi3ValueReference vr[], size_t n, fmi3Float64 v[],
                                  fmi3IntervalQualifier q[])
{ (void)i; (void)vr; (void)n; (void)v; (void)q; return fmi3Error; }
fmi3Status fmi3GetIntervalFraction(fmi3Instance i, const fmi3ValueReference vr[], size_t n, fmi3UInt64 c[],
                                   fmi3UInt64 r[], fmi3IntervalQualifier q[])
{ (void)i; (void)vr; (void)n; (void)c; (void)r; (void)q; return fmi3Error; }
fmi3Status fmi3GetShiftDecimal(fmi3Instance i, const fmi3ValueReference vr[], size_t n, fmi3Float64 s[])
{ (void)i; (void)vr; (void)n; (void)s; return fmi3Error; }
fmi3Status fmi3GetShiftFraction(fmi3Instance i, const fmi3ValueReference vr[], size_t n, fmi3UInt64 c[],
                                fmi3UInt64 r[])
{ (void)i; (void)vr; (void)n; (void)c; (void)r; return fmi3Error; }
fmi3Status fmi3SetIntervalDecimal(fmi3Instance i, const fmi3ValueReference vr[], size_t n, const fmi3Float64 v[])
{ (void)i; (void)vr; (void)n; (void)v; return fmi3Error; }
fmi3Status fmi3SetIntervalFraction(fmi3Instance i, const fmi3ValueReference vr[], size_t n, const fmi3UInt64 c[],
                                   const fmi3UInt64 r[])
{ (void)i; (void)vr; (void)n; (void)c; (void)r; return fmi3Error; }
fmi3Status fmi3SetShiftDecimal(fmi3Instance i, const fmi3ValueReference vr[], size_t n, const fmi3Float64 s[])
{ (void)i; (void)vr; (void)n; (void)s; return fmi3Error; }
fmi3Status fmi3SetShiftFraction(fmi3Instance i, const fmi3ValueReference vr[], size_t n, const fmi3UInt64 c[],
                                const fmi3UInt64 r[])
{ (void)i; (void)vr; (void)n; (void)c; (void)r; return fmi3Error; }
fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance i) { (void)i; return fmi3OK; }

/* ---- Model Exchange */

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance i, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime)
{
    instance *c = (instance *)i;
    int changed = 0;
    if (bondc_fmu_event_update(c->engine, &changed) != 0) return failed(c);
    *discreteStatesNeedUpdate = fmi3False;
    *terminateSimulation = fmi3False;
    *nominalsOfContinuousStatesChanged = fmi3False;
    *valuesOfContinuousStatesChanged = changed ? fmi3True : fmi3False;
    *nextEventTimeDefined = fmi3False;
    *nextEventTime = 0.0;
    return fmi3OK;
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance i) { (void)i; return fmi3OK; }

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance i, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    (void)i; (void)noSetFMUStatePriorToCurrentPoint;
    *enterEventMode = fmi3False;
    *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance i, fmi3Float64 time)
{
    ((instance *)i)->engine->t = time;
    return fmi3OK;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance i, const fmi3Float64 x[], size_t n)
{
    return status((instance *)i, bondc_fmu_set_states(((instance *)i)->engine, x, n));
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance i, fmi3Float64 derivatives[], size_t n)
{
    return status((instance *)i, bondc_fmu_get_derivatives(((instance *)i)->engine, derivatives, n));
}

fmi3Status fmi3GetEventIndicators(fmi3Instance i, fmi3Float64 indicators[], size_t n)
{
    return status((instance *)i, bondc_fmu_get_indicators(((instance *)i)->engine, indicators, n));
}

fmi3Status fmi3GetContinuousStates(fmi3Instance i, fmi3Float64 x[], size_t n)
{
    return status((instance *)i, bondc_fmu_get_states(((instance *)i)->engine, x, n));
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance i, fmi3Float64 nominals[], size_t n)
{
    (void)i;
    for (size_t k = 0; k < n; k++) nominals[k] = 1.0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance i, size_t *n)
{
    *n = ((instance *)i)->model_exchange ? (size_t)bondc_fmu_indicator_count() : 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance i, size_t *n)
{
    *n = ((instance *)i)->model_exchange ? BONDC_N_STATES : 0;
    return fmi3OK;
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 o[],
                                    fmi3Float64 v[], size_t n)
{ (void)i; (void)vr; (void)nvr; (void)o; (void)v; (void)n; return fmi3Error; }
fmi3Status fmi3ActivateModelPartition(fmi3Instance i, fmi3ValueReference clock, fmi3Float64 t)
{ (void)i; (void)clock; (void)t; return fmi3Error; }
