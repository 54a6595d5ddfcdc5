/*
 * servotune_rt.c -- reference runtime of servotune (C99, integer only, no I/O).
 *
 * Every function below mirrors one Python function line by line; the Python name is given
 * above each. Arithmetic rules (servotune's
 * docs/runtime.md#fixed-point-constants and the sections after it):
 *   - no right shift of a negative value and no left shift of a negative value (shift_round
 *     rounds the magnitude and restores the sign; align multiplies by 2^k);
 *   - products are int64 of an int32-bounded gain and an error clamped to +-(2^31 - 1), so
 *     they cannot overflow (scheduled gains are bounded by 2^32 - 1: st_check_consts);
 *   - sums that could overflow saturate (st_sat_add);
 *   - differences of positions and references (e, ec, dr, the unwrapped position) are formed
 *     modulo 2^64 in unsigned arithmetic and converted back without implementation-defined
 *     behaviour, which is what the Python (numba int64) code does; they only wrap for
 *     positions beyond +-2^62 counts, never on a real axis.
 * There is no undefined behaviour for any input once st_check_consts() (st_check_sync_consts()
 * for the sync compensator) accepted the constants.
 */
#include "servotune_rt.h"

#define ST_INT64_MAX INT64_MAX
#define ST_E_MAX ((int64_t)2147483647) /* fixed.E_MAX = 2^31 - 1 */

/* --- modular int64 arithmetic (numba's int64 wraps) ----------------------------------- */

static int64_t from_u64(uint64_t u)
{
    if (u <= (uint64_t)INT64_MAX) {
        return (int64_t)u;
    }
    return -(int64_t)(UINT64_MAX - u) - 1;
}

int64_t st_wrap_add(int64_t a, int64_t b)
{
    return from_u64((uint64_t)a + (uint64_t)b);
}

int64_t st_wrap_sub(int64_t a, int64_t b)
{
    return from_u64((uint64_t)a - (uint64_t)b);
}

/* --- servotune/fixed.py ------------------------------------------------------------------ */

/* fixed.shift_round: x * 2^-f rounded half away from zero, for f >= 1 and x > INT64_MIN. */
int64_t st_shift_round(int64_t x, int f)
{
    int64_t m;
    if (x >= 0) {
        return (x >> f) + ((x >> (f - 1)) & 1);
    }
    m = -x;
    return -((m >> f) + ((m >> (f - 1)) & 1));
}

/* fixed.sat_add: a + b saturated to +-INT64_MAX (INT64_MIN is never produced). */
int64_t st_sat_add(int64_t a, int64_t b)
{
    int64_t s;
    if (b > 0 && a > ST_INT64_MAX - b) {
        return ST_INT64_MAX;
    }
    if (b < 0 && a < -ST_INT64_MAX - b) {
        return -ST_INT64_MAX;
    }
    s = a + b;
    if (s < -ST_INT64_MAX) {
        return -ST_INT64_MAX;
    }
    return s;
}

/* fixed.align: x * 2^k for k >= 0, saturated to +-INT64_MAX; exact when it fits. */
int64_t st_align(int64_t x, int k)
{
    int64_t lim;
    if (k == 0) {
        return x;
    }
    lim = ST_INT64_MAX >> k;
    if (x > lim) {
        return ST_INT64_MAX;
    }
    if (x < -lim) {
        return -ST_INT64_MAX;
    }
    return x * ((int64_t)1 << k);
}

/* fixed.clamp_e: clamp an error, error change or reference change to +-(2^31 - 1). */
int64_t st_clamp_e(int64_t x)
{
    if (x > ST_E_MAX) {
        return ST_E_MAX;
    }
    if (x < -ST_E_MAX) {
        return -ST_E_MAX;
    }
    return x;
}

/* --- servotune/hw/counter.py ------------------------------------------------------------ */

/* counter.assemble: the register from its bytes, low first (counter_bits / 8 bytes). */
int64_t st_assemble(const uint8_t *bytes, int counter_bits)
{
    int64_t raw = 0;
    int j;
    for (j = 0; j < counter_bits / 8; j++) {
        raw |= (int64_t)bytes[j] << (8 * j);
    }
    return raw;
}

/* the high byte of a register value (never a shift of a negative value) */
static int64_t high_byte(int64_t raw, int bits)
{
    return (int64_t)(((uint64_t)raw >> (bits - 8)) & 0xFFu);
}

/* wraps * 2^bits + raw, modulo 2^64 as in numba */
static int64_t extend(int64_t wraps, int64_t raw, int bits)
{
    return from_u64((uint64_t)wraps * ((uint64_t)1 << bits) + (uint64_t)raw);
}

/* counter.unwrap_step: the high-byte rule. Returns 1 if the high byte moved by anything
 * other than 0, +-1 or +-255 (a counter fault). */
int st_unwrap_step(int64_t raw, int64_t *hi_prev, int64_t *wraps, int counter_bits,
                   int64_t *position)
{
    const int64_t hi = high_byte(raw, counter_bits);
    const int64_t dh = hi - *hi_prev;
    int fault = 0;
    if (dh == -255) {
        *wraps = st_wrap_add(*wraps, 1);
    } else if (dh == 255) {
        *wraps = st_wrap_sub(*wraps, 1);
    } else if (dh > 1 || dh < -1) {
        fault = 1;
    }
    *position = extend(*wraps, raw, counter_bits);
    *hi_prev = hi;
    return fault;
}

/* --- servotune/laws/lock.py, pi.py, fuzzy_pid.py ---------------------------------------- */

/* lock.lock_step: u_q = Kl * e [LSB, ST_F_U fraction bits]. */
static int64_t lock_step(int64_t kl_q, int64_t kl_f, int64_t e)
{
    return st_align(kl_q * st_clamp_e(e), ST_F_U - (int)kl_f);
}

/* the integrator's span: the D/A span in ST_F_U fraction bits */
static int64_t clamp_integ(int64_t integ, int64_t zero, int64_t code_max)
{
    const int64_t i_max = (code_max - zero) * ((int64_t)1 << ST_F_U);
    const int64_t i_min = -zero * ((int64_t)1 << ST_F_U);
    if (integ > i_max) {
        return i_max;
    }
    if (integ < i_min) {
        return i_min;
    }
    return integ;
}

