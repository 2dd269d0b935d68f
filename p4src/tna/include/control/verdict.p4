/*
 * CIVIC TNA -- verdict word and UDP checksum, in egress (pipeline.md
 * sections 3 and 5; see the v1model verdict.p4).
 *
 * Ingress has no stages to spare after the lsq chain, so the rewrite is
 * done in egress: the bridge header carries plant = 1 and the verdict word
 * (12 zero bits ++ cls1 ++ cls0). The frame reaches egress unmodified, so
 * hdr.plant.verdict and hdr.udp.checksum still hold the values it arrived
 * with.
 *
 * The 32-bit sum and two folds of pipeline.md section 5 are done as two
 * 16-bit ones' complement additions with end-around carry:
 *   u = ~HC (+) ~m ;  v = u (+) m'    where a (+) b = a + b + carry
 * (a + b wrapped below a means there was a carry). Ones' complement
 * addition is associative, and a (+) b is 0 only for a = b = 0, so v equals
 * the doubly folded 32-bit sum exactly; tests/p4/test_p4_source.py checks
 * this transcription against civic.wire.incremental_checksum.
 *   HC' = ~v, or 0xFFFF when ~v == 0; HC = 0 stays 0.
 */
#ifndef _CIVIC_TNA_VERDICT_P4_
#define _CIVIC_TNA_VERDICT_P4_

control Verdict(inout eg_headers_t hdr, in bit<16> m_new) {
    bit<16> n_hc;
    bit<16> n_m;
    bit<16> u;
    bit<16> v;

    apply {
        if (hdr.udp.checksum != 0) {
            n_hc = ~hdr.udp.checksum;
            n_m = ~hdr.plant.verdict;
            u = n_hc + n_m;
            if (u < n_hc) {
                u = u + 1;
            }
            v = u + m_new;
            if (v < u) {
                v = v + 1;
            }
            if (v == 0xFFFF) {
                hdr.udp.checksum = 0xFFFF;      // ~v == 0 is sent as 0xFFFF
            } else {
                hdr.udp.checksum = ~v;
            }
        }
        hdr.plant.verdict = m_new;
    }
}

#endif  /* _CIVIC_TNA_VERDICT_P4_ */
