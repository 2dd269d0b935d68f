/*
 * CIVIC v1model -- the signals a monitor slot reads from the message.
 *
 * set_config(signal) picks the monitored x, one of the four tank volumes
 * (0..3 = l1..l4, docs/pipeline.md section 6); x is also the class table's
 * level key. set_config(aux_plus, aux_minus) pick the two levels whose
 * difference drives the tank's inflow (section 3a):
 *   aux = max(x[aux_plus] - x[aux_minus], 0)   (16 bit, saturating at 0)
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

control SignalSelect(in plant_msg_t msg, inout monitor_md_t m) {
    Level() x;
    Level() plus;
    Level() minus;

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
    }
}

#endif  /* _CIVIC_V1MODEL_SIGNAL_SELECT_P4_ */
