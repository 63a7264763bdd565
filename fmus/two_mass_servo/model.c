/*
 * two_mass_servo: equations, RK4 integrator, input-delay history, parameter
 * validation.  See model.h for the interface and README.md for the physics.
 *
 *   Ta   = sat(Tm(t - delay))
 *   Tc   = KL*dz(theta_m - theta_L) + BL*(omega_m - omega_L)
 *   sgn  = tanh(w / vsmooth),  w = omega_m
 *   Tf   = Bm*w + Bm_asym*w*sgn + Fc*sgn + Fs*exp(-(w/vs)^2)*sgn
 *   Tcog = Tcog_amp*sin(ncog*theta_m)
 *   Jm*domega_m = Ta + Toffset - Tf - Tcog - Tc
 *   JL*domega_L = TL + Tc - mgl*sin(theta_L)
 */
#include "model.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const variable_names[VR_COUNT] = {
    "time",     "Tm",       "TL",          "theta_m",     "omega_m",     "theta_L",
    "omega_L",  "der_theta_m", "der_omega_m", "der_theta_L", "der_omega_L", "Jm",
    "JL",       "KL",       "Bm",          "BL",          "Fc",          "Fs",
    "vs",       "vsmooth",  "Bm_asym",     "backlash",    "Tcog",        "Tmax",
    "mgl",      "Toffset",  "delay",       "ncog",        "nsub"};

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
    /* linear plant: ~1-2 m alt-az telescope azimuth axis, see README.md */
    m->Jm = 250.0;     /* kg m^2 */
    m->JL = 1000.0;    /* kg m^2 */
    m->KL = 2.5e6;     /* N m/rad */
    m->Bm = 50.0;      /* N m s/rad */
    m->BL = 500.0;     /* N m s/rad */
    /* effects: all off */
    m->Fc = 0.0;
    m->Fs = 0.0;
    m->vs = 0.01;      /* rad/s */
    m->vsmooth = 1e-3; /* rad/s */
    m->Bm_asym = 0.0;
    m->backlash = 0.0;
    m->Tcog = 0.0;
    m->ncog = 12;
    m->Tmax = 0.0;
    m->mgl = 0.0;
    m->Toffset = 0.0;
    m->delay = 0.0;
    m->nsub = 10;
    m->Tm = 0.0;
    m->TL = 0.0;
    m->x[0] = m->x[1] = m->x[2] = m->x[3] = 0.0;
    m->time = 0.0;
    m->Tm_init = 0.0;
    m->hist.head = 0;
    m->hist.count = 0; /* keep the buffer for reuse */
    m->phase = PHASE_INSTANTIATED;
    m->msg[0] = '\0';
    update_derived(m);
}

void model_free(Model *m) {
    free(m->hist.t);
    free(m->hist.u);
    m->hist.t = m->hist.u = NULL;
    m->hist.head = m->hist.count = m->hist.cap = 0;
}

/* ------------------------------------------------------------------------ */
/* equations                                                                  */
/* ------------------------------------------------------------------------ */

/* tanh(z) rounds to exactly +-1 for |z| > 19.1: skip the call there. */
static double smooth_sign(double z) {
    if (z > 20.0) return 1.0;
    if (z < -20.0) return -1.0;
    return tanh(z);
}

static double saturate(const Model *m, double T) {
    if (m->Tmax > 0.0) {
        if (T > m->Tmax) return m->Tmax;
        if (T < -m->Tmax) return -m->Tmax;
    }
    return T;
}

/* Constants derived from the parameters, so that the right-hand side multiplies
 * instead of dividing and skips the effects that are off. */
static void update_derived(Model *m) {
    m->inv_Jm = 1.0 / m->Jm;
    m->inv_JL = 1.0 / m->JL;
    m->inv_vsmooth = 1.0 / m->vsmooth;
    m->inv_vs = m->vs != 0.0 ? 1.0 / m->vs : 0.0;
    m->has_friction = m->Fc != 0.0 || m->Fs != 0.0 || m->Bm_asym != 0.0;
    m->has_stribeck = m->Fs != 0.0;
    m->has_backlash = m->backlash != 0.0;
    m->has_cogging = m->Tcog != 0.0;
    m->has_gravity = m->mgl != 0.0;
}

#if defined(__GNUC__)
#define ALWAYS_INLINE __attribute__((always_inline)) inline
#else
#define ALWAYS_INLINE inline
#endif

