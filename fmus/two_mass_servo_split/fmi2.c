/*
 * FMI 2.0 Co-Simulation wrapper around a model core (model.h): one file for motor/ and shaft_load/ of
 * fmus/two_mass_servo_split (the builder takes a folder's missing wrapper from its parent); what differs
 * between the two FMUs is in their model.h and model.c.
 *
 * Every function checks its arguments; a bad call returns fmi2Error and, when the instance has a logger, logs
 * one line saying what was wrong.  Errors and warnings are always logged; with loggingOn the calls of the life
 * cycle are logged too (category logCalls).  Provided beyond the one-FMU servo's wrapper: FMU state get/set/free
 * (a deep copy of the whole model, the input-delay history included) and first-order input derivatives
 * (canInterpolateInputs).  Not provided: state serialisation, directional and output derivatives.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"

typedef struct {
    Model m;
    fmi2CallbackFunctions cb;
    char *name;
    int log_calls;
    double start_time;
} Instance;

/* FMI 2 loggers treat the message as a printf format: escape '%'. */
static void emit(const fmi2CallbackFunctions *cb, const char *name, fmi2Status status,
                 const char *category, const char *text) {
    char buf[1100];
    size_t i = 0, k = 0;
    if (!cb || !cb->logger) return;
    while (text[i] && k + 2 < sizeof buf) {
        if (text[i] == '%') buf[k++] = '%';
        buf[k++] = text[i++];
    }
    buf[k] = '\0';
    cb->logger(cb->componentEnvironment, name ? name : MODEL_IDENTIFIER, status, category, buf);
}

static void log_fmt(const Instance *s, fmi2Status status, const char *category, const char *fmt, ...) {
    char text[1024];
    va_list ap;
    if (!s) return;
    if (status == fmi2OK && !s->log_calls) return;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    emit(&s->cb, s->name, status, category, text);
}

/* Log the model's last message as an error, prefixed by the FMI function name. */
static fmi2Status model_error(const Instance *s, const char *function) {
    log_fmt(s, fmi2Error, "logStatusError", "%s: %s", function, s->m.msg);
    return fmi2Error;
}

static fmi2Status error(const Instance *s, const char *function, const char *what) {
    log_fmt(s, fmi2Error, "logStatusError", "%s: %s", function, what);
    return fmi2Error;
}

#define CHECK_INSTANCE(c) \
    if (!(c)) return fmi2Error; \
    Instance *s = (Instance *)(c)

#define CHECK_ARRAYS(fn, vr, nvr, value)                                                       \
    if ((nvr) > 0 && (!(vr) || !(value)))                                                     \
        return error(s, fn, "null pointer for the value references or values with nvr > 0")

/* ------------------------------------------------------------------------ */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    size_t i;
    int calls = 0;
    CHECK_INSTANCE(c);
    if (nCategories > 0 && !categories) return error(s, "fmi2SetDebugLogging", "null categories with nCategories > 0");
    for (i = 0; i < nCategories; ++i) {
        if (!categories[i]) return error(s, "fmi2SetDebugLogging", "null category name");
        if (strcmp(categories[i], "logCalls") == 0) calls = 1;
        else if (strcmp(categories[i], "logStatusError") != 0 && strcmp(categories[i], "logStatusWarning") != 0) {
            log_fmt(s, fmi2Error, "logStatusError",
                    "fmi2SetDebugLogging: unknown log category \"%s\" (known: logStatusError, "
                    "logStatusWarning, logCalls)",
                    categories[i]);
            return fmi2Error;
        }
    }
    s->log_calls = loggingOn && (nCategories == 0 || calls);
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    Instance *s;
    size_t n;
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions) return NULL;
    if (!instanceName || !instanceName[0]) {
        emit(functions, NULL, fmi2Error, "logStatusError", "fmi2Instantiate: missing instance name");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        emit(functions, instanceName, fmi2Error, "logStatusError",
             "fmi2Instantiate: " MODEL_IDENTIFIER " supports Co-Simulation only, not Model Exchange");
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, MODEL_GUID) != 0) {
        emit(functions, instanceName, fmi2Error, "logStatusError",
             "fmi2Instantiate: GUID does not match the binary (expected " MODEL_GUID
             "): the modelDescription.xml belongs to another build");
        return NULL;
    }
    s = (Instance *)calloc(1, sizeof(Instance));
    n = strlen(instanceName);
    if (s) s->name = (char *)malloc(n + 1);
    if (!s || !s->name) {
        free(s);
        emit(functions, instanceName, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
        return NULL;
    }
    memcpy(s->name, instanceName, n + 1);
    s->cb = *functions;
    s->log_calls = loggingOn ? 1 : 0;
    s->start_time = 0.0;
    model_reset(&s->m);
    log_fmt(s, fmi2OK, "logCalls", "fmi2Instantiate: instance \"%s\" created", instanceName);
    return s;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *s = (Instance *)c;
    if (!s) return;
    log_fmt(s, fmi2OK, "logCalls", "fmi2FreeInstance");
    model_free(&s->m);
    free(s->name);
    free(s);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    CHECK_INSTANCE(c);
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (s->m.phase != PHASE_INSTANTIATED)
        return error(s, "fmi2SetupExperiment", "only allowed after instantiation or reset");
    if (!isfinite(startTime)) return error(s, "fmi2SetupExperiment", "start time must be finite");
    s->start_time = startTime;
    log_fmt(s, fmi2OK, "logCalls", "fmi2SetupExperiment: startTime = %.17g", startTime);
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    CHECK_INSTANCE(c);
    if (model_enter_initialization(&s->m, s->start_time) != MODEL_OK)
        return model_error(s, "fmi2EnterInitializationMode");
    log_fmt(s, fmi2OK, "logCalls", "fmi2EnterInitializationMode");
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    CHECK_INSTANCE(c);
    if (model_exit_initialization(&s->m) != MODEL_OK) return model_error(s, "fmi2ExitInitializationMode");
    log_fmt(s, fmi2OK, "logCalls", "fmi2ExitInitializationMode");
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    CHECK_INSTANCE(c);
    if (model_terminate(&s->m) != MODEL_OK) return model_error(s, "fmi2Terminate");
    log_fmt(s, fmi2OK, "logCalls", "fmi2Terminate");
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    CHECK_INSTANCE(c);
    model_reset(&s->m);
    s->start_time = 0.0;
    log_fmt(s, fmi2OK, "logCalls", "fmi2Reset");
    return fmi2OK;
}

