/* The FMI 3.0 API (Model Exchange and Co-Simulation) on top of instance.c: each function
 * checks its handle and arguments, then calls the instance. No physics here. */
#include <string.h>

#include "fmi3Functions.h"
#include "instance.h"

#define LOOKUP(c, function)                        \
    SmInstance* inst = sm_lookup((c), (function)); \
    if (inst == NULL) return fmi3Error

#define CALL(c, function, mask) \
    LOOKUP(c, function);        \
    if (!sm_allowed(inst, (mask), (function))) return fmi3Error

static void log_fmi3(SmCallback callback, void* env, const char* instance, SmStatus status,
                     const char* category, const char* message) {
    (void)instance; /* FMI 3.0 loggers know their instance by its environment */
    ((fmi3LogMessageCallback)callback)(env, (fmi3Status)status, category, message);
}

static fmi3Status refuse(fmi3Instance c, const char* function, const char* why) {
    LOOKUP(c, function);
    sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: %s", function, why);
    return fmi3Error;
}

static int same_count(SmInstance* inst, const char* function, size_t n, size_t expected) {
    if (n == expected) return 1;
    sm_log(inst, SM_ERROR, SM_LOG_ERROR,
           "%s: %zu values for %zu value references (every variable is a scalar)", function, n,
           expected);
    return 0;
}

const char* fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    LOOKUP(c, "fmi3SetDebugLogging");
    return (fmi3Status)sm_set_logging(inst, loggingOn, nCategories, categories);
}

static fmi3Instance instantiate(fmi3String name, fmi3String token, int cosim, fmi3Boolean logging,
                                fmi3InstanceEnvironment env, fmi3LogMessageCallback log) {
    const char* why = NULL;
    if (name == NULL || name[0] == '\0') {
        why = "instantiate: the instance name is missing";
    } else if (token == NULL || strcmp(token, SM_GUID) != 0) {
        why = "instantiate: the instantiation token is not this FMU's (" SM_GUID ")";
    }
    if (why != NULL) {
        if (log != NULL) log(env, fmi3Error, "logStatusError", why);
        return NULL;
    }
    return sm_new(name, cosim, log_fmi3, (SmCallback)log, env, logging);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)resourcePath, (void)visible;
    return instantiate(instanceName, instantiationToken, 0, loggingOn, instanceEnvironment,
                       logMessage);
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    /* no events, no early return, no intermediate variables: event mode only if used */
    (void)resourcePath, (void)visible, (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables, (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    SmInstance* inst = instantiate(instanceName, instantiationToken, 1, loggingOn,
                                   instanceEnvironment, logMessage);
    if (inst != NULL) inst->event_mode = eventModeUsed != fmi3False;
    return inst;
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName, (void)instantiationToken, (void)resourcePath, (void)visible;
    (void)loggingOn, (void)clockUpdate, (void)lockPreemption, (void)unlockPreemption;
    if (logMessage != NULL) {
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateScheduledExecution: this FMU has no Scheduled Execution");
    }
    return NULL;
}

void fmi3FreeInstance(fmi3Instance c) {
    SmInstance* inst = sm_lookup(c, "fmi3FreeInstance");
    if (inst != NULL) sm_free(inst);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance c, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    char msg[SM_MSG] = "";
    CALL(c, "fmi3EnterInitializationMode", SM_INSTANTIATED);
    if (sm_set_tolerance(&inst->wk, toleranceDefined, tolerance, msg)) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "fmi3EnterInitializationMode: %s", msg);
        return fmi3Error;
    }
    if (sm_setup(inst, startTime, stopTimeDefined, stopTime) != SM_OK) return fmi3Error;
    return (fmi3Status)sm_enter_init(inst);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance c) {
    CALL(c, "fmi3ExitInitializationMode", SM_INIT);
    /* Co-Simulation: event mode first if the importer uses it, else step mode */
    return (fmi3Status)sm_exit_init(inst, inst->cosim && !inst->event_mode ? SM_STEP : SM_EVENT);
}

fmi3Status fmi3EnterEventMode(fmi3Instance c) {
    CALL(c, "fmi3EnterEventMode", SM_EVENT | SM_CONT | SM_STEP);
    if (!sm_mode_fits(inst, SM_EVENT)) {
        return refuse(c, "fmi3EnterEventMode",
                      "this Co-Simulation instance was instantiated without eventModeUsed");
    }
    inst->v.mode = SM_EVENT;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance c) {
    CALL(c, "fmi3Terminate", SM_STEP | SM_EVENT | SM_CONT);
    inst->v.mode = SM_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance c) {
    LOOKUP(c, "fmi3Reset");
    sm_reset(inst);
    return fmi3OK;
}

