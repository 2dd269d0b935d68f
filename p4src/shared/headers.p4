/*
 * CIVIC -- packet headers (shared by v1model and TNA).
 *
 * Only what pipeline.md section 1 needs to recognise a plant message, and
 * the 20-byte plant message itself (docs/wire-format.md). Everything after
 * the last extracted header stays packet payload and leaves the switch
 * unchanged (UDP payload of other datagrams, Ethernet padding, trailers).
 */
#ifndef _CIVIC_HEADERS_P4_
#define _CIVIC_HEADERS_P4_

#include "define.p4"

typedef bit<48> mac_addr_t;
typedef bit<32> ipv4_addr_t;

header ethernet_t {
    mac_addr_t dst_addr;
    mac_addr_t src_addr;
    bit<16>    ether_type;
}

// IPv4 without options. The three flag bits are separate fields so that
// the parser can select on MF without a slice.
header ipv4_t {
    bit<4>      version;
    bit<4>      ihl;
    bit<8>      dscp_ecn;
    bit<16>     total_len;
    bit<16>     identification;
    bit<1>      flag_reserved;
    bit<1>      flag_df;
    bit<1>      flag_mf;
    bit<13>     frag_offset;
    bit<8>      ttl;
    bit<8>      protocol;
    bit<16>     hdr_checksum;
    ipv4_addr_t src_addr;
    ipv4_addr_t dst_addr;
}

header udp_t {
    bit<16> src_port;
    bit<16> dst_port;
    bit<16> len;          // UDP length field (header + payload), 28 for a plant message
    bit<16> checksum;     // 0 = not used (stays 0, pipeline.md section 5)
}

// The plant control message, wire format v1: 20 bytes, unsigned big-endian.
header plant_msg_t {
    bit<32> seq;          // +1 per message, wraps at 2^32
    bit<16> l1;           // volume T1, mL
    bit<16> l2;           // volume T2, mL
    bit<16> l3;           // volume T3, mL
    bit<16> l4;           // volume T4, mL
    bit<16> p1;           // pump P1 command, 0.1 %
    bit<16> v1;           // valve V1 command, 0.1 %
    bit<16> v2;           // valve V2 command, 0.1 %
    bit<16> verdict;      // written by the switch: 2 bits per monitor
}

// One digest per plant message on which any monitor's verdict changes
// (pipeline.md section 7): bit k of `changed` says monitor k changed; its
// previous and new class are bits 2k+1..2k of `prev` and `cls`, its raw
// slope and level are slopeK and levelK. BMv2 sends at most one digest per
// packet, so all monitors share one.
struct verdict_change_t {
    bit<32> plant;          // ipv4.src_addr
    bit<32> seq;
    bit<8>  changed;
    bit<8>  prev;
    bit<8>  cls;
    bit<32> slope0;
    bit<16> level0;
    bit<32> slope1;
    bit<16> level1;
    bit<32> slope2;
    bit<16> level2;
    bit<32> slope3;
    bit<16> level3;
}

#endif  /* _CIVIC_HEADERS_P4_ */
