// node-opcua's client for the cross-stack test, the twin of tests/opcua_client.py (same arguments,
// same protocol): node client.js ENDPOINT CELLS.json. Browses Objects/Plants/<plant>/<monitor> by
// browse names, subscribes to each Class (queue 10000) and to the Server object's events, prints
// "subscribed", and on a line on stdin prints {"changes", "events", "final"} as JSON.
"use strict";
const fs = require("fs");
const readline = require("readline");
const {
    OPCUAClient, AttributeIds, TimestampsToReturn, ClientMonitoredItem, makeBrowsePath,
    constructEventFilter, resolveNodeId, MessageSecurityMode, SecurityPolicy,
} = require("node-opcua-client");

const VARIABLES = ["Class", "ClassCode", "Since", "Normal", "Warning", "Error", "Slope", "Level"];
// a relative path's reserved characters ('.' in an IPv4 address among them) are escaped with '&'
const escape = (name) => name.replace(/[/.<>:#!&]/g, (c) => "&" + c);
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

function plain(value) {
    if (value instanceof Date) return value.toISOString();
    if (Array.isArray(value) && value.length === 2 && typeof value[0] === "number") {
        return value[0] * 2 ** 32 + value[1];        // UInt64 as [high, low]
    }
    return value;
}

async function main(endpoint, cellsFile) {
    const cells = JSON.parse(fs.readFileSync(cellsFile, "utf8"));
    const client = OPCUAClient.create({
        endpointMustExist: false,
        securityMode: MessageSecurityMode.None,
        securityPolicy: SecurityPolicy.None,
        connectionStrategy: { maxRetry: 100, initialDelay: 100, maxDelay: 500 },
    });
    await client.connect(endpoint);
    const session = await client.createSession();
    const namespaces = (await session.read({ nodeId: "ns=0;i=2255", attributeId: AttributeIds.Value })).value.value;
    const ns = namespaces.indexOf("urn:civic");
    if (ns < 0) throw new Error("no namespace urn:civic");

    const nodes = {};
    for (const cell of cells) {
        const [plant, monitor] = cell.split("/");
        const path = `/Objects/${ns}:Plants/${ns}:${escape(plant)}/${ns}:${escape(monitor)}`;
        for (let tries = 0; ; tries++) {
            const res = await session.translateBrowsePath(makeBrowsePath("RootFolder", path));
            if (res.targets && res.targets.length) { nodes[cell] = res.targets[0].targetId; break; }
            if (tries > 600) throw new Error(`not found: ${path}`);
            await sleep(50);
        }
    }
    const variable = async (cell, name) => {
        const res = await session.translateBrowsePath(makeBrowsePath(nodes[cell], `/${ns}:${name}`));
        return res.targets[0].targetId;
    };

    const sub = await session.createSubscription2({
        requestedPublishingInterval: 20, requestedLifetimeCount: 6000, requestedMaxKeepAliveCount: 20,
        maxNotificationsPerPublish: 0, publishingEnabled: true, priority: 1,
    });
    const changes = {};
    const events = [];
    for (const cell of cells) {
        changes[cell] = [];
        const item = ClientMonitoredItem.create(sub, { nodeId: await variable(cell, "Class"), attributeId: AttributeIds.Value },
            { samplingInterval: 0, discardOldest: false, queueSize: 10000 }, TimestampsToReturn.Both);
        item.on("changed", (dv) => changes[cell].push(dv.value.value));
    }
    const filter = constructEventFilter(["Severity", "Message", `${ns}:Plant`, `${ns}:Monitor`, `${ns}:From`, `${ns}:To`]);
    const ev = ClientMonitoredItem.create(sub, { nodeId: resolveNodeId("Server"), attributeId: AttributeIds.EventNotifier },
        { queueSize: 10000, filter, discardOldest: false }, TimestampsToReturn.Neither);
    ev.on("changed", (f) => events.push([f[0].value, f[1].value.text, f[2].value, f[3].value, f[4].value, f[5].value]));
    await sleep(300);
    console.log("subscribed");

    const rl = readline.createInterface({ input: process.stdin });
    await new Promise((resolve) => rl.once("line", resolve));
    rl.close();
    await sleep(300);
    const final = {};
    for (const cell of cells) {
        final[cell] = {};
        for (const name of VARIABLES) {
            const dv = await session.read({ nodeId: await variable(cell, name), attributeId: AttributeIds.Value });
            final[cell][name] = plain(dv.value.value);
        }
    }
    console.log(JSON.stringify({ changes, events, final }));
    await sub.terminate();
    await session.close();
    await client.disconnect();
}

main(...process.argv.slice(2)).catch((err) => { console.error(String(err)); process.exit(1); });
