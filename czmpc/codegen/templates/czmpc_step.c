/*
 * czmpc_step.c: the offset-free Hammerstein MPC step (czmpc.controller.OffsetFreeMPC).
 *
 * Each function is the C of one Python stage, named after it, with the same
 * arithmetic in the same order (build with -ffp-contract=off: a fused multiply-add
 * changes the results). Matrix-vector products sum in column order from the first
 * term (gemv), as the Python controller's do (czmpc.ordered), and OSQP's workspace is
 * set up again from the exact problem at init (qp_setup_exact): in double precision
 * the step is bit-equal to the Python controller's (tests/codegen).
 */
#define CZMPC_MODEL_DATA
#include "czmpc_step.h"

#include <math.h>

#if CZMPC_SOLVER_DAQP
/* DAQP (solver "daqp", czmpc.qp_daqp): its API and the problem's data */
#include "api.h"
#include "utils.h"
#include "czmpc_daqp.h"
#include "czmpc_daqp_heap.h"
#include <string.h>

/* DAQP's problem and workspace: static; the workspace's arrays come from the arena
   (czmpc_daqp_heap.c), filled by DAQP's setup_daqp at init. */
static DAQPProblem daqp_qp;
static DAQPWorkspace daqp_work;
static DAQPSettings daqp_settings;
static double daqp_H[CZMPC_DAQP_N * CZMPC_DAQP_N];
static double daqp_A[(CZMPC_DAQP_M - CZMPC_DAQP_MS) * CZMPC_DAQP_N + 1];
static int daqp_sense0[CZMPC_DAQP_M];
static double daqp_x[CZMPC_DAQP_N];
static double daqp_lam[CZMPC_DAQP_M];
#else
#include "osqp.h"
#include "czmpc_qp_workspace.h"
/* OSQP's private headers, for qp_setup_exact only */
#include "algebra_impl.h"
#include "auxil.h"
#include "scaling.h"
#include "types.h"
#endif

#ifdef CZMPC_FLOAT32
#define CZMPC_SQRT sqrtf
#define CZMPC_FABS fabsf
#else
#define CZMPC_SQRT sqrt
#define CZMPC_FABS fabs
#endif

#define ZERO ((czmpc_real)0)
#define ONE ((czmpc_real)1)

/* What the target stage hands on (czmpc.target.Target). */
typedef struct {
    czmpc_real x_s[CZMPC_NX];
    czmpc_real w_s, y_s, w_unclipped;
    int is_reachable;
} target_t;

/* What the QP stage hands on (czmpc.qp.QPSolution and OffsetFreeMPC._Plan). */
typedef struct {
    int usable, accurate, status_val, n_iterations;
    czmpc_real outside_bounds_kw, slack_kw;
    const czmpc_real *w;   /* the plan, or NULL when unusable */
    czmpc_real w0, w_lo0, w_hi0;
    int fallback, solver_shed;
} plan_t;

/* ---- small helpers (czmpc.inversion.clamp, Python's min and max) ---- */

static czmpc_real clamp(czmpc_real value, czmpc_real lo, czmpc_real hi)
{
    value = value > lo ? value : lo;
    return value < hi ? value : hi;
}

static czmpc_real py_min(czmpc_real a, czmpc_real b) { return b < a ? b : a; }
static czmpc_real py_max(czmpc_real a, czmpc_real b) { return b > a ? b : a; }

static int all_finite(const czmpc_real *v, int n)
{
    int i;
    for (i = 0; i < n; ++i) {
        if (!isfinite(v[i])) return 0;
    }
    return 1;
}

/* y = M x for a row-major (rows x cols) matrix, each row summed from its first term
   (czmpc.ordered.OrderedProduct: the Python controller's order). */
static void gemv(const czmpc_real *m, int rows, int cols, const czmpc_real *x, czmpc_real *y)
{
    int i, j;
    for (i = 0; i < rows; ++i) {
        czmpc_real acc = ZERO;
        const czmpc_real *row = m + (long)i * cols;
        for (j = 0; j < cols; ++j) acc += row[j] * x[j];
        y[i] = acc;
    }
}

static void copy_status(char *dst, const char *src)
{
    int i;
    for (i = 0; i < CZMPC_STATUS_CHARS - 1 && src[i] != '\0'; ++i) dst[i] = src[i];
    dst[i] = '\0';
}

/* ---- f and its inverse (czmpc.inversion) ---- */

static czmpc_real evaluate(const czmpc_real *c, czmpc_real ds)
{
    czmpc_real out = ZERO;
    int i;
    for (i = CZMPC_NC - 1; i >= 0; --i) out = (out + c[i]) * ds;
    return out;
}

#if CZMPC_NC > 2
static czmpc_real slope(const czmpc_real *c, czmpc_real ds)
{
    czmpc_real out = ZERO;
    int i;
    for (i = CZMPC_NC; i >= 1; --i) out = out * ds + (czmpc_real)i * c[i - 1];
    return out;
}
#endif

static void full_map(czmpc_map *m)
{
    int i;
    for (i = 0; i < CZMPC_NC; ++i) m->c[i] = CZMPC_COEF[i];
    m->ds_min = CZMPC_DS_MIN_PCT;
    m->ds_max = CZMPC_DS_MAX_PCT;
    m->w_min = CZMPC_W_MIN;
    m->w_max = CZMPC_W_MAX;
}

#if CZMPC_NC > 2
static czmpc_real newton_inverse(const czmpc_map *m, czmpc_real w)
{
    const czmpc_real *c = m->c;
    czmpc_real lo = m->ds_min, hi = m->ds_max;
    czmpc_real ds = clamp(w / c[0], lo, hi);
    czmpc_real scale = py_max(py_max(ONE, CZMPC_FABS(lo)), CZMPC_FABS(hi));
    int it;
    for (it = 0; it < CZMPC_INVERSE_MAX_ITER; ++it) {
        czmpc_real residual = evaluate(c, ds) - w;
        czmpc_real step, candidate;
        if (residual == ZERO) return ds;
        if (residual > ZERO) hi = ds; else lo = ds;
        if (hi - lo <= (czmpc_real)CZMPC_INVERSE_RTOL * scale) break;
        step = residual / slope(c, ds);
        candidate = ds - step;
        ds = (lo < candidate && candidate < hi) ? candidate : (czmpc_real)0.5 * (lo + hi);
        if (CZMPC_FABS(step) <= (czmpc_real)CZMPC_INVERSE_RTOL * scale) break;
    }
    return clamp(ds, m->ds_min, m->ds_max);
}
#endif

/* InputMap.inverse: f^-1(w) on the range; outside [w_min, w_max] the nearer end. */
static czmpc_real inverse(const czmpc_map *m, czmpc_real w)
{
    if (w <= m->w_min) return m->ds_min;
    if (w >= m->w_max) return m->ds_max;
    if (w != w) return (czmpc_real)NAN;
#if CZMPC_NC <= 2
    {
        czmpc_real d1 = m->c[0];
        czmpc_real d2 = CZMPC_NC == 2 ? m->c[CZMPC_NC - 1] : ZERO;
        czmpc_real ds = (czmpc_real)2.0 * w
                        / (d1 + CZMPC_SQRT(d1 * d1 + (czmpc_real)4.0 * d2 * w));
        return clamp(ds, m->ds_min, m->ds_max);
    }
#else
    return newton_inverse(m, w);
#endif
}

/* ---- supervision (czmpc.supervision) ---- */

static void limits_move(czmpc_state *s, czmpc_real lo, czmpc_real hi)
{
    s->lim_lo = lo;
    s->lim_hi = hi;
    full_map(&s->lim_map);
    if (!(lo == CZMPC_DS_MIN_PCT && hi == CZMPC_DS_MAX_PCT)) {
        s->lim_map.ds_min = lo;
        s->lim_map.ds_max = hi;
        s->lim_map.w_min = evaluate(CZMPC_COEF, lo);
        s->lim_map.w_max = evaluate(CZMPC_COEF, hi);
    }
}

