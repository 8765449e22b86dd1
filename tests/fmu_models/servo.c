/* A test FMU in C: the gearbox servo of gearbox_servo.py (angle'' = w^2 (command - angle) - 2 zeta w angle',
 * 8 Hz, zeta 0.7) with both FMI interfaces, co-simulation (RK4, 16 sub-steps per communication step) and
 * model exchange (states angle and speed; one event indicator, angle - 0.5, so that the integrator's root
 * finding and the event iteration run), for FMI 2.0 (compiled as is) or FMI 3.0 (-DFMI3). tests/conftest.py compiles it with gcc and
 * zips it with a model description that declares one interface or both.
 *
 * Only the functions fmpy calls on such an FMU do anything; the others are there because fmpy loads every
 * function of the standard, and return an error if called. Value references: 0 command (input), 1 angle
 * (output, state), 2 speed (state), 3 acceleration (derivative of speed), 4 the event indicator. */

#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdlib.h>

#define OK 0
#define ERROR 3

typedef struct {
    double time, command, angle, speed;
    int crossings;
    bool above;
} Servo;

static const double W = 2.0 * 3.14159265358979323846 * 8.0, ZETA = 0.7;

static double acceleration(const Servo *s, double angle, double speed) {
    return W * W * (s->command - angle) - 2.0 * ZETA * W * speed;
}

static void rk4(Servo *s, double h) {
    double x = s->angle, v = s->speed;
    double k1x = v, k1v = acceleration(s, x, v);
    double k2x = v + 0.5 * h * k1v, k2v = acceleration(s, x + 0.5 * h * k1x, v + 0.5 * h * k1v);
    double k3x = v + 0.5 * h * k2v, k3v = acceleration(s, x + 0.5 * h * k2x, v + 0.5 * h * k2v);
    double k4x = v + h * k3v, k4v = acceleration(s, x + h * k3x, v + h * k3v);
    s->angle = x + h / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x);
    s->speed = v + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v);
}

static void *make(void) { return calloc(1, sizeof(Servo)); }

static int get(Servo *s, const unsigned *vr, size_t n, double *value) {
    for (size_t i = 0; i < n; i++) {
        switch (vr[i]) {
            case 0: value[i] = s->command; break;
            case 1: value[i] = s->angle; break;
            case 2: value[i] = s->speed; break;
            case 3: value[i] = acceleration(s, s->angle, s->speed); break;
            case 4: value[i] = s->angle - 0.5; break;
            default: return ERROR;
        }
    }
    return OK;
}

static int set(Servo *s, const unsigned *vr, size_t n, const double *value) {
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != 0) return ERROR;
        s->command = value[i];
    }
    return OK;
}

static void step(Servo *s, double h) {
    for (int k = 0; k < 16; k++) rk4(s, h / 16.0);
    s->time += h;
}

static void event(Servo *s) {
    bool above = s->angle > 0.5;
    if (above != s->above) s->crossings++;
    s->above = above;
}

#define STUB(name) int name(void) { return ERROR; }

/* -DBROKEN_RESET: a reset that says OK and keeps the state (an exporter's bug the block must survive) */
#ifdef BROKEN_RESET
#define RESET(c) ((void)(c))
#else
#define RESET(c) (*(Servo *)(c) = (Servo){0})
#endif

#ifndef FMI3

typedef struct {
    int newDiscreteStatesNeeded, terminateSimulation, nominalsOfContinuousStatesChanged,
        valuesOfContinuousStatesChanged, nextEventTimeDefined;
    double nextEventTime;
} EventInfo;

const char *fmi2GetTypesPlatform(void) { return "default"; }
const char *fmi2GetVersion(void) { return "2.0"; }
int fmi2SetDebugLogging(void *c, int on, size_t n, const char *const *categories) { return OK; }
void *fmi2Instantiate(const char *name, int type, const char *guid, const char *resources, const void *functions,
                      int visible, int logging) { return make(); }
void fmi2FreeInstance(void *c) { free(c); }
int fmi2SetupExperiment(void *c, int tolerance_defined, double tolerance, double start, int stop_defined,
                        double stop) { ((Servo *)c)->time = start; return OK; }