fmi3Status fmi3GetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Float64 values[], size_t nValues) {
    LOOKUP(c, "fmi3GetFloat64");
    if (!same_count(inst, "fmi3GetFloat64", nValues, nvr)) return fmi3Error;
    return (fmi3Status)sm_get_reals(inst, vr, nvr, values);
}

fmi3Status fmi3SetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues) {
    LOOKUP(c, "fmi3SetFloat64");
    if (!same_count(inst, "fmi3SetFloat64", nValues, nvr)) return fmi3Error;
    return (fmi3Status)sm_set_reals(inst, vr, nvr, values);
}

/* The FMU has Float64 variables only: any other type is an unknown value reference. */
static fmi3Status no_such(fmi3Instance c, const char* function, size_t nvr) {
    LOOKUP(c, function);
    if (nvr == 0) return fmi3OK;
    sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: this FMU has no variables of that type", function);
    return fmi3Error;
}

#define NO_SUCH_TYPE(Name, Type)                                                               \
    fmi3Status fmi3Get##Name(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,        \
                             Type values[], size_t nValues) {                                  \
        (void)vr, (void)values, (void)nValues;                                                 \
        return no_such(c, "fmi3Get" #Name, nvr);                                               \
    }                                                                                          \
    fmi3Status fmi3Set##Name(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,        \
                             const Type values[], size_t nValues) {                            \
        (void)vr, (void)values, (void)nValues;                                                 \
        return no_such(c, "fmi3Set" #Name, nvr);                                               \
    }

NO_SUCH_TYPE(Float32, fmi3Float32)
NO_SUCH_TYPE(Int8, fmi3Int8)
NO_SUCH_TYPE(UInt8, fmi3UInt8)
NO_SUCH_TYPE(Int16, fmi3Int16)
NO_SUCH_TYPE(UInt16, fmi3UInt16)
NO_SUCH_TYPE(Int32, fmi3Int32)
NO_SUCH_TYPE(UInt32, fmi3UInt32)
NO_SUCH_TYPE(Int64, fmi3Int64)
NO_SUCH_TYPE(UInt64, fmi3UInt64)
NO_SUCH_TYPE(Boolean, fmi3Boolean)
NO_SUCH_TYPE(String, fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    (void)vr, (void)valueSizes, (void)values, (void)nValues;
    return no_such(c, "fmi3GetBinary", nvr);
}

fmi3Status fmi3SetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    (void)vr, (void)valueSizes, (void)values, (void)nValues;
    return no_such(c, "fmi3SetBinary", nvr);
}

fmi3Status fmi3GetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Clock values[]) {
    (void)vr, (void)values;
    return no_such(c, "fmi3GetClock", nvr);
}

fmi3Status fmi3SetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[]) {
    (void)vr, (void)values;
    return no_such(c, "fmi3SetClock", nvr);
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance c, fmi3ValueReference valueReference,
                                               size_t* nDependencies) {
    (void)valueReference, (void)nDependencies;
    return refuse(c, "fmi3GetNumberOfVariableDependencies",
                  "not provided; the model description lists the dependencies");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance c, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent, (void)elementIndicesOfDependent, (void)independents;
    (void)elementIndicesOfIndependents, (void)dependencyKinds, (void)nDependencies;
    return refuse(c, "fmi3GetVariableDependencies",
                  "not provided; the model description lists the dependencies");
}

/* --- FMU state: handles checked against the registry of live states (instance.c) ------ */
fmi3Status fmi3GetFMUState(fmi3Instance c, fmi3FMUState* FMUState) {
    CALL(c, "fmi3GetFMUState", SM_ANY);
    return (fmi3Status)sm_get_state(inst, (void**)FMUState, "fmi3GetFMUState");
}

fmi3Status fmi3SetFMUState(fmi3Instance c, fmi3FMUState FMUState) {
    CALL(c, "fmi3SetFMUState", SM_ANY);
    return (fmi3Status)sm_set_state(inst, FMUState, "fmi3SetFMUState");
}

fmi3Status fmi3FreeFMUState(fmi3Instance c, fmi3FMUState* FMUState) {
    CALL(c, "fmi3FreeFMUState", SM_ANY);
    return (fmi3Status)sm_free_state(inst, (void**)FMUState, "fmi3FreeFMUState");
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance c, fmi3FMUState FMUState, size_t* size) {
    CALL(c, "fmi3SerializedFMUStateSize", SM_ANY);
    return (fmi3Status)sm_serialized_size(inst, FMUState, size, "fmi3SerializedFMUStateSize");
}

