"""The verdict-change digest (docs/pipeline.md section 7), as `civic watch` uses it."""
from __future__ import annotations

from finsy import P4DigestEntry, P4DigestList
from finsy.proto import p4r

from civic.errors import CivicError
from civic.switch.connection import SwitchConnection, WriteRejected
from civic.switch.schema import DIGEST_VERDICT_CHANGE, SwitchSchema


def enable_digest(conn: SwitchConnection, schema: SwitchSchema, max_timeout_ns: int = 1_000_000,
                  max_list_size: int = 64, ack_timeout_ns: int = 1_000_000_000) -> None:
    """Ask the switch to send the verdict-change digest (INSERT, or MODIFY if already configured)."""
    schema.digest(DIGEST_VERDICT_CHANGE)

    def entry() -> P4DigestEntry:      # finsy's +/~ mark the object itself: one per update
        return P4DigestEntry(DIGEST_VERDICT_CHANGE, max_timeout_ns=max_timeout_ns, max_list_size=max_list_size,
                             ack_timeout_ns=ack_timeout_ns)
    try:
        conn.write([(+entry()).encode_update(schema)])
    except WriteRejected:
        try:
            conn.write([(~entry()).encode_update(schema)])
        except WriteRejected as exc:
            raise CivicError(f"switch {conn.address}: cannot enable the verdict digest: {exc.summary}") from None


def digest_members(msg: p4r.StreamMessageResponse, schema: SwitchSchema) -> list[dict[str, int]]:
    """The verdict_change_t structs of one digest list message, as {member: value}."""
    try:
        return P4DigestList.decode(msg, schema).data
    except ValueError as exc:
        raise CivicError(f"digest {DIGEST_VERDICT_CHANGE}: {exc}") from None
