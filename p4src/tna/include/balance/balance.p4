/*
 * CIVIC TNA -- one balance monitor slot (docs/pipeline.md sections 2, 3,
 * 3b, 4, 7), for the balance profile (-DCIVIC_PROFILE_BALANCE, see
 * include/config.p4). The v1model twin is the balance branch of
 * p4src/v1model/include/control/monitor.p4, the model civic/pipeline/
 * (balance.py, switch.py).
 *
 * p4src/tna/civic_balance.p4 instantiates this control as mon2 (balance_t3)
 * and mon3 (balance_t1): every control-plane object is
 * CivicIngress.monK.<object> with v1model's names (config / set_config,
 * precondition, flow0 / flow1 / set_flow0 / set_flow1 (head, cmd) -> (flow,
 * band), classify, registers ring ptr run s0 acc accb ringb last_class),
 * except where Tofino's rules force a difference (p4src/README.md, "The
 * balance profile"):
 *  - W = R (include/config.p4), the signal x and the flow terms' operands are
 *    compile-time constants (the operands are the control's `in`
 *    parameters x, head0, cmd0, head1, cmd1; include/config.p4). set_config
 *    keeps v1model's fifteen parameters; `enabled` and `hold_min` (H) are
 *    used;
 *  - precondition is split as in the test-monitor profile: precondition
 *    (l1..l4) and precondition_cmd (p1 v1 v2 dp1 dv1 dv2: six 16-bit range
 *    keys, the most bf-p4c fits in one table);
 *  - classify matches slope_key as two 16-bit halves (as monitor.p4), runs
 *    the hold, and has one action per class (set_none, set_normal,
 *    set_warning, set_error; set_class only as the default action);
 *  - no s1 register: the slope itself is a register (`slope`, holding
 *    slope XOR 2^31, initial value 2^31), see "Slope" below;
 *  - cand and hold are one register (`hold`, a pair: cand high, hold low).
 *
 * Slope. pipeline.md keeps s0 and s1 and computes (W - 1) * s0' - 2 * s1'
 * after the update: with R * old and (W - 1) * s0' in shift-and-add that
 * chain is eight stages from the ring to classify (monitor.p4), three more
 * than this profile has behind the flow terms and the accumulator. With
 * s0' = s0 + d, s1' = s1 + s0 - R * old, d = z - old and R = W:
 *     slope' = (W - 1) * s0' - 2 * s1'
 *            = slope + (W - 1) * d - 2 * s0 + 2 * W * old
 *            = slope + (W - 1) * (z + old) + 2 * (old - s0)
 * which is what the `slope` register adds, every step modulo 2^32 (the
 * same ring homomorphism as pipeline.md: the result is bit-identical).
 * A stateful ALU's first operand must be its memory, so the registers give
 * what starts from their cell: the ring stores z and returns old + z, s0
 * adds d and returns s0 - old, and slope subtracts
 *     ndelta = 2 * (s0 - old) - (W - 1) * (z + old).
 * (W - 1) * (z + old) is two steps "(u << a) +- w" (W = 80: 79 = 5 * 16
 * - 1; config.p4), the shifted operand coming from an identity hash (a
 * Tofino ALU operation takes one PHV operand and one from the action data
 * bus, where hash results arrive), and 2 * (s0 - old) the same way in the
 * step that subtracts it. The register `slope` holds slope + 2^31, so that
 * it returns slope_key directly; it starts at 2^31 (slope 0 with s0 = s1
 * = 0). A control plane that clears a plant's state writes 0x80000000
 * there, 0 everywhere else.
 *
 * band_w (pipeline.md 3b): accb adds band and returns accb'; ringb (same
 * cell as the ring) stores accb' and returns oldb; band_w = (accb' - oldb)
 * >> 7, bits 22..7 taken into a 16-bit container by an identity hash.
 *
 * Hold (pipeline.md 3): classify's actions each run the `hold`
 * RegisterAction of their class C (a constant, as last_class's in
 * monitor.p4):
 *     w = (cand == C && hold >= H - 1) ? C : 0     (hold after >= H, H >= 2)
 * with H = set_config's hold_min (H - 1 computed in stage 0 or 1; H = 1
 * would need a third condition: it acts as H = 2);
 *     hold = cand == C ? hold |+| 1 : 1;  cand = C
 * w is the class written. hold is 16 bit here and saturates at 65535, not
 * 255: the written class only asks hold >= H <= 255, so it is the same.
 * When run < W (no classify), the class-0 action runs instead, as
 * pipeline.md updates cand / hold on every plant message.
 * last_class (stage after): if w != 0: chg = last_class == w ? 0 :
 * last_class | CHANGED; last_class = w.
 *
 * Dependent steps (stage plan in civic_balance.p4 and p4src/README.md):
 *   0 config, precondition, x16, the flow term on message fields
 *   1 the flow term on a head difference (e += flow, band += band), ptr,
 *     H - 1
 *   2 acc   3 z, accb   4 ring (old + z), ringb, 2 * z
 *   5 old, d, t1, accb - oldb, precondition_cmd
 *   6 s0 (s0 - old), (W - 1) * (z + old), band_w   7 ndelta, run   8 slope
 *   9 classify + hold   10 last_class, class byte
 */
