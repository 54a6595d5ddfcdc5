/*
 * servotune_link.h -- a slave CPU of a multi-CPU linkage: its receive queue of position
 * commands and its clock-sync logic (C99, integer only, no I/O, no allocation).
 *
 * The machine. One master CPU interpolates the path of every axis ahead of time into one
 * position command per axis per sampling period (a "tick") and broadcasts the commands on a
 * serial bus in blocks: block b carries the commands of ticks b*B .. b*B + B - 1 for every
 * axis (B = block_size). Each slave CPU drives 2 to 4 of the axes. It keeps the commands of
 * its own axes in the receive queue below, executes one command per axis every tick of its
 * own clock, and realigns its tick index with the master's at every clock-sync broadcast.
 * The clocks of the CPUs have the same nominal frequency but drift (a few ppm to a few
 * thousand ppm); the syncs keep a slave's ticks within a fraction of a tick of the master's.
 *
 * What the firmware calls (the constants come from servotune_link_plan.h, exported with the
 * plan: STL_CPU_<NAME>_CONSTS_INIT initialises an stl_consts_t):
 *
 *     static const stl_consts_t consts = STL_CPU_S1_CONSTS_INIT;
 *     static stl_state_t queue;
 *     stl_init(&queue);                         at power-up
 *     if (stl_check_consts(&consts) != 0) halt();
 *
 *     on each block frame received (the prefill blocks before motion included):
 *         flags = stl_push(&consts, &queue, block_index, setpoints);
 *     setpoints: the block's commands for this CPU's axes [counts], block_size rows of
 *     n_axes int32 values (row r: tick block_index * block_size + r; column a: the CPU's
 *     axis a, in the order of the plan's axis list for this CPU);
 *
 *     on each clock-sync broadcast (the first, at motion start, carries master tick 0):
 *         wait = stl_sync(&consts, &queue, master_tick);
 *     then restart the tick timer so that the next tick comes `wait` tick periods from now
 *     (0: tick at once);
 *
 *     on every tick of this CPU's clock:
 *         flags = stl_tick(&consts, &queue, commands);
 *     commands[a] is axis a's position command for this tick [counts]: the reference of its
 *     position loop (see servotune_rt.h, task mode).
 *
 * Queue semantics. The queue holds, for each command index (tick) that has arrived and not
 * yet been executed, the commands of the CPU's axes, oldest first; its level is the number of
 * indices held [setpoints per axis], at most depth. The tick index `next` is the index the
 * next tick executes; it starts at 0.
 *  - stl_push: each command of the block whose index is below `next` came too late (its tick
 *    has passed): it is ignored (counted in `late`). The others are appended while the queue
 *    has room; those that find it full are lost (counted in `dropped`; the block counts as an
 *    overrun). An index not newer than the newest command held (a repeated or out-of-order
 *    block) is ignored (counted in `stale`).
 *  - stl_tick: if the oldest command held has index `next`, it is popped and executed;
 *    otherwise the tick under-runs: every axis holds its previous command (0 before the
 *    first: the power-up home). Then `next` advances by one. A lost or late command thus
 *    under-runs at its own tick, and later commands still run at theirs.
 *  - stl_sync(k): the slave takes the master's tick index k. Behind (next < k): the commands
 *    held with indices below k are discarded unexecuted (counted in `skipped`) and the next
 *    tick executes index k at once. Ahead (next >= k: indices up to next - 1 already ran): no
 *    index runs twice; the next tick executes index `next`, next - k tick periods after the
 *    sync. While the drift between two syncs stays below one tick, nothing is skipped and a
 *    slave that runs fast waits at most one tick: only its tick phase moves.
 *
 * Watermarks (flags, for monitoring; nothing else depends on them): STL_LOW on a tick whose
 * level before the pop is below low_watermark (a block is later than planned, an under-run is
 * near), STL_HIGH on a block after which the level is above high_watermark (the CPU is behind
 * the master more than planned, an overrun is near).
 */
#ifndef SERVOTUNE_LINK_H
#define SERVOTUNE_LINK_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define STL_VERSION 1 /* servotune.linkage-plan/1 */

#ifndef STL_MAX_AXES
#define STL_MAX_AXES 4 /* a slave CPU drives 2 to 4 axes */
#endif

#ifndef STL_MAX_DEPTH
#define STL_MAX_DEPTH 256 /* largest queue depth [setpoints per axis]; sizes stl_state_t */
#endif