fmi3Status fmi3SerializeFMUState(fmi3Instance c, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    CALL(c, "fmi3SerializeFMUState", SM_ANY);
    return (fmi3Status)sm_serialize(inst, FMUState, (char*)serializedState, size,
                                    "fmi3SerializeFMUState");
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance c, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState* FMUState) {
    CALL(c, "fmi3DeserializeFMUState", SM_ANY);
    return (fmi3Status)sm_deserialize(inst, (const char*)serializedState, size, (void**)FMUState,
                                      "fmi3DeserializeFMUState");
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance c, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity) {
    const char* f = "fmi3GetDirectionalDerivative";
    LOOKUP(c, f);
    if (!same_count(inst, f, nSeed, nKnowns) || !same_count(inst, f, nSensitivity, nUnknowns)) {
        return fmi3Error;
    }
    return (fmi3Status)sm_get_directional(inst, unknowns, nUnknowns, knowns, nKnowns, seed,
                                          sensitivity);
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance c, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns, (void)nUnknowns, (void)knowns, (void)nKnowns, (void)seed, (void)nSeed;
    (void)sensitivity, (void)nSensitivity;
    return refuse(c, "fmi3GetAdjointDerivative", "providesAdjointDerivatives is false");
}

/* --- configuration, clocks: none ------------------------------------------------------ */
fmi3Status fmi3EnterConfigurationMode(fmi3Instance c) {
    return refuse(c, "fmi3EnterConfigurationMode", "this FMU has no structural parameters");
}
fmi3Status fmi3ExitConfigurationMode(fmi3Instance c) {
    return refuse(c, "fmi3ExitConfigurationMode", "this FMU has no structural parameters");
}

#define NO_CLOCKS "this FMU has no clocks"
fmi3Status fmi3GetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                  fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[]) {
    (void)vr, (void)nvr, (void)intervals, (void)qualifiers;
    return refuse(c, "fmi3GetIntervalDecimal", NO_CLOCKS);
}
fmi3Status fmi3GetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                   fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    (void)vr, (void)nvr, (void)counters, (void)resolutions, (void)qualifiers;
    return refuse(c, "fmi3GetIntervalFraction", NO_CLOCKS);
}
fmi3Status fmi3GetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                               fmi3Float64 shifts[]) {
    (void)vr, (void)nvr, (void)shifts;
    return refuse(c, "fmi3GetShiftDecimal", NO_CLOCKS);
}
fmi3Status fmi3GetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    return refuse(c, "fmi3GetShiftFraction", NO_CLOCKS);
}
fmi3Status fmi3SetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[]) {
    (void)vr, (void)nvr, (void)intervals;
    return refuse(c, "fmi3SetIntervalDecimal", NO_CLOCKS);
}
fmi3Status fmi3SetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    return refuse(c, "fmi3SetIntervalFraction", NO_CLOCKS);
}
fmi3Status fmi3SetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                               const fmi3Float64 shifts[]) {
    (void)vr, (void)nvr, (void)shifts;
    return refuse(c, "fmi3SetShiftDecimal", NO_CLOCKS);
}
fmi3Status fmi3SetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    return refuse(c, "fmi3SetShiftFraction", NO_CLOCKS);
}
fmi3Status fmi3ActivateModelPartition(fmi3Instance c, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference, (void)activationTime;
    return refuse(c, "fmi3ActivateModelPartition", NO_CLOCKS);
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance c) {
    CALL(c, "fmi3EvaluateDiscreteStates", SM_INIT | SM_EVENT | SM_CONT | SM_STEP);
    return fmi3OK; /* no discrete states */
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance c, fmi3Boolean* discreteStatesNeedUpdate,
                                    fmi3Boolean* terminateSimulation,
                                    fmi3Boolean* nominalsOfContinuousStatesChanged,
                                    fmi3Boolean* valuesOfContinuousStatesChanged,
                                    fmi3Boolean* nextEventTimeDefined,
                                    fmi3Float64* nextEventTime) {
    CALL(c, "fmi3UpdateDiscreteStates", SM_EVENT);
    fmi3Boolean* flags[] = {discreteStatesNeedUpdate, terminateSimulation,
                            nominalsOfContinuousStatesChanged, valuesOfContinuousStatesChanged,
                            nextEventTimeDefined};
    for (size_t i = 0; i < sizeof flags / sizeof flags[0]; i++) {
        if (flags[i] != NULL) *flags[i] = fmi3False;
    }
    if (nextEventTime != NULL) *nextEventTime = 0.0;
    return fmi3OK;
}

