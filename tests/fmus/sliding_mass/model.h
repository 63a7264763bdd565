/*
 * sliding_mass: a test FMU of cosim's (tests/fmus, not shipped), the model core shared by the FMI 2.0 and
 * FMI 3.0 wrappers.
 *
 * A mass on a spring, with viscous and (smoothed) Coulomb friction, pushed by one force F that two inputs
 * reach: `extForce` (the model's top-level input) and `force.f` (the input connector of the force component it
 * is connected to), as Dymola 2023x exports such a Modelica model. Writing either input sets F, so the input
 * set last wins; reading either gives F. An importer that sets `force.f` to its start value at every step
 * (nobody drives it) therefore overrides `extForce`: cosim before issue 38 did, FMPy does not.
 *
 *   der(mass.s) = mass.v
 *   m*der(mass.v) = F - k*mass.s - d*mass.v - Fc*tanh(mass.v/vs)
 *
 * Co-simulation: fixed-step RK4, SUBSTEPS per communication step. Model Exchange: the importer integrates the
 * two states (no events). C99, libc/libm only; the core knows nothing about FMI.
 */
#ifndef SLIDING_MASS_MODEL_H
#define SLIDING_MASS_MODEL_H

#define MODEL_IDENTIFIER "sliding_mass"
/* Must equal guid (FMI 2) / instantiationToken (FMI 3) of the model descriptions. */
#define MODEL_GUID "{5d1c3a0e-9b7f-4c2e-8a41-0f6e2d9b7c13}"
#define SUBSTEPS 10

/* Value references: identical in modelDescription.xml and modelDescription3.xml (FMI 2 index = vr + 1). */
enum {
    VR_TIME = 0,
    VR_EXTFORCE = 1, /* input */
    VR_FORCE_F = 2,  /* input: the same force */
    VR_S = 3,        /* mass.s, state */
    VR_V = 4,        /* mass.v, state */
    VR_DER_S = 5,
    VR_DER_V = 6,
    VR_M = 7,
    VR_K = 8,
    VR_D = 9,
    VR_FC = 10,
    VR_VS = 11,
    VR_POSITION = 12, /* output: mass.s, as a position sensor gives it */
    VR_COUNT = 13
};

typedef enum {
    PHASE_INSTANTIATED = 0, /* after instantiation or reset */
    PHASE_INITIALIZATION,   /* between Enter- and ExitInitializationMode */
    PHASE_STEPPING,         /* after ExitInitializationMode */
    PHASE_TERMINATED
} ModelPhase;

typedef enum { MODEL_OK = 0, MODEL_ERROR = 1 } ModelStatus;

typedef struct {
    double m, k, d, Fc, vs; /* parameters (SI units) */
    double F;               /* the one force both inputs write */
    double x[2];            /* mass.s, mass.v */
    double time;
    ModelPhase phase;
    char msg[256]; /* last error message */
} Model;

void model_reset(Model *m);
ModelStatus model_get_real(Model *m, unsigned vr, double *value);
ModelStatus model_set_real(Model *m, unsigned vr, double value);
ModelStatus model_enter_initialization(Model *m, double start_time);
ModelStatus model_exit_initialization(Model *m);
/* Co-simulation: integrates from t to t + h with F held; t must equal the end of the previous step. */
ModelStatus model_do_step(Model *m, double t, double h);
/* Model Exchange: the derivatives of the states x. */
void model_derivatives(const Model *m, const double x[2], double dx[2]);

#endif
