"""An OPC UA client (asyncua's) for the tests, run as a script beside the server:

    python opcua_client.py ENDPOINT CELLS.json [USER PASSWORD CERT KEY]

It connects (retrying while the server starts), waits until every (plant, monitor) of CELLS.json
is under Objects/Plants, found by browse names, subscribes to each one's Class (queue 10000) and
to the events of the Server object, prints "subscribed", and on a line on stdin prints one JSON
object: {"changes": {"plant/monitor": [Class values in arrival order]}, "events": [[severity,
message, plant, monitor, from, to] ...], "final": {"plant/monitor": {variable: value}}}.
"""
from __future__ import annotations

import asyncio
import logging
import json
import sys
import time

from asyncua import Client, ua

VARIABLES = ("Class", "ClassCode", "Since", "Normal", "Warning", "Error", "Slope", "Level")


class Collect:
    def __init__(self):
        self.names, self.changes, self.events = {}, {}, []

    def datachange_notification(self, node, val, data):
        self.changes.setdefault(self.names[node.nodeid], []).append(val)

    def event_notification(self, ev):
        self.events.append([ev.Severity, ev.Message.Text, ev.Plant, ev.Monitor, ev.From, ev.To])


async def find(client, ns, cells, timeout=30.0):
    """Browse until each cell's monitor object exists; {cell: node}."""
    end = time.monotonic() + timeout
    while True:
        found = {}
        for cell in cells:
            plant, monitor = cell.split("/")
            try:
                found[cell] = await client.nodes.objects.get_child([f"{ns}:Plants", f"{ns}:{plant}", f"{ns}:{monitor}"])
            except ua.UaError:
                break
        if len(found) == len(cells):
            return found
        if time.monotonic() > end:
            raise SystemExit(f"not under Plants after {timeout:g} s: {sorted(set(cells) - set(found))}")
        await asyncio.sleep(0.05)


async def connect(client, timeout=20.0):
    end = time.monotonic() + timeout
    while True:
        try:
            await client.connect()
            return
        except (OSError, asyncio.TimeoutError):
            if time.monotonic() > end:
                raise
            await asyncio.sleep(0.1)


async def main(endpoint, cells_file, user=None, password=None, cert=None, key=None):
    logging.getLogger("asyncua").setLevel(logging.ERROR)
    cells = json.load(open(cells_file))
    client = Client(endpoint)
    if cert:
        await client.set_security_string(f"Basic256Sha256,SignAndEncrypt,{cert},{key}")
    if user:
        client.set_user(user)
        client.set_password(password)
    await connect(client)
    try:
        ns = await client.get_namespace_index("urn:civic")
        nodes = await find(client, ns, cells)
        got = Collect()
        sub = await client.create_subscription(20, got)
        classes = {}
        for cell, node in nodes.items():
            classes[cell] = await node.get_child(f"{ns}:Class")
            got.names[classes[cell].nodeid] = cell
        await sub.subscribe_data_change(list(classes.values()), queuesize=10000)
        server_events = client.get_node(ua.ObjectIds.Server)
        etype = await client.nodes.base_event_type.get_child(f"{ns}:CivicVerdictChangeEventType")
        await sub.subscribe_events(server_events, etype, queuesize=10000)
        await asyncio.sleep(0.3)
        print("subscribed", flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.readline)
        await asyncio.sleep(0.3)
        final = {}
        for cell, node in nodes.items():
            final[cell] = {}
            for name in VARIABLES:
                value = await (await node.get_child(f"{ns}:{name}")).read_value()
                final[cell][name] = value.isoformat() if hasattr(value, "isoformat") else value
        print(json.dumps({"changes": got.changes, "events": got.events, "final": final}), flush=True)
    finally:
        await client.disconnect()


if __name__ == "__main__":
    asyncio.run(main(*sys.argv[1:]))
