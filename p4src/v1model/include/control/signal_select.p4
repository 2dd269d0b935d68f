/*
 * CIVIC v1model -- the monitored signal x of a monitor slot.
 *
 * set_config(signal) picks one of the four tank volumes (0..3 = l1..l4,
 * docs/pipeline.md section 6). x is also the class table's level key.
 * No table, action or extern here: the instance in Monitor adds nothing
 * to the P4Info.
 */
#ifndef _CIVIC_V1MODEL_SIGNAL_SELECT_P4_
#define _CIVIC_V1MODEL_SIGNAL_SELECT_P4_

control SignalSelect(in plant_msg_t msg, inout monitor_md_t m) {
    apply {
        if (m.signal == SIGNAL_L1) {
            m.x = msg.l1;
        } else if (m.signal == SIGNAL_L2) {
            m.x = msg.l2;
        } else if (m.signal == SIGNAL_L3) {
            m.x = msg.l3;
        } else {
            m.x = msg.l4;
        }
        m.level = m.x;
    }
}

#endif  /* _CIVIC_V1MODEL_SIGNAL_SELECT_P4_ */