/* LimitRamp.ramp */
static void limits_ramp(czmpc_state *s)
{
    if (s->lim_lo != s->lim_lo_goal || s->lim_hi != s->lim_hi_goal) {
        czmpc_real lo = s->lim_lo < s->lim_lo_goal
            ? py_min(s->lim_lo_goal, s->lim_lo + (czmpc_real)CZMPC_LIMIT_RAMP_PCT_PER_STEP)
            : s->lim_lo_goal;
        czmpc_real hi = s->lim_hi > s->lim_hi_goal
            ? py_max(s->lim_hi_goal, s->lim_hi - (czmpc_real)CZMPC_LIMIT_RAMP_PCT_PER_STEP)
            : s->lim_hi_goal;
        limits_move(s, lo, hi);
    }
}

/* SetpointShaper.verdict */
static int setpoint_verdict(czmpc_real sp)
{
    if (!isfinite(sp)) return CZMPC_SETPOINT_NOT_FINITE;
#if CZMPC_HAS_POWER_MIN
    if (sp < (czmpc_real)CZMPC_POWER_MIN_KW) return CZMPC_SETPOINT_BELOW_POWER_MIN;
#endif
    if (CZMPC_FABS(sp) > (czmpc_real)CZMPC_MAX_SETPOINT_KW) return CZMPC_SETPOINT_BEYOND_MAX_SETPOINT;
#if CZMPC_HAS_POWER_MAX
    if (sp > (czmpc_real)CZMPC_POWER_MAX_KW) return CZMPC_SETPOINT_ABOVE_POWER_MAX;
#endif
    return CZMPC_SETPOINT_VALID;
}

/* SetpointShaper.shape: returns the setpoint to use [kW]. */
static czmpc_real shape_setpoint(czmpc_state *s, czmpc_real sp, int *verdict)
{
    czmpc_real ramped;
    *verdict = setpoint_verdict(sp);
    if (*verdict == CZMPC_SETPOINT_VALID) s->sp_held = sp;
    ramped = s->sp_held;
#if CZMPC_HAS_SETPOINT_RAMP
    ramped = s->sp_ramped + clamp(ramped - s->sp_ramped, -(czmpc_real)CZMPC_SETPOINT_MAX_STEP_KW,
                                  (czmpc_real)CZMPC_SETPOINT_MAX_STEP_KW);
#endif
    s->sp_ramped = ramped;
    s->sp_filtered += (czmpc_real)CZMPC_SETPOINT_ALPHA * (ramped - s->sp_filtered);
    return s->sp_filtered;
}

/* SetpointShaper.preview: the shaped preview into s->preview; returns its length. */
static int shape_preview(czmpc_state *s, const czmpc_real *raw, int n_raw,
                         czmpc_real *low, czmpc_real *high)
{
    const czmpc_real lo_ok = CZMPC_PREVIEW_LO_OK_KW, hi_ok = CZMPC_PREVIEW_HI_OK_KW;
    int n = n_raw < CZMPC_N ? n_raw : CZMPC_N;
    int i, any_nan = 0;
    czmpc_real lo, hi;
    if (raw == 0 || n <= 0) return 0;
    lo = hi = raw[0];
    for (i = 0; i < n; ++i) {
        if (raw[i] != raw[i]) any_nan = 1;
        if (raw[i] < lo) lo = raw[i];
        if (raw[i] > hi) hi = raw[i];
    }
    if (any_nan || !(lo_ok <= lo && hi <= hi_ok)) {   /* cut at the first rejected entry */
        for (i = 0; i < n; ++i) {
            if (!(raw[i] >= lo_ok && raw[i] <= hi_ok)) break;
        }
        n = i;
        if (n == 0) return 0;
    }
    {
#if CZMPC_HAS_SETPOINT_RAMP
        const int shaped = 1;
#else
        const int shaped = (czmpc_real)CZMPC_SETPOINT_ALPHA != ONE;
#endif
        czmpc_real ramped = s->sp_ramped, filtered = s->sp_filtered;
        for (i = 0; i < n; ++i) {
            if (shaped) {
#if CZMPC_HAS_SETPOINT_RAMP
                ramped += clamp(raw[i] - ramped, -(czmpc_real)CZMPC_SETPOINT_MAX_STEP_KW,
                                (czmpc_real)CZMPC_SETPOINT_MAX_STEP_KW);
#else
                ramped = raw[i];
#endif
                filtered += (czmpc_real)CZMPC_SETPOINT_ALPHA * (ramped - filtered);
                s->preview[i] = filtered;
            } else {
                s->preview[i] = raw[i];
            }
        }
    }
    lo = hi = s->preview[0];
    for (i = 1; i < n; ++i) {
        if (s->preview[i] < lo) lo = s->preview[i];
        if (s->preview[i] > hi) hi = s->preview[i];
    }
    *low = lo;
    *high = hi;
    return n;
}

/* VoltageDeadband.take, then v^2 and (v^2 - 1) W0 (OffsetFreeMPC._take_voltage). */
static int take_voltage(czmpc_state *s, czmpc_real v)
{
    int verdict;
    if (v != v) {
        verdict = CZMPC_VOLTAGE_NOT_MEASURED;
    } else if ((czmpc_real)CZMPC_VOLTAGE_MIN <= v && v <= (czmpc_real)CZMPC_VOLTAGE_MAX) {
        verdict = CZMPC_VOLTAGE_VALID;
    } else {
        verdict = CZMPC_VOLTAGE_IMPLAUSIBLE;
    }
    if (verdict != CZMPC_VOLTAGE_VALID) {
        s->v_in_use = ONE;
    } else if (CZMPC_FABS(v - s->v_in_use) > (czmpc_real)CZMPC_VOLTAGE_DEADBAND) {
        s->v_in_use = v;
    }
    s->v2 = s->v_in_use * s->v_in_use;
    s->v_offset = (s->v2 - ONE) * (czmpc_real)CZMPC_W0_ABS;
    return verdict;
}

/* OffsetFreeMPC._effective: v^2 w + (v^2 - 1) W0 */
static czmpc_real effective(const czmpc_state *s, czmpc_real w)
{
    return s->v2 == ONE ? w : s->v2 * w + s->v_offset;
}

/* OffsetFreeMPC._scaled_map: v^2 f on em's range */
static void scaled_map(const czmpc_state *s, const czmpc_map *em, czmpc_map *out)
{
    int i;
    *out = *em;
    for (i = 0; i < CZMPC_NC; ++i) out->c[i] = s->v2 * em->c[i];
    out->w_min = s->v2 * em->w_min;
    out->w_max = s->v2 * em->w_max;
}

/* ---- the estimator (czmpc.kalman.Estimator) ---- */

static void est_set(czmpc_state *s, const czmpc_real *z)
{
    int i;
    czmpc_real acc = ZERO;
    for (i = 0; i < CZMPC_NZ; ++i) s->z[i] = z[i];
    for (i = 0; i < CZMPC_NZ; ++i) acc += CZMPC_C[i] * s->z[i];
    s->y_pred = acc;
}

static void est_restart(czmpc_state *s, const czmpc_real *z)
{
    est_set(s, z);
    s->eps = ZERO;
    s->gap = 0;
    s->hist_len = 0;
    s->hist_head = 0;
}

static czmpc_real est_innovation_std(const czmpc_state *s)
{
    return s->gap < CZMPC_NSTD ? CZMPC_STD_KW[s->gap] : CZMPC_STD_KW[CZMPC_NSTD - 1];
}

/* Estimator.update: the measurement update with y [kW deviation]. */
static int est_update(czmpc_state *s, czmpc_real y)
{
    czmpc_real eps = y - s->y_pred;
    int i;
    if (!(CZMPC_FABS(eps) <= (czmpc_real)CZMPC_MAX_INNOVATION_KW)) {
        s->gap += 1;
        return 0;
    }
    for (i = 0; i < CZMPC_NZ; ++i) s->z[i] = CZMPC_M[i] * eps + s->z[i];
    s->eps = eps;
    s->gap = 0;
    return 1;
}

