/*
 * CIVIC TNA -- precondition and class tables of one monitor slot (see the
 * v1model classification.p4; same names, keys and actions).
 *
 * set_class writes the class straight into the slot's field of the bridge
 * header (cls_out), from which egress builds the verdict word; a slot that
 * is not evaluated keeps the 0 the ingress parser put there.
 * Gate: run >= W with W the compile-time window of the slot.
 * Range keys become TCAM range expansions on Tofino (costly): the tables
 * are sized in include/config.p4.
 */
#ifndef _CIVIC_TNA_CLASSIFICATION_P4_
#define _CIVIC_TNA_CLASSIFICATION_P4_

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
        size = TNA_PRECONDITION_TABLE_SIZE;
    }

    apply {
        precondition.apply();
    }
}

control Classification(inout monitor_md_t m, inout bit<2> cls_out)(bit<8> window) {

    action set_class(bit<2> cls) {
        cls_out = cls;
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
        size = TNA_CLASSIFY_TABLE_SIZE;
    }

    apply {
        if (m.run >= window) {
            classify.apply();
        }
    }
}

#endif  /* _CIVIC_TNA_CLASSIFICATION_P4_ */
