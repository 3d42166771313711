/*
 * codegen_timing.c: times a generated czmpc step and its bare solver, no Python in the
 * loop (benchmarks/codegen_step.py builds and runs it; issue 42, item 5).
 *
 * Built in a directory written by `czmpc codegen`, against its libczmpc.a, with the
 * flags of that directory's Makefile (benchmarks/codegen_timing.mk):
 *
 *     make -C DIR -f Makefile -f .../codegen_timing.mk codegen_timing HARNESS=.../codegen_timing.c
 *     DIR/codegen_timing INPUTS [QP_OUT|-] [ROUNDS]
 *
 * The solver is the directory's: OSQP's generated code, or DAQP's C where the step was
 * generated with solver = "daqp" (CZMPC_SOLVER_DAQP of its czmpc_model.h). Only the
 * bare solver (bare_setup, bare_solve, bare_result, cap_begin, cap_end) differs.
 *
 * INPUTS (text, written by the benchmark): a line "czmpc-timing-inputs/1", a line
 * "n_steps initial_triac_pct", then one line per step:
 *     power_kw setpoint_kw grid_voltage_factor n_preview preview_1 .. preview_n
 * (nan: a missing sample, no voltage reading). Numbers are read with strtod, so the
 * step gets the very doubles Python's controller got.
 *
 * ROUNDS (default 1) times two passes over the steps, alternating so that a change in
 * the machine's load falls on both; each call timed with clock_gettime(CLOCK_MONOTONIC):
 *   step  czmpc_init_at, then czmpc_step on every step's inputs. In round 1, after each
 *         call (not timed), the QP vectors the step sent to its solver (q, l, u), whether
 *         the solver was to cold-start and the plan it used (czmpc_planned_w) are kept;
 *         the vectors and the flag are the state's own (czmpc_state: q, l, u,
 *         needs_cold_start), read here because no public call hands them out. Later
 *         rounds must compute round 1's TRIAC outputs bit for bit (else exit 4).
 *   bare  the solver afresh as czmpc_init_at sets it up, then for every step that
 *         reached the solver exactly the solver calls of the step's solve stage:
 *         OSQP   osqp_update_data_vec(q, l, u), osqp_cold_start where the step
 *                cold-started, osqp_solve, on the generated workspace (czmpc_init_at
 *                sets it up again);
 *         DAQP   daqp_update_ldp of f = q, blower = l, bupper = u (and the working set
 *                cleared where the step cold-started), daqp_solve, on a DAQP workspace
 *                of this harness set up as czmpc_init sets up the step's: setup_daqp on
 *                the same H, rows, settings and initial vectors, in the same arena
 *                (czmpc_daqp_heap.c), which it holds until the next czmpc_init_at.
 *         The same QPs from the same warm starts: the same iterations and the same plan
 *         (its first N entries compared bit for bit with the step's, where it had one).
 * Then once:
 *   cap   the QP that took the most iterations, solved REPEATS_CAP times from a cold
 *         start: OSQP with eps_abs = eps_rel = 0, so that only the iteration cap (the
 *         settings' max_iter) stops it; DAQP from an empty working set (it stops at the
 *         optimum). What a worst-case solve costs.
 *
 * Output on stdout, CSV:
 *     # sizeof_state=B sizeof_real=B n_steps=N max_iter=M rounds=R solver=osqp|daqp
 *     phase,round,k,triac_pct,n_iterations,status_val,elapsed_ns,same_plan
 * one "step" line per step and round (TRIAC [%] printed with 17 digits), one "bare"
 * line per solved QP and round (same_plan: 1 or 0, empty where the step had no plan),
 * REPEATS_CAP "cap" lines. status_val is the step's solver_status_val (DAQP:
 * CZMPC_SOLVER_DAQP_EXIT(exitflag)). QP_OUT ("-": none): per step, q (CZMPC_NVAR), l
 * and u (CZMPC_NCON each) as czmpc_real in native byte order.
 *
 * Exit codes: 0 done; 2 bad arguments or inputs; 3 the solver could not be set up;
 * 4 a round computed other outputs than round 1.
 */
#define _POSIX_C_SOURCE 199309L

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "czmpc_step.h"

#define INPUTS_MAGIC "czmpc-timing-inputs/1"
#define REPEATS_CAP 5
#define QP_LEN (CZMPC_NVAR + 2 * CZMPC_NCON)

/* Large: static, not on the stack. */
static czmpc_state state;

/* What one bare solve gave. */
typedef struct {
    int n_iterations, status_val;
    const czmpc_real *x;    /* the solution, NULL if the solver did not run */
} bare_result_t;

