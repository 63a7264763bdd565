/*
 * A cosim PID (controllers.pid.PID) as an FMI 2.0 Co-Simulation FMU, written by controllers.pid.fmu.export_fmu.
 * The controller's sample law in C, operation for operation as PID.__call__ computes it (the same bits).
 *
 * Value references: 0 time; 1 setpoint (input); 2 the measured controlled output (input); 3 the measured velocity
 * (input, with PID_VELOCITY); 4 the command (output, with direct feedthrough: a get after the inputs are set gives
 * the command for them, the state unchanged; doStep then commits that sample); 5..14 the Real parameters kp, ki,
 * kd, tf, b, tt, u0, u_min, u_max, du_max; 15 anti_windup (Integer: 0 none, 1 back-calculation, 2 clamping);
 * 16 dt (a constant: doStep takes steps of dt only). Inputs and the command are discrete: they hold between
 * samples. FMU state get/set copy the instance. pid_config.h holds the names, the GUID and the start values.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "pid_config.h"

#define N_REAL_PARAMETERS 10

typedef struct {
    double integral, d, y_prev, v_prev, u_prev;
    int has_y_prev, has_u_prev;
} Memory;

typedef struct {
    double inputs[3];                   /* setpoint, y, v */
    double par[N_REAL_PARAMETERS];      /* kp, ki, kd, tf, b, tt, u0, u_min, u_max, du_max */
    int anti_windup;
    double ad, bd, bi, ao, kb;          /* the discrete law's coefficients (PID._apply_gains) */
    Memory mem;
    double time;
    int initialized;
    fmi2CallbackFunctions cb;
    char name[256];
} Instance;

enum { KP, KI, KD, TF, B, TT, U0, UMIN, UMAX, DUMAX };

static fmi2Status fail(Instance *s, const char *function, const char *text) {
    if (s && s->cb.logger) s->cb.logger(s->cb.componentEnvironment, s->name, fmi2Error, "logStatusError", "%s: %s",
                                        function, text);
    return fmi2Error;
}

static void coefficients(Instance *s) {
    double kp = s->par[KP], ki = s->par[KI], kd = s->par[KD], tf = s->par[TF], dt = PID_DT;
    s->ad = tf / (tf + dt);
    s->bd = PID_VELOCITY ? kd * dt / (tf + dt) : kd / (tf + dt);
    s->bi = ki * dt;
    s->ao = (s->anti_windup == 1 && ki > 0) ? dt / s->par[TT] : 0.0;
    s->kb = kp * s->par[B];
}

/* PID.__call__ up to the command: d the derivative term, v the unlimited command; returns the command. */
static double command(const Instance *s, double *d_out, double *v_out) {
    double r = s->inputs[0], yv = s->inputs[1], vv = PID_VELOCITY ? s->inputs[2] : s->inputs[1], d, p, v, u;
    if (!PID_VELOCITY) {
        double y_prev = s->mem.has_y_prev ? s->mem.y_prev : yv;
        d = s->ad * s->mem.d - s->bd * (yv - y_prev);
    } else {
        d = s->ad * s->mem.d - s->bd * vv;
    }
    p = s->kb * r - s->par[KP] * yv;
    v = s->par[U0] + p + s->mem.integral + d;
    u = v;
    if (s->mem.has_u_prev) {
        if (u > s->mem.u_prev + s->par[DUMAX]) u = s->mem.u_prev + s->par[DUMAX];
        else if (u < s->mem.u_prev - s->par[DUMAX]) u = s->mem.u_prev - s->par[DUMAX];
    }
    if (u > s->par[UMAX]) u = s->par[UMAX];
    else if (u < s->par[UMIN]) u = s->par[UMIN];
    *d_out = d;
    *v_out = v;
    return u;
}

/* The rest of PID.__call__: the sample taken, the memory updated. */
static void commit(Instance *s) {
    double d, v, u = command(s, &d, &v), r = s->inputs[0], yv = s->inputs[1];
    double vv = PID_VELOCITY ? s->inputs[2] : yv, e = r - yv;
    if (s->ao) s->mem.integral += s->bi * e + s->ao * (u - v);
    else if (s->anti_windup != 2 || u == v || (u < v) == (e < 0)) s->mem.integral += s->bi * e;
    s->mem.d = d;
    s->mem.y_prev = yv;
    s->mem.v_prev = vv;
    s->mem.u_prev = u;
    s->mem.has_y_prev = s->mem.has_u_prev = 1;
}

