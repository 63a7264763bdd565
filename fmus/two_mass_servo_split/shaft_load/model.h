/*
 * shaft_load: the shaft and the load side of the two-mass servo (fmus/two_mass_servo) as an FMU of its own, the
 * model core shared by the FMI 2.0 and FMI 3.0 wrappers.
 *
 *   Tc             = KL*dz(theta_m - theta_L) + BL*(omega_m - omega_L)     (an output, direct feedthrough)
 *   JL*domega_L/dt = TL + Tc - mgl*sin(theta_L)
 *   dtheta_L/dt    = omega_L
 *
 * theta_m and omega_m, the motor's angle and speed, are inputs (the motor FMU computes them). The terms and
 * the RK4 with nsub substeps are those of the one-FMU servo; see ../README.md.
 *
 * C99, libc/libm only.  The core knows nothing about FMI; fmi2.c and fmi3.c are the same files in ../motor,
 * written against the interface below (which both model.h declare alike).  On failure a function returns
 * MODEL_ERROR and leaves a one-line message in Model.msg for the wrapper to log.
 */
#ifndef SHAFT_LOAD_MODEL_H
#define SHAFT_LOAD_MODEL_H

#include <stddef.h>

#define MODEL_IDENTIFIER "shaft_load"
/* Must equal guid (FMI 2) / instantiationToken (FMI 3) of the model descriptions. */
#define MODEL_GUID "{c7c9577d-efe7-43e5-a31e-6e64d62e3f46}"
/* Marks an FMU state saved by this model (fmi2GetFMUstate / fmi3GetFMUState). */
#define MODEL_STATE_TAG 0x6c6f6164UL

/* Value references: identical in modelDescription.xml and modelDescription3.xml.
 * FMI 2 index (1-based position in ModelVariables) = value reference + 1. */
enum {
    VR_TIME = 0,
    VR_THETA_M = 1,
    VR_OMEGA_M = 2,
    VR_TL = 3,
    VR_TC = 4,
    VR_THETA_L = 5,
    VR_OMEGA_L = 6,
    VR_DER_THETA_L = 7,
    VR_DER_OMEGA_L = 8,
    VR_JL = 9,
    VR_KL = 10,
    VR_BL = 11,
    VR_BACKLASH = 12,
    VR_MGL = 13,
    VR_NSUB = 14, /* Integer */
    VR_COUNT = 15
};

/* Divergence bound on the magnitude of every state. */
#define MODEL_STATE_LIMIT 1e12

typedef enum {
    PHASE_INSTANTIATED = 0, /* after instantiation or reset */
    PHASE_INITIALIZATION,   /* between Enter- and ExitInitializationMode */
    PHASE_STEPPING,         /* after ExitInitializationMode: doStep allowed */
    PHASE_TERMINATED,
    PHASE_ERROR             /* a step failed (divergence); only get/reset/free make sense */
} ModelPhase;

/* MODEL_WARNING: done, but not all of it (a message says what was left out). */
typedef enum { MODEL_OK = 0, MODEL_ERROR = 1, MODEL_WARNING = 2 } ModelStatus;

/* The three inputs, in value-reference order. */
enum { IN_THETA_M = 0, IN_OMEGA_M = 1, IN_TL = 2, N_INPUTS = 3 };

typedef struct {
    /* parameters (SI units), names and defaults of the one-FMU servo */
    double JL, KL, BL, backlash, mgl;
    int nsub;
    /* inputs [theta_m, omega_m, TL] at the communication point and their first time derivatives (FMI 2 input
     * interpolation): inside a step from t0 the input is u + du*(t - t0); du returns to 0 after each doStep */
    double u[N_INPUTS];
    double du[N_INPUTS];
    /* state x = [theta_L, omega_L] */
    double x[2];
    /* time: start time before initialization, then the end of the last step */
    double time;
    /* derived from the parameters when initialization ends (parameters are fixed then) */
    double inv_JL;
    int has_backlash, has_gravity;
    ModelPhase phase;
    char msg[512]; /* last error message */
} Model;

/* Back to the state after instantiation: default parameters, start values, phase PHASE_INSTANTIATED. */
void model_reset(Model *m);
/* Release what the model allocated (nothing: the interface is that of ../motor). */
void model_free(Model *m);
/* dst := src, a full copy.  Never fails (MODEL_OK). */
ModelStatus model_copy(Model *dst, const Model *src);

ModelStatus model_get_real(Model *m, unsigned vr, double *value);
ModelStatus model_set_real(Model *m, unsigned vr, double value);
ModelStatus model_get_integer(Model *m, unsigned vr, int *value);
ModelStatus model_set_integer(Model *m, unsigned vr, int value);
/* The order-th time derivative of a Real input, for the next step only (FMI 2 input interpolation): order 1
 * is used; higher orders are ignored with MODEL_WARNING (the input is then interpolated linearly). */
ModelStatus model_set_input_derivative(Model *m, unsigned vr, int order, double value);

ModelStatus model_enter_initialization(Model *m, double start_time);
/* Validates the parameters; the model then accepts doStep. */
ModelStatus model_exit_initialization(Model *m);
/* Integrates from t to t + h (h >= 0); t must equal the end of the previous step. */
ModelStatus model_do_step(Model *m, double t, double h);
ModelStatus model_terminate(Model *m);

/* Name of the variable with this value reference, or NULL. */
const char *model_variable_name(unsigned vr);

#endif
