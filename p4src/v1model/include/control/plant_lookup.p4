/*
 * CIVIC v1model -- is this frame a plant message, which plant, and did
 * the plant skip sequence numbers? (pipeline.md sections 1.3, 1.5, 3)
 *
 * Applied only when the parser extracted a complete plant message
 * (hdr.plant valid: IPv4/UDP, no options, not a fragment, UDP length 28).
 *
 *   monitored_port  hdr.udp.dst_port exact -> set_monitored()
 *   plant_prefix    hdr.ipv4.src_addr lpm  -> set_plant(), slot = src[7:0]
 *   last_seq        register, one 32-bit cell per slot
 *
 * A frame is a plant message when both tables hit; only then is last_seq
 * read and written. gap = (seq != last_seq + 1) in 32-bit modular
 * arithmetic, so 0xFFFFFFFF -> 0 is not a gap; every cell starts at 0, so
 * a plant's first message with seq 1 is not a gap either (as in the model).
 *
 * Names: absolute @name, see forwarding.p4.
 */
#ifndef _CIVIC_V1MODEL_PLANT_LOOKUP_P4_
#define _CIVIC_V1MODEL_PLANT_LOOKUP_P4_

control PlantLookup(in headers_t hdr, inout local_metadata_t meta) {

    @name(".CivicIngress.last_seq")
    register<bit<32>>(MAX_PLANTS) last_seq;
    // the plant's previous commands: the precondition's command steps
    @name(".CivicIngress.last_p1")
    register<bit<16>>(MAX_PLANTS) last_p1;
    @name(".CivicIngress.last_v1")
    register<bit<16>>(MAX_PLANTS) last_v1;
    @name(".CivicIngress.last_v2")
    register<bit<16>>(MAX_PLANTS) last_v2;

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
        meta.plant = 1;
        meta.slot = (bit<32>)hdr.ipv4.src_addr[7:0];
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
        default_action = NoAction();     // outside every prefix: not a plant
        size = PLANT_PREFIX_TABLE_SIZE;
    }

    apply {
        meta.monitored = 0;
        meta.plant = 0;
        meta.gap = 0;
        meta.dp1 = 0;
        meta.dv1 = 0;
        meta.dv2 = 0;
        monitored_port.apply();
        if (meta.monitored == 1) {
            plant_prefix.apply();
        }
        if (meta.plant == 1) {
            last_seq.read(meta.last_seq, meta.slot);
            if (hdr.plant.seq != meta.last_seq + 1) {
                meta.gap = 1;
            }
            last_seq.write(meta.slot, hdr.plant.seq);

            // command steps |u - last_u| (pipeline.md section 3)
            bit<16> last;
            last_p1.read(last, meta.slot);
            meta.dp1 = hdr.plant.p1 > last ? hdr.plant.p1 - last : last - hdr.plant.p1;
            last_p1.write(meta.slot, hdr.plant.p1);
            last_v1.read(last, meta.slot);
            meta.dv1 = hdr.plant.v1 > last ? hdr.plant.v1 - last : last - hdr.plant.v1;
            last_v1.write(meta.slot, hdr.plant.v1);
            last_v2.read(last, meta.slot);
            meta.dv2 = hdr.plant.v2 > last ? hdr.plant.v2 - last : last - hdr.plant.v2;
            last_v2.write(meta.slot, hdr.plant.v2);
        }
    }
}

#endif  /* _CIVIC_V1MODEL_PLANT_LOOKUP_P4_ */