/* pi.pi_step: one PI tick with conditional integration. Returns u_q; *integ := I(k). */
static int64_t pi_step(int64_t kp_q, int64_t kp_f, int64_t kit_q, int64_t kit_f,
                       int64_t *integ, int64_t e, int64_t u_add, int64_t zero,
                       int64_t code_max)
{
    const int64_t ec = st_clamp_e(e);
    const int64_t p_term = st_align(kp_q * ec, ST_F_U - (int)kp_f);
    const int64_t d_i = st_align(kit_q * ec, ST_F_U - (int)kit_f);
    /* I is bounded by its rails (the D/A span, 2^11 * 2^32 = 2^43 for 12 bits; for the sync
     * law +-limit * 2^32 < 2^63), p_term and d_i are saturated, so only the saturating adds
     * below can overflow and they saturate. */
    const int64_t u_pre = st_sat_add(st_sat_add(st_sat_add(p_term, *integ), d_i), u_add);
    const int64_t raw = st_shift_round(u_pre, ST_F_U) + zero;
    if (!((raw > code_max && d_i > 0) || (raw < 0 && d_i < 0))) {
        *integ = clamp_integ(st_sat_add(*integ, d_i), zero, code_max);
    }
    return st_sat_add(st_sat_add(p_term, *integ), u_add);
}

/* pi.pi_enter: bumpless entry, I := (u_last - u_add) - Kp*e, clamped. Returns u_q. */
static int64_t pi_enter(int64_t kp_q, int64_t kp_f, int64_t u_last, int64_t e, int64_t u_add,
                        int64_t zero, int64_t code_max, int64_t *integ)
{
    const int64_t p_term = st_align(kp_q * st_clamp_e(e), ST_F_U - (int)kp_f);
    *integ = clamp_integ(st_sat_add(st_sat_add(u_last, -u_add), -p_term), zero, code_max);
    return st_sat_add(st_sat_add(p_term, *integ), u_add);
}

/* fuzzy_pid.fuzzy_level: clamp(shift_round(clamp_e(x) * K_q, f_K), -n, n). */
static int64_t fuzzy_level(int64_t x, int64_t k_q, int64_t k_f, int64_t n)
{
    const int64_t p = st_clamp_e(x) * k_q; /* |x| < 2^31, |K_q| < 2^31: fits int64 */
    const int64_t lv = k_f > 0 ? st_shift_round(p, (int)k_f) : p;
    if (lv > n) {
        return n;
    }
    if (lv < -n) {
        return -n;
    }
    return lv;
}

/* fuzzy_pid.scheduled_gain: Kx0 + dKx in q units at the base's f (entry aligned by 2^(f-f_t)).
 * |entry * 2^(f - f_t)| <= 2^15 * 2^32 and |base| < 2^31: no overflow. */
static int64_t scheduled_gain(int64_t base_q, int64_t base_f, int64_t t_q, int64_t t_f)
{
    return base_q + st_align(t_q, (int)(base_f - t_f));
}

/* fuzzy_pid.feed_terms: (Kd/T)*ec + (K1/T)*dr [LSB, ST_F_U fraction bits]. */
static int64_t feed_terms(int64_t kd_q, int64_t kd_f, int64_t k1_q, int64_t k1_f, int64_t ec,
                          int64_t dr)
{
    const int64_t d = st_align(kd_q * st_clamp_e(ec), ST_F_U - (int)kd_f);
    const int64_t ff = st_align(k1_q * st_clamp_e(dr), ST_F_U - (int)k1_f);
    return st_sat_add(d, ff);
}

/* --- servotune/laws/sync.py ------------------------------------------------------------- */
/* Bounds (st_check_sync_consts): q in int32, 0 <= f <= ST_F_U, 0 <= dead_zone,
 * 1 <= limit <= 2^31 - 1. Then every product is int32 x (error clamped to +-(2^31 - 1)), and
 * the rails +-limit * 2^ST_F_U < 2^63 fit int64 (the bound that keeps the arithmetic exact);
 * pi_step and feed_terms saturate the rest. */

/* sync.dead_zone: e clamped to +-(2^31 - 1), then moved towards 0 by dz (0 inside +-dz). */
int64_t st_dead_zone(int64_t e, int64_t dz)
{
    e = st_clamp_e(e);
    if (e > dz) {
        return e - dz; /* 0 <= dz < e < 2^31 */
    }
    if (e < -dz) {
        return e + dz; /* -2^31 < e < -dz <= 0 */
    }
    return 0;
}

/* sync.sync_enter: bumpless enable, integ := -Kp*e_d (clamped to the rails), e_prev := e_d. */
void st_sync_enter(const st_sync_consts_t *c, st_sync_state_t *s, int64_t e)
{
    const int64_t e_d = st_dead_zone(e, c->dead_zone);
    /* |kp_q * e_d| <= 2^31 * (2^31 - 1) < 2^63; st_align never returns INT64_MIN, so the negation is exact */
    int64_t integ = -st_align(c->kp_q * e_d, ST_F_U - (int)c->kp_f);
    const int64_t i_max = c->limit * ((int64_t)1 << ST_F_U); /* limit < 2^31: < 2^63 */
    if (integ > i_max) {
        integ = i_max;
    } else if (integ < -i_max) {
        integ = -i_max;
    }
    s->integ = integ;
    s->e_prev = e_d;
}

/* sync.sync_step: one tick; returns the compensation [counts] within +-limit. */
int64_t st_sync_step(const st_sync_consts_t *c, st_sync_state_t *s, int64_t e)
{
    const int64_t e_d = st_dead_zone(e, c->dead_zone);
    /* e_d - e_prev: |e_d| < 2^31 and e_prev is a previous e_d, so it never wraps; formed
     * modulo 2^64 (as numba does) so that no state can make it undefined */
    const int64_t d_term = feed_terms(c->kdt_q, c->kdt_f, 0, 0, st_wrap_sub(e_d, s->e_prev), 0);
    /* the PI core with its rails at +-limit: pi_step's "zero code" is limit, its top 2*limit
     * (2 * limit < 2^32; the integrator is clamped to +-limit * 2^ST_F_U < 2^63) */
    const int64_t u_q = pi_step(c->kp_q, c->kp_f, c->kit_q, c->kit_f, &s->integ, e_d, d_term,
                                c->limit, 2 * c->limit);
    int64_t comp = st_shift_round(u_q, ST_F_U); /* u_q > INT64_MIN: st_sat_add's result */
    if (comp > c->limit) {
        comp = c->limit;
    } else if (comp < -c->limit) {
        comp = -c->limit;
    }
    s->e_prev = e_d;
    return comp;
}

