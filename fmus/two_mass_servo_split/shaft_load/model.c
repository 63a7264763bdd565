/*
 * shaft_load: equations, RK4 integrator, parameter validation, state copy.  See model.h for the interface and
 * ../README.md for the physics.  The terms and their order of evaluation are those of
 * fmus/two_mass_servo/model.c (its coupling and load rows, with theta_m and omega_m inputs):
 *
 *   Tc   = KL*dz(theta_m - theta_L) + BL*(omega_m - omega_L)
 *   JL*domega_L = TL + Tc - mgl*sin(theta_L)
 */
#include "model.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const variable_names[VR_COUNT] = {
    "time", "theta_m", "omega_m", "TL", "Tc", "theta_L", "omega_L", "der_theta_L", "der_omega_L", "JL",
    "KL",   "BL",      "backlash", "mgl", "nsub"};

const char *model_variable_name(unsigned vr) {
    return vr < VR_COUNT ? variable_names[vr] : NULL;
}

static void update_derived(Model *m);

static ModelStatus fail(Model *m, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(m->msg, sizeof m->msg, fmt, ap);
    va_end(ap);
    return MODEL_ERROR;
}

/* ------------------------------------------------------------------------ */
/* defaults                                                                   */
/* ------------------------------------------------------------------------ */

void model_reset(Model *m) {
    int i;
    /* the shaft and load side of the one-FMU servo's linear plant, see fmus/two_mass_servo/README.md */
    m->JL = 1000.0; /* kg m^2 */
    m->KL = 2.5e6;  /* N m/rad */
    m->BL = 500.0;  /* N m s/rad */
    /* effects: all off */
    m->backlash = 0.0;
    m->mgl = 0.0;
    m->nsub = 10;
    for (i = 0; i < N_INPUTS; ++i) m->u[i] = m->du[i] = 0.0;
    m->x[0] = m->x[1] = 0.0;
    m->time = 0.0;
    m->phase = PHASE_INSTANTIATED;
    m->msg[0] = '\0';
    update_derived(m);
}

void model_free(Model *m) {
    (void)m; /* nothing allocated */
}

ModelStatus model_copy(Model *dst, const Model *src) {
    if (dst != src) *dst = *src;
    return MODEL_OK;
}

/* ------------------------------------------------------------------------ */
/* equations                                                                  */
/* ------------------------------------------------------------------------ */

/* Constants derived from the parameters, so that the right-hand side multiplies instead of dividing and skips
 * the effects that are off. */
static void update_derived(Model *m) {
    m->inv_JL = 1.0 / m->JL;
    m->has_backlash = m->backlash != 0.0;
    m->has_gravity = m->mgl != 0.0;
}

#if defined(__GNUC__)
#define ALWAYS_INLINE __attribute__((always_inline)) inline
#else
#define ALWAYS_INLINE inline
#endif

/* The shaft torque on the load (and, reversed, on the motor) for motor angle and speed thm, wm. */
static ALWAYS_INLINE double coupling(const Model *m, double thm, double wm, const double x[2]) {
    const double d = thm - x[0];
    double dz = d;
    if (m->has_backlash) {
        const double b = m->backlash;
        dz = d > b ? d - b : (d < -b ? d + b : 0.0);
    }
    return m->KL * dz + m->BL * (wm - x[1]);
}

/* State derivative for the inputs v = [theta_m, omega_m, TL] at the time of the stage. */
static ALWAYS_INLINE void rhs(const Model *m, const double v[N_INPUTS], const double x[2], double dx[2]) {
    const double Tc = coupling(m, v[IN_THETA_M], v[IN_OMEGA_M], x);
    double Tl_net = v[IN_TL] + Tc;
    if (m->has_gravity) Tl_net -= m->mgl * sin(x[0]);
    dx[0] = x[1];
    dx[1] = Tl_net * m->inv_JL;
}

/* The inputs at time s of a step that began at t0: u + du*(s - t0) (with du = 0: exactly u, zero-order hold). */
static ALWAYS_INLINE void inputs_at(const Model *m, double t0, double s, double v[N_INPUTS]) {
    int i;
    for (i = 0; i < N_INPUTS; ++i) v[i] = m->u[i] + m->du[i] * (s - t0);
}

/* n RK4 steps of size dt from t0.  The weighted sum x + dt/6*(k1 + 2 k2 + 2 k3 + k4) is accumulated stage by
 * stage, as in the one-FMU servo.  Stage times are t0 + i*dt (+ dt/2), never accumulated. */