#if CZMPC_SOLVER_DAQP
#include "api.h"
#include "utils.h"
#define CZMPC_MODEL_DATA    /* czmpc_daqp.h's H and rows, for this harness's own set-up */
#include "czmpc_daqp.h"
#include "czmpc_daqp_heap.h"

#define SOLVER_NAME "daqp"
#define MAX_ITER ((long)CZMPC_DAQP_ITER_LIMIT)

/* This harness's DAQP: its problem, workspace and last result, and the arrays they use. */
static struct {
    DAQPProblem qp;
    DAQPWorkspace work;
    DAQPSettings settings;
    DAQPResult res;
    double H[CZMPC_DAQP_N * CZMPC_DAQP_N];
    double A[(CZMPC_DAQP_M - CZMPC_DAQP_MS) * CZMPC_DAQP_N + 1];
    int sense[CZMPC_DAQP_M];
    double x[CZMPC_DAQP_N], lam[CZMPC_DAQP_M];
    int solved;    /* daqp_solve ran (daqp_update_ldp accepted the vectors) */
} bare;

/* After czmpc_init_at: DAQP set up as czmpc_step.c's qp_setup sets up the step's, from
   the vectors the step was set up with, in the arena (the step's workspace there is
   overwritten: czmpc_step must not run before the next czmpc_init_at). */
static int bare_setup(void)
{
    int flag;
    memcpy(bare.H, CZMPC_DAQP_H0, sizeof bare.H);
    memcpy(bare.A, CZMPC_DAQP_A0, sizeof bare.A);
    memset(bare.sense, 0, sizeof bare.sense);
    daqp_default_settings(&bare.settings);
    bare.settings.iter_limit = CZMPC_DAQP_ITER_LIMIT;
    bare.settings.primal_tol = CZMPC_DAQP_PRIMAL_TOL;
    memset(&bare.work, 0, sizeof bare.work);
    bare.work.settings = &bare.settings;
    bare.qp = (DAQPProblem){.n = CZMPC_DAQP_N, .m = CZMPC_DAQP_M, .ms = CZMPC_DAQP_MS,
                            .H = bare.H, .f = state.q, .A = bare.A, .bupper = state.u,
                            .blower = state.l, .sense = bare.sense};
    czmpc_daqp_arena_open();
    flag = setup_daqp(&bare.qp, &bare.work, NULL);
    czmpc_daqp_arena_seal();
    return flag >= 0 && czmpc_daqp_arena_refused() == 0;
}

/* The step's DAQP calls (czmpc_step.c, qp_solve) on v = [q; l; u]. */
static void bare_solve(czmpc_real *v, int cold)
{
    int mask = DAQP_UPDATE_v | DAQP_UPDATE_d, flag;
    bare.qp.f = v;
    bare.qp.blower = v + CZMPC_NVAR;
    bare.qp.bupper = v + CZMPC_NVAR + CZMPC_NCON;
    if (cold) {
        memset(bare.sense, 0, sizeof bare.sense);
        bare.qp.sense = bare.sense;
        mask |= DAQP_UPDATE_sense;
    }
    bare.res = (DAQPResult){.x = bare.x, .lam = bare.lam};
    flag = daqp_update_ldp(mask, &bare.work, &bare.qp);
    bare.solved = flag >= 0;
    if (bare.solved) {
        daqp_solve(&bare.res, &bare.work);
    } else {
        bare.res.exitflag = flag;
    }
}

static bare_result_t bare_result(void)
{
    bare_result_t r;
    r.n_iterations = bare.res.iter;
    r.status_val = CZMPC_SOLVER_DAQP_EXIT(bare.res.exitflag);
    r.x = bare.solved ? bare.x : NULL;
    return r;
}

static void cap_begin(void) {}
static void cap_end(void) {}

#else
#include "osqp.h"
#include "czmpc_qp_workspace.h"

#define SOLVER_NAME "osqp"
#define MAX_ITER ((long)czmpc_qp_solver.settings->max_iter)

static OSQPFloat saved_eps_abs, saved_eps_rel;

/* After czmpc_init_at: the generated workspace is set up afresh already. */
static int bare_setup(void) { return 1; }

/* The step's OSQP calls (czmpc_step.c, qp_solve) on v = [q; l; u]. */
static void bare_solve(czmpc_real *v, int cold)
{
    (void)osqp_update_data_vec(&czmpc_qp_solver, v, v + CZMPC_NVAR, v + CZMPC_NVAR + CZMPC_NCON);
    if (cold) osqp_cold_start(&czmpc_qp_solver);
    (void)osqp_solve(&czmpc_qp_solver);
}

