/*
 * CIVIC -- Continuous In-situ Validation of Industrial Control models.
 * P4_16 data plane for the v1model architecture (BMv2 simple_switch_grpc).
 *
 * docs/pipeline.md is the normative contract; the software model in
 * civic/pipeline/ implements the same integer semantics and both must
 * produce byte-identical frames. Build: `make p4` (see p4src/README.md):
 *   p4c-bm2-ss --std p4-16 --arch v1model \
 *       --p4runtime-files build/v1model/civic.p4info.txtpb \
 *       -o build/v1model/civic.json p4src/v1model/civic.p4
 *
 * Per frame:
 *   1. forwarding   ingress_port -> egress port (every frame)
 *   2. plant_lookup monitored UDP port, plant prefix -> slot; seq gap
 *   3. per monitor slot k = 0..3 (Monitor() monK, if enabled):
 *        config, signal, precondition, data collection, slope, classification
 *   4. notify       one digest per message on which a verdict changes
 *   5. verdict      verdict word + incremental UDP checksum
 * Steps 2-4 run only for frames with a complete plant message; 3-4 only
 * for plant messages (monitored port and plant prefix). Other frames leave
 * byte-identical and touch no register.
 *
 * P4Info names (the control-plane contract, civic/switch/schema.py):
 *   CivicIngress.forward, .set_egress, .drop
 *   CivicIngress.monitored_port, .set_monitored
 *   CivicIngress.plant_prefix, .set_plant
 *   CivicIngress.last_seq, .last_p1, .last_v1, .last_v2
 *   CivicIngress.monK.{config, set_config, precondition, qualify,
 *                      disqualify, compensate, set_offset, flow0,
 *                      set_flow0, flow1, set_flow1, classify, set_class,
 *                      ring, ptr, run, s0, s1, last_class, acc, accb,
 *                      ringb, cand, hold,
 *                      verdicts (counter)}                  K = 0..3
 *   digest verdict_change_t
 */
#include <core.p4>
// The v1model API this program is written against (register<T> with a
// bit<32> index, standard_metadata ports bit<9>). It is p4c's default;
// pinning it keeps a newer default from changing the extern signatures.
#define V1MODEL_VERSION 20180101
#include <v1model.p4>

#include "../shared/define.p4"
#include "../shared/headers.p4"
#include "include/metadata.p4"
#include "include/parser.p4"
#include "include/control/forwarding.p4"
#include "include/control/plant_lookup.p4"
#include "include/control/signal_select.p4"
#include "include/control/slope.p4"
#include "include/control/monitor.p4"
#include "include/control/notify.p4"
#include "include/control/verdict.p4"

control CivicVerifyChecksum(inout headers_t hdr, inout local_metadata_t meta) {
    apply {
        // Nothing is verified: a frame with a wrong checksum is still a
        // plant message and keeps its error (pipeline.md section 5).
    }
}

control CivicIngress(inout headers_t hdr,
                     inout local_metadata_t meta,
                     inout standard_metadata_t standard_metadata) {

    Forwarding() forwarding;
    PlantLookup() plant_lookup;

    // Monitor slot k is the instance monK of Monitor: its tables, actions
    // and registers are CivicIngress.monK.* (see monitor.p4).
    Monitor() mon0;
    Monitor() mon1;
    Monitor() mon2;
    Monitor() mon3;

    Notify() notify;
    Verdict() verdict;

    apply {
        forwarding.apply(standard_metadata);

        meta.plant = 0;
        if (hdr.plant.isValid()) {
            plant_lookup.apply(hdr, meta);
        }
        if (meta.plant == 1) {
            mon0.apply(hdr.plant, meta.slot, meta.gap, meta.dp1, meta.dv1, meta.dv2, meta.mon0);
            mon1.apply(hdr.plant, meta.slot, meta.gap, meta.dp1, meta.dv1, meta.dv2, meta.mon1);
            mon2.apply(hdr.plant, meta.slot, meta.gap, meta.dp1, meta.dv1, meta.dv2, meta.mon2);
            mon3.apply(hdr.plant, meta.slot, meta.gap, meta.dp1, meta.dv1, meta.dv2, meta.mon3);
            notify.apply(hdr, meta);
            verdict.apply(hdr, meta);
        }
    }
}

control CivicEgress(inout headers_t hdr,
                    inout local_metadata_t meta,
                    inout standard_metadata_t standard_metadata) {
    apply { }
}

control CivicComputeChecksum(inout headers_t hdr, inout local_metadata_t meta) {
    apply {
        // The IPv4 header is never modified; the UDP checksum is updated
        // incrementally in verdict.p4.
    }
}

V1Switch(CivicParser(),
         CivicVerifyChecksum(),
         CivicIngress(),
         CivicEgress(),
         CivicComputeChecksum(),
         CivicDeparser()) main;