#ifndef _CIVIC_TNA_BALANCE_P4_
#define _CIVIC_TNA_BALANCE_P4_

// cand (high half) and hold (low half) of one plant
struct hold_pair_t {
    bit<16> hold;
    bit<16> cand;
}

control BalanceMonitor(in plant_msg_t msg, in bit<1> monitored, in bit<1> in_prefix,
                       in bit<8> slot, in bit<1> gap,
                       in bit<16> dp1, in bit<16> dv1, in bit<16> dv2,
                       in bit<16> x, in bit<16> head0, in bit<16> cmd0,
                       in bit<16> head1, in bit<16> cmd1,
                       inout balance_md_t m, inout bit<2> cls_out)
                      (bit<8> c_window, bit<8> c_ring_len, bool c_flow1_first,
                       int c_flow0_size, int c_flow1_size) {

    Register<bit<32>, bit<15>>(RING_CELLS, 0) ring;
    Register<bit<8>, bit<8>>(MAX_PLANTS, 0) ptr;
    Register<bit<8>, bit<8>>(MAX_PLANTS, 0) run;
    Register<bit<32>, bit<8>>(MAX_PLANTS, 0) s0;
    Register<bit<32>, bit<8>>(MAX_PLANTS, SLOPE_BIAS) slope;
    Register<bit<32>, bit<8>>(MAX_PLANTS, 0) acc;
    Register<bit<32>, bit<8>>(MAX_PLANTS, 0) accb;
    Register<bit<32>, bit<15>>(RING_CELLS, 0) ringb;
    Register<hold_pair_t, bit<8>>(MAX_PLANTS, {0, 0}) hold;
    Register<bit<8>, bit<8>>(MAX_PLANTS, 0) last_class;

    Hash<bit<15>>(HashAlgorithm_t.IDENTITY) ring_index;
    Hash<bit<15>>(HashAlgorithm_t.IDENTITY) ringb_index;
    // x << BALANCE_SHIFT zero-extended to 32 bit: an identity hash places x
    // above BALANCE_SHIFT zero bits
    Hash<bit<32>>(HashAlgorithm_t.IDENTITY) widen;
    Hash<bit<32>>(HashAlgorithm_t.IDENTITY) widen_b;
    Hash<bit<16>>(HashAlgorithm_t.IDENTITY) narrow_b;
    // the shifted operands of the slope steps (one 32-bit hash result per table)
    Hash<bit<32>>(HashAlgorithm_t.IDENTITY) shift_a;
    Hash<bit<32>>(HashAlgorithm_t.IDENTITY) shift_b;
    Hash<bit<32>>(HashAlgorithm_t.IDENTITY) shift_s0;

    // ------------------------------------------------------------ config
    // v1model's parameters; on TNA only `enabled` and `hold_min` are used
    // (the rest is fixed at compile time and must equal the constants of
    // include/config.p4)
    action set_config(bit<1> enabled, bit<2> signal, bit<8> window,
                      bit<8> ring_len, bit<2> estimator, bit<1> balance,
                      bit<8> hold_min, bit<2> aux_plus, bit<2> aux_minus,
                      bit<3> f0_plus, bit<3> f0_minus, bit<3> f0_cmd,
                      bit<3> f1_plus, bit<3> f1_minus, bit<3> f1_cmd) {
        m.enabled = enabled;
        m.hold_min = (bit<16>)hold_min;       // H, 2..255 (balance.p4: hold)
    }

    table config {
        actions = {
            set_config;
        }
        default_action = set_config(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0);   // disabled
        size = 1;
    }

    // ------------------------------------------------------------ flow terms (3b)
    // e = flow0 + flow1, band = band0 + band1 (e and band start at 0: the
    // ingress parser sets them, parser.p4); the term keyed on message
    // fields runs in stage 0 and the one keyed on a head difference adds to
    // it in stage 1. A miss adds (0, 0).
    action set_flow0(bit<32> flow, bit<16> band) {
        m.e = m.e + flow;
        m.band = m.band + band;
    }

    table flow0 {
        key = {
            head0: range @name("head");
            cmd0: range @name("cmd");
        }
        actions = {
            set_flow0;
        }
        default_action = set_flow0(0, 0);
        size = c_flow0_size;
    }

    action set_flow1(bit<32> flow, bit<16> band) {
        m.e = m.e + flow;
        m.band = m.band + band;
    }

    table flow1 {
        key = {
            head1: range @name("head");
            cmd1: range @name("cmd");
        }
        actions = {
            set_flow1;
        }
        default_action = set_flow1(0, 0);
        size = c_flow1_size;
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
        }
        actions = {
            qualify;
            disqualify;
        }
        default_action = disqualify();
        size = TNA_PRECONDITION_TABLE_SIZE;
    }

    action qualify_cmd() {
        m.q_cmd = 1;
    }

    action disqualify_cmd() {
        m.q_cmd = 0;
    }

    // the commands and their steps: six 16-bit range keys
    table precondition_cmd {
        key = {
            msg.p1: range @name("p1");
            msg.v1: range @name("v1");
            msg.v2: range @name("v2");
            dp1: range @name("dp1");
            dv1: range @name("dv1");
            dv2: range @name("dv2");
        }
        actions = {
            qualify_cmd;
            disqualify_cmd;
        }
        default_action = disqualify_cmd();
        size = TNA_PRECONDITION_TABLE_SIZE;
    }

    // ------------------------------------------------------------ hold and classification
