/*
 * loop_b_nostate: a test FMU of cosim's (tests/fmus, not shipped): tests/fmus/loop_b (see its model.h for the
 * equations, y = kb*u + c*sin(w*t) with direct feedthrough) that cannot save and restore its state
 * (canGetAndSetFMUstate false; CAN_GET_AND_SET_FMU_STATE 0 makes the wrappers' FMU state functions return an
 * error), so a master cannot iterate an algebraic loop through it (issue 40). The two folders differ in this
 * file (identifier, GUID, the flag) and the model descriptions only: model.c, fmi2.c and fmi3.c are loop_b's.
 * C99, libc/libm only; the core knows nothing about FMI.
 */
#ifndef LOOP_MODEL_H
#define LOOP_MODEL_H

#define MODEL_IDENTIFIER "loop_b_nostate"
/* Must equal guid (FMI 2) / instantiationToken (FMI 3) of the model descriptions. */
#define MODEL_GUID "{24a16ad4-0708-44eb-ab9d-67bab48e6bce}"
/* 1: fmi2GetFMUstate/fmi3GetFMUState and their kin save and restore the Model; 0: they return an error. */
#define CAN_GET_AND_SET_FMU_STATE 0

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
