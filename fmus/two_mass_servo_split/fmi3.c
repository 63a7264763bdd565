/*
 * FMI 3.0 Co-Simulation wrapper around a model core (model.h): one file for motor/ and shaft_load/ of
 * fmus/two_mass_servo_split (the builder takes a folder's missing wrapper from its parent); what differs
 * between the two FMUs is in their model.h and model.c.
 *
 * Every function checks its arguments; a bad call returns fmi3Error and logs one line through the logMessage
 * callback.  Provided beyond the one-FMU servo's wrapper: FMU state get/set/free (a deep copy of the whole
 * model, the input-delay history included).  FMI 3.0 has no input derivatives for Co-Simulation: inputs are
 * held over a step.  Model Exchange, Scheduled Execution, state serialisation, derivatives, clocks and
 * configuration mode are not provided: those functions exist (an importer may look them up) and return
 * fmi3Error.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "model.h"

typedef struct {
    Model m;
    fmi3LogMessageCallback logger;
    fmi3InstanceEnvironment env;
    char *name;
    int log_calls;
    int event_mode_used;
    int in_event_mode;
} Instance;

static void log_fmt(const Instance *s, fmi3Status status, const char *category, const char *fmt, ...) {
    char text[1024];
    va_list ap;
    if (!s || !s->logger) return;
    if (status == fmi3OK && !s->log_calls) return;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    s->logger(s->env, status, category, text);
}

static fmi3Status model_error(const Instance *s, const char *function) {
    log_fmt(s, fmi3Error, "logStatusError", "%s: %s", function, s->m.msg);
    return fmi3Error;
}

static fmi3Status error(const Instance *s, const char *function, const char *what) {
    log_fmt(s, fmi3Error, "logStatusError", "%s: %s", function, what);
    return fmi3Error;
}

#define CHECK_INSTANCE(c) \
    if (!(c)) return fmi3Error; \
    Instance *s = (Instance *)(c)

/* Scalar variables only: nValues must equal nValueReferences. */
#define CHECK_ARRAYS(fn, vr, nvr, values, nValues)                                              \
    if ((nvr) > 0 && (!(vr) || !(values)))                                                      \
        return error(s, fn, "null pointer for the value references or values with nvr > 0");   \
    if ((nValues) != (nvr)) return error(s, fn, "nValues must equal nValueReferences (all variables are scalars)")

