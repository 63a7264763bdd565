/*
 * loop_b: a test FMU of cosim's (tests/fmus, not shipped), the other half of loop_a's algebraic loop (issue 40);
 * the model core shared by the FMI 2.0 and FMI 3.0 wrappers (Co-Simulation only).
 *
 * A gain with a time-varying offset, its output passing its input straight through (direct feedthrough):
 *
 *   y = kb*u + c*sin(w*t)
 *
 * where t is the FMU's time: the start time in Initialization Mode and after it, the step's end after doStep.
 * y is computed when it is read, from the input set last: after setting u, reading y gives the output for the
 * new input at once (in Initialization Mode and at a communication point). No state but time.
 *
 * tests/fmus/loop_b_nostate is this model with CAN_GET_AND_SET_FMU_STATE 0 (and its own identifier and GUID):
 * the two folders differ in model.h and the model descriptions only.
 * C99, libc/libm only; the core knows nothing about FMI.
 */
#ifndef LOOP_MODEL_H
#define LOOP_MODEL_H

#define MODEL_IDENTIFIER "loop_b"
/* Must equal guid (FMI 2) / instantiationToken (FMI 3) of the model descriptions. */
#define MODEL_GUID "{d3cab8bd-96b9-47bf-9e69-7f71bb8644f4}"
/* 1: fmi2GetFMUstate/fmi3GetFMUState and their kin save and restore the Model; 0: they return an error. */
#define CAN_GET_AND_SET_FMU_STATE 1

/* Value references: identical in modelDescription.xml and modelDescription3.xml (FMI 2 index = vr + 1). */
enum {
    VR_TIME = 0,
    VR_U = 1, /* input */
    VR_Y = 2, /* output: kb*u + c*sin(w*t) */
    VR_KB = 3,
    VR_C = 4,
    VR_W = 5,
    VR_COUNT = 6
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
    double kb, c, w; /* parameters */
    double u;        /* input */
    double time;
    ModelPhase phase;
    char msg[256]; /* last error message */
} Model;

void model_reset(Model *m);
ModelStatus model_get_real(Model *m, unsigned vr, double *value);
ModelStatus model_set_real(Model *m, unsigned vr, double value);
ModelStatus model_enter_initialization(Model *m, double start_time);
ModelStatus model_exit_initialization(Model *m);
/* Co-simulation: from t to t + h; t must equal the end of the previous step. */
ModelStatus model_do_step(Model *m, double t, double h);

#endif
