"""The BMv2 replay target: run captures through `simple_switch_grpc` and collect its output.

Layout (everything torn down again, whatever happens):

    host namespace                     network namespace civic-XXXX
    ---------------                    ------------------------------------------
    P4Runtime client  -- veth /30 -->  ctl  simple_switch_grpc --grpc-server-addr ctl:9559
                                            port 1 = sw1 <-veth-> h1  (frames sent here)
                                            port 2 = sw2 <-veth-> h2  (output captured here)

The switch runs inside its own namespace because BMv2's Thrift server (when
built in) always binds 0.0.0.0:9090 and nothing else may be on its data
ports. The client reaches the gRPC server over a dedicated veth pair with a
link-local /30. The frame sockets (AF_PACKET on h1 and h2) are opened by a
helper thread that enters the namespace with setns(2); a socket stays in the
namespace it was created in, so the rest of the process never changes namespace.
IPv6 is disabled in the namespace so the kernel itself sends nothing on the ports.

Frames are pipelined: up to `window` frames are in flight at once. The switch
forwards port 1 -> port 2 in order (one ingress thread, one egress queue per port,
veths keep order), so each output frame is matched to the oldest frame still in
flight that it equals up to the bytes a switch may rewrite (verdict, UDP checksum);
frames skipped over by a later match were not forwarded (`missing`). An output
that matches none is the oldest in-flight frame's output, changed beyond those
bytes (a comparison with the model then shows it). When nothing comes out for
`frame_timeout` seconds, every frame still in flight counts as not forwarded.
That keeps the input order exact without relying on timestamps, at BMv2's speed
instead of one round trip per frame (`window=1` is the old lockstep).
"""
from __future__ import annotations

import copy
import ctypes
import errno
import os
import secrets
import select
import shutil
import signal
import socket
import struct
import subprocess
import tempfile
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from civic.entries import load_entries
from civic.errors import CivicError
from civic.switch.connection import SwitchConnection
from civic.switch.converge import ConvergeResult, converge
from civic.switch.desired import desired_state
from civic.switch.digests import digest_members, enable_digest
from civic.switch.pipeline import PIPELINE_JSON, PIPELINE_P4INFO, load_pipeline
from civic.switch.schema import DIGEST_VERDICT_CHANGE
from civic.links import LINKTYPE_ETHERNET
from civic.wire import ETH_LEN, Capture, decode_frames, is_pcapng, read_pcap, write_pcap

SWITCH_BINARY = "simple_switch_grpc"
GRPC_PORT = 9559
CLONE_NEWNET = 0x40000000
ETH_P_ALL = 0x0003
PACKET_OUTGOING = 4
VETH_MTU = 65535     # the largest a veth takes: jumbo frames of any recording cross
RECV_MAX = 1 << 17   # > VETH_MTU + headers: a frame is never cut on receive
ETH_HEADER = 14      # a veth refuses shorter frames (EINVAL) and longer than its MTU (EMSGSIZE)
SOL_PACKET, PACKET_AUXDATA = 263, 8
TP_STATUS_VLAN_VALID, TP_STATUS_VLAN_TPID_VALID = 0x10, 0x40
# bytes a switch may change in a plant message: UDP checksum and verdict
UDP_CSUM = 14 + 20 + 6
VERDICT = 14 + 20 + 8 + 18
WINDOW = 16          # frames in flight: throughput flattens from 8 on; at 64 BMv2 lost all past the 32nd


@dataclass
class BMv2Output:
    """What the switch did with one capture's frames."""

    frames: list                     # per input frame: bytes seen on the output port, or None
    capture: Capture | None = None   # the forwarded frames as a capture (input timestamps)
    missing: list = field(default_factory=list)   # indices of input frames not forwarded
    digests: list = field(default_factory=list)   # verdict_change_t digests ({member: value}), in order

    @property
    def complete(self) -> bool:
        return not self.missing


def _run(cmd: list[str], what: str, check: bool = True) -> subprocess.CompletedProcess:
    res = subprocess.run(cmd, capture_output=True, text=True)
    if check and res.returncode != 0:
        msg = (res.stderr or res.stdout).strip().splitlines()
        raise CivicError(f"{what} failed: {' '.join(cmd)}: {msg[-1] if msg else f'exit {res.returncode}'}")
    return res


