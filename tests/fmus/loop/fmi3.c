/*
 * FMI 3.0 Co-Simulation wrapper around a model core (model.h) of the loop test FMUs (issue 40). One file
 * for tests/fmus/loop/loop_a, loop_b and loop_b_nostate (the builder takes a folder's missing wrapper from its
 * parent): what differs between them is in model.h.
 *
 * A bad call returns fmi3Error and logs one line. Only Float64 variables exist. With CAN_GET_AND_SET_FMU_STATE
 * the FMU state functions save and restore a copy of the whole model (time, state, inputs, parameters);
 * without it they return fmi3Error. Model Exchange, Scheduled Execution, serialization, derivatives, clocks and
 * configuration mode are not provided (their functions exist, as an importer looks every one up, and return
 * fmi3Error).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "model.h"

typedef struct {
    Model m;
    fmi3LogMessageCallback logger;
    fmi3InstanceEnvironment env;
} Instance;

static fmi3Status error(const Instance *s, const char *function, const char *what) {
    char text[512];
    snprintf(text, sizeof text, "%s: %s", function, what);
    if (s->logger) s->logger(s->env, fmi3Error, "logStatusError", text);
    return fmi3Error;
}

#define CHECK_INSTANCE(c) \
    if (!(c)) return fmi3Error; \
    Instance *s = (Instance *)(c)
#define MODEL_CALL(fn, call) \
    if ((call) != MODEL_OK) return error(s, fn, s->m.msg); \
    return fmi3OK
#define NOT_PROVIDED(fn) \
    CHECK_INSTANCE(instance); \
    return error(s, fn, "not provided by this FMU")
#define NOT_CS(fn) \
    CHECK_INSTANCE(instance); \
    return error(s, fn, "this FMU is for Co-Simulation only")
#define OK_NOTHING_TO_DO \
    CHECK_INSTANCE(instance); \
    (void)s; \
    return fmi3OK

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    OK_NOTHING_TO_DO; /* errors are always logged; there is nothing else to log */
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateModelExchange: this FMU is for Co-Simulation only");
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
    if (eventModeUsed || nRequiredIntermediateVariables) return NULL;
    if (!instantiationToken || strcmp(instantiationToken, MODEL_GUID) != 0) return NULL;
    s = (Instance *)calloc(1, sizeof(Instance));
    if (!s) return NULL;
    s->logger = logMessage;
    s->env = instanceEnvironment;
    model_reset(&s->m);
    return s;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { free(instance); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    CHECK_INSTANCE(instance);
    MODEL_CALL("fmi3EnterInitializationMode", model_enter_initialization(&s->m, startTime));
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    MODEL_CALL("fmi3ExitInitializationMode", model_exit_initialization(&s->m));
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) { OK_NOTHING_TO_DO; }

fmi3Status fmi3Terminate(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    s->m.phase = PHASE_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    model_reset(&s->m);
    return fmi3OK;
}

/* ------------------------------------------------------------------------ */
/* get / set                                                                  */

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    size_t i;
    CHECK_INSTANCE(instance);
    if (nValues != nValueReferences) return error(s, "fmi3GetFloat64", "every variable is a scalar");
    for (i = 0; i < nValueReferences; ++i)
        if (model_get_real(&s->m, valueReferences[i], &values[i]) != MODEL_OK)
            return error(s, "fmi3GetFloat64", s->m.msg);
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    size_t i;
    CHECK_INSTANCE(instance);
    if (nValues != nValueReferences) return error(s, "fmi3SetFloat64", "every variable is a scalar");
    for (i = 0; i < nValueReferences; ++i)
        if (model_set_real(&s->m, valueReferences[i], values[i]) != MODEL_OK)
            return error(s, "fmi3SetFloat64", s->m.msg);
    return fmi3OK;
}

#define NO_SUCH_TYPE(fn, T)                                                                              \
    fmi3Status fn(fmi3Instance instance, const fmi3ValueReference valueReferences[],                     \
                  size_t nValueReferences, T values[], size_t nValues) {                                \
        CHECK_INSTANCE(instance);                                                                        \
        return nValueReferences ? error(s, #fn, "the model has Float64 variables only") : fmi3OK;        \
    }
NO_SUCH_TYPE(fmi3GetFloat32, fmi3Float32)
NO_SUCH_TYPE(fmi3GetInt8, fmi3Int8)
NO_SUCH_TYPE(fmi3GetUInt8, fmi3UInt8)
NO_SUCH_TYPE(fmi3GetInt16, fmi3Int16)
NO_SUCH_TYPE(fmi3GetUInt16, fmi3UInt16)
NO_SUCH_TYPE(fmi3GetInt32, fmi3Int32)
NO_SUCH_TYPE(fmi3GetUInt32, fmi3UInt32)
NO_SUCH_TYPE(fmi3GetInt64, fmi3Int64)
NO_SUCH_TYPE(fmi3GetUInt64, fmi3UInt64)
NO_SUCH_TYPE(fmi3GetBoolean, fmi3Boolean)
NO_SUCH_TYPE(fmi3GetString, fmi3String)
NO_SUCH_TYPE(fmi3SetFloat32, const fmi3Float32)
NO_SUCH_TYPE(fmi3SetInt8, const fmi3Int8)
NO_SUCH_TYPE(fmi3SetUInt8, const fmi3UInt8)
NO_SUCH_TYPE(fmi3SetInt16, const fmi3Int16)
NO_SUCH_TYPE(fmi3SetUInt16, const fmi3UInt16)
NO_SUCH_TYPE(fmi3SetInt32, const fmi3Int32)
NO_SUCH_TYPE(fmi3SetUInt32, const fmi3UInt32)
NO_SUCH_TYPE(fmi3SetInt64, const fmi3Int64)
NO_SUCH_TYPE(fmi3SetUInt64, const fmi3UInt64)
NO_SUCH_TYPE(fmi3SetBoolean, const fmi3Boolean)
NO_SUCH_TYPE(fmi3SetString, const fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    NOT_PROVIDED("fmi3GetBinary");
}
fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const size_t valueSizes[], const fmi3Binary values[],
                         size_t nValues) {
    NOT_PROVIDED("fmi3SetBinary");
}
fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Clock values[]) {
    NOT_PROVIDED("fmi3GetClock");
}
fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Clock values[]) {
    NOT_PROVIDED("fmi3SetClock");
}

