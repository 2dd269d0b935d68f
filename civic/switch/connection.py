"""One P4Runtime session on finsy's P4Client, for synchronous callers.

finsy's client is asyncio; a `SwitchConnection` runs it on an event loop in a
thread of its own, so `civic configure`, `civic watch` and the BMv2 target call
it like a function. finsy gives the channel, the stream and the error details;
CIVIC adds arbitration as a one-shot check (not primary is a one-line error
naming the election id), a connect timeout (an unreachable switch is one line
after `timeout` s), its own deadlines, per-update outcomes of a rejected Write
(`WriteRejected`, for rollback) and the legacy device config wrapper old PI
builds want.
"""
from __future__ import annotations

import asyncio
import queue
import threading

import grpc
from finsy import P4Client, P4ClientError
from finsy.grpcutil import GRPCStatusCode
from finsy.proto import p4r, p4r_grpc, rpc_code

from civic.errors import CivicError

UNREACHABLE = (GRPCStatusCode.UNAVAILABLE, GRPCStatusCode.DEADLINE_EXCEEDED)
RPC_TIMEOUT = 30.0     # s, for Read, Write and pipeline requests (the connect timeout is the caller's)


class WriteRejected(Exception):
    """A Write the switch refused: per-update (index, code name, message) for failed updates."""

    def __init__(self, failed: list, applied: list, summary: str):
        super().__init__(summary)
        self.failed = failed      # [(index or None for the whole batch, code name, message)]
        self.applied = applied    # indices of updates the switch applied
        self.summary = summary


class Unsupported(CivicError):
    """The switch does not implement this P4Runtime operation (e.g. registers on BMv2)."""


def legacy_device_config(device_data: bytes) -> bytes:
    """p4.tmp.P4DeviceConfig{reassign: true, device_data} serialized (PI's proto/p4/tmp/p4config.proto:
    bool reassign = 1; Extras extras = 2; bytes device_data = 3), for PI builds that require it."""
    n, size = len(device_data), bytearray()
    while True:
        size.append((n & 0x7F) | (0x80 if n >> 7 else 0))
        n >>= 7
        if not n:
            return b"\x08\x01\x1a" + bytes(size) + device_data


