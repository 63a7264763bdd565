/* The system master's communication steps in C (cosim.plant.system_plant, engine "c").
 *
 * The same arithmetic, in the same order, as the Python master of system_plant.py (SystemPlant._step_python):
 * the two give the same bits, which tests/test_system.py checks. Written by hand because no co-simulation
 * library on the package index runs a Jacobi or Gauss-Seidel master with input extrapolation over FMUs loaded
 * by another library (libcosim loads its own; FMPy's container FMU is a separate FMU): here the FMUs stay the
 * FmuPlant instances Python opened, and only their set/doStep/get function pointers are called.
 */
#include <stddef.h>
#include <stdbool.h>
#include <math.h>

typedef int (*set2_t)(void *, const unsigned int *, size_t, const double *);
typedef int (*get2_t)(void *, const unsigned int *, size_t, double *);
typedef int (*step2_t)(void *, double, double, int);
typedef int (*set3_t)(void *, const unsigned int *, size_t, const double *, size_t);
typedef int (*get3_t)(void *, const unsigned int *, size_t, double *, size_t);
typedef int (*step3_t)(void *, double, double, bool, bool *, bool *, bool *, double *);

typedef struct {
    int version, n_in, n_out, multiple, feedthrough, n_hist;
    long k;                       /* the component's own steps since t0 */
    double dt;                    /* its step: multiple * the master's (as Python computes it) */
    void *instance, *set, *get, *step;
    const unsigned int *in_vr, *out_vr;
    double *u, *y;                /* inputs set last, newest outputs */
    double *hist_t, *hist_y;      /* the last 3 communication points, oldest first: 3 and 3 * n_out */
    const int *src_kind, *src_comp, *src_index;   /* per input: 0 free (index into u_free), 1 a link */
    const double *src_factor, *src_offset;
    bool terminated, early;       /* FMI 3: the FMU asked to end the simulation; it returned early */
    double last_time;             /* FMI 3: its last successful time */
    int pre;                      /* an output answers a free input at once: settled before each step */
    const int *src_hold;          /* per input: its source is held (a discrete output), not extrapolated */
} Comp;

typedef struct {
    int n, jacobi, extrapolation;
    long k;
    double t0, dt;
    Comp *comps;
    const int *order, *settle;    /* the stepping order; the wiring's order, for the consistency pass */
    int failed_comp, failed_call; /* 0 set, 1 doStep, 2 get */
    int status;
    double failed_time;
} Master;

static int set_inputs(Comp *c, const double *u) {
    if (c->n_in == 0) return 0;
    if (c->version == 2) return ((set2_t)c->set)(c->instance, c->in_vr, (size_t)c->n_in, u);
    return ((set3_t)c->set)(c->instance, c->in_vr, (size_t)c->n_in, u, (size_t)c->n_in);
}

static int get_outputs(Comp *c) {
    if (c->n_out == 0) return 0;
    if (c->version == 2) return ((get2_t)c->get)(c->instance, c->out_vr, (size_t)c->n_out, c->y);
    return ((get3_t)c->get)(c->instance, c->out_vr, (size_t)c->n_out, c->y, (size_t)c->n_out);
}

/* The value a source gives an input: SystemPlant._input_values, one input. */
static double input_value(const Master *m, const Comp *c, int i, const double *u_free, double t, double h,
                          int at_end) {
    double value;
    if (c->src_kind[i] == 0) return u_free[c->src_index[i]];
    const Comp *s = &m->comps[c->src_comp[i]];
    int index = c->src_index[i], p = m->extrapolation;
    if (c->src_hold[i] && !at_end) {  /* a discrete signal: its value at the step's start */
        int a = s->n_hist - 1;
        while (a > 0 && s->hist_t[a] > t) a--;
        value = s->hist_y[a * s->n_out + index];
    } else if (at_end || p == 0) {
        value = (at_end || !m->jacobi) ? s->y[index] : s->hist_y[(s->n_hist - 1) * s->n_out + index];
    } else {
        int count = s->n_hist < p + 1 ? s->n_hist : p + 1, first = s->n_hist - count;
        if (count == 1) {
            value = s->hist_y[first * s->n_out + index];
        } else {
            double at = t + 0.5 * h;
            value = 0.0;
            for (int a = 0; a < count; a++) {
                double w = 1.0, ta = s->hist_t[first + a];
                for (int b = 0; b < count; b++)
                    if (b != a) w *= (at - s->hist_t[first + b]) / (ta - s->hist_t[first + b]);
                value += w * s->hist_y[(first + a) * s->n_out + index];
            }
        }
    }
    return c->src_factor[i] * value + c->src_offset[i];
}