/* sync.sync_monitor: ST_SYNC_TRIP if |e| >= trip (trip > 0), ST_SYNC_WARN if |e| >= warn
 * (warn > 0), else ST_SYNC_OK. |e| is formed modulo 2^64 as numba does: |INT64_MIN| stays
 * INT64_MIN (negative), so that one value reads as ST_SYNC_OK, exactly as in the Python. */
int st_sync_monitor(int64_t e, int64_t warn, int64_t trip)
{
    int64_t a = st_clamp_e(e); /* |e| of any int64 (INT64_MIN included), saturated */
    if (a < 0) {
        a = -a;
    }
    if (trip > 0 && a >= trip) {
        return ST_SYNC_TRIP;
    }
    if (warn > 0 && a >= warn) {
        return ST_SYNC_WARN;
    }
    return ST_SYNC_OK;
}

/* --- servotune/laws/axis.py ------------------------------------------------------------- */

/* axis.axis_read: unwrap one read with the high-byte rule, flag a counter fault. Returns the
 * extended position relative to the first read (the power-up home). */
int64_t st_axis_read(st_axis_state_t *s, const st_axis_consts_t *c, int64_t raw, int reset)
{
    const int bits = c->counter_bits;
    int64_t ext;
    int64_t y;
    if (s->init == 0) {
        s->origin = raw;
        s->wraps = 0;
        s->lock_target = 0;
        s->r_prev = 0;
        s->init = 1;
        reset = 1;
    }
    if (reset) {
        s->hi_prev = high_byte(raw, bits);
        y = st_wrap_sub(extend(s->wraps, raw, bits), s->origin);
        s->y = y;
        return y;
    }
    if (st_unwrap_step(raw, &s->hi_prev, &s->wraps, bits, &ext)) {
        s->fault |= ST_FLAG_COUNTER_FAULT;
    }
    y = st_wrap_sub(ext, s->origin);
    s->y = y;
    return y;
}

/* axis.filter_chain: the output filters of one axis (nf sections, in order) on x [D/A codes
 * relative to the zero, ST_FILTER_F fraction bits]; returns whole codes relative to the zero
 * and sets *held if a section's input was held at a rail. Each section's input is first held
 * to the D/A's range (-zero .. cmax - zero codes), the bound its sums were checked for at
 * export; the output is rounded half away from zero. */
static int64_t filter_chain(st_axis_state_t *s, const st_axis_consts_t *c, int64_t nf,
                            int64_t x, int64_t zero, int64_t cmax, int *held)
{
    const int64_t lo = -zero * ((int64_t)1 << ST_FILTER_F);
    const int64_t hi = (cmax - zero) * ((int64_t)1 << ST_FILTER_F);
    int64_t k;
    *held = 0;
    for (k = 0; k < nf; k++) {
        if (x < lo || x > hi) {
            *held = 1;
            x = x < lo ? lo : x;
            x = x > hi ? hi : x; /* min(max(x, lo), hi) */
        }
        x = st_biquad_step(&c->filter[k], s->filt[k], x); /* filters.biquad_step */
    }
    return st_shift_round(x, ST_FILTER_F);
}

/* axis.axis_control: one axis's control step after st_axis_read. Writes the D/A code and the
 * flags; returns the law's error e [counts] (0 in open mode or under a fault). */
