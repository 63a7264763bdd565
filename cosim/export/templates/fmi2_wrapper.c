/*
 * FMI 2.0 Co-Simulation wrapper of a model exported by cosim.export. Generic: the model (its right-hand
 * side, and for a linear model its exact zero-order-hold step) is in the generated model.c.
 *
 * Value references: 0 time; 1..NU inputs; NU+1..NU+NX states (outputs, initial="exact");
 * NU+NX+1..NU+2NX der(state); NU+2NX+1 dt (Real constant, linear models); NU+2NX+2 nsub (Integer
 * parameter, nonlinear models).  Every function checks its arguments; a bad call returns fmi2Error and logs
 * one line saying what was wrong (category logStatusError, always); with loggingOn the life-cycle calls
 * are logged too (logCalls).  FMU state get/set and directional derivatives are not supported.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"

#define NU_ALLOC (NU > 0 ? NU : 1)
#define VR_TIME 0u
#define VR_INPUT 1u
#define VR_STATE (1u + NU)
#define VR_DERIVATIVE (1u + NU + NX)
#define VR_DT (1u + NU + 2u * NX)
#define VR_NSUB (2u + NU + 2u * NX)
#define STATE_LIMIT DIVERGENCE_LIMIT_VALUE

typedef enum { PHASE_INSTANTIATED, PHASE_INITIALIZATION, PHASE_STEPPING, PHASE_TERMINATED, PHASE_ERROR } Phase;

typedef struct {
    double x[NX];
    double u[NU_ALLOC];
    double time;       /* start time before initialization, then the end of the last step */
    double start_time;
    int nsub;
    Phase phase;
    int log_calls;
    fmi2CallbackFunctions cb;
    char *name;
} Instance;

/* FMI 2 loggers treat the message as a printf format: escape '%'. */
static void emit(const fmi2CallbackFunctions *cb, const char *name, fmi2Status status, const char *category,
                 const char *text) {
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

static void log_calls(const Instance *s, const char *text) {
    if (s && s->log_calls) emit(&s->cb, s->name, fmi2OK, "logCalls", text);
}

static fmi2Status fail(const Instance *s, const char *function, const char *fmt, ...) {
    char text[900], line[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    snprintf(line, sizeof line, "%s: %s", function, text);
    if (s) emit(&s->cb, s->name, fmi2Error, "logStatusError", line);
    return fmi2Error;
}

static void reset_values(Instance *s) {
    int i;
    for (i = 0; i < NX; ++i) s->x[i] = 0.0;
    for (i = 0; i < NU_ALLOC; ++i) s->u[i] = 0.0;
    s->time = 0.0;
    s->start_time = 0.0;
    s->nsub = MODEL_NSUB;
    s->phase = PHASE_INSTANTIATED;
}

#define CHECK_INSTANCE(c) \
    if (!(c)) return fmi2Error; \
    Instance *s = (Instance *)(c)

#define CHECK_ARRAYS(fn, vr, nvr, value) \
    if ((nvr) > 0 && (!(vr) || !(value))) return fail(s, fn, "null pointer for the value references or values")

/* ------------------------------------------------------------------------ */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    size_t i;
    int calls = 0;
    CHECK_INSTANCE(c);
    if (nCategories > 0 && !categories) return fail(s, "fmi2SetDebugLogging", "null categories");
    for (i = 0; i < nCategories; ++i) {
        if (!categories[i]) return fail(s, "fmi2SetDebugLogging", "null category name");
        if (strcmp(categories[i], "logCalls") == 0) calls = 1;
        else if (strcmp(categories[i], "logStatusError") != 0)
            return fail(s, "fmi2SetDebugLogging", "unknown log category \"%s\" (known: logStatusError, logCalls)",
                        categories[i]);
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
             "fmi2Instantiate: this FMU supports Co-Simulation only, not Model Exchange");
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, MODEL_GUID) != 0) {
        emit(functions, instanceName, fmi2Error, "logStatusError",
             "fmi2Instantiate: GUID does not match the binary (expected " MODEL_GUID
             "): the modelDescription.xml belongs to another export");
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
    reset_values(s);
    log_calls(s, "fmi2Instantiate");
    return s;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *s = (Instance *)c;
    if (!s) return;
    log_calls(s, "fmi2FreeInstance");
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
    if (s->phase != PHASE_INSTANTIATED) return fail(s, "fmi2SetupExperiment", "only allowed after instantiation");
    if (!isfinite(startTime)) return fail(s, "fmi2SetupExperiment", "start time must be finite");
    s->start_time = startTime;
    log_calls(s, "fmi2SetupExperiment");
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    CHECK_INSTANCE(c);
    if (s->phase != PHASE_INSTANTIATED)
        return fail(s, "fmi2EnterInitializationMode", "only allowed right after instantiation or reset");
    s->time = s->start_time;
    s->phase = PHASE_INITIALIZATION;
    log_calls(s, "fmi2EnterInitializationMode");
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    CHECK_INSTANCE(c);
    if (s->phase != PHASE_INITIALIZATION) return fail(s, "fmi2ExitInitializationMode", "not in initialization mode");
    if (s->nsub < 1)
        return fail(s, "fmi2ExitInitializationMode", "parameter nsub = %d is invalid: needs at least 1 RK4 substep",
                    s->nsub);
    s->phase = PHASE_STEPPING;
    log_calls(s, "fmi2ExitInitializationMode");
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    CHECK_INSTANCE(c);
    if (s->phase == PHASE_INSTANTIATED) return fail(s, "fmi2Terminate", "the model was not initialized");
    s->phase = PHASE_TERMINATED;
    log_calls(s, "fmi2Terminate");
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    CHECK_INSTANCE(c);
    reset_values(s);
    log_calls(s, "fmi2Reset");
    return fmi2OK;
}

