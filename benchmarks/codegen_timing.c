/*
 * codegen_timing.c: times a generated czmpc step and its bare OSQP solve, no Python in
 * the loop (benchmarks/codegen_step.py builds and runs it; issue 42, item 5).
 *
 * Built in a directory written by `czmpc codegen`, against its libczmpc.a, with the
 * flags of that directory's Makefile (benchmarks/codegen_timing.mk):
 *
 *     make -C DIR -f Makefile -f .../codegen_timing.mk codegen_timing HARNESS=.../codegen_timing.c
 *     DIR/codegen_timing INPUTS [QP_OUT|-] [ROUNDS]
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
 *         call (not timed), the QP vectors the step sent to OSQP (q, l, u) and whether
 *         the solver was to cold-start are kept; they are the state's own (czmpc_state:
 *         q, l, u, needs_cold_start), read here because no public call hands them out.
 *         Later rounds must compute round 1's TRIAC outputs bit for bit (else exit 4).
 *   bare  czmpc_init_at again (OSQP's workspace as at the start), then for every step
 *         that solved a QP exactly what the step's solve stage calls:
 *         osqp_update_data_vec(q, l, u), osqp_cold_start where the step cold-started,
 *         osqp_solve. The same QPs from the same warm starts: the same iterations.
 * Then once:
 *   cap   the QP that took the most iterations, solved REPEATS_CAP times from a cold
 *         start with eps_abs = eps_rel = 0, so that only the iteration cap (the
 *         settings' max_iter) stops OSQP: what a worst-case solve costs.
 *
 * Output on stdout, CSV:
 *     # sizeof_state=B sizeof_real=B n_steps=N max_iter=M rounds=R
 *     phase,round,k,triac_pct,n_iterations,status_val,elapsed_ns
 * one "step" line per step and round (TRIAC [%] printed with 17 digits), one "bare"
 * line per solved QP and round, REPEATS_CAP "cap" lines. QP_OUT ("-": none): per step,
 * q (CZMPC_NVAR), l and u (CZMPC_NCON each) as czmpc_real in native byte order.
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
#include "osqp.h"
#include "czmpc_qp_workspace.h"

#define INPUTS_MAGIC "czmpc-timing-inputs/1"
#define REPEATS_CAP 5
#define QP_LEN (CZMPC_NVAR + 2 * CZMPC_NCON)

/* Large: static, not on the stack. */
static czmpc_state state;

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

int main(int argc, char **argv)
{
    FILE *f;
    char magic[64];
    double value, initial_triac_pct;
    long n, k, worst_k = -1;
    int i, r, rc, rounds, worst_iter = -1;
    const char *qp_out;
    czmpc_inputs *inputs;
    czmpc_real *previews, *qp, *triac;
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

    printf("# sizeof_state=%lu sizeof_real=%lu n_steps=%ld max_iter=%ld rounds=%d\n",
           czmpc_sizeof_state(), czmpc_sizeof_real(), n, (long)czmpc_qp_solver.settings->max_iter,
           rounds);
    printf("phase,round,k,triac_pct,n_iterations,status_val,elapsed_ns\n");

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
            printf("step,%d,%ld,%.17g,%d,%d,%lld\n", r, k, (double)u, out.n_iterations,
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
        if (czmpc_init_at(&state, (czmpc_real)initial_triac_pct) != CZMPC_OK) return 3;
        for (k = 0; k < n; ++k) {
            const czmpc_real *v = &qp[k * QP_LEN];
            long long t0, t1;
            if (status[k] <= 0) continue;   /* skipped or non-finite data: no solve */
            t0 = now_ns();
            (void)osqp_update_data_vec(&czmpc_qp_solver, v, v + CZMPC_NVAR,
                                       v + CZMPC_NVAR + CZMPC_NCON);
            if (cold[k]) osqp_cold_start(&czmpc_qp_solver);
            (void)osqp_solve(&czmpc_qp_solver);
            t1 = now_ns();
            printf("bare,%d,%ld,,%ld,%ld,%lld\n", r, k, (long)czmpc_qp_solver.info->iter,
                   (long)czmpc_qp_solver.info->status_val, t1 - t0);
        }
    }

    /* cap: the hardest QP of the run, stopped by the iteration cap alone */
    if (worst_k >= 0) {
        const czmpc_real *v = &qp[worst_k * QP_LEN];
        OSQPSettings *st = czmpc_qp_solver.settings;
        const OSQPFloat eps_abs = st->eps_abs, eps_rel = st->eps_rel;
        st->eps_abs = 0;
        st->eps_rel = 0;
        for (i = 0; i < REPEATS_CAP; ++i) {
            long long t0, t1;
            t0 = now_ns();
            (void)osqp_update_data_vec(&czmpc_qp_solver, v, v + CZMPC_NVAR,
                                       v + CZMPC_NVAR + CZMPC_NCON);
            osqp_cold_start(&czmpc_qp_solver);
            (void)osqp_solve(&czmpc_qp_solver);
            t1 = now_ns();
            printf("cap,0,%ld,,%ld,%ld,%lld\n", worst_k, (long)czmpc_qp_solver.info->iter,
                   (long)czmpc_qp_solver.info->status_val, t1 - t0);
        }
        st->eps_abs = eps_abs;
        st->eps_rel = eps_rel;
    }
    free(inputs);
    free(previews);
    free(qp);
    free(cold);
    free(status);
    free(triac);
    return 0;
}
