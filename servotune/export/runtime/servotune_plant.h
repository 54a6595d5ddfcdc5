/*
 * servotune_plant.h -- the simulator's motor + drive model in C (header only, double precision).
 *
 * A line-by-line mirror of servotune/plant.py (advance, _target_speed, advance_tick,
 * advance_tick_modal) and servotune/resonance.py (mode_coefficients, modes_segment,
 * modes_output, modes_speed): the same IEEE double operations in the same order, so with the
 * same libm (exp, expm1, log, sin, cos) it moves a plant exactly as the simulator does, bit for
 * bit. Compile without floating-point contraction into fused multiply-adds (-ffp-contract=off,
 * or a target without FMA): the Python side rounds every product.
 *
 * A plant row (servotune.plant.plant_row) carries the model and its one-tick coefficients,
 * indexed by the ST_R_* constants below (plant.R_*). One tick of the loop (the engine's order):
 * the counter latches floor(position) at the tick start; the law writes the D/A; the write of
 * tick k - m acts from lambda into tick k (m, lambda from the plant's compute + delay time); then
 * st_plant_advance_tick moves position and speed to the next tick start with w_old (the write
 * of tick k - m - 1, before lambda) and w_new (the write of tick k - m), both net of offset.
 *
 * A plant with lightly damped modes (docs/frf.md) carries their state q (ST_MAX_MODES pairs
 * q_i, w_i, zero at rest) beside position and speed: st_plant_advance_tick_modal moves all
 * three, and the counter latches floor(st_modes_output(...)), the measured position
 * p + sum g_i q_i, instead of floor(p). Without modes (row[ST_R_MODES] == 0) it is
 * st_plant_advance_tick and q is not touched.
 *
 * Encoder noise (row[ST_R_NOISE] = sigma [counts] > 0): the counter latches
 * floor(position + st_noise(&state, sigma)), one draw per tick from a splitmix64 stream
 * (servotune/sim/tick.py mix64, splitmix, normal, draw_noise: Box-Muller on two outputs).
 */
#ifndef SERVOTUNE_PLANT_H
#define SERVOTUNE_PLANT_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>

/* plant row layout (servotune/plant.py R_*) */
#define ST_R_GAIN 0
#define ST_R_TAU 1
#define ST_R_OFFSET 2
#define ST_R_COULOMB 3
#define ST_R_VMAX 4
#define ST_R_NOISE 5
#define ST_R_A1 6
#define ST_R_B1 7
#define ST_R_A2 8
#define ST_R_B2 9
#define ST_R_H1 10
#define ST_R_H2 11
#define ST_R_PHI_B 12
#define ST_R_PHI_A 13
#define ST_R_GO_P 14
#define ST_R_GO_V 15
#define ST_R_GN_P 16
#define ST_R_GN_V 17
#define ST_R_LINEAR 18
#define ST_R_GAIN_NEG 19
#define ST_R_COULOMB_NEG 20
#define ST_R_MODES 21
#define ST_NROW 107 /* ST_R_MODES + ST_MODES_HEADER + ST_MAX_MODES * ST_MODE_WIDTH */

/* the modes' layout from ST_R_MODES (servotune/resonance.py): the count, 1/tau, then per mode
 * ST_MODE_WIDTH numbers at these offsets; a piece's E11 E12 E21 E22 c1 c2 e1 e2 at
 * ST_MODE_PIECES + 8 * piece */
#define ST_MAX_MODES 4
#define ST_MODES_HEADER 2
#define ST_MODE_OMEGA2 0
#define ST_MODE_TWO_SIGMA 1
#define ST_MODE_GAIN 2
#define ST_MODE_SIGMA 3
#define ST_MODE_OMEGA_D 4
#define ST_MODE_PIECES 5
#define ST_MODE_WIDTH 21

/* resonance.mode_coefficients: one mode over a piece of h seconds, c[8] = E11 E12 E21 E22
 * c1 c2 e1 e2 (x(h) = E x(0) + c vinf + e (v0 - vinf)) */
