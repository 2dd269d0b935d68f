/*
 * CIVIC -- P4_16 data plane for Tofino (TNA), same behaviour as
 * p4src/v1model/civic.p4 within Tofino's rules. Build:
 *   bf-p4c --target tofino --arch tna -I p4src p4src/tna/civic.p4   (make p4-tna)
 *
 * Differences from v1model (details in p4src/README.md, "The TNA variant"):
 *  - 2 monitor slots (TNA_MONITORS); each slot's window, ring length and
 *    estimator are compile-time constants (include/config.p4), because
 *    Tofino multiplies only by constants (shift-and-add, const_mul.p4);
 *  - every register is read-modified-written by one RegisterAction, and
 *    every dependent ALU step is its own @hidden table (CIVIC_STEP);
 *  - precondition is split in two tables (precondition: l1..l4,
 *    precondition_cmd: p1 v1 v2) and classify matches slope_key as two
 *    16-bit halves: bf-p4c's range-match limits;
 *  - compensate's set_offset takes the key bias minus the offset (the
 *    offset rides in the bias added in stage 4: no extra stage);
 *  - the verdict word and the UDP checksum are written in egress
 *    (control/verdict.p4), from a 3-byte bridge header;
 *  - ring cells are 32 bit wide.
 * Control-plane names: those of v1model (BF-RT: with the prefix "pipe."),
 * plus monK.precondition_cmd / qualify_cmd / disqualify_cmd.
 *
 * The balance profile (balance_t3 and balance_t1, monitors 2 and 3, in place
 * of these two test monitors) is p4src/tna/civic_balance.p4.
 *
 * Ingress stage plan as bf-p4c 9.13.4 placed it (both slots in each stage):
 *   0  forward, monitored_port, plant_prefix, seq - 1, monK.config,
 *      monK.precondition, monK.precondition_cmd
 *   1  last_seq (gap), ptr, x (by signal), aux = x[aux_plus] |-| x[aux_minus]
 *   2  ring (old), x widened to 32 bit, compensate (bias)
 *   3  run, d = x - old, R*old shifts
 *   4  s0, R*old adds, e = d + bias (bias = B - offset / (W - 1))
 *                                  (endpoint: slope_key = d + bias)
 *   5  R*old, s0n = s0 + e, t (mon0)
 *   6  t = s0 - R*old, s1 (mon0), (W-1)*s0n shifts
 *   7  s1 (mon1), (W-1)*s0n adds, 2*s1
 *   8  (W-1)*s0n
 *   9  slope_key = (W-1)*s0n - 2*s1
 *  10  classify, last_class
 *  11  digest_type (a slot's verdict changed)
 * Egress: verdict word from the bridge header, checksum (stages 0-8).
 */
#ifdef CIVIC_PROFILE_BALANCE
#error "the balance profile is p4src/tna/civic_balance.p4 (it defines CIVIC_PROFILE_BALANCE)"
#endif
#include <core.p4>
#include <tna.p4>

#include "../shared/define.p4"
#include "../shared/headers.p4"
#include "include/config.p4"
#include "include/metadata.p4"
#include "include/parser.p4"
#include "include/control/forwarding.p4"
#include "include/control/plant_lookup.p4"
#include "include/control/const_mul.p4"
#include "include/control/monitor.p4"
#include "include/control/verdict.p4"
#include "include/control/notify.p4"

