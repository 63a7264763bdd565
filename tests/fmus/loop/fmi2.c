/*
 * FMI 2.0 Co-Simulation wrapper around a model core (model.h) of the loop test FMUs (issue 40). One file
 * for tests/fmus/loop/loop_a, loop_b and loop_b_nostate (the builder takes a folder's missing wrapper from its
 * parent): what differs between them is in model.h.
 *
 * A bad call returns fmi2Error and logs one line. Only Real variables exist. With CAN_GET_AND_SET_FMU_STATE
 * the FMU state functions save and restore a copy of the whole model (time, state, inputs, parameters);
 * without it they return fmi2Error. Serialization, directional derivatives and input derivatives are not
 * provided (their functions exist and return fmi2Error).
 */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"

typedef struct {
    Model m;
    fmi2CallbackFunctions cb;
    double start_time;
} Instance;

/* What an FMU state holds: everything of an instance but its callbacks. */
typedef struct {
    Model m;
    double start_time;
} SavedState;

static fmi2Status error(const Instance *s, const char *function, const char *what) {
    char text[512];
    size_t i = 0, k = 0;
    char raw[400];
    snprintf(raw, sizeof raw, "%s: %s", function, what);
    while (raw[i] && k + 2 < sizeof text) { /* FMI 2 loggers read the message as a printf format */
        if (raw[i] == '%') text[k++] = '%';
        text[k++] = raw[i++];
    }
    text[k] = '\0';
    if (s->cb.logger) s->cb.logger(s->cb.componentEnvironment, MODEL_IDENTIFIER, fmi2Error, "logStatusError", text);
    return fmi2Error;
}

#define CHECK_INSTANCE(c) \
    if (!(c)) return fmi2Error; \
    Instance *s = (Instance *)(c)
#define MODEL_CALL(fn, call) \
    if ((call) != MODEL_OK) return error(s, fn, s->m.msg); \
    return fmi2OK
#define NOT_PROVIDED(fn) \
    CHECK_INSTANCE(c); \
    return error(s, fn, "not provided by this FMU")

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    CHECK_INSTANCE(c);
    (void)s;
    return fmi2OK; /* errors are always logged; there is nothing else to log */
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    Instance *s;
    if (!functions || !instanceName || !fmuGUID || strcmp(fmuGUID, MODEL_GUID) != 0) return NULL;
    if (fmuType != fmi2CoSimulation) {
        if (functions->logger)
            functions->logger(functions->componentEnvironment, instanceName, fmi2Error, "logStatusError",
                              "fmi2Instantiate: this FMU is for Co-Simulation only");
        return NULL;
    }
    s = (Instance *)calloc(1, sizeof(Instance));
    if (!s) return NULL;
    s->cb = *functions;
    model_reset(&s->m);
    return s;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    CHECK_INSTANCE(c);
    s->start_time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    CHECK_INSTANCE(c);
    MODEL_CALL("fmi2EnterInitializationMode", model_enter_initialization(&s->m, s->start_time));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    CHECK_INSTANCE(c);
    MODEL_CALL("fmi2ExitInitializationMode", model_exit_initialization(&s->m));
}

fmi2Status fmi2Terminate(fmi2Component c) {
    CHECK_INSTANCE(c);
    s->m.phase = PHASE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    CHECK_INSTANCE(c);
    model_reset(&s->m);
    s->start_time = 0.0;
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    size_t i;
    CHECK_INSTANCE(c);
    for (i = 0; i < nvr; ++i)
        if (model_get_real(&s->m, vr[i], &value[i]) != MODEL_OK) return error(s, "fmi2GetReal", s->m.msg);
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    size_t i;
    CHECK_INSTANCE(c);
    for (i = 0; i < nvr; ++i)
        if (model_set_real(&s->m, vr[i], value[i]) != MODEL_OK) return error(s, "fmi2SetReal", s->m.msg);
    return fmi2OK;
}