def _open_ns_sockets(netns: str, send_if: str, recv_if: str) -> tuple[socket.socket, socket.socket]:
    """AF_PACKET sockets on interfaces inside `netns`, created from a thread that setns()es there."""
    result: dict = {}

    def worker():
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            path = next((d for d in (f"/run/netns/{netns}", f"/var/run/netns/{netns}") if os.path.exists(d)),
                        f"/run/netns/{netns}")
            with open(path) as f:
                if libc.setns(f.fileno(), CLONE_NEWNET) != 0:
                    err = ctypes.get_errno()
                    raise OSError(err, f"setns({netns}): {os.strerror(err)}")
            tx = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, 0)     # protocol 0: never receives
            tx.bind((send_if, 0))
            rx = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
            rx.bind((recv_if, 0))
            rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
            rx.setsockopt(SOL_PACKET, PACKET_AUXDATA, 1)     # VLAN tags the kernel strips (see _recv_frame)
            result["socks"] = (tx, rx)
        except OSError as exc:
            result["error"] = exc

    t = threading.Thread(target=worker, name="civic-netns")
    t.start()
    t.join()
    if "error" in result:
        raise CivicError(f"cannot open packet sockets in namespace {netns}: {result['error']}")
    return result["socks"]


def _die_with_parent() -> None:
    """preexec_fn: the switch gets SIGKILL if this process dies without cleaning up (Linux prctl)."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _free_link_local() -> tuple[str, str]:
    """Two addresses of an unused 169.254.X.Y/30 (host side, namespace side)."""
    used = _run(["ip", "-4", "-o", "addr", "show"], "ip addr").stdout
    for _ in range(64):
        x = 64 + secrets.randbelow(190)
        y = 4 * secrets.randbelow(63)
        if x == 169 or f"169.254.{x}." in used:
            continue
        return f"169.254.{x}.{y + 1}", f"169.254.{x}.{y + 2}"
    raise CivicError("no free 169.254.0.0/16 /30 for the switch control link")


def _sigterm(signum, frame):
    raise SystemExit(128 + signum)


def _recv_frame(rx: socket.socket) -> tuple[bytes, int] | None:
    """(frame, packet type) from a packet socket without blocking, or None when none is waiting.

    The kernel takes an 802.1Q tag out of a received frame into metadata (VLAN offload; veths
    have no ethtool switch here); like libpcap, put it back so the frame is what was on the wire.
    """
    try:
        data, anc, _, addr = rx.recvmsg(RECV_MAX, socket.CMSG_SPACE(20), socket.MSG_DONTWAIT)
    except BlockingIOError:
        return None
    for level, kind, aux in anc:
        if level == SOL_PACKET and kind == PACKET_AUXDATA and len(aux) >= 20:
            status, _, _, _, _, tci, tpid = struct.unpack("=IIIHHHH", aux[:20])
            if status & TP_STATUS_VLAN_VALID:
                tpid = tpid if status & TP_STATUS_VLAN_TPID_VALID else 0x8100
                data = data[:12] + struct.pack("!HH", tpid, tci) + data[12:]
    return data, addr[2]


def _same_frame(out: bytes, inp: bytes) -> bool:
    """out is inp, up to the bytes a switch may rewrite (UDP checksum, verdict)."""
    return (len(out) == len(inp) and out[:UDP_CSUM] == inp[:UDP_CSUM]
            and out[UDP_CSUM + 2:VERDICT] == inp[UDP_CSUM + 2:VERDICT] and out[VERDICT + 2:] == inp[VERDICT + 2:])


class BMv2Switch:
    """simple_switch_grpc in a fresh network namespace; use as a context manager."""

    def __init__(self, pipeline_dir: str | Path, *, binary: str = SWITCH_BINARY, device_id: int = 0,
                 startup_timeout: float = 20.0, log_path: str | Path | None = None,
                 ports: tuple[int, int] = (1, 2), padded_bytes: bool = True, controller: bool = True):
        """controller=False: start the switch bare (no pipeline, no P4Runtime session held), for
        another controller such as `civic configure --switch sw.address`."""
        self.controller = controller
        self.pipeline_dir = Path(pipeline_dir) if pipeline_dir is not None else None
        self.padded_bytes = padded_bytes   # full-width byte strings: accepted by every PI version
        self.binary = binary
        self.device_id = device_id
        self.startup_timeout = startup_timeout
        self.ports = ports
        tag = secrets.token_hex(3)
        self.netns = f"civic-{tag}"
        self.host_if = f"cv{tag}h"          # <= 15 characters
        self.tmp = Path(tempfile.mkdtemp(prefix=f"civic-bmv2-{tag}-"))
        self.log_path = Path(log_path) if log_path else self.tmp / "switch.log"
        self.proc: subprocess.Popen | None = None
        self.conn: SwitchConnection | None = None
        self.tx = self.rx = None
        self._log = None
        self._netns_made = False
        self._host_if_made = False

    # -- lifecycle
    def __enter__(self) -> "BMv2Switch":
        self._old_sigterm = None
        if threading.current_thread() is threading.main_thread():
            # a plain SIGTERM would skip the finally blocks: turn it into an exception
            self._old_sigterm = signal.signal(signal.SIGTERM, _sigterm)
        try:
            self.start()
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc) -> None:
        try:
            self.stop()
        finally:
            if self._old_sigterm is not None:
                signal.signal(signal.SIGTERM, self._old_sigterm)
                self._old_sigterm = None

    def start(self) -> None:
        path = shutil.which(self.binary)
        if path is None:
            raise CivicError(f"{self.binary} not found on PATH: install BMv2 with P4Runtime support "
                             "(behavioral-model built --with-pi)")
        if shutil.which("ip") is None:
            raise CivicError("'ip' (iproute2) not found on PATH: needed for the switch's network namespace")
        if os.geteuid() != 0:
            raise CivicError("the BMv2 target needs root (it creates a network namespace and veth pairs)")
        pipe = load_pipeline(self.pipeline_dir) if self.controller else None
        ns, ip = self.netns, ["ip"]
        _run(ip + ["netns", "add", ns], "creating namespace")
        self._netns_made = True
        nsx = ip + ["netns", "exec", ns]
        _run(nsx + ["sysctl", "-qw", "net.ipv6.conf.all.disable_ipv6=1",
                    "net.ipv6.conf.default.disable_ipv6=1"], "disabling IPv6", check=False)
        _run(ip + ["-n", ns, "link", "set", "dev", "lo", "up"], "namespace loopback")
        for p in self.ports:
            _run(ip + ["-n", ns, "link", "add", "name", f"sw{p}", "type", "veth", "peer", "name", f"h{p}"], "veth")
            for dev in (f"sw{p}", f"h{p}"):
                _run(ip + ["-n", ns, "link", "set", "dev", dev, "mtu", str(VETH_MTU)], "veth mtu", check=False)
                _run(ip + ["-n", ns, "link", "set", "dev", dev, "up"], "veth up")
                if shutil.which("ethtool"):
                    _run(nsx + ["ethtool", "-K", dev, "tx", "off", "rx", "off", "gro", "off", "gso", "off",
                                "tso", "off"], "ethtool", check=False)
        host_ip, ns_ip = _free_link_local()
        _run(ip + ["link", "add", "name", self.host_if, "type", "veth", "peer", "name", "ctl", "netns", ns],
             "control veth")
        self._host_if_made = True
        _run(["sysctl", "-qw", f"net.ipv6.conf.{self.host_if}.disable_ipv6=1"], "sysctl", check=False)
        _run(ip + ["addr", "add", f"{host_ip}/30", "dev", self.host_if], "control address")
        _run(ip + ["link", "set", "dev", self.host_if, "up"], "control link up")
        _run(ip + ["-n", ns, "addr", "add", f"{ns_ip}/30", "dev", "ctl"], "control address")
        _run(ip + ["-n", ns, "link", "set", "dev", "ctl", "up"], "control link up")
        self.address = f"{ns_ip}:{GRPC_PORT}"

        helptext = _run([path, "--help"], "simple_switch_grpc --help", check=False)
        helptext = (helptext.stdout or "") + (helptext.stderr or "")
        cmd = nsx + [path, "--no-p4", "--device-id", str(self.device_id)]
        for p in self.ports:
            cmd += ["-i", f"{p}@sw{p}"]
        if "--notifications-addr" in helptext:     # default ipc path in /tmp is shared by all namespaces
            cmd += ["--notifications-addr", f"ipc://{self.tmp}/notifications.ipc"]
        if "--thrift-port" in helptext:
            cmd += ["--thrift-port", "9090"]
        cmd += ["--", "--grpc-server-addr", self.address]
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                     start_new_session=True, preexec_fn=_die_with_parent)
        self.conn = self._connect()
        self.tx, self.rx = _open_ns_sockets(ns, f"h{self.ports[0]}", f"h{self.ports[1]}")
        if not self.controller:
            self.conn.close()
            self.conn = None
            return
        self.schema = pipe
        self.conn.set_pipeline(pipe.get_pipeline_config())

    def _connect(self) -> SwitchConnection:
        deadline = time.monotonic() + self.startup_timeout
        while True:
            if self.proc.poll() is not None:
                raise CivicError(f"{self.binary} exited with status {self.proc.returncode}: {self._log_tail()}")
            conn = SwitchConnection(self.address, self.device_id, election_id=1, timeout=1.0,
                                         padded_bytes=self.padded_bytes, arbitrate=self.controller)
            try:
                conn.connect()
                if self.controller:
                    conn.require_primary()
                return conn
            except CivicError:
                conn.close()
                if time.monotonic() > deadline:
                    raise CivicError(f"{self.binary} did not answer on {self.address} within "
                                     f"{self.startup_timeout:g} s: {self._log_tail()}") from None
                time.sleep(0.2)

    def _log_tail(self) -> str:
        try:
            lines = [ln for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()]
        except OSError:
            lines = []
        return lines[-1].strip() if lines else f"no output (log {self.log_path})"

    def stop(self) -> None:
        """Stop what start() started and delete the namespace; safe to call at any point."""
        for s in (self.tx, self.rx):
            if s is not None:
                s.close()
        self.tx = self.rx = None
        if self.conn is not None:
            try:
                self.conn.close()
            except Exception:
                pass
            self.conn = None
        if self.proc is not None:
            if self.proc.poll() is None:
                try:
                    os.killpg(self.proc.pid, signal.SIGTERM)   # its own session: only what we started
                except ProcessLookupError:
                    pass
                try:
                    self.proc.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    try:
                        os.killpg(self.proc.pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
                    self.proc.wait(timeout=5)
            self.proc = None
        if self._log is not None:
            self._log.close()
            self._log = None
        if self._host_if_made:
            _run(["ip", "link", "del", "dev", self.host_if], "deleting control veth", check=False)
            self._host_if_made = False
        if self._netns_made:
            _run(["ip", "netns", "delete", self.netns], "deleting namespace", check=False)
            self._netns_made = False
        shutil.rmtree(self.tmp, ignore_errors=True)   # the log lives here unless log_path was given

    # -- use
    def configure(self, entries_path: str | Path, reset: bool = False) -> ConvergeResult:
        """Install the entries; with reset, re-push the pipeline first (zeroes every register)."""
        if reset:
            self.conn.set_pipeline(self.schema.get_pipeline_config())
        result = converge(self.conn, load_entries(entries_path), self.schema, pipeline=self.schema)
        if self.schema.digests.get(DIGEST_VERDICT_CHANGE) is not None:
            enable_digest(self.conn, self.schema)
        return result

    def collect_digests(self, quiet: float = 0.5) -> list[dict]:
        """Every verdict-change digest the switch has sent, in order, until `quiet` s pass without
        one (the switch flushes a list after 1 ms); each list is acknowledged."""
        out = []
        while (msg := self.conn.next_stream_message(quiet)) is not None:
            if msg.HasField("digest"):
                out.extend(digest_members(msg, self.schema))
                self.conn.ack_digest(msg.digest)
        return out

    def send_frames(self, frames: Sequence[bytes], frame_timeout: float = 1.0, window: int = WINDOW,
                    progress=None) -> list:
        """Each frame on port 1, its output from port 2 in input order (None when not forwarded).

        Frames no Ethernet link carries (shorter than its header, longer than the MTU) are None.

        progress: called with the number of frames resolved so far (forwarded or not), now and then.
        """
        frames = [bytes(f) for f in frames]
        out: list = [None] * len(frames)
        pending: deque = deque()
        self._drain()
        sent = done = 0
        quiet_since = time.monotonic()
        while sent < len(frames) or pending:
            while sent < len(frames) and len(pending) < window:
                try:
                    if len(frames[sent]) < ETH_HEADER:
                        raise OSError(errno.EINVAL, "shorter than an Ethernet header")
                    self.tx.send(frames[sent])
                except OSError as exc:
                    if exc.errno not in (errno.EINVAL, errno.EMSGSIZE):
                        raise CivicError(f"frame {sent} ({len(frames[sent])} bytes) cannot be sent on a veth: "
                                         f"{exc.strerror}") from None
                    sent += 1                            # no link carries this frame: not forwarded
                    done += 1
                    continue
                pending.append(sent)
                sent += 1
            if not pending:
                continue
            left = frame_timeout - (time.monotonic() - quiet_since)
            if left > 0 and select.select([self.rx], [], [], left)[0]:
                while (got := _recv_frame(self.rx)) is not None:
                    if got[1] != PACKET_OUTGOING:
                        done += self._match(got[0], frames, pending, out)
                quiet_since = time.monotonic()
            elif left <= 0:
                done += len(pending)            # quiet for frame_timeout: none of these came out
                pending.clear()
                quiet_since = time.monotonic()
            if progress is not None:
                progress(done)
        return out

    @staticmethod
    def _match(data: bytes, frames: list, pending: deque, out: list) -> int:
        """Give an output frame to its input; returns how many pending frames it resolved."""
        if not pending:
            raise CivicError(f"a {len(data)}-byte frame came out of the switch with no frame in flight "
                             "(a late output: raise frame_timeout)")
        for pos, j in enumerate(pending):
            if _same_frame(data, frames[j]):
                for _ in range(pos + 1):        # the ones skipped over were not forwarded
                    pending.popleft()
                out[j] = data
                return pos + 1
        out[pending.popleft()] = data           # changed beyond verdict and checksum
        return 1

    def _drain(self) -> None:
        while select.select([self.rx], [], [], 0)[0]:
            self.rx.recv(RECV_MAX)


P4_SOURCE = Path(__file__).resolve().parents[2] / "p4src"      # the checkout's P4 sources


def compile_v1model(program: str | Path, pipeline_dir: str | Path) -> str:
    """p4c-bm2-ss: program -> pipeline_dir/civic.json + its P4Info; returns the compiler's messages."""
    d = Path(pipeline_dir)
    d.mkdir(parents=True, exist_ok=True)
    res = _run(["p4c-bm2-ss", "--std", "p4-16", "--arch", "v1model", "-o", str(d / PIPELINE_JSON),
                "--p4runtime-files", str(d / PIPELINE_P4INFO[0]), str(program)], "compiling the P4 program")
    return res.stdout + res.stderr


