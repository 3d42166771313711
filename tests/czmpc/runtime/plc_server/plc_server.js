// A test-only OPC UA server on node-opcua (not asyncua, not czmpc): the CZ heater as a
// PLC serves it, typed as a PLC types its variables.
//
//   node plc_server.js CONFIG.json
//
// It listens on 127.0.0.1 only, prints "READY <endpoint>" when it accepts sessions, and
// stops by itself after `wall_limit_s` (or on SIGTERM/SIGINT). As it goes it appends one
// JSON line per event to `events` (flushed at once, so a test reads it mid-run):
//   {"ev": "write", "node", "type" (the OPC UA data type written), "value", "t"}
//   {"ev": "refused", "node", "code", "t"}, {"ev": "hang", "node", "t"},
//   {"ev": "session", "t"}, {"ev": "plant", "k", "t", "applied", "power", "good"}
// The test arms faults by writing JSON to the String node ns=3;s="Test"."Control":
//   {"heartbeat": 65530}          set the heartbeat (a WORD near its top)
//   {"refuse": [N, COUNT, CODE]}  refuse COUNT command writes from the N-th next one
//   {"hang": N}                   the N-th next command write never answers
//   {"source_timestamps": false}  publish without source timestamps
//   {"bad_quality": [N, COUNT]}   power Bad (BadSensorFailure) for COUNT samples from the N-th next
//
// The plant is the model file's own difference equation (written here from the model
// file's contract, independently of czmpc's simulators), noise-free:
//   A(q) dP = B(q) f(ds),  f(ds) = sum_i p_i ds^i,  ds = s - s0,  P = P0 + dP (>= 0)
// stepped every ts_s / time_scale wall seconds with the command the PLC holds.
//
// Nodes (namespace 3, Siemens-style string ids and numeric ids):
//   ns=3;s="DB_Heater"."Power"          Float   r    measured power [kW]
//   ns=3;s="DB_Heater"."TriacCmd"       Float   rw   TRIAC command [%]
//   ns=3;s="DB_Heater"."TriacRaw"       Int16   rw   TRIAC command, raw 0..27648 = 0..100 %
//   ns=3;s="DB_Heater"."TriacCmdRO"     Float   r    a command tag the PLC made read-only
//   ns=3;s="DB_Heater"."TriacCmdBool"   Boolean rw   a command tag of the wrong kind
//   ns=3;s="DB_Heater"."TriacApplied"   Float   r    TRIAC input applied [%]
//   ns=3;s="DB_Heater"."Setpoint"       Float   rw   power setpoint [kW]
//   ns=3;s="DB_Heater"."ModelHealth"    Float   rw   the controller's model health [-]
//   ns=3;i=1001                         UInt16  rw   heartbeat (a WORD), starts near its top
//   ns=3;i=1002                         String  rw   mode OFF/PREDICT/ON
//   ns=3;i=1003                         Int16   rw   mode 0/1/2
// The plant is driven by the command node written last ("TriacCmd" or "TriacRaw").
"use strict";

const fs = require("fs");
const path = require("path");
const {
    OPCUAServer, Variant, DataType, DataValue, StatusCodes, SecurityPolicy,
    MessageSecurityMode, OPCUACertificateManager, WellKnownRoles, PermissionType,
    makeRoles
} = require("node-opcua");

const config = JSON.parse(fs.readFileSync(process.argv[2], "utf-8"));
const model = JSON.parse(fs.readFileSync(config.model, "utf-8"));
const RAW_FULL_SCALE = 27648;      // an S7 analog value's 100 %

// ---- the plant: the model's difference equation, noise-free ----
const A = model.A, B = model.B, poly = model.input_poly;
const s0 = model.operating_point.triac_pct, p0 = model.operating_point.power_kw;
const f = (ds) => poly.reduce((acc, p, i) => acc + p * Math.pow(ds, i + 1), 0);
const sum = (v) => v.reduce((a, b) => a + b, 0);
let applied = config.initial_triac_pct;
let k = 0;   // plant samples so far
const w0 = f(applied - s0);
const y0 = sum(B) * w0 / sum(A);
const yHist = new Array(A.length).fill(y0);          // yHist[i] = dP_{k-i}
const wHist = new Array(B.length).fill(w0);          // wHist[j] = w_{k-j}
function plantStep(triacPct) {
    wHist.unshift(f(triacPct - s0)); wHist.pop();
    let y = 0;
    for (let j = 0; j < B.length; j++) y += B[j] * wHist[j];
    for (let i = 1; i < A.length; i++) y -= A[i] * yHist[i - 1];
    yHist.unshift(y); yHist.pop();
    return Math.max(0, p0 + y);
}

// ---- what the test reads: one JSON line per event ----
const eventsFd = fs.openSync(config.events, "a");
function record(event) {
    fs.writeSync(eventsFd, JSON.stringify({ ...event, t: Date.now() / 1000 }) + "\n");
}
const faults = { refuse: null, hang: null, source_timestamps: true, bad_quality: null };
let drive = "TriacCmd";

