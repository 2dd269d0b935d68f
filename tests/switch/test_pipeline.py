"""Installing the pipeline: once per build, and with the legacy wrapper old PI builds want."""
from __future__ import annotations

import json
from concurrent import futures

import grpc
import pytest
from finsy.proto import p4r as p4runtime_pb2
from finsy.proto import p4r_grpc as p4runtime_pb2_grpc

from civic.cli import main
from civic.errors import CivicError
from civic.switch.converge import configure

from switch.p4rt_servicer import (
    FIXTURE_P4INFO,
    P4RuntimeFixture,
    entries_file,
    load_info,
)


def test_pipeline_pushed_once(tmp_path):
    fx = P4RuntimeFixture(None)     # no pipeline yet
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4))
    p4runtime_pb2_grpc.add_P4RuntimeServicer_to_server(fx, server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    addr = f"127.0.0.1:{port}"
    try:
        path = entries_file(tmp_path)
        with pytest.raises(CivicError, match="has no pipeline installed; pass --pipeline"):
            configure(addr, path)
        build = tmp_path / "build"
        build.mkdir()
        (build / "civic.json").write_text('{"program": "civic.p4"}')
        (build / "civic.p4info.txtpb").write_text(FIXTURE_P4INFO.read_text())
        res = configure(addr, path, build)
        assert res.pipeline_pushed and res.added == 11
        (req,) = fx.pipelines
        assert req.action == p4runtime_pb2.SetForwardingPipelineConfigRequest.VERIFY_AND_COMMIT
        assert req.config.p4_device_config == b'{"program": "civic.p4"}'
        assert req.config.p4info == load_info() and req.config.cookie.cookie != 0
        res = configure(addr, path, build)       # same pipeline: not pushed again, nothing written
        assert not res.pipeline_pushed and res.writes == 0 and len(fx.pipelines) == 1
        assert main(["configure", "--switch", addr, "--entries", str(path), "--pipeline", str(tmp_path / "nope")]) == 2
    finally:
        server.stop(grace=None)


def test_pipeline_for_pi_builds_that_want_the_legacy_wrapper(tmp_path):
    fx = P4RuntimeFixture(None)
    fx.legacy_device_config = True
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4))
    p4runtime_pb2_grpc.add_P4RuntimeServicer_to_server(fx, server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    try:
        build = tmp_path / "build"
        build.mkdir()
        blob = json.dumps({"program": "civic.p4", "pad": "x" * 300}).encode()    # > 127 bytes: 2-byte varint
        (build / "civic.json").write_bytes(blob)
        (build / "civic.p4info.txtpb").write_text(FIXTURE_P4INFO.read_text())
        res = configure(f"127.0.0.1:{port}", entries_file(tmp_path), build)
        assert res.pipeline_pushed and res.added == 11
        assert [p.config.p4_device_config[:1] for p in fx.pipelines] == [b"{", b"\x08"]   # raw, then wrapped
        assert fx.device_data == blob
    finally:
        server.stop(grace=None)