/* State derivative for applied (already delayed and saturated) torque Ta. */
static ALWAYS_INLINE void rhs(const Model *m, double Ta, const double x[4], double dx[4]) {
    const double wm = x[1];
    const double d = x[0] - x[2];
    double dz = d;
    if (m->has_backlash) {
        const double b = m->backlash;
        dz = d > b ? d - b : (d < -b ? d + b : 0.0);
    }
    const double Tc = m->KL * dz + m->BL * (wm - x[3]);

    double Tf = m->Bm * wm;
    if (m->has_friction) {
        const double s = smooth_sign(wm * m->inv_vsmooth);
        Tf += (m->Bm_asym * wm + m->Fc) * s;
        if (m->has_stribeck) {
            const double r = wm * m->inv_vs;
            const double r2 = r * r;
            if (r2 < 760.0) Tf += m->Fs * exp(-r2) * s; /* exp(-760) == 0 in double */
        }
    }
    if (m->has_cogging) Tf += m->Tcog * sin((double)m->ncog * x[0]);
    const double Tm_net = (Ta + m->Toffset) - (Tf + Tc);
    double Tl_net = m->TL + Tc;
    if (m->has_gravity) Tl_net -= m->mgl * sin(x[2]);

    dx[0] = wm;
    dx[1] = Tm_net * m->inv_Jm;
    dx[2] = x[3];
    dx[3] = Tl_net * m->inv_JL;
}

/* n RK4 steps of size dt with constant applied torque Ta.  The weighted sum
 * x + dt/6*(k1 + 2 k2 + 2 k3 + k4) is accumulated stage by stage, which keeps
 * it off the critical path of the next stage. */
static void rk4(Model *m, double Ta, double dt, long n) {
    double x[4], k[4], y[4], acc[4]; /* locals: no aliasing with the parameters in *m */
    const double half = 0.5 * dt, sixth = dt / 6.0, third = dt / 3.0;
    long i;
    int j;
    for (j = 0; j < 4; ++j) x[j] = m->x[j];
    for (i = 0; i < n; ++i) {
        rhs(m, Ta, x, k);
        for (j = 0; j < 4; ++j) {
            acc[j] = x[j] + sixth * k[j];
            y[j] = x[j] + half * k[j];
        }
        rhs(m, Ta, y, k);
        for (j = 0; j < 4; ++j) {
            acc[j] += third * k[j];
            y[j] = x[j] + half * k[j];
        }
        rhs(m, Ta, y, k);
        for (j = 0; j < 4; ++j) {
            acc[j] += third * k[j];
            y[j] = x[j] + dt * k[j];
        }
        rhs(m, Ta, y, k);
        for (j = 0; j < 4; ++j) x[j] = acc[j] + sixth * k[j];
    }
    for (j = 0; j < 4; ++j) m->x[j] = x[j];
}

/* ------------------------------------------------------------------------ */
/* input-delay history                                                        */
/* ------------------------------------------------------------------------ */

#define HIST_T(h, i) ((h)->t[((h)->head + (i)) % (h)->cap])
#define HIST_U(h, i) ((h)->u[((h)->head + (i)) % (h)->cap])

static int hist_push(TmHistory *h, double t, double u) {
    if (h->count > 0 && HIST_T(h, h->count - 1) >= t) {
        HIST_U(h, h->count - 1) = u; /* same communication point again */
        return 0;
    }
    if (h->count == h->cap) {
        size_t cap = h->cap ? 2 * h->cap : 64, i;
        double *nt = (double *)malloc(cap * sizeof(double));
        double *nu = (double *)malloc(cap * sizeof(double));
        if (!nt || !nu || cap < h->cap) {
            free(nt);
            free(nu);
            return -1;
        }
        for (i = 0; i < h->count; ++i) {
            nt[i] = HIST_T(h, i);
            nu[i] = HIST_U(h, i);
        }
        free(h->t);
        free(h->u);
        h->t = nt;
        h->u = nu;
        h->head = 0;
        h->cap = cap;
    }
    h->t[(h->head + h->count) % h->cap] = t;
    h->u[(h->head + h->count) % h->cap] = u;
    h->count++;
    return 0;
}

/* Drop entries that no longer matter at time t: an entry is needed while its
 * successor has not yet taken effect (successor time + delay > t). */
