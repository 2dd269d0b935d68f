/*
 * CIVIC -- P4_16 data plane for Tofino (TNA), balance profile: the two
 * always-on mass-balance monitors of configs/monitors.toml, balance_t3
 * (monitor 2, verdict bits 5..4) and balance_t1 (monitor 3, bits 7..6),
 * in place of the test monitors drain_t3 and fill_t1 of p4src/tna/civic.p4
 * (monitors 0 and 1, whose verdict bits stay 0 here). Build:
 *   bf-p4c --target tofino --arch tna -g -I p4src -o OUT p4src/tna/civic_balance.p4
 *
 * Why a profile: each program alone uses all 12 of Tofino's stages, and a
 * balance slot's chain (two flow terms, the accumulators, the rings, the
 * lsq slope, the hold, last_class) is itself 11 stages deep; per stage the
 * two profiles together would need more than one Tofino stage has (e.g.
 * stage 0 TCAM: 19 + 24 of 24 blocks; stage 1 stateful ALUs: 3 + 4 of 4;
 * p4src/README.md, "The balance profile"; a four-slot program was not
 * compiled). The profile keeps everything
 * else of civic.p4: parser, forwarding, plant lookup, sequence gaps, the
 * bridged class bytes, the verdict word and UDP checksum in egress, the
 * verdict counters and the verdict-change digest (for monitors 2 and 3).
 * The profile is this file defining CIVIC_PROFILE_BALANCE before the shared
 * includes (include/config.p4, metadata.p4, parser.p4, control/verdict.p4,
 * control/notify.p4 switch on it), as stratum / fabric-tna select profiles
 * with a define; its controls are include/balance/*.p4.
 *
 * Differences from pipeline.md 3 / 3b beyond those of civic.p4 (details in
 * include/balance/balance.p4 and p4src/README.md):
 *  - W = R (80), the signal and the flow terms' operands are fixed at
 *    compile time (include/config.p4); the hold H comes from set_config
 *    (hold_min, 2..255);
 *  - the lsq slope is kept in a register of its own (slope + 2^31), not
 *    recomputed from s1: same value, three stages shorter;
 *  - cand and hold are one register pair; hold saturates at 65535;
 *  - command steps from two saturating differences (|a - b| in the MAU);
 *  - flow terms are TCAM range tables of at most 2048 entries
 *    (include/config.p4), fewer than civic train's 2-D terms have.
 *
 * Ingress stage plan as bf-p4c 9.13.4 placed it (both slots in each stage):
 *   0  forward, monitored_port, plant_prefix, seq - 1, config, precondition,
 *      head differences, x << BALANCE_SHIFT, the flow term on message fields
 *      (mon2.flow1 V2 on (l3, v2); mon3.flow0 P1 on (zero, p1))
 *   1  the flow term on a head difference (mon2.flow0 pipe23 on (l2 - l3,
 *      zero); mon3.flow1 V1 on (l1 - l2, v1)), ptr, last_v1, last_v2,
 *      H - 1 (from set_config's hold_min)
 *   2  acc, last_seq, last_p1, band widened
 *   3  z = (x << BALANCE_SHIFT) - acc', accb, command steps (cmd |-| last,
 *      last |-| cmd)
 *   4  ring (returns old + z), ringb (returns oldb), 2 * z, command steps (OR)
 *   5  old, z - old, first step of (W - 1) * (z + old), accb - oldb,
 *      precondition_cmd
 *   6  s0 (returns s0 - old), (W - 1) * (z + old), band_w (mon3)
 *   7  ndelta = 2 * (s0 - old) - (W - 1) * (z + old), run, band_w (mon2)
 *   8  slope (returns slope_key)
 *   9  classify + hold
 *  10  last_class, class byte
 *  11  digest_type (a slot's verdict changed)
 * Egress: verdict word from the bridge header, checksum, counters (stages
 * 0-9).
 */
#define CIVIC_PROFILE_BALANCE

#include <core.p4>
#include <tna.p4>

#include "../shared/define.p4"
#include "../shared/headers.p4"
#include "include/config.p4"
#include "include/metadata.p4"
#include "include/parser.p4"
#include "include/control/forwarding.p4"
#include "include/control/const_mul.p4"
#include "include/control/plant_lookup.p4"
#include "include/balance/command_steps.p4"
#include "include/balance/balance.p4"
#include "include/control/verdict.p4"
#include "include/control/notify.p4"

