/*
 * CIVIC TNA -- compile-time configuration of the monitor slots.
 *
 * Tofino has no run-time multiplier: the MAU ALUs add, subtract, shift and
 * do logic, nothing else. The two products of docs/pipeline.md section 3,
 * R * old (s1 update) and (W - 1) * s0 (lsq slope), are therefore
 * shift-and-add sums of a compile-time constant (const_mul.p4), and each
 * monitor slot's window W, ring length R and estimator are fixed here.
 * Changing a window means editing this file and recompiling.
 *
 * The control plane still sets CivicIngress.monK.config's default action
 * set_config(enabled, signal, window, ring_len, lsq, aux_plus, aux_minus) as
 * on v1model, but on TNA window, ring_len and lsq are not used; they must
 * equal the constants below (civic configure should check this) and are
 * otherwise ignored.
 *
 * A product v * C is given as up to four signed power-of-two terms:
 *     MONk_x_MUL  a0, a1, a2, a3, used, negs
 *     C = sum over i with bit i of `used` set of (-1 if bit i of `negs`) * 2^ai
 * term 0 must be positive. Four terms cover every C <= 128 (canonical signed
 * digit form). tests/p4/test_p4_source.py checks that each sum equals its
 * constant and that R = W (lsq) or W - 1 (endpoint);
 * tests/p4/test_tna_compile.py checks MONk_S0_BIAS.
 *
 * MONk_S0_BIAS = 2^(31 - k), 2^k the largest power of two dividing W - 1
 * (lsq): the slope key's bias 2^31 rides through the product,
 * (W - 1) * (s0' + MONk_S0_BIAS) = (W - 1) * s0' + 2^31 (mod 2^32); for an
 * endpoint slot it is 2^31 itself. It is also the compensate table's
 * default (offset 0).
 *
 * Defaults: the two monitors of configs/monitors.toml with the lsq
 * estimator (civic train's default).
 */
#ifndef _CIVIC_TNA_CONFIG_P4_
#define _CIVIC_TNA_CONFIG_P4_

// Two monitor slots (verdict bits 3..0); bridged to egress as cls1, cls0.
#define TNA_MONITORS 2

// mon0: drain_t3, lsq, W = 20, R = W = 20
#define MON0_WINDOW 20
#define MON0_RING_LEN 20
#define MON0_LSQ 1
// R = 20 = 2^4 + 2^2
#define MON0_R_MUL 4, 2, 0, 0, 0x3, 0x0
// W - 1 = 19 = 2^4 + 2^1 + 2^0
#define MON0_W1_MUL 4, 1, 0, 0, 0x7, 0x0
// 2^(31 - k) with 2^k the largest power of two dividing W - 1, so that
// (W - 1) * MON0_S0_BIAS = 2^31 (mod 2^32): W - 1 = 19 is odd, k = 0
#define MON0_S0_BIAS 0x80000000

// mon1: fill_t1, lsq, W = 90, R = W = 90
#define MON1_WINDOW 90
#define MON1_RING_LEN 90
#define MON1_LSQ 1
// R = 90 = 2^6 + 2^4 + 2^3 + 2^1
#define MON1_R_MUL 6, 4, 3, 1, 0xF, 0x0
// W - 1 = 89 = 2^6 + 2^4 + 2^3 + 2^0
#define MON1_W1_MUL 6, 4, 3, 0, 0xF, 0x0
// W - 1 = 89 is odd: k = 0
#define MON1_S0_BIAS 0x80000000

// Range tables are TCAM with range expansion on Tofino: keep the class
// tables smaller than on v1model (a trained class table has tens of rows).
#define TNA_PRECONDITION_TABLE_SIZE 64
#define TNA_CLASSIFY_TABLE_SIZE 256
// compensate: civic train writes about 70 ranges (16-bit key aux). bf-p4c
// reserves TCAM rows for 25 % of a range table's entries at 2 * 4 - 1 = 7
// rows (4-bit DirtCAM per nibble) and 1 row for the rest: 128 entries = 320
// rows, one 512-row TCAM block per slot (256 would take two). v1model:
// COMPENSATE_TABLE_SIZE 256 (shared/define.p4).
#define TNA_COMPENSATE_TABLE_SIZE 128