static void hist_prune(TmHistory *h, double delay, double t) {
    while (h->count >= 2 && HIST_T(h, 1) + delay <= t) {
        h->head = (h->head + 1) % h->cap;
        h->count--;
    }
}

/* Tm in effect at time t (right-continuous), before saturation. */
static double delayed_Tm(const Model *m, double t, double eps) {
    const TmHistory *h = &m->hist;
    double u = m->Tm_init;
    size_t i;
    for (i = 0; i < h->count; ++i) {
        if (HIST_T(h, i) + m->delay > t + eps) break;
        u = HIST_U(h, i);
    }
    return u;
}

/* ------------------------------------------------------------------------ */
/* get / set                                                                  */
/* ------------------------------------------------------------------------ */

/* Applied torque at the current time (for the derivative outputs). */
static double current_Ta(const Model *m) {
    if (m->delay > 0.0 && (m->phase == PHASE_STEPPING || m->phase == PHASE_ERROR ||
                           m->phase == PHASE_TERMINATED)) {
        double eps = 8.0 * 2.220446049250313e-16 * (fabs(m->time) + m->delay);
        return saturate(m, delayed_Tm(m, m->time, eps));
    }
    return saturate(m, m->Tm);
}

static double *real_ptr(Model *m, unsigned vr) {
    switch (vr) {
    case VR_TM: return &m->Tm;
    case VR_TL: return &m->TL;
    case VR_THETA_M: return &m->x[0];
    case VR_OMEGA_M: return &m->x[1];
    case VR_THETA_L: return &m->x[2];
    case VR_OMEGA_L: return &m->x[3];
    case VR_JM: return &m->Jm;
    case VR_JL: return &m->JL;
    case VR_KL: return &m->KL;
    case VR_BM: return &m->Bm;
    case VR_BL: return &m->BL;
    case VR_FC: return &m->Fc;
    case VR_FS: return &m->Fs;
    case VR_VS: return &m->vs;
    case VR_VSMOOTH: return &m->vsmooth;
    case VR_BM_ASYM: return &m->Bm_asym;
    case VR_BACKLASH: return &m->backlash;
    case VR_TCOG: return &m->Tcog;
    case VR_TMAX: return &m->Tmax;
    case VR_MGL: return &m->mgl;
    case VR_TOFFSET: return &m->Toffset;
    case VR_DELAY: return &m->delay;
    default: return NULL;
    }
}

ModelStatus model_get_real(Model *m, unsigned vr, double *value) {
    double *p;
    if (vr == VR_TIME) {
        *value = m->time;
        return MODEL_OK;
    }
    if (vr >= VR_DER_THETA_M && vr <= VR_DER_OMEGA_L) {
        double dx[4];
        if (m->phase == PHASE_INSTANTIATED || m->phase == PHASE_INITIALIZATION) update_derived(m);
        rhs(m, current_Ta(m), m->x, dx);
        *value = dx[vr - VR_DER_THETA_M];
        return MODEL_OK;
    }
    p = real_ptr(m, vr);
    if (!p) return fail(m, "get real: unknown value reference %u (not a Real variable)", vr);
    *value = *p;
    return MODEL_OK;
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
    if (vr != VR_TM && vr != VR_TL && m->phase == PHASE_STEPPING)
        return fail(m, "set real: %s can only be set before the end of initialization "
                       "(only the inputs Tm and TL can change during the simulation)", name);
    *p = value;
    return MODEL_OK;
}

ModelStatus model_get_integer(Model *m, unsigned vr, int *value) {
    if (vr == VR_NCOG) *value = m->ncog;
    else if (vr == VR_NSUB) *value = m->nsub;
    else return fail(m, "get integer: unknown value reference %u (not an Integer variable)", vr);
    return MODEL_OK;
}