/* Estimator.absorb_level_change */
static void est_absorb_level_change(czmpc_state *s)
{
    const czmpc_real c_d = CZMPC_C_D;
    if (c_d == ZERO || s->gap || s->eps == ZERO) return;
    s->z[CZMPC_NZ - 1] += s->eps * (ONE - (czmpc_real)CZMPC_CM) / c_d;
}

/* Estimator.predict: z+ = A z + B w + G eps (a non-finite result keeps z). */
static void est_predict(czmpc_state *s, czmpc_real w)
{
    czmpc_real v[CZMPC_NZ + 2], out[CZMPC_NZ + 1];
    int i, h = s->hist_head;
    for (i = 0; i < CZMPC_NZ; ++i) s->hist_z[h][i] = s->z[i];
    s->hist_eps[h] = s->eps;
    s->hist_w[h] = w;
    s->hist_head = (h + 1) % CZMPC_HISTORY;
    if (s->hist_len < CZMPC_HISTORY) s->hist_len += 1;
    for (i = 0; i < CZMPC_NZ; ++i) v[i] = s->z[i];
    v[CZMPC_NZ] = w;
    v[CZMPC_NZ + 1] = s->eps;
    gemv(&CZMPC_ABG_C[0][0], CZMPC_NZ + 1, CZMPC_NZ + 2, v, out);
    if (all_finite(out, CZMPC_NZ + 1)) {
        for (i = 0; i < CZMPC_NZ; ++i) s->z[i] = out[i];
        s->y_pred = out[CZMPC_NZ];
    } else {
        czmpc_real z[CZMPC_NZ];
        for (i = 0; i < CZMPC_NZ; ++i) z[i] = s->z[i];
        est_set(s, z);
    }
    s->eps = ZERO;
}

/* Estimator.correct_input: the last predict assumed w_assumed; w_applied was applied. */
static void est_correct_input(czmpc_state *s, czmpc_real w_assumed, czmpc_real w_applied)
{
    czmpc_real z[CZMPC_NZ];
    int i;
    for (i = 0; i < CZMPC_NZ; ++i) z[i] = s->z[i] + CZMPC_B[i] * (w_applied - w_assumed);
    if (all_finite(z, CZMPC_NZ)) {
        est_set(s, z);
        if (s->hist_len > 0) {
            s->hist_w[(s->hist_head + CZMPC_HISTORY - 1) % CZMPC_HISTORY] = w_applied;
        }
    }
}

/* Estimator.roll_back: undo the updates of the last `samples` samples. */
static int est_roll_back(czmpc_state *s, int samples)
{
    czmpc_real z[CZMPC_NZ], az[CZMPC_NZ];
    int steps_back = samples + 1 < s->hist_len ? samples + 1 : s->hist_len;
    int i, j, idx, frozen;
    if (steps_back < 1) return 0;
    idx = (s->hist_head - steps_back + CZMPC_HISTORY) % CZMPC_HISTORY;
    gemv(&CZMPC_A[0][0], CZMPC_NZ, CZMPC_NZ, s->hist_z[idx], az);
    for (i = 0; i < CZMPC_NZ; ++i) {
        z[i] = az[i] + CZMPC_B[i] * s->hist_w[idx] + CZMPC_G[i] * s->hist_eps[idx];
    }
    for (j = 1; j < steps_back; ++j) {
        idx = (idx + 1) % CZMPC_HISTORY;
        gemv(&CZMPC_A[0][0], CZMPC_NZ, CZMPC_NZ, z, az);
        for (i = 0; i < CZMPC_NZ; ++i) z[i] = az[i] + CZMPC_B[i] * s->hist_w[idx];
    }
    if (!all_finite(z, CZMPC_NZ)) return 0;
    est_set(s, z);
    frozen = steps_back - 1;
    if (frozen > s->gap) s->gap = frozen;
    return frozen;
}

/* ---- measurement checks (czmpc.validation.MeasurementChecker) ---- */

static void checker_reset(czmpc_state *s)
{
    s->chk_has_last = 0;
    s->chk_last = ZERO;
    s->chk_run_value = (czmpc_real)NAN;
    s->chk_run_length = 0;
    s->chk_pred_min = (czmpc_real)INFINITY;
    s->chk_pred_max = -(czmpc_real)INFINITY;
    s->chk_n_rejected = 0;
    s->chk_gate_open = 0;
}

static int checker_stuck(czmpc_state *s, czmpc_real power, czmpc_real predicted)
{
    if (power == s->chk_run_value) {
        s->chk_run_length += 1;
    } else {
        s->chk_run_value = power;
        s->chk_run_length = 1;
        s->chk_pred_min = (czmpc_real)INFINITY;
        s->chk_pred_max = -(czmpc_real)INFINITY;
    }
    if (isfinite(predicted)) {
        if (predicted < s->chk_pred_min) s->chk_pred_min = predicted;
        if (predicted > s->chk_pred_max) s->chk_pred_max = predicted;
    }
    return CZMPC_STUCK_SAMPLES > 0 && s->chk_run_length >= CZMPC_STUCK_SAMPLES
           && s->chk_pred_max - s->chk_pred_min >= (czmpc_real)CZMPC_STUCK_MIN_CHANGE_KW;
}

/* MeasurementChecker.check: the verdict; *reopened for a level change. */
static int checker_check(czmpc_state *s, czmpc_real power, czmpc_real predicted,
                         czmpc_real std_kw, int gate, int *reopened)
{
    int suspect = CZMPC_VERDICT_VALID;
    *reopened = 0;
    if (!isfinite(power)) {
        s->chk_run_length = 0;
        s->chk_run_value = (czmpc_real)NAN;
        return CZMPC_VERDICT_MISSING;
    }
#if CZMPC_HAS_POWER_MIN
    if (power < (czmpc_real)CZMPC_POWER_MIN_KW) return CZMPC_VERDICT_BELOW_LIMIT;
#endif
#if CZMPC_HAS_POWER_MAX
    if (power > (czmpc_real)CZMPC_POWER_MAX_KW) return CZMPC_VERDICT_ABOVE_LIMIT;
#endif
    if (checker_stuck(s, power, predicted)) return CZMPC_VERDICT_STUCK;
#if CZMPC_HAS_MAX_CHANGE
    if (s->chk_has_last && !(CZMPC_FABS(power - s->chk_last) <= (czmpc_real)CZMPC_MAX_CHANGE_KW)) {
        suspect = CZMPC_VERDICT_TOO_FAST;
    } else
#endif
    {
#if CZMPC_HAS_SPIKE_GATE
        if (gate || s->chk_gate_open) {
            czmpc_real width = py_max((czmpc_real)CZMPC_SPIKE_K_SIGMA * std_kw,
                                      (czmpc_real)CZMPC_SPIKE_FLOOR_KW);
            int inside = CZMPC_FABS(power - predicted) <= width;
            if (s->chk_gate_open) {
                s->chk_gate_open = !inside;
            } else if (!inside) {
                suspect = CZMPC_VERDICT_SPIKE;
            }
        }
#else
        (void)gate;
        (void)std_kw;
#endif
    }
    if (suspect != CZMPC_VERDICT_VALID) {
        if (s->chk_n_rejected < CZMPC_REOPEN_AFTER) {
            s->chk_n_rejected += 1;
            return suspect;
        }
        *reopened = 1;
        s->chk_gate_open = suspect == CZMPC_VERDICT_SPIKE;
    }
    s->chk_n_rejected = 0;
    s->chk_has_last = 1;
    s->chk_last = power;
    return CZMPC_VERDICT_VALID;
}

/* ---- controller stages (czmpc.controller.OffsetFreeMPC) ---- */

static void restart_estimator(czmpc_state *s, czmpc_real w)
{
    czmpc_real z[CZMPC_NZ];
    czmpc_real w_eff = effective(s, w);
    int i;
    for (i = 0; i < CZMPC_NX; ++i) z[i] = CZMPC_XW[i] * w_eff;
    z[CZMPC_NX] = ZERO;
    est_restart(s, z);
    s->w_eff_assumed = w_eff;
    s->warm = 0;
    s->jump_sign = 0;
    s->stuck_rolled = 0;
    checker_reset(s);
}