/* ------------------------------------------------------------------------ */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    size_t i;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2GetReal", vr, nvr, value);
    for (i = 0; i < nvr; ++i)
        if (model_get_real(&s->m, vr[i], &value[i]) != MODEL_OK) return model_error(s, "fmi2GetReal");
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    size_t i;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2GetInteger", vr, nvr, value);
    for (i = 0; i < nvr; ++i)
        if (model_get_integer(&s->m, vr[i], &value[i]) != MODEL_OK) return model_error(s, "fmi2GetInteger");
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2GetBoolean", vr, nvr, value);
    if (nvr > 0) return error(s, "fmi2GetBoolean", "the model has no Boolean variables");
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2GetString", vr, nvr, value);
    if (nvr > 0) return error(s, "fmi2GetString", "the model has no String variables");
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    size_t i;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2SetReal", vr, nvr, value);
    for (i = 0; i < nvr; ++i)
        if (model_set_real(&s->m, vr[i], value[i]) != MODEL_OK) return model_error(s, "fmi2SetReal");
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    size_t i;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2SetInteger", vr, nvr, value);
    for (i = 0; i < nvr; ++i)
        if (model_set_integer(&s->m, vr[i], value[i]) != MODEL_OK) return model_error(s, "fmi2SetInteger");
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2SetBoolean", vr, nvr, value);
    if (nvr > 0) return error(s, "fmi2SetBoolean", "the model has no Boolean variables");
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2SetString", vr, nvr, value);
    if (nvr > 0) return error(s, "fmi2SetString", "the model has no String variables");
    return fmi2OK;
}

/* ------------------------------------------------------------------------ */
/* FMU state: a deep copy of the model (parameters, inputs and their derivatives, states, time, phase, the
 * input-delay history) and of the start time of fmi2SetupExperiment                                        */