int64_t st_axis_control(st_axis_state_t *s, const st_axis_consts_t *c, int64_t ref,
                        int64_t mode_cmd, int reset, int64_t u_add, int32_t *code_out,
                        int32_t *flags_out)
{
    const int64_t zero = c->dac_zero;
    const int64_t cmax = c->dac_max;
    const int64_t y = s->y;
    int entering;
    int64_t u_add_q;
    int64_t e = 0;
    int64_t u;
    int64_t fe;
    int64_t nf;
    int64_t code;
    int64_t flags;
    if (reset) {
        int k;
        int j;
        s->fault = 0;
        s->mode = ST_MODE_LOCK;
        s->lock_target = y;
        s->integ = 0;
        s->u_last = 0;
        s->e_prev = 0;
        s->r_prev = ref;
        for (k = 0; k < ST_MAX_FILTERS; k++) {
            for (j = 0; j < ST_FILTER_STATE; j++) {
                s->filt[k][j] = 0;
            }
        }
    }
    if (s->fault != 0) {
        s->u_last = 0;
        *code_out = (int32_t)zero;
        *flags_out = (int32_t)s->fault;
        return 0;
    }
    if (mode_cmd == ST_MODE_TASK && c->law == ST_LAW_NONE) {
        mode_cmd = ST_MODE_LOCK; /* no task law: the lock keeps the axis */
    }
    entering = mode_cmd == ST_MODE_TASK && s->mode != ST_MODE_TASK;
    if (mode_cmd == ST_MODE_LOCK && s->mode != ST_MODE_LOCK) {
        s->lock_target = y;
    }
    s->mode = mode_cmd;
    u_add_q = st_align(u_add, ST_F_U);
    if (mode_cmd == ST_MODE_LOCK) {
        e = st_wrap_sub(s->lock_target, y);
        u = st_sat_add(lock_step(c->lock_q, c->lock_f, e), u_add_q);
    } else if (mode_cmd == ST_MODE_TASK) {
        int64_t kp_q = c->kp_q;
        int64_t kit_q = c->kit_q;
        e = st_wrap_sub(ref, y);
        if (c->law == ST_LAW_FUZZY_PID) {
            /* composite law: schedule the gains from the query tables at (E, EC), then the PI
             * core with the derivative and feedforward terms added to its output */
            const int64_t ec = entering ? 0 : st_wrap_sub(e, s->e_prev);
            const int64_t dr = entering ? 0 : st_wrap_sub(ref, s->r_prev);
            const int64_t n = c->n;
            const int64_t size = 2 * n + 1;
            const int64_t lv_e = fuzzy_level(e, c->ke_q, c->ke_f, n);
            const int64_t lv_ec = fuzzy_level(ec, c->kec_q, c->kec_f, n);
            const int64_t cell = (lv_e + n) * size + lv_ec + n;
            int64_t kd_q;
            int64_t k1_q;
            kp_q = scheduled_gain(kp_q, c->kp_f, c->tab[ST_TAB_KP][cell], c->tf[ST_TAB_KP]);
            kit_q = scheduled_gain(kit_q, c->kit_f, c->tab[ST_TAB_KI][cell], c->tf[ST_TAB_KI]);
            kd_q = scheduled_gain(c->kdt_q, c->kdt_f, c->tab[ST_TAB_KD][cell],
                                  c->tf[ST_TAB_KD]);
            k1_q = scheduled_gain(c->k1t_q, c->k1t_f, c->tab[ST_TAB_K1][cell],
                                  c->tf[ST_TAB_K1]);
            u_add_q = st_sat_add(u_add_q, feed_terms(kd_q, c->kdt_f, k1_q, c->k1t_f, ec, dr));
        }
        if (entering) {
            u = pi_enter(kp_q, c->kp_f, s->u_last, e, u_add_q, zero, cmax, &s->integ);
        } else {
            u = pi_step(kp_q, c->kp_f, kit_q, c->kit_f, &s->integ, e, u_add_q, zero, cmax);
        }
    } else {
        u = u_add_q;
    }
    fe = c->fe_limit;
    if (fe > 0 && (e > fe || e < -fe)) {
        s->fault |= ST_FLAG_FOLLOWING_ERROR;
        s->u_last = 0;
        *code_out = (int32_t)zero;
        *flags_out = (int32_t)s->fault;
        return e;
    }
    s->u_last = u;
    s->e_prev = e;
    s->r_prev = ref;
    nf = c->n_filters;
    flags = s->fault;
    if (nf == 0) {
        code = st_shift_round(u, ST_F_U) + zero; /* dac.code_from_uq, with the rail flag */
    } else {
        int held;
        code = filter_chain(s, c, nf, st_shift_round(u, ST_F_U - ST_FILTER_F), zero, cmax,
                            &held)
               + zero;
        if (held) {
            flags |= ST_FLAG_SATURATED;
        }
    }
    if (code > cmax) {
        code = cmax;
        flags |= ST_FLAG_SATURATED;
    } else if (code < 0) {
        code = 0;
        flags |= ST_FLAG_SATURATED;
    }
    *code_out = (int32_t)code;
    *flags_out = (int32_t)flags;
    return e;
}

/* --- the tick (engine._run_group, steps 1-4) ------------------------------------------- */

void st_axis_init(st_axis_state_t *x)
{
    int k;
    int j;
    x->init = 0;
    x->hi_prev = 0;
    x->wraps = 0;
    x->y = 0;
    x->mode = 0;
    x->fault = 0;
    x->lock_target = 0;
    x->integ = 0;
    x->u_last = 0;
    x->e_prev = 0;
    x->r_prev = 0;
    x->origin = 0;
    for (k = 0; k < ST_MAX_FILTERS; k++) {
        for (j = 0; j < ST_FILTER_STATE; j++) {
            x->filt[k][j] = 0;
        }
    }
}

void st_init(st_state_t *s)
{
    int a;
    for (a = 0; a < ST_MAX_AXES; a++) {
        st_axis_init(&s->axis[a]);
    }
}

void st_tick(const st_consts_t *c, st_state_t *s, const st_axis_in_t *in, st_axis_out_t *out)
{
    int a;
    /* 1-2. sample and unwrap, every axis (a slave uses its master's read of this tick) */
    for (a = 0; a < c->n_axes; a++) {
        const st_axis_consts_t *ca = &c->axis[a];
        const int64_t raw = st_assemble(in[a].bytes, ca->counter_bits);
        out[a].y = st_axis_read(&s->axis[a], ca, raw, in[a].reset != 0);
    }
    /* 3-4. control law and D/A code, every axis */
    for (a = 0; a < c->n_axes; a++) {
        const st_axis_consts_t *ca = &c->axis[a];
        const int32_t src = ca->ref_source;
        const int64_t ref = src < 0 ? in[a].ref : out[src].y;
        out[a].e = st_axis_control(&s->axis[a], ca, ref, in[a].mode, in[a].reset != 0,
                                   in[a].u_add, &out[a].code, &out[a].flags);
        out[a].mode = (int32_t)s->axis[a].mode;
    }
}

/* --- constants check -------------------------------------------------------------------- */

/* field codes of st_check_consts (returned as 1 + 100 * axis + code) */
enum {
    CHK_N_AXES = 0,
    CHK_LAW = 1,
    CHK_LOCK_F = 2,
    CHK_KP_F = 3,
    CHK_KIT_F = 4,
    CHK_FE_LIMIT = 5,
    CHK_COUNTER_BITS = 6,
    CHK_DAC = 7,
    CHK_KDT_F = 8,
    CHK_K1T_F = 9,
    CHK_KE_F = 10,
    CHK_KEC_F = 11,
    CHK_N = 12,
    CHK_TABLE = 13,
    CHK_TABLE_F = 14,
    CHK_SCHEDULED = 15,
    CHK_REF_SOURCE = 16,
    CHK_N_FILTERS = 17,
    CHK_FILTER = 18,
    CHK_SHAPER_N = 19,
    CHK_SHAPER = 20
};

/* a reference shaper: 0 .. ST_MAX_SHAPER_N taps (a table when there are any), each amplitude
 * 0 .. 2^15, summing to exactly 2^15 (shaping.check_taps; servotune_shaper.h st_shaper_check) */
static int shaper_ok(const st_axis_consts_t *x)
{
    int64_t sum = 0;
    int32_t i;
    if (x->shaper_n == 0) {
        return 1;
    }
    if (x->shaper_q == NULL) {
        return 0;
    }
    for (i = 0; i < x->shaper_n; i++) {
        if (x->shaper_q[i] < 0 || x->shaper_q[i] > ST_SHAPER_ONE) {
            return 0;
        }
        sum += x->shaper_q[i];
    }
    return sum == ST_SHAPER_ONE;
}