static bare_result_t bare_result(void)
{
    bare_result_t r;
    r.n_iterations = (int)czmpc_qp_solver.info->iter;
    r.status_val = (int)czmpc_qp_solver.info->status_val;
    r.x = czmpc_qp_solver.solution->x;
    return r;
}

/* Only the iteration cap stops OSQP. */
static void cap_begin(void)
{
    OSQPSettings *st = czmpc_qp_solver.settings;
    saved_eps_abs = st->eps_abs;
    saved_eps_rel = st->eps_rel;
    st->eps_abs = 0;
    st->eps_rel = 0;
}

static void cap_end(void)
{
    czmpc_qp_solver.settings->eps_abs = saved_eps_abs;
    czmpc_qp_solver.settings->eps_rel = saved_eps_rel;
}
#endif

static long long now_ns(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (long long)t.tv_sec * 1000000000LL + (long long)t.tv_nsec;
}

static int read_number(FILE *f, double *value)
{
    char word[64];
    char *end;
    if (fscanf(f, "%63s", word) != 1) return 0;
    *value = strtod(word, &end);
    return *end == '\0';
}

static void *allocate(size_t n, size_t size)
{
    void *p = calloc(n > 0 ? n : 1, size);
    if (p == NULL) {
        fprintf(stderr, "codegen_timing: out of memory\n");
        exit(2);
    }
    return p;
}

/* "1" if x's first CZMPC_N entries are plan's bit for bit, "0" if not, "" if the step
   had no plan (not usable: NaN). */
static const char *same_plan(const czmpc_real *x, const czmpc_real *plan)
{
    if (isnan(plan[0])) return "";
    return x != NULL && memcmp(x, plan, CZMPC_N * sizeof *plan) == 0 ? "1" : "0";
}

