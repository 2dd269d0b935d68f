/*
 * CIVIC v1model -- precondition and class tables of one monitor slot
 * (docs/pipeline.md sections 3, 4 and 6).
 *
 * precondition: seven 16-bit range keys l1, l2, l3, l4, p1, v1, v2
 *   -> qualify() (q = 1); miss -> disqualify() (q = 0). The control plane
 *   installs one entry whose unconstrained fields are [0, 65535].
 *   Applied to every plant message of an enabled slot, before the run
 *   counter is updated.
 *
 * classify: range keys slope_key (bit<32>) and level (bit<16>, = x)
 *   -> set_class(cls); the default action is set_class(default_class), set
 *   by the control plane (initially CLASS_DEFAULT = error). Applied only
 *   when run >= W, i.e. the last W messages were contiguous and qualified;
 *   otherwise the slot's verdict bits stay 0 (not evaluated). Entries never
 *   overlap (the control plane checks), priorities are still required.
 */
#ifndef _CIVIC_V1MODEL_CLASSIFICATION_P4_
#define _CIVIC_V1MODEL_CLASSIFICATION_P4_

control Precondition(in plant_msg_t msg, inout monitor_md_t m) {

    action qualify() {
        m.q = 1;
    }

    action disqualify() {
        m.q = 0;
    }

    table precondition {
        key = {
            msg.l1: range @name("l1");
            msg.l2: range @name("l2");
            msg.l3: range @name("l3");
            msg.l4: range @name("l4");
            msg.p1: range @name("p1");
            msg.v1: range @name("v1");
            msg.v2: range @name("v2");
        }
        actions = {
            qualify;
            disqualify;
        }
        default_action = disqualify();
        size = PRECONDITION_TABLE_SIZE;
    }

    apply {
        m.q = 0;
        precondition.apply();
    }
}

control Classification(inout monitor_md_t m) {

    action set_class(bit<2> cls) {
        m.cls = cls;
    }

    table classify {
        key = {
            m.slope_key: range @name("slope_key");
            m.level: range @name("level");
        }
        actions = {
            set_class;
        }
        default_action = set_class(CLASS_DEFAULT);
        size = CLASSIFY_TABLE_SIZE;
    }

    apply {
        m.cls = CLASS_NOT_EVALUATED;
        if (m.run >= m.window) {
            classify.apply();
        }
    }
}

#endif  /* _CIVIC_V1MODEL_CLASSIFICATION_P4_ */
