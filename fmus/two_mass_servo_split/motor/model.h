/*
 * motor: the motor side of the two-mass servo (fmus/two_mass_servo) as an FMU of its own, the model core shared
 * by the FMI 2.0 and FMI 3.0 wrappers.
 *
 *   Jm*domega_m/dt = sat(Tm(t - delay)) + Toffset - Tf(omega_m) - Tcog*sin(ncog*theta_m) - Tc
 *   dtheta_m/dt    = omega_m
 *
 * Tc, the shaft torque acting on the motor, is an input (the shaft_load FMU computes it). The terms, the RK4
 * with nsub substeps and the input-delay history are those of the one-FMU servo; see ../README.md.
 *
 * C99, libc/libm only.  The core knows nothing about FMI; fmi2.c and fmi3.c are the same files in
 * ../shaft_load, written against the interface below (which both model.h declare alike).  On failure a function
 * returns MODEL_ERROR and leaves a one-line message in Model.msg for the wrapper to log.
 */
#ifndef MOTOR_MODEL_H
#define MOTOR_MODEL_H

#include <stddef.h>

#define MODEL_IDENTIFIER "motor"
/* Must equal guid (FMI 2) / instantiationToken (FMI 3) of the model descriptions. */
#define MODEL_GUID "{4dbe71bd-1fae-48a9-8542-f10d58fa1123}"
/* Marks an FMU state saved by this model (fmi2GetFMUstate / fmi3GetFMUState). */
#define MODEL_STATE_TAG 0x6d6f746fUL

/* Value references: identical in modelDescription.xml and modelDescription3.xml.
 * FMI 2 index (1-based position in ModelVariables) = value reference + 1. */
enum {
    VR_TIME = 0,
    VR_TM = 1,
    VR_TC = 2,
    VR_THETA_M = 3,
    VR_OMEGA_M = 4,
    VR_DER_THETA_M = 5,
    VR_DER_OMEGA_M = 6,
    VR_JM = 7,
    VR_BM = 8,
    VR_FC = 9,
    VR_FS = 10,
    VR_VS = 11,
    VR_VSMOOTH = 12,
    VR_BM_ASYM = 13,
    VR_TCOG = 14,
    VR_TMAX = 15,
    VR_TOFFSET = 16,
    VR_DELAY = 17,
    VR_NCOG = 18, /* Integer */
    VR_NSUB = 19, /* Integer */
    VR_COUNT = 20
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

/* History of (communication time, Tm, dTm/dt) for the input delay: a growable ring buffer, entries in
 * increasing time.  The slope is the FMI 2 input derivative of that step (0 when none was set). */
typedef struct {
    double *t;
    double *u;
    double *du;
    size_t head;
    size_t count;
    size_t cap;
} TmHistory;

typedef struct {
    /* parameters (SI units), names and defaults of the one-FMU servo */
    double Jm, Bm, Fc, Fs, vs, vsmooth, Bm_asym, Tcog, Tmax, Toffset, delay;
    int ncog, nsub;
    /* inputs at the communication point and their first time derivatives (FMI 2 input interpolation):
     * inside a step from t0 the input is u + du*(t - t0); du returns to 0 after each doStep */
    double Tm, Tc;
    double dTm, dTc;
    /* state x = [theta_m, omega_m] */
    double x[2];
    /* time: start time before initialization, then the end of the last step */
    double time;
    /* Tm at the end of initialization: the applied torque before any delayed input */
    double Tm_init;
    TmHistory hist;
    /* derived from the parameters when initialization ends (parameters are fixed then) */
    double inv_Jm, inv_vsmooth, inv_vs;
    int has_friction, has_stribeck, has_cogging;
    ModelPhase phase;
    char msg[512]; /* last error message */
} Model;

/* Back to the state after instantiation: default parameters, start values, phase PHASE_INSTANTIATED, empty
 * history (the buffers are kept). */
void model_reset(Model *m);
/* Release the history buffers (the Model itself belongs to the caller). */
void model_free(Model *m);
/* dst := src, a deep copy (the history too), reusing dst's buffers.  dst must be a Model that was reset or
 * copied into before, or zeroed memory.  On failure (out of memory) dst is unchanged. */
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