// As in civic.p4: every 32-bit arithmetic field in a 32-bit container,
// one-bit flags that tables of different slots write in one stage in
// containers of their own, one byte per bridged class code.
@pa_container_size("ingress", "meta.mon2.x16", 32)
@pa_container_size("ingress", "meta.mon2.e", 32)
@pa_container_size("ingress", "meta.mon2.acc", 32)
@pa_container_size("ingress", "meta.mon2.band32", 32)
@pa_container_size("ingress", "meta.mon2.accb", 32)
@pa_container_size("ingress", "meta.mon2.oldb", 32)
@pa_container_size("ingress", "meta.mon2.bdiff", 32)
@pa_container_size("ingress", "meta.mon2.z", 32)
@pa_container_size("ingress", "meta.mon2.old", 32)
@pa_container_size("ingress", "meta.mon2.d", 32)
@pa_container_size("ingress", "meta.mon2.a1", 32)
@pa_container_size("ingress", "meta.mon2.t1", 32)
@pa_container_size("ingress", "meta.mon2.w1a", 32)
@pa_container_size("ingress", "meta.mon2.ns0", 32)
@pa_container_size("ingress", "meta.mon2.ndelta", 32)
@pa_container_size("ingress", "meta.mon2.z2", 32)
@pa_container_size("ingress", "meta.mon2.slope_key", 32)
@pa_container_size("ingress", "meta.mon3.x16", 32)
@pa_container_size("ingress", "meta.mon3.e", 32)
@pa_container_size("ingress", "meta.mon3.acc", 32)
@pa_container_size("ingress", "meta.mon3.band32", 32)
@pa_container_size("ingress", "meta.mon3.accb", 32)
@pa_container_size("ingress", "meta.mon3.oldb", 32)
@pa_container_size("ingress", "meta.mon3.bdiff", 32)
@pa_container_size("ingress", "meta.mon3.z", 32)
@pa_container_size("ingress", "meta.mon3.old", 32)
@pa_container_size("ingress", "meta.mon3.d", 32)
@pa_container_size("ingress", "meta.mon3.a1", 32)
@pa_container_size("ingress", "meta.mon3.t1", 32)
@pa_container_size("ingress", "meta.mon3.w1a", 32)
@pa_container_size("ingress", "meta.mon3.ns0", 32)
@pa_container_size("ingress", "meta.mon3.ndelta", 32)
@pa_container_size("ingress", "meta.mon3.z2", 32)
@pa_container_size("ingress", "meta.mon3.slope_key", 32)
@pa_solitary("ingress", "meta.monitored")
@pa_solitary("ingress", "meta.in_prefix")
@pa_solitary("ingress", "meta.gap")
@pa_solitary("ingress", "meta.mon2.q")
@pa_solitary("ingress", "meta.mon2.q_cmd")
@pa_solitary("ingress", "meta.mon3.q")
@pa_solitary("ingress", "meta.mon3.q_cmd")
@pa_solitary("ingress", "meta.mon2.enabled")
@pa_solitary("ingress", "meta.mon3.enabled")
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
    CommandSteps() command_steps;
    CommandStepsAbs() command_steps_abs;

    // Balance slots (include/balance/balance.p4, include/config.p4): W, R, and
    // which flow term is keyed on message fields only (it runs first, in
    // stage 0). The operands are bound below: x, head0, cmd0, head1, cmd1.
    BalanceMonitor(BAL_WINDOW, BAL_RING_LEN, true,
                   TNA_FLOW_PIPE23_SIZE, TNA_FLOW_V2_SIZE) mon2;
    BalanceMonitor(BAL_WINDOW, BAL_RING_LEN, false,
                   TNA_FLOW_P1_SIZE, TNA_FLOW_V1_SIZE) mon3;

    // the head differences of the flow terms (16-bit modular, pipeline.md 3b)
    CIVIC_STEP(heads,
               meta.head23 = hdr.plant.l2 - hdr.plant.l3;
               meta.head12 = hdr.plant.l1 - hdr.plant.l2;)

    apply {
        forwarding.apply(ig_intr_md.ingress_port, ig_tm_md, ig_dprsr_md);
        plant_lookup.apply(hdr, meta);
        if (hdr.plant.isValid() && meta.monitored == 1 && meta.in_prefix == 1) {
            seq_gap.apply(hdr, meta);
            command_steps.apply(hdr, meta);
        }
        command_steps_abs.apply(hdr, meta);
        heads.apply();
        // balance_t3: x = l3; flow0 pipe23 (l2 - l3, zero); flow1 V2 (l3, v2)
        mon2.apply(hdr.plant, meta.monitored, meta.in_prefix, meta.slot, meta.gap,
                   meta.dp1, meta.dv1, meta.dv2,
                   hdr.plant.l3, meta.head23, meta.zero, hdr.plant.l3, hdr.plant.v2,
                   meta.mon2, hdr.bridge.cls0);
        // balance_t1: x = l1; flow0 P1 (zero, p1); flow1 V1 (l1 - l2, v1)
        mon3.apply(hdr.plant, meta.monitored, meta.in_prefix, meta.slot, meta.gap,
                   meta.dp1, meta.dv1, meta.dv2,
                   hdr.plant.l1, meta.zero, hdr.plant.p1, meta.head12, hdr.plant.v1,
                   meta.mon3, hdr.bridge.cls1);
        if (meta.mon2.chg != 0 || meta.mon3.chg != 0) {
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