#define CIVIC_HOLD_ACTION(NAME, C)                                          \
    RegisterAction<hold_pair_t, bit<8>, bit<8>>(hold) NAME = {             \
        void apply(inout hold_pair_t v, out bit<8> rv) {                    \
            hold_pair_t before = v;                                         \
            if (before.cand == C) {                                         \
                v.hold = before.hold |+| 1;                                 \
            } else {                                                        \
                v.hold = 1;                                                 \
            }                                                               \
            v.cand = C;                                                     \
            if (before.cand == C && before.hold >= m.hold_m1) {             \
                rv = (bit<8>)before.cand;                                   \
            }                                                               \
        }                                                                   \
    };
    // class 0 is never written: the same update, w = 0
    RegisterAction<hold_pair_t, bit<8>, bit<8>>(hold) hold_none = {
        void apply(inout hold_pair_t v, out bit<8> rv) {
            hold_pair_t before = v;
            if (before.cand == CLASS_NOT_EVALUATED) {
                v.hold = before.hold |+| 1;
                rv = (bit<8>)before.cand;
            } else {
                v.hold = 1;
            }
            v.cand = CLASS_NOT_EVALUATED;
        }
    };
    CIVIC_HOLD_ACTION(hold_normal, CLASS_NORMAL)
    CIVIC_HOLD_ACTION(hold_warning, CLASS_WARNING)
    CIVIC_HOLD_ACTION(hold_error, CLASS_ERROR)
