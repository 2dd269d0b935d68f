/*
 * CIVIC v1model -- verdict word and UDP checksum (docs/pipeline.md
 * sections 3 and 5).
 *
 * verdict = cls0 | cls1 << 2 | cls2 << 4 | cls3 << 6 (bits 15..8 stay 0;
 * the word has room for 8 monitors, this program has MAX_MONITORS = 4).
 * It overwrites the payload's verdict for every plant message, whatever
 * the gateway sent; a disabled or not evaluated slot contributes 0.
 *
 * UDP checksum, incremental (RFC 1624 eq. 3) for the one 16-bit word that
 * changes, m -> m':
 *   s = (~HC & 0xFFFF) + (~m & 0xFFFF) + m'
 *   s = (s & 0xFFFF) + (s >> 16); s = (s & 0xFFFF) + (s >> 16)
 *   HC' = ~s & 0xFFFF; if HC' == 0: HC' = 0xFFFF
 * and a checksum of 0 (not used) stays 0. This is done here in plain
 * arithmetic and not with update_checksum_with_payload: a full recompute
 * would sum the Ethernet trailer bytes that BMv2 keeps as payload, and it
 * would "repair" a wrong checksum, where the model keeps the error.
 * 3 * 0xFFFF < 2^18, so two folds of a 32-bit sum always reach 16 bits.
 */
#ifndef _CIVIC_V1MODEL_VERDICT_P4_
#define _CIVIC_V1MODEL_VERDICT_P4_

control Verdict(inout headers_t hdr, in local_metadata_t meta) {
    apply {
        bit<16> m_old = hdr.plant.verdict;
        bit<16> m_new = ((bit<16>)meta.mon3.cls << 6) | ((bit<16>)meta.mon2.cls << 4)
                      | ((bit<16>)meta.mon1.cls << 2) | (bit<16>)meta.mon0.cls;
        hdr.plant.verdict = m_new;

        if (hdr.udp.checksum != 0) {
            bit<32> s = (bit<32>)(~hdr.udp.checksum) + (bit<32>)(~m_old) + (bit<32>)m_new;
            s = (s & 0xFFFF) + (s >> 16);
            s = (s & 0xFFFF) + (s >> 16);
            bit<16> hc = ~(s[15:0]);
            if (hc == 0) {
                hc = 0xFFFF;
            }
            hdr.udp.checksum = hc;
        }
    }
}

#endif  /* _CIVIC_V1MODEL_VERDICT_P4_ */
