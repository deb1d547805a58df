// A palpa client in Node.js, written from docs/wire.md alone (zeromq.js + @msgpack/msgpack, nothing of palpa's).
// Run against a live launch/talker_listener.yaml, it does five jobs and prints one JSON line per job:
//   subscribe  take `chatter` and decode it (single messages and batches)
//   publish    publish on `chatter` so that the listener counts no gap and no decode error; one bad payload
//              then counts one decode error
//   latch      set a latched value, read it as a late joiner, cancel the watch (UNWATCH), see a refusal's reason
//   params     get and set the talker's rate_hz through its parameter services, and see the rate change
//   heartbeat  heartbeat as `js_node` (then `palpa node list` shows it) until SIGINT/SIGTERM: a last heartbeat
//              saying `leaving`, exit 0
// Exit status: 0 when every job passed, 1 otherwise (a failed job's line says why), 2 on a usage error.
//   node client.mjs [--bus ADDRESS] [--deadline SECONDS]
import * as zmq from "zeromq"
import { Decoder, Encoder } from "@msgpack/msgpack"
import fs from "node:fs"
import os from "node:os"
import path from "node:path"
import crypto from "node:crypto"

const NODE = "js_node"
// 64-bit integers as BigInt: every header integer is a uint64 on the wire (docs/wire.md, wire version 2), so
// header seq, stamp, inc and at always decode as BigInt and compare with ===
const decoder = new Decoder({ useBigInt64: true })
const encoder = new Encoder({ useBigInt64: true })
const pack = (v) => Buffer.from(encoder.encode(v))
const unpack = (b) => decoder.decode(b)
const nowNs = () => BigInt(Date.now()) * 1_000_000n
const json = (v) => JSON.stringify(v, (k, x) => (typeof x === "bigint" ? String(x) : x))
const sleep = (ms) => new Promise((r) => setTimeout(r, ms))

// ---- finding the bus (docs/wire.md, "Finding the bus") -------------------------------------------------
function parseAddress(text) {
  text = text.trim()
  if (text.includes("=")) {
    const ep = Object.fromEntries(text.split(";").filter(Boolean).map((p) => {
      const i = p.indexOf("=")
      return [p.slice(0, i), p.slice(i + 1)]
    }))
    if (!ep.pub || !ep.sub || !ep.latch) throw new Error(`bus address ${text}: needs pub=, sub= and latch=`)
    return ep
  }
  if (text.startsWith("ipc://")) return { pub: `${text}.pub`, sub: `${text}.sub`, latch: `${text}.latch` }
  const m = /^tcp:\/\/(.+):(\d+)$/.exec(text)
  if (m) {
    const port = Number(m[2])
    return { pub: `tcp://${m[1]}:${port}`, sub: `tcp://${m[1]}:${port + 1}`, latch: `tcp://${m[1]}:${port + 2}` }
  }
  throw new Error(`bus address ${text}: expected ipc://PATH, tcp://HOST:PORT or pub=..;sub=..;latch=..`)
}

function privateDir() {
  const xdg = process.env.XDG_RUNTIME_DIR
  if (xdg) {
    try {
      const st = fs.statSync(xdg)
      if (st.isDirectory() && st.uid === process.getuid() && (st.mode & 0o077) === 0) return path.join(xdg, "palpa")
    } catch { /* not usable: the /tmp form */ }
  }
  return `/tmp/palpa-${process.getuid()}`
}

function findBus(argBus) {
  if (argBus) return [parseAddress(argBus), "--bus"]
  if (process.env.PALPA_BUS) return [parseAddress(process.env.PALPA_BUS), "$PALPA_BUS"]
  // the running launches: one JSON entry each in <private dir>/launches (docs/wire.md, "Finding the bus")
  const folder = process.env.PALPA_CURRENT || path.join(privateDir(), "launches")
  const live = []
  let names = []
  try { names = fs.readdirSync(folder).filter((n) => n.endsWith(".json")).sort() } catch { /* none runs */ }
  for (const name of names) {
    try {
      const entry = JSON.parse(fs.readFileSync(path.join(folder, name), "utf8"))
      process.kill(entry.pid, 0) // a killed launcher leaves its entry behind: trust it only while its pid lives
      live.push(entry)
    } catch { /* unreadable, or its launcher is gone */ }
  }
  if (live.length > 1) { // never guess which graph to act on
    throw new Error(`${live.length} launches are running (${live.map((e) => e.run_dir).join(", ")}): say which with --bus`)
  }
  if (live.length === 1) return [parseAddress(live[0].bus), `the launch in ${live[0].run_dir}`]
  return [parseAddress(`ipc://${privateDir()}/bus`), "the default bus"]
}

