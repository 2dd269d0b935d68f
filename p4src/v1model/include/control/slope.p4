/*
 * CIVIC v1model -- slope estimators (docs/pipeline.md section 3).
 *
 * over z, the ring's values (x, or a balance monitor's (x << 6) - acc):
 *   endpoint: slope = z - old                 (old = z[n - W + 1], R = W - 1)
 *   value:    slope = z                       (limit monitors)
 *   lsq:      slope = (W - 1) * s0 - 2 * s1   (R = W; twice the least-
 *             squares numerator; the switch never divides, the class
 *             ranges are scaled instead)
 *
 * Both are signed 32-bit values computed in bit<32> modular arithmetic,
 * which is two's complement: x - old < 0 wraps to 2^32 - |x - old|.
 * resid = slope - offset (the compensate table's expected inflow, section
 * 3a; 0 on a miss) and slope_key = resid XOR SLOPE_BIAS, the order-
 * preserving unsigned key of the class table. BMv2 multiplies at run
 * time, so W comes from set_config.
 */
#ifndef _CIVIC_V1MODEL_SLOPE_P4_
#define _CIVIC_V1MODEL_SLOPE_P4_

control Slope(inout monitor_md_t m) {
    apply {
        if (m.estimator == ESTIMATOR_LSQ) {
            m.slope = ((bit<32>)m.window - 1) * m.s0 - (m.s1 << 1);
        } else if (m.estimator == ESTIMATOR_ENDPOINT) {
            m.slope = m.z - m.old;
        } else {
            m.slope = m.z;                      // value: a limit monitor's level
        }
        m.slope_key = (m.slope - m.offset) ^ SLOPE_BIAS;
    }
}

#endif  /* _CIVIC_V1MODEL_SLOPE_P4_ */
