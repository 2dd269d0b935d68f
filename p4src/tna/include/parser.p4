/*
 * CIVIC TNA -- ingress/egress parsers and deparsers (pipeline.md section 1).
 *
 * Same header walk as the v1model parser: ethernet -> ipv4 (version 4,
 * IHL 5, UDP, not a fragment) -> udp (length 28) -> plant_msg, accept as
 * soon as the frame cannot be a plant message; unparsed bytes (other
 * payloads, Ethernet padding, trailers) stay payload and are not touched.
 *
 * Ingress prepends the bridge header (metadata.p4); the egress parser takes
 * it off again and re-parses the frame, which ingress did not modify.
 * Egress writes the verdict and the UDP checksum (verdict.p4).
 *
 * Short frames: a frame that ends inside the plant message cannot be
 * extracted; whether Tofino then continues with hdr.plant invalid (as
 * BMv2 does) depends on the parser error handling of the target (see
 * p4src/README.md, TNA limitations). On Ethernet a 62-byte plant frame is
 * always complete (minimum frame 60 bytes + FCS).
 */
#ifndef _CIVIC_TNA_PARSER_P4_
#define _CIVIC_TNA_PARSER_P4_

parser CivicIngressParser(packet_in pkt,
                          out ig_headers_t hdr,
                          out ig_metadata_t meta,
                          out ingress_intrinsic_metadata_t ig_intr_md) {

    state start {
        pkt.extract(ig_intr_md);
        pkt.advance(PORT_METADATA_SIZE);
        hdr.bridge.setValid();
        hdr.bridge.pad = 0;
        hdr.bridge.plant = 0;
        hdr.bridge.pad1 = 0;
        hdr.bridge.pad0 = 0;
        hdr.bridge.cls1 = CLASS_NOT_EVALUATED;
        hdr.bridge.cls0 = CLASS_NOT_EVALUATED;
        meta.monitored = 0;
        meta.in_prefix = 0;
        meta.gap = 0;
#ifdef CIVIC_PROFILE_BALANCE
        // the flow terms add to e and band (balance.p4); w and chg gate
        // last_class and the digest; zero is the operand "zero"
        meta.mon2.e = 0;
        meta.mon2.band = 0;
        meta.mon2.w = 0;
        meta.mon2.chg = 0;
        meta.mon3.e = 0;
        meta.mon3.band = 0;
        meta.mon3.w = 0;
        meta.mon3.chg = 0;
        meta.zero = 0;
#endif
        transition parse_ethernet;
    }

    state parse_ethernet {
        pkt.extract(hdr.ethernet);
        transition select(hdr.ethernet.ether_type) {
            ETHERTYPE_IPV4: parse_ipv4;
            default: accept;
        }
    }

    state parse_ipv4 {
        pkt.extract(hdr.ipv4);
        transition select(hdr.ipv4.version, hdr.ipv4.ihl, hdr.ipv4.protocol,
                          hdr.ipv4.flag_mf, hdr.ipv4.frag_offset) {
            (IPV4_VERSION, IPV4_IHL_NO_OPTIONS, IP_PROTO_UDP, 0, 0): parse_udp;
            default: accept;
        }
    }

    state parse_udp {
        pkt.extract(hdr.udp);
        transition select(hdr.udp.len) {
            UDP_LEN_PLANT: parse_plant_msg;
            default: accept;
        }
    }

    state parse_plant_msg {
        pkt.extract(hdr.plant);
        transition accept;
    }
}

control CivicIngressDeparser(packet_out pkt,
                             inout ig_headers_t hdr,
                             in ig_metadata_t meta,
                             in ingress_intrinsic_metadata_for_deparser_t ig_dprsr_md) {
#ifdef CIVIC_PROFILE_BALANCE
    Digest<verdict_change_balance_t>() verdict_change;
#else
    Digest<verdict_change_tna_t>() verdict_change;
#endif

    apply {
        if (ig_dprsr_md.digest_type == DIGEST_VERDICT_CHANGE) {
#ifdef CIVIC_PROFILE_BALANCE
            // monitors 2 and 3; levels: balance_t3 watches l3, balance_t1 l1
            verdict_change.pack({hdr.ipv4.src_addr, hdr.plant.seq, meta.mon2.chg, meta.mon3.chg,
                                 hdr.bridge.cls0, hdr.bridge.cls1,
                                 meta.mon2.slope_key, meta.mon2.band_w, hdr.plant.l3,
                                 meta.mon3.slope_key, meta.mon3.band_w, hdr.plant.l1});
#else
            verdict_change.pack({hdr.ipv4.src_addr, hdr.plant.seq, meta.mon0.chg, meta.mon1.chg,
                                 hdr.bridge.cls0, hdr.bridge.cls1,
                                 meta.mon0.slope_key, meta.mon0.aux, meta.mon0.x,
                                 meta.mon1.slope_key, meta.mon1.aux, meta.mon1.x});
#endif
        }
        pkt.emit(hdr.bridge);
        pkt.emit(hdr.ethernet);
        pkt.emit(hdr.ipv4);
        pkt.emit(hdr.udp);
        pkt.emit(hdr.plant);
    }
}

parser CivicEgressParser(packet_in pkt,
                         out eg_headers_t hdr,
                         out eg_metadata_t meta,
                         out egress_intrinsic_metadata_t eg_intr_md) {

    state start {
        pkt.extract(eg_intr_md);
        pkt.extract(meta.bridge);
        transition parse_ethernet;
    }

    state parse_ethernet {
        pkt.extract(hdr.ethernet);
        transition select(hdr.ethernet.ether_type) {
            ETHERTYPE_IPV4: parse_ipv4;
            default: accept;
        }
    }

    state parse_ipv4 {
        pkt.extract(hdr.ipv4);
        transition select(hdr.ipv4.version, hdr.ipv4.ihl, hdr.ipv4.protocol,
                          hdr.ipv4.flag_mf, hdr.ipv4.frag_offset) {
            (IPV4_VERSION, IPV4_IHL_NO_OPTIONS, IP_PROTO_UDP, 0, 0): parse_udp;
            default: accept;
        }
    }

    state parse_udp {
        pkt.extract(hdr.udp);
        transition select(hdr.udp.len) {
            UDP_LEN_PLANT: parse_plant_msg;
            default: accept;
        }
    }

    state parse_plant_msg {
        pkt.extract(hdr.plant);
        transition accept;
    }
}

control CivicEgressDeparser(packet_out pkt,
                            inout eg_headers_t hdr,
                            in eg_metadata_t meta,
                            in egress_intrinsic_metadata_for_deparser_t eg_dprsr_md) {
    apply {
        // The bridge header lives in eg_metadata_t and is not emitted.
        pkt.emit(hdr.ethernet);
        pkt.emit(hdr.ipv4);
        pkt.emit(hdr.udp);
        pkt.emit(hdr.plant);
    }
}

#endif  /* _CIVIC_TNA_PARSER_P4_ */