// ---- receiving -----------------------------------------------------------------------------------------
// One reader per socket (zeromq.js allows one pending receive); what it reads waits in a queue until taken, as
// split(frames) makes it (the SUB's inbox holds messages: a batch is split into its messages).
class Inbox {
  constructor(sock, split = (frames) => [frames], limit = 20000) {
    this.items = []
    this.wakers = new Set()
    this.closed = false
    ;(async () => {
      try {
        for await (const frames of sock) {
          let items
          try {
            items = split(frames)
          } catch {
            continue // not msgpack: a malformed message is dropped (a palpa node counts it as a decode error)
          }
          this.items.push(...items)
          while (this.items.length > limit) this.items.shift()
          for (const w of this.wakers) w()
        }
      } catch { /* socket closed */ }
      this.closed = true
      for (const w of this.wakers) w()
    })()
  }

  // the first item for which fn returns something (not undefined), oldest first; what it passes over is dropped
  // (a take waits for what comes next). Throws after ms.
  async take(fn, ms, what) {
    const deadline = Date.now() + ms
    for (;;) {
      while (this.items.length) {
        const got = fn(this.items.shift())
        if (got !== undefined) return got
      }
      const left = deadline - Date.now()
      if (left <= 0 || this.closed) throw new Error(`timed out after ${ms} ms waiting for ${what}`)
      await new Promise((resolve) => {
        const done = () => { clearTimeout(timer); this.wakers.delete(done); resolve() }
        const timer = setTimeout(done, left)
        this.wakers.add(done)
      })
    }
  }
}

// zeromq.js takes one send at a time per socket: queue them
const chains = new WeakMap()
function send(sock, frames) {
  const next = (chains.get(sock) ?? Promise.resolve()).then(() => sock.send(frames))
  chains.set(sock, next.catch(() => {}))
  return next
}

// every message in one envelope: [{topic, header, payload, blobs}] (a batch carries arrays in frames 1 and 2)
function messages(frames) {
  if (frames.length < 3) return []
  const topic = frames[0].toString("utf8")
  const first = frames[1][0]
  const isArray = (first & 0xf0) === 0x90 || first === 0xdc || first === 0xdd
  if (!isArray) return [{ topic, header: unpack(frames[1]), payload: unpack(frames[2]), blobs: frames.slice(3) }]
  const headers = unpack(frames[1])
  const payloads = unpack(frames[2])
  return headers.map((header, i) => ({ topic, header, payload: payloads[i], blobs: [] }))
}

// ---- the client ----------------------------------------------------------------------------------------
class Client {
  constructor(ep) {
    this.ep = ep
    this.pub = new zmq.XPublisher() // an XPUB hears which prefixes are subscribed (docs/wire.md)
    this.sub = new zmq.Subscriber()
    this.latch = new zmq.Dealer()
    for (const s of [this.pub, this.sub, this.latch]) s.linger = 0
    this.pub.connect(ep.pub)
    this.sub.connect(ep.sub)
    this.latch.connect(ep.latch)
    this.inbox = new Inbox(this.sub, messages)
    this.latchInbox = new Inbox(this.latch)
    this.subscribed = new Set() // each subscription arrives once per connection: remember them
    this.seq = new Map() // topic -> last seq sent: seq counts per (this node, topic)
    this.counters = {}
    this.subscribes = {}
    this.publishes = { "_palpa/heartbeat": "Heartbeat" }
    this.started = Date.now()
    ;(async () => {
      try {
        for await (const [msg] of this.pub) {
          const prefix = msg.subarray(1).toString("utf8")
          if (msg[0] === 1) this.subscribed.add(prefix)
          else if (msg[0] === 0) this.subscribed.delete(prefix)
        }
      } catch { /* closed */ }
    })()
  }

  covered(topic) {
    for (const p of this.subscribed) if (topic.startsWith(p)) return true
    return false
  }

