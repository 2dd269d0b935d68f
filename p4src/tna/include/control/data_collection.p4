/*
 * CIVIC TNA -- per-plant history of one monitor slot (pipeline.md
 * sections 2 and 3; see the v1model data_collection.p4 for the semantics).
 *
 * Tofino rules shape this file:
 *  - a register is accessed once per packet, by one RegisterAction that
 *    reads, modifies and writes it in the stateful ALU; so every register
 *    update is a single RegisterAction (run has three, for the three
 *    mutually exclusive cases, of which one executes);
 *  - R is a compile-time constant (constructor parameter ring_len, from
 *    include/config.p4), and R * old is a shift-and-add (const_mul.p4).
 *
 * Registers (P4Info CivicIngress.monK.<name>):
 *   ring  bit<32> x MAX_PLANTS * MAX_WINDOW  (32 bit on TNA, values < 2^16:
 *         the RegisterAction returns it straight into 32-bit arithmetic)
 *   ptr   bit<8>, run bit<8>, s0 bit<32>, s1 bit<32>  x MAX_PLANTS
 * Ring cell of (slot, ptr) = slot ++ ptr[6:0] = slot * 128 + ptr, formed by
 * an identity hash of the two fields.
 *
 * Dependent steps (stage plan in p4src/README.md):
 *   ptr  -> ring (old) -> d, R*old (3 stages) -> s0 -> t -> s1
 */
#ifndef _CIVIC_TNA_DATA_COLLECTION_P4_
#define _CIVIC_TNA_DATA_COLLECTION_P4_

control DataCollection(in bit<8> slot, in bit<1> gap, inout monitor_md_t m)
                      (bit<8> ring_len,
                       bit<8> r_a0, bit<8> r_a1, bit<8> r_a2, bit<8> r_a3,
                       bit<4> r_used, bit<4> r_negs) {

    Register<bit<32>, bit<15>>(RING_CELLS, 0) ring;
    Register<bit<8>, bit<8>>(MAX_PLANTS, 0) ptr;
    Register<bit<8>, bit<8>>(MAX_PLANTS, 0) run;
    Register<bit<32>, bit<8>>(MAX_PLANTS, 0) s0;
    Register<bit<32>, bit<8>>(MAX_PLANTS, 0) s1;

    Hash<bit<15>>(HashAlgorithm_t.IDENTITY) ring_index;
    ConstMul(r_a0, r_a1, r_a2, r_a3, r_used, r_negs) r_mul;

    // run = 0 (precondition fails)
    RegisterAction<bit<8>, bit<8>, bit<8>>(run) run_clear = {
        void apply(inout bit<8> value, out bit<8> rv) {
            value = 0;
            rv = 0;
        }
    };
    // run = 1 (qualifies after a sequence gap)
    RegisterAction<bit<8>, bit<8>, bit<8>>(run) run_restart = {
        void apply(inout bit<8> value, out bit<8> rv) {
            value = 1;
            rv = 1;
        }
    };
    // run = min(run + 1, 255)
    RegisterAction<bit<8>, bit<8>, bit<8>>(run) run_count = {
        void apply(inout bit<8> value, out bit<8> rv) {
            if (value != RUN_MAX) {
                value = value + 1;
            }
            rv = value;
        }
    };

    // return ptr, then ptr = (ptr + 1 == R) ? 0 : ptr + 1
    RegisterAction<bit<8>, bit<8>, bit<8>>(ptr) ptr_advance = {
        void apply(inout bit<8> value, out bit<8> rv) {
            rv = value;
            if (value == ring_len - 1) {
                value = 0;
            } else {
                value = value + 1;
            }
        }
    };

    // old = ring[ptr]; ring[ptr] = x
    RegisterAction<bit<32>, bit<15>, bit<32>>(ring) ring_swap = {
        void apply(inout bit<32> value, out bit<32> rv) {
            rv = value;
            value = m.x32;
        }
    };

    // return s0 before the update; s0 = s0 + (x - old)
    RegisterAction<bit<32>, bit<8>, bit<32>>(s0) s0_add = {
        void apply(inout bit<32> value, out bit<32> rv) {
            rv = value;
            value = value + m.d;
        }
    };

    // s1 = s1 + (s0 - R * old); return s1 after the update
    RegisterAction<bit<32>, bit<8>, bit<32>>(s1) s1_add = {
        void apply(inout bit<32> value, out bit<32> rv) {
            value = value + m.t;
            rv = value;
        }
    };

    apply {
        if (m.q == 0) {
            m.run = run_clear.execute(slot);
        } else if (gap == 1) {
            m.run = run_restart.execute(slot);
        } else {
            m.run = run_count.execute(slot);
        }

        m.ptr = ptr_advance.execute(slot);
        m.old = ring_swap.execute(ring_index.get({slot, m.ptr[6:0]}));

        m.d = m.x32 - m.old;
        m.d_b = m.x32_b - m.old;
        r_mul.apply(m.old, m.r_old);

        m.s0 = s0_add.execute(slot);
        m.t = m.s0 - m.r_old;
        m.s1 = s1_add.execute(slot);
    }
}

#endif  /* _CIVIC_TNA_DATA_COLLECTION_P4_ */