/* Stage 0: the input applied over the last sample; returns whether it differs. */
static int take_applied_input(czmpc_state *s, czmpc_real applied)
{
    czmpc_real ds_a;
    int differs;
    if (!isfinite(applied)) return 0;
    ds_a = clamp(applied, ZERO, (czmpc_real)100.0) - (czmpc_real)CZMPC_S_NOM_PCT;
    differs = CZMPC_FABS(ds_a - s->ds_prev) > (czmpc_real)CZMPC_APPLIED_TOL_PCT;
    if (ds_a != s->ds_prev) {
        s->ds_prev = ds_a;
        s->w_prev = evaluate(CZMPC_COEF, ds_a);
    }
    return differs;
}

/* Stage 1: validity checks, then the measurement update with a valid sample only. */
static void measurement_update(czmpc_state *s, czmpc_real power, int *verdict, int *reopened,
                               int *used, czmpc_real *std_out, int *rolled_back)
{
    czmpc_real std_kw = est_innovation_std(s);
    *rolled_back = 0;
    *verdict = checker_check(s, power, (czmpc_real)CZMPC_P_NOM_KW + s->y_pred, std_kw,
                             s->warm >= CZMPC_WARMUP_SAMPLES, reopened);
    if (*verdict == CZMPC_VERDICT_STUCK) {
        if (!s->stuck_rolled) {
            s->stuck_rolled = 1;
            *rolled_back = est_roll_back(s, s->chk_run_length - 2);
            s->n_rejected += *rolled_back;
            std_kw = est_innovation_std(s);
        }
    } else {
        s->stuck_rolled = 0;
    }
    *used = *verdict == CZMPC_VERDICT_VALID
            && est_update(s, power - (czmpc_real)CZMPC_P_NOM_KW);
    if (*used) {
        int sign = 0;
        s->warm += 1;
#if CZMPC_HAS_LEVEL_CHANGE
        if (CZMPC_FABS(s->eps) > (czmpc_real)CZMPC_LEVEL_CHANGE_K_SIGMA * std_kw) {
            sign = s->eps > ZERO ? 1 : -1;
        }
#endif
        if (sign && sign == s->jump_sign) {
            est_absorb_level_change(s);
            sign = 0;
        }
        s->jump_sign = sign;
    } else {
        s->jump_sign = 0;
        if (*verdict != CZMPC_VERDICT_VALID) s->gap += 1;   /* Estimator.skip */
        s->n_rejected += 1;
    }
    *std_out = std_kw;
}

/* Stage 2: czmpc.target.compute_target */
static void compute_target(czmpc_real r, czmpc_real d, czmpc_real w_min, czmpc_real w_max,
                           target_t *t)
{
    const czmpc_real g = CZMPC_STATIC_GAIN;
    czmpc_real w_free, w_s, y_s;
    int i;
#if CZMPC_DISTURBANCE_INPUT
    w_free = r / g - d;
#else
    w_free = (r - d) / g;
#endif
    w_s = clamp(w_free, w_min, w_max);
#if CZMPC_DISTURBANCE_INPUT
    for (i = 0; i < CZMPC_NX; ++i) t->x_s[i] = CZMPC_XW[i] * (w_s + d);
    y_s = g * (w_s + d);
#else
    for (i = 0; i < CZMPC_NX; ++i) t->x_s[i] = CZMPC_XW[i] * w_s;
    y_s = g * w_s + d;
#endif
    t->is_reachable = w_s == w_free;
    if (t->is_reachable) y_s = r;
    t->w_s = w_s;
    t->y_s = y_s;
    t->w_unclipped = w_free;
}

/* Stage 2: OffsetFreeMPC._reference_cost into s->q_offset. */
static void reference_cost(czmpc_state *s, czmpc_real setpoint_kw, const czmpc_real *values,
                           int n_values, czmpc_real low_kw, czmpc_real high_kw,
                           const target_t *t, czmpc_real w_min, czmpc_real w_max)
{
    const czmpc_real inv_g = CZMPC_INV_STATIC_GAIN;
    czmpc_real *traj = s->traj;
    czmpc_real r_end = values[n_values - 1];
    czmpc_real low = py_min(low_kw, setpoint_kw), high = py_max(high_kw, setpoint_kw);
    int i;
    traj[0] = setpoint_kw;
    for (i = 0; i < n_values; ++i) traj[1 + i] = values[i];
    for (i = n_values + 1; i <= CZMPC_N; ++i) traj[i] = r_end;
    if (w_min <= t->w_unclipped + (low - r_end) * inv_g
            && t->w_unclipped + (high - r_end) * inv_g <= w_max) {
        traj[CZMPC_N + 1] = (czmpc_real)CZMPC_P_NOM_KW + t->y_s;
        traj[CZMPC_N + 2] = t->w_unclipped - t->w_s;
        gemv(&CZMPC_TRAJ_COST[0][0], CZMPC_N, CZMPC_N + 3, traj, s->q_offset);
        return;
    }
    {
        const czmpc_real c_y = (czmpc_real)CZMPC_P_NOM_KW + t->y_s;
        for (i = 0; i < CZMPC_N - 1; ++i) s->ref[i] = traj[1 + i] - c_y;
        for (i = 0; i <= CZMPC_N; ++i) {
            czmpc_real sigma = clamp(t->w_unclipped + (traj[i] - r_end) * inv_g, w_min, w_max);
            s->ref[CZMPC_N - 1 + i] = sigma - t->w_s;
        }
        gemv(&CZMPC_REF_COST[0][0], CZMPC_N, 2 * CZMPC_N, s->ref, s->q_offset);
    }
}

/* Stage 3: czmpc.qp.MoveBounds.compute into the QP's rows (box: l/u[0..N), rate:
   l/u[N..2N-1)). */
static void move_bounds(czmpc_state *s, const czmpc_map *m, czmpc_real ds_prev)
{
    int j;
#if !CZMPC_HAS_RATE_LIMIT
    (void)ds_prev;
    for (j = 0; j < CZMPC_N; ++j) {
        s->l[j] = m->w_min;
        s->u[j] = m->w_max;
    }
#else
    const czmpc_real delta = CZMPC_MAX_MOVE_PCT_PER_STEP;
    czmpc_real ds_lo[CZMPC_N], ds_hi[CZMPC_N];
    for (j = 0; j < CZMPC_N; ++j) {
        czmpc_real reach = delta * (czmpc_real)(j + 1);
        czmpc_real lo = -reach + ds_prev, hi = reach + ds_prev;
        lo = lo < m->ds_min ? m->ds_min : lo;
        lo = lo > m->ds_max ? m->ds_max : lo;
        hi = hi < m->ds_min ? m->ds_min : hi;
        hi = hi > m->ds_max ? m->ds_max : hi;
        ds_lo[j] = lo;
        ds_hi[j] = hi;
        s->l[j] = evaluate(m->c, lo);
        s->u[j] = evaluate(m->c, hi);
    }
    for (j = 1; j < CZMPC_N; ++j) {
        czmpc_real rate;
#if CZMPC_NC == 1
        (void)ds_lo;
        (void)ds_hi;
        rate = m->c[0];
#elif CZMPC_NC == 2
        rate = (m->c[1] >= ZERO ? ds_lo[j] : ds_hi[j]) * ((czmpc_real)2 * m->c[1]) + m->c[0];
#else
        {
            czmpc_real slo = slope(m->c, ds_lo[j]), shi = slope(m->c, ds_hi[j]);
            int i;
            rate = shi < slo ? shi : slo;
            for (i = 0; i < CZMPC_NCRIT; ++i) {
                czmpc_real r = CZMPC_CRIT[i];
                if (ds_lo[j] < r && r < ds_hi[j]) {
                    czmpc_real sr = slope(m->c, r);
                    rate = sr < rate ? sr : rate;
                }
            }
        }
#endif
        s->l[CZMPC_N + j - 1] = rate * -delta;
        s->u[CZMPC_N + j - 1] = rate * delta;
    }
#endif
}