static void rk4(Model *m, double t0, double dt, long n) {
    double x[2], k[2], y[2], acc[2], v[N_INPUTS], vmid[N_INPUTS];
    const double half = 0.5 * dt, sixth = dt / 6.0, third = dt / 3.0;
    long i;
    int j;
    for (j = 0; j < 2; ++j) x[j] = m->x[j];
    for (i = 0; i < n; ++i) {
        const double s0 = t0 + (double)i * dt;
        inputs_at(m, t0, s0 + half, vmid);
        inputs_at(m, t0, s0, v);
        rhs(m, v, x, k);
        for (j = 0; j < 2; ++j) {
            acc[j] = x[j] + sixth * k[j];
            y[j] = x[j] + half * k[j];
        }
        rhs(m, vmid, y, k);
        for (j = 0; j < 2; ++j) {
            acc[j] += third * k[j];
            y[j] = x[j] + half * k[j];
        }
        rhs(m, vmid, y, k);
        for (j = 0; j < 2; ++j) {
            acc[j] += third * k[j];
            y[j] = x[j] + dt * k[j];
        }
        inputs_at(m, t0, t0 + (double)(i + 1) * dt, v);
        rhs(m, v, y, k);
        for (j = 0; j < 2; ++j) x[j] = acc[j] + sixth * k[j];
    }
    for (j = 0; j < 2; ++j) m->x[j] = x[j];
}

/* ------------------------------------------------------------------------ */
/* get / set                                                                  */
/* ------------------------------------------------------------------------ */

static double *real_ptr(Model *m, unsigned vr) {
    switch (vr) {
    case VR_THETA_M: return &m->u[IN_THETA_M];
    case VR_OMEGA_M: return &m->u[IN_OMEGA_M];
    case VR_TL: return &m->u[IN_TL];
    case VR_THETA_L: return &m->x[0];
    case VR_OMEGA_L: return &m->x[1];
    case VR_JL: return &m->JL;
    case VR_KL: return &m->KL;
    case VR_BL: return &m->BL;
    case VR_BACKLASH: return &m->backlash;
    case VR_MGL: return &m->mgl;
    default: return NULL;
    }
}

ModelStatus model_get_real(Model *m, unsigned vr, double *value) {
    double *p;
    if (vr == VR_TIME) {
        *value = m->time;
        return MODEL_OK;
    }
    if (vr == VR_TC || vr == VR_DER_THETA_L || vr == VR_DER_OMEGA_L) {
        /* from the inputs as last set and the state now: a new input shows at once (direct feedthrough) */
        double dx[2];
        if (m->phase == PHASE_INSTANTIATED || m->phase == PHASE_INITIALIZATION) update_derived(m);
        if (vr == VR_TC) {
            *value = coupling(m, m->u[IN_THETA_M], m->u[IN_OMEGA_M], m->x);
            return MODEL_OK;
        }
        rhs(m, m->u, m->x, dx);
        *value = dx[vr - VR_DER_THETA_L];
        return MODEL_OK;
    }
    p = real_ptr(m, vr);
    if (!p) return fail(m, "get real: unknown value reference %u (not a Real variable)", vr);
    *value = *p;
    return MODEL_OK;
}

static int is_input(unsigned vr) {
    return vr == VR_THETA_M || vr == VR_OMEGA_M || vr == VR_TL;
}

ModelStatus model_set_real(Model *m, unsigned vr, double value) {
    double *p = real_ptr(m, vr);
    const char *name = model_variable_name(vr);
    if (!p) {
        if (name) return fail(m, "set real: variable %s (value reference %u) cannot be set", name, vr);
        return fail(m, "set real: unknown value reference %u (not a Real variable)", vr);
    }
    if (!isfinite(value)) return fail(m, "set real: %s must be finite, got %g", name, value);
    if (m->phase == PHASE_TERMINATED || m->phase == PHASE_ERROR)
        return fail(m, "set real: cannot set %s after terminate or error (call reset first)", name);
    if (!is_input(vr) && m->phase == PHASE_STEPPING)
        return fail(m, "set real: %s can only be set before the end of initialization "
                       "(only the inputs theta_m, omega_m and TL can change during the simulation)", name);
    *p = value;
    return MODEL_OK;
}

ModelStatus model_set_input_derivative(Model *m, unsigned vr, int order, double value) {
    if (!is_input(vr))
        return fail(m, "set input derivative: value reference %u is not a Real input (theta_m, omega_m, TL)", vr);
    if (order < 1) return fail(m, "set input derivative: order %d of %s must be >= 1", order, model_variable_name(vr));
    if (!isfinite(value))
        return fail(m, "set input derivative: the derivative of %s must be finite, got %g", model_variable_name(vr), value);
    if (m->phase != PHASE_INITIALIZATION && m->phase != PHASE_STEPPING)
        return fail(m, "set input derivative: only allowed in initialization mode and between steps");
    if (order > 1) {
        snprintf(m->msg, sizeof m->msg, "order %d derivative of %s ignored: the input is interpolated linearly "
                 "(order 1) inside a step", order, model_variable_name(vr));
        return MODEL_WARNING;
    }
    m->du[vr - VR_THETA_M] = value;
    return MODEL_OK;
}