#undef CIVIC_HOLD_ACTION

    action set_none() {
        m.w = hold_none.execute(slot);
    }

    action set_normal() {
        m.w = hold_normal.execute(slot);
    }

    action set_warning() {
        m.w = hold_warning.execute(slot);
    }

    action set_error() {
        m.w = hold_error.execute(slot);
    }

    // default only (a default action cannot address a register): the class
    // is written as it is, without the hold (p4src/README.md)
    action set_class(bit<2> cls) {
        m.w = (bit<8>)cls;
    }

    // slope_key as two 16-bit halves (bf-p4c's range keys: at most 4 PHV
    // nibbles); `level` is the band (pipeline.md 4)
    table classify {
        key = {
            m.slope_key[31:16]: range @name("slope_key_hi");
            m.slope_key[15:0]: range @name("slope_key_lo");
            m.band_w: range @name("level");
        }
        actions = {
            set_none;
            set_normal;
            set_warning;
            set_error;
            @defaultonly set_class;
        }
        default_action = set_class(CLASS_DEFAULT);
        size = TNA_CLASSIFY_TABLE_SIZE;
    }

    // ------------------------------------------------------------ registers
    RegisterAction<bit<8>, bit<8>, bit<8>>(run) run_clear = {
        void apply(inout bit<8> value, out bit<8> rv) {
            value = 0;
            rv = 0;
        }
    };
    RegisterAction<bit<8>, bit<8>, bit<8>>(run) run_restart = {
        void apply(inout bit<8> value, out bit<8> rv) {
            value = 1;
            rv = 1;
        }
    };
    RegisterAction<bit<8>, bit<8>, bit<8>>(run) run_count = {
        void apply(inout bit<8> value, out bit<8> rv) {
            if (value != RUN_MAX) {
                value = value + 1;
            }
            rv = value;
        }
    };

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

    // acc' = acc + e, returned
    RegisterAction<bit<32>, bit<8>, bit<32>>(acc) acc_add = {
        void apply(inout bit<32> value, out bit<32> rv) {
            value = value + m.e;
            rv = value;
        }
    };

    // accb' = accb + band, returned (band zero-extended by the ALU)
    RegisterAction<bit<32>, bit<8>, bit<32>>(accb) accb_add = {
        void apply(inout bit<32> value, out bit<32> rv) {
            value = value + m.band32;
            rv = value;
        }
    };

    // oldb = ringb[ptr]; ringb[ptr] = accb' (the ring's cell and pointer)
    RegisterAction<bit<32>, bit<15>, bit<32>>(ringb) ringb_swap = {
        void apply(inout bit<32> value, out bit<32> rv) {
            rv = value;
            value = m.accb;
        }
    };

    // ring[ptr] = z; return old + z (the old cell plus z: the stateful
    // ALU's first operand must be the memory, so z - old is not offered)
    RegisterAction<bit<32>, bit<15>, bit<32>>(ring) ring_swap = {
        void apply(inout bit<32> value, out bit<32> rv) {
            rv = value + m.z;
            value = m.z;
        }
    };

    // return s0 - old (s0 before the update); s0 = s0 + (z - old)
    RegisterAction<bit<32>, bit<8>, bit<32>>(s0) s0_add = {
        void apply(inout bit<32> value, out bit<32> rv) {
            rv = value - m.old;
            value = value + m.d;
        }
    };

    // slope + 2^31 -= ndelta; return it: slope_key
    RegisterAction<bit<32>, bit<8>, bit<32>>(slope) slope_add = {
        void apply(inout bit<32> value, out bit<32> rv) {
            value = value - m.ndelta;
            rv = value;
        }
    };

    // chg = last_class == w ? 0 : last_class | CHANGED; last_class = w
    RegisterAction<bit<8>, bit<8>, bit<8>>(last_class) last_swap = {
        void apply(inout bit<8> value, out bit<8> rv) {
            if (value == m.w) {
                rv = 0;
            } else {
                rv = value | CHANGED;
            }
            value = m.w;
        }
    };

    // ------------------------------------------------------------ one-operation steps
    CIVIC_STEP(widen_x, m.x16 = widen.get({x, (bit<BALANCE_SHIFT>)0});)
    // z = (x << BALANCE_SHIFT) - acc', and 2 * z
    CIVIC_STEP(push_z, m.z = m.x16 - m.acc;)
    CIVIC_STEP(twice_z, m.z2 = m.z << 1;)
    // from a1 = z + old (the ring's result): old = a1 - z, d = z - old = 2z - a1
    CIVIC_STEP(get_old, m.old = m.a1 - m.z;)
    CIVIC_STEP(diff, m.d = m.z2 - m.a1;)
    // (W - 1) * (z + old) in two steps (include/config.p4: BAL_W1_*)
#define CIVIC_SHL(SRC, N) {SRC[31 - (N):0], (bit<N>)0}
#if BAL_W1_S1 > 0
    CIVIC_STEP(times_a, m.t1 = shift_a.get(CIVIC_SHL(m.a1, BAL_W1_A)) + m.a1;)
