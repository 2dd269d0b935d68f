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
#include "include/control/signal_select.p4"
#include "include/control/const_mul.p4"
#include "include/control/slope.p4"
#include "include/control/monitor.p4"
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

    // Monitor slot k is the instance monK of Monitor: its tables, actions
    // and registers are CivicIngress.monK.* (see monitor.p4). Arguments:
    // W, R, estimator, bias-in-product (W even), R and W - 1 as
    // shift-and-add terms (include/config.p4).
    Monitor(MON0_WINDOW, MON0_RING_LEN, MON0_LSQ == 1, MON0_WINDOW % 2 == 0,
            MON0_R_MUL, MON0_W1_MUL) mon0;
    Monitor(MON1_WINDOW, MON1_RING_LEN, MON1_LSQ == 1, MON1_WINDOW % 2 == 0,
            MON1_R_MUL, MON1_W1_MUL) mon1;

    apply {
        forwarding.apply(ig_intr_md.ingress_port, ig_tm_md, ig_dprsr_md);

        if (hdr.plant.isValid()) {
            plant_lookup.apply(hdr, meta);
            if (meta.monitored == 1 && meta.in_prefix == 1) {
                meta.plant = 1;
                hdr.bridge.plant = 1;
                seq_gap.apply(hdr, meta);
            }
            mon0.apply(hdr.plant, meta.plant, meta.slot, meta.gap, meta.mon0, hdr.bridge.cls0);
            mon1.apply(hdr.plant, meta.plant, meta.slot, meta.gap, meta.mon1, hdr.bridge.cls1);
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
