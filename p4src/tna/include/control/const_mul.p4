/*
 * CIVIC TNA -- p = v * C for a compile-time constant C, in shift-and-add.
 *
 * Tofino multiplies only by powers of two (shifts). C is given as up to
 * four signed power-of-two terms (include/config.p4):
 *     C = t0 (+|-) t1 (+|-) t2 (+|-) t3,  ti = 2^ai if bit i of `used` is set
 * Every operation below is one ALU instruction and the additions form a
 * tree of depth 2, so the product costs 3 dependent stages (shift, add,
 * add). The conditions are on constructor parameters: after inlining they
 * are constants and the compiler removes the branches not taken.
 * All arithmetic is modular in bit<32>, as pipeline.md requires.
 */
#ifndef _CIVIC_TNA_CONST_MUL_P4_
#define _CIVIC_TNA_CONST_MUL_P4_

control ConstMul(in bit<32> v, out bit<32> p)
                (bit<8> a0, bit<8> a1, bit<8> a2, bit<8> a3, bit<4> used, bit<4> negs) {
    bit<32> t0;
    bit<32> t1;
    bit<32> t2;
    bit<32> t3;
    bit<32> u;
    bit<32> w;

    apply {
        t0 = 0;
        t1 = 0;
        t2 = 0;
        t3 = 0;
        if ((used & 1) != 0) {
            t0 = v << a0;
        }
        if ((used & 2) != 0) {
            t1 = v << a1;
        }
        if ((used & 4) != 0) {
            t2 = v << a2;
        }
        if ((used & 8) != 0) {
            t3 = v << a3;
        }
        // u = t0 +- t1
        if ((negs & 2) != 0) {
            u = t0 - t1;
        } else {
            u = t0 + t1;
        }
        // p = u +- t2 +- t3, as u + w or u - w
        if ((negs & 12) == 0) {
            w = t2 + t3;
            p = u + w;
        } else if ((negs & 12) == 12) {
            w = t2 + t3;
            p = u - w;
        } else if ((negs & 4) != 0) {
            w = t3 - t2;
            p = u + w;
        } else {
            w = t2 - t3;
            p = u + w;
        }
    }
}

#endif  /* _CIVIC_TNA_CONST_MUL_P4_ */
