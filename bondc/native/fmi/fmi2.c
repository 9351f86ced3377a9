/* bondc's FMI 2.0 wrapper (Co-Simulation and Model Exchange) around its engine (engine.c).

   Value references (modelDescription.xml, written by bondc.export.fmu, lists the same):
     [0, P)            the parameters, p[vr]                      (BONDC_N_PARAMETERS)
     [P, P + I)        the external inputs, p[vr]                 (BONDC_N_INPUTS)
     [S, S + N)        the states x, S = P + I                    (BONDC_N_STATES)
     [S + N, S + 2N)   their derivatives
     [S + 2N, ...)     the outputs                                (BONDC_N_OUTPUTS)
   Every variable is a Real. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "bondc_model.h"
#include "engine.h"

#define VR_INPUTS BONDC_N_PARAMETERS
#define VR_STATES (BONDC_N_PARAMETERS + BONDC_N_INPUTS)
#define VR_DERIVATIVES (VR_STATES + BONDC_N_STATES)
#define VR_OUTPUTS (VR_DERIVATIVES + BONDC_N_STATES)
#define VR_END (VR_OUTPUTS + BONDC_N_OUTPUTS)

typedef struct {
    bondc_fmu *engine;
    fmi2CallbackFunctions callbacks;
    char *name;
    int model_exchange, logging, initialized;
    double *buffer;     /* the derivatives, then the outputs */
} instance;

static void say(instance *c, fmi2Status status, const char *category, const char *format, ...)
{
    char text[1024];
    va_list args;
    if (!c || !c->callbacks.logger) return;
    if (status == fmi2OK && !c->logging) return;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    c->callbacks.logger(c->callbacks.componentEnvironment, c->name, status, category, "%s", text);
}

static fmi2Status failed(instance *c)
{
    say(c, fmi2Error, "logStatusError", "%s", c->engine->message);
    return fmi2Error;
}

/* the status of an engine call: 0 OK, -1 failed (said), else the wrong number of values */
static fmi2Status status(instance *c, int code)
{
    return code == 0 ? fmi2OK : (code == -1 ? failed(c) : fmi2Error);
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    (void)fmuResourceLocation; (void)visible;
    if (!functions || !functions->logger) return NULL;
    if (!fmuGUID || strcmp(fmuGUID, BONDC_FMU_GUID) != 0) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error, "logStatusError",
                          "the GUID %s is not this FMU's (%s)", fmuGUID ? fmuGUID : "(none)", BONDC_FMU_GUID);
        return NULL;
    }
#ifdef BONDC_FMU_ME
    int supported = fmuType == fmi2ModelExchange;
#else
    int supported = fmuType == fmi2CoSimulation;
#endif
    if (!supported) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error, "logStatusError",
                          "this FMU was built for %s only (bondc fmu --kind)",
#ifdef BONDC_FMU_ME
                          "Model Exchange"
#else
                          "Co-Simulation"
#endif
                          );
        return NULL;
    }
    instance *c = (instance *)calloc(1, sizeof(instance));
    if (!c) return NULL;
    c->callbacks = *functions;
    c->name = (char *)calloc(strlen(instanceName ? instanceName : "") + 1, 1);
    c->buffer = (double *)calloc(BONDC_N_STATES + BONDC_N_OUTPUTS + 1, sizeof(double));
    c->engine = bondc_fmu_new();
    if (!c->name || !c->buffer || !c->engine) {
        free(c->name); free(c->buffer); bondc_fmu_free(c->engine); free(c);
        return NULL;
    }
    strcpy(c->name, instanceName ? instanceName : "");
    c->model_exchange = fmuType == fmi2ModelExchange;
    c->logging = loggingOn;
    return c;
}

void fmi2FreeInstance(fmi2Component component)
{
    instance *c = (instance *)component;
    if (!c) return;
    bondc_fmu_free(c->engine);
    free(c->name);
    free(c->buffer);
    free(c);
}

