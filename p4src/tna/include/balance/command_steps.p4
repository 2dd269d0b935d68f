/*
 * CIVIC TNA, balance profile -- the plant's previous commands and the
 * command steps dp1, dv1, dv2 (pipeline.md sections 2 and 3; the v1model
 * twin is PlantLookup in p4src/v1model/include/control/plant_lookup.p4).
 * Absolute @names: CivicIngress.last_p1 / last_v1 / last_v2, as on v1model.
 */
#ifndef _CIVIC_TNA_COMMAND_STEPS_P4_
#define _CIVIC_TNA_COMMAND_STEPS_P4_

// Command steps (pipeline.md section 3): dp1 = |p1 - last_p1| etc., then
// last_p1 = p1. One RegisterAction per register returns the previous
// command and stores the new one (stage 1, next to last_seq: the four
// stateful ALUs of that stage). A stateful ALU's first operand must be its
// memory, so it cannot give p1 - last; the MAU takes the two saturating
// differences (stage 2), one of which is 0, and ORs them (stage 3):
//   dp1 = (p1 |-| last_p1) | (last_p1 |-| p1) = |p1 - last_p1|
// precondition_cmd (stage 4) and run (stage 5) have the time: the slope
// chain reaches classify in stage 9.
control CommandSteps(in ig_headers_t hdr, inout ig_metadata_t meta) {

    @name(".CivicIngress.last_p1")
    Register<bit<16>, bit<8>>(MAX_PLANTS, 0) last_p1;
    @name(".CivicIngress.last_v1")
    Register<bit<16>, bit<8>>(MAX_PLANTS, 0) last_v1;
    @name(".CivicIngress.last_v2")
    Register<bit<16>, bit<8>>(MAX_PLANTS, 0) last_v2;

    RegisterAction<bit<16>, bit<8>, bit<16>>(last_p1) swap_p1 = {
        void apply(inout bit<16> value, out bit<16> rv) {
            rv = value;
            value = hdr.plant.p1;
        }
    };
    RegisterAction<bit<16>, bit<8>, bit<16>>(last_v1) swap_v1 = {
        void apply(inout bit<16> value, out bit<16> rv) {
            rv = value;
            value = hdr.plant.v1;
        }
    };
    RegisterAction<bit<16>, bit<8>, bit<16>>(last_v2) swap_v2 = {
        void apply(inout bit<16> value, out bit<16> rv) {
            rv = value;
            value = hdr.plant.v2;
        }
    };

    apply {
        meta.last_p1 = swap_p1.execute(meta.slot);
        meta.last_v1 = swap_v1.execute(meta.slot);
        meta.last_v2 = swap_v2.execute(meta.slot);
    }
}

// |cmd - last_cmd| for every frame (only used for plant messages; a frame
// that is not one has last_* = 0 and touches no register)
control CommandStepsAbs(in ig_headers_t hdr, inout ig_metadata_t meta) {
    CIVIC_STEP(up,
               meta.up_p1 = hdr.plant.p1 |-| meta.last_p1;
               meta.up_v1 = hdr.plant.v1 |-| meta.last_v1;
               meta.up_v2 = hdr.plant.v2 |-| meta.last_v2;)
    CIVIC_STEP(down,
               meta.dn_p1 = meta.last_p1 |-| hdr.plant.p1;
               meta.dn_v1 = meta.last_v1 |-| hdr.plant.v1;
               meta.dn_v2 = meta.last_v2 |-| hdr.plant.v2;)
    CIVIC_STEP(either,
               meta.dp1 = meta.up_p1 | meta.dn_p1;
               meta.dv1 = meta.up_v1 | meta.dn_v1;
               meta.dv2 = meta.up_v2 | meta.dn_v2;)

    apply {
        up.apply();
        down.apply();
        either.apply();
    }
}

#endif  /* _CIVIC_TNA_COMMAND_STEPS_P4_ */
