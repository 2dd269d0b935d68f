/*
 * CIVIC TNA -- the monitored signal x of a monitor slot (see the v1model
 * signal_select.p4).
 *
 * x is also produced zero-extended (x32) and with the slope bias added
 * (x32_b = x + 2^31; x < 2^16 so this is a bit set): the endpoint slope
 * key is then x32_b - old in one subtraction (slope.p4).
 * No table, action or extern here: nothing in the P4Info.
 */
#ifndef _CIVIC_TNA_SIGNAL_SELECT_P4_
#define _CIVIC_TNA_SIGNAL_SELECT_P4_

control SignalSelect(in plant_msg_t msg, inout monitor_md_t m) {
    apply {
        if (m.signal == SIGNAL_L1) {
            m.x = msg.l1;
            m.x32 = 16w0 ++ msg.l1;
            m.x32_b = 16w0x8000 ++ msg.l1;
        } else if (m.signal == SIGNAL_L2) {
            m.x = msg.l2;
            m.x32 = 16w0 ++ msg.l2;
            m.x32_b = 16w0x8000 ++ msg.l2;
        } else if (m.signal == SIGNAL_L3) {
            m.x = msg.l3;
            m.x32 = 16w0 ++ msg.l3;
            m.x32_b = 16w0x8000 ++ msg.l3;
        } else {
            m.x = msg.l4;
            m.x32 = 16w0 ++ msg.l4;
            m.x32_b = 16w0x8000 ++ msg.l4;
        }
        m.level = m.x;
    }
}

#endif  /* _CIVIC_TNA_SIGNAL_SELECT_P4_ */
