/*
 * motor: equations, RK4 integrator, input-delay history, parameter validation, state copy.  See model.h for
 * the interface and ../README.md for the physics.  The terms and their order of evaluation are those of
 * fmus/two_mass_servo/model.c (its motor row, with the shaft torque Tc an input):
 *
 *   Ta   = sat(Tm(t - delay))
 *   sgn  = tanh(w / vsmooth),  w = omega_m
 *   Tf   = Bm*w + Bm_asym*w*sgn + Fc*sgn + Fs*exp(-(w/vs)^2)*sgn
 *   Tcog = Tcog_amp*sin(ncog*theta_m)
 *   Jm*domega_m = Ta + Toffset - Tf - Tcog - Tc
 */
#include "model.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const variable_names[VR_COUNT] = {
    "time", "Tm",      "Tc",      "theta_m", "omega_m", "der_theta_m", "der_omega_m", "Jm",    "Bm",   "Fc",
    "Fs",   "vs",      "vsmooth", "Bm_asym", "Tcog",    "Tmax",        "Toffset",     "delay", "ncog", "nsub"};

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
    /* the motor side of the one-FMU servo's linear plant, see fmus/two_mass_servo/README.md */
    m->Jm = 250.0; /* kg m^2 */
    m->Bm = 50.0;  /* N m s/rad */
    /* effects: all off */
    m->Fc = 0.0;
    m->Fs = 0.0;
    m->vs = 0.01;      /* rad/s */
    m->vsmooth = 1e-3; /* rad/s */
    m->Bm_asym = 0.0;
    m->Tcog = 0.0;
    m->ncog = 12;
    m->Tmax = 0.0;
    m->Toffset = 0.0;
    m->delay = 0.0;
    m->nsub = 10;
    m->Tm = 0.0;
    m->Tc = 0.0;
    m->dTm = 0.0;
    m->dTc = 0.0;
    m->x[0] = m->x[1] = 0.0;
    m->time = 0.0;
    m->Tm_init = 0.0;
    m->hist.head = 0;
    m->hist.count = 0; /* keep the buffers for reuse */
    m->phase = PHASE_INSTANTIATED;
    m->msg[0] = '\0';
    update_derived(m);
}