static inline void st_mode_coefficients(double h, double sigma, double omega_d, double omega2,
                                        double two_sigma, double inv_tau, double *c)
{
    double ex = exp(-sigma * h);
    double cs = cos(omega_d * h);
    double sn = sin(omega_d * h) / omega_d;
    double e11 = ex * (cs + sn * sigma);
    double e12 = ex * sn;
    double e21 = -ex * sn * omega2;
    double e22 = ex * (cs - sn * sigma);
    /* c = M^-1 (E - I) beta, beta = (1, -2 sigma),
     * M^-1 = [[-2 sigma, -1], [omega^2, 0]] / omega^2 */
    double d1 = (e11 - 1.0) - e12 * two_sigma;
    double d2 = e21 - (e22 - 1.0) * two_sigma;
    double et, f1, f2, det;
    c[0] = e11;
    c[1] = e12;
    c[2] = e21;
    c[3] = e22;
    c[4] = (-two_sigma * d1 - d2) / omega2;
    c[5] = d1;
    /* e = (M + I/tau)^-1 (E - exp(-h/tau) I) beta */
    et = exp(-h * inv_tau);
    f1 = (e11 - et) - e12 * two_sigma;
    f2 = e21 - (e22 - et) * two_sigma;
    det = inv_tau * (inv_tau - two_sigma) + omega2;
    c[6] = ((inv_tau - two_sigma) * f1 - f2) / det;
    c[7] = (omega2 * f1 + inv_tau * f2) / det;
}

/* resonance.modes_segment: the modes' state q over a piece of h seconds in which the rigid
 * speed is vinf + dv exp(-t/tau); with the row's coefficients of piece 0 or 1, or computed for
 * h if piece < 0 */
static inline void st_modes_segment(double *q, const double *row, int off, int piece, double h,
                                    double vinf, double dv)
{
    int n = (int)row[off];
    int i;
    for (i = 0; i < n; i++) {
        int o = off + ST_MODES_HEADER + i * ST_MODE_WIDTH;
        double own[8];
        const double *c;
        double qi, wi;
        if (piece >= 0) {
            c = row + o + ST_MODE_PIECES + 8 * piece;
        } else {
            st_mode_coefficients(h, row[o + ST_MODE_SIGMA], row[o + ST_MODE_OMEGA_D],
                                 row[o + ST_MODE_OMEGA2], row[o + ST_MODE_TWO_SIGMA],
                                 row[off + 1], own);
            c = own;
        }
        qi = q[2 * i];
        wi = q[2 * i + 1];
        q[2 * i] = c[0] * qi + c[1] * wi + c[4] * vinf + c[6] * dv;
        q[2 * i + 1] = c[2] * qi + c[3] * wi + c[5] * vinf + c[7] * dv;
    }
}

/* resonance.modes_output: the measured position p + sum g_i q_i [counts]; p without modes */
static inline double st_modes_output(double p, const double *q, const double *row, int off)
{
    int n = (int)row[off];
    int i;
    double y;
    if (n == 0) {
        return p;
    }
    y = p;
    for (i = 0; i < n; i++) {
        y += row[off + ST_MODES_HEADER + i * ST_MODE_WIDTH + ST_MODE_GAIN] * q[2 * i];
    }
    return y;
}

/* resonance.modes_speed: the measured speed v + sum g_i (w_i + v) [counts/s]; v without modes */
static inline double st_modes_speed(double v, const double *q, const double *row, int off)
{
    int n = (int)row[off];
    int i;
    double s;
    if (n == 0) {
        return v;
    }
    s = v;
    for (i = 0; i < n; i++) {
        s += row[off + ST_MODES_HEADER + i * ST_MODE_WIDTH + ST_MODE_GAIN] * (q[2 * i + 1] + v);
    }
    return s;
}

/* plant._target_speed */
static inline double st_plant_target_speed(double s, double w, double gain, double coulomb,
                                           double gain_neg, double coulomb_neg,
                                           double vmax)
{
    double vinf;
    if (s > 0.0) {
        vinf = gain * (w - coulomb * s);
    } else {
        vinf = gain_neg * (w - coulomb_neg * s);
    }
    if (vinf > vmax) {
        return vmax;
    }
    if (vinf < -vmax) {
        return -vmax;
    }
    return vinf;
}

