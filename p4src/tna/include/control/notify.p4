/*
 * CIVIC TNA -- verdict counters (docs/pipeline.md section 7), in egress.
 *
 * last_class and the change flags are in the monitor slots (monitor.p4),
 * the digest in the ingress deparser (parser.p4). The counters need the
 * class as part of their index, which classify's actions cannot give their
 * attached objects (one addressing for all actions of a table), so they
 * count here, from the bridged class codes: cell slot * 4 + class of
 * verdictsK, the slot being ipv4.src_addr[7:0] (an identity hash of
 * {slot, class} is the index, no extra stage).
 */
#ifndef _CIVIC_TNA_NOTIFY_P4_
#define _CIVIC_TNA_NOTIFY_P4_

control Notify(in eg_headers_t hdr, in bit<2> cls1, in bit<2> cls0) {
#ifdef CIVIC_PROFILE_BALANCE
    // the profile's slots are monitors 2 and 3: verdicts2, verdicts3
    @name("verdicts2")
    Counter<bit<32>, bit<10>>(VERDICT_COUNTER_CELLS, CounterType_t.PACKETS) verdicts0;
    @name("verdicts3")
    Counter<bit<32>, bit<10>>(VERDICT_COUNTER_CELLS, CounterType_t.PACKETS) verdicts1;
#else
    Counter<bit<32>, bit<10>>(VERDICT_COUNTER_CELLS, CounterType_t.PACKETS) verdicts0;
    Counter<bit<32>, bit<10>>(VERDICT_COUNTER_CELLS, CounterType_t.PACKETS) verdicts1;
#endif
    Hash<bit<10>>(HashAlgorithm_t.IDENTITY) cell0;
    Hash<bit<10>>(HashAlgorithm_t.IDENTITY) cell1;

    apply {
        if (cls0 != CLASS_NOT_EVALUATED) {
            verdicts0.count(cell0.get({hdr.ipv4.src_addr[7:0], cls0}));
        }
        if (cls1 != CLASS_NOT_EVALUATED) {
            verdicts1.count(cell1.get({hdr.ipv4.src_addr[7:0], cls1}));
        }
    }
}

#endif  /* _CIVIC_TNA_NOTIFY_P4_ */