/* ------------------------------------------------------------------------ */
/* FMU state                                                                  */

#if CAN_GET_AND_SET_FMU_STATE
fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    Model *saved;
    CHECK_INSTANCE(instance);
    if (!FMUState) return error(s, "fmi3GetFMUState", "FMUState is NULL");
    /* a state given back is overwritten, else a new one is made */
    saved = *FMUState ? (Model *)*FMUState : (Model *)malloc(sizeof(Model));
    if (!saved) return error(s, "fmi3GetFMUState", "out of memory");
    *saved = s->m;
    *FMUState = saved;
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    CHECK_INSTANCE(instance);
    if (!FMUState) return error(s, "fmi3SetFMUState", "FMUState is NULL");
    s->m = *(const Model *)FMUState;
    return fmi3OK;
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    CHECK_INSTANCE(instance);
    (void)s;
    if (FMUState) {
        free(*FMUState);
        *FMUState = NULL;
    }
    return fmi3OK;
}
#else
#define NO_STATE(fn) \
    CHECK_INSTANCE(instance); \
    return error(s, fn, "this FMU cannot save and restore its state (canGetAndSetFMUState is false)")
fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) { NO_STATE("fmi3GetFMUState"); }
fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) { NO_STATE("fmi3SetFMUState"); }
fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) { NO_STATE("fmi3FreeFMUState"); }
#endif

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    NOT_PROVIDED("fmi3SerializedFMUStateSize");
}
fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    NOT_PROVIDED("fmi3SerializeFMUState");
}
fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    NOT_PROVIDED("fmi3DeserializeFMUState");
}

/* ------------------------------------------------------------------------ */
/* not provided                                                               */

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    NOT_PROVIDED("fmi3GetNumberOfVariableDependencies");
}
fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    NOT_PROVIDED("fmi3GetVariableDependencies");
}
fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                        size_t nSensitivity) {
    NOT_PROVIDED("fmi3GetDirectionalDerivative");
}
fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    NOT_PROVIDED("fmi3GetAdjointDerivative");
}
fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) { NOT_PROVIDED("fmi3EnterConfigurationMode"); }
fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) { NOT_PROVIDED("fmi3ExitConfigurationMode"); }
fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    NOT_PROVIDED("fmi3GetIntervalDecimal");
}
fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    NOT_PROVIDED("fmi3GetIntervalFraction");
}
fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    NOT_PROVIDED("fmi3GetShiftDecimal");
}
fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    NOT_PROVIDED("fmi3GetShiftFraction");
}
fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    NOT_PROVIDED("fmi3SetIntervalDecimal");
}
fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    NOT_PROVIDED("fmi3SetIntervalFraction");
}
fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    NOT_PROVIDED("fmi3SetShiftDecimal");
}
fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    NOT_PROVIDED("fmi3SetShiftFraction");
}
fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    NOT_PROVIDED("fmi3GetOutputDerivatives");
}
fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    NOT_PROVIDED("fmi3ActivateModelPartition");
}

/* ------------------------------------------------------------------------ */
/* events (none)                                                              */

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) { OK_NOTHING_TO_DO; }

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    CHECK_INSTANCE(instance);
    (void)s;
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (nominalsOfContinuousStatesChanged) *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged) *valuesOfContinuousStatesChanged = fmi3False;
    if (nextEventTimeDefined) *nextEventTimeDefined = fmi3False;
    if (nextEventTime) *nextEventTime = 0.0;
    return fmi3OK;
}

/* ------------------------------------------------------------------------ */
/* Model Exchange (not provided: an instance is never one)                    */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) { NOT_CS("fmi3EnterContinuousTimeMode"); }
fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    NOT_CS("fmi3CompletedIntegratorStep");
}
fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) { NOT_CS("fmi3SetTime"); }
fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    NOT_CS("fmi3SetContinuousStates");
}
fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[], size_t nContinuousStates) {
    NOT_CS("fmi3GetContinuousStates");
}
fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    NOT_CS("fmi3GetContinuousStateDerivatives");
}
fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    NOT_CS("fmi3GetEventIndicators");
}
fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    NOT_CS("fmi3GetNominalsOfContinuousStates");
}
fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    NOT_CS("fmi3GetNumberOfEventIndicators");
}
fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    NOT_CS("fmi3GetNumberOfContinuousStates");
}

/* ------------------------------------------------------------------------ */
/* Co-Simulation                                                              */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) { OK_NOTHING_TO_DO; }

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn,
                      fmi3Float64 *lastSuccessfulTime) {
    CHECK_INSTANCE(instance);
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (model_do_step(&s->m, currentCommunicationPoint, communicationStepSize) != MODEL_OK)
        return error(s, "fmi3DoStep", s->m.msg);
    if (lastSuccessfulTime) *lastSuccessfulTime = s->m.time;
    return fmi3OK;
}
