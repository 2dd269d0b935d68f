/*
 * CIVIC -- named constants shared by the v1model and TNA programs.
 *
 * docs/pipeline.md is the normative contract; every number here is taken
 * from it (or from docs/wire-format.md) and tests/p4/test_p4_source.py
 * checks the ones that civic/wire.py and civic/switch/schema.py also define.
 */
#ifndef _CIVIC_DEFINE_P4_
#define _CIVIC_DEFINE_P4_

/* ---------------------------------------------------------------- framing */
// pipeline.md section 1.1: Ethernet II, IPv4, no VLAN tag.
#define ETHERTYPE_IPV4 0x0800
// section 1.2: IPv4 version 4, IHL 5 (20 bytes, no options), UDP.
#define IPV4_VERSION 4
#define IPV4_IHL_NO_OPTIONS 5
#define IP_PROTO_UDP 17
// section 1.4: UDP length field = 8-byte UDP header + 20-byte payload.
// Any other length is not a plant message (the payload is not parsed).
#define PLANT_PAYLOAD_LEN 20
#define UDP_LEN_PLANT 28
// Default monitored destination port (configs/monitors.toml udp_port).
// Not used by the data plane: the control plane installs the port(s) in
// the monitored_port table. Kept here so the default is written down once.
#define DEFAULT_UDP_PORT 50000

/* ---------------------------------------------------------------- state */
// section 1.5: the plant's slot is the last octet of its IPv4 source.
#define MAX_PLANTS 256
// section 2: window W <= 128, so one plant's ring needs at most 128 cells.
// The ring register is MAX_PLANTS * MAX_WINDOW cells; the cell of (slot,
// ptr) is slot * MAX_WINDOW + ptr. MAX_WINDOW is a power of two so that
// the index is slot ++ ptr[6:0] and a stale pointer can never reach into
// the next plant's cells (see v1model/include/control/monitor.p4).
#define MAX_WINDOW 128
#define MAX_WINDOW_LOG2 7
#define RING_CELLS 32768          // MAX_PLANTS * MAX_WINDOW
// section 3: run saturates at 255 (8-bit register).
#define RUN_MAX 255

/* ---------------------------------------------------------------- monitors */
// The verdict word (16 bit) has room for 8 monitors (2 bits each). The
// v1model program instantiates 4 monitor slots (mon0..mon3); the TNA
// program 2 (see p4src/tna/include/config.p4).
#define VERDICT_MONITORS 8
#define MAX_MONITORS 4
// Signal codes of set_config(signal): the monitored field.
#define SIGNAL_L1 0
#define SIGNAL_L2 1
#define SIGNAL_L3 2
#define SIGNAL_L4 3
// Estimator codes of set_config(estimator) (pipeline.md section 3).
#define ESTIMATOR_ENDPOINT 0
#define ESTIMATOR_LSQ 1
#define ESTIMATOR_VALUE 2
// Operand codes of a balance monitor's flow terms (pipeline.md 3b):
// l1..l4, the commands p1, v1, v2, and the constant 0.
#define OPERAND_L1 0
#define OPERAND_L2 1
#define OPERAND_L3 2
#define OPERAND_L4 3
#define OPERAND_P1 4
#define OPERAND_V1 5
#define OPERAND_V2 6
#define OPERAND_ZERO 7
// Balance monitors push (x << BALANCE_SHIFT) - acc: 1/64 mL.
#define BALANCE_SHIFT 6
// The class table's band key is the window's band sum >> BAND_SUM_SHIFT.
#define BAND_SUM_SHIFT 7
// hold saturates at 255 (8-bit register).
#define HOLD_MAX 255

/* ---------------------------------------------------------------- classes */
// section 4 / wire-format.md "Verdict field".
#define CLASS_NOT_EVALUATED 0
#define CLASS_NORMAL 1
#define CLASS_WARNING 2
#define CLASS_ERROR 3
// A miss in a class table gives the monitor's default_class; until the
// control plane sets it, the default is error (pipeline.md section 4).
#define CLASS_DEFAULT CLASS_ERROR

// section 4: slope_key = slope XOR 0x80000000 maps the signed 32-bit slope
// onto an order-preserving unsigned key, so that one range match on an
// unsigned key covers signed slope intervals.
#define SLOPE_BIAS 0x80000000

/* ---------------------------------------------------------------- table sizes */
#define FORWARD_TABLE_SIZE 64
#define MONITORED_PORT_TABLE_SIZE 16
#define PLANT_PREFIX_TABLE_SIZE 16
#define PRECONDITION_TABLE_SIZE 64
#define CLASSIFY_TABLE_SIZE 1024
#define COMPENSATE_TABLE_SIZE 256
// A balance monitor's flow term: a 2-D range table on (head, command),
// e.g. V2's outflow over L3 x V2 within +-3 % per cell (civic train).
#define FLOW_TABLE_SIZE 8192

/* ---------------------------------------------------------------- verdict changes */
// pipeline.md section 7: per monitor, a packet counter per (slot, class),
// cell slot * 4 + class (class 1..3; cell slot * 4 is never counted).
#define VERDICT_COUNTER_CELLS 1024   // MAX_PLANTS * 4
// Digest receiver id (v1model digest(receiver, data)).
#define VERDICT_DIGEST_RECEIVER 1

#endif  /* _CIVIC_DEFINE_P4_ */