#else
    CIVIC_STEP(times_a, m.t1 = shift_a.get(CIVIC_SHL(m.a1, BAL_W1_A)) - m.a1;)
#endif
#if BAL_W1_FORM == 0
#define CIVIC_W1_X m.t1
#define CIVIC_W1_Y m.t1
#elif BAL_W1_FORM == 1
#define CIVIC_W1_X m.t1
#define CIVIC_W1_Y m.a1
#else
#define CIVIC_W1_X m.a1
#define CIVIC_W1_Y m.t1
#endif
#if BAL_W1_S2 > 0
    CIVIC_STEP(times_b, m.w1a = shift_b.get(CIVIC_SHL(CIVIC_W1_X, BAL_W1_B)) + CIVIC_W1_Y;)
#else
    CIVIC_STEP(times_b, m.w1a = shift_b.get(CIVIC_SHL(CIVIC_W1_X, BAL_W1_B)) - CIVIC_W1_Y;)
#endif
#undef CIVIC_W1_X
#undef CIVIC_W1_Y
    // ndelta = -delta = 2 * (s0 - old) - (W - 1) * (z + old)
    CIVIC_STEP(add_s0, m.ndelta = shift_s0.get(CIVIC_SHL(m.ns0, 1)) - m.w1a;)
#undef CIVIC_SHL
    CIVIC_STEP(write_cls, cls_out = m.w[1:0];)
    // H - 1, what the hold RegisterActions compare the count before this message with
    CIVIC_STEP(hold_less_one, m.hold_m1 = m.hold_min - 1;)
    // band_w = ((accb' - oldb) mod 2^32) >> 7: the last R bands summed, / 128
    CIVIC_STEP(widen_band, m.band32 = widen_b.get({m.band});)
    CIVIC_STEP(band_sum, m.bdiff = m.accb - m.oldb;)
    // (bits 7..22 into a 16-bit container: an identity hash, as widen)
    CIVIC_STEP(band_scale, m.band_w = narrow_b.get({m.bdiff[TNA_BAND_SUM_SHIFT + 15:TNA_BAND_SUM_SHIFT]});)

    apply {
        config.apply();
        precondition.apply();
        widen_x.apply();
        hold_less_one.apply();
        // the term on message fields first: it needs no head step
        if (c_flow1_first) {
            flow1.apply();
            flow0.apply();
        } else {
            flow0.apply();
            flow1.apply();
        }
        precondition_cmd.apply();

#define ON (msg.isValid() && monitored == 1 && in_prefix == 1 && m.enabled == 1)
        if (ON) {
            m.ptr = ptr_advance.execute(slot);
        }
        if (ON) {
            m.acc = acc_add.execute(slot);
        }
        widen_band.apply();
        if (ON) {
            m.accb = accb_add.execute(slot);
        }
        if (ON) {
            m.oldb = ringb_swap.execute(ringb_index.get({slot, m.ptr[6:0]}));
        }
        band_sum.apply();
        band_scale.apply();
        if (ON && (m.q == 0 || m.q_cmd == 0)) {
            m.run = run_clear.execute(slot);
        } else if (ON && gap == 1) {
            m.run = run_restart.execute(slot);
        } else if (ON) {
            m.run = run_count.execute(slot);
        }
        // the arithmetic runs for every frame and has no effect unless `on`
        push_z.apply();
        twice_z.apply();
        if (ON) {
            m.a1 = ring_swap.execute(ring_index.get({slot, m.ptr[6:0]}));
        }
        get_old.apply();
        diff.apply();
        if (ON) {
            m.ns0 = s0_add.execute(slot);
        }
        times_a.apply();
        times_b.apply();
        add_s0.apply();
        if (ON) {
            m.slope_key = slope_add.execute(slot);
        }
        if (ON && m.run >= c_window) {
            classify.apply();
        } else if (ON) {
            m.w = hold_none.execute(slot);     // run < W: c_raw = 0
        }
        if (ON && m.w != 0) {
            m.chg = last_swap.execute(slot);
        }
        write_cls.apply();
#undef ON
    }
}

#endif  /* _CIVIC_TNA_BALANCE_P4_ */