def build_pipeline(pipeline_dir: str | Path, source: Path = P4_SOURCE) -> bool:
    """Compile p4src/v1model/civic.p4 into pipeline_dir when it has no build or an older one.

    Only where the P4 sources are beside the package (a checkout) and p4c-bm2-ss is on PATH;
    returns whether it compiled. A directory built from elsewhere (no p4src here) is left alone.
    """
    d = Path(pipeline_dir)
    main = source / "v1model" / "civic.p4"
    if not main.is_file() or shutil.which("p4c-bm2-ss") is None:
        return False
    js = d / PIPELINE_JSON
    newest = max(f.stat().st_mtime for sub in ("v1model", "shared") for f in (source / sub).rglob("*.p4"))
    if js.is_file() and (d / PIPELINE_P4INFO[0]).is_file() and js.stat().st_mtime >= newest:
        return False
    compile_v1model(main, d)
    return True


def output_capture(capture: Capture, frames: list, udp_port: int, plant_prefix: str) -> Capture:
    """The forwarded frames as a Capture with the input frames' timestamps (missing ones left out).

    When every frame came out with its input's length (the normal case) this is a copy of the
    input capture with the frames patched in place, so the pcap headers stay byte-identical (and
    a Linux cooked capture's link headers). Otherwise the frames that came out are written anew,
    pcap or pcapng as the input, of Ethernet frames: a cooked frame as the switch saw it.
    """
    if len(frames) != len(capture):
        raise CivicError(f"{len(frames)} output frames for {len(capture)} input frames")
    if all(f is not None and len(f) == int(capture.caplen[i]) for i, f in enumerate(frames)):
        out = copy.deepcopy(capture)
        for i, f in enumerate(frames):
            # a cooked capture's link header stays as captured: the switch saw its Ethernet view
            skip = 0 if out.link is None or out.link[i] == LINKTYPE_ETHERNET else ETH_LEN
            o = int(out.offset[i])
            out.data[o + skip:o + len(f)] = f[skip:]
        t = out.messages["t"].copy()
        out.messages = decode_frames(out.data, out.offset, out.caplen, udp_port, plant_prefix, out.link)
        out.messages["t"] = t
        return out
    keep = [i for i, f in enumerate(frames) if f is not None]
    with tempfile.TemporaryDirectory(prefix="civic-bmv2-out-") as tmp:
        path = Path(tmp) / ("out.pcapng" if is_pcapng(capture.data[:4]) else "out.pcap")     # the input's format
        write_pcap(path, capture.messages["t"][keep], [frames[i] for i in keep])
        out = read_pcap(path, udp_port, plant_prefix)
    out.path = capture.path
    return out


