/*
 * CIVIC v1model -- one monitor slot (docs/pipeline.md sections 2, 3, 4, 6).
 *
 * CivicIngress instantiates this control once per slot, as mon0 .. mon3
 * (`Monitor() mon0;` ...). Every control-plane object of a slot is
 * declared directly in this control, so that p4c names it
 * CivicIngress.monK.<object> (the inliner prefixes an inlined instance's
 * objects with the instance name, ComputeNewNames in
 * frontends/p4/inlining.cpp, and HierarchicalNames prefixes the top-level
 * control's name) -- the names civic/switch/schema.py looks up:
 *
 *   table  config        keyless; default action set_config(enabled,
 *                        signal, window, ring_len, lsq, aux_plus,
 *                        aux_minus), set by the control plane (initially
 *                        all 0: the slot is disabled and touches no
 *                        register)
 *   table  precondition  l1 l2 l3 l4 p1 v1 v2 range -> qualify (q = 1);
 *                        miss -> disqualify (q = 0)
 *   table  compensate    aux range (16 bit) -> set_offset(offset), the
 *                        expected inflow in raw slope units; miss ->
 *                        set_offset(0) (pipeline.md section 3a)
 *   table  classify      slope_key range (32 bit), level range (16 bit)
 *                        -> set_class(cls); miss -> default set_class(3),
 *                        the control plane sets the monitor's default_class
 *   registers ring bit<16> x 32768, ptr bit<8>, run bit<8>, s0 bit<32>,
 *             s1 bit<32>, last_class bit<2> (x 256 each)
 *   counter   verdicts (packets) x 1024: cell slot * 4 + class
 *             (pipeline.md section 7)
 *
 * Objects without control-plane state (signal selection, slope) are
 * sub-controls in their own files; an instance of a control that declares
 * no table, action or extern adds nothing to the P4Info.
 *
 * Per plant message, when the slot is enabled:
 *   x = the configured signal; q = precondition(l1..p1, v1, v2)
 *   run = q ? (gap ? 1 : min(run + 1, 255)) : 0
 *   old = ring[ptr]; ring[ptr] = x; ptr = (ptr + 1 == R) ? 0 : ptr + 1
 *   s1  = s1 + s0 - R * old          (s0 before its update)
 *   s0  = s0 + x - old
 *   aux = max(x[aux_plus] - x[aux_minus], 0); offset = compensate(aux)
 *   slope, slope_key = (slope - offset) ^ 2^31     (slope.p4)
 *   cls = run >= W ? classify(slope_key, x) : 0
 *   cls != 0: verdicts[slot * 4 + cls]++; prev = last_class; changed =
 *             (cls != prev); last_class = cls       (section 7)
 * The ring, pointer and sums are updated for every plant message,
 * qualifying or not; all bit<32> arithmetic is modular, as in the model.
 *
 * Ring cell of (slot, ptr) = slot * MAX_WINDOW + ptr. The index takes
 * ptr[6:0]: with R <= MAX_WINDOW the pointer is always < R and this is
 * exactly slot * 128 + ptr; the mask only matters if the control plane
 * shrinks R while a plant has state (civic configure clears the slot's
 * registers when a monitor changes), and then keeps every plant in its own
 * cells.
 */
#ifndef _CIVIC_V1MODEL_MONITOR_P4_
#define _CIVIC_V1MODEL_MONITOR_P4_

