// Baseline for `make bench`: the least a v1model program can do with a frame
// (port 1 <-> port 2, nothing parsed), so civic.p4's cost shows as a ratio.
#include <core.p4>
#include <v1model.p4>

struct headers_t {}
struct meta_t {}

parser ForwardParser(packet_in pkt, out headers_t hdr, inout meta_t meta,
                     inout standard_metadata_t sm) {
    state start { transition accept; }
}
control NoVerify(inout headers_t hdr, inout meta_t meta) { apply {} }
control ForwardIngress(inout headers_t hdr, inout meta_t meta, inout standard_metadata_t sm) {
    apply { sm.egress_spec = (sm.ingress_port == 1) ? (bit<9>)2 : (bit<9>)1; }
}
control NoEgress(inout headers_t hdr, inout meta_t meta, inout standard_metadata_t sm) { apply {} }
control NoCompute(inout headers_t hdr, inout meta_t meta) { apply {} }
control ForwardDeparser(packet_out pkt, in headers_t hdr) { apply {} }

V1Switch(ForwardParser(), NoVerify(), ForwardIngress(), NoEgress(), NoCompute(), ForwardDeparser()) main;
