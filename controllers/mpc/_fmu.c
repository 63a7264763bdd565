/*
 * A cosim MPC (controllers.mpc.MPC) as an FMI 2.0 Co-Simulation FMU, written by controllers.mpc.fmu.export_fmu.
 * The controller's whole step is the casadi Function the MPC compiles for itself (its generated C, step.c, and the
 * QP solver's static library): filter, target, condensed QP, the clipped first move and the prediction. What
 * MPC._fallback does in Python when the QP fails is written here, in the same order.
 *
 * Value references: 0 time; 1..P the measured outputs; P+1..P+NT the set-points of the tracked outputs (inputs,
 * discrete); P+NT+1..P+NT+M the commands (outputs, discrete, direct feedthrough: a get after the inputs are set
 * solves the step for them, the state unchanged; doStep commits it). mpc_config.h: names, sizes, matrices, the
 * state after MPC.reset(). The generated step keeps its solver memory static: one instance per process.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "mpc_config.h"

typedef long long casadi_int;
int MPC_STEP(const double **arg, double **res, casadi_int *iw, double *w, int mem);
int MPC_STEP_WORK(casadi_int *sz_arg, casadi_int *sz_res, casadi_int *sz_iw, casadi_int *sz_w);

#define VR_MEAS 1u
#define VR_U (1u + MPC_NMEAS)

typedef struct {
    double meas[MPC_NMEAS], state[MPC_NSTATE], next[MPC_NSTATE], out[MPC_NOUT];
    int fresh;          /* out and next hold the step for meas and state */
    int failures;       /* consecutive fallbacks */
    double time;
    casadi_int *iw;
    double *w;
    const double **arg;
    double **res;
    fmi2CallbackFunctions cb;
    char name[256];
} Instance;

static fmi2Status fail(Instance *s, const char *function, const char *text) {
    if (s && s->cb.logger) s->cb.logger(s->cb.componentEnvironment, s->name, fmi2Error, "logStatusError", "%s: %s",
                                        function, text);
    return fmi2Error;
}

/* y = A x (+ y), A row-major r x c; summed in the order numpy's small products sum (left to right). */
static void product(const double *A, const double *x, int r, int c, double *y, int add) {
    int i, j;
    for (i = 0; i < r; ++i) {
        double v = 0.0;
        for (j = 0; j < c; ++j) v += A[i * c + j] * x[j];
        y[i] = add ? y[i] + v : v;
    }
}

/* MPC._fallback: filter, the held input or the last plan's move within the bounds, the prediction, the plan
 * shifted. Returns 0, or 1 when the controller gives up (on_infeasible raise, or too many fallbacks). */
static int fallback(Instance *s) {
    const double *y = s->meas, *xa_prior = s->state, *u_prev = s->state + MPC_NA, *plan = s->state + MPC_NA + MPC_M;
    double xa[MPC_NA], innovation[MPC_P], u[MPC_M], rd[MPC_NT + MPC_NA - MPC_N];
    int i;
    for (i = 0; i < MPC_P; ++i) if (!isfinite(y[i])) return 1;
    if (MPC_ON_INFEASIBLE == 2 || ++s->failures > MPC_MAX_FALLBACKS) return 1;
    product(MPC_CO, xa_prior, MPC_P, MPC_NA, innovation, 0);
    for (i = 0; i < MPC_P; ++i) innovation[i] = y[i] - innovation[i] - MPC_FO[i];
    product(MPC_L, innovation, MPC_NA, MPC_P, xa, 0);
    for (i = 0; i < MPC_NA; ++i) xa[i] = xa_prior[i] + xa[i];
    for (i = 0; i < MPC_M; ++i) {
        double lo = fmax(MPC_UMIN[i], u_prev[i] - MPC_DUMAX[i]), hi = fmin(MPC_UMAX[i], u_prev[i] + MPC_DUMAX[i]);
        double v = MPC_ON_INFEASIBLE == 0 ? plan[i] : u_prev[i];
        u[i] = v < lo ? lo : (v > hi ? hi : v);
    }
    for (i = 0; i < MPC_NT; ++i) rd[i] = s->meas[MPC_P + i];
    for (i = 0; i < MPC_NA - MPC_N; ++i) rd[MPC_NT + i] = xa[MPC_N + i];
    product(MPC_AO, xa, MPC_NA, MPC_NA, s->next, 0);
    product(MPC_BO, u, MPC_NA, MPC_M, s->next, 1);
    for (i = 0; i < MPC_NA; ++i) s->next[i] += MPC_EO[i];
    for (i = 0; i < MPC_M; ++i) s->next[MPC_NA + i] = u[i];
    for (i = 0; i < (MPC_HORIZON - 1) * MPC_M; ++i) s->next[MPC_NA + MPC_M + i] = plan[MPC_M + i];
    for (i = 0; i < MPC_M; ++i) s->next[MPC_NA + MPC_M + (MPC_HORIZON - 1) * MPC_M + i] =
        plan[(MPC_HORIZON - 1) * MPC_M + i];
    for (i = 0; i < MPC_M; ++i) s->out[i] = u[i];
    for (i = 0; i < MPC_NA; ++i) s->out[MPC_M + 1 + i] = xa[i];
    product(MPC_T, rd, MPC_N + MPC_M, MPC_NT + MPC_NA - MPC_N, s->out + MPC_M + 1 + MPC_NA, 0);
    for (i = 0; i < MPC_N + MPC_M; ++i) s->out[MPC_M + 1 + MPC_NA + i] += MPC_T0[i];
    return 0;
}

