/* bench/c_loop.c: the exported C runtime closing the loop around a C copy of the plant.
 *
 * The bench's yardstick for the engine (make bench, figure engine_vs_c_runtime): the same loop
 * as servotune.sim.engine.simulate runs (latched counter, no noise, the tick-slot hold of the
 * writes, the exact one-tick plant map) written in C around the project's exported runtime
 * (st_tick). The plant is servotune_plant.h (package data beside the runtime, not part of it:
 * the runtime holds laws and hardware arithmetic only, the project's decision 16), the C mirror
 * of servotune/plant.py that the HAL plant component also runs. Built with -ffp-contract=off
 * so that the floating point operations are the engine's, one by one: the bench checks every
 * D/A code against it.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "servotune_plant.h"
#include "servotune_tables.h"

static const st_consts_t consts = SERVOTUNE_TABLES_INIT;

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
        w_off = row[ST_R_OFFSET] + 0.0;
        st_plant_advance_tick(&pos, &spd, v_old + w_off, v_new + w_off, row);
    }
    return 0;
}
