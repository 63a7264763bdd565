/*
 * two_mass_servo: model core shared by the FMI 2.0 and FMI 3.0 wrappers.
 *
 * Azimuth axis of a telescope as a two-mass system (motor side and load side
 * coupled by a torsional spring and damper) with optional nonlinear effects
 * (friction, backlash, cogging, torque saturation, gravity unbalance, torque
 * offset, input delay).  Fixed-step RK4, nsub substeps per communication step.
 * See README.md for the equations, units and parameter defaults.
 *
 * C99, libc/libm only.  The core knows nothing about FMI: it stores values by
 * value reference, checks in which phase a value may be set, validates the
 * parameters and integrates.  On failure a function returns MODEL_ERROR and
 * leaves a one-line message in Model.msg for the wrapper to log.
 */
#ifndef TWO_MASS_SERVO_MODEL_H
#define TWO_MASS_SERVO_MODEL_H

#include <stddef.h>

#define MODEL_IDENTIFIER "two_mass_servo"
/* Must equal guid (FMI 2) / instantiationToken (FMI 3) of the model descriptions. */
#define MODEL_GUID "{d3f2a102-347b-4bb6-aa33-214f87a55820}"

/* Value references: identical in modelDescription.xml and modelDescription3.xml.
 * FMI 2 index (1-based position in ModelVariables) = value reference + 1. */
enum {
    VR_TIME = 0,
    VR_TM = 1,
    VR_TL = 2,
    VR_THETA_M = 3,
    VR_OMEGA_M = 4,
    VR_THETA_L = 5,
    VR_OMEGA_L = 6,
    VR_DER_THETA_M = 7,
    VR_DER_OMEGA_M = 8,
    VR_DER_THETA_L = 9,
    VR_DER_OMEGA_L = 10,
    VR_JM = 11,
    VR_JL = 12,
    VR_KL = 13,
    VR_BM = 14,
    VR_BL = 15,
    VR_FC = 16,
    VR_FS = 17,
    VR_VS = 18,
    VR_VSMOOTH = 19,
    VR_BM_ASYM = 20,
    VR_BACKLASH = 21,
    VR_TCOG = 22,
    VR_TMAX = 23,
    VR_MGL = 24,
    VR_TOFFSET = 25,
    VR_DELAY = 26,
    VR_NCOG = 27, /* Integer */
    VR_NSUB = 28, /* Integer */
    VR_COUNT = 29
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

typedef enum { MODEL_OK = 0, MODEL_ERROR = 1 } ModelStatus;

/* History of (communication time, Tm) pairs for the input delay: a growable
 * ring buffer, entries in increasing time. */
typedef struct {
    double *t;
    double *u;
    size_t head;
    size_t count;
    size_t cap;
} TmHistory;

typedef struct {
    /* parameters (SI units) */
    double Jm, JL, KL, Bm, BL;
    double Fc, Fs, vs, vsmooth, Bm_asym;
    double backlash, Tcog, Tmax, mgl, Toffset, delay;
    int ncog, nsub;
    /* inputs, held constant over a communication step */
    double Tm, TL;
    /* state x = [theta_m, omega_m, theta_L, omega_L] */
    double x[4];
    /* time: start time before initialization, then the end of the last step */
    double time;
    /* Tm at the end of initialization: the applied torque before any delayed input */
    double Tm_init;
    TmHistory hist;
    /* derived from the parameters when initialization ends (parameters are fixed then) */
    double inv_Jm, inv_JL, inv_vsmooth, inv_vs;
    int has_friction, has_stribeck, has_backlash, has_cogging, has_gravity;
    ModelPhase phase;
    char msg[512]; /* last error message */
} Model;

/* Back to the state after instantiation: default parameters, start values,
 * phase PHASE_INSTANTIATED, empty history (the buffer is kept). */
void model_reset(Model *m);
/* Release the history buffer (the Model itself belongs to the caller). */
void model_free(Model *m);

ModelStatus model_get_real(Model *m, unsigned vr, double *value);
ModelStatus model_set_real(Model *m, unsigned vr, double value);
ModelStatus model_get_integer(Model *m, unsigned vr, int *value);
ModelStatus model_set_integer(Model *m, unsigned vr, int value);

ModelStatus model_enter_initialization(Model *m, double start_time);
/* Validates the parameters; the model then accepts doStep. */
ModelStatus model_exit_initialization(Model *m);
/* Integrates from t to t + h (h >= 0) with inputs held; t must equal the end of the previous step. */
ModelStatus model_do_step(Model *m, double t, double h);
ModelStatus model_terminate(Model *m);

/* Name of the variable with this value reference, or NULL. */
const char *model_variable_name(unsigned vr);

#endif
