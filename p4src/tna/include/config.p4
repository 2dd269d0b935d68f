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

// Verdict changes (pipeline.md section 7): last_class holds the class, the
// digest's chgK says "changed" with this bit (so that a change from "none
// yet", 0, is not 0); ig_dprsr_md.digest_type of the verdict-change digest.
#define CHANGED 4
#define DIGEST_VERDICT_CHANGE 1

#endif  /* _CIVIC_TNA_CONFIG_P4_ */
