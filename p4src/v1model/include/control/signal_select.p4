/*
 * CIVIC v1model -- the signals a monitor slot reads from the message.
 *
 * set_config(signal) picks the monitored x, one of the four tank volumes
 * (0..3 = l1..l4, docs/pipeline.md section 6); x is also the class table's
 * level key. set_config(aux_plus, aux_minus) pick the two levels whose
 * difference drives the tank's inflow (section 3a):
 *   aux = max(x[aux_plus] - x[aux_minus], 0)   (16 bit, saturating at 0)
 * A balance monitor's flow terms read operands (Operand: l1..l4, p1, v1,
 * v2 or 0) for their keys head = f[plus] - f[minus] and cmd (section 3b).
 * No table, action or extern here: the instance in Monitor adds nothing
 * to the P4Info.
 */
#ifndef _CIVIC_V1MODEL_SIGNAL_SELECT_P4_
#define _CIVIC_V1MODEL_SIGNAL_SELECT_P4_

control Level(in plant_msg_t msg, in bit<2> code, out bit<16> value) {
    apply {
        if (code == SIGNAL_L1) {
            value = msg.l1;
        } else if (code == SIGNAL_L2) {
            value = msg.l2;
        } else if (code == SIGNAL_L3) {
            value = msg.l3;
        } else {
            value = msg.l4;
        }
    }
}

// A flow term's operand (pipeline.md 3b): a level, a command, or 0.
control Operand(in plant_msg_t msg, in bit<3> code, out bit<16> value) {
    apply {
        if (code == OPERAND_L1) {
            value = msg.l1;
        } else if (code == OPERAND_L2) {
            value = msg.l2;
        } else if (code == OPERAND_L3) {
            value = msg.l3;
        } else if (code == OPERAND_L4) {
            value = msg.l4;
        } else if (code == OPERAND_P1) {
            value = msg.p1;
        } else if (code == OPERAND_V1) {
            value = msg.v1;
        } else if (code == OPERAND_V2) {
            value = msg.v2;
        } else {
            value = 0;
        }
    }
}

control SignalSelect(in plant_msg_t msg, inout monitor_md_t m) {
    Level() x;
    Level() plus;
    Level() minus;
    Operand() f0_plus;
    Operand() f0_minus;
    Operand() f0_cmd;
    Operand() f1_plus;
    Operand() f1_minus;
    Operand() f1_cmd;

    apply {
        x.apply(msg, m.signal, m.x);
        m.level = m.x;
        plus.apply(msg, m.aux_plus, m.aux_a);
        minus.apply(msg, m.aux_minus, m.aux_b);
        if (m.aux_a > m.aux_b) {
            m.aux = m.aux_a - m.aux_b;
        } else {
            m.aux = 0;
        }
        // flow term keys: head = f[plus] - f[minus] (16-bit modular), cmd
        bit<16> a;
        bit<16> b;
        f0_plus.apply(msg, m.f0_plus, a);
        f0_minus.apply(msg, m.f0_minus, b);
        m.head0 = a - b;
        f0_cmd.apply(msg, m.f0_cmd, m.cmd0);
        f1_plus.apply(msg, m.f1_plus, a);
        f1_minus.apply(msg, m.f1_minus, b);
        m.head1 = a - b;
        f1_cmd.apply(msg, m.f1_cmd, m.cmd1);
    }
}

#endif  /* _CIVIC_V1MODEL_SIGNAL_SELECT_P4_ */