ModelStatus model_get_integer(Model *m, unsigned vr, int *value) {
    if (vr == VR_NSUB) *value = m->nsub;
    else return fail(m, "get integer: unknown value reference %u (not an Integer variable)", vr);
    return MODEL_OK;
}

ModelStatus model_set_integer(Model *m, unsigned vr, int value) {
    if (vr != VR_NSUB) return fail(m, "set integer: unknown value reference %u (not an Integer variable)", vr);
    if (m->phase != PHASE_INSTANTIATED && m->phase != PHASE_INITIALIZATION)
        return fail(m, "set integer: nsub can only be set before the end of initialization");
    m->nsub = value;
    return MODEL_OK;
}

/* ------------------------------------------------------------------------ */
/* initialization                                                             */
/* ------------------------------------------------------------------------ */

ModelStatus model_enter_initialization(Model *m, double start_time) {
    if (m->phase != PHASE_INSTANTIATED)
        return fail(m, "enter initialization mode: only allowed right after instantiation or reset");
    if (!isfinite(start_time)) return fail(m, "enter initialization mode: start time must be finite");
    m->time = start_time;
    m->phase = PHASE_INITIALIZATION;
    return MODEL_OK;
}

static ModelStatus validate(Model *m) {
    static const unsigned reals[] = {VR_JL, VR_KL, VR_BL, VR_BACKLASH, VR_MGL};
    size_t i;
    for (i = 0; i < sizeof reals / sizeof reals[0]; ++i) {
        double v = *real_ptr(m, reals[i]);
        if (!isfinite(v)) return fail(m, "parameter %s = %g is invalid: must be finite", variable_names[reals[i]], v);
    }
    if (!(m->JL > 0.0)) return fail(m, "parameter JL = %g is invalid: the load inertia must be > 0 kg m^2", m->JL);
    if (m->KL < 0.0) return fail(m, "parameter KL = %g is invalid: the stiffness must be >= 0 N m/rad", m->KL);
    if (m->backlash < 0.0) return fail(m, "parameter backlash = %g is invalid: must be >= 0 rad", m->backlash);
    if (m->nsub < 1) return fail(m, "parameter nsub = %d is invalid: needs at least 1 RK4 substep", m->nsub);
    return MODEL_OK;
}

ModelStatus model_exit_initialization(Model *m) {
    if (m->phase != PHASE_INITIALIZATION)
        return fail(m, "exit initialization mode: not in initialization mode");
    if (validate(m) != MODEL_OK) return MODEL_ERROR;
    update_derived(m);
    m->phase = PHASE_STEPPING;
    return MODEL_OK;
}

ModelStatus model_terminate(Model *m) {
    if (m->phase == PHASE_INSTANTIATED)
        return fail(m, "terminate: the model was not initialized");
    m->phase = PHASE_TERMINATED;
    return MODEL_OK;
}

/* ------------------------------------------------------------------------ */
/* doStep                                                                     */
/* ------------------------------------------------------------------------ */

static ModelStatus do_step(Model *m, double t0, double h) {
    static const char *const state_names[2] = {"theta_L", "omega_L"};
    double t1, tol;
    int j;

    if (m->phase == PHASE_ERROR)
        return fail(m, "doStep: the model is in an error state after a failed step (call reset)");
    if (m->phase != PHASE_STEPPING)
        return fail(m, "doStep: only allowed after the end of initialization and before terminate");
    if (!isfinite(t0) || !isfinite(h) || h < 0.0)
        return fail(m, "doStep: invalid communication point %g or step size %g (step size must be >= 0)", t0, h);
    tol = 1e-9 * (fabs(t0) > 1.0 ? fabs(t0) : 1.0);
    if (fabs(t0 - m->time) > tol)
        return fail(m, "doStep: communication point %.17g differs from the model time %.17g "
                       "(steps must follow each other)", t0, m->time);
    if (h == 0.0) return MODEL_OK;
    t1 = t0 + h;
    rk4(m, t0, h / (double)m->nsub, m->nsub);
    for (j = 0; j < 2; ++j) {
        if (!isfinite(m->x[j]) || fabs(m->x[j]) > MODEL_STATE_LIMIT) {
            m->phase = PHASE_ERROR; /* time stays at t0, the last successful time */
            return fail(m, "doStep from t = %.12g to t = %.12g: state %s diverged (value %g, limit %g); "
                           "check the parameters (negative damping, unstable coupling) and the step size",
                        t0, t1, state_names[j], m->x[j], MODEL_STATE_LIMIT);
        }
    }
    m->time = t1;
    return MODEL_OK;
}

ModelStatus model_do_step(Model *m, double t0, double h) {
    const ModelStatus status = do_step(m, t0, h);
    int i;
    for (i = 0; i < N_INPUTS; ++i) m->du[i] = 0.0; /* input derivatives hold for one step only */
    return status;
}