fmi2Status fmi2SetDebugLogging(fmi2Component component, fmi2Boolean loggingOn, size_t n, const fmi2String categories[])
{
    (void)n; (void)categories;
    ((instance *)component)->logging = loggingOn;
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component component, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    instance *c = (instance *)component;
    bondc_fmu_setup(c->engine, toleranceDefined ? tolerance : 0.0, startTime,
                    stopTimeDefined ? stopTime : startTime + bondc_experiment[0]);
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component component)
{
    instance *c = (instance *)component;
    bondc_fmu_parameters_changed(c->engine, 1);
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component component)
{
    instance *c = (instance *)component;
    int changed;
    bondc_fmu_parameters_changed(c->engine, !c->engine->states_set);
    if (bondc_fmu_event(c->engine, &changed) != 0) return failed(c);
    c->initialized = 1;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component component) { (void)component; return fmi2OK; }

fmi2Status fmi2Reset(fmi2Component component)
{
    instance *c = (instance *)component;
    bondc_fmu_reset(c->engine);
    c->initialized = 0;
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    instance *c = (instance *)component;
    bondc_fmu *e = c->engine;
    int changed, derivatives = 0, outputs = 0;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= VR_END) return fmi2Error;
        derivatives |= vr[i] >= VR_DERIVATIVES && vr[i] < VR_OUTPUTS;
        outputs |= vr[i] >= VR_OUTPUTS;
    }
    /* Model Exchange: the modes of the event the importer found. Co-Simulation: the modes the last
       step ended with (a crossing at its end is the next step's: the outputs are its left limit) */
    if (c->model_exchange && (derivatives || outputs) && bondc_fmu_event(e, &changed) != 0) return failed(c);
    if (derivatives) bondc_fmu_derivatives(e, c->buffer);
    if (outputs) bondc_fmu_outputs(e, c->buffer + BONDC_N_STATES);
    for (size_t i = 0; i < nvr; i++) {
        fmi2ValueReference r = vr[i];
        if (r < VR_STATES) value[i] = e->p[r];
        else if (r < VR_DERIVATIVES) value[i] = e->x[r - VR_STATES];
        else if (r < VR_OUTPUTS) value[i] = c->buffer[r - VR_DERIVATIVES];
        else value[i] = c->buffer[BONDC_N_STATES + r - VR_OUTPUTS];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    instance *c = (instance *)component;
    bondc_fmu *e = c->engine;
    int parameters = 0;
    for (size_t i = 0; i < nvr; i++) {
        fmi2ValueReference r = vr[i];
        if (r < VR_INPUTS) {
            if (bondc_parameter_derived[r]) {
                say(c, fmi2Error, "logStatusError", "%s is computed from other parameters", bondc_parameters[r].name);
                return fmi2Error;
            }
            if (e->p[r] != value[i]) parameters = 1;
            e->p[r] = value[i];
        } else if (r < VR_STATES) {
            /* an input changed between two steps (Co-Simulation): the modes are selected again at
               the next step's start, as bondc simulate restarts at each sample of an input; in
               Model Exchange its switches are event indicators the importer watches */
            if (e->p[r] != value[i] && !c->model_exchange) e->selected = 0;
            e->p[r] = value[i];
        } else {
            say(c, fmi2Error, "logStatusError", "variable %u cannot be set", (unsigned)r);
            return fmi2Error;
        }
    }
    /* a tunable parameter changed during the run: the run goes on from its state with the new value */
    if (parameters) bondc_fmu_parameters_changed(e, !c->initialized && !e->states_set);
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{ (void)c; (void)vr; (void)value; return nvr ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{ (void)c; (void)vr; (void)value; return nvr ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[])
{ (void)c; (void)vr; (void)value; return nvr ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{ (void)c; (void)vr; (void)value; return nvr ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{ (void)c; (void)vr; (void)value; return nvr ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[])
{ (void)c; (void)vr; (void)value; return nvr ? fmi2Error : fmi2OK; }

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) { (void)c; (void)state; return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) { (void)c; (void)state; return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) { (void)c; (void)state; return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size)
{ (void)c; (void)state; (void)size; return fmi2Error; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size)
{ (void)c; (void)state; (void)bytes; (void)size; return fmi2Error; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state)
{ (void)c; (void)bytes; (void)size; (void)state; return fmi2Error; }
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference unknown[], size_t nUnknown,
                                        const fmi2ValueReference known[], size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[])
{ (void)c; (void)unknown; (void)nUnknown; (void)known; (void)nKnown; (void)dvKnown; (void)dvUnknown; return fmi2Error; }

/* ---- Model Exchange */

fmi2Status fmi2EnterEventMode(fmi2Component component) { (void)component; return fmi2OK; }

fmi2Status fmi2NewDiscreteStates(fmi2Component component, fmi2EventInfo *info)
{
    instance *c = (instance *)component;
    int changed = 0;
    if (bondc_fmu_event_update(c->engine, &changed) != 0) return failed(c);
    info->newDiscreteStatesNeeded = fmi2False;
    info->terminateSimulation = fmi2False;
    info->nominalsOfContinuousStatesChanged = fmi2False;
    info->valuesOfContinuousStatesChanged = changed ? fmi2True : fmi2False;
    info->nextEventTimeDefined = fmi2False;
    info->nextEventTime = 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component component) { (void)component; return fmi2OK; }

fmi2Status fmi2CompletedIntegratorStep(fmi2Component component, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
{
    (void)component; (void)noSetFMUStatePriorToCurrentPoint;
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component component, fmi2Real time)
{
    ((instance *)component)->engine->t = time;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component component, const fmi2Real x[], size_t nx)
{
    return status((instance *)component, bondc_fmu_set_states(((instance *)component)->engine, x, nx));
}

fmi2Status fmi2GetDerivatives(fmi2Component component, fmi2Real derivatives[], size_t nx)
{
    return status((instance *)component, bondc_fmu_get_derivatives(((instance *)component)->engine, derivatives, nx));
}

fmi2Status fmi2GetEventIndicators(fmi2Component component, fmi2Real indicators[], size_t ni)
{
    return status((instance *)component, bondc_fmu_get_indicators(((instance *)component)->engine, indicators, ni));
}

fmi2Status fmi2GetContinuousStates(fmi2Component component, fmi2Real x[], size_t nx)
{
    return status((instance *)component, bondc_fmu_get_states(((instance *)component)->engine, x, nx));
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component component, fmi2Real nominals[], size_t nx)
{
    (void)component;
    for (size_t i = 0; i < nx; i++) nominals[i] = 1.0;
    return fmi2OK;
}

/* ---- Co-Simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{ (void)c; (void)vr; (void)nvr; (void)order; (void)value; return fmi2Error; }
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{ (void)c; (void)vr; (void)nvr; (void)order; (void)value; return fmi2Error; }

fmi2Status fmi2DoStep(fmi2Component component, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentCommunicationPoint)
{
    instance *c = (instance *)component;
    (void)noSetFMUStatePriorToCurrentCommunicationPoint;
    if (communicationStepSize < 0) return fmi2Error;
    c->engine->t = currentCommunicationPoint;
    if (bondc_fmu_advance(c->engine, currentCommunicationPoint + communicationStepSize) != 0) return failed(c);
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{ (void)c; (void)s; *value = fmi2OK; return fmi2OK; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{ instance *i = (instance *)c; if (s != fmi2LastSuccessfulTime) return fmi2Discard; *value = i->engine->t; return fmi2OK; }
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{ (void)c; (void)s; (void)value; return fmi2Discard; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{ (void)c; (void)s; (void)value; return fmi2Discard; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{ (void)c; (void)s; (void)value; return fmi2Discard; }
