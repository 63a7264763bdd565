/*
 * loop_a: a test FMU of cosim's (tests/fmus, not shipped), one half of an algebraic loop (issue 40); the model
 * core shared by the FMI 2.0 and FMI 3.0 wrappers (Co-Simulation only).
 *
 * A first-order lag x whose output passes its input straight through (direct feedthrough):
 *
 *   y = ka*u + x
 *   der(x) = (u - x)/tau
 *
 * doStep integrates x exactly for the input held over the step: x(t+h) = u + (x(t) - u)*exp(-h/tau).
 * y is computed when it is read, from the input set last: after setting u, reading y gives the output for the
 * new input at once (in Initialization Mode and at a communication point), and setting u never changes x.
 * Wired to loop_b (a.y -> b.u, b.y -> a.u), the two form an algebraic loop.
 *
 * The FMU can save and restore its state (canGetAndSetFMUstate): the wrappers copy the whole Model.
 * C99, libc/libm only; the core knows nothing about FMI.
 */
#ifndef LOOP_MODEL_H
#define LOOP_MODEL_H

#define MODEL_IDENTIFIER "loop_a"
/* Must equal guid (FMI 2) / instantiationToken (FMI 3) of the model descriptions. */
#define MODEL_GUID "{3b83cd6e-be91-4899-8651-feecea5fd363}"
/* 1: fmi2GetFMUstate/fmi3GetFMUState and their kin save and restore the Model; 0: they return an error. */
#define CAN_GET_AND_SET_FMU_STATE 1

/* Value references: identical in modelDescription.xml and modelDescription3.xml (FMI 2 index = vr + 1). */
enum {
    VR_TIME = 0,
    VR_U = 1,     /* input */
    VR_Y = 2,     /* output: ka*u + x */
    VR_X = 3,     /* state (local, start value x0) */
    VR_DER_X = 4, /* (u - x)/tau */
    VR_KA = 5,
    VR_TAU = 6,
    VR_STEADY = 7, /* parameter: 1 starts x at its input's value at the end of initialization (steady state) */
    VR_COUNT = 8
};

typedef enum {
    PHASE_INSTANTIATED = 0, /* after instantiation or reset */
    PHASE_INITIALIZATION,   /* between Enter- and ExitInitializationMode */
    PHASE_STEPPING,         /* after ExitInitializationMode */
    PHASE_TERMINATED
} ModelPhase;

typedef enum { MODEL_OK = 0, MODEL_ERROR = 1 } ModelStatus;

/* Plain data, no pointers: an FMU state is a copy of it. */
typedef struct {
    double ka, tau, steady; /* parameters */
    double u;       /* input */
    double x;       /* state */
    double time;
    ModelPhase phase;
    char msg[256]; /* last error message */
} Model;

void model_reset(Model *m);
ModelStatus model_get_real(Model *m, unsigned vr, double *value);
ModelStatus model_set_real(Model *m, unsigned vr, double value);
ModelStatus model_enter_initialization(Model *m, double start_time);
ModelStatus model_exit_initialization(Model *m);
/* Co-simulation: from t to t + h with u held; t must equal the end of the previous step. */
ModelStatus model_do_step(Model *m, double t, double h);

#endif
