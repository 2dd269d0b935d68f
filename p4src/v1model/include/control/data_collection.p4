/*
 * CIVIC v1model -- per-plant history of one monitor slot
 * (docs/pipeline.md sections 2 and 3).
 *
 * Registers (P4Info CivicIngress.monK.<name>, see monitor_config.p4):
 *   ring  bit<16> x MAX_PLANTS * MAX_WINDOW  the last R values of x
 *   ptr   bit<8>  x MAX_PLANTS               next ring cell to overwrite
 *   run   bit<8>  x MAX_PLANTS               contiguous qualifying messages
 *   s0    bit<32> x MAX_PLANTS               sum(ring)
 *   s1    bit<32> x MAX_PLANTS               sum(age * value), age 0 = newest
 *
 * Runs for every plant message when the slot is enabled, qualifying or not:
 *   run = q ? (gap ? 1 : min(run + 1, 255)) : 0
 *   old = ring[ptr]; ring[ptr] = x; ptr = (ptr + 1 == R) ? 0 : ptr + 1
 *   s1  = s1 + s0 - R * old          (s0 before its update)
 *   s0  = s0 + x - old
 * All bit<32> arithmetic is modular, as in the model; with W <= 128 and
 * x <= 65535 the sums never wrap (pipeline.md section 3 bounds).
 *
 * Ring cell of (slot, ptr) = slot * MAX_WINDOW + ptr. The index takes
 * ptr[6:0]: with R <= MAX_WINDOW the pointer is always < R and this is
 * exactly slot * 128 + ptr; the mask only matters if the control plane
 * shrinks R while a plant has state (it should clear the slot's registers
 * when it changes a monitor), and then keeps every plant in its own cells.
 */
#ifndef _CIVIC_V1MODEL_DATA_COLLECTION_P4_
#define _CIVIC_V1MODEL_DATA_COLLECTION_P4_

control DataCollection(in bit<32> slot, in bit<1> gap, inout monitor_md_t m) {

    register<bit<16>>(RING_CELLS) ring;
    register<bit<8>>(MAX_PLANTS) ptr;
    register<bit<8>>(MAX_PLANTS) run;
    register<bit<32>>(MAX_PLANTS) s0;
    register<bit<32>>(MAX_PLANTS) s1;

    apply {
        // run counter: reset on a sequence gap, saturate at RUN_MAX
        run.read(m.run, slot);
        if (m.q == 0) {
            m.run = 0;
        } else if (gap == 1) {
            m.run = 1;
        } else if (m.run != RUN_MAX) {
            m.run = m.run + 1;
        }
        run.write(slot, m.run);

        // ring buffer: swap x in, old out; advance the pointer modulo R
        ptr.read(m.ptr, slot);
        m.ring_idx = (slot << MAX_WINDOW_LOG2) | (bit<32>)(m.ptr & (MAX_WINDOW - 1));
        ring.read(m.old, m.ring_idx);
        ring.write(m.ring_idx, m.x);
        if (m.ptr + 1 == m.ring_len) {
            ptr.write(slot, 0);
        } else {
            ptr.write(slot, m.ptr + 1);
        }

        // running sums (s1 first: it uses s0 before the update)
        s0.read(m.s0, slot);
        s1.read(m.s1, slot);
        m.s1 = m.s1 + m.s0 - (bit<32>)m.ring_len * (bit<32>)m.old;
        m.s0 = m.s0 + (bit<32>)m.x - (bit<32>)m.old;
        s0.write(slot, m.s0);
        s1.write(slot, m.s1);
    }
}

#endif  /* _CIVIC_V1MODEL_DATA_COLLECTION_P4_ */
