/*
 * CIVIC TNA -- one-operation steps and p = v * C for a compile-time
 * constant C in shift-and-add.
 *
 * Why steps: bf-p4c's midend propagates every assignment of the apply block
 * into the next use (LocalCopyPropagation, also for metadata fields), so
 * `u = t0 + t1; p = u + w;` written as statements reaches the backend as
 * one action `p = (t0 + t1) + w`, which needs two ALU passes and fails
 * with "action spanning multiple stages". An action of a table is not
 * propagated into, so every dependent step here is its own keyless
 * @hidden table with one const default action: the dependency between
 * tables is what gives each step its own stage. @hidden tables and their
 * actions are not in the P4Info / BF-RT JSON (tests/p4/test_tna_compile.py
 * checks bfrt.json), so the control-plane names stay those of v1model.
 *
 * CIVIC_STEP(NAME, body...) declares table NAME running NAME_do() { body }.
 *
 * Tofino multiplies only by powers of two (shifts). C is given as up to
 * four signed power-of-two terms (include/config.p4):
 *     C = t0 (+|-) t1 (+|-) t2 (+|-) t3,  ti = 2^ai if bit i of `used` is set
 * with `used` one of 1, 3, 7, 15 (terms in order) and term 0 positive.
 * CIVIC_CONST_MUL(P, IN, OUT, a0, a1, a2, a3, used, negs) declares the
 * steps of OUT = IN * C inside Monitor (temporaries m.t0 .. m.t3 of
 * monitor_md_t, shared by the slot's two products, which run in different
 * stages); CIVIC_CONST_MUL_APPLY(P, used) applies them:
 *   1 term:   OUT = IN << a0                                      1 stage
 *   2 terms:  shifts;  OUT = t0 +- t1                             2 stages
 *   3 terms:  shifts;  t0 = t0 +- t1;  OUT = t0 +- t2             3 stages
 *   4 terms:  shifts;  t0 = t0 +- t1, t2 = t2 +- t3 (or t3 - t2); OUT = t0 +- t2
 *                                                                 3 stages
 * All arithmetic is modular in bit<32>, as pipeline.md requires.
 * The conditions are on constructor parameters of Monitor: after inlining
 * they are constants and the compiler removes the branches not taken.
 */
#ifndef _CIVIC_TNA_CONST_MUL_P4_
#define _CIVIC_TNA_CONST_MUL_P4_

#define CIVIC_STEP(NAME, ...)                                               \
    @hidden action NAME##_do() { __VA_ARGS__ }                              \
    @hidden table NAME {                                                    \
        actions = { NAME##_do; }                                            \
        const default_action = NAME##_do();                                 \
        size = 1;                                                           \
    }

// CIVIC_SELECT4(NAME, KEY, body0, body1, body2, body3) declares table NAME
// keyed on KEY (exact) with const entries 0..3 running NAME_0() { body0 }
// .. NAME_3() { body3 }: one table instead of a chain of four gateways.
#define CIVIC_SELECT4(NAME, KEY, B0, B1, B2, B3)                            \
    @hidden action NAME##_0() { B0 }                                        \
    @hidden action NAME##_1() { B1 }                                        \
    @hidden action NAME##_2() { B2 }                                        \
    @hidden action NAME##_3() { B3 }                                        \
    @hidden table NAME {                                                    \
        key = { KEY: exact; }                                               \
        actions = { NAME##_0; NAME##_1; NAME##_2; NAME##_3; }               \
        const entries = {                                                   \
            0: NAME##_0();                                                  \
            1: NAME##_1();                                                  \
            2: NAME##_2();                                                  \
            3: NAME##_3();                                                  \
        }                                                                   \
        size = 4;                                                           \
    }

#define CIVIC_CONST_MUL(P, IN, OUT, A0, A1, A2, A3, USED, NEGS)             \
    CIVIC_STEP(P##_one, OUT = IN << A0;)                                    \
    CIVIC_STEP(P##_shift,                                                   \
        m.t0 = IN << A0;                                                    \
        m.t1 = IN << A1;                                                    \
        if (((USED) & 4) != 0) { m.t2 = IN << A2; }                         \
        if (((USED) & 8) != 0) { m.t3 = IN << A3; })                        \
    CIVIC_STEP(P##_two,                                                     \
        if (((NEGS) & 2) != 0) { OUT = m.t0 - m.t1; }                       \
        else { OUT = m.t0 + m.t1; })                                        \
    CIVIC_STEP(P##_add,                                                     \
        if (((NEGS) & 2) != 0) { m.t0 = m.t0 - m.t1; }                      \
        else { m.t0 = m.t0 + m.t1; }                                        \
        if (((USED) & 8) != 0) {                                            \
            if (((NEGS) & 12) == 4) { m.t2 = m.t3 - m.t2; }                 \
            else if (((NEGS) & 12) == 8) { m.t2 = m.t2 - m.t3; }            \
            else { m.t2 = m.t2 + m.t3; }                                    \
        })                                                                  \
    CIVIC_STEP(P##_sum3,                                                    \
        if (((NEGS) & 4) != 0) { OUT = m.t0 - m.t2; }                       \
        else { OUT = m.t0 + m.t2; })                                        \
    CIVIC_STEP(P##_sum4,                                                    \
        if (((NEGS) & 12) == 12) { OUT = m.t0 - m.t2; }                     \
        else { OUT = m.t0 + m.t2; })

#define CIVIC_CONST_MUL_APPLY(P, USED)                                      \
    if ((USED) == 1) {                                                      \
        P##_one.apply();                                                    \
    } else {                                                                \
        P##_shift.apply();                                                  \
        if ((USED) == 3) {                                                  \
            P##_two.apply();                                                \
        } else {                                                            \
            P##_add.apply();                                                \
            if ((USED) == 7) {                                              \
                P##_sum3.apply();                                           \
            } else {                                                        \
                P##_sum4.apply();                                           \
            }                                                               \
        }                                                                   \
    }

#endif  /* _CIVIC_TNA_CONST_MUL_P4_ */
