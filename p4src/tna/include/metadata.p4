/*
 * CIVIC TNA -- header and metadata structs.
 */
#ifndef _CIVIC_TNA_METADATA_P4_
#define _CIVIC_TNA_METADATA_P4_

#include "../../shared/headers.p4"

// Bridged from ingress to egress in front of the Ethernet header. Ingress
// writes the two class codes into their own fields; egress reads the same
// three bytes as {flags, 16-bit verdict word}, so the verdict word is
// assembled by the layout, not by an ALU:
//   verdict = 12 zero bits ++ cls1 ++ cls0
header bridge_ig_h {
    bit<7>  pad;
    bit<1>  plant;          // this frame is a plant message
    bit<12> verdict_hi;     // always 0 (slots 2..7 do not exist on TNA)
    bit<2>  cls1;
    bit<2>  cls0;
}

header bridge_eg_h {
    bit<7>  pad;
    bit<1>  plant;
    bit<16> verdict;
}

struct ig_headers_t {
    bridge_ig_h bridge;
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

// Working state of one monitor slot for the packet being processed; every
// field is written by one ALU operation (Tofino does one operation per
// field per stage), see the stage plan in p4src/README.md.
struct monitor_md_t {
    bit<1>  enabled;        // set_config
    bit<2>  signal;
    bit<8>  window;         // set_config parameters that TNA ignores
    bit<8>  ring_len;
    bit<1>  lsq;
    bit<16> x;              // the monitored signal
    bit<32> x32;            // x, zero-extended
    bit<32> x32_b;          // x + 2^31
    bit<1>  q;              // precondition holds
    bit<8>  run;            // run counter after this message
    bit<8>  ptr;            // ring pointer before this message
    bit<32> old;            // ring cell overwritten by x
    bit<32> d;              // x - old
    bit<32> d_b;            // x - old + 2^31
    bit<32> r_old;          // R * old
    bit<32> s0;             // s0 before the update
    bit<32> t;              // s0 - R * old
    bit<32> s1;             // s1 after the update
    bit<32> s0n;            // s0 after the update (+ 2^31, see slope.p4)
    bit<32> prod;           // (W - 1) * s0n
    bit<32> s1x2;           // 2 * s1
    bit<32> slope;
    bit<32> slope_key;      // slope XOR 2^31
    bit<16> level;          // = x
}

struct ig_metadata_t {
    bit<1>       monitored;  // monitored_port hit
    bit<1>       in_prefix;  // plant_prefix hit
    bit<1>       plant;      // monitored and in_prefix: a plant message
    bit<8>       slot;       // ipv4.src_addr[7:0]
    bit<32>      seq_m1;     // seq - 1
    bit<1>       gap;
    monitor_md_t mon0;
    monitor_md_t mon1;
}

struct eg_metadata_t {
    bridge_eg_h bridge;
}

#endif  /* _CIVIC_TNA_METADATA_P4_ */