/* plant.advance: position *p and speed *v over h seconds of constant net input w;
 * a = exp(-h/tau), b = tau (1 - a) precomputed for h. A resonant plant's modes: their state q
 * moved over every piece of constant target speed, the row that holds them, and which of the
 * row's two pieces of a tick h is (-1: neither, coefficients computed for h); q == NULL: no
 * modes (row and piece unused). */
static inline void st_plant_advance(double *p, double *v, double w, double h, double a,
                                    double b, double gain, double tau, double coulomb,
                                    double vmax, double gain_neg, double coulomb_neg, double *q,
                                    const double *row, int piece)
{
    double s, vinf, vend, t0, hr, ar;
    int kinks;
    if (h <= 0.0) {
        return;
    }
    if (*v == 0.0) {
        if (w <= coulomb && w >= -coulomb_neg) {
            if (q != NULL) { /* at rest the whole piece: the modes ring out freely */
                st_modes_segment(q, row, ST_R_MODES, piece, h, 0.0, 0.0);
            }
            *v = 0.0;
            return;
        }
        s = w > 0.0 ? 1.0 : -1.0;
    } else {
        s = *v > 0.0 ? 1.0 : -1.0;
    }
    vinf = st_plant_target_speed(s, w, gain, coulomb, gain_neg, coulomb_neg, vmax);
    vend = vinf + (*v - vinf) * a;
    kinks = coulomb > 0.0 || coulomb_neg > 0.0 || gain_neg != gain;
    if (kinks && *v != 0.0 && vinf * s < 0.0 && vend * s <= 0.0) {
        /* the speed reaches zero inside the interval: the crossing time, exactly */
        t0 = tau * log((*v - vinf) / (-vinf));
        if (t0 > h) {
            t0 = h;
        }
        *p += vinf * t0 - (*v - vinf) * tau * expm1(-t0 / tau);
        hr = h - t0;
        if (q != NULL) {
            st_modes_segment(q, row, ST_R_MODES, -1, t0, vinf, *v - vinf);
        }
        if ((w <= coulomb && w >= -coulomb_neg) || hr <= 0.0) {
            if (q != NULL && hr > 0.0) {
                st_modes_segment(q, row, ST_R_MODES, -1, hr, 0.0, 0.0);
            }
            *v = 0.0;
            return;
        }
        /* from rest the other way, with that direction's gain and Coulomb level */
        s = w > 0.0 ? 1.0 : -1.0;
        vinf = st_plant_target_speed(s, w, gain, coulomb, gain_neg, coulomb_neg, vmax);
        ar = exp(-hr / tau);
        *p += vinf * hr + vinf * tau * expm1(-hr / tau);
        if (q != NULL) {
            st_modes_segment(q, row, ST_R_MODES, -1, hr, vinf, -vinf);
        }
        *v = vinf * (1.0 - ar);
        return;
    }
    if (q != NULL) {
        st_modes_segment(q, row, ST_R_MODES, piece, h, vinf, *v - vinf);
    }
    *p = *p + vinf * h + (*v - vinf) * b;
    *v = vend;
}

/* plant.advance_tick: one tick, w_old until lambda then w_new [V, net of offset]. */
static inline void st_plant_advance_tick(double *p, double *v, double w_old, double w_new,
                                         const double *row)
{
    double vmax = row[ST_R_VMAX];
    double gain = row[ST_R_GAIN];
    if (row[ST_R_LINEAR] > 0.0 && fabs(w_new) * gain <= vmax && fabs(w_old) * gain <= vmax) {
        double p_n = *p + row[ST_R_PHI_B] * *v + row[ST_R_GO_P] * w_old + row[ST_R_GN_P] * w_new;
        double v_n = row[ST_R_PHI_A] * *v + row[ST_R_GO_V] * w_old + row[ST_R_GN_V] * w_new;
        *p = p_n;
        *v = v_n;
        return;
    }
    if (row[ST_R_H1] > 0.0) {
        st_plant_advance(p, v, w_old, row[ST_R_H1], row[ST_R_A1], row[ST_R_B1], gain,
                         row[ST_R_TAU], row[ST_R_COULOMB], vmax, row[ST_R_GAIN_NEG],
                         row[ST_R_COULOMB_NEG], NULL, NULL, -1);
    }
    st_plant_advance(p, v, w_new, row[ST_R_H2], row[ST_R_A2], row[ST_R_B2], gain, row[ST_R_TAU],
                     row[ST_R_COULOMB], vmax, row[ST_R_GAIN_NEG], row[ST_R_COULOMB_NEG], NULL,
                     NULL, -1);
}