/* The step for the present inputs and state into out and next (once: until an input or the state changes). */
static int solve(Instance *s) {
    int rc;
    if (s->fresh) return 0;
    s->arg[0] = s->meas;
    s->arg[1] = s->state;
    s->res[0] = s->out;
    s->res[1] = s->next;
    rc = MPC_STEP(s->arg, s->res, s->iw, s->w, 0);
    if (rc || !(s->out[MPC_M] <= MPC_VIOLATION_TOL)) {
        if (fallback(s)) return 1;
    } else {
        s->failures = 0;
    }
    s->fresh = 1;
    return 0;
}

static void start(Instance *s) {
    memset(s->meas, 0, sizeof s->meas);
    memcpy(s->state, MPC_STATE0, sizeof s->state);
    s->fresh = 0;
    s->failures = 0;
    s->time = 0.0;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String location,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging) {
    Instance *s;
    casadi_int sz_arg, sz_res, sz_iw, sz_w;
    (void)location; (void)visible; (void)logging;
    if (type != fmi2CoSimulation || !guid || strcmp(guid, MPC_GUID) != 0) return NULL;
    if (MPC_STEP_WORK(&sz_arg, &sz_res, &sz_iw, &sz_w)) return NULL;
    s = (Instance *)calloc(1, sizeof *s);
    if (!s) return NULL;
    s->iw = (casadi_int *)calloc((size_t)(sz_iw > 0 ? sz_iw : 1), sizeof(casadi_int));
    s->w = (double *)calloc((size_t)(sz_w > 0 ? sz_w : 1), sizeof(double));
    s->arg = (const double **)calloc((size_t)(sz_arg > 2 ? sz_arg : 2), sizeof(double *));
    s->res = (double **)calloc((size_t)(sz_res > 2 ? sz_res : 2), sizeof(double *));
    if (!s->iw || !s->w || !s->arg || !s->res) {
        free(s->iw); free(s->w); free(s->arg); free(s->res); free(s);
        return NULL;
    }
    if (cb) s->cb = *cb;
    snprintf(s->name, sizeof s->name, "%s", name ? name : MPC_IDENTIFIER);
    start(s);
    return s;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *s = (Instance *)c;
    if (!s) return;
    free(s->iw); free(s->w); free((void *)s->arg); free(s->res); free(s);
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    (void)c; (void)on; (void)n; (void)cats;
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tol_defined, fmi2Real tol, fmi2Real t0,
                               fmi2Boolean stop_defined, fmi2Real stop) {
    (void)tol_defined; (void)tol; (void)stop_defined; (void)stop;
    ((Instance *)c)->time = t0;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }

