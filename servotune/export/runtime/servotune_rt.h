/*
 * servotune_rt.h -- reference runtime of servotune (C99, integer only, no I/O).
 *
 * A line-by-line mirror of the Python laws (servotune/laws/axis.py, pi.py, fuzzy_pid.py,
 * lock.py, servotune/fixed.py, servotune/hw/counter.py): the same integer arithmetic gives
 * the same D/A codes and fault flags, bit for bit (servotune's
 * docs/runtime.md).
 *
 * One tick (st_tick): for every axis, assemble the latched counter bytes (low, mid, high),
 * unwrap with the high-byte rule and flag a counter fault (st_axis_read); then for every axis,
 * run the law of its mode -- position lock, PI, or fuzzy-PID + feedforward -- with bumpless
 * lock/task handover, the following-error trip and latched faults, then the axis's output
 * filters (up to ST_MAX_FILTERS biquad sections in series, servotune_filter.h; docs/runtime.md
 * #filters-in-the-law) before the D/A code (st_axis_control). A slave's
 * reference is the position of the axis it follows, read in the same tick. The firmware reads
 * the counter card, calls st_tick and writes the returned codes to the D/A itself.
 *
 * The synchronisation compensator of a listening slave (servotune/laws/sync.py;
 * docs/systems.md#fieldbus-gantry-with-a-listening-slave) is a
 * separate set of calls (st_sync_enter, st_sync_step, st_sync_monitor) on its own constants
 * and state: the firmware feeds it the sync error y_master - y_slave [counts], adds the
 * returned compensation to the slave's position command, and on a monitor trip latches
 * ST_FLAG_SYNC_TRIP into both axes' fault (st_state_t.axis[a].fault |= ST_FLAG_SYNC_TRIP):
 * st_axis_control then holds them at mid-scale, as for any latched fault, until a reset.
 *
 * Constants come from servotune_tables.h (servotune export), whose SERVOTUNE_TABLES_INIT
 * initialises an st_consts_t; they are compiled in (there is no loader). Check them once at
 * start-up: st_check_digest(&consts, st_tables_sha256) recomputes the SHA-256 of the
 * compiled-in constants and tables in the C layout (below) and compares it with the exported
 * ST_TABLES_SHA256 (accidental edits, stale files, mix-ups); st_check_consts() checks the
 * ranges the arithmetic relies on. st_consts_crc32() / st_table_crc32() give the CRCs of the
 * same bytes, for comparison with the exported ones.
 *
 * Constants CRC (CRC-32 IEEE, as zlib's crc32): over (q int32, f int16) pairs, little-endian,
 * in this order; integers are pairs (value, 0), unused constants (0, 0):
 *   (n_axes, 0), (timer_divisor, 0), then for each axis a = 0 .. n_axes-1:
 *   (law, 0), (lock_q, lock_f), (kp_q, kp_f), (kit_q, kit_f), (fe_limit, 0),
 *   (counter_bits, 0), (dac_zero, 0), (dac_max, 0), (kdt_q, kdt_f), (k1t_q, k1t_f),
 *   (ke_q, ke_f), (kec_q, kec_f), (n, 0), (ref_source, 0), (n_filters, 0), then for each of
 *   the ST_MAX_FILTERS section slots k = 0 .. 3 (filter[k]): (b0, frac_bits), (b1, frac_bits),
 *   (b2, frac_bits), (a1, frac_bits), (a2, frac_bits) -- a slot k >= n_filters is all zero,
 *   five (0, 0). 35 pairs per axis.
 * Each table's CRC covers int16 n, int16 f, then its (2n+1)^2 int16 entries row-major
 * (row E = -n..n, column EC = -n..n), little-endian.
 *
 * C layout (SHA-256, st_consts_sha256 / st_check_digest; servotune/export/layout.py): the
 * constants CRC's bytes as above, then for each axis a = 0 .. n_axes-1 whose law is
 * ST_LAW_FUZZY_PID, for each table i = ST_TAB_KP, ST_TAB_KI, ST_TAB_KD, ST_TAB_K1, that
 * table CRC's bytes (int16 n, int16 tf[i], the entries), then for each axis a = 0 ..
 * n_axes-1 its shaper: int32 shaper_n, then its shaper_n int32 amplitudes (little-endian).
 * No padding, no length prefix.
 */
