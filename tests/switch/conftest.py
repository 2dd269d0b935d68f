"""The P4Runtime servicer fixture of the switch tests (tests/switch/p4rt_servicer.py)."""
from __future__ import annotations

from concurrent import futures

import grpc
import pytest
from finsy.proto import p4r_grpc as p4runtime_pb2_grpc

from switch.p4rt_servicer import P4RuntimeFixture, load_info


@pytest.fixture
def servicer():
    fx = P4RuntimeFixture(load_info())
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=8))
    p4runtime_pb2_grpc.add_P4RuntimeServicer_to_server(fx, server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    fx.address = f"127.0.0.1:{port}"
    yield fx
    server.stop(grace=None)
