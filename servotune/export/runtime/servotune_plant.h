/*
 * servotune_plant.h -- the simulator's motor + drive model in C (header only, double precision).
 *
 * A line-by-line mirror of servotune/plant.py (advance, _target_speed, advance_tick): the same
 * IEEE double operations in the same order, so with the same libm (exp, expm1, log) it moves a
 * plant exactly as the simulator does, bit for bit. Compile without floating-point contraction
 * into fused multiply-adds (-ffp-contract=off, or a target without FMA): the Python side rounds
 * every product.
 *
 * A plant row (servotune.plant.plant_row) carries the model and its one-tick coefficients,
 * indexed by the ST_R_* constants below (plant.R_*). One tick of the loop (the engine's order):
 * the counter latches floor(position) at the tick start; the law writes the D/A; the write of
 * tick k - m acts from lambda into tick k (m, lambda from the plant's compute + delay time); then
 * st_plant_advance_tick moves position and speed to the next tick start with w_old (the write
 * of tick k - m - 1, before lambda) and w_new (the write of tick k - m), both net of offset.
 */
#ifndef SERVOTUNE_PLANT_H
#define SERVOTUNE_PLANT_H

#include <math.h>

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
#define ST_NROW 21

/* plant._target_speed */
static double st_plant_target_speed(double s, double w, double gain, double coulomb,
                                    double gain_neg, double coulomb_neg, double vmax)
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
 * a = exp(-h/tau), b = tau (1 - a) precomputed for h. */
static void st_plant_advance(double *p, double *v, double w, double h, double a, double b,
                             double gain, double tau, double coulomb, double vmax,
                             double gain_neg, double coulomb_neg)
{
    double s, vinf, vend, t0, hr, ar;
    int kinks;
    if (h <= 0.0) {
        return;
    }
    if (*v == 0.0) {
        if (w <= coulomb && w >= -coulomb_neg) {
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
        if ((w <= coulomb && w >= -coulomb_neg) || hr <= 0.0) {
            *v = 0.0;
            return;
        }
        /* from rest the other way, with that direction's gain and Coulomb level */
        s = w > 0.0 ? 1.0 : -1.0;
        vinf = st_plant_target_speed(s, w, gain, coulomb, gain_neg, coulomb_neg, vmax);
        ar = exp(-hr / tau);
        *p += vinf * hr + vinf * tau * expm1(-hr / tau);
        *v = vinf * (1.0 - ar);
        return;
    }
    *p = *p + vinf * h + (*v - vinf) * b;
    *v = vend;
}

/* plant.advance_tick: one tick, w_old until lambda then w_new [V, net of offset]. */
static void st_plant_advance_tick(double *p, double *v, double w_old, double w_new,
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
                         row[ST_R_COULOMB_NEG]);
    }
    st_plant_advance(p, v, w_new, row[ST_R_H2], row[ST_R_A2], row[ST_R_B2], gain, row[ST_R_TAU],
                     row[ST_R_COULOMB], vmax, row[ST_R_GAIN_NEG], row[ST_R_COULOMB_NEG]);
}

#endif /* SERVOTUNE_PLANT_H */