def replay_bmv2(captures: Sequence[Capture], entries_path: str | Path, pipeline_dir: str | Path, *,
                reset_between: bool = True, frame_timeout: float = 1.0, startup_timeout: float = 20.0,
                binary: str = SWITCH_BINARY, log_path: str | Path | None = None,
                padded_bytes: bool = True, window: int = WINDOW, progress=None) -> list[BMv2Output]:
    """Replay captures through BMv2 (simple_switch_grpc) and return what came out, in input order.

    captures:      `civic.wire.Capture`s (e.g. from `read_pcap`); every frame of each is sent on
                   switch port 1, in order, up to `window` frames in flight (1 = lockstep).
    entries_path:  an entries JSON (docs/pipeline.md section 6) installed with `civic configure`'s
                   converge; it also gives udp_port / plant_prefix for decoding the output.
    pipeline_dir:  directory with civic.json (BMv2 JSON) and civic.p4info.txtpb from p4c-bm2-ss.
    reset_between: re-push the pipeline before each capture, so every capture starts from zeroed
                   registers like `SwitchModel(entries).run(...)`; False carries state across captures.
    frame_timeout: seconds without output on port 2 after which the frames in flight count as not
                   forwarded.
    progress:      called with the number of frames resolved, over all captures, now and then.
    padded_bytes:  send full-width P4Runtime byte strings (older PI builds reject canonical ones;
                   newer ones accept both).
    log_path:      keep the switch's stdout/stderr there (default: a temporary file, removed).

    Returns one `BMv2Output` per capture: `.frames[i]` is the bytes port 2 emitted for input frame i
    (None if nothing came out), `.missing` lists those i, `.capture` holds the forwarded frames as a
    Capture with the input timestamps (write it with `.write(path)`).
    Needs root and `simple_switch_grpc` on PATH; the namespace, veths and switch process are removed
    in all cases. Raises CivicError on any failure (one line).
    """
    entries = load_entries(entries_path)
    desired_state(entries, load_pipeline(pipeline_dir))  # fail fast
    results = []
    with BMv2Switch(pipeline_dir, binary=binary, startup_timeout=startup_timeout, log_path=log_path,
                    padded_bytes=padded_bytes) as sw:
        before = 0
        for n, cap in enumerate(captures):
            sw.configure(entries_path, reset=reset_between and n > 0)
            step = None if progress is None else (lambda k, b=before: progress(b + k))
            frames = sw.send_frames([cap.frame(i) for i in range(len(cap))], frame_timeout, window, step)
            before += len(cap)
            missing = [i for i, f in enumerate(frames) if f is None]
            results.append(BMv2Output(frames=frames, missing=missing,
                                      capture=output_capture(cap, frames, entries.udp_port, entries.plant_prefix),
                                      digests=sw.collect_digests()))
    return results