/* Functions for variable types the model does not have. */
#define NO_SUCH_TYPE_GET(fn, T)                                                                  \
    fmi3Status fn(fmi3Instance instance, const fmi3ValueReference valueReferences[],             \
                  size_t nValueReferences, T values[], size_t nValues) {                        \
        CHECK_INSTANCE(instance);                                                                \
        (void)valueReferences;                                                                   \
        (void)values;                                                                            \
        (void)nValues;                                                                           \
        if (nValueReferences > 0) return error(s, #fn, "the model has no variables of this type"); \
        return fmi3OK;                                                                           \
    }
#define NO_SUCH_TYPE_SET(fn, T)                                                                  \
    fmi3Status fn(fmi3Instance instance, const fmi3ValueReference valueReferences[],             \
                  size_t nValueReferences, const T values[], size_t nValues) {                  \
        CHECK_INSTANCE(instance);                                                                \
        (void)valueReferences;                                                                   \
        (void)values;                                                                            \
        (void)nValues;                                                                           \
        if (nValueReferences > 0) return error(s, #fn, "the model has no variables of this type"); \
        return fmi3OK;                                                                           \
    }

/* ------------------------------------------------------------------------ */
/* common functions                                                           */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    size_t i;
    int calls = 0;
    CHECK_INSTANCE(instance);
    if (nCategories > 0 && !categories) return error(s, "fmi3SetDebugLogging", "null categories with nCategories > 0");
    for (i = 0; i < nCategories; ++i) {
        if (!categories[i]) return error(s, "fmi3SetDebugLogging", "null category name");
        if (strcmp(categories[i], "logCalls") == 0) calls = 1;
        else if (strcmp(categories[i], "logStatusError") != 0 && strcmp(categories[i], "logStatusWarning") != 0) {
            log_fmt(s, fmi3Error, "logStatusError",
                    "fmi3SetDebugLogging: unknown log category \"%s\" (known: logStatusError, "
                    "logStatusWarning, logCalls)",
                    categories[i]);
            return fmi3Error;
        }
    }
    s->log_calls = loggingOn && (nCategories == 0 || calls);
    return fmi3OK;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateModelExchange: " MODEL_IDENTIFIER " supports Co-Simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    Instance *s;
    size_t n;
    (void)resourcePath;
    (void)visible;
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)intermediateUpdate;
    if (!instanceName || !instanceName[0]) {
        if (logMessage)
            logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                       "fmi3InstantiateCoSimulation: missing instance name");
        return NULL;
    }
    if (!instantiationToken || strcmp(instantiationToken, MODEL_GUID) != 0) {
        if (logMessage)
            logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                       "fmi3InstantiateCoSimulation: instantiationToken does not match the binary (expected "
                       MODEL_GUID "): the modelDescription.xml belongs to another build");
        return NULL;
    }
    if (nRequiredIntermediateVariables > 0) {
        if (logMessage)
            logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                       "fmi3InstantiateCoSimulation: intermediate variable access is not provided");
        return NULL;
    }
    s = (Instance *)calloc(1, sizeof(Instance));
    n = strlen(instanceName);
    if (s) s->name = (char *)malloc(n + 1);
    if (!s || !s->name) {
        free(s);
        if (logMessage)
            logMessage(instanceEnvironment, fmi3Error, "logStatusError", "fmi3InstantiateCoSimulation: out of memory");
        return NULL;
    }
    memcpy(s->name, instanceName, n + 1);
    s->logger = logMessage;
    s->env = instanceEnvironment;
    s->log_calls = loggingOn ? 1 : 0;
    s->event_mode_used = eventModeUsed ? 1 : 0;
    s->in_event_mode = 0;
    model_reset(&s->m);
    log_fmt(s, fmi3OK, "logCalls", "fmi3InstantiateCoSimulation: instance \"%s\" created", instanceName);
    return s;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)clockUpdate;
    (void)lockPreemption;
    (void)unlockPreemption;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateScheduledExecution: " MODEL_IDENTIFIER " supports Co-Simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    Instance *s = (Instance *)instance;
    if (!s) return;
    log_fmt(s, fmi3OK, "logCalls", "fmi3FreeInstance");
    model_free(&s->m);
    free(s->name);
    free(s);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    CHECK_INSTANCE(instance);
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (model_enter_initialization(&s->m, startTime) != MODEL_OK)
        return model_error(s, "fmi3EnterInitializationMode");
    log_fmt(s, fmi3OK, "logCalls", "fmi3EnterInitializationMode: startTime = %.17g", startTime);
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    if (model_exit_initialization(&s->m) != MODEL_OK) return model_error(s, "fmi3ExitInitializationMode");
    s->in_event_mode = s->event_mode_used;
    log_fmt(s, fmi3OK, "logCalls", "fmi3ExitInitializationMode");
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    if (s->m.phase != PHASE_STEPPING) return error(s, "fmi3EnterEventMode", "only allowed in Step Mode");
    if (!s->event_mode_used)
        return error(s, "fmi3EnterEventMode", "the instance was created with eventModeUsed = false");
    s->in_event_mode = 1;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    if (model_terminate(&s->m) != MODEL_OK) return model_error(s, "fmi3Terminate");
    s->in_event_mode = 0;
    log_fmt(s, fmi3OK, "logCalls", "fmi3Terminate");
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    model_reset(&s->m);
    s->in_event_mode = 0;
    log_fmt(s, fmi3OK, "logCalls", "fmi3Reset");
    return fmi3OK;
}