ModelStatus model_set_integer(Model *m, unsigned vr, int value) {
    int *p = vr == VR_NCOG ? &m->ncog : (vr == VR_NSUB ? &m->nsub : NULL);
    if (!p) return fail(m, "set integer: unknown value reference %u (not an Integer variable)", vr);
    if (m->phase != PHASE_INSTANTIATED && m->phase != PHASE_INITIALIZATION)
        return fail(m, "set integer: %s can only be set before the end of initialization",
                    model_variable_name(vr));
    *p = value;
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
    static const unsigned reals[] = {VR_JM, VR_JL, VR_KL, VR_BM, VR_BL, VR_FC, VR_FS, VR_VS,
                                     VR_VSMOOTH, VR_BM_ASYM, VR_BACKLASH, VR_TCOG, VR_TMAX,
                                     VR_MGL, VR_TOFFSET, VR_DELAY};
    size_t i;
    for (i = 0; i < sizeof reals / sizeof reals[0]; ++i) {
        double v = *real_ptr(m, reals[i]);
        if (!isfinite(v)) return fail(m, "parameter %s = %g is invalid: must be finite", variable_names[reals[i]], v);
    }
    if (!(m->Jm > 0.0)) return fail(m, "parameter Jm = %g is invalid: the motor inertia must be > 0 kg m^2", m->Jm);
    if (!(m->JL > 0.0)) return fail(m, "parameter JL = %g is invalid: the load inertia must be > 0 kg m^2", m->JL);
    if (m->KL < 0.0) return fail(m, "parameter KL = %g is invalid: the stiffness must be >= 0 N m/rad", m->KL);
    if (m->Fs != 0.0 && !(m->vs > 0.0))
        return fail(m, "parameter vs = %g is invalid: the Stribeck velocity must be > 0 rad/s when Fs != 0", m->vs);
    if (!(m->vsmooth > 0.0))
        return fail(m, "parameter vsmooth = %g is invalid: the sign smoothing velocity must be > 0 rad/s", m->vsmooth);
    if (m->backlash < 0.0) return fail(m, "parameter backlash = %g is invalid: must be >= 0 rad", m->backlash);
    if (m->Tmax < 0.0) return fail(m, "parameter Tmax = %g is invalid: must be >= 0 N m (0 = no saturation)", m->Tmax);
    if (m->delay < 0.0) return fail(m, "parameter delay = %g is invalid: must be >= 0 s", m->delay);
    if (m->nsub < 1) return fail(m, "parameter nsub = %d is invalid: needs at least 1 RK4 substep", m->nsub);
    return MODEL_OK;
}

ModelStatus model_exit_initialization(Model *m) {
    if (m->phase != PHASE_INITIALIZATION)
        return fail(m, "exit initialization mode: not in initialization mode");
    if (validate(m) != MODEL_OK) return MODEL_ERROR;
    update_derived(m);
    m->Tm_init = m->Tm;
    m->hist.head = 0;
    m->hist.count = 0;
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

/* Number of RK4 substeps for a piece of length len of a step of size h. */
static long substeps(const Model *m, double len, double h) {
    double n = ceil((double)m->nsub * (len / h) - 1e-9);
    if (!(n >= 1.0)) return 1;
    if (n > (double)m->nsub) return m->nsub;
    return (long)n;
}

ModelStatus model_do_step(Model *m, double t0, double h) {
    static const char *const state_names[4] = {"theta_m", "omega_m", "theta_L", "omega_L"};
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

    if (m->delay == 0.0) {
        rk4(m, saturate(m, m->Tm), h / (double)m->nsub, m->nsub);
    } else {
        /* Split [t0, t1] at the instants t_k + delay when a past input takes effect. */
        const double eps = 1e-9 * h + 8.0 * 2.220446049250313e-16 * (fabs(t1) + m->delay);
        TmHistory *hist = &m->hist;
        double a = t0, u = m->Tm_init;
        size_t i;
        if (hist_push(hist, t0, m->Tm) != 0) {
            m->phase = PHASE_ERROR;
            return fail(m, "doStep at t = %.12g: out of memory for the input-delay history", t0);
        }
        hist_prune(hist, m->delay, t0 + eps);
        for (i = 0; i < hist->count; ++i) {
            const double bp = HIST_T(hist, i) + m->delay;
            if (bp <= a + eps) {
                u = HIST_U(hist, i); /* already in effect at a */
                continue;
            }
            if (bp >= t1 - eps) break;
            rk4(m, saturate(m, u), (bp - a) / (double)substeps(m, bp - a, h), substeps(m, bp - a, h));
            a = bp;
            u = HIST_U(hist, i);
        }
        rk4(m, saturate(m, u), (t1 - a) / (double)substeps(m, t1 - a, h), substeps(m, t1 - a, h));
    }
    for (j = 0; j < 4; ++j) {
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
