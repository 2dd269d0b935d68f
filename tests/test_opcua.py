"""civic.opcua: the OPC UA server of a watch/monitor session, driven through a WatchState and read
with asyncua's client: tags and their types, events, read-only, endpoints, certificates, users."""
from __future__ import annotations

import asyncio
import datetime
import socket
import subprocess
import sys

import pytest
from asyncua import Client, ua
from asyncua.crypto import cert_gen
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID

from civic.errors import CivicError
from civic.opcua import OpcUaServer, check_password, hash_password, load_users
from civic.watch import WatchState, publish

MONITORS = ["drain_t3", "fill_t1"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def change(plant, monitor, prev, to, t, slope=-1234, level=6000):
    return {"t": t, "plant": plant, "monitor": monitor, "from": prev, "to": to, "seq": 1, "slope": slope,
            "level": level}


def served_on(endpoint, *args):
    """Start a server and serve until it listens; then close it (for start-up errors)."""
    server = OpcUaServer(endpoint, *args)
    server.start()
    try:
        server.serve(WatchState(list(MONITORS)))
    finally:
        server.close()


@pytest.fixture
def served():
    """An anonymous server on a free port over a WatchState; (endpoint, state, server)."""
    state = WatchState(list(MONITORS))
    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/civic"
    server = OpcUaServer(endpoint)
    server.start()
    server.serve(state)
    yield endpoint, state, server
    server.close()


async def monitor_node(client, plant, monitor, timeout: float = 10.0):
    """(namespace, the monitor's object) once the server has built it and written a first change:
    polled, however loaded the machine."""
    ns = await client.get_namespace_index("urn:civic")
    deadline = asyncio.get_running_loop().time() + timeout
    while True:
        try:
            node = await client.nodes.objects.get_child([f"{ns}:Plants", f"{ns}:{plant}", f"{ns}:{monitor}"])
            if await (await node.get_child(f"{ns}:Class")).read_value() != "none":
                return ns, node
        except ua.uaerrors.BadNoMatch:
            pass
        assert asyncio.get_running_loop().time() < deadline, f"no tags for {plant}/{monitor} in {timeout:g} s"
        await asyncio.sleep(0.05)


def test_tags_have_the_documented_names_types_and_values(served):
    endpoint, state, server = served
    t0 = 1767225600.25
    publish(state, change("10.0.0.7", "drain_t3", None, "normal", t0), t0, on_event=server.publish)
    publish(state, change("10.0.0.7", "drain_t3", "normal", "error", t0 + 4, slope=-99, level=5123), t0,
            on_event=server.publish)
    state.apply_counts("10.0.0.7", "drain_t3", {1: 40, 2: 0, 3: 2 ** 40})

    since = datetime.datetime.fromtimestamp(t0 + 4, datetime.timezone.utc)
    want = {"Class": ("error", ua.VariantType.String), "ClassCode": (3, ua.VariantType.UInt16),
            "Since": (since, ua.VariantType.DateTime), "Normal": (40, ua.VariantType.UInt64),
            "Warning": (0, ua.VariantType.UInt64), "Error": (2 ** 40, ua.VariantType.UInt64),
            "Slope": (-99, ua.VariantType.Int32), "Level": (5123, ua.VariantType.UInt16)}

    async def read():
        async with Client(endpoint) as client:
            ns, node = await monitor_node(client, "10.0.0.7", "drain_t3")
            assert (await node.read_event_notifier()) == {ua.EventNotifier.SubscribeToEvents}
            tags = {}
            for name in want:
                tags[name] = await node.get_child(f"{ns}:{name}")
                assert tags[name].nodeid == ua.NodeId(f"Plants/10.0.0.7/drain_t3/{name}", ns)
            for _ in range(50):        # counts reach the tags within COUNTS_S: within 5 s however loaded
                out = {}
                for name, var in tags.items():
                    dv = await var.read_data_value()
                    out[name] = (dv.Value.Value, dv.Value.VariantType)
                if out == want:
                    break
                await asyncio.sleep(0.1)
            return out

    assert asyncio.run(read()) == want


def test_monitor_objects_raise_and_clear_events(served):
    endpoint, state, server = served
    seen = []

    class Handler:
        def event_notification(self, ev):
            seen.append((ev.Severity, ev.Message.Text, ev.SourceName, ev.From, ev.To))

    async def run():
        async with Client(endpoint) as client:
            publish(state, change("10.0.0.2", "fill_t1", None, "normal", 1.0), 1.0, on_event=server.publish)
            ns, node = await monitor_node(client, "10.0.0.2", "fill_t1")
            etype = await client.nodes.base_event_type.get_child(f"{ns}:CivicVerdictChangeEventType")
            sub = await client.create_subscription(20, Handler())
            await sub.subscribe_events(node, etype)
            await asyncio.sleep(0.2)
            for prev, to in (("normal", "warning"), ("warning", "error"), ("error", "normal")):
                publish(state, change("10.0.0.2", "fill_t1", prev, to, 2.0), 2.0, on_event=server.publish)
            for _ in range(50):        # delivered within 5 s however loaded the machine (0.5 s was flaky)
                if len(seen) >= 3:
                    break
                await asyncio.sleep(0.1)
            await asyncio.sleep(0.2)   # and nothing more follows

    asyncio.run(run())
    assert seen == [(500, "10.0.0.2 fill_t1: normal -> warning", "10.0.0.2/fill_t1", "normal", "warning"),
                    (900, "10.0.0.2 fill_t1: warning -> error", "10.0.0.2/fill_t1", "warning", "error"),
                    (100, "10.0.0.2 fill_t1: error -> normal (cleared)", "10.0.0.2/fill_t1", "error", "normal")]


def test_nothing_is_writable_and_admin_is_nobody(served):
    endpoint, state, server = served
    publish(state, change("10.0.0.1", "drain_t3", None, "warning", 1.0), 1.0, on_event=server.publish)

    async def run():
        async with Client(endpoint) as client:
            ns, node = await monitor_node(client, "10.0.0.1", "drain_t3")
            cls = await node.get_child(f"{ns}:Class")
            with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
                await cls.write_value("normal")
            with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
                await client.nodes.objects.add_folder(ns, "Injected")
            with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
                await node.delete()
            assert await cls.read_value() == "warning"
        admin = Client(endpoint)
        admin.set_user("admin")
        admin.set_password("anything")
        with pytest.raises(ua.UaStatusCodeError):       # no user tokens on an anonymous endpoint
            await admin.connect()

    asyncio.run(run())
    # and no variable anywhere in the address space grants a write
    writable = [nid for nid, data in server._server.iserver.aspace._nodes.items()
                if ua.AttributeIds.UserAccessLevel in data.attributes
                and data.attributes[ua.AttributeIds.UserAccessLevel].value.Value.Value & ua.AccessLevel.CurrentWrite.mask]
    assert writable == []


@pytest.mark.parametrize("endpoint, message", [
    ("http://127.0.0.1:4840/civic", "not an endpoint URL"),
    ("opc.tcp://127.0.0.1/civic", "not an endpoint URL"),
    ("opc.tcp://127.0.0.1:99999/civic", "not an endpoint URL"),
    ("opc.tcp://no-such-host.invalid:4840/civic", "unknown host"),
])
def test_bad_endpoints_are_one_line_and_exit_2(endpoint, message):
    proc = subprocess.run([sys.executable, "-m", "civic", "watch", "--switch", "127.0.0.1:1", "--opcua", endpoint],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.startswith("civic watch: error: --opcua") and message in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_a_port_in_use_is_an_error():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(CivicError, match="address already in use"):
            served_on(f"opc.tcp://127.0.0.1:{port}/civic")


def make_cert(tmp_path, name="civic"):
    key = cert_gen.generate_private_key()
    cert = cert_gen.generate_self_signed_app_certificate(
        key, name, {}, [x509.UniformResourceIdentifier(f"urn:test:{name}"), x509.DNSName("localhost")],
        [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH])
    from cryptography.hazmat.primitives import serialization
    (tmp_path / f"{name}.der").write_bytes(cert.public_bytes(serialization.Encoding.DER))
    (tmp_path / f"{name}.pem").write_bytes(cert_gen.dump_private_key_as_pem(key))
    return tmp_path / f"{name}.der", tmp_path / f"{name}.pem"


def test_with_a_certificate_only_encrypted_sessions_of_listed_users(tmp_path):
    cert, key = make_cert(tmp_path, "server")
    client_cert, client_key = make_cert(tmp_path, "client")
    users = tmp_path / "users"
    users.write_text(f"# operators\noperator:{hash_password('s3cret')}\n")
    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/civic"
    server = OpcUaServer(endpoint, str(cert), str(key), str(users))
    state = WatchState(list(MONITORS))
    server.start()
    server.serve(state)
    publish(state, change("10.0.0.3", "fill_t1", None, "error", 1.0), 1.0, on_event=server.publish)
    secure = f"Basic256Sha256,SignAndEncrypt,{client_cert},{client_key}"

    async def session(user=None, password=None, security=secure):
        client = Client(endpoint)
        if security:
            await client.set_security_string(security)
        if user:
            client.set_user(user)
            client.set_password(password)
        async with client:
            ns, node = await monitor_node(client, "10.0.0.3", "fill_t1")
            return await (await node.get_child(f"{ns}:Class")).read_value()

    async def endpoints():
        client = Client(endpoint)
        return [(e.SecurityPolicyUri.rsplit("#", 1)[1], e.SecurityMode) for e in await client.connect_and_get_server_endpoints()]

    try:
        assert asyncio.run(endpoints()) == [("Basic256Sha256", ua.MessageSecurityMode.SignAndEncrypt)]
        assert asyncio.run(session("operator", "s3cret")) == "error"
        for user, password, security in (("operator", "wrong", secure), (None, None, secure),
                                         ("operator", "s3cret", None)):
            with pytest.raises(Exception):
                asyncio.run(session(user, password, security))
    finally:
        server.close()


def test_broken_certificates_and_keys_are_one_line_errors(tmp_path):
    cert, key = make_cert(tmp_path, "server")
    _, other_key = make_cert(tmp_path, "other")
    junk = tmp_path / "junk.pem"
    junk.write_text("-----BEGIN CERTIFICATE-----\nnot a certificate\n-----END CERTIFICATE-----\n")
    for c, k, message in ((junk, key, "cannot load"), (cert, junk, "cannot load"), (cert, other_key, "not the key of")):
        with pytest.raises(CivicError, match=message) as err:
            served_on(f"opc.tcp://127.0.0.1:{free_port()}/civic", str(c), str(k))
        assert "\n" not in str(err.value)
    with pytest.raises(CivicError, match="go together"):
        OpcUaServer("opc.tcp://127.0.0.1:4840/civic", str(cert))
    with pytest.raises(CivicError, match="need --opcua-cert"):
        OpcUaServer("opc.tcp://127.0.0.1:4840/civic", users=str(tmp_path / "users"))


def test_users_files(tmp_path):
    stored = hash_password("pw")
    assert check_password("pw", stored) and not check_password("pW", stored)
    good = tmp_path / "good"
    good.write_text(f"a:{stored}\n\n# b is gone\n")
    assert load_users(str(good)) == {"a": stored}
    for text, message in (("a:plain\n", "not NAME:"), (f"a:{stored[:-2]}zz\n", "hex"), ("# none\n", "no users")):
        bad = tmp_path / "bad"
        bad.write_text(text)
        with pytest.raises(CivicError, match=message):
            load_users(str(bad))
    with pytest.raises(CivicError, match="No such file"):
        load_users(str(tmp_path / "absent"))


def test_opcua_user_prints_a_line_the_server_accepts(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "civic", "opcua-user", "operator"], input="s3cret\n",
                          capture_output=True, text=True, check=True)
    (tmp_path / "users").write_text(proc.stdout)
    assert check_password("s3cret", load_users(str(tmp_path / "users"))["operator"])


def test_a_trust_list_admits_only_its_clients(tmp_path):
    cert, key = make_cert(tmp_path, "server")
    trusted = tmp_path / "trusted"
    trusted.mkdir()
    good_cert, good_key = make_cert(tmp_path, "client")
    (trusted / good_cert.name).write_bytes(good_cert.read_bytes())
    stranger_cert, stranger_key = make_cert(tmp_path, "stranger")
    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/civic"
    server = OpcUaServer(endpoint, str(cert), str(key), trust=str(trusted))
    server.start()
    server.serve(WatchState(list(MONITORS)))

    async def session(client_cert, client_key):
        client = Client(endpoint)
        client.application_uri = f"urn:test:{client_cert.stem}"        # as its certificate says
        await client.set_security_string(f"Basic256Sha256,SignAndEncrypt,{client_cert},{client_key}")
        async with client:
            return await client.get_namespace_index("urn:civic")

    try:
        assert asyncio.run(session(good_cert, good_key)) >= 2
        with pytest.raises(Exception):
            asyncio.run(session(stranger_cert, stranger_key))
    finally:
        server.close()