#if !CZMPC_SOLVER_DAQP || CZMPC_DAQP_CHECK_BOUNDS
/* czmpc.qp.MPCQP._bound_violation: the largest violation of the box and rate rows by w. */
static czmpc_real bound_violation(const czmpc_state *s, const czmpc_real *w)
{
    czmpc_real worst = ZERO;
    int j;
    for (j = 0; j < CZMPC_N; ++j) {
        if (s->l[j] - w[j] > worst) worst = s->l[j] - w[j];
        if (w[j] - s->u[j] > worst) worst = w[j] - s->u[j];
    }
#if CZMPC_HAS_RATE_LIMIT
    for (j = 1; j < CZMPC_N; ++j) {
        czmpc_real v = CZMPC_FABS(w[j] - w[j - 1]) - s->u[CZMPC_N + j - 1];
        if (v > worst) worst = v;
    }
#endif
    return worst;
}
#endif

/* Stage 3: czmpc.qp.MPCQP.solve on the vectors in s (box and rate rows written). */
static void qp_solve(czmpc_state *s, czmpc_real w_prev, const target_t *t, int has_q_offset,
                     plan_t *p)
{
#if !CZMPC_SOLVER_DAQP
    const OSQPSolution *sol;
#endif
    int j;
    s->params[CZMPC_NPAR - 2] = w_prev;
    s->params[CZMPC_NPAR - 1] = t->w_s;
    gemv(&CZMPC_Q_PARAMS[0][0], CZMPC_N, CZMPC_NPAR, s->params, s->q);
    if (has_q_offset) {
        for (j = 0; j < CZMPC_N; ++j) s->q[j] += s->q_offset[j];
    }
#if CZMPC_HAS_SOFT
    {
        czmpc_real chp[CZMPC_N];
        int r0 = CZMPC_ROW_SOFT;
        gemv(&CZMPC_CPHI_MAP[0][0], CZMPC_N, CZMPC_NPAR - 2, s->params, chp);
        for (j = 0; j < CZMPC_N; ++j) chp[j] = chp[j] - CZMPC_CGAM_ROWSUM[j] * t->w_s + t->y_s;
#if CZMPC_HAS_SOFT_MAX
        for (j = 0; j < CZMPC_N; ++j) s->u[r0 + j] = (czmpc_real)CZMPC_SOFT_MAX_REL_KW - chp[j];
        r0 += CZMPC_N;
#endif
#if CZMPC_HAS_SOFT_MIN
        for (j = 0; j < CZMPC_N; ++j) s->l[r0 + j] = (czmpc_real)CZMPC_SOFT_MIN_REL_KW - chp[j];
#endif
    }
#endif
    p->outside_bounds_kw = ZERO;
    p->w = 0;
    p->usable = p->accurate = 0;
    p->n_iterations = 0;
    p->slack_kw = CZMPC_HAS_SOFT ? (czmpc_real)NAN : ZERO;
    if (!(all_finite(s->q, CZMPC_NVAR) && all_finite(s->l, CZMPC_NCON)
          && all_finite(s->u, CZMPC_NCON))) {
        p->status_val = CZMPC_SOLVER_NONFINITE_DATA;
        s->needs_cold_start = 1;
        return;
    }
#if CZMPC_SOLVER_DAQP
    /* czmpc.qp_daqp.DAQPMPCQP.solve: update f, bupper, blower (and the working set
       cleared on a cold start), then DAQP from the previous working set. */
    {
        int mask = DAQP_UPDATE_v | DAQP_UPDATE_d, flag;
        DAQPResult res;
        daqp_qp.f = s->q;
        daqp_qp.bupper = s->u;
        daqp_qp.blower = s->l;
        if (s->needs_cold_start) {
            for (j = 0; j < CZMPC_DAQP_M; ++j) daqp_sense0[j] = 0;
            daqp_qp.sense = daqp_sense0;
            mask |= DAQP_UPDATE_sense;
            s->needs_cold_start = 0;
        }
        flag = daqp_update_ldp(mask, &daqp_work, &daqp_qp);
        if (flag < 0) {
            p->status_val = CZMPC_SOLVER_DAQP_EXIT(flag);
            s->needs_cold_start = 1;
            return;
        }
        res.x = daqp_x;
        res.lam = daqp_lam;
        res.fval = 0;
        res.soft_slack = 0;
        res.exitflag = 0;
        res.iter = 0;
        res.nodes = 0;
        res.solve_time = 0;
        res.setup_time = 0;
        daqp_solve(&res, &daqp_work);
        p->status_val = CZMPC_SOLVER_DAQP_EXIT(res.exitflag);
        p->n_iterations = res.iter;
        p->usable = res.exitflag == CZMPC_DAQP_EXIT_OPTIMAL && all_finite(daqp_x, CZMPC_NVAR);
#if CZMPC_DAQP_CHECK_BOUNDS
        if (p->usable) {
            czmpc_real worst = bound_violation(s, daqp_x);
            if (worst > (czmpc_real)CZMPC_SOLVER_BOUND_TOL_KW) {
                p->usable = 0;
                p->outside_bounds_kw = worst;
            }
        }
#endif
        if (p->usable) {
            p->w = daqp_x;
            p->accurate = 1;
#if CZMPC_HAS_SOFT
            p->slack_kw = py_max(ZERO, daqp_x[CZMPC_N]);
#endif
        } else {
            s->needs_cold_start = 1;
        }
    }
#else
    /* Python ignores osqp_update_data_vec's exit flag (l > u): so does this. */
    (void)osqp_update_data_vec(&czmpc_qp_solver, s->q, s->l, s->u);
    if (s->needs_cold_start) {
        osqp_cold_start(&czmpc_qp_solver);   /* = warm_start(0, 0) */
        s->needs_cold_start = 0;
    }
    (void)osqp_solve(&czmpc_qp_solver);
    p->status_val = (int)czmpc_qp_solver.info->status_val;
    p->n_iterations = (int)czmpc_qp_solver.info->iter;
    sol = czmpc_qp_solver.solution;
    p->usable = p->status_val == OSQP_SOLVED || p->status_val == OSQP_SOLVED_INACCURATE;
    if (p->usable && !(czmpc_qp_solver.info->prim_res <= (czmpc_real)CZMPC_SOLVER_BOUND_TOL_KW)) {
        if (!all_finite(sol->x, CZMPC_NVAR)) {
            p->usable = 0;
        } else {
            czmpc_real worst = bound_violation(s, sol->x);
            if (worst > (czmpc_real)CZMPC_SOLVER_BOUND_TOL_KW) {
                p->usable = 0;
                p->outside_bounds_kw = worst;
            }
        }
    }
    if (p->usable) {
        p->w = sol->x;
        p->accurate = p->status_val == OSQP_SOLVED;
#if CZMPC_HAS_SOFT
        p->slack_kw = py_max(ZERO, sol->x[CZMPC_N]);
#endif
    } else {
        s->needs_cold_start = 1;
    }
#endif
}

/* Stage 3: OffsetFreeMPC._solve_or_fall_back */
static void solve_or_fall_back(czmpc_state *s, const target_t *t, const czmpc_map *em,
                               const czmpc_map *em_v, int has_q_offset, plan_t *p)
{
    const czmpc_real ds_prev = s->ds_prev;
    const czmpc_real ds_base = clamp(ds_prev, em->ds_min, em->ds_max);
    const czmpc_real v_off = s->v_offset;
    czmpc_real w_base;
    int i, j;
    if (ds_base == ds_prev) {
        w_base = effective(s, s->w_prev);
    } else {
        w_base = v_off != ZERO ? evaluate(em_v->c, ds_base) + v_off : evaluate(em_v->c, ds_base);
    }
    for (i = 0; i < CZMPC_NZ; ++i) s->params[i] = s->z[i];
    for (i = 0; i < CZMPC_NX; ++i) s->params[CZMPC_NZ + i] = t->x_s[i];
    s->params[CZMPC_NZ + CZMPC_NX] = s->eps;
    move_bounds(s, em_v, ds_base);
    if (v_off != ZERO) {
        for (j = 0; j < CZMPC_N; ++j) {
            s->l[j] += v_off;
            s->u[j] += v_off;
        }
    }
    qp_solve(s, w_base, t, has_q_offset, p);
    if (p->usable) {
        p->w0 = p->w[0];
        p->fallback = CZMPC_FALLBACK_NONE;
        for (j = 0; j < CZMPC_N; ++j) s->plan[j] = p->w[j];
        s->has_plan = 1;
        s->plan_k = s->k;
        s->bad_in_row = 0;
        if (!p->accurate) s->n_inaccurate += 1;
    } else {
        long age = s->k - s->plan_k;
        s->n_fallbacks += 1;
        s->bad_in_row += 1;
        if (s->bad_in_row < CZMPC_MAX_BAD_SOLVES && s->has_plan && age < CZMPC_N) {
            p->w0 = s->plan[age];
            p->fallback = CZMPC_FALLBACK_SHIFTED_PLAN;
        } else {
            p->w0 = t->w_s;
            p->fallback = CZMPC_FALLBACK_TARGET;
            s->has_plan = 0;
        }
    }
    p->w_lo0 = s->l[0];
    p->w_hi0 = s->u[0];
    p->solver_shed = s->bad_in_row >= CZMPC_MAX_BAD_SOLVES;
}