control Monitor(in plant_msg_t msg, in bit<32> slot, in bit<1> gap,
                in bit<16> dp1, in bit<16> dv1, in bit<16> dv2,
                inout monitor_md_t m) {

    register<bit<32>>(RING_CELLS) ring;
    register<bit<8>>(MAX_PLANTS) ptr;
    register<bit<8>>(MAX_PLANTS) run;
    register<bit<32>>(MAX_PLANTS) s0;
    register<bit<32>>(MAX_PLANTS) s1;
    register<bit<2>>(MAX_PLANTS) last_class;
    register<bit<32>>(MAX_PLANTS) acc;      // balance: accumulated expected inflow
    register<bit<32>>(MAX_PLANTS) accb;     // balance: accumulated band
    register<bit<32>>(RING_CELLS) ringb;    // balance: accb of the last R messages (ring's cells)
    register<bit<2>>(MAX_PLANTS) cand;      // hold: the table's last result ...
    register<bit<8>>(MAX_PLANTS) hold;      // ... and for how many messages
    counter(VERDICT_COUNTER_CELLS, CounterType.packets) verdicts;

    SignalSelect() signal_select;
    Slope() slope;

    // ------------------------------------------------------------ config
    action set_config(bit<1> enabled, bit<2> signal, bit<8> window,
                      bit<8> ring_len, bit<2> estimator, bit<1> balance,
                      bit<8> hold_min, bit<2> aux_plus, bit<2> aux_minus,
                      bit<3> f0_plus, bit<3> f0_minus, bit<3> f0_cmd,
                      bit<3> f1_plus, bit<3> f1_minus, bit<3> f1_cmd) {
        m.enabled = enabled;
        m.signal = signal;
        m.window = window;
        m.ring_len = ring_len;
        m.estimator = estimator;
        m.balance = balance;
        m.hold_min = hold_min;
        m.aux_plus = aux_plus;
        m.aux_minus = aux_minus;
        m.f0_plus = f0_plus;
        m.f0_minus = f0_minus;
        m.f0_cmd = f0_cmd;
        m.f1_plus = f1_plus;
        m.f1_minus = f1_minus;
        m.f1_cmd = f1_cmd;
    }

    table config {
        actions = {
            set_config;
        }
        default_action = set_config(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0);   // disabled
        size = 1;
    }

    // ------------------------------------------------------------ compensation
    action set_offset(bit<32> offset) {
        m.offset = offset;
    }

    table compensate {
        key = {
            m.aux: range @name("aux");
        }
        actions = {
            set_offset;
        }
        default_action = set_offset(0);
        size = COMPENSATE_TABLE_SIZE;
    }

    // ------------------------------------------------------------ flow terms (3b)
    action set_flow0(bit<32> flow, bit<16> band) {
        m.flow0 = flow;
        m.band0 = band;
    }

    table flow0 {
        key = {
            m.head0: range @name("head");
            m.cmd0: range @name("cmd");
        }
        actions = {
            set_flow0;
        }
        default_action = set_flow0(0, 0);
        size = FLOW_TABLE_SIZE;
    }

    action set_flow1(bit<32> flow, bit<16> band) {
        m.flow1 = flow;
        m.band1 = band;
    }

    table flow1 {
        key = {
            m.head1: range @name("head");
            m.cmd1: range @name("cmd");
        }
        actions = {
            set_flow1;
        }
        default_action = set_flow1(0, 0);
        size = FLOW_TABLE_SIZE;
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
            dp1: range @name("dp1");
            dv1: range @name("dv1");
            dv2: range @name("dv2");
        }
        actions = {
            qualify;
            disqualify;
        }
        default_action = disqualify();
        size = PRECONDITION_TABLE_SIZE;
    }

    // ------------------------------------------------------------ classification
    action set_class(bit<2> cls) {
        m.cls = cls;
    }

    table classify {
        key = {
            m.slope_key: range @name("slope_key");
            m.key2: range @name("level");
        }
        actions = {
            set_class;
        }
        default_action = set_class(CLASS_DEFAULT);
        size = CLASSIFY_TABLE_SIZE;
    }

    apply {
        m.enabled = 0;
        m.cls = CLASS_NOT_EVALUATED;
        m.prev = CLASS_NOT_EVALUATED;
        m.changed = 0;
        config.apply();
        if (m.enabled == 1) {
            signal_select.apply(msg, m);

            m.q = 0;
            precondition.apply();

            // run counter: reset on a sequence gap, saturate at RUN_MAX
            run.read(m.run, slot);
            if (m.q == 0) {
                m.run = 0;
            } else if (gap == 1) {
                m.run = 1;
            } else if (m.run != RUN_MAX) {
                m.run = m.run + 1;
            }
            run.write(slot, m.run);

            // balance monitors: z = (x << 6) - acc, acc += expected inflow;
            // the class table's band key: the bands summed over the window
            ptr.read(m.ptr, slot);
            m.ring_idx = (slot << MAX_WINDOW_LOG2) | (bit<32>)(m.ptr & (MAX_WINDOW - 1));
            m.z = (bit<32>)m.x;
            m.key2 = m.x;
            if (m.balance == 1) {
                m.flow0 = 0;
                m.flow1 = 0;
                m.band0 = 0;
                m.band1 = 0;
                flow0.apply();
                flow1.apply();
                acc.read(m.acc, slot);
                m.acc = m.acc + m.flow0 + m.flow1;
                acc.write(slot, m.acc);
                m.z = ((bit<32>)m.x << BALANCE_SHIFT) - m.acc;
                accb.read(m.accb, slot);
                m.accb = m.accb + (bit<32>)(m.band0 + m.band1);
                accb.write(slot, m.accb);
                ringb.read(m.oldb, m.ring_idx);
                ringb.write(m.ring_idx, m.accb);
                m.key2 = ((m.accb - m.oldb) >> BAND_SUM_SHIFT)[15:0];
            }

            // ring buffer: swap z in, old out; advance the pointer modulo R
            ring.read(m.old, m.ring_idx);
            ring.write(m.ring_idx, m.z);
            if (m.ptr + 1 == m.ring_len) {
                ptr.write(slot, 0);
            } else {
                ptr.write(slot, m.ptr + 1);
            }

            // running sums (s1 first: it uses s0 before the update)
            s0.read(m.s0, slot);
            s1.read(m.s1, slot);
            m.s1 = m.s1 + m.s0 - (bit<32>)m.ring_len * m.old;
            m.s0 = m.s0 + m.z - m.old;
            s0.write(slot, m.s0);
            s1.write(slot, m.s1);

            m.offset = 0;
            compensate.apply();
            slope.apply(m);

            m.c_raw = CLASS_NOT_EVALUATED;
            if (m.run >= m.window) {
                classify.apply();
                m.c_raw = m.cls;
            }

            // hold: write a class once the table gave it hold_min times in a row
            cand.read(m.cand, slot);
            hold.read(m.hold, slot);
            if (m.c_raw == m.cand) {
                if (m.hold != HOLD_MAX) {
                    m.hold = m.hold + 1;
                }
            } else {
                m.cand = m.c_raw;
                m.hold = 1;
            }
            cand.write(slot, m.cand);
            hold.write(slot, m.hold);
            m.cls = CLASS_NOT_EVALUATED;
            if (m.hold >= m.hold_min) {
                m.cls = m.c_raw;
            }

            // verdict counts and changes (section 7): messages without a
            // verdict touch neither
            if (m.cls != CLASS_NOT_EVALUATED) {
                verdicts.count((slot << 2) | (bit<32>)m.cls);
                last_class.read(m.prev, slot);
                if (m.cls != m.prev) {
                    m.changed = 1;
                    last_class.write(slot, m.cls);
                }
            }
        }
    }
}

#endif  /* _CIVIC_V1MODEL_MONITOR_P4_ */