/* ------------------------------------------------------------------------ */
/* get / set                                                                  */

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    size_t i;
    CHECK_INSTANCE(instance);
    CHECK_ARRAYS("fmi3GetFloat64", valueReferences, nValueReferences, values, nValues);
    for (i = 0; i < nValueReferences; ++i)
        if (model_get_real(&s->m, valueReferences[i], &values[i]) != MODEL_OK)
            return model_error(s, "fmi3GetFloat64");
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    size_t i;
    CHECK_INSTANCE(instance);
    CHECK_ARRAYS("fmi3SetFloat64", valueReferences, nValueReferences, values, nValues);
    for (i = 0; i < nValueReferences; ++i)
        if (model_set_real(&s->m, valueReferences[i], values[i]) != MODEL_OK)
            return model_error(s, "fmi3SetFloat64");
    return fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Int32 values[], size_t nValues) {
    size_t i;
    CHECK_INSTANCE(instance);
    CHECK_ARRAYS("fmi3GetInt32", valueReferences, nValueReferences, values, nValues);
    for (i = 0; i < nValueReferences; ++i) {
        int v;
        if (model_get_integer(&s->m, valueReferences[i], &v) != MODEL_OK) return model_error(s, "fmi3GetInt32");
        values[i] = (fmi3Int32)v;
    }
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Int32 values[], size_t nValues) {
    size_t i;
    CHECK_INSTANCE(instance);
    CHECK_ARRAYS("fmi3SetInt32", valueReferences, nValueReferences, values, nValues);
    for (i = 0; i < nValueReferences; ++i)
        if (model_set_integer(&s->m, valueReferences[i], (int)values[i]) != MODEL_OK)
            return model_error(s, "fmi3SetInt32");
    return fmi3OK;
}

NO_SUCH_TYPE_GET(fmi3GetFloat32, fmi3Float32)
NO_SUCH_TYPE_GET(fmi3GetInt8, fmi3Int8)
NO_SUCH_TYPE_GET(fmi3GetUInt8, fmi3UInt8)
NO_SUCH_TYPE_GET(fmi3GetInt16, fmi3Int16)
NO_SUCH_TYPE_GET(fmi3GetUInt16, fmi3UInt16)
NO_SUCH_TYPE_GET(fmi3GetUInt32, fmi3UInt32)
NO_SUCH_TYPE_GET(fmi3GetInt64, fmi3Int64)
NO_SUCH_TYPE_GET(fmi3GetUInt64, fmi3UInt64)
NO_SUCH_TYPE_GET(fmi3GetBoolean, fmi3Boolean)
NO_SUCH_TYPE_GET(fmi3GetString, fmi3String)
NO_SUCH_TYPE_SET(fmi3SetFloat32, fmi3Float32)
NO_SUCH_TYPE_SET(fmi3SetInt8, fmi3Int8)
NO_SUCH_TYPE_SET(fmi3SetUInt8, fmi3UInt8)
NO_SUCH_TYPE_SET(fmi3SetInt16, fmi3Int16)
NO_SUCH_TYPE_SET(fmi3SetUInt16, fmi3UInt16)
NO_SUCH_TYPE_SET(fmi3SetUInt32, fmi3UInt32)
NO_SUCH_TYPE_SET(fmi3SetInt64, fmi3Int64)
NO_SUCH_TYPE_SET(fmi3SetUInt64, fmi3UInt64)
NO_SUCH_TYPE_SET(fmi3SetBoolean, fmi3Boolean)
NO_SUCH_TYPE_SET(fmi3SetString, fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    CHECK_INSTANCE(instance);
    (void)valueReferences;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    if (nValueReferences > 0) return error(s, "fmi3GetBinary", "the model has no Binary variables");
    return fmi3OK;
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const size_t valueSizes[], const fmi3Binary values[],
                         size_t nValues) {
    CHECK_INSTANCE(instance);
    (void)valueReferences;
    (void)valueSizes;
    (void)values;
    (void)nValues;
    if (nValueReferences > 0) return error(s, "fmi3SetBinary", "the model has no Binary variables");
    return fmi3OK;
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Clock values[]) {
    CHECK_INSTANCE(instance);
    (void)valueReferences;
    (void)values;
    if (nValueReferences > 0) return error(s, "fmi3GetClock", "the model has no clocks");
    return fmi3OK;
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Clock values[]) {
    CHECK_INSTANCE(instance);
    (void)valueReferences;
    (void)values;
    if (nValueReferences > 0) return error(s, "fmi3SetClock", "the model has no clocks");
    return fmi3OK;
}

/* ------------------------------------------------------------------------ */
/* not provided                                                               */

