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
 *   3. per monitor slot k = 0..3 (if enabled):
 *        config, precondition, data collection, slope, classification
 *   4. verdict      verdict word + incremental UDP checksum
 * Steps 2-4 run only for frames with a complete plant message; 3-4 only
 * for plant messages (monitored port and plant prefix). Other frames leave
 * byte-identical and touch no register.
 *
 * P4Info names (the control-plane contract, civic/p4runtime.py):
 *   CivicIngress.forward, .set_egress, .drop
 *   CivicIngress.monitored_port, .set_monitored
 *   CivicIngress.plant_prefix, .set_plant
 *   CivicIngress.last_seq
 *   CivicIngress.monK.{config, set_config, precondition, qualify,
 *                      disqualify, classify, set_class,
 *                      ring, ptr, run, s0, s1}            K = 0..3
 */
#include <core.p4>
#include <v1model.p4>

#include "../shared/define.p4"
#include "../shared/headers.p4"
#include "include/metadata.p4"
#include "include/parser.p4"
#include "include/control/forwarding.p4"
#include "include/control/plant_lookup.p4"
#include "include/control/monitor_config.p4"
#include "include/control/data_collection.p4"
#include "include/control/slope.p4"
#include "include/control/classification.p4"
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

    // Monitor slot k: five instances sharing the external name "monK", so
    // that their tables, actions and registers are CivicIngress.monK.*
    // (see monitor_config.p4).
    @name("mon0") MonitorConfig() mon0_config;
    @name("mon0") Precondition() mon0_precondition;
    @name("mon0") DataCollection() mon0_data;
    @name("mon0") Slope() mon0_slope;
    @name("mon0") Classification() mon0_classification;

    @name("mon1") MonitorConfig() mon1_config;
    @name("mon1") Precondition() mon1_precondition;
    @name("mon1") DataCollection() mon1_data;
    @name("mon1") Slope() mon1_slope;
    @name("mon1") Classification() mon1_classification;

    @name("mon2") MonitorConfig() mon2_config;
    @name("mon2") Precondition() mon2_precondition;
    @name("mon2") DataCollection() mon2_data;
    @name("mon2") Slope() mon2_slope;
    @name("mon2") Classification() mon2_classification;

    @name("mon3") MonitorConfig() mon3_config;
    @name("mon3") Precondition() mon3_precondition;
    @name("mon3") DataCollection() mon3_data;
    @name("mon3") Slope() mon3_slope;
    @name("mon3") Classification() mon3_classification;

    Verdict() verdict;

    apply {
        forwarding.apply(standard_metadata);

        meta.plant = 0;
        if (hdr.plant.isValid()) {
            plant_lookup.apply(hdr, meta);
        }
        if (meta.plant == 1) {
            mon0_config.apply(hdr.plant, meta.mon0);
            if (meta.mon0.enabled == 1) {
                mon0_precondition.apply(hdr.plant, meta.mon0);
                mon0_data.apply(meta.slot, meta.gap, meta.mon0);
                mon0_slope.apply(meta.mon0);
                mon0_classification.apply(meta.mon0);
            }

            mon1_config.apply(hdr.plant, meta.mon1);
            if (meta.mon1.enabled == 1) {
                mon1_precondition.apply(hdr.plant, meta.mon1);
                mon1_data.apply(meta.slot, meta.gap, meta.mon1);
                mon1_slope.apply(meta.mon1);
                mon1_classification.apply(meta.mon1);
            }

            mon2_config.apply(hdr.plant, meta.mon2);
            if (meta.mon2.enabled == 1) {
                mon2_precondition.apply(hdr.plant, meta.mon2);
                mon2_data.apply(meta.slot, meta.gap, meta.mon2);
                mon2_slope.apply(meta.mon2);
                mon2_classification.apply(meta.mon2);
            }

            mon3_config.apply(hdr.plant, meta.mon3);
            if (meta.mon3.enabled == 1) {
                mon3_precondition.apply(hdr.plant, meta.mon3);
                mon3_data.apply(meta.slot, meta.gap, meta.mon3);
                mon3_slope.apply(meta.mon3);
                mon3_classification.apply(meta.mon3);
            }

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
