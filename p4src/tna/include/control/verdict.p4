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
 * The checksum is pipeline.md section 5 literally, one ALU operation per
 * step (CIVIC_STEP, const_mul.p4), in 32 bits:
 *   s  = (~HC & 0xFFFF) + (~m & 0xFFFF) + m'  = (0x1FFFE - HC) + (m' - m)
 *   s  = (s & 0xFFFF) + (s >> 16), twice
 *   HC' = ~s & 0xFFFF, or 0xFFFF when that is 0 (s == 0xFFFF); HC = 0 stays 0.
 * (m' - m may wrap below 0; the sum is exact modulo 2^32 and s < 2^18.)
 * An earlier version added 16-bit words with end-around carry detected by
 * `u < n_hc`; bf-p4c would need a two-field comparison in a gateway for
 * that, the folds need none.
 */
#ifndef _CIVIC_TNA_VERDICT_P4_
#define _CIVIC_TNA_VERDICT_P4_

control Verdict(inout eg_headers_t hdr, in bit<2> cls1, in bit<2> cls0) {
    bit<32> hc;
    bit<32> m_old;
    bit<32> m_n;
    bit<32> a;
    bit<32> b;
    bit<32> s;
    bit<32> lo;
    bit<32> hi;

    bit<32> s_n;
    // 16-bit fields into 32-bit containers and back through identity
    // hashes (ALU operations do not mix container sizes)
    Hash<bit<32>>(HashAlgorithm_t.IDENTITY) widen_hc;
    Hash<bit<32>>(HashAlgorithm_t.IDENTITY) widen_m_old;
    Hash<bit<32>>(HashAlgorithm_t.IDENTITY) widen_m_new;
    Hash<bit<16>>(HashAlgorithm_t.IDENTITY) narrow;
    // m' = 12 zero bits ++ cls1 ++ cls0, assembled by identity hashes
    Hash<bit<16>>(HashAlgorithm_t.IDENTITY) verdict_word;

    // (one hash result per table: 32 bits of immediate data each)
    CIVIC_STEP(widen_1, hc = widen_hc.get({hdr.udp.checksum});)
    CIVIC_STEP(widen_2, m_old = widen_m_old.get({hdr.plant.verdict});)
    CIVIC_STEP(terms, a = 0x1FFFE - hc; b = m_n - m_old;)
    CIVIC_STEP(sum, s = a + b;)
    CIVIC_STEP(split1, lo = s & 0xFFFF; hi = s >> 16;)
    CIVIC_STEP(fold1, s = lo + hi;)
    CIVIC_STEP(split2, lo = s & 0xFFFF; hi = s >> 16;)
    CIVIC_STEP(fold2, s = lo + hi;)
    CIVIC_STEP(invert, s_n = ~s;)
    CIVIC_STEP(write_ffff, hdr.udp.checksum = 0xFFFF;)
    CIVIC_STEP(write_sum, hdr.udp.checksum = narrow.get({s_n[15:0]});)
#ifdef CIVIC_PROFILE_BALANCE
    // the profile's slots are monitors 2 and 3: bits 7..6 and 5..4
    CIVIC_STEP(widen_3, m_n = widen_m_new.get({cls1, cls0, 4w0});)
    CIVIC_STEP(write_verdict, hdr.plant.verdict = verdict_word.get({cls1, cls0, 4w0});)
#else
    CIVIC_STEP(widen_3, m_n = widen_m_new.get({cls1, cls0});)
    CIVIC_STEP(write_verdict, hdr.plant.verdict = verdict_word.get({cls1, cls0});)
#endif

    apply {
        // reads hdr.plant.verdict before write_verdict replaces it (stage order)
        if (hdr.udp.checksum != 0) {
            widen_1.apply();
            widen_2.apply();
            widen_3.apply();
            terms.apply();
            sum.apply();
            split1.apply();
            fold1.apply();
            split2.apply();
            fold2.apply();
            invert.apply();
            if (s == 0xFFFF) {
                write_ffff.apply();     // ~s == 0 is sent as 0xFFFF
            } else {
                write_sum.apply();
            }
        }
        write_verdict.apply();
    }
}

#endif  /* _CIVIC_TNA_VERDICT_P4_ */
