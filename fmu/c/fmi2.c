/* The FMI 2.0 API (Model Exchange and Co-Simulation) on top of instance.c: each function
 * checks its handle and arguments, then calls the instance. No physics here. */
#include <string.h>

#include "fmi2Functions.h"
#include "instance.h"

#define LOOKUP(c, function)                                 \
    SmInstance* inst = sm_lookup((c), (function));          \
    if (inst == NULL) return fmi2Error

#define CALL(c, function, mask)                              \
    LOOKUP(c, function);                                     \
    if (!sm_allowed(inst, (mask), (function))) return fmi2Error

#define RUNNING (SM_INIT | SM_STEP | SM_EVENT | SM_CONT | SM_TERMINATED | SM_FAILED)

/* FMI 2.0 loggers take a printf format: every '%' of the message is doubled. */
static void log_fmi2(SmCallback callback, void* env, const char* instance, SmStatus status,
                 const char* category, const char* message) {
    char escaped[2 * SM_MSG];
    size_t k = 0;
    for (size_t i = 0; message[i] != '\0' && k + 2 < sizeof escaped; i++) {
        if (message[i] == '%') escaped[k++] = '%';
        escaped[k++] = message[i];
    }
    escaped[k] = '\0';
    ((fmi2CallbackLogger)callback)(env, instance, (fmi2Status)status, category, escaped);
}

const char* fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char* fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    LOOKUP(c, "fmi2SetDebugLogging");
    return (fmi2Status)sm_set_logging(inst, loggingOn, nCategories, categories);
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions* functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    (void)fmuResourceLocation; /* the FMU needs no resources */
    (void)visible;
    fmi2CallbackLogger logger = functions != NULL ? functions->logger : NULL;
    void* env = functions != NULL ? functions->componentEnvironment : NULL;
    const char* name = instanceName != NULL ? instanceName : "";
    const char* why = NULL;
    if (instanceName == NULL || instanceName[0] == '\0') {
        why = "fmi2Instantiate: the instance name is missing";
    } else if (fmuType != fmi2ModelExchange && fmuType != fmi2CoSimulation) {
        why = "fmi2Instantiate: unknown FMU type";
    } else if (fmuGUID == NULL || strcmp(fmuGUID, SM_GUID) != 0) {
        why = "fmi2Instantiate: the GUID is not this FMU's (" SM_GUID ")";
    }
    if (why != NULL) {
        if (logger != NULL) logger(env, name, fmi2Error, "logStatusError", why);
        return NULL;
    }
    return sm_new(name, fmuType == fmi2CoSimulation, log_fmi2, (SmCallback)logger, env, loggingOn);
}

void fmi2FreeInstance(fmi2Component c) {
    SmInstance* inst = sm_lookup(c, "fmi2FreeInstance");
    if (inst != NULL) sm_free(inst);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    char msg[SM_MSG] = "";
    CALL(c, "fmi2SetupExperiment", SM_INSTANTIATED);
    if (sm_set_tolerance(&inst->wk, toleranceDefined, tolerance, msg)) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "fmi2SetupExperiment: %s", msg);
        return fmi2Error;
    }
    return (fmi2Status)sm_setup(inst, startTime, stopTimeDefined, stopTime);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    CALL(c, "fmi2EnterInitializationMode", SM_INSTANTIATED);
    return (fmi2Status)sm_enter_init(inst);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    CALL(c, "fmi2ExitInitializationMode", SM_INIT);
    return (fmi2Status)sm_exit_init(inst, inst->cosim ? SM_STEP : SM_EVENT);
}

fmi2Status fmi2Terminate(fmi2Component c) {
    CALL(c, "fmi2Terminate", SM_STEP | SM_EVENT | SM_CONT);
    inst->v.mode = SM_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    LOOKUP(c, "fmi2Reset");
    sm_reset(inst);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    LOOKUP(c, "fmi2GetReal");
    return (fmi2Status)sm_get_reals(inst, vr, nvr, value);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    LOOKUP(c, "fmi2SetReal");
    return (fmi2Status)sm_set_reals(inst, vr, nvr, value);
}

/* The FMU has Real variables only: any other type is an unknown value reference. */
static fmi2Status no_such(fmi2Component c, const char* function, size_t nvr) {
    LOOKUP(c, function);
    if (nvr == 0) return fmi2OK;
    sm_log(inst, SM_ERROR, SM_LOG_ERROR, "%s: this FMU has no variables of that type", function);
    return fmi2Error;
}