int fmi2EnterInitializationMode(void *c) { return OK; }
int fmi2ExitInitializationMode(void *c) { event(c); return OK; }
int fmi2Terminate(void *c) { return OK; }
int fmi2Reset(void *c) { RESET(c); return OK; }
int fmi2GetReal(void *c, const unsigned *vr, size_t n, double *value) { return get(c, vr, n, value); }
int fmi2SetReal(void *c, const unsigned *vr, size_t n, const double *value) { return set(c, vr, n, value); }
int fmi2DoStep(void *c, double t, double h, int no_set_prior) { step(c, h); return OK; }
int fmi2EnterEventMode(void *c) { return OK; }
int fmi2NewDiscreteStates(void *c, EventInfo *info) {
    event(c);
    *info = (EventInfo){0};
    return OK;
}
int fmi2EnterContinuousTimeMode(void *c) { return OK; }
int fmi2CompletedIntegratorStep(void *c, int no_set_prior, int *enter_event_mode, int *terminate) {
    *enter_event_mode = 0;
    *terminate = 0;
    return OK;
}
int fmi2SetTime(void *c, double t) { ((Servo *)c)->time = t; return OK; }
int fmi2SetContinuousStates(void *c, const double *x, size_t n) {
    Servo *s = c;
    s->angle = x[0];
    s->speed = x[1];
    return OK;
}
int fmi2GetContinuousStates(void *c, double *x, size_t n) {
    Servo *s = c;
    x[0] = s->angle;
    x[1] = s->speed;
    return OK;
}
int fmi2GetDerivatives(void *c, double *dx, size_t n) {
    Servo *s = c;
    dx[0] = s->speed;
    dx[1] = acceleration(s, s->angle, s->speed);
    return OK;
}
int fmi2GetEventIndicators(void *c, double *z, size_t n) { z[0] = ((Servo *)c)->angle - 0.5; return OK; }
int fmi2GetNominalsOfContinuousStates(void *c, double *x, size_t n) { x[0] = x[1] = 1.0; return OK; }
STUB(fmi2GetInteger) STUB(fmi2GetBoolean) STUB(fmi2GetString) STUB(fmi2SetInteger) STUB(fmi2SetBoolean)
STUB(fmi2SetString) STUB(fmi2GetFMUstate) STUB(fmi2SetFMUstate) STUB(fmi2FreeFMUstate)
STUB(fmi2SerializedFMUstateSize) STUB(fmi2SerializeFMUstate) STUB(fmi2DeSerializeFMUstate)
STUB(fmi2GetDirectionalDerivative) STUB(fmi2SetRealInputDerivatives) STUB(fmi2GetRealOutputDerivatives)
STUB(fmi2CancelStep) STUB(fmi2GetStatus) STUB(fmi2GetRealStatus) STUB(fmi2GetIntegerStatus)
STUB(fmi2GetBooleanStatus) STUB(fmi2GetStringStatus)

#else

const char *fmi3GetVersion(void) { return "3.0"; }
int fmi3SetDebugLogging(void *c, bool on, size_t n, const char *const *categories) { return OK; }
void *fmi3InstantiateModelExchange(const char *name, const char *token, const char *resources, bool visible,
                                   bool logging, void *environment, void *log) { return make(); }
void *fmi3InstantiateCoSimulation(const char *name, const char *token, const char *resources, bool visible,
                                  bool logging, bool event_mode_used, bool early_return_allowed,
                                  const unsigned *required, size_t n_required, void *environment, void *log,
                                  void *intermediate_update) { return make(); }
void fmi3FreeInstance(void *c) { free(c); }
int fmi3EnterInitializationMode(void *c, bool tolerance_defined, double tolerance, double start, bool stop_defined,
                                double stop) { ((Servo *)c)->time = start; return OK; }