/* a filter section in use: frac_bits 1 .. 30 and a stable quantised denominator, as
 * filters.SectionQ.from_dict checks it (|a2| < 2^f, |a1| < 2^f + a2) */
static int section_ok(const st_section_t *q)
{
    int64_t one;
    if (q->frac_bits < 1 || q->frac_bits > 30) {
        return 0;
    }
    one = (int64_t)1 << q->frac_bits;
    return (q->a2 < 0 ? -(int64_t)q->a2 : (int64_t)q->a2) < one
           && (q->a1 < 0 ? -(int64_t)q->a1 : (int64_t)q->a1) < one + q->a2;
}

static int f_ok(int64_t f)
{
    return f >= 0 && f <= ST_F_U;
}

int st_check_consts(const st_consts_t *c)
{
    int a;
    if (c->n_axes < 1 || c->n_axes > ST_MAX_AXES) {
        return 1 + CHK_N_AXES;
    }
    for (a = 0; a < c->n_axes; a++) {
        const st_axis_consts_t *x = &c->axis[a];
        const int err = 1 + 100 * a;
        int k;
        if (x->law < ST_LAW_NONE || x->law > ST_LAW_FUZZY_PID) {
            return err + CHK_LAW;
        }
        if (!f_ok(x->lock_f)) {
            return err + CHK_LOCK_F;
        }
        if (!f_ok(x->kp_f)) {
            return err + CHK_KP_F;
        }
        if (!f_ok(x->kit_f)) {
            return err + CHK_KIT_F;
        }
        if (x->fe_limit < 0) {
            return err + CHK_FE_LIMIT;
        }
        if (x->counter_bits != 16 && x->counter_bits != 24 && x->counter_bits != 32) {
            return err + CHK_COUNTER_BITS;
        }
        if (x->dac_zero < 0 || x->dac_max < x->dac_zero || x->dac_max > 65535) {
            return err + CHK_DAC;
        }
        if (!f_ok(x->kdt_f)) {
            return err + CHK_KDT_F;
        }
        if (!f_ok(x->k1t_f)) {
            return err + CHK_K1T_F;
        }
        if (!f_ok(x->ke_f)) {
            return err + CHK_KE_F;
        }
        if (!f_ok(x->kec_f)) {
            return err + CHK_KEC_F;
        }
        if (x->ref_source != -1
            && (x->ref_source < 0 || x->ref_source >= c->n_axes || x->ref_source == a)) {
            return err + CHK_REF_SOURCE;
        }
        if (x->n_filters < 0 || x->n_filters > ST_MAX_FILTERS) {
            return err + CHK_N_FILTERS;
        }
        for (k = 0; k < x->n_filters; k++) {
            if (!section_ok(&x->filter[k])) {
                return err + CHK_FILTER;
            }
        }
        if (x->shaper_n < 0 || x->shaper_n > ST_MAX_SHAPER_N) {
            return err + CHK_SHAPER_N;
        }
        if (!shaper_ok(x)) {
            return err + CHK_SHAPER;
        }
        if (x->law == ST_LAW_FUZZY_PID) {
            const int32_t base_q[ST_N_TABLES] = {x->kp_q, x->kit_q, x->kdt_q, x->k1t_q};
            const int16_t base_f[ST_N_TABLES] = {x->kp_f, x->kit_f, x->kdt_f, x->k1t_f};
            int i;
            int64_t size;
            int64_t j;
            if (x->n < 1 || x->n > ST_MAX_LEVELS) {
                return err + CHK_N;
            }
            size = (2 * (int64_t)x->n + 1) * (2 * (int64_t)x->n + 1);
            for (i = 0; i < ST_N_TABLES; i++) {
                if (x->tab[i] == NULL) {
                    return err + CHK_TABLE;
                }
                if (x->tf[i] < 0 || x->tf[i] > base_f[i]) {
                    return err + CHK_TABLE_F;
                }
                for (j = 0; j < size; j++) {
                    /* the bound behind every product: 0 <= Kx0 + dKx <= 2^32 - 1 */
                    const int64_t g = scheduled_gain(base_q[i], base_f[i], x->tab[i][j],
                                                     x->tf[i]);
                    if (g < 0 || g > (int64_t)4294967295) {
                        return err + CHK_SCHEDULED;
                    }
                }
            }
        }
    }
    return 0;
}

/* axis.switch_filters: the axis's output filters become sec[0 .. n-1] between two ticks,
 * without a bump. The new sections' state is the chain's steady state at its last input x
 * and output y (filters.bumpless_state): section 0 x1 = x2 = x, y1 = y2 = y; every later one
 * x1 = x2 = y1 = y2 = y; remainders zero. x is section 0's last (held) input and y the last
 * section's last output; without filters before, both are u_last rounded to ST_FILTER_F
 * fraction bits and held to the D/A range. 1 if n is out of range, 2 + k if section k fails
 * the checks of st_check_consts (nothing changed then); 0 when switched. */
int st_axis_switch_filters(st_axis_consts_t *c, st_axis_state_t *s, int32_t n,
                           const st_section_t *sec)
{
    const int64_t zero = c->dac_zero;
    const int64_t lo = -zero * ((int64_t)1 << ST_FILTER_F);
    const int64_t hi = ((int64_t)c->dac_max - zero) * ((int64_t)1 << ST_FILTER_F);
    const int32_t nf = c->n_filters;
    int64_t x;
    int64_t y;
    int32_t k;
    int j;
    if (n < 0 || n > ST_MAX_FILTERS) {
        return 1;
    }
    for (k = 0; k < n; k++) {
        if (!section_ok(&sec[k])) {
            return 2 + k;
        }
    }
    if (nf > 0) {
        x = s->filt[0][0];
        y = s->filt[nf - 1][2];
    } else {
        x = st_shift_round(s->u_last, ST_F_U - ST_FILTER_F);
        x = x < lo ? lo : x;
        x = x > hi ? hi : x; /* min(max(x, lo), hi) */
        y = x;
    }
    c->n_filters = n;
    for (k = 0; k < ST_MAX_FILTERS; k++) {
        const st_section_t none = {0, 0, 0, 0, 0, 0};
        const int64_t held = k == 0 ? x : y;
        const int on = k < n;
        c->filter[k] = on ? sec[k] : none;
        s->filt[k][0] = on ? held : 0;
        s->filt[k][1] = on ? held : 0;
        s->filt[k][2] = on ? y : 0;
        s->filt[k][3] = on ? y : 0;
        for (j = 4; j < ST_FILTER_STATE; j++) {
            s->filt[k][j] = 0;
        }
    }
    return 0;
}

