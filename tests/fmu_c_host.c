/* A minimal FMI 2.0 co-simulation importer with no Python of its own: load, instantiate, step, read. */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    va_list args;
    va_start(args, message);
    printf("log %d: ", (int)status);
    vprintf(message, args);
    printf("\n");
    va_end(args);
}

#define LOAD(f) f##TYPE *f = (f##TYPE *)dlsym(lib, #f); if (!f) { printf("missing %s\n", #f); return 3; }

int main(int argc, char **argv) {
    /* argv: library, resources URI, guid, input vr, output vr, steps, input value (held) */
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { printf("dlopen: %s\n", dlerror()); return 2; }
    LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal) LOAD(fmi2GetReal) LOAD(fmi2DoStep)
    LOAD(fmi2Terminate) LOAD(fmi2FreeInstance)
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("host", fmi2CoSimulation, argv[3], argv[2], &cb, fmi2False, fmi2True);
    if (!c) { printf("instantiate failed\n"); return 4; }
    fmi2ValueReference in = (fmi2ValueReference)atoi(argv[4]), out = (fmi2ValueReference)atoi(argv[5]);
    int steps = atoi(argv[6]);
    fmi2Real torque = atof(argv[7]), value = 0.0, h = 1e-3;
    fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);
    fmi2SetReal(c, &in, 1, &torque);
    for (int k = 0; k < steps; k++) {
        fmi2Status s = fmi2DoStep(c, k * h, h, fmi2True);
        if (s != fmi2OK) { printf("doStep status %d\n", (int)s); return 5; }
    }
    fmi2GetReal(c, &out, 1, &value);
    printf("value %.17g\n", value);
    fmi2Terminate(c);
    fmi2FreeInstance(c);
    return 0;
}