#define NO_SUCH_TYPE(fn, T)                                                                       \
    fmi2Status fn(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, T value[]) {        \
        CHECK_INSTANCE(c);                                                                        \
        return nvr ? error(s, #fn, "the model has Real variables only") : fmi2OK;                 \
    }
NO_SUCH_TYPE(fmi2GetInteger, fmi2Integer)
NO_SUCH_TYPE(fmi2GetBoolean, fmi2Boolean)
NO_SUCH_TYPE(fmi2GetString, fmi2String)
NO_SUCH_TYPE(fmi2SetInteger, const fmi2Integer)
NO_SUCH_TYPE(fmi2SetBoolean, const fmi2Boolean)
NO_SUCH_TYPE(fmi2SetString, const fmi2String)

/* ------------------------------------------------------------------------ */
/* FMU state                                                                  */

#if CAN_GET_AND_SET_FMU_STATE
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    SavedState *saved;
    CHECK_INSTANCE(c);
    if (!FMUstate) return error(s, "fmi2GetFMUstate", "FMUstate is NULL");
    /* a state given back is overwritten (FMI 2.0, 2.1.8), else a new one is made */
    saved = *FMUstate ? (SavedState *)*FMUstate : (SavedState *)malloc(sizeof(SavedState));
    if (!saved) return error(s, "fmi2GetFMUstate", "out of memory");
    saved->m = s->m;
    saved->start_time = s->start_time;
    *FMUstate = saved;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    const SavedState *saved = (const SavedState *)FMUstate;
    CHECK_INSTANCE(c);
    if (!saved) return error(s, "fmi2SetFMUstate", "FMUstate is NULL");
    s->m = saved->m;
    s->start_time = saved->start_time;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    CHECK_INSTANCE(c);
    (void)s;
    if (FMUstate) {
        free(*FMUstate);
        *FMUstate = NULL;
    }
    return fmi2OK;
}
#else
#define NO_STATE(fn) \
    CHECK_INSTANCE(c); \
    return error(s, fn, "this FMU cannot save and restore its state (canGetAndSetFMUstate is false)")
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) { NO_STATE("fmi2GetFMUstate"); }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) { NO_STATE("fmi2SetFMUstate"); }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) { NO_STATE("fmi2FreeFMUstate"); }
#endif

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    NOT_PROVIDED("fmi2SerializedFMUstateSize");
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    NOT_PROVIDED("fmi2SerializeFMUstate");
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    NOT_PROVIDED("fmi2DeSerializeFMUstate");
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    NOT_PROVIDED("fmi2GetDirectionalDerivative");
}

/* ------------------------------------------------------------------------ */
/* Co-Simulation                                                              */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    NOT_PROVIDED("fmi2SetRealInputDerivatives");
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    NOT_PROVIDED("fmi2GetRealOutputDerivatives");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    CHECK_INSTANCE(c);
    MODEL_CALL("fmi2DoStep", model_do_step(&s->m, currentCommunicationPoint, communicationStepSize));
}

fmi2Status fmi2CancelStep(fmi2Component c) { NOT_PROVIDED("fmi2CancelStep"); }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Status *value) {
    NOT_PROVIDED("fmi2GetStatus");
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Integer *value) {
    NOT_PROVIDED("fmi2GetIntegerStatus");
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind kind, fmi2String *value) {
    NOT_PROVIDED("fmi2GetStringStatus");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Real *value) {
    CHECK_INSTANCE(c);
    if (kind != fmi2LastSuccessfulTime || !value) return error(s, "fmi2GetRealStatus", "only fmi2LastSuccessfulTime");
    *value = s->m.time;
    return fmi2OK;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Boolean *value) {
    CHECK_INSTANCE(c);
    if (kind != fmi2Terminated || !value) return error(s, "fmi2GetBooleanStatus", "only fmi2Terminated");
    *value = fmi2False; /* the model never ends the simulation */
    return fmi2OK;
}
