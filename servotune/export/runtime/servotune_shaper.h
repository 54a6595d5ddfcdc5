/*
 * servotune_shaper.h -- input shaping of a move's reference (C99, integer only, header only).
 *
 * A line-by-line mirror of servotune/laws/shaping.py (shaper_step): the reference of each tick
 * is pushed into a delay line and the shaped reference is shift_round(sum_i a_i r[k - i], 15),
 * the runtime's rounding (half away from zero, no right shift of a negative value), with Q15
 * amplitudes a_i that sum to exactly 2^15 (a constant reference passes to the count). Before
 * the first tick the line holds the first reference. |ref| must stay below 2^47.
 *
 * st_shaper_t: n taps (1 .. ST_SHAPER_MAX_TAPS) and their amplitudes; st_shaper_state_t: the
 * delay line, the write position and the primed flag (zero it to start).
 */
#ifndef SERVOTUNE_SHAPER_H
#define SERVOTUNE_SHAPER_H

#include <stdint.h>

#ifndef ST_SHAPER_MAX_TAPS
#define ST_SHAPER_MAX_TAPS 1024
#endif
#define ST_SHAPER_FRAC_BITS 15

typedef struct {
    int32_t n;
    int32_t a_q[ST_SHAPER_MAX_TAPS];
} st_shaper_t;

typedef struct {
    int64_t line[ST_SHAPER_MAX_TAPS];
    int32_t head;
    int32_t primed;
} st_shaper_state_t;

static int64_t st_shaper_round(int64_t x, int f)
{
    if (x >= 0) {
        return (x >> f) + ((x >> (f - 1)) & 1);
    }
    {
        int64_t m = -x;
        return -((m >> f) + ((m >> (f - 1)) & 1));
    }
}

/* 0 if the amplitudes are well formed (n in range, each in [0, 2^15], summing to 2^15) */
static int st_shaper_check(const st_shaper_t *c)
{
    int64_t sum = 0;
    int32_t i;
    if (c->n < 1 || c->n > ST_SHAPER_MAX_TAPS) {
        return 1;
    }
    for (i = 0; i < c->n; i++) {
        if (c->a_q[i] < 0 || c->a_q[i] > (1 << ST_SHAPER_FRAC_BITS)) {
            return 2;
        }
        sum += c->a_q[i];
    }
    return sum == (1 << ST_SHAPER_FRAC_BITS) ? 0 : 3;
}

static int64_t st_shaper_step(const st_shaper_t *c, st_shaper_state_t *s, int64_t ref)
{
    int32_t n = c->n;
    int32_t i;
    int32_t j;
    int64_t acc = 0;
    if (!s->primed) {
        for (i = 0; i < n; i++) {
            s->line[i] = ref;
        }
        s->head = 0;
        s->primed = 1;
    }
    s->line[s->head] = ref;
    j = s->head;
    for (i = 0; i < n; i++) {
        acc += (int64_t)c->a_q[i] * s->line[j];
        j = j > 0 ? j - 1 : n - 1;
    }
    s->head = s->head + 1 < n ? s->head + 1 : 0;
    return st_shaper_round(acc, ST_SHAPER_FRAC_BITS);
}

#endif /* SERVOTUNE_SHAPER_H */