#ifndef SERVOTUNE_RT_H
#define SERVOTUNE_RT_H

#include <stddef.h>
#include <stdint.h>

#include "servotune_filter.h"

#ifdef __cplusplus
extern "C" {
#endif

#define ST_RT_VERSION 3 /* servotune.tables/4 */

#ifndef ST_MAX_AXES
#define ST_MAX_AXES 4 /* a slave CPU drives 2 to 4 axes (multi-CPU linkage) */
#endif

#define ST_F_U 32         /* fraction bits of u_q and of the integrator (fixed.F_U) */
#define ST_MAX_LEVELS 64  /* largest n of the query tables */
#define ST_N_TABLES 4     /* kp, ki, kd, k1 (fuzzy_pid.TABLE_NAMES order) */
#define ST_MAX_FILTERS 4  /* output filter sections per axis (axis.MAX_FILTERS) */
#define ST_FILTER_F 16    /* fraction bits of the filters' signal [D/A codes] (axis.FILTER_F) */
#define ST_MAX_SHAPER_N 1024 /* taps of a reference shaper (shaping.MAX_SHAPER_TAPS) */
#define ST_SHAPER_ONE 32768  /* the Q15 amplitudes' sum (2^15, shaping.SHAPER_FRAC_BITS) */

/* modes (laws/axis.py MODE_*) */
#define ST_MODE_LOCK 0
#define ST_MODE_TASK 1
#define ST_MODE_OPEN 2

/* task laws (LAW_*) */
#define ST_LAW_NONE 0
#define ST_LAW_PI 1
#define ST_LAW_FUZZY_PID 2

/* flags (FLAG_*): faults latch until a reset; SATURATED is per tick. The latched faults
 * (FAULT_MASK) are COUNTER_FAULT | FOLLOWING_ERROR | SYNC_TRIP; st_axis_control stops an axis
 * on any nonzero latched fault. */
#define ST_FLAG_COUNTER_FAULT 1
#define ST_FLAG_FOLLOWING_ERROR 2
#define ST_FLAG_SATURATED 4
#define ST_FLAG_SYNC_TRIP 8 /* set by the caller on an ST_SYNC_TRIP (laws/sync.py) */
#define ST_FAULT_MASK (ST_FLAG_COUNTER_FAULT | ST_FLAG_FOLLOWING_ERROR | ST_FLAG_SYNC_TRIP)

/* sync monitor levels (laws/sync.py SYNC_*) */
#define ST_SYNC_OK 0
#define ST_SYNC_WARN 1
#define ST_SYNC_TRIP 2

/* query tables (TABLE_NAMES order) */
#define ST_TAB_KP 0
#define ST_TAB_KI 1
#define ST_TAB_KD 2
#define ST_TAB_K1 3

/* One axis's constants: the Python constants vector (laws/axis.py C_* layout). */
typedef struct st_axis_consts {
    int32_t law;             /* C_LAW: ST_LAW_* */
    int32_t lock_q;          /* C_LOCK_Q: lock gain [D/A LSB per count] */
    int16_t lock_f;          /* C_LOCK_F */
    int32_t kp_q;            /* C_KP_Q: Kp (base Kp0 for fuzzy-PID) [LSB/count] */
    int16_t kp_f;            /* C_KP_F */
    int32_t kit_q;           /* C_KIT_Q: Ki*T [LSB/count/tick] */
    int16_t kit_f;           /* C_KIT_F */
    int32_t fe_limit;        /* C_FE_LIMIT: following-error trip [counts], 0 = off */
    int16_t counter_bits;    /* C_COUNTER_BITS: 16, 24 or 32 */
    int32_t dac_zero;        /* C_DAC_ZERO: code of 0 V */
    int32_t dac_max;         /* C_DAC_MAX: largest code */
    int32_t kdt_q;           /* C_KDT_Q: Kd/T [LSB per count change per tick] */
    int16_t kdt_f;           /* C_KDT_F */
    int32_t k1t_q;           /* C_K1T_Q: K1/T (feedforward differential) */
    int16_t k1t_f;           /* C_K1T_F */
    int32_t ke_q;            /* C_KE_Q: Ke [levels/count] */
    int16_t ke_f;            /* C_KE_F */
    int32_t kec_q;           /* C_KEC_Q: Kec [levels per count/tick] */
    int16_t kec_f;           /* C_KEC_F */
    int16_t n;               /* C_N: levels -n..n (0 unless fuzzy-PID) */
    int16_t tf[ST_N_TABLES]; /* C_TF + i: fraction bits of table i */
    const int16_t *tab[ST_N_TABLES]; /* C_TAB + i*(2n+1)^2: table i, row-major; NULL unless
                                        fuzzy-PID */
    int32_t ref_source;      /* engine Loop.ref_source[a]: -1 = external reference (master),
                                else the index of the axis whose position is the reference */
    int32_t n_filters;       /* C_NF: output filter sections in use, 0 .. ST_MAX_FILTERS */
    st_section_t filter[ST_MAX_FILTERS]; /* C_FILT + 6*k: section k (b0 b1 b2 a1 a2
                                            frac_bits), in series order; all zero when unused */
    int32_t shaper_n;        /* AxisController.shaper: taps of the task reference's input
                                shaper, 0 = none (docs/runtime.md#shapers-in-the-tables); the
                                tick does not run it: the firmware shapes the reference it
                                hands st_tick (servotune_shaper.h) */
    const int32_t *shaper_q; /* its Q15 amplitudes, tick 0 first, summing to ST_SHAPER_ONE;
                                NULL when shaper_n is 0 */
} st_axis_consts_t;

/* All axes of one runtime. */
typedef struct st_consts {
    int32_t n_axes;          /* 1 .. ST_MAX_AXES */
    int32_t timer_divisor;   /* 8253 divisor of the tick (for the firmware; not used here) */
    st_axis_consts_t axis[ST_MAX_AXES];
} st_consts_t;

/* One axis's state: the Python state row (laws/axis.py S_* layout). Zero = power-up. */
typedef struct st_axis_state {
    int64_t init;        /* S_INIT: 0 until the first read */
    int64_t hi_prev;     /* S_HI_PREV: high byte of the previous read */
    int64_t wraps;       /* S_WRAPS: register wraps so far (signed) */
    int64_t y;           /* S_Y: extended position [counts] relative to the first read */
    int64_t mode;        /* S_MODE: mode run last tick (ST_MODE_*) */
    int64_t fault;       /* S_FAULT: latched fault flags */
    int64_t lock_target; /* S_LOCK_TARGET [counts] */
    int64_t integ;       /* S_INTEG: integrator [LSB, ST_F_U fraction bits] */
    int64_t u_last;      /* S_U_LAST: last output u_q [LSB, ST_F_U fraction bits] */
    int64_t e_prev;      /* S_E_PREV [counts] */
    int64_t r_prev;      /* S_R_PREV [counts] */
    int64_t origin;      /* S_ORIGIN: register value of the first read */
    int64_t filt[ST_MAX_FILTERS][ST_FILTER_STATE]; /* S_FILT + 6*k: section k's x1 x2 y1 y2
                                                      r1 r2 (laws/filters.py biquad_step) */
} st_axis_state_t;

typedef struct st_state {
    st_axis_state_t axis[ST_MAX_AXES];
} st_state_t;

/* Per-axis input of one tick. */
typedef struct st_axis_in {
    uint8_t bytes[4]; /* latched counter bytes, low first (counter_bits / 8 of them) */
    int64_t ref;      /* task reference [counts] (used when ref_source == -1) */
    int32_t mode;     /* requested mode (ST_MODE_*) */
    int32_t reset;    /* nonzero: clear latched faults, lock at the current position */
    int64_t u_add;    /* command added to the output [D/A codes] (0 normally) */
} st_axis_in_t;

/* Per-axis output of one tick. */
typedef struct st_axis_out {
    int32_t code;  /* D/A code to write */
    int32_t flags; /* ST_FLAG_* */
    int64_t e;     /* the law's error [counts] (0 in open mode or under a fault) */
    int64_t y;     /* extended position [counts] */
    int32_t mode;  /* mode run this tick */
} st_axis_out_t;

/* --- the tick ------------------------------------------------------------------------- */

/* Power-up state (all zero): of every axis, or of one. */
void st_init(st_state_t *s);
void st_axis_init(st_axis_state_t *x);

/* Check constants (ranges the no-overflow bounds rely on). 0 if valid, else
 * 1 + 100 * axis + field code (see servotune_rt.c) for the first bad field. Of an output
 * filter it checks n_filters and each section in use (frac_bits 1 .. 30, a stable quantised
 * denominator); the bound on its sums for inputs within the D/A range is checked at export
 * (servotune/export/json.py). Of a reference shaper: shaper_n 0 .. ST_MAX_SHAPER_N (field
 * code 19) and its table (non-NULL, amplitudes 0 .. 2^15 summing to 2^15; code 20). */
int st_check_consts(const st_consts_t *c);

/* One tick of every axis: in[a], out[a] for a < c->n_axes. */
void st_tick(const st_consts_t *c, st_state_t *s, const st_axis_in_t *in, st_axis_out_t *out);

/* The two halves of one axis's tick (laws/axis.py axis_read, axis_control). */
int64_t st_axis_read(st_axis_state_t *s, const st_axis_consts_t *c, int64_t raw, int reset);
int64_t st_axis_control(st_axis_state_t *s, const st_axis_consts_t *c, int64_t ref,
                        int64_t mode_cmd, int reset, int64_t u_add, int32_t *code,
                        int32_t *flags);

/* Switch an axis's output filters to sec[0 .. n-1] between two ticks, while it runs
 * (laws/axis.py switch_filters; docs/runtime.md#switching-filters-while-running): a filter
 * switched in, re-tuned or switched out without a bump (at a steady input the next code is
 * the last within 1 LSB). It writes c's filter constants, so the firmware keeps a writable
 * copy of the checked constants and ticks with it; the sections come from an exported (and
 * checked) tables document, realised for the axis's D/A range. 0 if switched; 1 if n is out
 * of 0 .. ST_MAX_FILTERS, 2 + k if section k fails st_check_consts' checks (nothing changed). */
int st_axis_switch_filters(st_axis_consts_t *c, st_axis_state_t *s, int32_t n,
                           const st_section_t *sec);

/* --- the sync compensator (servotune/laws/sync.py) -------------------------------------- */

/* Sync compensator constants (laws/sync.py SyncConstants) and monitor thresholds. Gains are
 * counts of compensation per count of sync error, as (q, f) pairs (value q * 2^-f). */
typedef struct st_sync_consts {
    int64_t kp_q;      /* Kp [counts per count]: int32 range */
    int64_t kp_f;      /* 0 .. ST_F_U */
    int64_t kit_q;     /* Ki*T [counts per count per tick] (0 for PD): int32 range */
    int64_t kit_f;     /* 0 .. ST_F_U */
    int64_t kdt_q;     /* Kd/T [counts per count change per tick] (0 for PI): int32 range */
    int64_t kdt_f;     /* 0 .. ST_F_U */
    int64_t dead_zone; /* sync errors within +-dead_zone give no correction [counts], >= 0 */
    int64_t limit;     /* largest compensation either way [counts], 1 .. 2^31 - 1; also the
                          integrator's clamp (+-limit * 2^ST_F_U) */
    int64_t warn;      /* monitor warning threshold on |e| [counts], 0 = off */
    int64_t trip;      /* monitor trip threshold on |e| [counts], 0 = off */
} st_sync_consts_t;

/* Sync compensator state. Zero = power-up; st_sync_enter on enable or after a reset. */
typedef struct st_sync_state {
    int64_t integ;  /* integrator [counts, ST_F_U fraction bits], within +-limit * 2^ST_F_U */
    int64_t e_prev; /* the previous tick's dead-zoned sync error [counts] */
} st_sync_state_t;

/* Check sync constants (ranges the no-overflow bounds rely on). 0 if valid, else 1 + the
 * index of the first bad field in st_sync_consts_t order: 1 kp_q, 2 kp_f, 3 kit_q, 4 kit_f,
 * 5 kdt_q, 6 kdt_f, 7 dead_zone, 8 limit, 9 warn, 10 trip. */
int st_check_sync_consts(const st_sync_consts_t *c);

/* sync.dead_zone: e clamped to +-(2^31 - 1), then moved towards 0 by dz >= 0 (0 inside
 * +-dz) [counts]. */
int64_t st_dead_zone(int64_t e, int64_t dz);

/* sync.sync_enter: bumpless enable (or after a reset) with sync error e [counts]:
 * integ := -Kp*e_d clamped to +-limit * 2^ST_F_U, so Kp*e_d + integ = 0 (the compensation at
 * entry is 0 unless the clamp binds), and e_prev := e_d (no derivative kick). */
void st_sync_enter(const st_sync_consts_t *c, st_sync_state_t *s, int64_t e);

/* sync.sync_step: one tick with sync error e = y_master - y_slave [counts]. Returns the
 * compensation added to the slave's position command [counts], within +-limit. */
int64_t st_sync_step(const st_sync_consts_t *c, st_sync_state_t *s, int64_t e);

/* sync.sync_monitor: ST_SYNC_TRIP if |e| >= trip (trip > 0), ST_SYNC_WARN if |e| >= warn
 * (warn > 0), else ST_SYNC_OK. */
int st_sync_monitor(int64_t e, int64_t warn, int64_t trip);

/* --- primitives (servotune/fixed.py, hw/counter.py) ------------------------------------- */

int64_t st_shift_round(int64_t x, int f);   /* f >= 1, x > INT64_MIN */
int64_t st_sat_add(int64_t a, int64_t b);   /* saturated to +-INT64_MAX */
int64_t st_align(int64_t x, int k);         /* x * 2^k, 0 <= k <= 62, saturated */
int64_t st_clamp_e(int64_t x);              /* clamp to +-(2^31 - 1) */
int64_t st_wrap_add(int64_t a, int64_t b);  /* a + b modulo 2^64 (as numba's int64 wraps) */
int64_t st_wrap_sub(int64_t a, int64_t b);  /* a - b modulo 2^64 */
int64_t st_assemble(const uint8_t *bytes, int counter_bits);
int st_unwrap_step(int64_t raw, int64_t *hi_prev, int64_t *wraps, int counter_bits,
                   int64_t *position);      /* returns 1 on a counter fault */

/* --- integrity ------------------------------------------------------------------------ */

uint32_t st_crc32(uint32_t crc, const uint8_t *p, size_t len); /* zlib.crc32(p, crc) */
uint32_t st_table_crc32(int n, int f, const int16_t *q);
uint32_t st_consts_crc32(const st_consts_t *c);

/* SHA-256 (FIPS 180-4), incremental: st_sha256_init, st_sha256_update any number of times,
 * st_sha256_final (which ends the context: init it again to reuse it). No allocation. */
typedef struct st_sha256_ctx {
    uint32_t h[8];     /* intermediate hash value */
    uint64_t n_bytes;  /* message length so far [bytes] */
    uint8_t block[64]; /* the current, partial message block */
    uint32_t fill;     /* bytes in block, 0 .. 63 */
} st_sha256_ctx_t;

void st_sha256_init(st_sha256_ctx_t *s);
void st_sha256_update(st_sha256_ctx_t *s, const uint8_t *p, size_t len);
void st_sha256_final(st_sha256_ctx_t *s, uint8_t out[32]);
void st_sha256(const uint8_t *p, size_t len, uint8_t out[32]); /* one call: init+update+final */

/* results of st_consts_sha256 / st_check_digest */
#define ST_DIGEST_OK 0        /* the digest was computed / matches */
#define ST_DIGEST_MISMATCH 1  /* st_check_digest: the constants are not the exported ones */
#define ST_DIGEST_MALFORMED 2 /* n_axes outside 1 .. ST_MAX_AXES, or a fuzzy-PID axis with n
                                 outside 1 .. ST_MAX_LEVELS or a NULL table: not walked */

/* SHA-256 of the constants in the C layout (header comment) into out. ST_DIGEST_OK, or
 * ST_DIGEST_MALFORMED (out untouched). */
int st_consts_sha256(const st_consts_t *c, uint8_t out[32]);

/* Start-up check of the compiled-in constants against the exported digest
 * (st_tables_sha256 of servotune_tables.h): ST_DIGEST_OK (0) if they match, else
 * ST_DIGEST_MISMATCH or ST_DIGEST_MALFORMED. Halt on anything but 0. */
int st_check_digest(const st_consts_t *c, const uint8_t expected[32]);

#ifdef __cplusplus
}
#endif

#endif /* SERVOTUNE_RT_H */