  async waitCovered(topics, ms) {
    const deadline = Date.now() + ms
    while (!topics.every((t) => this.covered(t))) {
      if (Date.now() > deadline) throw new Error(`no subscription to ${topics.filter((t) => !this.covered(t))} within ${ms} ms`)
      await sleep(10)
    }
  }

  subscribe(topic, type) {
    this.sub.subscribe(topic)
    this.subscribes[topic] = type
  }

  header(topic, type, extra = {}) {
    const seq = (this.seq.get(topic) ?? 0n) + 1n
    this.seq.set(topic, seq)
    return { type, seq, stamp: nowNs(), node: NODE, ...extra }
  }

  async publish(topic, type, payload, rawPayload) {
    this.publishes[topic] = type
    await send(this.pub, [topic, pack(this.header(topic, type)), rawPayload ?? pack(payload)])
  }

  // fn(msg) of the next message on exactly `topic` for which that is not undefined
  async next(topic, ms, fn = (m) => m) {
    // subscriptions match by prefix: compare the topic exactly
    return this.inbox.take((m) => (m.topic === topic ? fn(m) : undefined), ms, `a message on ${topic}`)
  }

  // the next reply `verb` (on `topic`, if given) from the latch cache, read from `inbox`
  async latchReply(inbox, verb, ms, topic) {
    return inbox.take((f) => (f[0].toString() === verb && (topic === undefined || f[1].toString() === topic) ? f : undefined),
      ms, `${verb} ${topic ?? ""} from the latch cache`)
  }

  async heartbeat(state = "running") {
    const topic = "_palpa/heartbeat"
    const next = (this.seq.get(topic) ?? 0n) + 1n
    const sent = Object.fromEntries(Object.keys(this.publishes).map((t) => [t, this.seq.get(t) ?? 0n]))
    sent[topic] = next // the heartbeat counts itself
    await this.publish(topic, "Heartbeat", {
      node: NODE, pid: process.pid, host: os.hostname(), publishes: this.publishes, subscribes: this.subscribes,
      counters: this.counters, sent, uptime_s: (Date.now() - this.started) / 1000, state, direct: [], services: {},
      wire: 2,
    })
  }

  close() {
    for (const s of [this.pub, this.sub, this.latch]) s.close()
  }
}

// the next heartbeat of `node`
async function heartbeatOf(c, node, ms) {
  return c.next("_palpa/heartbeat", ms, (m) => (m.payload.node === node ? m.payload : undefined))
}

// ---- the five jobs -------------------------------------------------------------------------------------
async function jobSubscribe(c) {
  const got = []
  while (got.length < 5) {
    got.push(await c.next("chatter", 10000, (m) => (m.header.node === "talker" ? m : undefined)))
  }
  const seqs = got.map((m) => m.header.seq)
  if (!seqs.every((s) => typeof s === "bigint")) throw new Error(`seq not a uint64: ${seqs.map((s) => typeof s)}`)
  if (!got.every((m) => m.header.type === "Text" && typeof m.payload.text === "string")) {
    throw new Error(`not Text: ${json(got.map((m) => m.header.type))}`)
  }
  for (let i = 1; i < seqs.length; i++) {
    if (seqs[i] !== seqs[i - 1] + 1n) throw new Error(`talker's seq not consecutive: ${seqs}`)
  }
  return { received: got.length, text: got[0].payload.text, first_seq: String(seqs[0]) }
}

async function jobPublish(c) {
  const n = 20
  await c.waitCovered(["chatter"], 10000) // the listener's subscription has reached us
  const mine = []
  for (let i = 1; i <= n; i++) {
    const text = `from js ${String(i).padStart(4, "0")} ${"x".repeat(20)}`
    mine.push(text.length)
    await c.publish("chatter", "Text", { text, stamp_ns: nowNs() })
  }
  // the listener republishes each text's length on chatter_len: ours are 34 long, the talker's much shorter
  let echoed = 0
  while (echoed < n) {
    await c.next("chatter_len", 10000, (m) => (m.payload.text === String(mine[0]) ? true : undefined))
    echoed++
  }
  // the listener's next heartbeat counts everything before it (one publisher socket: in order)
  const good = (await heartbeatOf(c, "listener", 5000)).counters.chatter
  // a payload that is not a Text (text must be a string): a decode error, not a delivery
  await c.publish("chatter", "Text", null, pack({ text: 42 }))
  let bad
  for (let tries = 0; tries < 5; tries++) {
    bad = (await heartbeatOf(c, "listener", 5000)).counters.chatter
    if (Number(bad.decode_errors) >= 1) break
  }
  // payload integers come in the smallest width: small counters decode as numbers (BigInt above 32 bits)
  if (Number(good.gaps) !== 0 || Number(good.decode_errors) !== 0) throw new Error(`listener counted ${json(good)}`)
  if (Number(bad.decode_errors) !== 1 || Number(bad.gaps) !== 0) throw new Error(`after one bad payload: ${json(bad)}`)
  return { sent: n, echoed, listener_after_good: good, listener_after_bad: bad }
}

