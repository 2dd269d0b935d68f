/*
 * CIVIC TNA -- one monitor slot (docs/pipeline.md sections 2, 3, 4, 6; see
 * the v1model monitor.p4 for the semantics and the naming rule).
 *
 * CivicIngress instantiates this control once per slot, as mon0 and mon1;
 * every control-plane object of a slot is declared here, so that it is
 * CivicIngress.monK.<object>, with the same names, keys and action
 * parameters as on v1model (config / set_config, precondition / qualify /
 * disqualify, compensate / set_offset, classify / set_class, registers
 * ring ptr run s0 s1), except set_offset's parameter (below).
 *
 * Tofino rules shape this file:
 *  - W, R and the estimator are compile-time constants (constructor
 *    parameters c_window, c_ring_len, c_lsq, from include/config.p4):
 *    Tofino has no run-time multiplier, and R * old and (W - 1) * s0 are
 *    shift-and-add sums (const_mul.p4).
 *    set_config keeps its seven parameters so that the control plane is
 *    the same, but only `enabled`, `signal`, `aux_plus` and `aux_minus`
 *    are used here; window, ring_len and lsq must equal the compiled
 *    constants;
 *  - a register is accessed once per packet, by one RegisterAction that
 *    reads, modifies and writes it in the stateful ALU (run has three
 *    RegisterActions for the three mutually exclusive cases, of which one
 *    executes);
 *  - one ALU operation per field per stage: every dependent step is its
 *    own @hidden table (CIVIC_STEP, const_mul.p4);
 *  - ring cells are 32 bit (values < 2^16): the RegisterAction returns the
 *    old value straight into 32-bit arithmetic. Cell of (slot, ptr) =
 *    slot ++ ptr[6:0] = slot * 128 + ptr, an identity hash of the two.
 *
 * config, the precondition tables and the arithmetic steps only read the
 * message and write this slot's metadata: they run for every frame so that
 * the dependency chain starts in stage 0 and no if-block holds more than
 * one table. The registers and classify are touched only for a plant
 * message (valid, monitored port, plant prefix) when the slot is enabled.
 *
 * Dependent steps (stage plan in tna/civic.p4 and p4src/README.md), lsq:
 *   0 config  1 x, ptr, aux  2 ring (old), x32, compensate (bias)
 *   3 d, R*old shifts, run  4 s0, R*old adds, e = d + bias
 *   5 R*old, s0n  6 t, (W-1)*s0n shifts  7 s1, adds  8 prod, 2*s1
 *   9 slope_key  10 classify
 * endpoint: as far as 3 d, then 4 slope_key = d + bias  5 classify (the
 * sums are still kept, as pipeline.md requires).
 *
 * Slope bias: slope_key = slope XOR 2^31 = slope + 2^31 (mod 2^32).
 *   endpoint: slope_key = (x - old) XOR 2^31;
 *   lsq: with B = c_s0_bias = 2^(31 - k), 2^k the largest power of two
 *     dividing W - 1 (config.p4), (W - 1) * B = 2^31 (mod 2^32), so
 *     s0n = s0 + (d + B) = s0' + B carries the bias through the product
 *     and slope_key = (W - 1) * s0n - 2 * s1' directly, for every W.
 * Compensation (pipeline.md 3a) costs no stage of its own: the offset rides
 * in the same bias. The compensate action's parameter is the bias itself,
 * set_offset(bias), computed by the control plane from the offset:
 *   lsq:      bias = B - offset / (W - 1)   (offset is a multiple of W - 1)
 *             e = d + bias, so slope_key = (W - 1) * (s0' + B) - 2 * s1'
 *             - offset = (slope - offset) XOR 2^31
 *   endpoint: bias = 2^31 - offset,  slope_key = d + bias
 * (all mod 2^32) and a miss keeps the default set_offset(c_s0_bias):
 * offset 0 (c_s0_bias = B for lsq, 2^31 = SLOPE_BIAS for endpoint).
 * v1model's set_offset(offset) takes the offset itself; a control plane
 * for TNA writes set_offset(bias) with the bias above. The chain
 * config (stage 0) -> aux (1: one table on (aux_plus, aux_minus) whose
 * action is one saturating subtract, `ssubu` in civic.bfa) -> compensate
 * (2) ends before the stage-4 step that adds bias: no stage of its own.
 *
 * set_class writes the class straight into the slot's field of the bridge
 * header (cls_out); a slot that is not evaluated keeps the 0 the ingress
 * parser put there.
 */
