/*
 * servotune_gantry.c -- reference runtime of a fieldbus gantry (C99, integer only, no I/O,
 * no allocation). See servotune_gantry.h for the cycle, the constants and the digest layout.
 *
 * st_gantry_step mirrors the controller part of one cycle of the servotune gantry simulation
 * (servotune/arch/gantry/run.py, _gantry_kernel) statement by statement; the laws themselves
 * are servotune_rt.c's (st_axis_read, st_axis_control, st_sync_*).
 */
#include "servotune_gantry.h"


/* --- power-up ------------------------------------------------------------------------- */

void st_gantry_init(st_gantry_state_t *s)
{
    int a;
    int j;
    for (a = 0; a < 2; a++) {
        st_axis_init(&s->drive[a]);
        for (j = 0; j <= ST_GANTRY_MAX_LATENCY; j++) {
            s->y_hist[a][j] = 0;
        }
        s->stop_cycle[a] = 0;
    }
    s->sync.integ = 0;
    s->sync.e_prev = 0;
    s->cycle = 0;
    s->tripped = 0;
    s->sync_entered = 0;
}

/* --- constants check -------------------------------------------------------------------- */

/* one drive: 0 or the field code f of the header (100 * (drive + 1) is added by the caller).
 * The drive is checked as servotune_rt checks a one-axis runtime (st_check_consts), whose
 * codes 1 + (2..7) name the same fields as codes 2..7 here (lock_f, kp_f, kit_f, fe_limit,
 * counter_bits, the D/A range) and codes 1 + (17, 18) its output filters (10 here); a gantry
 * drive must also run the PI law (1) and have no reference axis (8); any other field
 * st_check_consts refuses is 9. */
static int check_drive(const st_axis_consts_t *x)
{
    st_consts_t one;
    int r;
    if (x->law != ST_LAW_PI) {
        return 1;
    }
    one.n_axes = 1;
    one.timer_divisor = 0;
    one.axis[0] = *x;
    r = st_check_consts(&one);
    if (r == 0) {
        return 0;
    }
    if (r - 1 >= 2 && r - 1 <= 7) {
        return r - 1;
    }
    if (r - 1 == 17 || r - 1 == 18) { /* CHK_N_FILTERS, CHK_FILTER */
        return 10;
    }
    return x->ref_source != -1 ? 8 : 9;
}

int st_gantry_check(const st_gantry_consts_t *c)
{
    int a;
    int r;
    if (c->topology < ST_TOPO_PARALLEL || c->topology > ST_TOPO_CROSS) {
        return 1;
    }
    if (c->latency < 0 || c->latency > ST_GANTRY_MAX_LATENCY) {
        return 2;
    }
    for (a = 0; a < 2; a++) {
        r = check_drive(&c->drive[a]);
        if (r != 0) {
            return 100 * (a + 1) + r;
        }
    }
    r = st_check_sync_consts(&c->sync);
    if (r != 0) {
        return 300 + r;
    }
    return 0;
}

/* --- digest ----------------------------------------------------------------------------- */

/* one number of the layout: little-endian two's-complement int64 */
static void put_i64(st_sha256_ctx_t *h, int64_t v)
{
    const uint64_t u = (uint64_t)v; /* modulo 2^64: two's complement */
    uint8_t b[8];
    int j;
    for (j = 0; j < 8; j++) {
        b[j] = (uint8_t)((u >> (8 * j)) & 0xFFu);
    }
    st_sha256_update(h, b, 8);
}

void st_gantry_sha256(const st_gantry_consts_t *c, uint8_t out[32])
{
    st_sha256_ctx_t h;
    int a;
    int k;
    st_sha256_init(&h);
    put_i64(&h, c->topology);
    put_i64(&h, c->latency);
    for (a = 0; a < 2; a++) {
        const st_axis_consts_t *x = &c->drive[a];
        put_i64(&h, x->law);
        put_i64(&h, x->lock_q);
        put_i64(&h, x->lock_f);
        put_i64(&h, x->kp_q);
        put_i64(&h, x->kp_f);
        put_i64(&h, x->kit_q);
        put_i64(&h, x->kit_f);
        put_i64(&h, x->fe_limit);
        put_i64(&h, x->counter_bits);
        put_i64(&h, x->dac_zero);
        put_i64(&h, x->dac_max);
        put_i64(&h, x->n_filters);
        for (k = 0; k < ST_MAX_FILTERS; k++) {
            /* every slot as compiled in: one past n_filters is zero in an exported header */
            const st_section_t *q = &x->filter[k];
            put_i64(&h, q->b0);
            put_i64(&h, q->b1);
            put_i64(&h, q->b2);
            put_i64(&h, q->a1);
            put_i64(&h, q->a2);
            put_i64(&h, q->frac_bits);
        }
    }
    put_i64(&h, c->sync.kp_q);
    put_i64(&h, c->sync.kp_f);
    put_i64(&h, c->sync.kit_q);
    put_i64(&h, c->sync.kit_f);
    put_i64(&h, c->sync.kdt_q);
    put_i64(&h, c->sync.kdt_f);
    put_i64(&h, c->sync.dead_zone);
    put_i64(&h, c->sync.limit);
    put_i64(&h, c->sync.warn);
    put_i64(&h, c->sync.trip);
    st_sha256_final(&h, out);
}

