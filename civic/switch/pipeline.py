"""Pipeline build directories (p4c-bm2-ss output) and installing one unless the switch runs it."""
from __future__ import annotations

from pathlib import Path

from finsy.proto import p4r

from civic.errors import CivicError
from civic.switch.connection import SwitchConnection
from civic.switch.schema import SwitchSchema

PIPELINE_JSON = "civic.json"
PIPELINE_P4INFO = ("civic.p4info.txtpb", "civic.p4info.txt", "civic.p4info.txtpb.txt")


def load_pipeline(directory: str | Path) -> SwitchSchema:
    """civic.json + civic.p4info.txtpb from a p4c-bm2-ss build directory, as a schema with its blob."""
    d = Path(directory)
    if not d.is_dir():
        raise CivicError(f"pipeline directory {d} does not exist (build it with p4c-bm2-ss)")
    js = d / PIPELINE_JSON
    info_path = next((d / n for n in PIPELINE_P4INFO if (d / n).is_file()), None)
    if not js.is_file():
        raise CivicError(f"{d}: no {PIPELINE_JSON} (BMv2 JSON from p4c-bm2-ss)")
    if info_path is None:
        raise CivicError(f"{d}: no {PIPELINE_P4INFO[0]} (P4Info from p4c-bm2-ss --p4runtime-files)")
    return SwitchSchema.from_text(info_path.read_text(), str(info_path), js.read_bytes())


def ensure_pipeline(conn: SwitchConnection, pipeline: SwitchSchema | None) -> tuple[SwitchSchema, bool]:
    """Install the pipeline unless the switch already runs it (same cookie); return (schema, pushed).
    Without a pipeline, the schema of the one the switch runs."""
    if pipeline is not None:
        cur = conn.get_pipeline(p4r.GetForwardingPipelineConfigRequest.COOKIE_ONLY)
        if cur is not None and cur.HasField("cookie") and cur.cookie.cookie == pipeline.p4cookie:
            return pipeline, False
        conn.set_pipeline(pipeline.get_pipeline_config())
        return pipeline, True
    cur = conn.get_pipeline()
    if cur is None or not (cur.p4info.tables or cur.p4info.actions or cur.p4info.HasField("pkg_info")):
        raise CivicError(f"switch {conn.address} has no pipeline installed; pass --pipeline build/v1model")
    return SwitchSchema(cur.p4info), False