// ------------------------------------------------------------ balance profile
// p4src/tna/civic_balance.p4 defines CIVIC_PROFILE_BALANCE: its two slots
// are the always-on balance monitors of configs/monitors.toml,
// balance_t3 (monitor 2, verdict bits 5..4) and balance_t1 (monitor 3, bits
// 7..6), instead of drain_t3 and fill_t1 (monitors 0 and 1, whose verdict
// bits stay 0 in this profile). Each profile alone uses all 12 stages
// (p4src/README.md, "The balance profile").
// What TNA fixes at compile time for a balance slot (include/balance/balance.p4):
//  - the window W = R (lsq; the ring holds z = (x << BALANCE_SHIFT) - acc),
//    configs/monitors.toml's balance window (tests/p4/test_tna_compile.py
//    checks that they agree);
//  - the signal and the flow terms' operands (pipeline.md 3b), those of
//    configs/monitors.toml:
//      mon2 balance_t3: x = l3; flow0 = pipe23 (head l2 - l3, cmd zero),
//                       flow1 = V2 (head l3 - zero, cmd v2)
//      mon3 balance_t1: x = l1; flow0 = P1 (head zero - zero, cmd p1),
//                       flow1 = V1 (head l1 - l2, cmd v1)
//    (the band comes from whichever term's entries carry it: band = band0 +
//    band1 as on v1model);
//  (the hold H is set_config's hold_min at run time, 2..255; the entries'
//  window must equal BAL_WINDOW).
#ifdef CIVIC_PROFILE_BALANCE
#define BAL_WINDOW 80
#define BAL_RING_LEN 80
// The lsq slope is carried in a register of its own (include/balance/balance.p4):
//   slope' = slope + (W - 1) * (z + old) + 2 * (old - s0)      (R = W)
// (W - 1) * v takes two steps, one stage each, of the form "(u << a) +- w":
// the shifted operand comes from an identity hash (a Tofino ALU operation
// takes one operand from the PHV, the other from the action data bus):
//   t1 = (v << BAL_W1_A) + BAL_W1_S1 * v
//   t2 = (X << BAL_W1_B) + BAL_W1_S2 * Y,  (X, Y) = (t1, t1) for FORM 0,
//        (t1, v) for FORM 1, (v, t1) for FORM 2
// so W - 1 is (2^A +- 1)(2^B +- 1), (2^A +- 1) 2^B +- 1 or 2^B +- (2^A +- 1).
// W = 80: W - 1 = 79 = (2^2 + 1) 2^4 - 1   (W = 100: 99 = (2^1 + 1)(2^5 + 1),
// A 1, S1 1, FORM 0, B 5, S2 1)
#define BAL_W1_A 2
#define BAL_W1_S1 1
#define BAL_W1_FORM 1
#define BAL_W1_B 4
#define BAL_W1_S2 -1
// the class table's second key is the window's band sum >> 7 (pipeline.md 3b,
// civic/entries.py BAND_SUM_SHIFT; shared/define.p4's BAND_SUM_SHIFT when
// it defines one)
#ifdef BAND_SUM_SHIFT
#define TNA_BAND_SUM_SHIFT BAND_SUM_SHIFT
#else
#define TNA_BAND_SUM_SHIFT 7
#endif
#endif

// Flow terms (pipeline.md 3b) are range x range tables in TCAM: each (head,
// cmd) rectangle expands to (words of the head range) x (words of the cmd
// range) TCAM words (p4src/README.md, "The balance profile"). The term on
// message fields runs in stage 0, the one on a head difference in stage 1:
// their sizes fill those stages' 24 TCAM blocks next to plant_prefix and
// the level preconditions (bf-p4c reserves about 2.5 words per entry):
//   stage 0: V2 (mon2.flow1) 1200 -> 12 blocks, P1 (mon3.flow0) 128 -> 3
//   stage 1: V1 (mon3.flow1) 2048 -> 20 blocks, pipe23 (mon2.flow0) 192 -> 3
// v1model: FLOW_TABLE_SIZE 8192 per term.
#define TNA_FLOW_PIPE23_SIZE 192
#define TNA_FLOW_V2_SIZE 1200
#define TNA_FLOW_P1_SIZE 128
#define TNA_FLOW_V1_SIZE 2048

// Verdict changes (pipeline.md section 7): last_class holds the class, the
// digest's chgK says "changed" with this bit (so that a change from "none
// yet", 0, is not 0); ig_dprsr_md.digest_type of the verdict-change digest.
#define CHANGED 4
#define DIGEST_VERDICT_CHANGE 1

#endif  /* _CIVIC_TNA_CONFIG_P4_ */