async function jobLatch(c) {
  const topic = "js/latched"
  const value = { text: "set by js", stamp_ns: nowNs() }
  await send(c.latch, ["SET", topic, pack(c.header(topic, "Text", { latched: true })), pack(value)])
  // a value of a topic nobody declared latched is refused, with a reason in plain text
  await send(c.latch, ["SET", "js/notlatched", pack(c.header("js/notlatched", "Text")), pack(value)])
  const err = await c.latchReply(c.latchInbox, "ERR", 5000)
  const reason = err[2].toString("utf8")
  if (err[1].toString() !== "js/notlatched" || reason.includes("b'")) throw new Error(`ERR ${err.map(String)}`)

  // the late joiner: its own DEALER connection; subscribe first, then GET
  const late = new zmq.Dealer()
  late.linger = 0
  late.connect(c.ep.latch)
  const lateInbox = new Inbox(late)
  try {
    await send(late, ["GET", topic])
    const val = await c.latchReply(lateInbox, "VAL", 5000)
    const [hdr, payload] = [unpack(val[2]), unpack(val[3])]
    if (val[1].toString() !== topic || payload.text !== value.text || hdr.seq !== 1n || hdr.node !== NODE) {
      throw new Error(`late joiner got ${val[1]} ${json(payload)} seq ${hdr.seq}`)
    }
    // the watch pushes later SETs; UNWATCH ends it. PING orders it: the setter's PONG says its SET was handled
    // (and any push sent), the late joiner's PONG comes after whatever was pushed to it.
    const pushedBefore = async () => {
      await send(c.latch, ["SET", topic, pack(c.header(topic, "Text", { latched: true })), pack(value)])
      await send(c.latch, ["PING", "set"])
      await c.latchReply(c.latchInbox, "PONG", 5000)
      await send(late, ["PING", "late"])
      const first = await lateInbox.take((f) => (["VAL", "PONG"].includes(f[0].toString()) ? f : undefined), 5000,
        "VAL or PONG")
      if (first[0].toString() === "VAL") await c.latchReply(lateInbox, "PONG", 5000)
      return first[0].toString() === "VAL"
    }
    const watched = await pushedBefore()
    await send(late, ["UNWATCH", topic])
    const unwatched = await pushedBefore()
    if (!watched || unwatched) throw new Error(`pushed while watching: ${watched}, after UNWATCH: ${unwatched}`)
    return { late_joiner_got: payload.text, pushed_while_watching: watched, pushed_after_unwatch: unwatched,
      refusal: reason }
  } finally {
    late.close()
  }
}

