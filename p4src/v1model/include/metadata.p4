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
    bit<1>  lsq;            // 1: lsq estimator, 0: endpoint estimator
    bit<2>  aux_plus;       // SIGNAL_L1..L4: aux = max(x[aux_plus] - x[aux_minus], 0)
    bit<2>  aux_minus;
    // per message
    bit<16> x;              // the monitored signal
    bit<16> aux_a;          // x[aux_plus], x[aux_minus]
    bit<16> aux_b;
    bit<16> aux;            // compensate table key
    bit<32> offset;         // compensate table result (signed), 0 on a miss
    bit<1>  q;              // precondition holds
    bit<8>  run;            // run counter after this message
    bit<8>  ptr;            // ring pointer before this message
    bit<32> ring_idx;       // slot * MAX_WINDOW + ptr
    bit<16> old;            // ring cell overwritten by x
    bit<32> s0;             // running sums after this message
    bit<32> s1;
    bit<32> slope;          // signed 32-bit estimator value
    bit<32> slope_key;      // (slope - offset) XOR SLOPE_BIAS (class table key)
    bit<16> level;          // = x (class table key)
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
    monitor_md_t mon0;
    monitor_md_t mon1;
    monitor_md_t mon2;
    monitor_md_t mon3;
}

#endif  /* _CIVIC_V1MODEL_METADATA_P4_ */