const now = () => new Date();
const values = {};   // node name -> DataValue served
function dv(dataType, value, statusCode = StatusCodes.Good, stamp = now()) {
    return new DataValue({
        value: new Variant({ dataType, value }), statusCode,
        sourceTimestamp: stamp, serverTimestamp: stamp,
    });
}

// A server without source timestamps: node-opcua's address space always keeps one, so the
// fault strips it where the Read service applies the requested timestamps (the server
// timestamp stays: for a published node, its time of publication).
const dataValueModule = require("node-opcua-data-value/dist/datavalue.js");   // the index re-exports it live
for (const name of ["apply_timestamps", "apply_timestamps_no_copy"]) {
    const original = dataValueModule[name];
    dataValueModule[name] = function (...args) {
        const result = original.apply(this, args);
        const out = result || args[0];
        if (!faults.source_timestamps && out && args[2] === 13 /* AttributeIds.Value */) {
            out.sourceTimestamp = null;
            out.sourcePicoseconds = 0;
        }
        return result;
    };
}

let commandWrites = 0;
const COMMANDS = new Set(["TriacCmd", "TriacRaw"]);
function setter(name) {
    return async function (dataValue) {
        const type = DataType[dataValue.value.dataType];
        if (COMMANDS.has(name)) {
            commandWrites += 1;
            if (faults.hang !== null && commandWrites === faults.hang) {
                record({ ev: "hang", node: name });
                return new Promise(() => {});   // never answers: the call hangs
            }
            const refuse = faults.refuse;   // [first, count, code] in command writes
            if (refuse && commandWrites >= refuse[0] && commandWrites < refuse[0] + refuse[1]) {
                record({ ev: "refused", node: name, code: refuse[2] });
                return StatusCodes[refuse[2]];
            }
            drive = name;
        }
        record({ ev: "write", node: name, type, value: dataValue.value.value });
        values[name] = dv(dataValue.value.dataType, dataValue.value.value);
        return StatusCodes.Good;
    };
}

function control(dataValue) {
    const order = JSON.parse(dataValue.value.value);
    if (order.heartbeat !== undefined) values.Heartbeat = dv(DataType.UInt16, order.heartbeat);
    if (order.refuse) faults.refuse = [commandWrites + order.refuse[0], order.refuse[1], order.refuse[2]];
    if (order.hang !== undefined) faults.hang = commandWrites + order.hang;
    if (order.source_timestamps !== undefined) faults.source_timestamps = order.source_timestamps;
    if (order.bad_quality) faults.bad_quality = [k + order.bad_quality[0], order.bad_quality[1]];
    values.Control = dv(DataType.String, dataValue.value.value);
    record({ ev: "control", order });
    return StatusCodes.Good;
}

// ---- roles: anonymous sessions (plain endpoint) and 'mpc' may write, 'viewer' may only
// read. node-opcua evaluates every session's permissions with the Anonymous role added,
// so Anonymous itself may only read, and anonymous sessions get Operator besides
// (the role-policy override in main()).
const users = (config.security && config.security.users) || {};
const userManager = {
    isValidUser: (name, password) => users[name] !== undefined && users[name].password === password,
    getUserRoles: (name) => makeRoles(users[name] && users[name].write
        ? [WellKnownRoles.AuthenticatedUser, WellKnownRoles.Operator]
        : [WellKnownRoles.AuthenticatedUser, WellKnownRoles.Observer]),
};
const READ = PermissionType.Browse | PermissionType.Read | PermissionType.ReadRolePermissions;
const WRITE = READ | PermissionType.Write;
const writablePermissions = [
    { roleId: WellKnownRoles.Anonymous, permissions: READ },
    { roleId: WellKnownRoles.AuthenticatedUser, permissions: READ },
    { roleId: WellKnownRoles.Observer, permissions: READ },
    { roleId: WellKnownRoles.Operator, permissions: WRITE },
];

