/*
 * CIVIC -- P4_16 data plane for Tofino (TNA), same behaviour as
 * p4src/v1model/civic.p4 within Tofino's rules. Build:
 *   bf-p4c --target tofino --arch tna p4src/tna/civic.p4
 *
 * Differences from v1model (details in p4src/README.md):
 *  - 2 monitor slots (TNA_MONITORS); each slot's window, ring length and
 *    estimator are compile-time constants (include/config.p4), because
 *    Tofino multiplies only by constants (shift-and-add, const_mul.p4);
 *  - every register is read-modified-written by one RegisterAction;
 *  - the verdict word and the UDP checksum are written in egress
 *    (control/verdict.p4), from a 3-byte bridge header;
 *  - ring cells are 32 bit wide.
 * P4Info names: the same as v1model for what exists here
 * (CivicIngress.forward, ..., CivicIngress.mon0.*, CivicIngress.mon1.*).
 *
 * Ingress stage plan (one dependent step per stage; both slots in parallel):
 *   0  monitored_port, plant_prefix, forward, monK.config,
 *      monK.precondition, seq - 1
 *   1  last_seq (gap), ptr, x
 *   2  ring (old), run
 *   3  d = x - old, d_b, R*old shifts         (endpoint key = d_b)
 *   4  s0, R*old adds                         (endpoint: classify)
 *   5  R*old, s0' = s0 + d_b
 *   6  t = s0 - R*old, (W-1)*s0' shifts
 *   7  s1, (W-1)*s0' adds
 *   8  (W-1)*s0' + bias, 2*s1
 *   9  slope_key = prod - 2*s1
 *  10  classify
 * Egress: verdict word from the bridge header, checksum (~6 stages).
 */
#include <core.p4>
#include <tna.p4>

#include "../shared/define.p4"
#include "../shared/headers.p4"
#include "include/config.p4"
#include "include/metadata.p4"
#include "include/parser.p4"
#include "include/control/forwarding.p4"
#include "include/control/plant_lookup.p4"
#include "include/control/monitor_config.p4"
#include "include/control/const_mul.p4"
#include "include/control/data_collection.p4"
#include "include/control/slope.p4"
#include "include/control/classification.p4"
#include "include/control/verdict.p4"

control CivicIngress(inout ig_headers_t hdr,
                     inout ig_metadata_t meta,
                     in ingress_intrinsic_metadata_t ig_intr_md,
                     in ingress_intrinsic_metadata_from_parser_t ig_prsr_md,
                     inout ingress_intrinsic_metadata_for_deparser_t ig_dprsr_md,
                     inout ingress_intrinsic_metadata_for_tm_t ig_tm_md) {

    Forwarding() forwarding;
    PlantLookup() plant_lookup;
    SeqGap() seq_gap;

    @name("mon0") MonitorConfig() mon0_config;
    @name("mon0") Precondition() mon0_precondition;
    @name("mon0") DataCollection(MON0_RING_LEN, MON0_R_MUL) mon0_data;
    @name("mon0") Slope(MON0_LSQ == 1, MON0_WINDOW % 2 == 0, MON0_W1_MUL) mon0_slope;
    @name("mon0") Classification(MON0_WINDOW) mon0_classification;

    @name("mon1") MonitorConfig() mon1_config;
    @name("mon1") Precondition() mon1_precondition;
    @name("mon1") DataCollection(MON1_RING_LEN, MON1_R_MUL) mon1_data;
    @name("mon1") Slope(MON1_LSQ == 1, MON1_WINDOW % 2 == 0, MON1_W1_MUL) mon1_slope;
    @name("mon1") Classification(MON1_WINDOW) mon1_classification;

    apply {
        forwarding.apply(ig_intr_md.ingress_port, ig_tm_md, ig_dprsr_md);

        if (hdr.plant.isValid()) {
            plant_lookup.apply(hdr, meta);
            mon0_config.apply(hdr.plant, meta.mon0);
            mon0_precondition.apply(hdr.plant, meta.mon0);
            mon1_config.apply(hdr.plant, meta.mon1);
            mon1_precondition.apply(hdr.plant, meta.mon1);

            if (meta.monitored == 1 && meta.in_prefix == 1) {
                hdr.bridge.plant = 1;
                seq_gap.apply(hdr, meta);

                if (meta.mon0.enabled == 1) {
                    mon0_data.apply(meta.slot, meta.gap, meta.mon0);
                    mon0_slope.apply(meta.mon0);
                    mon0_classification.apply(meta.mon0, hdr.bridge.cls0);
                }
                if (meta.mon1.enabled == 1) {
                    mon1_data.apply(meta.slot, meta.gap, meta.mon1);
                    mon1_slope.apply(meta.mon1);
                    mon1_classification.apply(meta.mon1, hdr.bridge.cls1);
                }
            }
        }
    }
}

control CivicEgress(inout eg_headers_t hdr,
                    inout eg_metadata_t meta,
                    in egress_intrinsic_metadata_t eg_intr_md,
                    in egress_intrinsic_metadata_from_parser_t eg_prsr_md,
                    inout egress_intrinsic_metadata_for_deparser_t eg_dprsr_md,
                    inout egress_intrinsic_metadata_for_output_port_t eg_oport_md) {

    Verdict() verdict;

    apply {
        if (meta.bridge.plant == 1 && hdr.plant.isValid()) {
            verdict.apply(hdr, meta.bridge.verdict);
        }
    }
}

Pipeline(CivicIngressParser(),
         CivicIngress(),
         CivicIngressDeparser(),
         CivicEgressParser(),
         CivicEgress(),
         CivicEgressDeparser()) pipe;

Switch(pipe) main;
