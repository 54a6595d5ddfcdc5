/* bench/c_loop.c: the exported C runtime closing the loop around a C copy of the plant.
 *
 * The bench's yardstick for the engine (make bench, figure engine_vs_c_runtime): the same loop
 * as servotune.sim.engine.simulate runs (latched counter, no noise, the tick-slot hold of the
 * writes, the exact one-tick plant map) written in C around the project's exported runtime
 * (st_tick). The plant here is a line-by-line copy of servotune/plant.py (_target_speed,
 * advance, advance_tick: the asymmetric model, gain and Coulomb level per direction) for this
 * benchmark only: the runtime itself holds laws and hardware arithmetic only (the project's
 * decision 16). The row layout comes from plant_rows.h, which the bench writes from
 * servotune.plant's R_* indices. Built with -ffp-contract=off so that the floating
 * point operations are the engine's, one by one: the bench checks every D/A code against it.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "plant_rows.h"
#include "servotune_tables.h"

static const st_consts_t consts = SERVOTUNE_TABLES_INIT;

/* servotune.plant._target_speed: the speed the motor tends to moving in direction s (+-1) */
static double target_speed(double s, double w, double gain, double coulomb, double gain_neg,
                           double coulomb_neg, double vmax)
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

/* servotune.plant.advance: exact motion over h seconds of constant net input w [V]; gain and
 * coulomb act moving positive, gain_neg and coulomb_neg moving negative */
static void advance(double *pp, double *pv, double w, double h, double a, double b, double gain,
                    double tau, double coulomb, double vmax, double gain_neg, double coulomb_neg)
{
    double p = *pp;
    double v = *pv;
    double s;
    double vinf;
    double vend;
    int kinks;
    if (h <= 0.0) {
        return;
    }
    if (v == 0.0) {
        if (w <= coulomb && w >= -coulomb_neg) {
            *pv = 0.0;
            return;
        }
        s = w > 0.0 ? 1.0 : -1.0;
    } else {
        s = v > 0.0 ? 1.0 : -1.0;
    }
    vinf = target_speed(s, w, gain, coulomb, gain_neg, coulomb_neg, vmax);
    vend = vinf + (v - vinf) * a;
    kinks = coulomb > 0.0 || coulomb_neg > 0.0 || gain_neg != gain;
    if (kinks && v != 0.0 && vinf * s < 0.0 && vend * s <= 0.0) {
        double t0 = tau * log((v - vinf) / (-vinf));
        double hr;
        double ar;
        if (t0 > h) {
            t0 = h;
        }
        p += vinf * t0 - (v - vinf) * tau * expm1(-t0 / tau);
        hr = h - t0;
        if ((w <= coulomb && w >= -coulomb_neg) || hr <= 0.0) {
            *pp = p;
            *pv = 0.0;
            return;
        }
        s = w > 0.0 ? 1.0 : -1.0;
        vinf = target_speed(s, w, gain, coulomb, gain_neg, coulomb_neg, vmax);
        ar = exp(-hr / tau);
        p += vinf * hr + vinf * tau * expm1(-hr / tau);
        *pp = p;
        *pv = vinf * (1.0 - ar);
        return;
    }
    *pp = p + vinf * h + (v - vinf) * b;
    *pv = vend;
}

/* servotune.plant.advance_tick: w_old for the row's lambda, then w_new */
static void advance_tick(double *p, double *v, double w_old, double w_new, const double *row)
{
    const double vmax = row[R_VMAX];
    const double gain = row[R_GAIN];
    if (row[R_LINEAR] > 0.0 && fabs(w_new) * gain <= vmax && fabs(w_old) * gain <= vmax) {
        const double p0 = *p;
        const double v0 = *v;
        *p = p0 + row[R_PHI_B] * v0 + row[R_GO_P] * w_old + row[R_GN_P] * w_new;
        *v = row[R_PHI_A] * v0 + row[R_GO_V] * w_old + row[R_GN_V] * w_new;
        return;
    }
    if (row[R_H1] > 0.0) {
        advance(p, v, w_old, row[R_H1], row[R_A1], row[R_B1], gain, row[R_TAU], row[R_COULOMB],
                vmax, row[R_GAIN_NEG], row[R_COULOMB_NEG]);
    }
    advance(p, v, w_new, row[R_H2], row[R_A2], row[R_B2], gain, row[R_TAU], row[R_COULOMB], vmax,
            row[R_GAIN_NEG], row[R_COULOMB_NEG]);
}

#define RING 8

/* n ticks of one axis in task mode on ref[]: the codes written go to codes[]; 0 if done,
 * -1 if the lag needs a longer ring than RING */
int c_loop(int64_t n, const double *row, int64_t lag, int64_t init, int bits, double dac_lo,
           double lsb, const int64_t *ref, int32_t *codes)
{
    st_state_t state;
    st_axis_in_t in;
    st_axis_out_t out;
    double ring[RING] = {0.0};
    const int64_t mask = ((int64_t)1 << bits) - 1;
    const int ring_n = (int)lag + 2;
    double pos = 0.0;
    double spd = 0.0;
    int slot = ring_n - 1;
    int64_t k;
    int j;
    if (ring_n > RING) {
        return -1;
    }
    st_init(&state);
    in.mode = ST_MODE_TASK;
    in.reset = 0;
    in.u_add = 0;
    for (k = 0; k < n; k++) {
        const int64_t raw = (init + (int64_t)floor(pos + 0.0)) & mask;
        int j_new;
        int j_old;
        double v_new;
        double v_old;
        double w_off;
        slot = slot + 1 == ring_n ? 0 : slot + 1;
        for (j = 0; j < 4; j++) {
            in.bytes[j] = (uint8_t)(((uint64_t)raw >> (8 * j)) & 0xFFu);
        }
        in.ref = ref[k];
        st_tick(&consts, &state, &in, &out);
        codes[k] = out.code;
        ring[slot] = dac_lo + out.code * lsb;
        j_new = slot - (int)lag;
        if (j_new < 0) {
            j_new += ring_n;
        }
        v_new = k >= lag ? ring[j_new] : 0.0;
        j_old = j_new - 1;
        if (j_old < 0) {
            j_old += ring_n;
        }
        v_old = k >= lag + 1 ? ring[j_old] : 0.0;
        w_off = row[R_OFFSET] + 0.0;
        advance_tick(&pos, &spd, v_old + w_off, v_new + w_off, row);
    }
    return 0;
}