#define NO_SUCH_TYPE(Name, Type)                                                         \
    fmi2Status fmi2Get##Name(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, \
                             Type value[]) {                                             \
        (void)vr, (void)value;                                                           \
        return no_such(c, "fmi2Get" #Name, nvr);                                         \
    }                                                                                    \
    fmi2Status fmi2Set##Name(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, \
                             const Type value[]) {                                       \
        (void)vr, (void)value;                                                           \
        return no_such(c, "fmi2Set" #Name, nvr);                                         \
    }

NO_SUCH_TYPE(Integer, fmi2Integer)
NO_SUCH_TYPE(Boolean, fmi2Boolean)
NO_SUCH_TYPE(String, fmi2String)

/* --- FMU state: handles checked against the registry of live states (instance.c) ------ */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate* FMUstate) {
    CALL(c, "fmi2GetFMUstate", SM_ANY);
    return (fmi2Status)sm_get_state(inst, (void**)FMUstate, "fmi2GetFMUstate");
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    CALL(c, "fmi2SetFMUstate", SM_ANY);
    return (fmi2Status)sm_set_state(inst, FMUstate, "fmi2SetFMUstate");
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate* FMUstate) {
    CALL(c, "fmi2FreeFMUstate", SM_ANY);
    return (fmi2Status)sm_free_state(inst, (void**)FMUstate, "fmi2FreeFMUstate");
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t* size) {
    CALL(c, "fmi2SerializedFMUstateSize", SM_ANY);
    return (fmi2Status)sm_serialized_size(inst, FMUstate, size, "fmi2SerializedFMUstateSize");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    CALL(c, "fmi2SerializeFMUstate", SM_ANY);
    return (fmi2Status)sm_serialize(inst, FMUstate, serializedState, size,
                                    "fmi2SerializeFMUstate");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate* FMUstate) {
    CALL(c, "fmi2DeSerializeFMUstate", SM_ANY);
    return (fmi2Status)sm_deserialize(inst, serializedState, size, (void**)FMUstate,
                                      "fmi2DeSerializeFMUstate");
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    LOOKUP(c, "fmi2GetDirectionalDerivative");
    return (fmi2Status)sm_get_directional(inst, vUnknown_ref, nUnknown, vKnown_ref, nKnown,
                                          dvKnown, dvUnknown);
}

/* --- Model Exchange ------------------------------------------------------------------- */
fmi2Status fmi2EnterEventMode(fmi2Component c) {
    CALL(c, "fmi2EnterEventMode", SM_EVENT | SM_CONT);
    inst->v.mode = SM_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo* eventInfo) {
    CALL(c, "fmi2NewDiscreteStates", SM_EVENT);
    if (eventInfo == NULL) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "fmi2NewDiscreteStates: eventInfo is NULL");
        return fmi2Error;
    }
    memset(eventInfo, 0, sizeof *eventInfo); /* no events, no discrete states */
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    CALL(c, "fmi2EnterContinuousTimeMode", SM_EVENT);
    inst->v.mode = SM_CONT;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean* enterEventMode,
                                       fmi2Boolean* terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    char msg[SM_MSG];
    CALL(c, "fmi2CompletedIntegratorStep", SM_CONT);
    if (enterEventMode == NULL || terminateSimulation == NULL) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "fmi2CompletedIntegratorStep: NULL argument");
        return fmi2Error;
    }
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    if (sm_check_domain(&inst->wk, inst->v.x, inst->v.u, inst->v.p, msg)) {
        return (fmi2Status)sm_fail(inst, "at t = %.9g s: %s", inst->v.t, msg);
    }
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    LOOKUP(c, "fmi2SetTime");
    return (fmi2Status)sm_set_time(inst, time);
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    LOOKUP(c, "fmi2SetContinuousStates");
    return (fmi2Status)sm_set_states(inst, x, nx);
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    LOOKUP(c, "fmi2GetDerivatives");
    return (fmi2Status)sm_get_derivatives(inst, derivatives, nx);
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators;
    CALL(c, "fmi2GetEventIndicators", RUNNING);
    if (ni != 0) {
        sm_log(inst, SM_ERROR, SM_LOG_ERROR, "fmi2GetEventIndicators: this FMU has none");
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    LOOKUP(c, "fmi2GetContinuousStates");
    return (fmi2Status)sm_get_states(inst, x, nx);
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    LOOKUP(c, "fmi2GetNominalsOfContinuousStates");
    return (fmi2Status)sm_get_nominals(inst, x_nominal, nx);
}

/* --- Co-Simulation -------------------------------------------------------------------- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr, (void)order, (void)value;
    return no_such(c, "fmi2SetRealInputDerivatives (canInterpolateInputs is false)", nvr);
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr, (void)order, (void)value;
    return no_such(c, "fmi2GetRealOutputDerivatives (maxOutputDerivativeOrder is 0)", nvr);
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    LOOKUP(c, "fmi2DoStep");
    return (fmi2Status)sm_do_step(inst, currentCommunicationPoint, communicationStepSize);
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    CALL(c, "fmi2CancelStep", SM_STEP);
    sm_log(inst, SM_ERROR, SM_LOG_ERROR, "fmi2CancelStep: doStep never runs asynchronously");
    return fmi2Error;
}

static fmi2Status status_query(fmi2Component c, const char* function) {
    CALL(c, function, SM_STEP | SM_TERMINATED | SM_FAILED);
    sm_log(inst, SM_DISCARD, SM_LOG_WARNING, "%s: doStep never returns fmi2Pending", function);
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status* value) {
    (void)s, (void)value;
    return status_query(c, "fmi2GetStatus");
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real* value) {
    LOOKUP(c, "fmi2GetRealStatus");
    if (s == fmi2LastSuccessfulTime && value != NULL) {
        *value = inst->v.t;
        return fmi2OK;
    }
    return status_query(c, "fmi2GetRealStatus");
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer* value) {
    (void)s, (void)value;
    return status_query(c, "fmi2GetIntegerStatus");
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean* value) {
    (void)s, (void)value;
    return status_query(c, "fmi2GetBooleanStatus");
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String* value) {
    (void)s, (void)value;
    return status_query(c, "fmi2GetStringStatus");
}