#define NOT_PROVIDED(fn, why) \
    CHECK_INSTANCE(instance);   \
    return error(s, fn, why)

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference;
    (void)nDependencies;
    NOT_PROVIDED("fmi3GetNumberOfVariableDependencies", "not provided (see ModelStructure)");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent;
    (void)elementIndicesOfDependent;
    (void)independents;
    (void)elementIndicesOfIndependents;
    (void)dependencyKinds;
    (void)nDependencies;
    NOT_PROVIDED("fmi3GetVariableDependencies", "not provided (see ModelStructure)");
}

/* FMU state: a deep copy of the model (parameters, inputs, states, time, phase, the input-delay history). */

typedef struct {
    unsigned long tag; /* MODEL_STATE_TAG: refuses a state of another model, or a freed one */
    Model m;
} SavedState;

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    SavedState *st;
    int fresh = 0;
    CHECK_INSTANCE(instance);
    if (!FMUState) return error(s, "fmi3GetFMUState", "null pointer for the FMU state");
    st = (SavedState *)*FMUState;
    if (st && st->tag != MODEL_STATE_TAG)
        return error(s, "fmi3GetFMUState", "the FMU state to overwrite was not made by " MODEL_IDENTIFIER);
    if (!st) {
        st = (SavedState *)calloc(1, sizeof(SavedState));
        if (!st) return error(s, "fmi3GetFMUState", "out of memory");
        st->tag = MODEL_STATE_TAG;
        fresh = 1;
    }
    if (model_copy(&st->m, &s->m) != MODEL_OK) {
        log_fmt(s, fmi3Error, "logStatusError", "fmi3GetFMUState: %s", st->m.msg);
        if (fresh) {
            model_free(&st->m);
            free(st);
        }
        return fmi3Error;
    }
    *FMUState = st;
    log_fmt(s, fmi3OK, "logCalls", "fmi3GetFMUState: at t = %.17g", s->m.time);
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    const SavedState *st = (const SavedState *)FMUState;
    CHECK_INSTANCE(instance);
    if (!st) return error(s, "fmi3SetFMUState", "null FMU state");
    if (st->tag != MODEL_STATE_TAG)
        return error(s, "fmi3SetFMUState", "the FMU state was not made by " MODEL_IDENTIFIER " (or was freed)");
    if (model_copy(&s->m, &st->m) != MODEL_OK) return model_error(s, "fmi3SetFMUState");
    log_fmt(s, fmi3OK, "logCalls", "fmi3SetFMUState: back to t = %.17g", s->m.time);
    return fmi3OK;
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    SavedState *st;
    CHECK_INSTANCE(instance);
    if (!FMUState) return error(s, "fmi3FreeFMUState", "null pointer for the FMU state");
    st = (SavedState *)*FMUState;
    if (!st) return fmi3OK; /* nothing to free */
    if (st->tag != MODEL_STATE_TAG)
        return error(s, "fmi3FreeFMUState", "the FMU state was not made by " MODEL_IDENTIFIER " (or was freed)");
    st->tag = 0;
    model_free(&st->m);
    free(st);
    *FMUState = NULL;
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    (void)FMUState;
    (void)size;
    NOT_PROVIDED("fmi3SerializedFMUStateSize", "not supported (canSerializeFMUState = false)");
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    (void)FMUState;
    (void)serializedState;
    (void)size;
    NOT_PROVIDED("fmi3SerializeFMUState", "not supported (canSerializeFMUState = false)");
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    (void)serializedState;
    (void)size;
    (void)FMUState;
    NOT_PROVIDED("fmi3DeserializeFMUState", "not supported (canSerializeFMUState = false)");
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                        size_t nSensitivity) {
    (void)unknowns;
    (void)nUnknowns;
    (void)knowns;
    (void)nKnowns;
    (void)seed;
    (void)nSeed;
    (void)sensitivity;
    (void)nSensitivity;
    NOT_PROVIDED("fmi3GetDirectionalDerivative", "not provided (providesDirectionalDerivatives = false)");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns;
    (void)nUnknowns;
    (void)knowns;
    (void)nKnowns;
    (void)seed;
    (void)nSeed;
    (void)sensitivity;
    (void)nSensitivity;
    NOT_PROVIDED("fmi3GetAdjointDerivative", "not provided (providesAdjointDerivatives = false)");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    NOT_PROVIDED("fmi3EnterConfigurationMode", "the model has no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    NOT_PROVIDED("fmi3ExitConfigurationMode", "the model has no structural parameters");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)intervals;
    (void)qualifiers;
    NOT_PROVIDED("fmi3GetIntervalDecimal", "the model has no clocks");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    (void)qualifiers;
    NOT_PROVIDED("fmi3GetIntervalFraction", "the model has no clocks");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)shifts;
    NOT_PROVIDED("fmi3GetShiftDecimal", "the model has no clocks");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    NOT_PROVIDED("fmi3GetShiftFraction", "the model has no clocks");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)intervals;
    NOT_PROVIDED("fmi3SetIntervalDecimal", "the model has no clocks");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    NOT_PROVIDED("fmi3SetIntervalFraction", "the model has no clocks");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)shifts;
    NOT_PROVIDED("fmi3SetShiftDecimal", "the model has no clocks");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    NOT_PROVIDED("fmi3SetShiftFraction", "the model has no clocks");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    (void)s;
    return fmi3OK; /* no discrete states */
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    CHECK_INSTANCE(instance);
    if (s->m.phase != PHASE_INITIALIZATION && s->m.phase != PHASE_STEPPING)
        return error(s, "fmi3UpdateDiscreteStates", "only allowed in Event Mode");
    /* no discrete states and no events: nothing ever changes */
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (nominalsOfContinuousStatesChanged) *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged) *valuesOfContinuousStatesChanged = fmi3False;
    if (nextEventTimeDefined) *nextEventTimeDefined = fmi3False;
    if (nextEventTime) *nextEventTime = 0.0;
    return fmi3OK;
}