int st_gantry_check_digest(const st_gantry_consts_t *c, const uint8_t sha256[32])
{
    uint8_t d[32];
    unsigned diff = 0;
    int j;
    if (sha256 == NULL) {
        return ST_GANTRY_DIGEST_MISMATCH;
    }
    st_gantry_sha256(c, d);
    for (j = 0; j < 32; j++) {
        diff |= (unsigned)(d[j] ^ sha256[j]);
    }
    return diff == 0 ? ST_GANTRY_DIGEST_OK : ST_GANTRY_DIGEST_MISMATCH;
}

/* --- one bus cycle ---------------------------------------------------------------------- */

void st_gantry_step(const st_gantry_consts_t *c, st_gantry_state_t *s, const st_gantry_in_t *in,
                    st_gantry_out_t *out)
{
    const int64_t k = s->cycle;
    const int reset = in->reset != 0;
    const int topo = c->topology;
    const int listening = topo == ST_TOPO_LISTENING;
    /* L, kept inside the history even for constants st_gantry_check would reject */
    const int64_t lat = c->latency < 0 ? 0
                        : c->latency > ST_GANTRY_MAX_LATENCY ? ST_GANTRY_MAX_LATENCY
                                                             : c->latency;
    /* cycle k's slot in the history, and cycle k - L's: (k + 1) mod (L + 1) */
    const size_t slot = (size_t)((uint64_t)k % (uint64_t)(lat + 1));
    const size_t slot_old = slot == (size_t)lat ? 0 : slot + 1;
    const int seen = k >= lat; /* the sync error of cycle k - L has arrived */
    int64_t comp = 0;
    int64_t r_m;
    int64_t r_s;
    int a;

    /* 0. the operator's reset: the trip cleared, the drives' faults with their laws (5.) */
    if (reset) {
        s->tripped = 0;
        s->stop_cycle[0] = 0;
        s->stop_cycle[1] = 0;
        s->sync_entered = 0;
    }
    /* 1. read and unwrap both counters (re-initialised from this read on a reset) */
    for (a = 0; a < 2; a++) {
        out->y[a] = st_axis_read(&s->drive[a], &c->drive[a], in->counter[a], reset);
        s->y_hist[a][slot] = out->y[a];
    }
    out->sync_op = ST_SYNC_OP_NONE;
    out->sync_input = 0;
    out->sync_comp = 0;
    out->sync_level = ST_SYNC_OK;
    if (seen) {
        /* 2. the sync error as the slave / the CNC sees it: measured, L cycles old */
        const int64_t e_seen = st_wrap_sub(s->y_hist[0][slot_old], s->y_hist[1][slot_old]);
        /* 3. the monitor; the first trip latches and schedules the stops */
        const int lv = st_sync_monitor(e_seen, c->sync.warn, c->sync.trip);
        const int64_t next = k < INT64_MAX ? k + 1 : k;
        out->sync_level = lv;
        if (lv == ST_SYNC_TRIP && !s->tripped) {
            s->tripped = 1;
            s->stop_cycle[1] = listening ? k : next; /* the listening slave stops at once */
            s->stop_cycle[0] = next;
        }
        /* 4. the compensator, while no trip is latched */
        if ((listening || topo == ST_TOPO_CROSS) && !s->tripped) {
            out->sync_input = e_seen;
            if (!s->sync_entered) {
                st_sync_enter(&c->sync, &s->sync, e_seen);
                out->sync_op = ST_SYNC_OP_ENTER;
                s->sync_entered = 1;
            } else {
                comp = st_sync_step(&c->sync, &s->sync, e_seen);
                out->sync_op = ST_SYNC_OP_STEP;
            }
            out->sync_comp = comp;
        }
    }
    /* a stopped drive: ST_FLAG_SYNC_TRIP latched into its fault (0 V until a reset) */
    for (a = 0; a < 2; a++) {
        if (s->tripped && k >= s->stop_cycle[a]) {
            s->drive[a].fault |= ST_FLAG_SYNC_TRIP;
        }
    }
    /* 5. the references by topology */
    r_m = in->command;
    r_s = in->command;
    if (topo == ST_TOPO_FOLLOWING && seen) {
        r_s = s->y_hist[0][slot_old];
    } else if (listening) {
        r_s = st_wrap_add(in->command, comp);
    } else if (topo == ST_TOPO_CROSS) {
        const int64_t half = st_shift_round(comp, 1); /* |comp| <= limit < 2^31 */
        r_m = st_wrap_sub(in->command, half);
        r_s = st_wrap_add(in->command, comp - half);
    }
    out->ref[0] = r_m;
    out->ref[1] = r_s;
    /* the drives' laws, task mode, with the operator's reset; a drive the monitor stops in
     * this very cycle keeps its fault (the reset is refused) */
    for (a = 0; a < 2; a++) {
        const int stopped = s->tripped && k >= s->stop_cycle[a];
        (void)st_axis_control(&s->drive[a], &c->drive[a], a == 0 ? r_m : r_s, ST_MODE_TASK,
                              reset && !stopped, 0, &out->code[a], &out->flags[a]);
    }
    out->tripped = s->tripped;
    if (s->cycle < INT64_MAX) {
        s->cycle++;
    }
}
