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

struct ig_metadata_t {
    bit<1>       monitored;  // monitored_port hit
    bit<1>       in_prefix;  // plant_prefix hit
    bit<8>       slot;       // ipv4.src_addr[7:0]
    bit<32>      seq_m1;     // seq - 1
    bit<1>       gap;
    monitor_md_t mon0;
    monitor_md_t mon1;
}

struct eg_metadata_t {
    bridge_h    bridge;
}

#endif  /* _CIVIC_TNA_METADATA_P4_ */