async function jobParams(c) {
  // find the servers in the directory (the latch cache)
  const id = `${NODE}.${crypto.randomBytes(4).toString("hex")}`
  const call = async (name, type, request) => {
    const infoTopic = `_palpa/srv/${name}`
    await send(c.latch, ["GET", infoTopic])
    const info = unpack((await c.latchReply(c.latchInbox, "VAL", 5000, infoTopic))[3])
    await send(c.latch, ["UNWATCH", infoTopic]) // found: later announcements need not be pushed to us
    if (info.alive === false || info.request_type !== type) throw new Error(`no server of ${name}: ${json(info)}`)
    const replyTopic = `${name}/reply/${id}`
    if (!(replyTopic in c.subscribes)) c.subscribe(replyTopic, info.response_type)
    await c.waitCovered([`${name}/request`, replyTopic], 10000)
    const h = c.header(`${name}/request`, type) // seq per (client id, service): per request topic
    h.node = id
    await send(c.pub, [`${name}/request`, pack(h), pack(request)])
    return c.next(replyTopic, 5000, (m) => (m.header.seq === h.seq ? m : undefined)) // BigInt === BigInt
  }
  const intervals = async () => {
    const stamps = []
    while (stamps.length < 12) {
      stamps.push(await c.next("chatter", 10000, (m) => (m.header.node === "talker" ? m.payload.stamp_ns : undefined)))
    }
    const d = stamps.slice(1).map((s, i) => Number(BigInt(s) - BigInt(stamps[i])) / 1e6).sort((a, b) => a - b)
    return d[Math.floor(d.length / 2)]
  }
  const got = await call("_palpa/param/talker/get", "ParamGet", {})
  if (got.header.type !== "ParamValues") throw new Error(`get answered ${got.header.type}`)
  const before = got.payload.values.rate_hz
  const medianBefore = await intervals()
  const set = await call("_palpa/param/talker/set", "ParamSet", { values: { rate_hz: before * 2 } })
  if (set.header.type !== "ParamValues" || set.payload.values.rate_hz !== before * 2) {
    throw new Error(`set answered ${set.header.type} ${json(set.payload)}`)
  }
  await c.inbox.take(() => undefined, 0, "nothing").catch(() => {}) // forget chatter sent before the change
  await intervals() // the first intervals may straddle the change
  const medianAfter = await intervals()
  const bad = await call("_palpa/param/talker/set", "ParamSet", { values: { rate_hz: "fast" } })
  if (bad.header.type !== "ServiceFault" || bad.payload.kind !== "bad_request") {
    throw new Error(`a bad rate answered ${bad.header.type} ${json(bad.payload)}`)
  }
  const again = await call("_palpa/param/talker/get", "ParamGet", {})
  const ratio = medianAfter / medianBefore
  if (!(ratio > 0.35 && ratio < 0.7)) throw new Error(`median interval ${medianBefore} ms -> ${medianAfter} ms`)
  return { rate_hz_before: before, rate_hz_after: again.payload.values.rate_hz, median_ms_before: medianBefore,
    median_ms_after: medianAfter, bad_value: bad.payload.kind }
}

// ---- main ----------------------------------------------------------------------------------------------
function args(argv) {
  const out = { bus: "", deadline: 120 }
  for (let i = 0; i < argv.length; i++) {
    if (argv[i] === "--bus") out.bus = argv[++i]
    else if (argv[i] === "--deadline") out.deadline = Number(argv[++i])
    else throw new Error(`unknown argument ${argv[i]} (usage: client.mjs [--bus ADDRESS] [--deadline SECONDS])`)
  }
  if (!(out.deadline > 0)) throw new Error("--deadline must be a positive number of seconds")
  return out
}

async function main() {
  let opts, ep, where
  try {
    opts = args(process.argv.slice(2))
    ;[ep, where] = findBus(opts.bus)
  } catch (e) {
    console.error(`client.mjs: ${e.message}`)
    process.exit(2)
  }
  const overall = setTimeout(() => {
    console.log(json({ job: "all", ok: false, error: `not done within ${opts.deadline} s` }))
    process.exit(1)
  }, opts.deadline * 1000)
  console.log(json({ bus: ep, found_by: where }))
  const c = new Client(ep)
  c.subscribe("chatter", "Text")
  c.subscribe("chatter_len", "Text")
  c.subscribe("_palpa/heartbeat", "Heartbeat")
  const beat = setInterval(() => c.heartbeat().catch(() => {}), 1000)
  await c.heartbeat()
  let failed = 0
  for (const [name, job] of [["subscribe", jobSubscribe], ["publish", jobPublish], ["latch", jobLatch],
    ["params", jobParams]]) {
    try {
      console.log(json({ job: name, ok: true, ...(await job(c)) }))
    } catch (e) {
      failed++
      console.log(json({ job: name, ok: false, error: e.message }))
    }
  }
  clearTimeout(overall)
  console.log(json({ job: "heartbeat", ok: true, node: NODE, failed_jobs: failed }))
  const leave = async () => {
    clearInterval(beat)
    await c.heartbeat("leaving").catch(() => {})
    await sleep(100) // linger: the last heartbeat leaves before the socket closes
    c.close()
    process.exit(failed ? 1 : 0)
  }
  process.on("SIGINT", leave)
  process.on("SIGTERM", leave)
}

main()
