/*
 * CIVIC v1model -- forwarding: a port-to-port patch panel.
 *
 * CIVIC sits on the path between the plant gateway and the controller; the
 * control plane installs ingress_port -> egress port pairs. Every frame,
 * plant message or not, is forwarded by this table; a port without an
 * entry drops (default action). Dropping does not undo state updates of a
 * plant message: the verdict logic does not depend on where a frame goes.
 *
 * The objects carry absolute @name annotations (leading dot) so that their
 * P4Info names are CivicIngress.<name>, as if they were declared directly
 * in CivicIngress: p4c's inliner keeps a name starting with '.' unchanged
 * instead of prefixing it with the instance name (ComputeNewNames in
 * frontends/p4/inlining.cpp), and the P4Info drops the leading dot.
 */
#ifndef _CIVIC_V1MODEL_FORWARDING_P4_
#define _CIVIC_V1MODEL_FORWARDING_P4_

control Forwarding(inout standard_metadata_t standard_metadata) {

    @name(".CivicIngress.set_egress")
    action set_egress(bit<9> port) {
        standard_metadata.egress_spec = port;
    }

    @name(".CivicIngress.drop")
    action drop() {
        mark_to_drop(standard_metadata);
    }

    @name(".CivicIngress.forward")
    table forward {
        key = {
            standard_metadata.ingress_port: exact @name("ingress_port");
        }
        actions = {
            set_egress;
            drop;
        }
        default_action = drop();
        size = FORWARD_TABLE_SIZE;
    }

    apply {
        forward.apply();
    }
}

#endif  /* _CIVIC_V1MODEL_FORWARDING_P4_ */
