#!/usr/bin/env node
// An independent Foxglove WebSocket client for Shoal's bridge tests.
//
// It uses Foxglove's own packages as the Foxglove app does: @foxglove/ws-protocol's
// FoxgloveClient for the protocol, @foxglove/omgidl-parser and
// @foxglove/omgidl-serialization to decode `omgidl`/`cdr` channels from the schema the
// server advertises, and protobufjs with the advertised FileDescriptorSet for
// `protobuf` channels (foxglove.LocationFix). It advertises nothing, subscribes to the
// topics asked for, prints one JSON line per decoded message and exits 0 after --count
// messages (exit 2 on a timeout, 1 on an error).
//
// Usage: node client.js --url ws://127.0.0.1:PORT/ --topics a,b --count N
//          [--timeout-ms 20000] [--subprotocol foxglove.websocket.v1] [--token TOKEN]
// Output lines: {"topic", "schemaName", "encoding", "logTimeNs", "message"} and, first,
// {"advertised": [{topic, encoding, schemaName, schemaEncoding}, ...]}.
"use strict";

const { FoxgloveClient } = require("@foxglove/ws-protocol");
const { parseIDL } = require("@foxglove/omgidl-parser");
const { MessageReader } = require("@foxglove/omgidl-serialization");
const protobuf = require("protobufjs");
const { FileDescriptorSet } = require("protobufjs/ext/descriptor");
const WebSocket = require("ws");

function args(argv) {
  const out = {
    timeoutMs: 20000,
    subprotocol: FoxgloveClient.SUPPORTED_SUBPROTOCOL,
  };
  for (let i = 2; i < argv.length; i += 2) {
    const [key, value] = [argv[i], argv[i + 1]];
    if (value === undefined) throw new Error(`${key} needs a value`);
    switch (key) {
      case "--url": out.url = value; break;
      case "--topics": out.topics = value.split(","); break;
      case "--count": out.count = Number(value); break;
      case "--timeout-ms": out.timeoutMs = Number(value); break;
      case "--subprotocol": out.subprotocol = value; break;
      case "--token": out.token = value; break;
      default: throw new Error(`unknown option ${key}`);
    }
  }
  if (!out.url || !out.topics || !(out.count > 0)) {
    throw new Error("--url, --topics and --count are required");
  }
  return out;
}

function decoderFor(channel) {
  if (channel.encoding === "cdr" && channel.schemaEncoding === "omgidl") {
    const reader = new MessageReader(channel.schemaName, parseIDL(channel.schema));
    return (bytes) => reader.readMessage(bytes);
  }
  if (channel.encoding === "protobuf") {
    const set = FileDescriptorSet.decode(Buffer.from(channel.schema, "base64"));
    const type = protobuf.Root.fromDescriptor(set).lookupType(channel.schemaName);
    return (bytes) =>
      type.toObject(type.decode(bytes), { longs: String, enums: String, defaults: true });
  }
  if (channel.encoding === "json") {
    const text = new TextDecoder();
    return (bytes) => JSON.parse(text.decode(bytes));
  }
  throw new Error(`${channel.topic}: no decoder for ${channel.encoding}/${channel.schemaEncoding}`);
}

function json(value) {
  return JSON.stringify(value, (_k, v) => (typeof v === "bigint" ? v.toString() : v));
}

function main() {
  const opts = args(process.argv);
  const headers = opts.token ? { Authorization: `Bearer ${opts.token}` } : {};
  const ws = new WebSocket(opts.url, [opts.subprotocol], { headers });
  const client = new FoxgloveClient({ ws });
  const wanted = new Set(opts.topics);
  const subscriptions = new Map(); // subscription id -> { channel, decode }
  let received = 0;

  const timer = setTimeout(() => {
    process.stderr.write(`timeout: ${received} of ${opts.count} messages\n`);
    process.exit(2);
  }, opts.timeoutMs);

  const fail = (error) => {
    process.stderr.write(`error: ${error && error.stack ? error.stack : error}\n`);
    clearTimeout(timer);
    process.exit(1);
  };

  client.on("error", fail);
  client.on("close", (event) => {
    if (received < opts.count) fail(`closed after ${received} messages (code ${event.code})`);
  });
  client.on("advertise", (channels) => {
    process.stdout.write(
      json({
        advertised: channels.map((c) => ({
          topic: c.topic,
          encoding: c.encoding,
          schemaName: c.schemaName,
          schemaEncoding: c.schemaEncoding,
        })),
      }) + "\n",
    );
    for (const channel of channels) {
      if (!wanted.has(channel.topic)) continue;
      try {
        const decode = decoderFor(channel);
        subscriptions.set(client.subscribe(channel.id), { channel, decode });
      } catch (error) {
        fail(error);
      }
    }
  });
  client.on("message", ({ subscriptionId, timestamp, data }) => {
    const sub = subscriptions.get(subscriptionId);
    if (!sub) return;
    const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
    let message;
    try {
      message = sub.decode(bytes);
    } catch (error) {
      fail(error);
      return;
    }
    process.stdout.write(
      json({
        topic: sub.channel.topic,
        schemaName: sub.channel.schemaName,
        encoding: sub.channel.encoding,
        logTimeNs: timestamp,
        message,
      }) + "\n",
    );
    received += 1;
    if (received >= opts.count) {
      clearTimeout(timer);
      client.close();
      process.exit(0);
    }
  });
}

try {
  main();
} catch (error) {
  process.stderr.write(`error: ${error.stack || error}\n`);
  process.exit(1);
}
