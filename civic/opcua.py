"""OPC UA server of a `civic watch` / `civic monitor` session (asyncua): verdicts as tags, alarm events.

Address space, namespace `urn:civic`, every NodeId a string in it (`ns=<urn:civic>;s=<path>`):

    Objects/Plants                                   folder
        <plant IPv4>                                 object, e.g. 10.0.0.1
            <monitor>                                object, e.g. drain_t3; an event notifier
                Class      String    none | normal | warning | error
                ClassCode  UInt16    0 none, 1 normal, 2 warning, 3 error (the verdict code)
                Since      DateTime  time of the last change (OPC UA's null date before the first)
                Normal, Warning, Error   UInt64   verdict counts
                Slope      Int32     slope or mass-balance residual that decided the last change
                Level      UInt16    level (mL) that decided the last change

    path of a variable: Plants/<plant>/<monitor>/<name>, e.g. Plants/10.0.0.1/drain_t3/Class

A plant appears with its first verdict change or its first counts (within COUNTS_S). Every
change is written in order, with the capture time as SourceTimestamp, so a data-change
subscription with a queue sees each one. A change into warning or error raises a
CivicVerdictChangeEventType event (a BaseEventType with Plant, Monitor, From, To) of Severity
500 / 900 on the monitor object and on the Server object; a return to normal raises one of
Severity 100 that clears it. asyncua implements no Part 9 condition state machine
(Acknowledge, Confirm, Shelving), so these are events, not conditions (README).

Read-only: no node is writable and every session has asyncua's User role (no writes, no node
management); asyncua's "admin" login is switched off. Anonymous on a plain endpoint by default;
with a certificate and key the only endpoint is Basic256Sha256 SignAndEncrypt, clients
optionally limited to trusted application certificates and to users of a password file.

The server runs its asyncio loop in a thread of its own; the session thread hands it events
(`publish`) and it reads the session's WatchState for counts and new plants.
"""
from __future__ import annotations

import asyncio
import gc
import hashlib
import hmac
import logging
import os
import secrets
import socket
import sys
import threading
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from urllib.parse import urlsplit

from civic.errors import CivicError
from civic.wire import CLASS_CODES

NAMESPACE = "urn:civic"
EVENT_TYPE = "CivicVerdictChangeEventType"
SEVERITY = {"normal": 100, "warning": 500, "error": 900}     # OPC UA 1..1000: low, medium-high, high
COUNTS_S = 0.25               # counts and new plants are read from the session state this often
START_TIMEOUT_S = 15.0
TICK = object()               # no change arrived within COUNTS_S
NULL_DATE = datetime(1601, 1, 1, tzinfo=timezone.utc)   # OPC UA's DateTime 0
# a monitor object's variables: name -> (value before the first verdict, asyncua VariantType name)
VARIABLES = {"Class": ("none", "String"), "ClassCode": (0, "UInt16"), "Since": (NULL_DATE, "DateTime"),
             "Normal": (0, "UInt64"), "Warning": (0, "UInt64"), "Error": (0, "UInt64"),
             "Slope": (0, "Int32"), "Level": (0, "UInt16")}
COUNT_VARIABLES = ((1, "Normal"), (2, "Warning"), (3, "Error"))
PBKDF2 = "pbkdf2_sha256"
PBKDF2_ROUNDS = 200_000


@dataclass
class _Cell:
    """The nodes of one (plant, monitor) and what was last written to them."""

    node: object
    variables: dict
    events: object                                     # EventGenerator on the monitor object
    counts: dict = field(default_factory=dict)


def parse_endpoint(endpoint: str) -> tuple[str, int]:
    """opc.tcp://HOST:PORT[/PATH] -> (host, port); one-line error otherwise."""
    try:
        url = urlsplit(endpoint)
        port = url.port
    except ValueError:
        raise CivicError(f"--opcua {endpoint!r}: not an endpoint URL (opc.tcp://HOST:PORT/PATH)") from None
    if url.scheme != "opc.tcp" or not url.hostname or port is None or not 0 < port < 65536:
        raise CivicError(f"--opcua {endpoint!r}: not an endpoint URL (opc.tcp://HOST:PORT/PATH, port 1-65535)")
    try:
        socket.getaddrinfo(url.hostname, port)
    except OSError:
        raise CivicError(f"--opcua {endpoint!r}: unknown host {url.hostname!r}") from None
    return url.hostname, port