class SwitchConnection:
    """Arbitration, pipeline, Read, Write and the stream of one switch; a context manager."""

    def __init__(self, address: str, device_id: int = 0, election_id: int = 1, timeout: float = 5.0,
                 padded_bytes: bool = False, arbitrate: bool = True):
        self.address = address
        self.arbitrate = arbitrate         # False: read-only session, no StreamChannel (Read needs none)
        self.padded_bytes = padded_bytes   # send full-width byte strings instead of canonical ones
        self.device_id = device_id
        self.election_id = election_id
        self.timeout = timeout
        self.primary = False
        self._client: P4Client | None = None
        self._stub: p4r_grpc.P4RuntimeStub | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._reader = None
        self._closing = False
        self._responses: queue.Queue = queue.Queue()

    def __enter__(self) -> "SwitchConnection":
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _serve(self) -> None:
        """The session thread: run the event loop until close() stops it."""
        self._loop.run_forever()
        self._loop.close()

    def _loop_error(self, loop, context) -> None:
        """While the session closes, gRPC's poller may still fire on a descriptor it has just
        closed ("Bad file descriptor"): not an error of ours, not for the user's terminal."""
        if not self._closing:
            loop.default_exception_handler(context)

    def _run(self, coro):
        """Run a coroutine on the session's event loop and wait for its result."""
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result()

    def _request(self, msg, timeout: float | None = None):
        """One unary (or, for Read, server-streaming) RPC with our device and election ids.

        It goes through the stub on finsy's channel, not `P4Client.request`, whose deadline is a
        fixed 10 s: a Write of a full entries file can take longer on a slow server.
        """
        if isinstance(msg, (p4r.WriteRequest, p4r.SetForwardingPipelineConfigRequest)):
            msg.election_id.high, msg.election_id.low = self.election_id >> 64, self.election_id & (2**64 - 1)
        if "device_id" in msg.DESCRIPTOR.fields_by_name:
            msg.device_id = self.device_id
        rpc = getattr(self._stub, type(msg).__name__.removesuffix("Request"))
        deadline = timeout or max(self.timeout, RPC_TIMEOUT)

        async def call():
            try:
                if isinstance(msg, p4r.ReadRequest):
                    return [e async for resp in rpc(msg, timeout=deadline) for e in resp.entities]
                # the connect probe waits for the channel to come up; the rest fail fast
                return await rpc(msg, timeout=deadline, wait_for_ready=isinstance(msg, p4r.CapabilitiesRequest))
            except grpc.RpcError as exc:
                raise P4ClientError(exc, type(msg).__name__, msg=msg) from None
        return self._run(call())

    # -- session
    def connect(self) -> None:
        self._loop = asyncio.new_event_loop()
        self._loop.set_exception_handler(self._loop_error)
        self._closing = False
        self._thread = threading.Thread(target=self._serve, name="p4rt-loop", daemon=True)
        self._thread.start()
        self._client = P4Client(self.address)
        self._run(self._client.open())
        self._stub = p4r_grpc.P4RuntimeStub(self._client.channel)
        try:   # any answer, even UNIMPLEMENTED, means a server is there
            self._request(p4r.CapabilitiesRequest(), timeout=self.timeout)
        except P4ClientError as exc:
            if exc.code in UNREACHABLE:
                self.close()
                raise CivicError(f"cannot reach switch {self.address} (no P4Runtime server answered "
                                 f"within {self.timeout:g} s)") from None
        if not self.arbitrate:
            return
        req = p4r.StreamMessageRequest()
        req.arbitration.device_id = self.device_id
        req.arbitration.election_id.high = self.election_id >> 64
        req.arbitration.election_id.low = self.election_id & (2**64 - 1)
        try:
            self._run(self._client.send(req))
        except P4ClientError as exc:
            self.close()
            raise self._error("arbitration", exc) from None
        self._reader = asyncio.run_coroutine_threadsafe(self._read_stream(), self._loop)
        while True:
            try:
                msg = self.next_stream_message(self.timeout)
            except CivicError as exc:
                self.close()
                raise CivicError(f"{exc} during arbitration") from None
            if msg is None:
                self.close()
                raise CivicError(f"switch {self.address}: no arbitration answer within {self.timeout:g} s")
            if msg.HasField("arbitration"):
                return

    async def _read_stream(self) -> None:
        try:
            while True:
                self._responses.put(await self._client.receive())
        except P4ClientError as exc:
            self._responses.put(exc)
        except RuntimeError:      # finsy: the server ended the stream
            pass
        finally:
            self._responses.put(None)

    def close(self) -> None:
        if self._loop is None:
            return
        self._closing = True
        if self._reader is not None:
            self._reader.cancel()
            self._reader = None
        if self._client is not None:
            self._run(self._client.close())
            self._client = self._stub = None
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join()
        self._loop = self._thread = None

    # -- stream (digests, arbitration updates)
    def next_stream_message(self, timeout: float):
        """The next StreamChannel message (digest lists, arbitration updates), None after `timeout`
        s of silence. Arbitration updates also update `primary`. A closed stream is a CivicError."""
        try:
            msg = self._responses.get(timeout=timeout)
        except queue.Empty:
            return None
        if isinstance(msg, P4ClientError):
            raise self._error("stream", msg)
        if msg is None:
            self._responses.put(None)           # stays closed for every later call
            raise CivicError(f"switch {self.address}: the P4Runtime stream closed")
        if msg.HasField("arbitration"):
            self.primary = msg.arbitration.status.code == rpc_code.OK
        return msg

    def ack_digest(self, digest_list: p4r.DigestList) -> None:
        req = p4r.StreamMessageRequest()
        req.digest_ack.digest_id = digest_list.digest_id
        req.digest_ack.list_id = digest_list.list_id
        self._run(self._client.send(req))

    def require_primary(self) -> None:
        if not self.arbitrate:
            raise CivicError("internal: a read-only session cannot write")
        if not self.primary:
            raise CivicError(f"switch {self.address} device {self.device_id}: another controller is primary "
                             f"(election id above {self.election_id}); pass a higher --election-id")

    def _error(self, what: str, exc: P4ClientError) -> CivicError:
        if exc.code in UNREACHABLE:
            return CivicError(f"cannot reach switch {self.address} ({what}: {exc.code.name})")
        detail = exc.message.strip().splitlines()
        return CivicError(f"switch {self.address}: {what} failed: {exc.code.name}: "
                          f"{detail[0] if detail else ''}".rstrip(": "))

    # -- pipeline
    def get_pipeline(self, response_type=p4r.GetForwardingPipelineConfigRequest.P4INFO_AND_COOKIE):
        """The installed pipeline config, None if there is none."""
        try:
            return self._request(p4r.GetForwardingPipelineConfigRequest(response_type=response_type)).config
        except P4ClientError as exc:
            if exc.code == GRPCStatusCode.FAILED_PRECONDITION:
                return None
            raise self._error("GetForwardingPipelineConfig", exc) from None

    def set_pipeline(self, config: p4r.ForwardingPipelineConfig) -> None:
        """VERIFY_AND_COMMIT. The BMv2 JSON goes as is; PI builds that only take the deprecated
        p4.tmp.P4DeviceConfig wrapper say so (INVALID_ARGUMENT) and get it on a second try."""
        self.require_primary()
        req = p4r.SetForwardingPipelineConfigRequest(
            action=p4r.SetForwardingPipelineConfigRequest.VERIFY_AND_COMMIT, config=config)
        try:
            self._request(req)
            return
        except P4ClientError as exc:
            if exc.code != GRPCStatusCode.INVALID_ARGUMENT or "P4DeviceConfig" not in exc.message:
                raise self._error("SetForwardingPipelineConfig", exc) from None
        req.config.p4_device_config = legacy_device_config(config.p4_device_config)
        try:
            self._request(req)
        except P4ClientError as exc:
            raise self._error("SetForwardingPipelineConfig", exc) from None

    # -- read / write
    def read(self, entities: list) -> list:
        """The entities of one ReadRequest (all responses of the stream)."""
        try:
            return self._request(p4r.ReadRequest(entities=entities))
        except P4ClientError as exc:
            if exc.code == GRPCStatusCode.UNIMPLEMENTED:
                raise Unsupported(f"switch {self.address} does not implement this Read: "
                                  f"{exc.message.strip()}") from None
            raise self._error("Read", exc) from None

    def write(self, updates: list) -> None:
        """One WriteRequest; raises WriteRejected with the per-update outcome."""
        try:
            self._request(p4r.WriteRequest(updates=updates))
        except P4ClientError as exc:
            if exc.code in UNREACHABLE:
                raise self._error("Write", exc) from None
            if exc.details:
                failed = [(i, err.canonical_code.name, err.message) for i, err in sorted(exc.details.items())]
                applied = [i for i in range(len(updates)) if i not in exc.details]
            else:      # no per-update detail: the whole batch failed (nothing applied)
                failed, applied = [(None, exc.code.name, exc.message)], []
            raise WriteRejected(failed, applied, exc.message) from None
