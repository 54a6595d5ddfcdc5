/*
 * servotune_gantry.h -- reference runtime of a fieldbus gantry (C99, integer only, no I/O,
 * no allocation).
 *
 * A gantry is two drives, one on each side of a beam (the master and the slave), whose
 * position loops are closed at the bus cycle, plus a synchronisation compensator and a sync
 * monitor on the sync error e = y_master - y_slave [counts]. This file is the controller side
 * of one bus cycle, in the same order and with the same integer arithmetic as the servotune
 * gantry simulation (servotune/arch/gantry/run.py), so that it gives the simulated D/A codes,
 * flags and compensation bit for bit. It is built on servotune_rt.h: each drive is an
 * st_axis_* axis running the PI law, the compensator and monitor are the st_sync_* calls.
 *
 * One bus cycle (st_gantry_step), given the two counter registers the drives latched at the
 * sync instant, the CNC's command and the operator's reset:
 *
 *   0. operator's reset (in->reset != 0): the sync trip and the stops are cleared, and the
 *      compensator will enter again (bumplessly) the next time it runs; the drives' latched
 *      faults are cleared by their laws in step 5, which re-enter task mode bumplessly. If
 *      the monitor trips again in the reset cycle (the skew is still past the threshold), the
 *      reset is refused to every drive the trip stops in that cycle: it keeps its fault and
 *      stays at 0 V;
 *   1. read and unwrap both counters (st_axis_read, master then slave; on a reset the unwrap
 *      starts again from this read, which clears a counter fault's aftermath);
 *   2. the sync error as the slave (or the CNC) sees it: the measured positions of
 *      `latency` cycles ago, e(k) = y_master(k - L) - y_slave(k - L), from cycle k = L on
 *      (nothing is seen before);
 *   3. the monitor (st_sync_monitor) on e(k), run by the station that forms the sync error
 *      (the listening slave, else the CNC). The first ST_SYNC_TRIP latches the trip, which
 *      stops the drives: in the listening topology the slave stops in the trip cycle and the
 *      master one cycle later (with the next frame); in the other topologies both stop one
 *      cycle later;
 *   4. the compensator, in the listening and cross topologies while no trip is latched:
 *      st_sync_enter on its first run after power-up or after a reset (compensation 0), else
 *      st_sync_step; then every stopped drive gets ST_FLAG_SYNC_TRIP in its latched fault,
 *      which holds it at its D/A zero code (st_axis_control) until a reset;
 *   5. the two position commands by topology (cmd = the CNC's command, comp = the
 *      compensation of step 4, 0 when the compensator did not run):
 *        ST_TOPO_PARALLEL   master cmd, slave cmd;
 *        ST_TOPO_FOLLOWING  master cmd, slave y_master(k - L) (cmd before cycle L);
 *        ST_TOPO_LISTENING  master cmd, slave cmd + comp;
 *        ST_TOPO_CROSS      master cmd - h, slave cmd + (comp - h), h = comp / 2 rounded
 *                           half away from zero (st_shift_round(comp, 1));
 *      then each drive's law in task mode (st_axis_control, master then slave, with the
 *      operator's reset) gives its D/A code and flags.
 *
 * The firmware calls st_gantry_step once per bus cycle and writes out.code[] to the drives'
 * D/As (or sends them over the bus). Everything the controller remembers is in
 * st_gantry_state_t; all zero is the power-up state.
 *
 * Start-up checks: st_gantry_check_digest(&consts, expected_sha256) ties the compiled-in
 * constants to the exported ones (servotune's gantry export gives the SHA-256 of the layout
 * below), and st_gantry_check(&consts) checks the ranges the arithmetic relies on. Halt on
 * anything but 0 from either. st_gantry_step assumes st_gantry_check accepted the constants;
 * even without it, it never reads or writes outside its structs.
 *
 * Arithmetic: as servotune_rt.c. Positions, references and the sync error are int64 counts;
 * differences and sums of positions and commands are formed modulo 2^64 (two's complement),
 * as the simulation's int64 arithmetic does, so no input value is undefined behaviour; they
 * only wrap for positions or commands beyond +-2^62 counts, never on a real machine.
 *
 * Output filters: a drive with n_filters > 0 runs its sections in series on its law's output
 * before the D/A (st_axis_control, as in the one-rig runtime).
 *
 * Digest layout (st_gantry_check_digest): 84 numbers, each a little-endian two's-complement
 * int64, 672 bytes, no padding, in this order:
 *   topology, latency,
 *   for the master, then the slave: law, lock_q, lock_f, kp_q, kp_f, kit_q, kit_f, fe_limit,
 *     counter_bits, dac_zero, dac_max, n_filters, then every one of the ST_MAX_FILTERS
 *     filter slots (those past n_filters as compiled in, zero in an exported header):
 *     b0, b1, b2, a1, a2, frac_bits,
 *   sync: kp_q, kp_f, kit_q, kit_f, kdt_q, kdt_f, dead_zone, limit, warn, trip.
 * (A drive's other st_axis_consts_t fields are not used by the PI law and are not hashed.)
 */
