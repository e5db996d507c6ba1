/* Misuse of an FMI 2.0 Co-Simulation FMU, one case per run (argv[1]), compiled with the
 * FMU's own sources under AddressSanitizer and UBSan by tests/fmu/test_fmi_memory.py.
 * Prints each log message and "status <name> <fmi2Status>" per call; exits 0 unless a
 * sanitizer stops it. */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "instance.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    (void)env, (void)name;
    printf("log %d %s %s\n", (int)status, category, message);
}

static const fmi2CallbackFunctions callbacks = {logger, NULL, NULL, NULL, NULL};

static void report(const char* call, fmi2Status status) {
    printf("status %s %d\n", call, (int)status);
    fflush(stdout);
}

/* A Co-Simulation instance in step mode; stop time defined if stop > 0. */
static fmi2Component started(const char* name, double stop) {
    fmi2Component c = fmi2Instantiate(name, fmi2CoSimulation, SM_GUID, "", &callbacks,
                                      fmi2False, fmi2False);
    if (c == NULL) return NULL;
    fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, stop > 0, stop);
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);
    return c;
}

static int freed_state(void) {
    fmi2Component c = started("freed", 0.0);
    fmi2FMUstate s = NULL;
    report("get", fmi2GetFMUstate(c, &s));
    fmi2FMUstate copy = s;
    report("free", fmi2FreeFMUstate(c, &s));
    report("set_freed", fmi2SetFMUstate(c, copy));
    report("serialize_freed", fmi2SerializeFMUstate(c, copy, NULL, 0));
    report("free_again", fmi2FreeFMUstate(c, &copy));
    fmi2FreeInstance(c);
    return 0;
}

static int bogus_state(void) {
    fmi2Component c = started("bogus", 0.0);
    double zeros[64] = {0};
    report("set_bogus", fmi2SetFMUstate(c, (fmi2FMUstate)(size_t)0x1234));
    report("set_foreign", fmi2SetFMUstate(c, (fmi2FMUstate)zeros));
    fmi2FMUstate garbage = (fmi2FMUstate)(size_t)0x5678; /* not NULL, not issued: refused */
    report("get_into_bogus", fmi2GetFMUstate(c, &garbage));
    fmi2FreeInstance(c);
    return 0;
}

static int state_of_freed_instance(void) {
    fmi2Component a = started("a", 0.0), b = started("b", 0.0);
    fmi2FMUstate s = NULL;
    report("get", fmi2GetFMUstate(a, &s));
    fmi2FreeInstance(a); /* frees the states a made */
    report("set_in_b", fmi2SetFMUstate(b, s));
    fmi2FreeInstance(b);
    return 0;
}

static int huge_step(void) {
    fmi2Component c = started("huge", 0.0);
    report("step_1e20", fmi2DoStep(c, 0.0, 1e20, fmi2True));
    report("step_ok", fmi2DoStep(c, 0.0, 1e-3, fmi2True));
    fmi2FreeInstance(c);
    return 0;
}

static int past_stop(void) {
    fmi2Component c = started("stop", 0.01);
    report("step_to_0.005", fmi2DoStep(c, 0.0, 0.005, fmi2True));
    report("step_to_0.015", fmi2DoStep(c, 0.005, 0.01, fmi2True));
    report("step_to_0.01", fmi2DoStep(c, 0.005, 0.005, fmi2True));
    fmi2FreeInstance(c);
    return 0;
}

/* A serialised state whose mode (the third double from the end) is `mode`. */
static int bad_mode(double mode) {
    fmi2Component c = started("mode", 0.0);
    fmi2FMUstate s = NULL, back = NULL;
    size_t size = 0;
    fmi2GetFMUstate(c, &s);
    fmi2SerializedFMUstateSize(c, s, &size);
    char bytes[4096];
    if (size > sizeof bytes) return 2;
    report("serialize", fmi2SerializeFMUstate(c, s, bytes, size));
    memcpy(bytes + size - 3 * sizeof(double), &mode, sizeof mode);
    report("deserialize", fmi2DeSerializeFMUstate(c, bytes, size, &back));
    fmi2FreeInstance(c);
    return 0;
}

static int log_category(void) {
    fmi2Component c = started("log", 0.0);
    fmi2SetDebugLogging(c, fmi2True, 0, NULL);
    sm_log((SmInstance*)c, SM_WARNING, SM_LOG_WARNING | SM_LOG_SOLVER, "combined category");
    sm_log((SmInstance*)c, SM_WARNING, 1 << 12, "unknown category");
    report("logged", fmi2OK);
    fmi2FreeInstance(c);
    return 0;
}

static int many_instances(void) {
    enum { N = 1000 };
    static fmi2Component c[N];
    int made = 0;
    for (int i = 0; i < N; i++) {
        char name[32];
        snprintf(name, sizeof name, "i%d", i);
        c[i] = started(name, 0.0);
        made += c[i] != NULL;
    }
    printf("instances %d\n", made);
    report("last_step", fmi2DoStep(c[N - 1], 0.0, 1e-3, fmi2True));
    for (int i = 0; i < N; i++) fmi2FreeInstance(c[i]);
    return 0;
}

int main(int argc, char** argv) {
    const char* what = argc > 1 ? argv[1] : "";
    if (!strcmp(what, "freed_state")) return freed_state();
    if (!strcmp(what, "bogus_state")) return bogus_state();
    if (!strcmp(what, "state_of_freed_instance")) return state_of_freed_instance();
    if (!strcmp(what, "huge_step")) return huge_step();
    if (!strcmp(what, "past_stop")) return past_stop();
    if (!strcmp(what, "huge_mode")) return bad_mode(1e300);
    if (!strcmp(what, "fraction_mode")) return bad_mode(2.5);
    if (!strcmp(what, "log_category")) return log_category();
    if (!strcmp(what, "many_instances")) return many_instances();
    fprintf(stderr, "unknown case '%s'\n", what);
    return 2;
}