int fmi3ExitInitializationMode(void *c) { event(c); return OK; }
int fmi3Terminate(void *c) { return OK; }
int fmi3Reset(void *c) { RESET(c); return OK; }
int fmi3GetFloat64(void *c, const unsigned *vr, size_t n, double *value, size_t n_values) {
    return get(c, vr, n, value);
}
int fmi3SetFloat64(void *c, const unsigned *vr, size_t n, const double *value, size_t n_values) {
    return set(c, vr, n, value);
}
int fmi3DoStep(void *c, double t, double h, bool no_set_prior, bool *event_needed, bool *terminate,
               bool *early_return, double *last_time) {
    step(c, h);
    *event_needed = *terminate = *early_return = false;
    *last_time = t + h;
    return OK;
}
int fmi3EnterEventMode(void *c) { return OK; }
int fmi3UpdateDiscreteStates(void *c, bool *update_needed, bool *terminate, bool *nominals_changed,
                             bool *values_changed, bool *next_defined, double *next_time) {
    event(c);
    *update_needed = *terminate = *nominals_changed = *values_changed = *next_defined = false;
    *next_time = 0.0;
    return OK;
}
int fmi3EnterContinuousTimeMode(void *c) { return OK; }
int fmi3CompletedIntegratorStep(void *c, bool no_set_prior, bool *enter_event_mode, bool *terminate) {
    *enter_event_mode = *terminate = false;
    return OK;
}
int fmi3SetTime(void *c, double t) { ((Servo *)c)->time = t; return OK; }
int fmi3SetContinuousStates(void *c, const double *x, size_t n) {
    Servo *s = c;
    s->angle = x[0];
    s->speed = x[1];
    return OK;
}
int fmi3GetContinuousStates(void *c, double *x, size_t n) {
    Servo *s = c;
    x[0] = s->angle;
    x[1] = s->speed;
    return OK;
}
int fmi3GetContinuousStateDerivatives(void *c, double *dx, size_t n) {
    Servo *s = c;
    dx[0] = s->speed;
    dx[1] = acceleration(s, s->angle, s->speed);
    return OK;
}
int fmi3GetEventIndicators(void *c, double *z, size_t n) { z[0] = ((Servo *)c)->angle - 0.5; return OK; }
int fmi3GetNominalsOfContinuousStates(void *c, double *x, size_t n) { x[0] = x[1] = 1.0; return OK; }
int fmi3GetNumberOfContinuousStates(void *c, size_t *n) { *n = 2; return OK; }
int fmi3GetNumberOfEventIndicators(void *c, size_t *n) { *n = 1; return OK; }
STUB(fmi3ActivateModelPartition) STUB(fmi3DeserializeFMUState) STUB(fmi3EnterConfigurationMode)
STUB(fmi3EnterStepMode) STUB(fmi3EvaluateDiscreteStates) STUB(fmi3ExitConfigurationMode) STUB(fmi3FreeFMUState)
STUB(fmi3GetAdjointDerivative) STUB(fmi3GetBinary) STUB(fmi3GetBoolean) STUB(fmi3GetClock)
STUB(fmi3GetDirectionalDerivative) STUB(fmi3GetFMUState) STUB(fmi3GetFloat32) STUB(fmi3GetInt16)
STUB(fmi3GetInt32) STUB(fmi3GetInt64) STUB(fmi3GetInt8) STUB(fmi3GetIntervalDecimal) STUB(fmi3GetIntervalFraction)
STUB(fmi3GetNumberOfVariableDependencies) STUB(fmi3GetOutputDerivatives) STUB(fmi3GetShiftDecimal)
STUB(fmi3GetShiftFraction) STUB(fmi3GetString) STUB(fmi3GetUInt16) STUB(fmi3GetUInt32) STUB(fmi3GetUInt64)
STUB(fmi3GetUInt8) STUB(fmi3GetVariableDependencies) STUB(fmi3InstantiateScheduledExecution)
STUB(fmi3SerializeFMUState) STUB(fmi3SerializedFMUStateSize) STUB(fmi3SetBinary) STUB(fmi3SetBoolean)
STUB(fmi3SetClock) STUB(fmi3SetFMUState) STUB(fmi3SetFloat32) STUB(fmi3SetInt16) STUB(fmi3SetInt32)
STUB(fmi3SetInt64) STUB(fmi3SetInt8) STUB(fmi3SetIntervalDecimal) STUB(fmi3SetIntervalFraction)
STUB(fmi3SetShiftDecimal) STUB(fmi3SetShiftFraction) STUB(fmi3SetString) STUB(fmi3SetUInt16) STUB(fmi3SetUInt32)
STUB(fmi3SetUInt64) STUB(fmi3SetUInt8)

#endif