fmi2Status fmi2Reset(fmi2Component c) {
    start((Instance *)c);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Instance *s = (Instance *)c;
    size_t i;
    for (i = 0; i < n; ++i) {
        if (vr[i] == 0) {
            value[i] = s->time;
        } else if (vr[i] >= VR_MEAS && vr[i] < VR_U) {
            value[i] = s->meas[vr[i] - VR_MEAS];
        } else if (vr[i] >= VR_U && vr[i] < VR_U + MPC_M) {
            if (solve(s)) return fail(s, "fmi2GetReal", "the QP failed and the fallbacks are used up (or "
                                      "on_infeasible is raise)");
            value[i] = s->out[vr[i] - VR_U];
        } else {
            return fail(s, "fmi2GetReal", "unknown value reference");
        }
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Instance *s = (Instance *)c;
    size_t i;
    for (i = 0; i < n; ++i) {
        if (vr[i] < VR_MEAS || vr[i] >= VR_U) return fail(s, "fmi2SetReal", "not an input");
        if (s->meas[vr[i] - VR_MEAS] != value[i]) s->fresh = 0;
        s->meas[vr[i] - VR_MEAS] = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean no_prior) {
    Instance *s = (Instance *)c;
    (void)no_prior;
    if (fabs(h - MPC_DT) > 1e-9 * MPC_DT) return fail(s, "fmi2DoStep", "the MPC runs at its sample time dt only");
    if (solve(s)) return fail(s, "fmi2DoStep", "the QP failed and the fallbacks are used up (or on_infeasible is "
                              "raise), or a measurement is not finite");
    memcpy(s->state, s->next, sizeof s->state);
    s->fresh = 0;
    s->time = t + h;
    return fmi2OK;
}

/* What this FMU does not do: one line each, and fmi2Error. */
#define UNSUPPORTED(call, ...) \
    fmi2Status call(fmi2Component c, __VA_ARGS__) { return fail((Instance *)c, #call, "not supported"); }
UNSUPPORTED(fmi2GetInteger, const fmi2ValueReference vr[], size_t n, fmi2Integer v[])
UNSUPPORTED(fmi2SetInteger, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[])
UNSUPPORTED(fmi2GetBoolean, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[])
UNSUPPORTED(fmi2SetBoolean, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[])
UNSUPPORTED(fmi2GetString, const fmi2ValueReference vr[], size_t n, fmi2String v[])
UNSUPPORTED(fmi2SetString, const fmi2ValueReference vr[], size_t n, const fmi2String v[])
UNSUPPORTED(fmi2GetFMUstate, fmi2FMUstate *state)
UNSUPPORTED(fmi2SetFMUstate, fmi2FMUstate state)
UNSUPPORTED(fmi2FreeFMUstate, fmi2FMUstate *state)
UNSUPPORTED(fmi2SerializedFMUstateSize, fmi2FMUstate s, size_t *size)
UNSUPPORTED(fmi2SerializeFMUstate, fmi2FMUstate s, fmi2Byte b[], size_t size)
UNSUPPORTED(fmi2DeSerializeFMUstate, const fmi2Byte b[], size_t size, fmi2FMUstate *s)
UNSUPPORTED(fmi2GetDirectionalDerivative, const fmi2ValueReference a[], size_t na, const fmi2ValueReference b[],
            size_t nb, const fmi2Real dv[], fmi2Real df[])
UNSUPPORTED(fmi2SetRealInputDerivatives, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[],
            const fmi2Real v[])
UNSUPPORTED(fmi2GetRealOutputDerivatives, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[],
            fmi2Real v[])
UNSUPPORTED(fmi2GetStatus, const fmi2StatusKind k, fmi2Status *v)
UNSUPPORTED(fmi2GetRealStatus, const fmi2StatusKind k, fmi2Real *v)
UNSUPPORTED(fmi2GetIntegerStatus, const fmi2StatusKind k, fmi2Integer *v)
UNSUPPORTED(fmi2GetBooleanStatus, const fmi2StatusKind k, fmi2Boolean *v)
UNSUPPORTED(fmi2GetStringStatus, const fmi2StatusKind k, fmi2String *v)

fmi2Status fmi2CancelStep(fmi2Component c) { return fail((Instance *)c, "fmi2CancelStep", "not supported"); }
