/*
 * servotune_filter.h -- a filter section of the law's output in C (C99, integer only, header
 * only; docs/runtime.md#filters).
 *
 * A line-by-line mirror of servotune/laws/filters.py (biquad_step, bumpless_state): Direct
 * Form I in int64 with second-order error feedback,
 *
 *     ef  = shift_round(a1*r1 + a2*r2, f)
 *     acc = b0*x + b1*x1 + b2*x2 - a1*y1 - a2*y2 - ef
 *     y   = shift_round(acc, f)          r = acc - y*2^f
 *
 * with the runtime's rounding (half away from zero, no right shift of a negative value). The
 * caller keeps |x| within the bound the section was sized for (state_bound), which keeps every
 * partial sum inside +-2^62. The state is six int64 words: x1, x2, y1, y2, r1, r2.
 */
#ifndef SERVOTUNE_FILTER_H
#define SERVOTUNE_FILTER_H

#include <stdint.h>

#define ST_FILTER_STATE 6

/* a quantised section: int32 mantissas with frac_bits (1 .. 30) fraction bits, a0 = 1 */
typedef struct {
    int32_t b0;
    int32_t b1;
    int32_t b2;
    int32_t a1;
    int32_t a2;
    int32_t frac_bits;
} st_section_t;

static inline int64_t st_filter_round(int64_t x, int f)
{
    if (x >= 0) {
        return (x >> f) + ((x >> (f - 1)) & 1);
    }
    {
        int64_t m = -x;
        return -((m >> f) + ((m >> (f - 1)) & 1));
    }
}

/* one tick of section c on input x; st updated in place; returns the output */
static inline int64_t st_biquad_step(const st_section_t *c, int64_t *st, int64_t x)
{
    int f = (int)c->frac_bits;
    int64_t a1 = c->a1;
    int64_t a2 = c->a2;
    int64_t ef = st_filter_round(a1 * st[4] + a2 * st[5], f);
    int64_t acc = (int64_t)c->b0 * x + (int64_t)c->b1 * st[0] + (int64_t)c->b2 * st[1]
                  - a1 * st[2] - a2 * st[3] - ef;
    int64_t y = st_filter_round(acc, f);
    int64_t r = acc - y * ((int64_t)1 << f);
    st[1] = st[0];
    st[0] = x;
    st[3] = st[2];
    st[2] = y;
    st[5] = st[4];
    st[4] = r;
    return y;
}

/* the state for switching a section in, or re-tuning it, from the last input and output */
static inline void st_filter_bumpless(int64_t *st, int64_t x_now, int64_t y_now)
{
    st[0] = x_now;
    st[1] = x_now;
    st[2] = y_now;
    st[3] = y_now;
    st[4] = 0;
    st[5] = 0;
}

#endif /* SERVOTUNE_FILTER_H */