static void push(Comp *c, double t_end) {
    if (c->n_hist == 3) {
        for (int a = 0; a < 2; a++) {
            c->hist_t[a] = c->hist_t[a + 1];
            for (int j = 0; j < c->n_out; j++) c->hist_y[a * c->n_out + j] = c->hist_y[(a + 1) * c->n_out + j];
        }
        c->n_hist = 2;
    }
    c->hist_t[c->n_hist] = t_end;
    for (int j = 0; j < c->n_out; j++) c->hist_y[c->n_hist * c->n_out + j] = c->y[j];
    c->n_hist++;
}

static int fail(Master *m, int comp, int call, int status, double t) {
    m->failed_comp = comp;
    m->failed_call = call;
    m->status = status;
    m->failed_time = t;
    return -1;
}

/* The consistency pass: components with direct feedthrough given their inputs' newest values, read again
 * (`pre`: only those answering a free input at once, before a step). */
static int settle(Master *m, const double *u_free, int pre) {
    for (int a = 0; a < m->n; a++) {
        int ci = m->settle[a];
        Comp *c = &m->comps[ci];
        if (pre ? !c->pre : !c->feedthrough) continue;
        for (int i = 0; i < c->n_in; i++) c->u[i] = input_value(m, c, i, u_free, 0.0, 0.0, 1);
        int status = set_inputs(c, c->u);
        if (status > 1) return fail(m, ci, 0, status, m->t0 + m->k * m->dt);
        status = get_outputs(c);
        if (status > 1) return fail(m, ci, 2, status, m->t0 + m->k * m->dt);
    }
    return 0;
}

/* One communication step (SystemPlant._step_python); 0, or -1 with the failure in m->failed_*. Outputs are read
 * from the components' y by the caller. */
static int master_step(Master *m, const double *u_free) {
    long k = m->k;
    double t = m->t0 + k * m->dt;
    int any_pre = 0;
    for (int a = 0; a < m->n; a++) any_pre |= m->comps[a].pre;
    if (any_pre) {  /* step()'s inputs hold from t: what answers them at once, answers now */
        if (settle(m, u_free, 1)) return -1;
        for (int a = 0; a < m->n; a++) {
            Comp *c = &m->comps[a];
            if (c->pre && c->hist_t[c->n_hist - 1] == t)
                for (int j = 0; j < c->n_out; j++) c->hist_y[(c->n_hist - 1) * c->n_out + j] = c->y[j];
        }
    }
    for (int a = 0; a < m->n; a++) {
        int ci = m->order[a];
        Comp *c = &m->comps[ci];
        if (k % c->multiple) continue;
        double h = (m->t0 + (k + c->multiple) * m->dt) - t;
        for (int i = 0; i < c->n_in; i++) {
            c->u[i] = input_value(m, c, i, u_free, t, h, 0);
            if (!isfinite(c->u[i])) return fail(m, ci, 0, -2, t);
        }
        int status = set_inputs(c, c->u);
        if (status > 1) return fail(m, ci, 0, status, t);
        double tc = m->t0 + c->k * c->dt, hc = (m->t0 + (c->k + 1) * c->dt) - tc;
        if (c->version == 2) {
            status = ((step2_t)c->step)(c->instance, tc, hc, 1);
        } else {
            bool event = false;
            c->terminated = c->early = false;
            status = ((step3_t)c->step)(c->instance, tc, hc, true, &event, &c->terminated, &c->early,
                                        &c->last_time);
        }
        if (status > 1 || c->terminated) return fail(m, ci, 1, status, tc);
        c->k++;
        status = get_outputs(c);
        if (status > 1) return fail(m, ci, 2, status, tc + hc);
        if (!m->jacobi) push(c, m->t0 + (k + c->multiple) * m->dt);
    }
    if (m->jacobi)
        for (int a = 0; a < m->n; a++) {
            Comp *c = &m->comps[m->order[a]];
            if (k % c->multiple == 0) push(c, m->t0 + (k + c->multiple) * m->dt);
        }
    m->k = k + 1;
    if (settle(m, u_free, 0)) return -1;
    for (int a = 0; a < m->n; a++) {  /* the settled values are the history's newest */
        Comp *c = &m->comps[m->order[a]];
        if (k % c->multiple == 0)
            for (int j = 0; j < c->n_out; j++) c->hist_y[(c->n_hist - 1) * c->n_out + j] = c->y[j];
    }
    return 0;
}

/* `steps` communication steps: u_free row by row (n_free each), the picked outputs after each into y_out
 * (n_pick each: component and output index). Returns the steps done; fewer when one failed. */
long cosim_master_run(Master *m, long steps, const double *u_free, int n_free, double *y_out, int n_pick,
                      const int *pick_comp, const int *pick_index) {
    for (long s = 0; s < steps; s++) {
        if (master_step(m, u_free + s * n_free)) return s;
        for (int j = 0; j < n_pick; j++) y_out[s * n_pick + j] = m->comps[pick_comp[j]].y[pick_index[j]];
    }
    return steps;
}
