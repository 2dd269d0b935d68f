/*
 * CIVIC TNA -- plant message? which plant? sequence gap?
 * (pipeline.md sections 1.3, 1.5, 3; see the v1model plant_lookup.p4).
 *
 * Differences from v1model, for the stage budget: monitored_port and
 * plant_prefix are applied to every frame in parallel (stage 0; they only
 * set flags) and CivicIngress ANDs their hits with hdr.plant.isValid();
 * last_seq is one RegisterAction that returns the gap flag and stores seq
 * in the same access:
 *   gap = (last_seq != seq - 1), last_seq = seq
 * which is seq != last_seq + 1 in 32-bit modular arithmetic.
 * SeqGap is applied by CivicIngress only for plant messages; it also marks
 * the frame as one in the bridge header (egress then writes the verdict).
 */
#ifndef _CIVIC_TNA_PLANT_LOOKUP_P4_
#define _CIVIC_TNA_PLANT_LOOKUP_P4_

control PlantLookup(in ig_headers_t hdr, inout ig_metadata_t meta) {

    @name(".CivicIngress.set_monitored")
    action set_monitored() {
        meta.monitored = 1;
    }

    @name(".CivicIngress.monitored_port")
    table monitored_port {
        key = {
            hdr.udp.dst_port: exact @name("dst_port");
        }
        actions = {
            set_monitored;
            @defaultonly NoAction;
        }
        default_action = NoAction();
        size = MONITORED_PORT_TABLE_SIZE;
    }

    @name(".CivicIngress.set_plant")
    action set_plant() {
        meta.in_prefix = 1;
        meta.slot = hdr.ipv4.src_addr[7:0];
    }

    @name(".CivicIngress.plant_prefix")
    table plant_prefix {
        key = {
            hdr.ipv4.src_addr: lpm @name("src_addr");
        }
        actions = {
            set_plant;
            @defaultonly NoAction;
        }
        default_action = NoAction();
        size = PLANT_PREFIX_TABLE_SIZE;
    }

    apply {
        meta.seq_m1 = hdr.plant.seq - 1;
        monitored_port.apply();
        plant_prefix.apply();
    }
}

control SeqGap(inout ig_headers_t hdr, inout ig_metadata_t meta) {

    @name(".CivicIngress.last_seq")
    Register<bit<32>, bit<8>>(MAX_PLANTS, 0) last_seq;

    RegisterAction<bit<32>, bit<8>, bit<1>>(last_seq) check_and_store = {
        void apply(inout bit<32> value, out bit<1> gap) {
            if (value == meta.seq_m1) {
                gap = 0;
            } else {
                gap = 1;
            }
            value = hdr.plant.seq;
        }
    };

    apply {
        meta.gap = check_and_store.execute(meta.slot);
        hdr.bridge.plant = 1;
    }
}

#endif  /* _CIVIC_TNA_PLANT_LOOKUP_P4_ */
