/*
 * CIVIC TNA -- header and metadata structs.
 */
#ifndef _CIVIC_TNA_METADATA_P4_
#define _CIVIC_TNA_METADATA_P4_

#include "../../shared/headers.p4"

// Bridged from ingress to egress in front of the Ethernet header. Each
// slot's class code has a byte of its own: two tables may not write one
// PHV container in the same stage, and the two slots' classify tables run
// in the same stage. Egress assembles the verdict word 12 zero bits ++ cls1
// ++ cls0 from them (verdict.p4).
header bridge_h {
    bit<7>  pad;
    bit<1>  plant;          // this frame is a plant message
    bit<6>  pad1;
    bit<2>  cls1;
    bit<6>  pad0;
    bit<2>  cls0;
}

struct ig_headers_t {
    bridge_h    bridge;
    ethernet_t  ethernet;
    ipv4_t      ipv4;
    udp_t       udp;
    plant_msg_t plant;
}

struct eg_headers_t {
    ethernet_t  ethernet;
    ipv4_t      ipv4;
    udp_t       udp;
    plant_msg_t plant;
}

// Working state of one monitor slot for the packet being processed. Every
// field is written by one ALU operation in one stage (see the stage plan in
// tna/civic.p4). Ingress has 48 32-bit PHV containers for everything, so
// the temporaries are few and reused: t0..t3 hold the shift-and-add terms
// of R * old (stages 3-4) and later of (W - 1) * s0n (stages 6-7), acc
// their sums, and d is reused for 2 * s1 once s0n is known. Fields a
// slot's constants do not need are never written and take no PHV.
struct monitor_md_t {
    bit<1>  enabled;        // set_config
    bit<2>  signal;
    bit<8>  window;         // set_config parameters that TNA ignores
    bit<8>  ring_len;
    bit<1>  lsq;
    bit<2>  aux_plus;       // set_config: aux = max(x[aux_plus] - x[aux_minus], 0)
    bit<2>  aux_minus;
    bit<16> x;              // the monitored signal (also the class table's level)
    bit<16> aux;            // compensate table key
    bit<32> bias;           // compensate result: the key bias minus the offset (monitor.p4)
    bit<32> x32;            // x, zero-extended
    bit<1>  q;              // precondition (l1..l4) holds
    bit<1>  q_cmd;          // precondition_cmd (p1, v1, v2) holds
    bit<8>  run;            // run counter after this message
    bit<8>  ptr;            // ring pointer before this message
    bit<32> old;            // ring cell overwritten by x
    bit<32> d;              // x - old; later 2 * s1
    bit<32> e;              // d + bias (lsq; bias = B - offset / (W - 1), see monitor.p4)
    bit<32> t0;             // shift-and-add terms and partial sums (const_mul.p4)
    bit<32> t1;
    bit<32> t2;
    bit<32> t3;
    bit<32> acc;            // R * old, later (W - 1) * s0n
    bit<32> s0;             // s0 before the update
    bit<32> t;              // s0 - R * old
    bit<32> s1;             // s1 after the update
    bit<32> s0n;            // s0 after the update, + B
    bit<32> slope_key;      // (slope - offset) XOR 2^31
    bit<8>  chg;            // 0: no verdict change; else last_class before | CHANGED
}

// The verdict-change digest of the two TNA slots (pipeline.md section 7,
// p4src/README.md): chgK = 0 (no change) or CHANGED | previous class; clsK
// the new class; the compensated slope key, aux and level of each slot
// (raw slope = (key XOR 2^31) + compensate(aux), which the control plane
// knows from its entries).
struct verdict_change_tna_t {
    bit<32> plant;
    bit<32> seq;
    bit<8>  chg0;
    bit<8>  chg1;
    bit<2>  cls0;
    bit<2>  cls1;
    bit<32> key0;
    bit<16> aux0;
    bit<16> level0;
    bit<32> key1;
    bit<16> aux1;
    bit<16> level1;
}

