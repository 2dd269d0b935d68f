/*
 * CIVIC TNA -- slope estimators and the class key (pipeline.md section 3;
 * see the v1model slope.p4).
 *
 *   endpoint: slope_key = (x - old) XOR 2^31 = x32_b - old  (d_b, ready
 *             right after the ring access)
 *   lsq:      slope = (W - 1) * s0' - 2 * s1'  (s0', s1' after the update),
 *             (W - 1) * s0' by shift-and-add (const_mul.p4)
 *
 * XOR with 2^31 is the same as adding 2^31 modulo 2^32. When W - 1 is odd
 * (W even) the bias rides along in the product for free:
 *   (W - 1) * (s0' + 2^31) = (W - 1) * s0' + 2^31   (mod 2^32)
 * and s0' + 2^31 = s0 + d_b is one addition, so slope_key = prod - 2 * s1'
 * with no extra stage. For odd W the XOR is a separate last step.
 */
#ifndef _CIVIC_TNA_SLOPE_P4_
#define _CIVIC_TNA_SLOPE_P4_

control Slope(inout monitor_md_t m)
             (bool lsq, bool bias_in_product,
              bit<8> w_a0, bit<8> w_a1, bit<8> w_a2, bit<8> w_a3,
              bit<4> w_used, bit<4> w_negs) {

    ConstMul(w_a0, w_a1, w_a2, w_a3, w_used, w_negs) w1_mul;

    apply {
        if (lsq) {
            if (bias_in_product) {
                m.s0n = m.s0 + m.d_b;
            } else {
                m.s0n = m.s0 + m.d;
            }
            w1_mul.apply(m.s0n, m.prod);
            m.s1x2 = m.s1 << 1;
            if (bias_in_product) {
                m.slope_key = m.prod - m.s1x2;
            } else {
                m.slope = m.prod - m.s1x2;
                m.slope_key = m.slope ^ SLOPE_BIAS;
            }
        } else {
            m.slope_key = m.d_b;
        }
    }
}

#endif  /* _CIVIC_TNA_SLOPE_P4_ */