static void start_values(Instance *s) {
    static const double par[N_REAL_PARAMETERS] = PID_PARAMETER_STARTS;
    memcpy(s->par, par, sizeof par);
    memset(s->inputs, 0, sizeof s->inputs);
    memset(&s->mem, 0, sizeof s->mem);
    s->anti_windup = PID_ANTI_WINDUP;
    s->time = 0.0;
    s->initialized = 0;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String location,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging) {
    Instance *s;
    (void)location; (void)visible; (void)logging;
    if (type != fmi2CoSimulation || !guid || strcmp(guid, PID_GUID) != 0) return NULL;
    s = (Instance *)calloc(1, sizeof *s);
    if (!s) return NULL;
    if (cb) s->cb = *cb;
    snprintf(s->name, sizeof s->name, "%s", name ? name : PID_IDENTIFIER);
    start_values(s);
    return s;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    (void)c; (void)on; (void)n; (void)cats;
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tol_defined, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stop_defined, fmi2Real stop) {
    (void)tol_defined; (void)tol; (void)stop_defined; (void)stop;
    ((Instance *)c)->time = start;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *s = (Instance *)c;
    if (s->par[TT] < PID_DT && s->anti_windup == 1 && s->par[KI] > 0)
        return fail(s, "fmi2ExitInitializationMode", "tt is shorter than the sample time dt");
    coefficients(s);
    s->initialized = 1;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2Reset(fmi2Component c) {
    Instance *s = (Instance *)c;
    start_values(s);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Instance *s = (Instance *)c;
    size_t i;
    for (i = 0; i < n; ++i) {
        double d, v;
        if (vr[i] == 0) value[i] = s->time;
        else if (vr[i] >= 1 && vr[i] <= 3) value[i] = s->inputs[vr[i] - 1];
        else if (vr[i] == 4) value[i] = s->initialized ? command(s, &d, &v) : 0.0;
        else if (vr[i] >= 5 && vr[i] < 5 + N_REAL_PARAMETERS) value[i] = s->par[vr[i] - 5];
        else if (vr[i] == 16) value[i] = PID_DT;
        else return fail(s, "fmi2GetReal", "unknown value reference");
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Instance *s = (Instance *)c;
    size_t i;
    for (i = 0; i < n; ++i) {
        if (vr[i] >= 1 && vr[i] <= 3) {
            s->inputs[vr[i] - 1] = value[i];
        } else if (vr[i] >= 5 && vr[i] < 5 + N_REAL_PARAMETERS) {
            if (s->initialized) return fail(s, "fmi2SetReal", "a parameter is fixed after initialization");
            s->par[vr[i] - 5] = value[i];
        } else {
            return fail(s, "fmi2SetReal", "not an input or parameter");
        }
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer value[]) {
    size_t i;
    for (i = 0; i < n; ++i) {
        if (vr[i] != 15) return fail((Instance *)c, "fmi2GetInteger", "unknown value reference");
        value[i] = ((Instance *)c)->anti_windup;
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[]) {
    Instance *s = (Instance *)c;
    size_t i;
    for (i = 0; i < n; ++i) {
        if (vr[i] != 15 || value[i] < 0 || value[i] > 2 || s->initialized)
            return fail(s, "fmi2SetInteger", "anti_windup takes 0, 1 or 2 before initialization");
        s->anti_windup = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean no_prior) {
    Instance *s = (Instance *)c;
    (void)no_prior;
    if (fabs(h - PID_DT) > 1e-9 * PID_DT)
        return fail(s, "fmi2DoStep", "the controller runs at its sample time dt only");
    if (!isfinite(s->inputs[1]) || !isfinite(s->inputs[2]) || !isfinite(s->inputs[0]))
        return fail(s, "fmi2DoStep", "a measurement or the setpoint is not finite");
    commit(s);
    s->time = t + h;
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    Instance *copy = (Instance *)malloc(sizeof(Instance));
    if (!copy) return fmi2Error;
    memcpy(copy, c, sizeof(Instance));
    *state = copy;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    memcpy(c, state, sizeof(Instance));
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)c;
    free(*state);
    *state = NULL;
    return fmi2OK;
}

/* What this FMU does not do: one line each, and fmi2Error. */
#define UNSUPPORTED(call, ...) \
    fmi2Status call(fmi2Component c, __VA_ARGS__) { return fail((Instance *)c, #call, "not supported"); }
UNSUPPORTED(fmi2GetBoolean, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[])
UNSUPPORTED(fmi2SetBoolean, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[])
UNSUPPORTED(fmi2GetString, const fmi2ValueReference vr[], size_t n, fmi2String v[])
UNSUPPORTED(fmi2SetString, const fmi2ValueReference vr[], size_t n, const fmi2String v[])
UNSUPPORTED(fmi2SerializedFMUstateSize, fmi2FMUstate s, size_t *size)
UNSUPPORTED(fmi2SerializeFMUstate, fmi2FMUstate s, fmi2Byte b[], size_t size)
UNSUPPORTED(fmi2DeSerializeFMUstate, const fmi2Byte b[], size_t size, fmi2FMUstate *s)
UNSUPPORTED(fmi2GetDirectionalDerivative, const fmi2ValueReference a[], size_t na, const fmi2ValueReference b[],
            size_t nb, const fmi2Real dv[], fmi2Real df[])
UNSUPPORTED(fmi2SetRealInputDerivatives, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[],
            const fmi2Real v[])
UNSUPPORTED(fmi2GetRealOutputDerivatives, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[],
            fmi2Real v[])

fmi2Status fmi2CancelStep(fmi2Component c) { return fail((Instance *)c, "fmi2CancelStep", "not supported"); }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v) {
    (void)k; (void)v;
    return fail((Instance *)c, "fmi2GetStatus", "not supported");
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v) {
    (void)k; (void)v;
    return fail((Instance *)c, "fmi2GetRealStatus", "not supported");
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v) {
    (void)k; (void)v;
    return fail((Instance *)c, "fmi2GetIntegerStatus", "not supported");
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v) {
    (void)k; (void)v;
    return fail((Instance *)c, "fmi2GetBooleanStatus", "not supported");
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v) {
    (void)k; (void)v;
    return fail((Instance *)c, "fmi2GetStringStatus", "not supported");
}
