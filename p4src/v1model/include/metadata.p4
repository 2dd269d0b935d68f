/*
 * CIVIC v1model -- header and metadata structs.
 */
#ifndef _CIVIC_V1MODEL_METADATA_P4_
#define _CIVIC_V1MODEL_METADATA_P4_

#include "../../shared/headers.p4"

struct headers_t {
    ethernet_t  ethernet;
    ipv4_t      ipv4;
    udp_t       udp;
    plant_msg_t plant;      // valid only for a complete 20-byte payload
}

// Working state of one monitor slot for the packet being processed.
// Nothing here persists between packets: the persistent state is in the
// registers of control/monitor.p4.
struct monitor_md_t {
    // set_config(...) of the slot's keyless config table
    bit<1>  enabled;
    bit<2>  signal;         // SIGNAL_L1..SIGNAL_L4
    bit<8>  window;         // W
    bit<8>  ring_len;       // R = W (lsq) or W - 1 (endpoint)
    bit<2>  estimator;      // ESTIMATOR_ENDPOINT, _LSQ, _VALUE
    bit<1>  balance;        // 1: balance monitor (pipeline.md 3b)
    bit<8>  hold_min;       // H: a class is written once held this many messages
    bit<2>  aux_plus;       // SIGNAL_L1..L4: aux = max(x[aux_plus] - x[aux_minus], 0)
    bit<2>  aux_minus;
    bit<3>  f0_plus;        // OPERAND_*: flow term 0 keys head = f[plus] - f[minus], cmd = f[cmd]
    bit<3>  f0_minus;
    bit<3>  f0_cmd;
    bit<3>  f1_plus;        // flow term 1
    bit<3>  f1_minus;
    bit<3>  f1_cmd;
    // per message
    bit<16> x;              // the monitored signal
    bit<16> head0;          // flow term keys and results (balance monitors)
    bit<16> cmd0;
    bit<16> head1;
    bit<16> cmd1;
    bit<32> flow0;
    bit<32> flow1;
    bit<16> band0;
    bit<16> band1;
    bit<32> acc;            // accumulated expected inflow after this message
    bit<32> accb;           // accumulated band after this message
    bit<32> oldb;           // accb R messages ago (the ringb cell overwritten)
    bit<32> z;              // what the ring gets: x, or (x << 4) - acc
    bit<16> aux_a;          // x[aux_plus], x[aux_minus]
    bit<16> aux_b;
    bit<16> aux;            // compensate table key
    bit<32> offset;         // compensate table result (signed), 0 on a miss
    bit<1>  q;              // precondition holds
    bit<8>  run;            // run counter after this message
    bit<8>  ptr;            // ring pointer before this message
    bit<32> ring_idx;       // slot * MAX_WINDOW + ptr
    bit<32> old;            // ring cell overwritten by z
    bit<32> s0;             // running sums after this message
    bit<32> s1;
    bit<32> slope;          // signed 32-bit estimator value
    bit<32> slope_key;      // (slope - offset) XOR SLOPE_BIAS (class table key)
    bit<16> level;          // = x (reported in the digest)
    bit<16> key2;           // class table's second key: x, or the balance band
    bit<2>  c_raw;          // class table result (0 where not evaluated)
    bit<2>  cand;           // hold registers after this message
    bit<8>  hold;
    bit<2>  cls;            // verdict bits of this monitor
    bit<2>  prev;           // last_class[slot] before this message (when cls != 0)
    bit<1>  changed;        // cls != 0 and cls != prev: a verdict change
}

struct local_metadata_t {
    bit<1>       monitored;  // monitored_port hit
    bit<1>       plant;      // monitored_port hit and plant_prefix hit
    bit<32>      slot;       // ipv4.src_addr[7:0], register index
    bit<32>      last_seq;   // last_seq[slot] before this message
    bit<1>       gap;        // seq != last_seq + 1 (modular)
    bit<16>      dp1;        // command steps since the plant's previous message
    bit<16>      dv1;
    bit<16>      dv2;
    monitor_md_t mon0;
    monitor_md_t mon1;
    monitor_md_t mon2;
    monitor_md_t mon3;
}

#endif  /* _CIVIC_V1MODEL_METADATA_P4_ */
