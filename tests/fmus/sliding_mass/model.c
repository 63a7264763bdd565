/*
 * sliding_mass: equations, RK4 and parameter checks. See model.h.
 */
#include "model.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>

static ModelStatus fail(Model *m, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(m->msg, sizeof m->msg, fmt, ap);
    va_end(ap);
    return MODEL_ERROR;
}

void model_reset(Model *m) {
    m->m = 1.0;   /* kg */
    m->k = 20.0;  /* N/m */
    m->d = 0.4;   /* N s/m */
    m->Fc = 1.5;  /* N */
    m->vs = 0.05; /* m/s */
    m->F = 0.0;
    m->x[0] = 0.2; /* m: released from a stretched spring */
    m->x[1] = 0.0;
    m->time = 0.0;
    m->phase = PHASE_INSTANTIATED;
    m->msg[0] = '\0';
}

void model_derivatives(const Model *m, const double x[2], double dx[2]) {
    dx[0] = x[1];
    dx[1] = (m->F - m->k * x[0] - m->d * x[1] - m->Fc * tanh(x[1] / m->vs)) / m->m;
}

ModelStatus model_get_real(Model *m, unsigned vr, double *value) {
    double dx[2];
    switch (vr) {
    case VR_TIME: *value = m->time; return MODEL_OK;
    case VR_EXTFORCE:
    case VR_FORCE_F: *value = m->F; return MODEL_OK;
    case VR_S:
    case VR_POSITION: *value = m->x[0]; return MODEL_OK;
    case VR_V: *value = m->x[1]; return MODEL_OK;
    case VR_DER_S:
    case VR_DER_V:
        model_derivatives(m, m->x, dx);
        *value = dx[vr - VR_DER_S];
        return MODEL_OK;
    case VR_M: *value = m->m; return MODEL_OK;
    case VR_K: *value = m->k; return MODEL_OK;
    case VR_D: *value = m->d; return MODEL_OK;
    case VR_FC: *value = m->Fc; return MODEL_OK;
    case VR_VS: *value = m->vs; return MODEL_OK;
    default: return fail(m, "no Real variable has value reference %u", vr);
    }
}

ModelStatus model_set_real(Model *m, unsigned vr, double value) {
    const int before_init = m->phase == PHASE_INSTANTIATED || m->phase == PHASE_INITIALIZATION;
    if (!isfinite(value)) return fail(m, "value reference %u: %g is not finite", vr, value);
    switch (vr) {
    case VR_EXTFORCE:
    case VR_FORCE_F: m->F = value; return MODEL_OK; /* either input: the one force */
    case VR_S:
    case VR_V:
        if (!before_init) return fail(m, "the start values of mass.s and mass.v are set before initialization");
        m->x[vr - VR_S] = value;
        return MODEL_OK;
    case VR_M:
    case VR_K:
    case VR_D:
    case VR_FC:
    case VR_VS:
        if (!before_init) return fail(m, "the parameters are fixed: set them before initialization");
        if (vr == VR_M) m->m = value;
        else if (vr == VR_K) m->k = value;
        else if (vr == VR_D) m->d = value;
        else if (vr == VR_FC) m->Fc = value;
        else m->vs = value;
        return MODEL_OK;
    default: return fail(m, "value reference %u cannot be set", vr);
    }
}

ModelStatus model_enter_initialization(Model *m, double start_time) {
    if (m->phase != PHASE_INSTANTIATED) return fail(m, "initialization only follows instantiation or reset");
    m->time = start_time;
    m->phase = PHASE_INITIALIZATION;
    return MODEL_OK;
}

ModelStatus model_exit_initialization(Model *m) {
    if (m->phase != PHASE_INITIALIZATION) return fail(m, "not in Initialization Mode");
    if (!(m->m > 0.0) || !(m->vs > 0.0) || m->k < 0.0 || m->d < 0.0 || m->Fc < 0.0)
        return fail(m, "need m > 0, vs > 0 and k, d, Fc >= 0");
    m->phase = PHASE_STEPPING;
    return MODEL_OK;
}

ModelStatus model_do_step(Model *m, double t, double h) {
    double k1[2], k2[2], k3[2], k4[2], y[2], dt;
    int i, j;
    if (m->phase != PHASE_STEPPING) return fail(m, "doStep: only allowed after initialization");
    if (!isfinite(h) || h < 0.0) return fail(m, "doStep: step size %g must be >= 0", h);
    if (fabs(t - m->time) > 1e-9 * (fabs(t) > 1.0 ? fabs(t) : 1.0))
        return fail(m, "doStep: communication point %.17g differs from the model time %.17g", t, m->time);
    dt = h / SUBSTEPS;
    for (i = 0; i < SUBSTEPS; ++i) {
        model_derivatives(m, m->x, k1);
        for (j = 0; j < 2; ++j) y[j] = m->x[j] + 0.5 * dt * k1[j];
        model_derivatives(m, y, k2);
        for (j = 0; j < 2; ++j) y[j] = m->x[j] + 0.5 * dt * k2[j];
        model_derivatives(m, y, k3);
        for (j = 0; j < 2; ++j) y[j] = m->x[j] + dt * k3[j];
        model_derivatives(m, y, k4);
        for (j = 0; j < 2; ++j) m->x[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
    }
    m->time = t + h;
    return MODEL_OK;
}
