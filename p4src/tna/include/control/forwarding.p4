/*
 * CIVIC TNA -- forwarding: ingress_port -> egress port (see the v1model
 * forwarding.p4). Absolute @name annotations give the P4Info names
 * CivicIngress.forward / .set_egress / .drop, as on v1model.
 */
#ifndef _CIVIC_TNA_FORWARDING_P4_
#define _CIVIC_TNA_FORWARDING_P4_

control Forwarding(in PortId_t ingress_port,
                   inout ingress_intrinsic_metadata_for_tm_t ig_tm_md,
                   inout ingress_intrinsic_metadata_for_deparser_t ig_dprsr_md) {

    @name(".CivicIngress.set_egress")
    action set_egress(PortId_t port) {
        ig_tm_md.ucast_egress_port = port;
    }

    @name(".CivicIngress.drop")
    action drop() {
        ig_dprsr_md.drop_ctl = 1;
    }

    @name(".CivicIngress.forward")
    table forward {
        key = {
            ingress_port: exact @name("ingress_port");
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

#endif  /* _CIVIC_TNA_FORWARDING_P4_ */