#ifndef _CIVIC_TNA_MONITOR_P4_
#define _CIVIC_TNA_MONITOR_P4_

control Monitor(in plant_msg_t msg, in bit<1> monitored, in bit<1> in_prefix,
                in bit<8> slot, in bit<1> gap,
                inout monitor_md_t m, inout bit<2> cls_out)
               (bit<8> c_window, bit<8> c_ring_len, bool c_lsq, bit<32> c_s0_bias,
                bit<8> r_a0, bit<8> r_a1, bit<8> r_a2, bit<8> r_a3, bit<4> r_used, bit<4> r_negs,
                bit<8> w_a0, bit<8> w_a1, bit<8> w_a2, bit<8> w_a3, bit<4> w_used, bit<4> w_negs) {

    Register<bit<32>, bit<15>>(RING_CELLS, 0) ring;
    Register<bit<8>, bit<8>>(MAX_PLANTS, 0) ptr;
    Register<bit<8>, bit<8>>(MAX_PLANTS, 0) run;
    Register<bit<32>, bit<8>>(MAX_PLANTS, 0) s0;
    Register<bit<32>, bit<8>>(MAX_PLANTS, 0) s1;

    Hash<bit<15>>(HashAlgorithm_t.IDENTITY) ring_index;
    // x zero-extended to 32 bit: an identity hash carries a 16-bit field
    // into a 32-bit container (ALU operations do not mix container sizes)
    Hash<bit<32>>(HashAlgorithm_t.IDENTITY) widen;

    // ------------------------------------------------------------ config
    action set_config(bit<1> enabled, bit<2> signal, bit<8> window,
                      bit<8> ring_len, bit<1> lsq, bit<2> aux_plus,
                      bit<2> aux_minus) {
        m.enabled = enabled;
        m.signal = signal;
        m.window = window;
        m.ring_len = ring_len;
        m.lsq = lsq;
        m.aux_plus = aux_plus;
        m.aux_minus = aux_minus;
    }

    table config {
        actions = {
            set_config;
        }
        default_action = set_config(0, 0, 0, 0, 0, 0, 0);   // disabled
        size = 1;
    }

    // ------------------------------------------------------------ compensation
    // bias = the key bias minus the offset (see the header of this file)
    action set_offset(bit<32> bias) {
        m.bias = bias;
    }

    table compensate {
        key = {
            m.aux: range @name("aux");
        }
        actions = {
            set_offset;
        }
        default_action = set_offset(c_s0_bias);     // offset 0
        size = TNA_COMPENSATE_TABLE_SIZE;
    }

    // ------------------------------------------------------------ precondition
    action qualify() {
        m.q = 1;
    }

    action disqualify() {
        m.q = 0;
    }

    // pipeline.md's precondition is one conjunction of seven 16-bit ranges.
    // bf-p4c places at most six 16-bit range keys in one Tofino table (the
    // seventh does not fit the ternary input crossbar), so TNA splits it:
    // precondition keeps the levels l1..l4 and its names, precondition_cmd
    // takes the commands p1 v1 v2; q = both hit a qualifying entry. For one
    // entry per table (civic train writes one conjunction) this is the same
    // predicate.
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

    table precondition_cmd {
        key = {
            msg.p1: range @name("p1");
            msg.v1: range @name("v1");
            msg.v2: range @name("v2");
        }
        actions = {
            qualify_cmd;
            disqualify_cmd;
        }
        default_action = disqualify_cmd();
        size = TNA_PRECONDITION_TABLE_SIZE;
    }

    // ------------------------------------------------------------ classification
    // and verdict changes (pipeline.md section 7). The class is an action
    // constant here, not a parameter: the last_class register runs in the
    // classify table's own stage (the last free one follows it), where a
    // stateful ALU cannot read a class written in that stage, but can be
    // handed one by the action that runs it. So one action per class, each with its own
    // RegisterAction (one of them executes per packet):
    //   chg = last_class == C ? 0 : last_class | CHANGED;  last_class = C
    // (CHANGED = 4 marks a change even from "none yet", 0). The control plane
    // writes set_normal / set_warning / set_error where v1model has
    // set_class(1 / 2 / 3). The verdicts counter is in egress (notify.p4):
    // the actions of one table must address their attached objects alike.
    Register<bit<8>, bit<8>>(MAX_PLANTS, 0) last_class;

    RegisterAction<bit<8>, bit<8>, bit<8>>(last_class) set_normal_swap = {
        void apply(inout bit<8> value, out bit<8> rv) {
            if (value == CLASS_NORMAL) {
                rv = 0;
            } else {
                rv = value | CHANGED;
            }
            value = CLASS_NORMAL;
        }
    };

    action set_normal() {
        cls_out = CLASS_NORMAL;
        m.chg = set_normal_swap.execute(slot);
    }

    RegisterAction<bit<8>, bit<8>, bit<8>>(last_class) set_warning_swap = {
        void apply(inout bit<8> value, out bit<8> rv) {
            if (value == CLASS_WARNING) {
                rv = 0;
            } else {
                rv = value | CHANGED;
            }
            value = CLASS_WARNING;
        }
    };

    action set_warning() {
        cls_out = CLASS_WARNING;
        m.chg = set_warning_swap.execute(slot);
    }

    RegisterAction<bit<8>, bit<8>, bit<8>>(last_class) set_error_swap = {
        void apply(inout bit<8> value, out bit<8> rv) {
            if (value == CLASS_ERROR) {
                rv = 0;
            } else {
                rv = value | CHANGED;
            }
            value = CLASS_ERROR;
        }
    };

    action set_error() {
        cls_out = CLASS_ERROR;
        m.chg = set_error_swap.execute(slot);
    }
    // A default action cannot address a register (bf-p4c: it would need the
    // hash-distribution unit), so a miss gives the default class without
    // touching last_class. A TNA control plane installs a lowest-priority
    // catch-all entry with the default class instead (civic train's tables
    // cover every key anyway), which keeps pipeline.md's semantics.
    action set_class(bit<2> cls) {
        cls_out = cls;
    }

    // bf-p4c range-matches keys of at most 4 PHV nibbles (16 bit): the
    // 32-bit slope_key of pipeline.md is matched as its two halves. An
    // entry slope [lo, hi] becomes up to three entries (hi halves equal:
    // one; else the first high half with [lo_lo, 0xFFFF], the high halves
    // strictly between with [0, 0xFFFF], the last with [0, hi_lo]), which
    // match exactly the same keys and stay disjoint (p4src/README.md).
    table classify {
        key = {
            m.slope_key[31:16]: range @name("slope_key_hi");
            m.slope_key[15:0]: range @name("slope_key_lo");
            m.x: range @name("level");
        }
        actions = {
            set_normal;
            set_warning;
            set_error;
            @defaultonly set_class;
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
            value = (bit<32>)m.x;
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

    // ------------------------------------------------------------ one-operation steps
    // x = l1..l4 by signal (SIGNAL_L1..L4), zero-extended
    CIVIC_SELECT4(select_x, m.signal,
                  m.x = msg.l1;, m.x = msg.l2;, m.x = msg.l3;, m.x = msg.l4;)
    // aux = max(x[aux_plus] - x[aux_minus], 0) in one saturating subtract:
    // one table on (aux_plus, aux_minus) whose 12 const entries each
    // subtract one pair of levels (equal codes miss: aux = 0), a stage
    // shorter than selecting both levels first
    @hidden action aux_zero() { m.aux = 0; }
    @hidden action aux_l1_l2() { m.aux = msg.l1 |-| msg.l2; }
    @hidden action aux_l1_l3() { m.aux = msg.l1 |-| msg.l3; }
    @hidden action aux_l1_l4() { m.aux = msg.l1 |-| msg.l4; }
    @hidden action aux_l2_l1() { m.aux = msg.l2 |-| msg.l1; }
    @hidden action aux_l2_l3() { m.aux = msg.l2 |-| msg.l3; }
    @hidden action aux_l2_l4() { m.aux = msg.l2 |-| msg.l4; }
    @hidden action aux_l3_l1() { m.aux = msg.l3 |-| msg.l1; }
    @hidden action aux_l3_l2() { m.aux = msg.l3 |-| msg.l2; }
    @hidden action aux_l3_l4() { m.aux = msg.l3 |-| msg.l4; }
    @hidden action aux_l4_l1() { m.aux = msg.l4 |-| msg.l1; }
    @hidden action aux_l4_l2() { m.aux = msg.l4 |-| msg.l2; }
    @hidden action aux_l4_l3() { m.aux = msg.l4 |-| msg.l3; }
    @hidden table aux_diff {
        key = {
            m.aux_plus: exact;
            m.aux_minus: exact;
        }
        actions = {
            aux_zero;
            aux_l1_l2;
            aux_l1_l3;
            aux_l1_l4;
            aux_l2_l1;
            aux_l2_l3;
            aux_l2_l4;
            aux_l3_l1;
            aux_l3_l2;
            aux_l3_l4;
            aux_l4_l1;
            aux_l4_l2;
            aux_l4_l3;
        }
        const entries = {
            (0, 1): aux_l1_l2();
            (0, 2): aux_l1_l3();
            (0, 3): aux_l1_l4();
            (1, 0): aux_l2_l1();
            (1, 2): aux_l2_l3();
            (1, 3): aux_l2_l4();
            (2, 0): aux_l3_l1();
            (2, 1): aux_l3_l2();
            (2, 3): aux_l3_l4();
            (3, 0): aux_l4_l1();
            (3, 1): aux_l4_l2();
            (3, 2): aux_l4_l3();
        }
        const default_action = aux_zero();
        size = 16;
    }
    // x zero-extended into a 32-bit container (in the stage of the ring
    // access, which takes the 16-bit x directly)
    CIVIC_STEP(widen_x, m.x32 = widen.get({m.x});)
    // d = x - old
    CIVIC_STEP(diff, m.d = m.x32 - m.old;)
    // R * old
    CIVIC_CONST_MUL(r, m.old, m.acc, r_a0, r_a1, r_a2, r_a3, r_used, r_negs)
    // endpoint: slope_key = (x - old - offset) XOR 2^31 = d + bias;
    // lsq: e = d + bias (bias = B - offset / (W - 1))
    CIVIC_STEP(key_endpoint, m.slope_key = m.d + m.bias;)
    CIVIC_STEP(diff_b, m.e = m.d + m.bias;)
    // t = s0 - R * old, the increment of s1
    CIVIC_STEP(s1_inc, m.t = m.s0 - m.acc;)
    // s0n = s0' + B
    CIVIC_STEP(s0_new_b, m.s0n = m.s0 + m.e;)
    // (W - 1) * s0n
    CIVIC_CONST_MUL(p, m.s0n, m.acc, w_a0, w_a1, w_a2, w_a3, w_used, w_negs)
    // 2 * s1 (into d, which is no longer needed)
    CIVIC_STEP(s1_twice, m.d = m.s1 << 1;)
    CIVIC_STEP(key_lsq_b, m.slope_key = m.acc - m.d;)

    // Every conditional guards one table (see CivicIngress); `on` is the
    // condition under which the slot touches its registers.
    apply {
        config.apply();
        precondition.apply();
        precondition_cmd.apply();
        // x is computed for every frame; it is used only when `on`
        select_x.apply();           // SIGNAL_L1..L4 = 0..3
        widen_x.apply();
        aux_diff.apply();
        compensate.apply();

#define ON (msg.isValid() && monitored == 1 && in_prefix == 1 && m.enabled == 1)
        if (ON) {
            m.ptr = ptr_advance.execute(slot);
        }
        if (ON && (m.q == 0 || m.q_cmd == 0)) {
            m.run = run_clear.execute(slot);
        } else if (ON && gap == 1) {
            m.run = run_restart.execute(slot);
        } else if (ON) {
            m.run = run_count.execute(slot);
        }
        if (ON) {
            m.old = ring_swap.execute(ring_index.get({slot, m.ptr[6:0]}));
        }
        // the arithmetic runs for every frame and has no effect unless `on`
        diff.apply();
        CIVIC_CONST_MUL_APPLY(r, r_used)
        if (ON) {
            m.s0 = s0_add.execute(slot);
        }
        if (c_lsq) {
            diff_b.apply();
        } else {
            key_endpoint.apply();
        }
        s1_inc.apply();
        if (ON) {
            m.s1 = s1_add.execute(slot);
        }
        if (c_lsq) {
            s0_new_b.apply();
            CIVIC_CONST_MUL_APPLY(p, w_used)
            s1_twice.apply();
            key_lsq_b.apply();
        }
        if (ON && m.run >= c_window) {
            classify.apply();
        }
#undef ON
    }
}

#endif  /* _CIVIC_TNA_MONITOR_P4_ */
