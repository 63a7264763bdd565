/*
 * loop_a: equations, the exact step and parameter checks. See model.h.
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
    m->ka = 0.5;
    m->tau = 0.2; /* s */
    m->steady = 0.0;
    m->u = 0.0;
    m->x = 1.0; /* x0 */
    m->time = 0.0;
    m->phase = PHASE_INSTANTIATED;
    m->msg[0] = '\0';
}

ModelStatus model_get_real(Model *m, unsigned vr, double *value) {
    switch (vr) {
    case VR_TIME: *value = m->time; return MODEL_OK;
    case VR_U: *value = m->u; return MODEL_OK;
    case VR_Y: *value = m->ka * m->u + m->x; return MODEL_OK; /* from the input set last */
    case VR_X: *value = m->x; return MODEL_OK;
    case VR_DER_X: *value = (m->u - m->x) / m->tau; return MODEL_OK;
    case VR_KA: *value = m->ka; return MODEL_OK;
    case VR_TAU: *value = m->tau; return MODEL_OK;
    case VR_STEADY: *value = m->steady; return MODEL_OK;
    default: return fail(m, "no Real variable has value reference %u", vr);
    }
}

ModelStatus model_set_real(Model *m, unsigned vr, double value) {
    const int before_init = m->phase == PHASE_INSTANTIATED || m->phase == PHASE_INITIALIZATION;
    if (!isfinite(value)) return fail(m, "value reference %u: %g is not finite", vr, value);
    switch (vr) {
    case VR_U: m->u = value; return MODEL_OK; /* the state x is left as it is */
    case VR_X:
        if (!before_init) return fail(m, "the start value of x is set before initialization");
        m->x = value;
        return MODEL_OK;
    case VR_KA:
    case VR_TAU:
    case VR_STEADY:
        if (!before_init) return fail(m, "the parameters are fixed: set them before initialization");
        if (vr == VR_KA) m->ka = value;
        else if (vr == VR_TAU) m->tau = value;
        else m->steady = value;
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
    if (!(m->tau > 0.0)) return fail(m, "need tau > 0, got %g", m->tau);
    if (m->steady != 0.0) m->x = m->u; /* x in steady state with the input set during initialization */
    m->phase = PHASE_STEPPING;
    return MODEL_OK;
}

ModelStatus model_do_step(Model *m, double t, double h) {
    if (m->phase != PHASE_STEPPING) return fail(m, "doStep: only allowed after initialization");
    if (!isfinite(h) || h < 0.0) return fail(m, "doStep: step size %g must be >= 0", h);
    if (fabs(t - m->time) > 1e-9 * (fabs(t) > 1.0 ? fabs(t) : 1.0))
        return fail(m, "doStep: communication point %.17g differs from the model time %.17g", t, m->time);
    m->x = m->u + (m->x - m->u) * exp(-h / m->tau); /* exact for u held over the step */
    m->time = t + h;
    return MODEL_OK;
}