/* plant.advance_tick_modal: st_plant_advance_tick of a plant that may have modes, their state
 * q[2 * ST_MAX_MODES] moved exactly with the rigid part over each piece of the tick; without
 * modes st_plant_advance_tick (q not touched). */
static inline void st_plant_advance_tick_modal(double *p, double *v, double *q, double w_old,
                                               double w_new, const double *row)
{
    double vmax, gain, tau, coulomb, gain_neg, coulomb_neg;
    if (row[ST_R_MODES] == 0.0) {
        st_plant_advance_tick(p, v, w_old, w_new, row);
        return;
    }
    vmax = row[ST_R_VMAX];
    gain = row[ST_R_GAIN];
    if (row[ST_R_LINEAR] > 0.0 && fabs(w_new) * gain <= vmax && fabs(w_old) * gain <= vmax) {
        double v_lam = *v;
        double vinf, p_n, v_n;
        if (row[ST_R_H1] > 0.0) {
            vinf = gain * w_old;
            st_modes_segment(q, row, ST_R_MODES, 0, row[ST_R_H1], vinf, *v - vinf);
            v_lam = vinf + (*v - vinf) * row[ST_R_A1];
        }
        vinf = gain * w_new;
        st_modes_segment(q, row, ST_R_MODES, 1, row[ST_R_H2], vinf, v_lam - vinf);
        p_n = *p + row[ST_R_PHI_B] * *v + row[ST_R_GO_P] * w_old + row[ST_R_GN_P] * w_new;
        v_n = row[ST_R_PHI_A] * *v + row[ST_R_GO_V] * w_old + row[ST_R_GN_V] * w_new;
        *p = p_n;
        *v = v_n;
        return;
    }
    tau = row[ST_R_TAU];
    coulomb = row[ST_R_COULOMB];
    gain_neg = row[ST_R_GAIN_NEG];
    coulomb_neg = row[ST_R_COULOMB_NEG];
    if (row[ST_R_H1] > 0.0) {
        st_plant_advance(p, v, w_old, row[ST_R_H1], row[ST_R_A1], row[ST_R_B1], gain, tau,
                         coulomb, vmax, gain_neg, coulomb_neg, q, row, 0);
    }
    st_plant_advance(p, v, w_new, row[ST_R_H2], row[ST_R_A2], row[ST_R_B2], gain, tau, coulomb,
                     vmax, gain_neg, coulomb_neg, q, row, 1);
}

/* --- encoder noise: servotune/sim/tick.py line by line ------------------------------------ */

static inline uint64_t st_mix64(uint64_t z)
{
    z = (z ^ (z >> 30)) * UINT64_C(0xBF58476D1CE4E5B9);
    z = (z ^ (z >> 27)) * UINT64_C(0x94D049BB133111EB);
    return z ^ (z >> 31);
}

/* the next 64-bit output of the stream whose state is *state (advanced) */
static inline uint64_t st_splitmix(uint64_t *state)
{
    *state += UINT64_C(0x9E3779B97F4A7C15);
    return st_mix64(*state);
}

/* a standard normal draw: Box-Muller on two outputs, u1 in (0, 1), u2 in [0, 1) */
static inline double st_normal(uint64_t *state)
{
    uint64_t z1 = st_splitmix(state);
    uint64_t z2 = st_splitmix(state);
    double u1 = ((double)(int64_t)(z1 >> 11) + 0.5) * (1.0 / 9007199254740992.0);
    double u2 = (double)(int64_t)(z2 >> 11) * (1.0 / 9007199254740992.0);
    return sqrt(-2.0 * log(u1)) * cos(2.0 * 3.141592653589793 * u2);
}

/* one sample's encoder noise [counts]: sigma times a normal draw; no draw if sigma is 0 */
static inline double st_noise(uint64_t *state, double sigma)
{
    return sigma > 0.0 ? st_normal(state) * sigma : 0.0;
}

#endif /* SERVOTUNE_PLANT_H */
