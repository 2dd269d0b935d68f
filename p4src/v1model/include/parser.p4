/*
 * CIVIC v1model -- parser and deparser (pipeline.md section 1).
 *
 * The parser goes ethernet -> ipv4 -> udp -> plant_msg and stops (accept)
 * as soon as a frame cannot be a plant message. Whatever it did not
 * extract stays payload, and the deparser emits only valid headers, then
 * the payload: a frame that is not a plant message leaves byte-identical.
 *
 * Short frames: if the frame ends inside a header, BMv2's extract throws
 * PacketTooShort *before* it marks the header valid (check_enough_data_for
 * _extract in bm_sim/parser.cpp), records standard_metadata.parser_error
 * and continues with ingress; the bytes of the header it could not extract
 * stay in the payload. So a frame shorter than 62 bytes whose UDP length
 * says 28 has hdr.plant invalid: it touches no state and is forwarded
 * unchanged. Nothing in this program drops on parser_error.
 */
#ifndef _CIVIC_V1MODEL_PARSER_P4_
#define _CIVIC_V1MODEL_PARSER_P4_

parser CivicParser(packet_in packet,
                   out headers_t hdr,
                   inout local_metadata_t meta,
                   inout standard_metadata_t standard_metadata) {

    state start {
        packet.extract(hdr.ethernet);
        transition select(hdr.ethernet.ether_type) {
            ETHERTYPE_IPV4: parse_ipv4;
            default: accept;          // ARP, VLAN-tagged, IPv6, ...
        }
    }

    state parse_ipv4 {
        packet.extract(hdr.ipv4);
        // Plant messages are IPv4 without options, UDP, not a fragment.
        // Anything else: the IPv4 header is re-emitted unchanged and its
        // options / payload follow as packet payload.
        transition select(hdr.ipv4.version, hdr.ipv4.ihl, hdr.ipv4.protocol,
                          hdr.ipv4.flag_mf, hdr.ipv4.frag_offset) {
            (IPV4_VERSION, IPV4_IHL_NO_OPTIONS, IP_PROTO_UDP, 0, 0): parse_udp;
            default: accept;
        }
    }

    state parse_udp {
        packet.extract(hdr.udp);
        // Payload exactly 20 bytes. The destination port is checked by the
        // monitored_port table (it is configurable at run time).
        transition select(hdr.udp.len) {
            UDP_LEN_PLANT: parse_plant_msg;
            default: accept;
        }
    }

    state parse_plant_msg {
        packet.extract(hdr.plant);
        transition accept;            // trailer / padding bytes stay payload
    }
}

control CivicDeparser(packet_out packet, in headers_t hdr) {
    apply {
        // emit() of an invalid header emits nothing.
        packet.emit(hdr.ethernet);
        packet.emit(hdr.ipv4);
        packet.emit(hdr.udp);
        packet.emit(hdr.plant);
    }
}

#endif  /* _CIVIC_V1MODEL_PARSER_P4_ */