/* --- Model Exchange ------------------------------------------------------------------- */
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance c) {
    CALL(c, "fmi3EnterContinuousTimeMode", SM_EVENT);
    if (!sm_mode_fits(inst, SM_CONT)) {
        return refuse(c, "fmi3EnterContinuousTimeMode", "not a Model Exchange instance");
    }
    inst->v.mode = SM_CONT;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance c, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean* enterEventMode,
                                       fmi3Boolean* terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    char msg[SM_MSG];
    CALL(c, "fmi3CompletedIntegratorStep", SM_CONT);
    if (enterEventMode == NULL || terminateSimulation == NULL) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "fmi3CompletedIntegratorStep: NULL argument");
        return fmi3Error;
    }
    *enterEventMode = fmi3False;
    *terminateSimulation = fmi3False;
    if (sm_check_domain(&inst->wk, inst->v.x, inst->v.u, inst->v.p, msg)) {
        return (fmi3Status)sm_fail(inst, "at t = %.9g s: %s", inst->v.t, msg);
    }
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance c, fmi3Float64 time) {
    LOOKUP(c, "fmi3SetTime");
    return (fmi3Status)sm_set_time(inst, time);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance c, const fmi3Float64 x[], size_t nx) {
    LOOKUP(c, "fmi3SetContinuousStates");
    return (fmi3Status)sm_set_states(inst, x, nx);
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance c, fmi3Float64 derivatives[],
                                             size_t nx) {
    LOOKUP(c, "fmi3GetContinuousStateDerivatives");
    return (fmi3Status)sm_get_derivatives(inst, derivatives, nx);
}

fmi3Status fmi3GetEventIndicators(fmi3Instance c, fmi3Float64 eventIndicators[], size_t ni) {
    (void)eventIndicators;
    CALL(c, "fmi3GetEventIndicators", SM_ANY & ~SM_INSTANTIATED);
    if (ni != 0) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "fmi3GetEventIndicators: this FMU has none");
        return fmi3Error;
    }
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStates(fmi3Instance c, fmi3Float64 x[], size_t nx) {
    LOOKUP(c, "fmi3GetContinuousStates");
    return (fmi3Status)sm_get_states(inst, x, nx);
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance c, fmi3Float64 nominals[], size_t nx) {
    LOOKUP(c, "fmi3GetNominalsOfContinuousStates");
    return (fmi3Status)sm_get_nominals(inst, nominals, nx);
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance c, size_t* n) {
    CALL(c, "fmi3GetNumberOfEventIndicators", SM_ANY);
    if (n == NULL) return refuse(c, "fmi3GetNumberOfEventIndicators", "NULL argument");
    *n = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance c, size_t* n) {
    CALL(c, "fmi3GetNumberOfContinuousStates", SM_ANY);
    if (n == NULL) return refuse(c, "fmi3GetNumberOfContinuousStates", "NULL argument");
    *n = SM_NX;
    return fmi3OK;
}

/* --- Co-Simulation -------------------------------------------------------------------- */
fmi3Status fmi3EnterStepMode(fmi3Instance c) {
    CALL(c, "fmi3EnterStepMode", SM_EVENT);
    if (!inst->cosim) return refuse(c, "fmi3EnterStepMode", "not a Co-Simulation instance");
    inst->v.mode = SM_STEP;
    return fmi3OK;
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    (void)vr, (void)orders, (void)values, (void)nValues;
    return no_such(c, "fmi3GetOutputDerivatives (maxOutputDerivativeOrder is 0)", nvr);
}

fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean* eventHandlingNeeded, fmi3Boolean* terminateSimulation,
                      fmi3Boolean* earlyReturn, fmi3Float64* lastSuccessfulTime) {
    (void)noSetFMUStatePriorToCurrentPoint;
    LOOKUP(c, "fmi3DoStep");
    if (eventHandlingNeeded == NULL || terminateSimulation == NULL || earlyReturn == NULL ||
        lastSuccessfulTime == NULL) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "fmi3DoStep: NULL argument");
        return fmi3Error;
    }
    SmStatus status = sm_do_step(inst, currentCommunicationPoint, communicationStepSize);
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = inst->v.t;
    return (fmi3Status)status;
}