typedef struct {
    unsigned long tag; /* MODEL_STATE_TAG: refuses a state of another model, or a freed one */
    double start_time;
    Model m;
} SavedState;

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    SavedState *st;
    int fresh = 0;
    CHECK_INSTANCE(c);
    if (!FMUstate) return error(s, "fmi2GetFMUstate", "null pointer for the FMU state");
    st = (SavedState *)*FMUstate;
    if (st && st->tag != MODEL_STATE_TAG)
        return error(s, "fmi2GetFMUstate", "the FMU state to overwrite was not made by " MODEL_IDENTIFIER);
    if (!st) {
        st = (SavedState *)calloc(1, sizeof(SavedState));
        if (!st) return error(s, "fmi2GetFMUstate", "out of memory");
        st->tag = MODEL_STATE_TAG;
        fresh = 1;
    }
    if (model_copy(&st->m, &s->m) != MODEL_OK) {
        log_fmt(s, fmi2Error, "logStatusError", "fmi2GetFMUstate: %s", st->m.msg);
        if (fresh) {
            model_free(&st->m);
            free(st);
        }
        return fmi2Error;
    }
    st->start_time = s->start_time;
    *FMUstate = st;
    log_fmt(s, fmi2OK, "logCalls", "fmi2GetFMUstate: at t = %.17g", s->m.time);
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    const SavedState *st = (const SavedState *)FMUstate;
    CHECK_INSTANCE(c);
    if (!st) return error(s, "fmi2SetFMUstate", "null FMU state");
    if (st->tag != MODEL_STATE_TAG)
        return error(s, "fmi2SetFMUstate", "the FMU state was not made by " MODEL_IDENTIFIER " (or was freed)");
    if (model_copy(&s->m, &st->m) != MODEL_OK) return model_error(s, "fmi2SetFMUstate");
    s->start_time = st->start_time;
    log_fmt(s, fmi2OK, "logCalls", "fmi2SetFMUstate: back to t = %.17g", s->m.time);
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    SavedState *st;
    CHECK_INSTANCE(c);
    if (!FMUstate) return error(s, "fmi2FreeFMUstate", "null pointer for the FMU state");
    st = (SavedState *)*FMUstate;
    if (!st) return fmi2OK; /* nothing to free */
    if (st->tag != MODEL_STATE_TAG)
        return error(s, "fmi2FreeFMUstate", "the FMU state was not made by " MODEL_IDENTIFIER " (or was freed)");
    st->tag = 0;
    model_free(&st->m);
    free(st);
    *FMUstate = NULL;
    return fmi2OK;
}

/* ------------------------------------------------------------------------ */
/* not supported                                                              */

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    CHECK_INSTANCE(c);
    (void)FMUstate;
    (void)size;
    return error(s, "fmi2SerializedFMUstateSize", "not supported (canSerializeFMUstate = false)");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    CHECK_INSTANCE(c);
    (void)FMUstate;
    (void)serializedState;
    (void)size;
    return error(s, "fmi2SerializeFMUstate", "not supported (canSerializeFMUstate = false)");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    CHECK_INSTANCE(c);
    (void)serializedState;
    (void)size;
    (void)FMUstate;
    return error(s, "fmi2DeSerializeFMUstate", "not supported (canSerializeFMUstate = false)");
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    CHECK_INSTANCE(c);
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    return error(s, "fmi2GetDirectionalDerivative", "not supported (providesDirectionalDerivative = false)");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    size_t i;
    fmi2Status status = fmi2OK;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2SetRealInputDerivatives", vr, nvr, value);
    if (nvr > 0 && !order) return error(s, "fmi2SetRealInputDerivatives", "null pointer for the orders with nvr > 0");
    for (i = 0; i < nvr; ++i) {
        ModelStatus done = model_set_input_derivative(&s->m, vr[i], (int)order[i], value[i]);
        if (done == MODEL_ERROR) return model_error(s, "fmi2SetRealInputDerivatives");
        if (done == MODEL_WARNING) {
            log_fmt(s, fmi2Warning, "logStatusWarning", "fmi2SetRealInputDerivatives: %s", s->m.msg);
            status = fmi2Warning;
        }
    }
    return status;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    CHECK_INSTANCE(c);
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return error(s, "fmi2GetRealOutputDerivatives", "not supported (maxOutputDerivativeOrder = 0)");
}

/* ------------------------------------------------------------------------ */
/* co-simulation                                                              */

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    CHECK_INSTANCE(c);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (model_do_step(&s->m, currentCommunicationPoint, communicationStepSize) != MODEL_OK)
        return model_error(s, "fmi2DoStep");
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    CHECK_INSTANCE(c);
    return error(s, "fmi2CancelStep", "not supported: doStep never runs asynchronously");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Status *value) {
    CHECK_INSTANCE(c);
    (void)kind;
    (void)value;
    return error(s, "fmi2GetStatus", "no status to query: doStep never returns fmi2Pending");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Real *value) {
    CHECK_INSTANCE(c);
    if (!value) return error(s, "fmi2GetRealStatus", "null value pointer");
    if (kind != fmi2LastSuccessfulTime)
        return error(s, "fmi2GetRealStatus", "only fmi2LastSuccessfulTime is available");
    *value = s->m.time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Integer *value) {
    CHECK_INSTANCE(c);
    (void)kind;
    (void)value;
    return error(s, "fmi2GetIntegerStatus", "no Integer status is available");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Boolean *value) {
    CHECK_INSTANCE(c);
    if (!value) return error(s, "fmi2GetBooleanStatus", "null value pointer");
    if (kind != fmi2Terminated) return error(s, "fmi2GetBooleanStatus", "only fmi2Terminated is available");
    *value = fmi2False; /* the model never asks to end the simulation */
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind kind, fmi2String *value) {
    CHECK_INSTANCE(c);
    (void)kind;
    (void)value;
    return error(s, "fmi2GetStringStatus", "no String status is available: doStep never returns fmi2Pending");
}