/* st_check_sync_consts: 1 + the index of the first bad field (header), 0 if valid. */
static int q_ok(int64_t q)
{
    return q >= INT32_MIN && q <= INT32_MAX; /* |q| <= 2^31, |e| < 2^31: |q * e| < 2^62 */
}

int st_check_sync_consts(const st_sync_consts_t *c)
{
    if (!q_ok(c->kp_q)) {
        return 1;
    }
    if (!f_ok(c->kp_f)) {
        return 2;
    }
    if (!q_ok(c->kit_q)) {
        return 3;
    }
    if (!f_ok(c->kit_f)) {
        return 4;
    }
    if (!q_ok(c->kdt_q)) {
        return 5;
    }
    if (!f_ok(c->kdt_f)) {
        return 6;
    }
    if (c->dead_zone < 0) {
        return 7;
    }
    if (c->limit < 1 || c->limit > (int64_t)2147483647) {
        return 8; /* sync.LIMIT_MAX_COUNTS: the rails +-limit * 2^ST_F_U fit int64 */
    }
    if (c->warn < 0) {
        return 9;
    }
    if (c->trip < 0) {
        return 10;
    }
    return 0;
}

/* --- integrity: the byte streams (docs/runtime.md#integrity-crcs-and-the-c-layout) ---- */

/* The constants and tables are serialised once, here, into a sink: the CRC-32s and the
 * SHA-256 of the C layout read the same bytes (servotune/export/layout.py). */
typedef void (*st_sink_fn)(void *ctx, const uint8_t *p, size_t len);

static void put_i16(st_sink_fn put, void *ctx, int64_t v)
{
    const uint16_t u = (uint16_t)v; /* modulo 2^16: two's complement, little-endian below */
    uint8_t b[2];
    b[0] = (uint8_t)(u & 0xFFu);
    b[1] = (uint8_t)((u >> 8) & 0xFFu);
    put(ctx, b, 2);
}

static void put_i32(st_sink_fn put, void *ctx, int64_t v)
{
    const uint32_t u = (uint32_t)v; /* modulo 2^32 */
    uint8_t b[4];
    b[0] = (uint8_t)(u & 0xFFu);
    b[1] = (uint8_t)((u >> 8) & 0xFFu);
    b[2] = (uint8_t)((u >> 16) & 0xFFu);
    b[3] = (uint8_t)((u >> 24) & 0xFFu);
    put(ctx, b, 4);
}

static void put_pair(st_sink_fn put, void *ctx, int64_t q, int64_t f)
{
    put_i32(put, ctx, q);
    put_i16(put, ctx, f);
}

/* One table: int16 n, int16 f, then the (2n+1)^2 int16 entries row-major. */
static void put_table(st_sink_fn put, void *ctx, int n, int f, const int16_t *q)
{
    const int64_t size = (2 * (int64_t)n + 1) * (2 * (int64_t)n + 1);
    int64_t j;
    put_i16(put, ctx, n);
    put_i16(put, ctx, f);
    for (j = 0; j < size; j++) {
        put_i16(put, ctx, q[j]);
    }
}

/* The constants as (q int32, f int16) pairs, in the order of the header comment
 * (servotune/export/json.py, layout.py part 1). */
static void put_consts(st_sink_fn put, void *ctx, const st_consts_t *c)
{
    int a;
    int k;
    put_pair(put, ctx, c->n_axes, 0);
    put_pair(put, ctx, c->timer_divisor, 0);
    for (a = 0; a < c->n_axes; a++) {
        const st_axis_consts_t *x = &c->axis[a];
        put_pair(put, ctx, x->law, 0);
        put_pair(put, ctx, x->lock_q, x->lock_f);
        put_pair(put, ctx, x->kp_q, x->kp_f);
        put_pair(put, ctx, x->kit_q, x->kit_f);
        put_pair(put, ctx, x->fe_limit, 0);
        put_pair(put, ctx, x->counter_bits, 0);
        put_pair(put, ctx, x->dac_zero, 0);
        put_pair(put, ctx, x->dac_max, 0);
        put_pair(put, ctx, x->kdt_q, x->kdt_f);
        put_pair(put, ctx, x->k1t_q, x->k1t_f);
        put_pair(put, ctx, x->ke_q, x->ke_f);
        put_pair(put, ctx, x->kec_q, x->kec_f);
        put_pair(put, ctx, x->n, 0);
        put_pair(put, ctx, x->ref_source, 0);
        put_pair(put, ctx, x->n_filters, 0);
        for (k = 0; k < ST_MAX_FILTERS; k++) {
            /* every slot as compiled in: one past n_filters is zero in an exported header */
            const st_section_t *q = &x->filter[k];
            put_pair(put, ctx, q->b0, q->frac_bits);
            put_pair(put, ctx, q->b1, q->frac_bits);
            put_pair(put, ctx, q->b2, q->frac_bits);
            put_pair(put, ctx, q->a1, q->frac_bits);
            put_pair(put, ctx, q->a2, q->frac_bits);
        }
    }
}

/* --- integrity: CRC-32 (IEEE 802.3, reflected, as zlib's crc32) ------------------------- */

uint32_t st_crc32(uint32_t crc, const uint8_t *p, size_t len)
{
    int k;
    crc = ~crc;
    while (len-- > 0) {
        crc ^= *p++;
        for (k = 0; k < 8; k++) {
            crc = (crc >> 1) ^ ((uint32_t)0xEDB88320 & ((uint32_t)0 - (crc & (uint32_t)1)));
        }
    }
    return ~crc;
}

static void crc_sink(void *ctx, const uint8_t *p, size_t len)
{
    uint32_t *crc = (uint32_t *)ctx;
    *crc = st_crc32(*crc, p, len);
}