/* Stage 4: OffsetFreeMPC._guard_input (em is v^2 f); *ds_raw is the input asked for. */
static czmpc_real guard_input(const czmpc_state *s, czmpc_real w0, czmpc_real ds_prev,
                              int measurement_shed, const target_t *t, const czmpc_map *em,
                              czmpc_real *ds_raw)
{
#if CZMPC_HAS_RATE_LIMIT
    const czmpc_real r_lo = ds_prev - (czmpc_real)CZMPC_MAX_MOVE_PCT_PER_STEP;
    const czmpc_real r_hi = ds_prev + (czmpc_real)CZMPC_MAX_MOVE_PCT_PER_STEP;
#else
    const czmpc_real r_lo = -(czmpc_real)INFINITY, r_hi = (czmpc_real)INFINITY;
#endif
    if (measurement_shed) {
#if CZMPC_HAS_SHED_INPUT
        (void)t;
        (void)s;
        *ds_raw = CZMPC_SHED_DS_PCT;
#else
        *ds_raw = inverse(em, t->w_s - s->v_offset);
#endif
    } else {
        *ds_raw = inverse(em, w0);
        if (!isfinite(*ds_raw)) *ds_raw = ds_prev;
    }
    return clamp(clamp(*ds_raw, r_lo, r_hi), em->ds_min, em->ds_max);
}

/* Stage 5: OffsetFreeMPC._judge */
static int judge(czmpc_state *s, int used, const plan_t *p, const target_t *t, czmpc_real ds,
                 czmpc_real ds_raw, int applied_differs, int shed)
{
    if (shed) {
        s->n_shed += 1;
        return CZMPC_STATUS_SHED;
    }
    if (p->fallback != CZMPC_FALLBACK_NONE) return CZMPC_STATUS_HELD;
    if (!used) return CZMPC_STATUS_PREDICTED;
    if (applied_differs || !t->is_reachable || CZMPC_FABS(ds - ds_raw) > (czmpc_real)CZMPC_CLAMP_TOL
            || CZMPC_FABS(p->w0 - p->w_lo0) <= (czmpc_real)CZMPC_CLAMP_TOL
            || CZMPC_FABS(p->w0 - p->w_hi0) <= (czmpc_real)CZMPC_CLAMP_TOL) {
        return CZMPC_STATUS_CLAMPED;
    }
    return CZMPC_STATUS_GOOD;
}

/* ---- the QP solver's workspace, exact ---- */

#if CZMPC_SOLVER_DAQP
/* Set DAQP up as daqp.Model.setup did for the Python controller (czmpc.qp_daqp): the
   settings (DAQP's defaults, iter_limit and primal_tol as DAQPMPCQP sets them), the
   exact H and general rows, the initial f, bupper, blower (from czmpc_init_at) and an
   empty working set; DAQP's own setup_daqp forms the LDP (Cholesky factor of H, its
   inverse, M = R^-T A^T, normalisation) in the static arena of czmpc_daqp_heap.c, which
   is sealed afterwards: nothing is allocated after init. Returns CZMPC_OK, or
   CZMPC_ERR_SOLVER if DAQP refuses the problem or the arena is too small. */
static int qp_setup_exact(const czmpc_state *s)
{
    int i, flag;
    (void)s;
    for (i = 0; i < CZMPC_DAQP_N * CZMPC_DAQP_N; ++i) daqp_H[i] = CZMPC_DAQP_H0[i];
    for (i = 0; i < (CZMPC_DAQP_M - CZMPC_DAQP_MS) * CZMPC_DAQP_N; ++i) daqp_A[i] = CZMPC_DAQP_A0[i];
    for (i = 0; i < CZMPC_DAQP_M; ++i) daqp_sense0[i] = 0;
    daqp_default_settings(&daqp_settings);
    daqp_settings.iter_limit = CZMPC_DAQP_ITER_LIMIT;
    daqp_settings.primal_tol = CZMPC_DAQP_PRIMAL_TOL;
    memset(&daqp_work, 0, sizeof daqp_work);
    daqp_work.settings = &daqp_settings;
    daqp_qp.n = CZMPC_DAQP_N;
    daqp_qp.m = CZMPC_DAQP_M;
    daqp_qp.ms = CZMPC_DAQP_MS;
    daqp_qp.H = daqp_H;
    daqp_qp.f = (double *)s->q;
    daqp_qp.A = daqp_A;
    daqp_qp.bupper = (double *)s->u;
    daqp_qp.blower = (double *)s->l;
    daqp_qp.sense = daqp_sense0;
    daqp_qp.break_points = NULL;
    daqp_qp.nh = 0;
    daqp_qp.problem_type = 0;
    czmpc_daqp_arena_open();
    flag = setup_daqp(&daqp_qp, &daqp_work, NULL);
    czmpc_daqp_arena_seal();
    return flag < 0 || czmpc_daqp_arena_refused() != 0 ? CZMPC_ERR_SOLVER : CZMPC_OK;
}

/* The status text of a DAQP solve, as czmpc.qp_daqp.daqp_status. */
static const char *daqp_status_text(int status_val)
{
    int i, flag = status_val - CZMPC_SOLVER_DAQP_EXIT(0);
    for (i = 0; i < CZMPC_DAQP_N_STATUS; ++i) {
        if (CZMPC_DAQP_STATUS[i].exitflag == flag) return CZMPC_DAQP_STATUS[i].text;
    }
    return "unknown exit flag";
}
#else

/* Set OSQP's generated workspace up again from the exact problem, as osqp_setup did for
   the Python controller: float settings, unscaled P and A, the initial q, l, u (from
   czmpc_init_at), then scaling, rho vector, KKT matrix and its factorization. OSQP's
   code generator prints every number as "%.20f", which drops digits of those below
   1e-4 in magnitude (scaled matrices, scaling vectors, KKT factor): without this the
   solver's iterates differ from Python's in the last digits and, over a run, in the
   iteration counts. Uses only functions of OSQP's embedded code (no heap). Returns
   CZMPC_OK, or CZMPC_ERR_SOLVER if the KKT matrix cannot be factored. */
