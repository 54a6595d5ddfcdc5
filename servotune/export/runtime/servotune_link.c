/*
 * servotune_link.c -- a slave CPU of a multi-CPU linkage: receive queue and clock sync.
 *
 * See servotune_link.h for the machine, the calls and their semantics. The queue is a ring of
 * `depth` slots holding, oldest first, the command index and the commands of each tick that
 * has arrived and not yet run; indices in the ring increase from the oldest to the newest and
 * are never below `next` (stl_push refuses late ones, stl_tick and stl_sync remove the oldest
 * before `next` moves past them). This is the linkage simulation's queue model, line by line:
 * its event log replayed through these functions gives the same commands, levels and counts
 * (tests/export/test_c_linkage.py).
 */
#include "servotune_link.h"

/* the slot `k` places after the oldest (k < depth) */
static int32_t slot(const stl_consts_t *c, const stl_state_t *s, int32_t k)
{
    int32_t i = s->first + k;
    return i >= c->depth ? i - c->depth : i;
}

/* remove the oldest command held (level > 0) */
static void drop_oldest(const stl_consts_t *c, stl_state_t *s)
{
    s->first = slot(c, s, 1);
    s->level -= 1;
}

void stl_init(stl_state_t *s)
{
    int32_t i;
    int32_t a;
    s->next = 0;
    s->first = 0;
    s->level = 0;
    for (i = 0; i < STL_MAX_DEPTH; i++) {
        s->index[i] = 0;
        for (a = 0; a < STL_MAX_AXES; a++) {
            s->cmd[i][a] = 0;
        }
    }
    for (a = 0; a < STL_MAX_AXES; a++) {
        s->last[a] = 0;
    }
    s->ticks = 0;
    s->underruns = 0;
    s->overruns = 0;
    s->dropped = 0;
    s->late = 0;
    s->stale = 0;
    s->syncs = 0;
    s->skipped = 0;
    s->behind = 0;
    s->ahead = 0;
    s->last_correction = 0;
}

int stl_check_consts(const stl_consts_t *c)
{
    if (c->n_axes < 1 || c->n_axes > STL_MAX_AXES) {
        return 1;
    }
    if (c->depth < 1 || c->depth > STL_MAX_DEPTH) {
        return 2;
    }
    if (c->block_size < 1 || c->block_size > c->depth) {
        return 3;
    }
    if (c->low_watermark < 0 || c->low_watermark > c->depth) {
        return 4;
    }
    if (c->high_watermark < c->low_watermark || c->high_watermark > c->depth) {
        return 5;
    }
    return 0;
}

int32_t stl_push(const stl_consts_t *c, stl_state_t *s, int64_t block, const int32_t *setpoints)
{
    int32_t flags = 0;
    int32_t r;
    int32_t a;
    int64_t first;
    if (block < 0 || block > (INT64_MAX - c->block_size) / c->block_size) {
        return STL_BAD;
    }
    first = block * c->block_size;
    for (r = 0; r < c->block_size; r++) {
        const int64_t i = first + r;
        int32_t k;
        if (i < s->next) { /* its tick has passed */
            s->late += 1;
            flags |= STL_LATE;
            continue;
        }
        if (s->level > 0 && i <= s->index[slot(c, s, s->level - 1)]) { /* held already */
            s->stale += 1;
            flags |= STL_STALE;
            continue;
        }
        if (s->level >= c->depth) { /* full: lost */
            s->dropped += 1;
            flags |= STL_OVERRUN;
            continue;
        }
        k = slot(c, s, s->level);
        s->index[k] = i;
        for (a = 0; a < c->n_axes; a++) {
            s->cmd[k][a] = setpoints[r * c->n_axes + a];
        }
        s->level += 1;
    }
    if (flags & STL_OVERRUN) {
        s->overruns += 1;
    }
    if (s->level > c->high_watermark) {
        flags |= STL_HIGH;
    }
    return flags;
}

int32_t stl_tick(const stl_consts_t *c, stl_state_t *s, int32_t *commands)
{
    int32_t flags = 0;
    int32_t a;
    if (s->level < c->low_watermark) {
        flags |= STL_LOW;
    }
    /* the oldest command held has an index >= next (see the top of this file) */
    if (s->level > 0 && s->index[s->first] == s->next) {
        for (a = 0; a < c->n_axes; a++) {
            s->last[a] = s->cmd[s->first][a];
        }
        drop_oldest(c, s);
    } else {
        s->underruns += 1;
        flags |= STL_UNDERRUN;
    }
    for (a = 0; a < c->n_axes; a++) {
        commands[a] = s->last[a];
    }
    if (s->next < INT64_MAX) { /* 2^63 ticks: never reached (2 ms ticks: 5.8e8 years) */
        s->next += 1;
    }
    s->ticks += 1;
    return flags;
}

int64_t stl_sync(const stl_consts_t *c, stl_state_t *s, int64_t master_tick)
{
    const int64_t j = s->next;
    if (master_tick < 0) {
        return -1;
    }
    s->syncs += 1;
    s->last_correction = master_tick - j; /* both >= 0: no overflow */
    if (j < master_tick) {                /* behind: discard the commands before master_tick */
        while (s->level > 0 && s->index[s->first] < master_tick) {
            drop_oldest(c, s);
            s->skipped += 1;
        }
        s->next = master_tick;
        s->behind += 1;
        return 0;
    }
    if (j > master_tick) {
        s->ahead += 1;
    }
    return j - master_tick;
}
