/*
 * CIVIC v1model -- a monitor slot's configuration and its signal x.
 *
 * config is keyless: the control plane sets its default action
 *   set_config(enabled, signal, window, ring_len, lsq)
 * per slot (docs/pipeline.md section 6: signal 0..3 = l1..l4, window W,
 * ring_len R = W for lsq and W - 1 for endpoint, lsq 1/0). The initial
 * default leaves the slot disabled: verdict bits 0 and no register of the
 * slot is touched.
 *
 * Monitor slot k is made of five control instances (MonitorConfig,
 * Precondition, DataCollection, Slope, Classification), all declared in
 * CivicIngress with @name("monK"). p4c prefixes the objects of an inlined
 * instance with the instance's external name, so all of them land in the
 * same P4Info namespace CivicIngress.monK (CivicIngress.monK.config,
 * CivicIngress.monK.ring, ...) although they live in separate controls.
 */
#ifndef _CIVIC_V1MODEL_MONITOR_CONFIG_P4_
#define _CIVIC_V1MODEL_MONITOR_CONFIG_P4_

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
        m.enabled = 0;
        m.cls = CLASS_NOT_EVALUATED;
        config.apply();
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

#endif  /* _CIVIC_V1MODEL_MONITOR_CONFIG_P4_ */