// Every 32-bit arithmetic field of a monitor slot in one 32-bit container:
// Tofino ALU operations take at most two PHV sources, and a field split
// over two 16-bit containers makes an add or subtract need four.
@pa_container_size("ingress", "meta.mon0.x32", 32)
@pa_container_size("ingress", "meta.mon0.old", 32)
@pa_container_size("ingress", "meta.mon0.d", 32)
@pa_container_size("ingress", "meta.mon0.e", 32)
@pa_container_size("ingress", "meta.mon0.t0", 32)
@pa_container_size("ingress", "meta.mon0.t1", 32)
@pa_container_size("ingress", "meta.mon0.t2", 32)
@pa_container_size("ingress", "meta.mon0.t3", 32)
@pa_container_size("ingress", "meta.mon0.acc", 32)
@pa_container_size("ingress", "meta.mon0.s0", 32)
@pa_container_size("ingress", "meta.mon0.t", 32)
@pa_container_size("ingress", "meta.mon0.s1", 32)
@pa_container_size("ingress", "meta.mon0.s0n", 32)
@pa_container_size("ingress", "meta.mon0.slope_key", 32)
@pa_container_size("ingress", "meta.mon1.x32", 32)
@pa_container_size("ingress", "meta.mon1.old", 32)
@pa_container_size("ingress", "meta.mon1.d", 32)
@pa_container_size("ingress", "meta.mon1.e", 32)
@pa_container_size("ingress", "meta.mon1.t0", 32)
@pa_container_size("ingress", "meta.mon1.t1", 32)
@pa_container_size("ingress", "meta.mon1.t2", 32)
@pa_container_size("ingress", "meta.mon1.t3", 32)
@pa_container_size("ingress", "meta.mon1.acc", 32)
@pa_container_size("ingress", "meta.mon1.s0", 32)
@pa_container_size("ingress", "meta.mon1.t", 32)
@pa_container_size("ingress", "meta.mon1.s1", 32)
@pa_container_size("ingress", "meta.mon1.s0n", 32)
@pa_container_size("ingress", "meta.mon1.slope_key", 32)
// One-bit flags that tables of different slots write in the same stage
// get containers of their own (two tables cannot write one container in
// one stage); so do the two class codes of the bridge header.
@pa_solitary("ingress", "meta.monitored")
@pa_solitary("ingress", "meta.in_prefix")
@pa_solitary("ingress", "meta.gap")
@pa_solitary("ingress", "meta.mon0.q")
@pa_solitary("ingress", "meta.mon0.q_cmd")
@pa_solitary("ingress", "meta.mon1.q")
@pa_solitary("ingress", "meta.mon1.q_cmd")
// The two slots' config tables write their fields in stage 0: `enabled`
// (which the allocator would otherwise pack with the other slot's and with
// drop_ctl, written by forward) gets a container of its own.
@pa_solitary("ingress", "meta.mon0.enabled")
@pa_solitary("ingress", "meta.mon1.enabled")
@pa_container_size("ingress", "meta.mon0.bias", 32)
@pa_container_size("ingress", "meta.mon1.bias", 32)
@pa_container_size("ingress", "hdr.bridge.cls0", 8)
@pa_container_size("ingress", "hdr.bridge.cls1", 8)

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
    // W, R, estimator, the bias added to s0' (lsq), R and W - 1 as
    // shift-and-add terms (include/config.p4).
    Monitor(MON0_WINDOW, MON0_RING_LEN, MON0_LSQ == 1, MON0_S0_BIAS,
            MON0_R_MUL, MON0_W1_MUL) mon0;
    Monitor(MON1_WINDOW, MON1_RING_LEN, MON1_LSQ == 1, MON1_S0_BIAS,
            MON1_R_MUL, MON1_W1_MUL) mon1;

    // Every conditional below guards one table. bf-p4c places the tables of
    // two sibling if-blocks one block after the other on Tofino (a block's
    // tables are reached through next-table chaining), which would put
    // mon1's chain behind mon0's; flat single-table conditions let the two
    // slots' chains share stages.
    apply {
        forwarding.apply(ig_intr_md.ingress_port, ig_tm_md, ig_dprsr_md);

        // monitored_port, plant_prefix (only read the headers; their hits
        // count only for a complete plant message)
        plant_lookup.apply(hdr, meta);
        if (hdr.plant.isValid() && meta.monitored == 1 && meta.in_prefix == 1) {
            seq_gap.apply(hdr, meta);
        }
        mon0.apply(hdr.plant, meta.monitored, meta.in_prefix, meta.slot, meta.gap,
                   meta.mon0, hdr.bridge.cls0);
        mon1.apply(hdr.plant, meta.monitored, meta.in_prefix, meta.slot, meta.gap,
                   meta.mon1, hdr.bridge.cls1);
        // a verdict changed on this message: the deparser sends the digest
        if (meta.mon0.chg != 0 || meta.mon1.chg != 0) {
            ig_dprsr_md.digest_type = DIGEST_VERDICT_CHANGE;
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
    Notify() notify;

    apply {
        if (meta.bridge.plant == 1 && hdr.plant.isValid()) {
            verdict.apply(hdr, meta.bridge.cls1, meta.bridge.cls0);
            notify.apply(hdr, meta.bridge.cls1, meta.bridge.cls0);
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