/* flags returned by stl_push and stl_tick (several may be set) */
#define STL_UNDERRUN 1 /* stl_tick: the command of this tick was not in the queue; held */
#define STL_OVERRUN 2  /* stl_push: the queue was full: commands of the block were lost */
#define STL_LATE 4     /* stl_push: commands whose tick had passed were ignored */
#define STL_STALE 8    /* stl_push: commands not newer than the newest held were ignored */
#define STL_LOW 16     /* stl_tick: level before the pop < low_watermark */
#define STL_HIGH 32    /* stl_push: level after the block > high_watermark */
#define STL_BAD 64     /* stl_push: a negative or too large block index: nothing done */

/* The queue's constants, from the plan (servotune_link_plan.h); check with stl_check_consts. */
typedef struct stl_consts {
    int32_t n_axes;         /* axes this CPU drives, 1..STL_MAX_AXES */
    int32_t depth;          /* queue capacity [setpoints per axis], 1..STL_MAX_DEPTH */
    int32_t block_size;     /* commands per axis in one block (B) [setpoints], 1..depth */
    int32_t low_watermark;  /* STL_LOW below this level before a pop [setpoints], 0..depth */
    int32_t high_watermark; /* STL_HIGH above this level after a block [setpoints],
                               low_watermark..depth */
} stl_consts_t;

/* The queue and the clock-sync bookkeeping of one slave CPU. Zero (stl_init) at power-up;
 * only the functions below change it. */
typedef struct stl_state {
    int64_t next;  /* index of the command the next tick executes (0 at motion start) */
    int32_t first; /* slot of the oldest command held (ring position, 0..depth-1) */
    int32_t level; /* commands held [setpoints per axis], 0..depth */
    int64_t index[STL_MAX_DEPTH];             /* command index held in each slot */
    int32_t cmd[STL_MAX_DEPTH][STL_MAX_AXES]; /* the commands held [counts], per slot and axis */
    int32_t last[STL_MAX_AXES]; /* the command each axis executed last [counts] (held on an
                                   under-run; 0 before the first tick: the power-up home) */
    /* counters since power-up */
    int64_t ticks;          /* ticks executed (stl_tick calls) */
    int64_t underruns;      /* ticks whose command was not in the queue */
    int64_t overruns;       /* blocks that did not fit completely */
    int64_t dropped;        /* commands lost to a full queue [setpoints per axis] */
    int64_t late;           /* commands that arrived after their tick [setpoints per axis] */
    int64_t stale;          /* commands of repeated or out-of-order blocks [setpoints] */
    int64_t syncs;          /* clock-sync broadcasts received (the start sync included) */
    int64_t skipped;        /* commands discarded unexecuted at syncs [setpoints per axis] */
    int64_t behind;         /* syncs that found the CPU behind (it skipped ahead) */
    int64_t ahead;          /* syncs that found it ahead by a tick or more (it waited) */
    int64_t last_correction; /* master tick - next index at the last sync [ticks]: > 0 behind
                                (indices skipped), < 0 ahead (ticks waited), 0 in step */
} stl_state_t;

/* Power-up: an empty queue, tick index 0, every counter and held command 0. */
void stl_init(stl_state_t *s);

/* 0 if the constants are usable, else 1 + the index of the first bad field in
 * stl_consts_t order (1 n_axes, 2 depth, 3 block_size, 4 low_watermark, 5 high_watermark). */
int stl_check_consts(const stl_consts_t *c);

/* A block frame has arrived: queue its commands (semantics above). `block` is the block
 * index, `setpoints` its block_size rows of n_axes commands [counts]. Returns the STL_*
 * flags of the block (0: every command queued). */
int32_t stl_push(const stl_consts_t *c, stl_state_t *s, int64_t block, const int32_t *setpoints);

/* One tick: pop the command of index `next` into commands[0 .. n_axes-1] [counts] (on an
 * under-run, each axis's previous command) and advance `next`. Returns the STL_* flags of the
 * tick (STL_UNDERRUN, STL_LOW). */
int32_t stl_tick(const stl_consts_t *c, stl_state_t *s, int32_t *commands);

/* A clock-sync broadcast carrying the master's tick index `master_tick` (>= 0). Returns the
 * tick periods to wait before the next tick (0: tick now; semantics above), or -1 for a
 * negative `master_tick` (ignored). */
int64_t stl_sync(const stl_consts_t *c, stl_state_t *s, int64_t master_tick);

#ifdef __cplusplus
}
#endif

#endif /* SERVOTUNE_LINK_H */