static int qp_setup_exact(const czmpc_state *s)
{
    OSQPSolver *solver = &czmpc_qp_solver;
    OSQPWorkspace *work = solver->work;
    OSQPSettings *st = solver->settings;
    OSQPFloat *px = work->data->P->csc->x, *ax = work->data->A->csc->x;
    OSQPFloat *q = work->data->q->values, *l = work->data->l->values, *u = work->data->u->values;
    int i, bad;
    st->rho = (czmpc_real)CZMPC_OSQP_RHO;
    st->sigma = (czmpc_real)CZMPC_OSQP_SIGMA;
    st->alpha = (czmpc_real)CZMPC_OSQP_ALPHA;
    st->eps_abs = (czmpc_real)CZMPC_OSQP_EPS_ABS;
    st->eps_rel = (czmpc_real)CZMPC_OSQP_EPS_REL;
    st->eps_prim_inf = (czmpc_real)CZMPC_OSQP_EPS_PRIM_INF;
    st->eps_dual_inf = (czmpc_real)CZMPC_OSQP_EPS_DUAL_INF;
    st->adaptive_rho_tolerance = (czmpc_real)CZMPC_OSQP_ADAPTIVE_RHO_TOLERANCE;
    st->adaptive_rho_fraction = (czmpc_real)CZMPC_OSQP_ADAPTIVE_RHO_FRACTION;
    for (i = 0; i < CZMPC_QP_NNZ_P; ++i) px[i] = CZMPC_QP_P_X[i];
    for (i = 0; i < CZMPC_QP_NNZ_A; ++i) ax[i] = CZMPC_QP_A_X[i];
    for (i = 0; i < CZMPC_NVAR; ++i) q[i] = s->q[i];
    for (i = 0; i < CZMPC_NCON; ++i) {
        l[i] = s->l[i];
        u[i] = s->u[i];
    }
    if (st->scaling) scale_data(solver);
    if (st->rho_is_vec) {
        set_rho_vec(solver);
    } else {   /* as osqp_setup */
        st->rho = st->rho < OSQP_RHO_MIN ? OSQP_RHO_MIN : (st->rho > OSQP_RHO_MAX ? OSQP_RHO_MAX : st->rho);
        work->rho_inv = 1. / st->rho;
    }
    bad = work->linsys_solver->update_matrices(work->linsys_solver, work->data->P, OSQP_NULL,
                                               CZMPC_QP_NNZ_P, work->data->A, OSQP_NULL,
                                               CZMPC_QP_NNZ_A) != 0;
    bad |= work->linsys_solver->update_rho_vec(work->linsys_solver, work->rho_vec, st->rho) != 0;
    reset_info(solver->info);
    osqp_cold_start(solver);
    return bad ? CZMPC_ERR_SOLVER : CZMPC_OK;
}
#endif

/* ---- public API ---- */

void czmpc_reset(czmpc_state *s)
{
    int i;
    czmpc_real w0 = evaluate(CZMPC_COEF, s->ds_init);
    s->v_in_use = ONE;
    s->v2 = ONE;
    s->v_offset = ZERO;
    restart_estimator(s, w0);
    s->ds_prev = s->ds_init;
    s->w_prev = w0;
    s->sp_held = s->sp_ramped = s->sp_filtered
        = (czmpc_real)CZMPC_P_NOM_KW + (czmpc_real)CZMPC_STATIC_GAIN * w0;
    s->k = 0;
    s->has_plan = 0;
    s->plan_k = 0;
    s->n_fallbacks = s->n_inaccurate = s->n_rejected = s->n_shed = 0;
    s->bad_in_row = 0;
    s->mode = CZMPC_INITIAL_MODE;
    s->warm = s->mode == CZMPC_MODE_ON ? CZMPC_WARMUP_SAMPLES : 0;
    s->lim_lo_goal = CZMPC_DS_MIN_PCT;
    s->lim_hi_goal = CZMPC_DS_MAX_PCT;
    limits_move(s, CZMPC_DS_MIN_PCT, CZMPC_DS_MAX_PCT);
    s->needs_cold_start = 1;
    for (i = 0; i < CZMPC_N; ++i) s->last_plan[i] = (czmpc_real)NAN;
}

int czmpc_init_at(czmpc_state *s, czmpc_real initial_triac_pct)
{
    czmpc_real ds = initial_triac_pct - (czmpc_real)CZMPC_S_NOM_PCT;
    int i;
    if (!((czmpc_real)CZMPC_DS_MIN_PCT <= ds && ds <= (czmpc_real)CZMPC_DS_MAX_PCT)) {
        return CZMPC_ERR_RANGE;
    }
    s->ds_init = ds;
    for (i = 0; i < CZMPC_NVAR; ++i) s->q[i] = ZERO;
    for (i = 0; i < CZMPC_NCON; ++i) {
        s->l[i] = -(czmpc_real)CZMPC_OSQP_INFINITY;
        s->u[i] = (czmpc_real)CZMPC_OSQP_INFINITY;
    }
#if CZMPC_HAS_SOFT
    s->q[CZMPC_N] = CZMPC_SOFT_LINEAR_WEIGHT;
    s->l[CZMPC_NCON - 1] = ZERO;
#endif
    /* The solver as set up in Python (its step size back to the start, too). */
    if (qp_setup_exact(s) != CZMPC_OK) return CZMPC_ERR_SOLVER;
    czmpc_reset(s);
    return CZMPC_OK;
}

int czmpc_init(czmpc_state *s)
{
    s->ds_init = CZMPC_DS_INIT_PCT;
    return czmpc_init_at(s, (czmpc_real)CZMPC_S_NOM_PCT + (czmpc_real)CZMPC_DS_INIT_PCT);
}

czmpc_inputs czmpc_inputs_default(czmpc_real power_kw, czmpc_real setpoint_kw)
{
    czmpc_inputs in;
    in.power_kw = power_kw;
    in.setpoint_kw = setpoint_kw;
    in.applied_triac_pct = (czmpc_real)NAN;
    in.grid_voltage_factor = (czmpc_real)NAN;
    in.setpoint_preview_kw = 0;
    in.n_preview = 0;
    return in;
}

int czmpc_request_mode(czmpc_state *s, int mode)
{
    if (mode != CZMPC_MODE_OFF && mode != CZMPC_MODE_PREDICT && mode != CZMPC_MODE_ON) {
        return CZMPC_ERR_UNKNOWN;
    }
    if (mode == s->mode) return CZMPC_OK;
    if (mode == CZMPC_MODE_ON && !(s->warm >= CZMPC_WARMUP_SAMPLES)) return CZMPC_ERR_NOT_READY;
    if (mode == CZMPC_MODE_OFF) {
        s->warm = 0;
    } else if (s->mode == CZMPC_MODE_OFF) {
        restart_estimator(s, s->w_prev);
    }
    if (mode == CZMPC_MODE_ON) {
        s->needs_cold_start = 1;
        s->has_plan = 0;
    }
    s->mode = mode;
    return CZMPC_OK;
}

int czmpc_set_triac_limits(czmpc_state *s, czmpc_real triac_min_pct, czmpc_real triac_max_pct)
{
    czmpc_real lo, hi, new_lo, new_hi;
    if (!(isfinite(triac_min_pct) && isfinite(triac_max_pct) && triac_min_pct < triac_max_pct)) {
        return CZMPC_ERR_RANGE;
    }
    lo = py_max(CZMPC_DS_MIN_PCT, triac_min_pct - (czmpc_real)CZMPC_S_NOM_PCT);
    hi = py_min(CZMPC_DS_MAX_PCT, triac_max_pct - (czmpc_real)CZMPC_S_NOM_PCT);
    if (!(lo < hi)) return CZMPC_ERR_RANGE;
    s->lim_lo_goal = lo;
    s->lim_hi_goal = hi;
    new_lo = lo <= s->lim_lo ? lo : clamp(s->ds_prev, s->lim_lo, lo);
    new_hi = hi >= s->lim_hi ? hi : py_max(hi, py_min(s->lim_hi, s->ds_prev));
    limits_move(s, new_lo, new_hi);
    return CZMPC_OK;
}

