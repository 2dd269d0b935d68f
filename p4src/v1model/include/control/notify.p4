/*
 * CIVIC v1model -- verdict-change digest (docs/pipeline.md section 7).
 *
 * Each monitor slot keeps last_class and counts its verdicts (monitor.p4);
 * here the slots' changes of one plant message become one digest
 * verdict_change_t (shared/headers.p4): BMv2 keeps one digest per packet
 * (a second digest() call in the same packet replaces the first), so a
 * message on which two monitors change must carry both. The controller
 * expands it into one event per set bit of `changed`, in monitor order.
 * P4Info: the digest is named after its type, verdict_change_t.
 */
#ifndef _CIVIC_V1MODEL_NOTIFY_P4_
#define _CIVIC_V1MODEL_NOTIFY_P4_

control Notify(in headers_t hdr, in local_metadata_t meta) {
    apply {
        bit<8> changed = (bit<8>)meta.mon3.changed << 3 | (bit<8>)meta.mon2.changed << 2
                       | (bit<8>)meta.mon1.changed << 1 | (bit<8>)meta.mon0.changed;
        if (changed != 0) {
            digest<verdict_change_t>(VERDICT_DIGEST_RECEIVER, {
                hdr.ipv4.src_addr,
                hdr.plant.seq,
                changed,
                (bit<8>)meta.mon3.prev << 6 | (bit<8>)meta.mon2.prev << 4
                    | (bit<8>)meta.mon1.prev << 2 | (bit<8>)meta.mon0.prev,
                (bit<8>)meta.mon3.cls << 6 | (bit<8>)meta.mon2.cls << 4
                    | (bit<8>)meta.mon1.cls << 2 | (bit<8>)meta.mon0.cls,
                meta.mon0.slope, meta.mon0.level,
                meta.mon1.slope, meta.mon1.level,
                meta.mon2.slope, meta.mon2.level,
                meta.mon3.slope, meta.mon3.level});
        }
    }
}

#endif  /* _CIVIC_V1MODEL_NOTIFY_P4_ */