int main(int argc, char **argv)
{
    FILE *f;
    char magic[64];
    double value, initial_triac_pct;
    long n, k, worst_k = -1;
    int i, r, rc, rounds, worst_iter = -1;
    const char *qp_out;
    czmpc_inputs *inputs;
    czmpc_real *previews, *qp, *triac, *plans;
    unsigned char *cold;
    int *status;
    czmpc_outputs out;

    if (argc < 2 || argc > 4 || (argc == 4 && !(atoi(argv[3]) >= 1))) {
        fprintf(stderr, "usage: codegen_timing INPUTS [QP_OUT|-] [ROUNDS >= 1]\n");
        return 2;
    }
    qp_out = argc >= 3 && strcmp(argv[2], "-") != 0 ? argv[2] : NULL;
    rounds = argc == 4 ? atoi(argv[3]) : 1;
    f = fopen(argv[1], "r");
    if (f == NULL) {
        fprintf(stderr, "codegen_timing: cannot open %s\n", argv[1]);
        return 2;
    }
    if (fscanf(f, "%63s", magic) != 1 || strcmp(magic, INPUTS_MAGIC) != 0
        || !read_number(f, &value) || !(value >= 1.0) || !read_number(f, &initial_triac_pct)) {
        fprintf(stderr, "codegen_timing: %s: expected '%s', then n_steps >= 1 and the initial "
                "TRIAC input\n", argv[1], INPUTS_MAGIC);
        return 2;
    }
    n = (long)value;
    inputs = allocate((size_t)n, sizeof *inputs);
    previews = allocate((size_t)n * CZMPC_N, sizeof *previews);
    qp = allocate((size_t)n * QP_LEN, sizeof *qp);
    plans = allocate((size_t)n * CZMPC_N, sizeof *plans);
    cold = allocate((size_t)n, 1);
    status = allocate((size_t)n, sizeof *status);
    triac = allocate((size_t)n, sizeof *triac);
    for (k = 0; k < n; ++k) {
        double power, setpoint, volts, n_preview;
        if (!read_number(f, &power) || !read_number(f, &setpoint) || !read_number(f, &volts)
            || !read_number(f, &n_preview) || !(n_preview >= 0.0 && n_preview <= CZMPC_N)) {
            fprintf(stderr, "codegen_timing: %s: step %ld: expected power setpoint voltage "
                    "n_preview (0..%d) preview...\n", argv[1], k, CZMPC_N);
            return 2;
        }
        inputs[k] = czmpc_inputs_default((czmpc_real)power, (czmpc_real)setpoint);
        inputs[k].grid_voltage_factor = (czmpc_real)volts;
        inputs[k].n_preview = (int)n_preview;
        for (i = 0; i < inputs[k].n_preview; ++i) {
            if (!read_number(f, &value)) {
                fprintf(stderr, "codegen_timing: %s: step %ld: preview entry %d missing\n",
                        argv[1], k, i + 1);
                return 2;
            }
            previews[k * CZMPC_N + i] = (czmpc_real)value;
        }
        inputs[k].setpoint_preview_kw = inputs[k].n_preview > 0 ? &previews[k * CZMPC_N] : NULL;
    }
    fclose(f);

    printf("# sizeof_state=%lu sizeof_real=%lu n_steps=%ld max_iter=%ld rounds=%d solver=%s\n",
           czmpc_sizeof_state(), czmpc_sizeof_real(), n, MAX_ITER, rounds, SOLVER_NAME);
    printf("phase,round,k,triac_pct,n_iterations,status_val,elapsed_ns,same_plan\n");

    for (r = 0; r < rounds; ++r) {
        /* step: the whole controller step */
        rc = czmpc_init_at(&state, (czmpc_real)initial_triac_pct);
        if (rc != CZMPC_OK) {
            fprintf(stderr, "codegen_timing: czmpc_init_at(%g) returned %d\n", initial_triac_pct,
                    rc);
            return rc == CZMPC_ERR_RANGE ? 2 : 3;
        }
        for (k = 0; k < n; ++k) {
            long long t0, t1;
            czmpc_real u;
            const int cold_now = state.needs_cold_start != 0;
            t0 = now_ns();
            u = czmpc_step(&state, &inputs[k], &out);
            t1 = now_ns();
            if (r == 0) {
                cold[k] = (unsigned char)cold_now;
                memcpy(&qp[k * QP_LEN], state.q, CZMPC_NVAR * sizeof(czmpc_real));
                memcpy(&qp[k * QP_LEN + CZMPC_NVAR], state.l, CZMPC_NCON * sizeof(czmpc_real));
                memcpy(&qp[k * QP_LEN + CZMPC_NVAR + CZMPC_NCON], state.u,
                       CZMPC_NCON * sizeof(czmpc_real));
                memcpy(&plans[k * CZMPC_N], czmpc_planned_w(&state), CZMPC_N * sizeof *plans);
                status[k] = out.solver_status_val;
                triac[k] = u;
                if (status[k] > 0 && out.n_iterations > worst_iter) {
                    worst_iter = out.n_iterations;
                    worst_k = k;
                }
            } else if (memcmp(&u, &triac[k], sizeof u) != 0) {
                fprintf(stderr, "codegen_timing: round %d, step %ld: TRIAC %.17g, round 1 "
                        "computed %.17g\n", r + 1, k, (double)u, (double)triac[k]);
                return 4;
            }
            printf("step,%d,%ld,%.17g,%d,%d,%lld,\n", r, k, (double)u, out.n_iterations,
                   out.solver_status_val, t1 - t0);
        }
        if (r == 0 && qp_out != NULL) {
            FILE *g = fopen(qp_out, "wb");
            if (g == NULL || fwrite(qp, sizeof *qp, (size_t)n * QP_LEN, g) != (size_t)n * QP_LEN) {
                fprintf(stderr, "codegen_timing: cannot write %s\n", qp_out);
                return 2;
            }
            fclose(g);
        }

        /* bare: the solver alone on the step's own QPs, in the same order */
        if (czmpc_init_at(&state, (czmpc_real)initial_triac_pct) != CZMPC_OK || !bare_setup()) {
            return 3;
        }
        for (k = 0; k < n; ++k) {
            bare_result_t b;
            long long t0, t1;
            if (status[k] <= 0) continue;   /* skipped or non-finite data: no solve */
            t0 = now_ns();
            bare_solve(&qp[k * QP_LEN], cold[k]);
            t1 = now_ns();
            b = bare_result();
            printf("bare,%d,%ld,,%d,%d,%lld,%s\n", r, k, b.n_iterations, b.status_val, t1 - t0,
                   same_plan(b.x, &plans[k * CZMPC_N]));
        }
    }

    /* cap: the hardest QP of the run from a cold start */
    if (worst_k >= 0) {
        cap_begin();
        for (i = 0; i < REPEATS_CAP; ++i) {
            bare_result_t b;
            long long t0, t1;
            t0 = now_ns();
            bare_solve(&qp[worst_k * QP_LEN], 1);
            t1 = now_ns();
            b = bare_result();
            printf("cap,0,%ld,,%d,%d,%lld,\n", worst_k, b.n_iterations, b.status_val, t1 - t0);
        }
        cap_end();
    }
    free(inputs);
    free(previews);
    free(qp);
    free(plans);
    free(cold);
    free(status);
    free(triac);
    return 0;
}