def hash_password(password: str, salt: bytes | None = None, rounds: int = PBKDF2_ROUNDS) -> str:
    """The users-file form of a password: pbkdf2_sha256$ROUNDS$SALT$HASH (hex)."""
    salt = salt or secrets.token_bytes(16)
    digest = hashlib.pbkdf2_hmac("sha256", password.encode(), salt, rounds)
    return f"{PBKDF2}${rounds}${salt.hex()}${digest.hex()}"


def check_password(password: str, stored: str) -> bool:
    scheme, rounds, salt, digest = stored.split("$")
    again = hash_password(password, bytes.fromhex(salt), int(rounds)).split("$")[3]
    return scheme == PBKDF2 and hmac.compare_digest(again, digest)


def load_users(path: str) -> dict[str, str]:
    """A users file: one `name:pbkdf2_sha256$ROUNDS$SALT$HASH` per line (civic opcua-user NAME)."""
    try:
        lines = Path(path).read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise CivicError(f"--opcua-users {path}: {getattr(exc, 'strerror', None) or exc}") from None
    users = {}
    for n, line in enumerate(lines, 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        name, _, stored = line.strip().partition(":")
        parts = stored.split("$")
        if not name or len(parts) != 4 or parts[0] != PBKDF2 or not parts[1].isdigit():
            raise CivicError(f"--opcua-users {path}:{n}: not NAME:{PBKDF2}$ROUNDS$SALT$HASH")
        try:
            bytes.fromhex(parts[2]), bytes.fromhex(parts[3])
        except ValueError:
            raise CivicError(f"--opcua-users {path}:{n}: salt and hash must be hex") from None
        users[name] = stored
    if not users:
        raise CivicError(f"--opcua-users {path}: no users")
    return users


class ReadOnlyUsers:
    """asyncua user manager: every session reads and none writes (UserRole.User). With a users
    file only its users get a session; otherwise anyone the endpoint lets in."""

    def __init__(self, users: dict[str, str] | None = None):
        self.users = users

    def get_user(self, iserver, username=None, password=None, certificate=None):
        from asyncua.crypto.permission_rules import User, UserRole

        if self.users is not None:
            stored = self.users.get(username or "")
            if stored is None or not check_password(password or "", stored):
                return None
        return User(role=UserRole.User)


def certificate_uri(cert) -> str | None:
    """The application URI a certificate names (its subjectAltName URI), if any."""
    from cryptography import x509

    try:
        names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return None
    uris = names.get_values_for_type(x509.UniformResourceIdentifier)
    return uris[0] if uris else None


def public_der(cert_or_key) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return cert_or_key.public_key().public_bytes(serialization.Encoding.DER,
                                                 serialization.PublicFormat.SubjectPublicKeyInfo)


def space_cache() -> Path:
    """Where the standard address space is kept between runs (per asyncua version)."""
    from importlib.metadata import version

    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "civic" / f"opcua-space-asyncua-{version('asyncua')}.pickle"


def _cached_space_server(user_manager):
    """asyncua's InternalServer, its standard address space (6 k nodes, 0.65 s to build from
    asyncua's generated code) loaded from space_cache() when there (0.3 s) and saved there when not."""
    from asyncua.server.internal_server import InternalServer

    class CachedSpaceServer(InternalServer):
        async def load_standard_address_space(self, shelf_file=None) -> None:
            path = space_cache()
            try:
                self.aspace.load(path)
                return
            except Exception:             # absent, unreadable or from another build: build it anew
                pass
            await super().load_standard_address_space(shelf_file)
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(f".{os.getpid()}.tmp")
                self.aspace.dump(tmp)              # no method callbacks are bound yet: nothing is lost
                os.replace(tmp, path)
            except OSError:
                pass                               # no cache, still a server

    return CachedSpaceServer(user_manager=user_manager)


class OpcUaServer:
    """The verdicts of a session's WatchState served over OPC UA (see the module docstring)."""

    def __init__(self, endpoint: str, cert: str | None = None, key: str | None = None,
                 users: str | None = None, trust: str | None = None):
        parse_endpoint(endpoint)
        if bool(cert) != bool(key):
            raise CivicError("--opcua-cert and --opcua-key go together")
        if (users or trust) and not cert:
            raise CivicError("--opcua-users and --opcua-trust need --opcua-cert/--opcua-key (an encrypted endpoint)")
        for flag, path in (("--opcua-cert", cert), ("--opcua-key", key)):
            if path and not os.path.isfile(path):
                raise CivicError(f"{flag} {path}: no such file")
        if trust and not os.path.isdir(trust):
            raise CivicError(f"--opcua-trust {trust}: no such directory")
        self.state, self.endpoint = None, endpoint
        self.cert, self.key, self.trust = cert, key, trust
        self.users = load_users(users) if users else None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._queue: asyncio.Queue | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._closing = threading.Event()
        self._error: str | None = None
        self._cells: dict = {}
        self._plants: dict = {}
        self._server = None                # the asyncua Server, once serving

    # -- the session's side
    def start(self) -> None:
        """Start building and listening in the server's thread; returns at once, so the session's
        own start-up overlaps it. serve() waits for it."""
        self._thread = threading.Thread(target=self._run, name="civic-opcua", daemon=True)
        self._thread.start()

    def serve(self, state) -> None:
        """Once the endpoint listens, the tags follow `state` (a WatchState) and the events given to
        publish(). A port in use or a bad certificate: CivicError."""
        if not self._ready.wait(START_TIMEOUT_S):
            raise CivicError(f"--opcua {self.endpoint}: the server did not start within {START_TIMEOUT_S:g} s")
        if self._error:
            self._thread.join()
            raise CivicError(self._error)
        self.state = state

    def publish(self, ev: dict) -> None:
        """A verdict-change event (civic.events form), from any thread."""
        if self._loop is not None and not self._loop.is_closed():
            self._loop.call_soon_threadsafe(self._queue.put_nowait, ev)

    def close(self) -> None:
        if self._thread is None:
            return
        self._closing.set()
        if not self._ready.is_set():             # still building (a start-up error of the session):
            return                               # it stops once built; a daemon, it holds no exit up
        if self._loop is not None and not self._loop.is_closed():
            try:
                self._loop.call_soon_threadsafe(self._queue.put_nowait, None)
            except RuntimeError:
                pass
        self._thread.join(10.0)
        self._thread = None

    # -- the server's thread
    def _run(self) -> None:
        for name in ("asyncua", "asyncio"):       # its own warnings are not the user's business
            logging.getLogger(name).setLevel(logging.CRITICAL)
        try:
            asyncio.run(self._main())
        except Exception as exc:                   # never a traceback from the server thread
            if self._ready.is_set():               # it served: say why the tags stop following
                print(f"civic: the OPC UA server on {self.endpoint} stopped: {type(exc).__name__}: {exc}",
                      file=sys.stderr, flush=True)
            else:
                self._error = f"--opcua {self.endpoint}: {exc}"
                self._ready.set()

    async def _main(self) -> None:
        self._loop, self._queue = asyncio.get_running_loop(), asyncio.Queue()
        try:
            server = await self._serve()
        except CivicError as exc:
            self._error = str(exc)
            self._ready.set()
            return
        self._server = server
        self._ready.set()
        try:
            while not self._closing.is_set():
                try:
                    ev = await asyncio.wait_for(self._queue.get(), COUNTS_S)
                except TimeoutError:
                    ev = TICK
                if ev is None:
                    break
                if ev is not TICK:
                    await self._change(server, ev)
                    if not self._queue.empty():
                        continue           # a burst of changes first, in order; counts after it
                await self._sync(server)
        finally:
            # its clock task sleeps a second between ticks and stop() awaits it: cancelled first
            clock, server.iserver.time_task = server.iserver.time_task, None
            if clock is not None:
                clock.cancel()
            await server.stop()

    async def _serve(self):
        from asyncua import Server, ua

        server = Server(iserver=_cached_space_server(ReadOnlyUsers(self.users)))
        gc.disable()         # the standard address space is ~1e6 objects: 2x faster to build without GC
        try:
            await server.init()
        finally:
            gc.enable()
        server.allow_remote_admin(False)
        server.set_endpoint(self.endpoint)
        server.set_server_name("CIVIC")
        uri = f"{NAMESPACE}:{socket.gethostname()}"
        if self.cert:
            try:
                await server.load_certificate(self.cert)
                await server.load_private_key(self.key)
            except Exception as exc:
                raise CivicError(f"--opcua-cert/--opcua-key: cannot load ({type(exc).__name__}: {exc})") from None
            uri = certificate_uri(server.iserver.certificate) or uri     # clients check the two agree
            if public_der(server.iserver.certificate) != public_der(server.iserver.private_key):
                raise CivicError(f"--opcua-key {self.key}: not the key of {self.cert}")
            server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
            if self.trust:
                from asyncua.crypto.truststore import TrustStore
                from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
                store = TrustStore([Path(self.trust)], [])
                try:
                    await store.load()
                except Exception as exc:
                    raise CivicError(f"--opcua-trust {self.trust}: cannot load ({exc})") from None
                server.set_certificate_validator(CertificateValidator(
                    CertificateValidatorOptions.TRUSTED_VALIDATION | CertificateValidatorOptions.PEER_CLIENT, store))
        else:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        await server.set_application_uri(uri)
        server.set_identity_tokens([ua.UserNameIdentityToken] if self.users else [ua.AnonymousIdentityToken])
        self.ns = await server.register_namespace(NAMESPACE)
        self._root = await server.nodes.objects.add_folder(ua.NodeId("Plants", self.ns),
                                                             ua.QualifiedName("Plants", self.ns))
        self._etype = await server.create_custom_event_type(
            self.ns, EVENT_TYPE, ua.ObjectIds.BaseEventType,
            [("Plant", ua.VariantType.String), ("Monitor", ua.VariantType.String),
             ("From", ua.VariantType.String), ("To", ua.VariantType.String)])
        self._server_events = await server.get_event_generator(self._etype)
        try:
            await server.start()
        except OSError as exc:
            await server.iserver.stop()
            raise CivicError(f"--opcua {self.endpoint}: {exc.strerror or exc}") from None
        return server

    async def _cell(self, server, plant: str, monitor: str) -> _Cell:
        from asyncua import ua

        cell = self._cells.get((plant, monitor))
        if cell is not None:
            return cell
        pnode = self._plants.get(plant)
        if pnode is None:
            pnode = await self._root.add_object(ua.NodeId(f"Plants/{plant}", self.ns), ua.QualifiedName(plant, self.ns))
            self._plants[plant] = pnode
        path = f"Plants/{plant}/{monitor}"
        mnode = await pnode.add_object(ua.NodeId(path, self.ns), ua.QualifiedName(monitor, self.ns))
        variables = {}
        for name, (value, vtype) in VARIABLES.items():
            variables[name] = await mnode.add_variable(ua.NodeId(f"{path}/{name}", self.ns), ua.QualifiedName(
                name, self.ns), ua.Variant(value, getattr(ua.VariantType, vtype)))
        events = await server.get_event_generator(self._etype, mnode)
        cell = self._cells[(plant, monitor)] = _Cell(mnode, variables, events)
        return cell

    async def _write(self, server, cell: _Cell, values: dict, when: datetime) -> None:
        from asyncua import ua

        now = datetime.now(timezone.utc)
        for name, value in values.items():
            vtype = getattr(ua.VariantType, VARIABLES[name][1])
            await server.write_attribute_value(cell.variables[name].nodeid, ua.DataValue(
                ua.Variant(value, vtype), SourceTimestamp=when, ServerTimestamp=now))

    async def _change(self, server, ev: dict) -> None:
        """One verdict change: the tags in order, then the event."""
        plant, monitor, to, prev = ev["plant"], ev["monitor"], ev["to"], ev["from"]
        cell = await self._cell(server, plant, monitor)
        when = datetime.fromtimestamp(ev["t"], timezone.utc)
        await self._write(server, cell, {"Class": to, "ClassCode": CLASS_CODES[to], "Since": when,
                                         "Slope": ev["slope"], "Level": ev["level"]}, when)
        if to == "normal" and prev in (None, "normal"):
            return                                       # nothing raised, nothing to clear
        text = f"{plant} {monitor}: {prev or 'none'} -> {to}" + (" (cleared)" if to == "normal" else "")
        for gen in (cell.events, self._server_events):
            gen.event.Severity = SEVERITY[to]
            gen.event.SourceName = f"{plant}/{monitor}"
            gen.event.SourceNode = cell.node.nodeid
            gen.event.Plant, gen.event.Monitor, gen.event.From, gen.event.To = plant, monitor, prev or "none", to
            await gen.trigger(when, text)

    async def _sync(self, server) -> None:
        """Counts, and plants seen only by their counts so far, from the session's state."""
        if self.state is None:
            return
        for (plant, monitor), pm in list(self.state.cells.items()):
            cell = await self._cell(server, plant, monitor)
            counts = dict(pm.counts)
            if counts != cell.counts:
                values = {name: int(counts.get(code, 0)) for code, name in COUNT_VARIABLES}
                await self._write(server, cell, values, datetime.now(timezone.utc))
                cell.counts = counts