/* The table CRC: int16 n, int16 f, then the (2n+1)^2 int16 entries row-major. */
uint32_t st_table_crc32(int n, int f, const int16_t *q)
{
    uint32_t crc = 0;
    put_table(crc_sink, &crc, n, f, q);
    return crc;
}

/* The constants CRC, in the order of the header comment (servotune/export/json.py). */
uint32_t st_consts_crc32(const st_consts_t *c)
{
    uint32_t crc = 0;
    put_consts(crc_sink, &crc, c);
    return crc;
}

/* --- integrity: SHA-256 (FIPS 180-4) ----------------------------------------------------- */
/* Written from FIPS 180-4: functions section 4.1.2, constants K section 4.2.2, padding
 * section 5.1.1, initial hash value section 5.3.3, computation section 6.2.2 (the message
 * schedule kept as a ring of 16 words). Words are big-endian. Every uint32_t result is reduced
 * modulo 2^32 by the assignment, whatever the width of int. */

static const uint32_t sha256_k[64] = {
    UINT32_C(0x428a2f98), UINT32_C(0x71374491), UINT32_C(0xb5c0fbcf), UINT32_C(0xe9b5dba5),
    UINT32_C(0x3956c25b), UINT32_C(0x59f111f1), UINT32_C(0x923f82a4), UINT32_C(0xab1c5ed5),
    UINT32_C(0xd807aa98), UINT32_C(0x12835b01), UINT32_C(0x243185be), UINT32_C(0x550c7dc3),
    UINT32_C(0x72be5d74), UINT32_C(0x80deb1fe), UINT32_C(0x9bdc06a7), UINT32_C(0xc19bf174),
    UINT32_C(0xe49b69c1), UINT32_C(0xefbe4786), UINT32_C(0x0fc19dc6), UINT32_C(0x240ca1cc),
    UINT32_C(0x2de92c6f), UINT32_C(0x4a7484aa), UINT32_C(0x5cb0a9dc), UINT32_C(0x76f988da),
    UINT32_C(0x983e5152), UINT32_C(0xa831c66d), UINT32_C(0xb00327c8), UINT32_C(0xbf597fc7),
    UINT32_C(0xc6e00bf3), UINT32_C(0xd5a79147), UINT32_C(0x06ca6351), UINT32_C(0x14292967),
    UINT32_C(0x27b70a85), UINT32_C(0x2e1b2138), UINT32_C(0x4d2c6dfc), UINT32_C(0x53380d13),
    UINT32_C(0x650a7354), UINT32_C(0x766a0abb), UINT32_C(0x81c2c92e), UINT32_C(0x92722c85),
    UINT32_C(0xa2bfe8a1), UINT32_C(0xa81a664b), UINT32_C(0xc24b8b70), UINT32_C(0xc76c51a3),
    UINT32_C(0xd192e819), UINT32_C(0xd6990624), UINT32_C(0xf40e3585), UINT32_C(0x106aa070),
    UINT32_C(0x19a4c116), UINT32_C(0x1e376c08), UINT32_C(0x2748774c), UINT32_C(0x34b0bcb5),
    UINT32_C(0x391c0cb3), UINT32_C(0x4ed8aa4a), UINT32_C(0x5b9cca4f), UINT32_C(0x682e6ff3),
    UINT32_C(0x748f82ee), UINT32_C(0x78a5636f), UINT32_C(0x84c87814), UINT32_C(0x8cc70208),
    UINT32_C(0x90befffa), UINT32_C(0xa4506ceb), UINT32_C(0xbef9a3f7), UINT32_C(0xc67178f2)
};

/* ROTR^n(x), 0 < n < 32 */
static uint32_t rotr32(uint32_t x, unsigned n)
{
    return (uint32_t)((x >> n) | (x << (32u - n)));
}

/* Ch(x, y, z) = (x AND y) XOR (NOT x AND z), written without a complement */
static uint32_t sha_ch(uint32_t x, uint32_t y, uint32_t z)
{
    return z ^ (x & (y ^ z));
}

/* Maj(x, y, z) = (x AND y) XOR (x AND z) XOR (y AND z) */
static uint32_t sha_maj(uint32_t x, uint32_t y, uint32_t z)
{
    return (x & y) | (z & (x | y));
}

static uint32_t sha_big_sigma0(uint32_t x)
{
    return rotr32(x, 2) ^ rotr32(x, 13) ^ rotr32(x, 22);
}

static uint32_t sha_big_sigma1(uint32_t x)
{
    return rotr32(x, 6) ^ rotr32(x, 11) ^ rotr32(x, 25);
}

static uint32_t sha_small_sigma0(uint32_t x)
{
    return rotr32(x, 7) ^ rotr32(x, 18) ^ (x >> 3);
}

static uint32_t sha_small_sigma1(uint32_t x)
{
    return rotr32(x, 17) ^ rotr32(x, 19) ^ (x >> 10);
}

/* one 512-bit block M(i): H(i) := H(i-1) + the 64 rounds */
static void sha256_block(uint32_t h[8], const uint8_t *m)
{
    uint32_t w[16];
    uint32_t a = h[0];
    uint32_t b = h[1];
    uint32_t c = h[2];
    uint32_t d = h[3];
    uint32_t e = h[4];
    uint32_t f = h[5];
    uint32_t g = h[6];
    uint32_t hh = h[7];
    int t;
    for (t = 0; t < 16; t++) {
        w[t] = ((uint32_t)m[4 * t] << 24) | ((uint32_t)m[4 * t + 1] << 16)
               | ((uint32_t)m[4 * t + 2] << 8) | (uint32_t)m[4 * t + 3];
    }
    for (t = 0; t < 64; t++) {
        uint32_t wt;
        uint32_t t1;
        uint32_t t2;
        if (t < 16) {
            wt = w[t];
        } else {
            /* W(t) = s1(W(t-2)) + W(t-7) + s0(W(t-15)) + W(t-16); w[t & 15] holds W(t-16) */
            wt = sha_small_sigma1(w[(t - 2) & 15]) + w[(t - 7) & 15]
                 + sha_small_sigma0(w[(t - 15) & 15]) + w[t & 15];
            w[t & 15] = wt;
        }
        t1 = hh + sha_big_sigma1(e) + sha_ch(e, f, g) + sha256_k[t] + wt;
        t2 = sha_big_sigma0(a) + sha_maj(a, b, c);
        hh = g;
        g = f;
        f = e;
        e = d + t1;
        d = c;
        c = b;
        b = a;
        a = t1 + t2;
    }
    h[0] += a;
    h[1] += b;
    h[2] += c;
    h[3] += d;
    h[4] += e;
    h[5] += f;
    h[6] += g;
    h[7] += hh;
}