/* ------------------------------------------------------------------------ */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    size_t i;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2GetReal", vr, nvr, value);
    for (i = 0; i < nvr; ++i) {
        const fmi2ValueReference r = vr[i];
        if (r == VR_TIME) value[i] = s->time;
        else if (r >= VR_INPUT && r < VR_STATE) value[i] = s->u[r - VR_INPUT];
        else if (r >= VR_STATE && r < VR_DERIVATIVE) value[i] = s->x[r - VR_STATE];
        else if (r >= VR_DERIVATIVE && r < VR_DERIVATIVE + NX) {
            double dx[NX];
            model_rhs(s->x, s->u, dx);
            value[i] = dx[r - VR_DERIVATIVE];
        }
#if MODEL_LINEAR
        else if (r == VR_DT) value[i] = MODEL_DT;
#endif
        else return fail(s, "fmi2GetReal", "unknown value reference %u (not a Real variable)", (unsigned)r);
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    size_t i;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2SetReal", vr, nvr, value);
    for (i = 0; i < nvr; ++i) {
        const fmi2ValueReference r = vr[i];
        if (r >= VR_INPUT && r < VR_STATE) {
            if (!isfinite(value[i]))
                return fail(s, "fmi2SetReal", "input %u must be finite, got %g", (unsigned)(r - VR_INPUT), value[i]);
            if (s->phase == PHASE_TERMINATED || s->phase == PHASE_ERROR)
                return fail(s, "fmi2SetReal", "cannot set inputs after terminate or error (call reset first)");
            s->u[r - VR_INPUT] = value[i];
        } else if (r >= VR_STATE && r < VR_DERIVATIVE) {
            const char *name = model_state_names[r - VR_STATE];
            if (!isfinite(value[i])) return fail(s, "fmi2SetReal", "%s must be finite, got %g", name, value[i]);
            if (s->phase != PHASE_INSTANTIATED && s->phase != PHASE_INITIALIZATION)
                return fail(s, "fmi2SetReal", "the state %s can only be set before the end of initialization "
                            "(its start value is the initial state)", name);
            s->x[r - VR_STATE] = value[i];
        } else if (r == VR_TIME || (r >= VR_DERIVATIVE && r < VR_DERIVATIVE + NX) || (MODEL_LINEAR && r == VR_DT)) {
            return fail(s, "fmi2SetReal", "the variable with value reference %u cannot be set", (unsigned)r);
        } else {
            return fail(s, "fmi2SetReal", "unknown value reference %u (not a Real variable)", (unsigned)r);
        }
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    size_t i;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2GetInteger", vr, nvr, value);
    for (i = 0; i < nvr; ++i) {
        if (MODEL_LINEAR || vr[i] != VR_NSUB)
            return fail(s, "fmi2GetInteger", "unknown value reference %u (not an Integer variable)", (unsigned)vr[i]);
        value[i] = s->nsub;
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    size_t i;
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2SetInteger", vr, nvr, value);
    for (i = 0; i < nvr; ++i) {
        if (MODEL_LINEAR || vr[i] != VR_NSUB)
            return fail(s, "fmi2SetInteger", "unknown value reference %u (not an Integer variable)", (unsigned)vr[i]);
        if (s->phase != PHASE_INSTANTIATED && s->phase != PHASE_INITIALIZATION)
            return fail(s, "fmi2SetInteger", "nsub can only be set before the end of initialization");
        s->nsub = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2GetBoolean", vr, nvr, value);
    if (nvr > 0) return fail(s, "fmi2GetBoolean", "the model has no Boolean variables");
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2GetString", vr, nvr, value);
    if (nvr > 0) return fail(s, "fmi2GetString", "the model has no String variables");
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2SetBoolean", vr, nvr, value);
    if (nvr > 0) return fail(s, "fmi2SetBoolean", "the model has no Boolean variables");
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    CHECK_INSTANCE(c);
    CHECK_ARRAYS("fmi2SetString", vr, nvr, value);
    if (nvr > 0) return fail(s, "fmi2SetString", "the model has no String variables");
    return fmi2OK;
}

/* ------------------------------------------------------------------------ */
/* not supported                                                              */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    CHECK_INSTANCE(c);
    (void)FMUstate;
    return fail(s, "fmi2GetFMUstate", "not supported (canGetAndSetFMUstate = false)");
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    CHECK_INSTANCE(c);
    (void)FMUstate;
    return fail(s, "fmi2SetFMUstate", "not supported (canGetAndSetFMUstate = false)");
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    CHECK_INSTANCE(c);
    (void)FMUstate;
    return fail(s, "fmi2FreeFMUstate", "not supported (canGetAndSetFMUstate = false)");
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    CHECK_INSTANCE(c);
    (void)FMUstate;
    (void)size;
    return fail(s, "fmi2SerializedFMUstateSize", "not supported (canSerializeFMUstate = false)");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    CHECK_INSTANCE(c);
    (void)FMUstate;
    (void)serializedState;
    (void)size;
    return fail(s, "fmi2SerializeFMUstate", "not supported (canSerializeFMUstate = false)");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    CHECK_INSTANCE(c);
    (void)serializedState;
    (void)size;
    (void)FMUstate;
    return fail(s, "fmi2DeSerializeFMUstate", "not supported (canSerializeFMUstate = false)");
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
    return fail(s, "fmi2GetDirectionalDerivative", "not supported (providesDirectionalDerivative = false)");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    CHECK_INSTANCE(c);
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return fail(s, "fmi2SetRealInputDerivatives", "not supported (canInterpolateInputs = false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    CHECK_INSTANCE(c);
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return fail(s, "fmi2GetRealOutputDerivatives", "not supported (maxOutputDerivativeOrder = 0)");
}

/* ------------------------------------------------------------------------ */
/* co-simulation                                                              */

#if !MODEL_LINEAR
/* n classical RK4 steps of size h, inputs held: the arithmetic of IdentifiedModel.simulate. */
static void rk4(Instance *s, double h, int n) {
    double k1[NX], k2[NX], k3[NX], k4[NX], y[NX];
    int i, j;
    for (i = 0; i < n; ++i) {
        model_rhs(s->x, s->u, k1);
        for (j = 0; j < NX; ++j) y[j] = s->x[j] + 0.5 * h * k1[j];
        model_rhs(y, s->u, k2);
        for (j = 0; j < NX; ++j) y[j] = s->x[j] + 0.5 * h * k2[j];
        model_rhs(y, s->u, k3);
        for (j = 0; j < NX; ++j) y[j] = s->x[j] + h * k3[j];
        model_rhs(y, s->u, k4);
        for (j = 0; j < NX; ++j) s->x[j] = s->x[j] + h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
    }
}
#endif

static int diverged(const Instance *s) {
    int j;
    for (j = 0; j < NX; ++j)
        if (!(fabs(s->x[j]) < STATE_LIMIT)) return j + 1; /* also catches NaN */
    return 0;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    const double t0 = currentCommunicationPoint, h = communicationStepSize;
    double tol;
    int bad = 0;
    CHECK_INSTANCE(c);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (s->phase == PHASE_ERROR) return fail(s, "fmi2DoStep", "the model is in an error state after a failed step "
                                             "(call reset)");
    if (s->phase != PHASE_STEPPING)
        return fail(s, "fmi2DoStep", "only allowed after the end of initialization and before terminate");
    if (!isfinite(t0) || !isfinite(h) || h < 0.0)
        return fail(s, "fmi2DoStep", "invalid communication point %g or step size %g (step size must be >= 0)", t0, h);
    tol = 1e-9 * (fabs(t0) > 1.0 ? fabs(t0) : 1.0);
    if (fabs(t0 - s->time) > tol)
        return fail(s, "fmi2DoStep", "communication point %.17g differs from the model time %.17g (steps must follow "
                    "each other)", t0, s->time);
    if (h == 0.0) return fmi2OK;
#if MODEL_LINEAR
    {
        const double k = floor(h / MODEL_DT + 0.5);
        double i;
        if (k < 1.0 || k > 1e9 || fabs(k * MODEL_DT - h) > 1e-9 * h)
            return fail(s, "fmi2DoStep", "step size %.17g is not a whole multiple of dt = %.17g, the step this FMU's "
                        "exact discretisation was computed for; step with dt, or export the model again with "
                        "dt=%.17g", h, MODEL_DT, h);
        for (i = 0.0; i < k && !bad; i += 1.0) {
            model_zoh_step(s->x, s->u);
            bad = diverged(s);
        }
    }
#else
    rk4(s, h / (double)s->nsub, s->nsub);
    bad = diverged(s);
#endif
    if (bad) {
        s->phase = PHASE_ERROR; /* time stays at t0, the last successful time */
        return fail(s, "fmi2DoStep", "from t = %.12g to t = %.12g: state %s diverged (value %g, limit %g): the model "
                    "is unstable or the inputs drive it out of range", t0, t0 + h, model_state_names[bad - 1],
                    s->x[bad - 1], STATE_LIMIT);
    }
    s->time = t0 + h;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    CHECK_INSTANCE(c);
    return fail(s, "fmi2CancelStep", "not supported: doStep never returns fmi2Pending");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Status *value) {
    CHECK_INSTANCE(c);
    (void)kind;
    (void)value;
    return fail(s, "fmi2GetStatus", "no status to query: doStep never returns fmi2Pending");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Real *value) {
    CHECK_INSTANCE(c);
    if (!value) return fail(s, "fmi2GetRealStatus", "null value pointer");
    if (kind != fmi2LastSuccessfulTime) return fail(s, "fmi2GetRealStatus", "only fmi2LastSuccessfulTime is available");
    *value = s->time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Integer *value) {
    CHECK_INSTANCE(c);
    (void)kind;
    (void)value;
    return fail(s, "fmi2GetIntegerStatus", "no Integer status is available");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Boolean *value) {
    CHECK_INSTANCE(c);
    if (!value) return fail(s, "fmi2GetBooleanStatus", "null value pointer");
    if (kind != fmi2Terminated) return fail(s, "fmi2GetBooleanStatus", "only fmi2Terminated is available");
    *value = fmi2False; /* the model never asks to end the simulation */
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind kind, fmi2String *value) {
    CHECK_INSTANCE(c);
    (void)kind;
    (void)value;
    return fail(s, "fmi2GetStringStatus", "no String status is available: doStep never returns fmi2Pending");
}