#ifndef SERVOTUNE_GANTRY_H
#define SERVOTUNE_GANTRY_H

#include <stdint.h>

#include "servotune_rt.h"

#ifdef __cplusplus
extern "C" {
#endif

#define ST_GANTRY_VERSION 2 /* version of this interface (2: output filters hashed) */

/* topologies (st_gantry_consts_t.topology) */
#define ST_TOPO_PARALLEL 0  /* the CNC commands both drives; no compensator */
#define ST_TOPO_FOLLOWING 1 /* the slave follows the master's measured position */
#define ST_TOPO_LISTENING 2 /* the slave adds the compensation to the CNC's command */
#define ST_TOPO_CROSS 3     /* the CNC splits the compensation between the two drives */

/* Largest bus latency [cycles]; sizes the position history in st_gantry_state_t
 * (2 * (ST_GANTRY_MAX_LATENCY + 1) int64). Define it smaller before including this header to
 * save memory on a target with a short latency. */
#ifndef ST_GANTRY_MAX_LATENCY
#define ST_GANTRY_MAX_LATENCY 1000
#endif

/* what the compensator did in a cycle (st_gantry_out_t.sync_op) */
#define ST_SYNC_OP_NONE 0  /* not run (topology without it, before cycle L, or tripped) */
#define ST_SYNC_OP_ENTER 1 /* entered bumplessly (st_sync_enter): compensation 0 */
#define ST_SYNC_OP_STEP 2  /* one step of the law (st_sync_step) */

/* drive indices */
#define ST_GANTRY_MASTER 0
#define ST_GANTRY_SLAVE 1

/* The gantry's constants. */
typedef struct st_gantry_consts {
    int32_t topology;           /* ST_TOPO_* */
    int32_t latency;            /* L: cycles until the master's feedback reaches the slave
                                   and the CNC, 0 .. ST_GANTRY_MAX_LATENCY (servotune's
                                   gantry configs take 1 and more; 0 = the sync error of the
                                   cycle itself) */
    st_axis_consts_t drive[2];  /* [ST_GANTRY_MASTER], [ST_GANTRY_SLAVE]: each a PI law
                                   (law = ST_LAW_PI) with ref_source = -1 */
    st_sync_consts_t sync;      /* the compensator's gains, dead zone and limit, and the
                                   monitor's warning and trip thresholds */
} st_gantry_consts_t;

/* The gantry controller's state. All zero = power-up (st_gantry_init). Written only by
 * st_gantry_init and st_gantry_step. */
typedef struct st_gantry_state {
    st_axis_state_t drive[2]; /* the drives' law states (master, slave) */
    st_sync_state_t sync;     /* the compensator's integrator and previous dead-zoned error */
    int64_t cycle;            /* k: the index of the next cycle (cycles run since power-up;
                                 saturates at INT64_MAX, some 3e8 years at 1 kHz) */
    int64_t y_hist[2][ST_GANTRY_MAX_LATENCY + 1]; /* measured positions of the last L + 1
                                 cycles per drive [counts]: cycle j in slot j mod (L + 1) */
    int32_t tripped;          /* 1: the monitor tripped and no reset came since */
    int32_t sync_entered;     /* 0: the compensator enters at its next run (power-up, reset) */
    int64_t stop_cycle[2];    /* while tripped: the cycle from which each drive is stopped */
} st_gantry_state_t;

/* One cycle's input. */
typedef struct st_gantry_in {
    int64_t counter[2]; /* the counter registers the master and the slave latched at the
                           sync instant (0 .. 2^counter_bits - 1) */
    int64_t command;    /* the CNC's position command [counts], in the frame of the drives'
                           positions (0 = the first read) */
    int32_t reset;      /* nonzero: the operator's reset (clears the sync trip and both
                           drives' latched faults; the compensator enters again) */
} st_gantry_in_t;

/* One cycle's output. */
typedef struct st_gantry_out {
    int32_t code[2];    /* D/A codes to write (master, slave) */
    int32_t flags[2];   /* ST_FLAG_* of each drive: its latched faults (ST_FLAG_SYNC_TRIP
                           once stopped by the monitor) and ST_FLAG_SATURATED */
    int64_t y[2];       /* measured positions [counts], relative to each drive's first read */
    int64_t ref[2];     /* the position commands the drives' laws followed [counts] */
    int32_t sync_op;    /* ST_SYNC_OP_*: what the compensator did */
    int64_t sync_input; /* the sync error the compensator saw [counts] (0 if not run) */
    int64_t sync_comp;  /* its compensation [counts], within +-sync.limit (0 if not run or
                           on entering) */
    int32_t sync_level; /* the monitor's level on the seen sync error (ST_SYNC_OK, _WARN,
                           _TRIP); ST_SYNC_OK before cycle L */
    int32_t tripped;    /* 1 if the sync trip is latched after this cycle */
} st_gantry_out_t;

/* Power-up state (all zero). */
void st_gantry_init(st_gantry_state_t *s);

/* st_gantry_check: the ranges the arithmetic relies on. Returns 0 if valid, else the code of
 * the first bad field:
 *     1  topology not one of ST_TOPO_*
 *     2  latency outside 0 .. ST_GANTRY_MAX_LATENCY
 *   100 + f  the master's drive[0], 200 + f  the slave's drive[1], with f:
 *     1  law is not ST_LAW_PI
 *     2  lock_f outside 0 .. ST_F_U
 *     3  kp_f outside 0 .. ST_F_U
 *     4  kit_f outside 0 .. ST_F_U
 *     5  fe_limit < 0
 *     6  counter_bits not 16, 24 or 32
 *     7  dac_zero < 0, dac_max < dac_zero or dac_max > 65535
 *     8  ref_source is not -1 (the gantry routes the references itself)
 *     9  a field the PI law does not use that st_check_consts rejects (kdt_f, k1t_f, ke_f,
 *        kec_f outside 0 .. ST_F_U, a reference shaper)
 *    10  n_filters outside 0 .. ST_MAX_FILTERS, or a filter section in use with frac_bits
 *        outside 1 .. 30 or an unstable denominator (st_check_consts' codes 18, 19)
 *   300 + s  the sync constants, s = st_check_sync_consts' code: 1 kp_q, 2 kp_f, 3 kit_q,
 *        4 kit_f, 5 kdt_q, 6 kdt_f, 7 dead_zone, 8 limit, 9 warn, 10 trip */
int st_gantry_check(const st_gantry_consts_t *c);

/* results of st_gantry_check_digest */
#define ST_GANTRY_DIGEST_OK 0       /* the constants are the exported ones */
#define ST_GANTRY_DIGEST_MISMATCH 1 /* they are not (or sha256 is NULL) */

/* SHA-256 of the constants in the digest layout (header comment), 672 bytes. */
void st_gantry_sha256(const st_gantry_consts_t *c, uint8_t out[32]);

/* Start-up check of the compiled-in constants against the exported SHA-256 of their layout:
 * ST_GANTRY_DIGEST_OK (0) if it matches, else ST_GANTRY_DIGEST_MISMATCH. */
int st_gantry_check_digest(const st_gantry_consts_t *c, const uint8_t sha256[32]);

/* One bus cycle (header comment, steps 0-5): reads in, updates s, writes out. */
void st_gantry_step(const st_gantry_consts_t *c, st_gantry_state_t *s, const st_gantry_in_t *in,
                    st_gantry_out_t *out);

#ifdef __cplusplus
}
#endif

#endif /* SERVOTUNE_GANTRY_H */