void st_sha256_init(st_sha256_ctx_t *s)
{
    s->h[0] = UINT32_C(0x6a09e667);
    s->h[1] = UINT32_C(0xbb67ae85);
    s->h[2] = UINT32_C(0x3c6ef372);
    s->h[3] = UINT32_C(0xa54ff53a);
    s->h[4] = UINT32_C(0x510e527f);
    s->h[5] = UINT32_C(0x9b05688c);
    s->h[6] = UINT32_C(0x1f83d9ab);
    s->h[7] = UINT32_C(0x5be0cd19);
    s->n_bytes = 0;
    s->fill = 0;
}

void st_sha256_update(st_sha256_ctx_t *s, const uint8_t *p, size_t len)
{
    s->n_bytes += (uint64_t)len;
    while (len > 0) {
        if (s->fill == 0 && len >= 64) {
            sha256_block(s->h, p); /* whole blocks straight from the input */
            p += 64;
            len -= 64;
        } else {
            s->block[s->fill++] = *p++;
            len--;
            if (s->fill == 64) {
                sha256_block(s->h, s->block);
                s->fill = 0;
            }
        }
    }
}

void st_sha256_final(st_sha256_ctx_t *s, uint8_t out[32])
{
    /* length in bits, modulo 2^64 (messages are far shorter than 2^61 bytes) */
    const uint64_t bits = s->n_bytes * 8u;
    int j;
    /* padding: a 1 bit, zeros up to 448 bits modulo 512, then the 64-bit length */
    s->block[s->fill++] = 0x80u;
    if (s->fill > 56) {
        while (s->fill < 64) {
            s->block[s->fill++] = 0;
        }
        sha256_block(s->h, s->block);
        s->fill = 0;
    }
    while (s->fill < 56) {
        s->block[s->fill++] = 0;
    }
    for (j = 0; j < 8; j++) {
        s->block[56 + j] = (uint8_t)((bits >> (56 - 8 * j)) & 0xFFu);
    }
    sha256_block(s->h, s->block);
    s->fill = 0;
    for (j = 0; j < 8; j++) {
        out[4 * j] = (uint8_t)((s->h[j] >> 24) & 0xFFu);
        out[4 * j + 1] = (uint8_t)((s->h[j] >> 16) & 0xFFu);
        out[4 * j + 2] = (uint8_t)((s->h[j] >> 8) & 0xFFu);
        out[4 * j + 3] = (uint8_t)(s->h[j] & 0xFFu);
    }
}

void st_sha256(const uint8_t *p, size_t len, uint8_t out[32])
{
    st_sha256_ctx_t s;
    st_sha256_init(&s);
    st_sha256_update(&s, p, len);
    st_sha256_final(&s, out);
}

/* --- integrity: the digest of the compiled-in constants (C layout) ----------------------- */

static void sha_sink(void *ctx, const uint8_t *p, size_t len)
{
    st_sha256_update((st_sha256_ctx_t *)ctx, p, len);
}

/* The C layout (servotune/export/layout.py): the constants CRC's bytes, then for each
 * fuzzy-PID axis in order its four tables' CRC bytes (ST_TAB_* order). */
int st_consts_sha256(const st_consts_t *c, uint8_t out[32])
{
    st_sha256_ctx_t s;
    int a;
    int i;
    /* only what can be walked safely: the axes present, for fuzzy-PID n and the tables, and
     * a shaper's count and table */
    if (c->n_axes < 1 || c->n_axes > ST_MAX_AXES) {
        return ST_DIGEST_MALFORMED;
    }
    for (a = 0; a < c->n_axes; a++) {
        const st_axis_consts_t *x = &c->axis[a];
        if (x->shaper_n < 0 || x->shaper_n > ST_MAX_SHAPER_N
            || (x->shaper_n > 0 && x->shaper_q == NULL)) {
            return ST_DIGEST_MALFORMED;
        }
        if (x->law == ST_LAW_FUZZY_PID) {
            if (x->n < 1 || x->n > ST_MAX_LEVELS) {
                return ST_DIGEST_MALFORMED;
            }
            for (i = 0; i < ST_N_TABLES; i++) {
                if (x->tab[i] == NULL) {
                    return ST_DIGEST_MALFORMED;
                }
            }
        }
    }
    st_sha256_init(&s);
    put_consts(sha_sink, &s, c);
    for (a = 0; a < c->n_axes; a++) {
        const st_axis_consts_t *x = &c->axis[a];
        if (x->law == ST_LAW_FUZZY_PID) {
            for (i = 0; i < ST_N_TABLES; i++) {
                put_table(sha_sink, &s, x->n, x->tf[i], x->tab[i]);
            }
        }
    }
    for (a = 0; a < c->n_axes; a++) {
        const st_axis_consts_t *x = &c->axis[a];
        put_i32(sha_sink, &s, x->shaper_n);
        for (i = 0; i < x->shaper_n; i++) {
            put_i32(sha_sink, &s, x->shaper_q[i]);
        }
    }
    st_sha256_final(&s, out);
    return ST_DIGEST_OK;
}

int st_check_digest(const st_consts_t *c, const uint8_t expected[32])
{
    uint8_t d[32];
    unsigned diff = 0;
    int j;
    const int r = st_consts_sha256(c, d);
    if (r != ST_DIGEST_OK) {
        return r;
    }
    if (expected == NULL) {
        return ST_DIGEST_MISMATCH;
    }
    for (j = 0; j < 32; j++) {
        diff |= (unsigned)(d[j] ^ expected[j]);
    }
    return diff == 0 ? ST_DIGEST_OK : ST_DIGEST_MISMATCH;
}