czmpc_real czmpc_step(czmpc_state *s, const czmpc_inputs *in, czmpc_outputs *out)
{
    const int mode = s->mode;
    const czmpc_real power = in->power_kw;
    int applied_differs, v_verdict, sp_verdict, n_preview = 0;
    czmpc_real sp_used, pv_low = ZERO, pv_high = ZERO;
    czmpc_real triac;
    int verdict, reopened, used, rolled_back, i;
    czmpc_real std_kw, d, v_off, w_min, w_max, ds_prev, ds, ds_raw;
    czmpc_map em_scaled;
    const czmpc_map *em, *em_v;
    target_t t;
    plan_t p;
    int has_q_offset, measurement_shed, status;

    applied_differs = take_applied_input(s, in->applied_triac_pct);
    v_verdict = take_voltage(s, in->grid_voltage_factor);
    if (mode != CZMPC_MODE_OFF) {
        czmpc_real w_eff = effective(s, s->w_prev);
        if (w_eff != s->w_eff_assumed) {
            est_correct_input(s, s->w_eff_assumed, w_eff);
            s->w_eff_assumed = w_eff;
        }
    }
    limits_ramp(s);
    sp_used = shape_setpoint(s, in->setpoint_kw, &sp_verdict);
    n_preview = shape_preview(s, in->setpoint_preview_kw, in->n_preview, &pv_low, &pv_high);

    if (mode == CZMPC_MODE_OFF) {
        triac = (czmpc_real)CZMPC_S_NOM_PCT + s->ds_prev;
        for (i = 0; i < CZMPC_N; ++i) s->last_plan[i] = (czmpc_real)NAN;
        if (out) {
            out->k = s->k;
            out->triac_pct = triac;
            out->mode = CZMPC_MODE_OFF;
            out->status = CZMPC_STATUS_HELD;
            out->fallback = CZMPC_FALLBACK_NONE;
            out->measurement_used = 0;
            out->verdict = isfinite(power) ? CZMPC_VERDICT_VALID : CZMPC_VERDICT_MISSING;
            out->level_change_accepted = 0;
            out->setpoint_verdict = sp_verdict;
            out->voltage_verdict = v_verdict;
            out->solver_status_val = CZMPC_SOLVER_SKIPPED;
            out->n_iterations = 0;
            out->setpoint_reachable = 1;
            out->samples_without_measurement = s->gap;
            out->bad_solves_in_row = s->bad_in_row;
            out->rolled_back_samples = 0;
            out->preview_samples = n_preview;
            copy_status(out->solver_status, "skipped (mode off)");
            out->solver_outside_bounds_kw = ZERO;
            out->setpoint_kw = in->setpoint_kw;
            out->setpoint_used_kw = sp_used;
            out->innovation_kw = ZERO;
            out->innovation_std_kw = (czmpc_real)NAN;
            out->disturbance_estimate = s->z[CZMPC_NX];
            out->disturbance_power_kw = s->z[CZMPC_NX] * (czmpc_real)CZMPC_D_POWER_GAIN;
            out->target_w = out->target_triac_pct = out->target_power_kw = (czmpc_real)NAN;
            out->slack_kw = ZERO;
            out->advised_triac_pct = out->applied_triac_pct = triac;
            out->triac_min_pct = s->lim_lo + (czmpc_real)CZMPC_S_NOM_PCT;
            out->triac_max_pct = s->lim_hi + (czmpc_real)CZMPC_S_NOM_PCT;
            out->voltage_factor_used = CZMPC_SQRT(s->v2);
        }
        s->k += 1;
        return triac;
    }

    measurement_update(s, power, &verdict, &reopened, &used, &std_kw, &rolled_back);
    d = s->z[CZMPC_NX];
    em = &s->lim_map;
    v_off = s->v_offset;
    if (s->v2 == ONE) {
        em_v = em;
    } else {
        scaled_map(s, em, &em_scaled);
        em_v = &em_scaled;
    }
    w_min = em_v->w_min + v_off;
    w_max = em_v->w_max + v_off;
    if (n_preview) {
        compute_target(s->preview[n_preview - 1] - (czmpc_real)CZMPC_P_NOM_KW, d, w_min, w_max, &t);
        reference_cost(s, sp_used, s->preview, n_preview, pv_low, pv_high, &t, w_min, w_max);
        has_q_offset = 1;
    } else {
        compute_target(sp_used - (czmpc_real)CZMPC_P_NOM_KW, d, w_min, w_max, &t);
        has_q_offset = !t.is_reachable;
        if (has_q_offset) reference_cost(s, sp_used, &sp_used, 1, sp_used, sp_used, &t, w_min, w_max);
    }
    ds_prev = s->ds_prev;
    solve_or_fall_back(s, &t, em, em_v, has_q_offset, &p);
    measurement_shed = s->gap > CZMPC_MAX_PREDICTED_SAMPLES;
    ds = guard_input(s, p.w0 - v_off, ds_prev, measurement_shed, &t, em_v, &ds_raw);
    if (mode == CZMPC_MODE_ON) {
        status = judge(s, used, &p, &t, ds, ds_raw, applied_differs,
                       measurement_shed || p.solver_shed);
        s->ds_prev = ds;
        s->w_prev = evaluate(em->c, ds);
    } else {
        status = CZMPC_STATUS_HELD;
    }
    for (i = 0; i < CZMPC_N; ++i) s->last_plan[i] = p.usable ? p.w[i] : (czmpc_real)NAN;
    if (out) {
        /* before the time update: the estimate this step used */
        out->innovation_kw = s->eps;
        out->disturbance_estimate = d;
        out->samples_without_measurement = s->gap;
    }
    s->w_eff_assumed = effective(s, s->w_prev);
    est_predict(s, s->w_eff_assumed);

    triac = (czmpc_real)CZMPC_S_NOM_PCT + s->ds_prev;
    if (out) {
        out->k = s->k;
        out->triac_pct = triac;
        out->mode = mode;
        out->status = status;
        out->fallback = p.fallback;
        out->measurement_used = used;
        out->verdict = verdict;
        out->level_change_accepted = reopened;
        out->setpoint_verdict = sp_verdict;
        out->voltage_verdict = v_verdict;
        out->solver_status_val = p.status_val;
        out->n_iterations = p.n_iterations;
        out->setpoint_reachable = t.is_reachable;
        out->bad_solves_in_row = s->bad_in_row;
        out->rolled_back_samples = rolled_back;
        out->preview_samples = n_preview;
        if (p.status_val == CZMPC_SOLVER_NONFINITE_DATA) {
            copy_status(out->solver_status, "non-finite problem data");
        } else {
#if CZMPC_SOLVER_DAQP
            copy_status(out->solver_status, daqp_status_text(p.status_val));
#else
            copy_status(out->solver_status, czmpc_qp_solver.info->status);
#endif
        }
        out->solver_outside_bounds_kw = p.outside_bounds_kw;
        out->setpoint_kw = in->setpoint_kw;
        out->setpoint_used_kw = sp_used;
        out->innovation_std_kw = std_kw;
        out->disturbance_power_kw = d * (czmpc_real)CZMPC_D_POWER_GAIN;
        out->target_w = t.w_s;
        out->target_triac_pct = (czmpc_real)CZMPC_S_NOM_PCT + inverse(em_v, t.w_s - v_off);
        out->target_power_kw = (czmpc_real)CZMPC_P_NOM_KW + t.y_s;
        out->slack_kw = p.slack_kw;
        out->advised_triac_pct = (czmpc_real)CZMPC_S_NOM_PCT + ds;
        out->applied_triac_pct = (czmpc_real)CZMPC_S_NOM_PCT + ds_prev;
        out->triac_min_pct = s->lim_lo + (czmpc_real)CZMPC_S_NOM_PCT;
        out->triac_max_pct = s->lim_hi + (czmpc_real)CZMPC_S_NOM_PCT;
        out->voltage_factor_used = CZMPC_SQRT(s->v2);
    }
    s->k += 1;
    return triac;
}

const czmpc_real *czmpc_planned_w(const czmpc_state *s) { return s->last_plan; }
long czmpc_n_fallbacks(const czmpc_state *s) { return s->n_fallbacks; }
long czmpc_n_inaccurate(const czmpc_state *s) { return s->n_inaccurate; }
long czmpc_n_rejected_measurements(const czmpc_state *s) { return s->n_rejected; }
long czmpc_n_shed_steps(const czmpc_state *s) { return s->n_shed; }
double czmpc_sampling_time_s(void) { return (double)CZMPC_TS_S; }
int czmpc_horizon_steps(void) { return CZMPC_N; }
unsigned long czmpc_sizeof_state(void) { return (unsigned long)sizeof(czmpc_state); }
unsigned long czmpc_sizeof_outputs(void) { return (unsigned long)sizeof(czmpc_outputs); }
unsigned long czmpc_sizeof_inputs(void) { return (unsigned long)sizeof(czmpc_inputs); }
unsigned long czmpc_sizeof_real(void) { return (unsigned long)sizeof(czmpc_real); }
