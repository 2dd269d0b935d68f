/*
 * CIVIC TNA -- one monitor slot (docs/pipeline.md sections 2, 3, 4, 6; see
 * the v1model monitor.p4 for the semantics and the naming rule).
 *
 * CivicIngress instantiates this control once per slot, as mon0 and mon1;
 * every control-plane object of a slot is declared here, so that it is
 * CivicIngress.monK.<object>, with the same names, keys and action
 * parameters as on v1model (config / set_config, precondition / qualify /
 * disqualify, classify / set_class, registers ring ptr run s0 s1).
 *
 * Tofino rules shape this file:
 *  - W, R and the estimator are compile-time constants (constructor
 *    parameters c_window, c_ring_len, c_lsq, from include/config.p4):
 *    Tofino has no run-time multiplier, and R * old and (W - 1) * s0 are
 *    shift-and-add sums (const_mul.p4).
 *    set_config keeps its five parameters so that the control plane is
 *    the same, but only `enabled` and `signal` are used here; window,
 *    ring_len and lsq must equal the compiled constants;
 *  - a register is accessed once per packet, by one RegisterAction that
 *    reads, modifies and writes it in the stateful ALU (run has three
 *    RegisterActions for the three mutually exclusive cases, of which one
 *    executes);
 *  - ring cells are 32 bit (values < 2^16): the RegisterAction returns the
 *    old value straight into 32-bit arithmetic. Cell of (slot, ptr) =
 *    slot ++ ptr[6:0] = slot * 128 + ptr, an identity hash of the two.
 *
 * config and precondition only read the message: they run for every
 * complete plant message (is_plant or not) so that the dependency chain
 * starts in stage 0; the registers are touched only when is_plant == 1
 * and the slot is enabled.
 *
 * Dependent steps (stage plan in tna/civic.p4 and p4src/README.md):
 *   ptr -> ring (old) -> d, R*old (3 stages) -> s0 -> t -> s1 -> slope
 *   -> classify
 * set_class writes the class straight into the slot's field of the bridge
 * header (cls_out); a slot that is not evaluated keeps the 0 the ingress
 * parser put there.
 */
#ifndef _CIVIC_TNA_MONITOR_P4_
#define _CIVIC_TNA_MONITOR_P4_

control Monitor(in plant_msg_t msg, in bit<1> is_plant, in bit<8> slot, in bit<1> gap,
                inout monitor_md_t m, inout bit<2> cls_out)
               (bit<8> c_window, bit<8> c_ring_len, bool c_lsq, bool c_bias_in_product,
                bit<8> r_a0, bit<8> r_a1, bit<8> r_a2, bit<8> r_a3, bit<4> r_used, bit<4> r_negs,
                bit<8> w_a0, bit<8> w_a1, bit<8> w_a2, bit<8> w_a3, bit<4> w_used, bit<4> w_negs) {

    Register<bit<32>, bit<15>>(RING_CELLS, 0) ring;
    Register<bit<8>, bit<8>>(MAX_PLANTS, 0) ptr;
    Register<bit<8>, bit<8>>(MAX_PLANTS, 0) run;
    Register<bit<32>, bit<8>>(MAX_PLANTS, 0) s0;
    Register<bit<32>, bit<8>>(MAX_PLANTS, 0) s1;

    Hash<bit<15>>(HashAlgorithm_t.IDENTITY) ring_index;
    SignalSelect() signal_select;
    ConstMul(r_a0, r_a1, r_a2, r_a3, r_used, r_negs) r_mul;
    Slope(c_lsq, c_bias_in_product, w_a0, w_a1, w_a2, w_a3, w_used, w_negs) slope;

    // ------------------------------------------------------------ config
    action set_config(bit<1> enabled, bit<2> signal, bit<8> window,
                      bit<8> ring_len, bit<1> lsq) {
        m.enabled = enabled;
        m.signal = signal;
        m.window = window;
        m.ring_len = ring_len;
        m.lsq = lsq;
    }

    table config {
        actions = {
            set_config;
        }
        default_action = set_config(0, 0, 0, 0, 0);   // disabled
        size = 1;
    }

    // ------------------------------------------------------------ precondition
    action qualify() {
        m.q = 1;
    }

    action disqualify() {
        m.q = 0;
    }

    table precondition {
        key = {
            msg.l1: range @name("l1");
            msg.l2: range @name("l2");
            msg.l3: range @name("l3");
            msg.l4: range @name("l4");
            msg.p1: range @name("p1");
            msg.v1: range @name("v1");
            msg.v2: range @name("v2");
        }
        actions = {
            qualify;
            disqualify;
        }
        default_action = disqualify();
        size = TNA_PRECONDITION_TABLE_SIZE;
    }

    // ------------------------------------------------------------ classification
    action set_class(bit<2> cls) {
        cls_out = cls;
    }

    table classify {
        key = {
            m.slope_key: range @name("slope_key");
            m.level: range @name("level");
        }
        actions = {
            set_class;
        }
        default_action = set_class(CLASS_DEFAULT);
        size = TNA_CLASSIFY_TABLE_SIZE;
    }

    // ------------------------------------------------------------ registers
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
            if (value == c_ring_len - 1) {
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
        config.apply();
        signal_select.apply(msg, m);
        precondition.apply();

        if (is_plant == 1 && m.enabled == 1) {
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

            slope.apply(m);

            if (m.run >= c_window) {
                classify.apply();
            }
        }
    }
}

#endif  /* _CIVIC_TNA_MONITOR_P4_ */