async function main() {
    const options = {
        port: config.port, host: "127.0.0.1", hostname: "127.0.0.1",
        resourcePath: "/plc", allowAnonymous: true, userManager,
        serverInfo: { applicationUri: "urn:test:plant", productUri: "urn:test:plc-server" },
        buildInfo: { productName: "czmpc test PLC (node-opcua)" },
        securityPolicies: [SecurityPolicy.None],
        securityModes: [MessageSecurityMode.None],
    };
    if (config.security) {
        const pki = config.security.pki_dir;
        const manager = new OPCUACertificateManager({ rootFolder: pki, automaticallyAcceptUnknownCertificate: false });
        await manager.initialize();
        await manager.trustCertificate(fs.readFileSync(config.security.trusted_client));
        Object.assign(options, {
            certificateFile: config.security.certificate, privateKeyFile: config.security.private_key,
            serverCertificateManager: manager,
            securityPolicies: [SecurityPolicy.None, SecurityPolicy.Basic256Sha256],
            securityModes: [MessageSecurityMode.None, MessageSecurityMode.SignAndEncrypt],
        });
    }
    const server = new OPCUAServer(options);
    await server.initialize();
    server.setRolePolicyOverride({
        getUserRoles: (name) => name === "anonymous"
            ? makeRoles([WellKnownRoles.Anonymous, WellKnownRoles.Operator]) : null,
    });
    const space = server.engine.addressSpace;
    space.registerNamespace("urn:test:unused");          // ns=2, so that the PLC's is ns=3
    const ns = space.registerNamespace("urn:test:plc");
    const folder = ns.addObject({ organizedBy: space.rootFolder.objects, browseName: "DB_Heater" });

    // Writable nodes are bound to `values` (the setter sees every write); read-only ones
    // are published with setValueFromSource, so that their server timestamp is the time
    // of publication (as a server that stamps value changes), not the time of the read.
    const published = {};
    function add(name, nodeId, dataType, initial, { writable = true, set = null } = {}) {
        values[name] = dv(dataType, initial);
        const access = writable ? "CurrentRead | CurrentWrite" : "CurrentRead";
        const variable = ns.addVariable({
            componentOf: folder, browseName: name, nodeId, dataType: DataType[dataType],
            accessLevel: access, userAccessLevel: access, minimumSamplingInterval: 0,
            rolePermissions: writable ? writablePermissions : undefined,
            value: writable ? {
                timestamped_get: () => values[name],
                timestamped_set: set || setter(name),
            } : new Variant({ dataType, value: initial }),
        });
        if (!writable) published[name] = variable;
    }
    function publish(name, dataType, value, statusCode = StatusCodes.Good) {
        published[name].setValueFromSource(new Variant({ dataType, value }), statusCode, now());
    }
    const raw0 = Math.round(applied / 100 * RAW_FULL_SCALE);
    add("Power", 's="DB_Heater"."Power"', DataType.Float, plantStep(applied), { writable: false });
    add("TriacCmd", 's="DB_Heater"."TriacCmd"', DataType.Float, applied);
    add("TriacRaw", 's="DB_Heater"."TriacRaw"', DataType.Int16, raw0);
    add("TriacCmdRO", 's="DB_Heater"."TriacCmdRO"', DataType.Float, applied, { writable: false });
    add("TriacCmdBool", 's="DB_Heater"."TriacCmdBool"', DataType.Boolean, false);
    add("TriacApplied", 's="DB_Heater"."TriacApplied"', DataType.Float, applied, { writable: false });
    add("Setpoint", 's="DB_Heater"."Setpoint"', DataType.Float, config.setpoint_kw);
    add("ModelHealth", 's="DB_Heater"."ModelHealth"', DataType.Float, 0);
    add("Heartbeat", "i=1001", DataType.UInt16, config.heartbeat_start);
    add("Mode", "i=1002", DataType.String, "ON");
    add("ModeInt", "i=1003", DataType.Int16, 2);
    add("Control", 's="Test"."Control"', DataType.String, "{}", { set: async (d) => control(d) });

    server.on("session_activated", () => record({ ev: "session" }));
    await server.start();
    const endpoint = `opc.tcp://127.0.0.1:${config.port}/plc`;
    process.stdout.write(`READY ${endpoint}\n`);

    // ---- the plant's clock ----
    const period = 1000 * config.ts_s / config.time_scale;
    const t0 = Date.now();
    let stopping = false;
    function commandPct() {
        const held = values[drive].value.value;
        const pct = drive === "TriacRaw" ? 100 * held / RAW_FULL_SCALE : held;
        return Math.min(100, Math.max(0, pct));
    }
    function tick() {
        if (stopping) return;
        applied = commandPct();
        const power = plantStep(applied);
        k += 1;
        const plantTime = k * config.ts_s;
        const bad = faults.bad_quality;
        const good = !(bad && k >= bad[0] && k < bad[0] + bad[1]);
        publish("Power", DataType.Float, power, good ? StatusCodes.Good : StatusCodes.BadSensorFailure);
        publish("TriacApplied", DataType.Float, applied);
        record({ ev: "plant", k, plant_time_s: plantTime, applied, power, good });
        setTimeout(tick, Math.max(0, t0 + (k + 1) * period - Date.now()));
    }
    setTimeout(tick, period);

    async function stop() {
        if (stopping) return;
        stopping = true;
        await server.shutdown(100);
        process.exit(0);
    }
    process.on("SIGTERM", stop);
    process.on("SIGINT", stop);
    setTimeout(stop, 1000 * config.wall_limit_s);
}

main().catch((err) => {
    process.stderr.write(`plc_server: ${err.stack || err}\n`);
    process.exit(3);
});