// Working state of one balance slot (CIVIC_PROFILE_BALANCE, balance.p4).
// As in monitor_md_t, every field is written by one ALU operation in one
// stage; the 32-bit ones are pinned to 32-bit containers (civic.p4).
struct balance_md_t {
    bit<1>  enabled;        // set_config
    bit<16> hold_min;       // set_config: H
    bit<16> hold_m1;        // H - 1
    bit<1>  q;              // precondition (l1..l4) holds
    bit<1>  q_cmd;          // precondition_cmd (p1 v1 v2 dp1 dv1 dv2) holds
    bit<8>  run;            // run counter after this message
    bit<8>  ptr;            // ring pointer before this message
    bit<32> x16;            // x << BALANCE_SHIFT, zero-extended
    bit<32> e;              // flow0 + flow1: expected net inflow of this sample
    bit<16> band;           // band0 + band1
    bit<32> band32;         // band, zero-extended
    bit<32> acc;            // acc after this message (acc')
    bit<32> accb;           // accb after this message: the bands accumulated
    bit<32> oldb;           // ringb cell overwritten by accb
    bit<32> bdiff;          // accb - oldb: the last R bands summed
    bit<16> band_w;         // (bdiff >> 7) mod 2^16: the class table's second key
    bit<32> z;              // (x << BALANCE_SHIFT) - acc', what the ring gets
    bit<32> z2;             // 2 * z
    bit<32> a1;             // z + old (the ring's result)
    bit<32> old;            // ring cell overwritten by z
    bit<32> d;              // z - old
    bit<32> t1;             // first step of (W - 1) * (z + old) (config.p4)
    bit<32> w1a;            // (W - 1) * (z + old)
    bit<32> ns0;            // s0 - old (s0 before its update)
    bit<32> ndelta;         // minus the slope increment: 2 * (s0 - old) - (W - 1) * (z + old)
    bit<32> slope_key;      // slope XOR 2^31 (the slope register)
    bit<8>  w;              // the class written (0 while hold < H)
    bit<8>  chg;            // 0: no verdict change; else last_class before | CHANGED
}

// The verdict-change digest of the balance profile: as verdict_change_tna_t
// for monitors 2 and 3, with band_w (the class table's second key) in place
// of aux, and the slope key = raw slope XOR 2^31 (no compensation).
struct verdict_change_balance_t {
    bit<32> plant;
    bit<32> seq;
    bit<8>  chg2;
    bit<8>  chg3;
    bit<2>  cls2;
    bit<2>  cls3;
    bit<32> key2;
    bit<16> band2;
    bit<16> level2;
    bit<32> key3;
    bit<16> band3;
    bit<16> level3;
}

struct ig_metadata_t {
    bit<1>       monitored;  // monitored_port hit
    bit<1>       in_prefix;  // plant_prefix hit
    bit<8>       slot;       // ipv4.src_addr[7:0]
    bit<32>      seq_m1;     // seq - 1
    bit<1>       gap;
#ifdef CIVIC_PROFILE_BALANCE
    bit<16>      last_p1;    // the plant's previous commands (CommandSteps)
    bit<16>      last_v1;
    bit<16>      last_v2;
    bit<16>      up_p1;      // cmd |-| last_cmd
    bit<16>      up_v1;
    bit<16>      up_v2;
    bit<16>      dn_p1;      // last_cmd |-| cmd
    bit<16>      dn_v1;
    bit<16>      dn_v2;
    bit<16>      dp1;        // command steps |cmd - last_cmd| (pipeline.md 3)
    bit<16>      dv1;
    bit<16>      dv2;
    bit<16>      head23;     // (l2 - l3) mod 2^16: balance_t3's pipe23 head
    bit<16>      head12;     // (l1 - l2) mod 2^16: balance_t1's V1 head
    bit<16>      zero;       // the operand "zero" (0, set by the parser)
    balance_md_t mon2;
    balance_md_t mon3;
#else
    monitor_md_t mon0;
    monitor_md_t mon1;
#endif
}

struct eg_metadata_t {
    bridge_h    bridge;
}

#endif  /* _CIVIC_TNA_METADATA_P4_ */
