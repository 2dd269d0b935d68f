"""A veth pair inside a network namespace of its own, and a sender replaying a pcap into it
(root only): how `civic monitor` is fed live frames in the tests and the bench."""
from __future__ import annotations

import os
import secrets
import shutil
import subprocess
import sys

SENDER = """
import socket, sys, time
from civic.wire import read_pcap
cap = read_pcap(sys.argv[2])
rate = float(sys.argv[3])
frames = [cap.frame(i) for i in range(len(cap))]
s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW)
s.bind((sys.argv[1], 0))
t0 = time.perf_counter()
for i, f in enumerate(frames):
    if rate:
        while time.perf_counter() < t0 + i / rate:
            pass
    s.send(f)
print(len(frames) / (time.perf_counter() - t0))
"""


def why_not() -> str | None:
    """Why veth pairs cannot be made here (None: they can)."""
    if os.geteuid() != 0:
        return "needs root (network namespaces, raw sockets)"
    if shutil.which("ip") is None:
        return "needs iproute2's ip"
    return None


class VethPair:
    """Namespace `ns` with veth `a` <-> `b`, both up, IPv6 off (no stray router solicitations)."""

    def __init__(self):
        tag = secrets.token_hex(3)
        self.ns, self.a, self.b = f"civic-mon-{tag}", "va", "vb"

    def __enter__(self) -> "VethPair":
        run = lambda *cmd: subprocess.run(cmd, check=True, capture_output=True)  # noqa: E731
        run("ip", "netns", "add", self.ns)
        try:
            self.exec_("sysctl", "-qw", "net.ipv6.conf.all.disable_ipv6=1")
            self.exec_("sysctl", "-qw", "net.ipv6.conf.default.disable_ipv6=1")
            self.exec_("ip", "link", "add", self.a, "type", "veth", "peer", "name", self.b)
            for dev in (self.a, self.b, "lo"):
                self.exec_("ip", "link", "set", dev, "up")
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc) -> None:
        subprocess.run(["ip", "netns", "delete", self.ns], capture_output=True)

    def exec_(self, *cmd) -> subprocess.CompletedProcess:
        return subprocess.run(["ip", "netns", "exec", self.ns, *cmd], check=True, capture_output=True, text=True)

    def popen(self, *cmd, **kw) -> subprocess.Popen:
        return subprocess.Popen(["ip", "netns", "exec", self.ns, *cmd], **kw)

    def send(self, pcap, rate: float = 0.0) -> float:
        """Every frame of pcap into veth a (rate frames/s; 0: as fast as it goes); the rate reached."""
        out = self.exec_(sys.executable, "-c", SENDER, self.a, str(pcap), str(rate))
        return float(out.stdout.split()[-1])
