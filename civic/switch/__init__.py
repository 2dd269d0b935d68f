"""Everything that talks to a switch: P4Runtime through finsy, CIVIC's entries and converge on top.

schema      the program's control-plane names; lookups in its P4Info (finsy's P4Schema)
pipeline    pipeline build directories; installing one unless the switch runs it
desired     the table entries and default actions an entries file asks for
connection  one P4Runtime session (finsy's P4Client): arbitration, pipeline, Read, Write, stream
converge    diff desired vs read-back, write with rollback, verify; `configure`
registers   per-plant register state (`civic configure --read`)
digests     the verdict-change digest (`civic watch`)
counters    the verdict counters (`civic watch`)
bmv2        simple_switch_grpc in a network namespace; `--target bmv2`
"""