void model_free(Model *m) {
    free(m->hist.t);
    free(m->hist.u);
    free(m->hist.du);
    m->hist.t = m->hist.u = m->hist.du = NULL;
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

/* Constants derived from the parameters, so that the right-hand side multiplies instead of dividing and skips
 * the effects that are off. */
static void update_derived(Model *m) {
    m->inv_Jm = 1.0 / m->Jm;
    m->inv_vsmooth = 1.0 / m->vsmooth;
    m->inv_vs = m->vs != 0.0 ? 1.0 / m->vs : 0.0;
    m->has_friction = m->Fc != 0.0 || m->Fs != 0.0 || m->Bm_asym != 0.0;
    m->has_stribeck = m->Fs != 0.0;
    m->has_cogging = m->Tcog != 0.0;
}

#if defined(__GNUC__)
#define ALWAYS_INLINE __attribute__((always_inline)) inline
#else
#define ALWAYS_INLINE inline
#endif

/* State derivative for applied (already delayed and saturated) torque Ta and shaft torque Tc. */
static ALWAYS_INLINE void rhs(const Model *m, double Ta, double Tc, const double x[2], double dx[2]) {
    const double wm = x[1];
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
    dx[0] = wm;
    dx[1] = ((Ta + m->Toffset) - (Tf + Tc)) * m->inv_Jm;
}

/* The inputs over one piece of a step: Tm(s) = um + dum*(s - sm) before saturation, Tc(s) = uc + duc*(s - sc).
 * With zero slopes the inputs are held (zero-order hold) and the sums are exactly um and uc. */
typedef struct {
    double um, dum, sm;
    double uc, duc, sc;
} Drive;

static ALWAYS_INLINE double drive_Ta(const Model *m, const Drive *d, double s) {
    return saturate(m, d->um + d->dum * (s - d->sm));
}

static ALWAYS_INLINE double drive_Tc(const Drive *d, double s) {
    return d->uc + d->duc * (s - d->sc);
}

/* n RK4 steps of size dt from time a.  The weighted sum x + dt/6*(k1 + 2 k2 + 2 k3 + k4) is accumulated stage
 * by stage, as in the one-FMU servo.  Stage times are a + i*dt (+ dt/2), never accumulated. */
static void rk4(Model *m, const Drive *d, double a, double dt, long n) {
    double x[2], k[2], y[2], acc[2]; /* locals: no aliasing with the parameters in *m */
    const double half = 0.5 * dt, sixth = dt / 6.0, third = dt / 3.0;
    long i;
    int j;
    for (j = 0; j < 2; ++j) x[j] = m->x[j];
    for (i = 0; i < n; ++i) {
        const double s0 = a + (double)i * dt, s1 = s0 + half, s2 = a + (double)(i + 1) * dt;
        const double Ta_mid = drive_Ta(m, d, s1), Tc_mid = drive_Tc(d, s1);
        rhs(m, drive_Ta(m, d, s0), drive_Tc(d, s0), x, k);
        for (j = 0; j < 2; ++j) {
            acc[j] = x[j] + sixth * k[j];
            y[j] = x[j] + half * k[j];
        }
        rhs(m, Ta_mid, Tc_mid, y, k);
        for (j = 0; j < 2; ++j) {
            acc[j] += third * k[j];
            y[j] = x[j] + half * k[j];
        }
        rhs(m, Ta_mid, Tc_mid, y, k);
        for (j = 0; j < 2; ++j) {
            acc[j] += third * k[j];
            y[j] = x[j] + dt * k[j];
        }
        rhs(m, drive_Ta(m, d, s2), drive_Tc(d, s2), y, k);
        for (j = 0; j < 2; ++j) x[j] = acc[j] + sixth * k[j];
    }
    for (j = 0; j < 2; ++j) m->x[j] = x[j];
}

/* ------------------------------------------------------------------------ */
/* input-delay history                                                        */
/* ------------------------------------------------------------------------ */

#define HIST_AT(h, arr, i) ((h)->arr[((h)->head + (i)) % (h)->cap])

static int hist_push(TmHistory *h, double t, double u, double du) {
    if (h->count > 0 && HIST_AT(h, t, h->count - 1) >= t) {
        HIST_AT(h, u, h->count - 1) = u; /* same communication point again */
        HIST_AT(h, du, h->count - 1) = du;
        return 0;
    }
    if (h->count == h->cap) {
        size_t cap = h->cap ? 2 * h->cap : 64, i;
        double *nt = (double *)malloc(cap * sizeof(double));
        double *nu = (double *)malloc(cap * sizeof(double));
        double *ndu = (double *)malloc(cap * sizeof(double));
        if (!nt || !nu || !ndu || cap < h->cap) {
            free(nt);
            free(nu);
            free(ndu);
            return -1;
        }
        for (i = 0; i < h->count; ++i) {
            nt[i] = HIST_AT(h, t, i);
            nu[i] = HIST_AT(h, u, i);
            ndu[i] = HIST_AT(h, du, i);
        }
        free(h->t);
        free(h->u);
        free(h->du);
        h->t = nt;
        h->u = nu;
        h->du = ndu;
        h->head = 0;
        h->cap = cap;
    }
    h->t[(h->head + h->count) % h->cap] = t;
    h->u[(h->head + h->count) % h->cap] = u;
    h->du[(h->head + h->count) % h->cap] = du;
    h->count++;
    return 0;
}

/* Drop entries that no longer matter at time t: an entry is needed while its successor has not yet taken
 * effect (successor time + delay > t). */
static void hist_prune(TmHistory *h, double delay, double t) {
    while (h->count >= 2 && HIST_AT(h, t, 1) + delay <= t) {
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
        const double tk = HIST_AT(h, t, i);
        if (tk + m->delay > t + eps) break;
        u = HIST_AT(h, u, i) + HIST_AT(h, du, i) * (t - (tk + m->delay));
    }
    return u;
}

ModelStatus model_copy(Model *dst, const Model *src) {
    const size_t n = src->hist.count;
    double *t = dst->hist.t, *u = dst->hist.u, *du = dst->hist.du;
    size_t cap = dst->hist.cap, i;
    if (dst == src) return MODEL_OK;
    if (cap < n) { /* the saved history does not fit: new buffers, the old ones freed only on success */
        double *nt = (double *)malloc(n * sizeof(double));
        double *nu = (double *)malloc(n * sizeof(double));
        double *ndu = (double *)malloc(n * sizeof(double));
        if (!nt || !nu || !ndu) {
            free(nt);
            free(nu);
            free(ndu);
            return fail(dst, "out of memory for a copy of the input-delay history (%lu entries)", (unsigned long)n);
        }
        free(t);
        free(u);
        free(du);
        t = nt;
        u = nu;
        du = ndu;
        cap = n;
    }
    for (i = 0; i < n; ++i) {
        t[i] = HIST_AT(&src->hist, t, i);
        u[i] = HIST_AT(&src->hist, u, i);
        du[i] = HIST_AT(&src->hist, du, i);
    }
    *dst = *src;
    dst->hist.t = t;
    dst->hist.u = u;
    dst->hist.du = du;
    dst->hist.cap = cap;
    dst->hist.head = 0;
    dst->hist.count = n;
    return MODEL_OK;
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
    case VR_TC: return &m->Tc;
    case VR_THETA_M: return &m->x[0];
    case VR_OMEGA_M: return &m->x[1];
    case VR_JM: return &m->Jm;
    case VR_BM: return &m->Bm;
    case VR_FC: return &m->Fc;
    case VR_FS: return &m->Fs;
    case VR_VS: return &m->vs;
    case VR_VSMOOTH: return &m->vsmooth;
    case VR_BM_ASYM: return &m->Bm_asym;
    case VR_TCOG: return &m->Tcog;
    case VR_TMAX: return &m->Tmax;
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
    if (vr == VR_DER_THETA_M || vr == VR_DER_OMEGA_M) {
        double dx[2];
        if (m->phase == PHASE_INSTANTIATED || m->phase == PHASE_INITIALIZATION) update_derived(m);
        rhs(m, current_Ta(m), m->Tc, m->x, dx);
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
    if (vr != VR_TM && vr != VR_TC && m->phase == PHASE_STEPPING)
        return fail(m, "set real: %s can only be set before the end of initialization "
                       "(only the inputs Tm and Tc can change during the simulation)", name);
    *p = value;
    return MODEL_OK;
}

ModelStatus model_set_input_derivative(Model *m, unsigned vr, int order, double value) {
    double *p = vr == VR_TM ? &m->dTm : (vr == VR_TC ? &m->dTc : NULL);
    if (!p) return fail(m, "set input derivative: value reference %u is not a Real input (Tm, Tc)", vr);
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
    static const unsigned reals[] = {VR_JM,   VR_BM,   VR_FC,   VR_FS,      VR_VS,   VR_VSMOOTH,
                                     VR_BM_ASYM, VR_TCOG, VR_TMAX, VR_TOFFSET, VR_DELAY};
    size_t i;
    for (i = 0; i < sizeof reals / sizeof reals[0]; ++i) {
        double v = *real_ptr(m, reals[i]);
        if (!isfinite(v)) return fail(m, "parameter %s = %g is invalid: must be finite", variable_names[reals[i]], v);
    }
    if (!(m->Jm > 0.0)) return fail(m, "parameter Jm = %g is invalid: the motor inertia must be > 0 kg m^2", m->Jm);
    if (m->Fs != 0.0 && !(m->vs > 0.0))
        return fail(m, "parameter vs = %g is invalid: the Stribeck velocity must be > 0 rad/s when Fs != 0", m->vs);
    if (!(m->vsmooth > 0.0))
        return fail(m, "parameter vsmooth = %g is invalid: the sign smoothing velocity must be > 0 rad/s", m->vsmooth);
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

/* One piece [a, b] of a step with the inputs d. */
static void integrate_piece(Model *m, const Drive *d, double a, double b, double h) {
    const long n = substeps(m, b - a, h);
    rk4(m, d, a, (b - a) / (double)n, n);
}

static ModelStatus do_step(Model *m, double t0, double h) {
    static const char *const state_names[2] = {"theta_m", "omega_m"};
    Drive d;
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
    d.uc = m->Tc;
    d.duc = m->dTc;
    d.sc = t0;

    if (m->delay == 0.0) {
        d.um = m->Tm;
        d.dum = m->dTm;
        d.sm = t0;
        rk4(m, &d, t0, h / (double)m->nsub, m->nsub);
    } else {
        /* Split [t0, t1] at the instants t_k + delay when a past input takes effect. */
        const double eps = 1e-9 * h + 8.0 * 2.220446049250313e-16 * (fabs(t1) + m->delay);
        TmHistory *hist = &m->hist;
        double a = t0;
        size_t i;
        if (hist_push(hist, t0, m->Tm, m->dTm) != 0) {
            m->phase = PHASE_ERROR;
            return fail(m, "doStep at t = %.12g: out of memory for the input-delay history", t0);
        }
        hist_prune(hist, m->delay, t0 + eps);
        d.um = m->Tm_init; /* before the first recorded input takes effect */
        d.dum = 0.0;
        d.sm = t0;
        for (i = 0; i < hist->count; ++i) {
            const double bp = HIST_AT(hist, t, i) + m->delay;
            if (bp > a + eps) {
                if (bp >= t1 - eps) break;
                integrate_piece(m, &d, a, bp, h);
                a = bp;
            }
            d.um = HIST_AT(hist, u, i); /* in effect from bp on */
            d.dum = HIST_AT(hist, du, i);
            d.sm = bp;
        }
        integrate_piece(m, &d, a, t1, h);
    }
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
    m->dTm = m->dTc = 0.0; /* input derivatives hold for one step only */
    return status;
}
