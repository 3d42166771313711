/*
 * czmpc_example.c: try the generated step before integrating it.
 *
 * Reads one sample per line on stdin:
 *
 *     power_kw,setpoint_kw[,grid_voltage_factor[,applied_triac_pct[,preview_kw...]]]
 *
 * ("nan" for a missing value; lines starting with '#' are skipped) and writes one line
 * per step on stdout:
 *
 *     triac_pct,mode,status,fallback,n_iterations,solver_status
 *
 * the first field being the TRIAC input [%] to apply (17 significant digits: the exact
 * double). Optional: argv[1] the initial TRIAC input [%] (bumpless start).
 *
 *     make && printf '45.0,46.0\n45.2,46.0\nnan,46.0\n' | ./example
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "czmpc_step.h"

#define MAX_LINE 65536

static czmpc_state state;   /* the whole controller: static, no heap */
static czmpc_real preview[CZMPC_N];
static char line[MAX_LINE];

static const char *const MODES[] = {"off", "predict", "on"};
static const char *const STATUSES[] = {"good", "predicted", "clamped", "held", "shed"};
static const char *const FALLBACKS[] = {"none", "shifted_plan", "target"};

/* The next comma-separated number of *cursor (strtod reads "nan" and "inf"); NaN for an
   empty field; *ok = 0 when there is no field left. */
static double next_field(char **cursor, int *ok)
{
    char *end;
    double v;
    if (*cursor == NULL) {
        *ok = 0;
        return 0.0;
    }
    *ok = 1;
    v = strtod(*cursor, &end);
    if (end == *cursor) v = (double)NAN;
    end = strchr(*cursor, ',');
    *cursor = end ? end + 1 : NULL;
    return v;
}

int main(int argc, char **argv)
{
    czmpc_outputs out;
    long line_no = 0;
    if (argc > 1) {
        int rc = czmpc_init_at(&state, (czmpc_real)strtod(argv[1], NULL));
        if (rc == CZMPC_ERR_RANGE) {
            fprintf(stderr, "example: initial TRIAC input must lie in [%g, %g] %%; got %s\n",
                    (double)CZMPC_ALLOWED_TRIAC_MIN_PCT, (double)CZMPC_ALLOWED_TRIAC_MAX_PCT,
                    argv[1]);
            return 2;
        }
        if (rc != CZMPC_OK) {
            fprintf(stderr, "example: the QP solver could not be set up (code %d)\n", rc);
            return 2;
        }
    } else if (czmpc_init(&state) != CZMPC_OK) {
        fprintf(stderr, "example: the QP solver could not be set up\n");
        return 2;
    }
    while (fgets(line, sizeof line, stdin) != NULL) {
        char *cursor = line;
        czmpc_inputs in;
        double power, setpoint, value;
        int ok, n = 0;
        czmpc_real u;
        line_no++;
        if (line[0] == '#' || line[0] == '\n' || line[0] == '\r') continue;
        power = next_field(&cursor, &ok);
        setpoint = next_field(&cursor, &ok);
        if (!ok) {
            fprintf(stderr, "example: line %ld: expected power_kw,setpoint_kw; got %s", line_no, line);
            return 2;
        }
        in = czmpc_inputs_default((czmpc_real)power, (czmpc_real)setpoint);
        value = next_field(&cursor, &ok);
        if (ok) in.grid_voltage_factor = (czmpc_real)value;
        value = next_field(&cursor, &ok);
        if (ok) in.applied_triac_pct = (czmpc_real)value;
        while (n < CZMPC_N) {
            value = next_field(&cursor, &ok);
            if (!ok) break;
            preview[n++] = (czmpc_real)value;
        }
        in.setpoint_preview_kw = n ? preview : NULL;
        in.n_preview = n;
        u = czmpc_step(&state, &in, &out);
        printf("%.17g,%s,%s,%s,%d,%s\n", (double)u, MODES[out.mode], STATUSES[out.status],
               FALLBACKS[out.fallback], out.n_iterations, out.solver_status);
    }
    return 0;
}
