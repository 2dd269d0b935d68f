/*
 * CIVIC TNA -- a monitor slot's configuration and its signal x.
 *
 * Same table and action names as v1model (CivicIngress.monK.config,
 * set_config(enabled, signal, window, ring_len, lsq)); on TNA window,
 * ring_len and lsq are compile-time constants (include/config.p4) and the
 * parameters are only stored. The monitor slot's five control instances
 * share @name("monK"), see the v1model monitor_config.p4.
 *
 * x is also produced zero-extended (x32) and with the slope bias added
 * (x32_b = x + 2^31, x < 2^16 so this is a bit set): the endpoint slope
 * key is then x32_b - old in one subtraction (slope.p4).
 */
#ifndef _CIVIC_TNA_MONITOR_CONFIG_P4_
#define _CIVIC_TNA_MONITOR_CONFIG_P4_

control MonitorConfig(in plant_msg_t msg, inout monitor_md_t m) {

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

    apply {
        config.apply();
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

#endif  /* _CIVIC_TNA_MONITOR_CONFIG_P4_ */