/* Model Exchange: not provided */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    NOT_PROVIDED("fmi3EnterContinuousTimeMode", "Model Exchange is not provided");
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    (void)enterEventMode;
    (void)terminateSimulation;
    NOT_PROVIDED("fmi3CompletedIntegratorStep", "Model Exchange is not provided");
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    (void)time;
    NOT_PROVIDED("fmi3SetTime", "Model Exchange is not provided");
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates;
    (void)nContinuousStates;
    NOT_PROVIDED("fmi3SetContinuousStates", "Model Exchange is not provided");
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    (void)derivatives;
    (void)nContinuousStates;
    NOT_PROVIDED("fmi3GetContinuousStateDerivatives", "Model Exchange is not provided");
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    (void)eventIndicators;
    (void)nEventIndicators;
    NOT_PROVIDED("fmi3GetEventIndicators", "Model Exchange is not provided");
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates;
    (void)nContinuousStates;
    NOT_PROVIDED("fmi3GetContinuousStates", "Model Exchange is not provided");
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    (void)nominals;
    (void)nContinuousStates;
    NOT_PROVIDED("fmi3GetNominalsOfContinuousStates", "Model Exchange is not provided");
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    (void)nEventIndicators;
    NOT_PROVIDED("fmi3GetNumberOfEventIndicators", "Model Exchange is not provided");
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    (void)nContinuousStates;
    NOT_PROVIDED("fmi3GetNumberOfContinuousStates", "Model Exchange is not provided");
}

/* ------------------------------------------------------------------------ */
/* co-simulation                                                              */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    if (s->m.phase != PHASE_STEPPING) return error(s, "fmi3EnterStepMode", "only allowed after initialization");
    s->in_event_mode = 0;
    return fmi3OK;
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)orders;
    (void)values;
    (void)nValues;
    NOT_PROVIDED("fmi3GetOutputDerivatives", "not provided (maxOutputDerivativeOrder = 0)");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn,
                      fmi3Float64 *lastSuccessfulTime) {
    fmi3Status status = fmi3OK;
    CHECK_INSTANCE(instance);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (s->in_event_mode) {
        status = error(s, "fmi3DoStep", "the instance is in Event Mode: call fmi3EnterStepMode first");
    } else if (model_do_step(&s->m, currentCommunicationPoint, communicationStepSize) != MODEL_OK) {
        status = model_error(s, "fmi3DoStep");
    }
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (lastSuccessfulTime) *lastSuccessfulTime = s->m.time;
    return status;
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference;
    (void)activationTime;
    NOT_PROVIDED("fmi3ActivateModelPartition", "Scheduled Execution is not provided");
}
