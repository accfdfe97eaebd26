// A face the page draws itself (three.js, and three-vrm for VRM files): the avatar file the server names, posed
// by the face frames that come on the "eca-face" data channel (the server's web/browser_face.py says their
// layout), and shown in step with the agent's voice as this browser plays it.
//
// Sync: each frame carries its time on the sender's NTP clock, the clock of the voice's RTCP sender reports. The
// server repeats those reports on the data channel (an RTP timestamp of the voice and when it left); the audio
// receiver's synchronization source says which RTP timestamp this browser last handed to its speakers, and when.
// Together: "what the listener hears now" at every animation frame, through jitter, drift and buffer changes.
// Through Janus, whose Streaming plugin numbers each viewer's voice from the first packet it relays to it (RTP
// timestamp less that packet's), the page works out that first packet from its own counts and the talk spurts the
// server names (VoiceClock.rebase).
// What the voice moves (mouth, jaw) is taken from the frame of that instant; everything else (brows, eyes, head,
// an emotion, a barge-in) from the newest frame, as soon as it arrives.
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { VRMHumanoidLoaderPlugin, VRMLoaderPlugin, VRMMetaLoaderPlugin, VRMUtils } from "@pixiv/three-vrm";

const FRAME = 1, VOICE_CLOCK = 2, VOICE_SPURTS = 3;  // message kinds
const HEADER_BYTES = 16;
const SPURTS_HEAD_BYTES = 6;  // after the voice's spurts' header: f32 the way to Janus, u16 the last sequence number
const SPURT_BYTES = 6;  // u16 sequence number, u32 RTP timestamp
const SPURTS_KEPT = 256;  // talk spurts the page remembers (through Janus)
const VOICED = 1;
const MARK = 2;  // the frame's time is a whole second of the master clock (the calibration clicks' times)
const LOG_MAX = 2000;
const OPUS_RATE = 48000;  // RTP clock of the voice (Opus)
const KEEP_MS = 3000;  // frames kept for the voice to catch up with
const FRAME_SAMPLES = 960;  // the voice's packets, 20 ms each
const FRAME_MS = 20;
const FIRST_READINGS = 20;  // the latest estimates of Janus's first packet (about 5 s of them while the voice sounds)
const CLOCK_ASKS = 12;  // the latest asks of the server's clock, the quickest taken
const CLOCK_ASK_EVERY_MS = 2000;
const NTP_UNIX_OFFSET_MS = 2208988800000;  // NTP counts from 1900, Unix time from 1970
// how much earlier than the page asked Janus for the voice its first packet may have left the server (clocks'
// offset and ways misjudged): a reading that puts it earlier is impossible, Janus relays nothing it got before
const WATCHED_LEEWAY_MS = 500;

// a difference of two 16-bit sequence numbers, or of two 32-bit RTP timestamps, as the nearest signed one
const wrapped16 = (d) => ((((d + 2 ** 15) % 2 ** 16) + 2 ** 16) % 2 ** 16) - 2 ** 15;
const wrapped32 = (d) => ((((d + 2 ** 31) % 2 ** 32) + 2 ** 32) % 2 ** 32) - 2 ** 31;

export function webglAvailable() {
  try {
    const canvas = document.createElement("canvas");
    return !!(canvas.getContext("webgl2") || canvas.getContext("webgl"));
  } catch {
    return false;
  }
}

// The server's wall clock (Unix ms, GET `url`: /clock) with when the request left and its answer came back, on this
// page's clock (ms since 1970), from the browser's network timing of that request (Resource Timing), not from when
// this page's script ran: a busy page (software WebGL drawing) takes its time to run the answer's callback, which
// makes the way back look longer than the way there, and the midpoint of the two would put the server's clock early
// by half the difference (and every voice packet's departure with it, VoiceClock.rebase).
let clockAsks = 0;
export async function askServerClock(url) {
  const address = new URL(url, location.href);
  address.searchParams.set("ask", String(clockAsks += 1));  // a name of its own, to find its timing by
  const answer = await (await fetch(address, { cache: "no-store" })).json();
  const timing = performance.getEntriesByName(address.href).pop();
  // the buffer holds 250 entries (then drops new ones); cleared when near full, not at every ask, so that an ask
  // still under way keeps its entry
  if (performance.getEntriesByType("resource").length > 200) performance.clearResourceTimings();
  if (!timing || !(timing.requestStart > 0) || timing.responseStart < timing.requestStart) {
    return { unix_ms: answer.unix_ms };  // no network timing: VoiceClock times it by the script
  }
  return { unix_ms: answer.unix_ms, sentMs: performance.timeOrigin + timing.requestStart,
           backMs: performance.timeOrigin + timing.responseStart };
}

// What the listener hears now, on the sender's clock (ms since 1900), or null until the server's first report.
// The server reports what its RTCP sender reports carry (an RTP timestamp of the voice and when it left, on the
// data channel: a page cannot read the reports its browser receives); the audio receiver's synchronization
// source says which RTP timestamp was last handed to the speakers, and when. Both are of the same RTP clock,
// so what plays now is the report's time plus the samples between them.
export class VoiceClock {
  // `serverClock` (a function answering { unix_ms: the server's wall clock, and sentMs, backMs: when the asking left and
  // its answer came, on this page's clock, if known }; askServerClock): the voice comes through Janus, whose RTP
  // timestamps start from the first packet it relayed here; `watchedSinceMs` (this page's clock, ms since 1970): when
  // the page asked Janus for it (no packet Janus relays here left the server much before)
  constructor(receiver, { serverClock = null, watchedSinceMs = null } = {}) {
    this.receiver = receiver;
    this.rebased = !!serverClock;
    this.watchedSinceMs = watchedSinceMs;
    this.report = null;  // { rtp, ntpMs }, in this receiver's RTP numbering
    this.asks = [];  // rebased: { rttMs, offsetMs } of the latest asks of the server's clock
    this.firsts = [];  // rebased: the latest estimates of the sequence number of Janus's first packet (unwrapped)
    this.spurts = [];  // rebased: { seq (unwrapped), rtp } of talk spurts' first packets, in order
    this.lastSeq = null;  // rebased: the newest report's last sequence number, unwrapped
    this.legs = [];  // rebased: the latest round trips to Janus (ms), from the connection's own checks
    this.base = null;  // rebased: the sender's RTP timestamp of that packet
    this.dropped = { beforeSpurts: 0, beforeWatched: 0 };  // rebased: readings left out, and why (for diagnosis)
    this.timer = null;
    if (serverClock) {
      const ask = async () => {
        const asked = performance.timeOrigin + performance.now();
        try {
          const answer = await serverClock();
          const sent = answer.sentMs ?? asked;  // the browser's own times of the request, when it gives them
          const back = answer.backMs ?? performance.timeOrigin + performance.now();
          this.asks.push({ rttMs: back - sent, offsetMs: answer.unix_ms - (sent + back) / 2 });
          if (this.asks.length > CLOCK_ASKS) this.asks.shift();
        } catch {
          // the server away for a moment: the asks kept still hold
        }
      };
      for (let i = 0; i < 4; i += 1) setTimeout(ask, 100 * i);
      this.timer = setInterval(ask, CLOCK_ASK_EVERY_MS);
    }
    // what the synchronization source says was handed to the speakers still goes through the output's buffers:
    // the audio output's own latency (as an AudioContext on the default device reports it) is heard later
    this.outputLatencyMs = 0;
    try {
      const context = new AudioContext();
      const measure = () => { this.outputLatencyMs = 1000 * ((context.outputLatency || 0) + (context.baseLatency || 0)); };
      measure();
      setTimeout(() => { measure(); context.close(); }, 1000);  // outputLatency is known once the context runs
    } catch {
      // no audio output to ask: none added
    }
  }

  onReport(rtp, ntpMs) {
    this.report = { rtp, ntpMs };
  }

  // Through Janus: the server's report (the RTP timestamp of its last voice packet and when it left, the way to
  // Janus, that packet's sequence number) and the latest talk spurts' first packets ([sequence number, RTP
  // timestamp], oldest first), in the server's numbering
  onSpurts(rtp, ntpMs, wayMs, lastSeq, spurts) {
    const last = this.lastSeq == null ? lastSeq + 2 ** 16 : this.lastSeq + wrapped16(lastSeq - this.lastSeq);
    this.lastSeq = last;
    for (const [seq, spurtRtp] of spurts) {
      const at = last - (((lastSeq - seq) % 2 ** 16) + 2 ** 16) % 2 ** 16;  // a spurt starts at or before the last
      if (!this.spurts.some((p) => p.seq === at)) this.spurts.push({ seq: at, rtp: spurtRtp });
    }
    this.spurts.sort((a, b) => a.seq - b.seq);
    while (this.spurts.length > SPURTS_KEPT) this.spurts.shift();
    this.rebase(rtp, ntpMs, wayMs);
  }

  // How far the server's clock is ahead of this page's: from the quickest of the latest asks (a slow answer, held
  // up anywhere, says least), as NTP does
  serverOffsetMs() {
    if (!this.asks.length) return null;
    return this.asks.reduce((a, b) => (b.rttMs < a.rttMs ? b : a)).offsetMs;
  }

  // Janus numbers this viewer's voice from the first packet it relays: RTP timestamp less that packet's (`base`),
  // and sequence numbers the same way, which the page is not told. It counts: the receiver's newest packet is
  // packet number packetsReceived + packetsLost - 1 of the ones Janus relayed, and arrived at
  // lastPacketReceivedTimestamp (the network's time, not the page's, so a busy page does not move it), on this
  // page's clock: on the server's, that plus the clocks' offset (serverOffsetMs). Less the way from Janus to here
  // (half the quickest of the connection's latest round trips, which its ICE checks measure) and the server's way
  // to Janus (it says), that is when the server sent it. The voice pauses in silence, so which packet the server
  // sent then comes from the talk spurts it names: within a spurt its packets leave 20 ms apart, and an RTP
  // timestamp's time is the report's plus the samples between them (the RTP clock is the master clock). The
  // newest packet's number less the count is the first packet's; each reading is late by however late the packet
  // left (a loaded server sends late, never early), so the lowest of the latest readings is the one to take, and
  // exact. Its spurt gives its RTP timestamp.
  async rebase(rtp, ntpMs, wayMs) {
    const offsetMs = this.serverOffsetMs();
    if (offsetMs == null) return;
    let stats;
    try {
      stats = await this.receiver.getStats();
    } catch {
      return;  // the connection is closing
    }
    const legMs = this.legFromJanusMs(stats);
    for (const r of stats.values()) {
      if (r.type !== "inbound-rtp" || !r.packetsReceived || !r.lastPacketReceivedTimestamp) continue;
      const newest = r.packetsReceived + (r.packetsLost || 0) - 1;
      const sentMs = r.lastPacketReceivedTimestamp + offsetMs + NTP_UNIX_OFFSET_MS - legMs - wayMs;
      const seq = this.packetSentAt(sentMs, rtp, ntpMs);
      // a reading that puts the first packet before every spurt known says nothing usable (an early one: the
      // clocks' offset or a way misjudged under load); kept, it would hold the lowest for the next twenty
      if (seq == null || !this.spurts.length || seq - newest < this.spurts[0].seq) {
        this.dropped.beforeSpurts += 1;
        return;
      }
      // nor one that puts it before the page watched: an early reading at a spurt's first packet lands on the last
      // packet of the spurt before, whose RTP timestamp is a whole pause earlier (its sequence number is only one)
      const watchedMs = this.watchedSinceMs == null ? null
        : this.watchedSinceMs + offsetMs + NTP_UNIX_OFFSET_MS - WATCHED_LEEWAY_MS;
      if (watchedMs != null && this.sentMsOf(seq - newest, rtp, ntpMs) < watchedMs) {
        this.dropped.beforeWatched += 1;
        return;
      }
      this.firsts.push(seq - newest);
      if (this.firsts.length > FIRST_READINGS) this.firsts.shift();
      const first = Math.min(...this.firsts);
      const spurt = this.spurtOf(first);
      if (!spurt) return;  // its spurt is no longer known: the base found before holds
      this.base = (spurt.rtp + (first - spurt.seq) * FRAME_SAMPLES) % 2 ** 32;
      this.report = { rtp: (((rtp - this.base) % 2 ** 32) + 2 ** 32) % 2 ** 32, ntpMs };
      this.rebasings = (this.rebasings || 0) + 1;
      this.legMs = legMs;
      return;
    }
  }

  // The talk spurt packet `seq` (unwrapped) belongs to: the last begun at or before it; null before every one known
  spurtOf(seq) {
    let spurt = null;
    for (const p of this.spurts) if (p.seq <= seq) spurt = p;
    return spurt;
  }

  // When the server sent packet `seq` (unwrapped; its NTP clock, ms), by the spurts it names: the RTP timestamp of
  // its spurt's first plus the packets between them; -Infinity before every spurt known
  sentMsOf(seq, rtp, ntpMs) {
    const spurt = this.spurtOf(seq);
    if (!spurt) return -Infinity;
    return ntpMs + wrapped32(spurt.rtp + (seq - spurt.seq) * FRAME_SAMPLES - rtp) * 1000 / OPUS_RATE;
  }

  // The sequence number (unwrapped) of the packet the server sent at `sentMs` (its NTP clock), by the spurts: the
  // last spurt begun by then (half a packet's leeway), and within it the packet nearest that time, at most the
  // spurt's last (the packet before the next spurt's first)
  packetSentAt(sentMs, rtp, ntpMs) {
    const timeOf = (ts) => ntpMs + wrapped32(ts - rtp) * 1000 / OPUS_RATE;
    let k = -1;
    for (let i = 0; i < this.spurts.length; i += 1) {
      if (timeOf(this.spurts[i].rtp) <= sentMs + FRAME_MS / 2) k = i;
    }
    if (k < 0) return null;
    const p = this.spurts[k];
    let seq = p.seq + Math.max(0, Math.round((sentMs - timeOf(p.rtp)) / FRAME_MS));
    if (k + 1 < this.spurts.length) seq = Math.min(seq, this.spurts[k + 1].seq - 1);
    return seq;
  }

  // Half the quickest of the latest round trips of the connection's selected candidate pair (its ICE checks, to
  // Janus and back), noted from `stats` (the receiver's, which name the transport and its pair); 0 before any
  legFromJanusMs(stats) {
    let pair = null;
    for (const r of stats.values()) {
      if (r.type === "transport" && r.selectedCandidatePairId) pair = stats.get(r.selectedCandidatePairId) || pair;
    }
    if (!pair) {
      for (const r of stats.values()) {
        if (r.type === "candidate-pair" && r.nominated && r.state === "succeeded") pair = r;
      }
    }
    if (pair && pair.currentRoundTripTime > 0) {
      this.legs.push(pair.currentRoundTripTime * 1000);
      if (this.legs.length > FIRST_READINGS) this.legs.shift();
    }
    return this.legs.length ? Math.min(...this.legs) / 2 : 0;
  }

  stop() {
    if (this.timer) clearInterval(this.timer);
    this.timer = null;
  }

  // the RTP position (samples) of what plays now, unwrapped near `near` (the RTP clock wraps at 2^32)
  rtpNow(near) {
    const sources = this.receiver.getSynchronizationSources();
    if (!sources.length) return null;
    const src = sources[0];
    const now = src.timestamp > 1e12 ? performance.timeOrigin + performance.now() : performance.now();
    const rtp = src.rtpTimestamp + (now - src.timestamp) * OPUS_RATE / 1000;
    return rtp + Math.round((near - rtp) / 2 ** 32) * 2 ** 32;
  }

  nowMs() {
    if (!this.report) return null;
    const rtp = this.rtpNow(this.report.rtp);
    if (rtp == null) return null;
    return this.report.ntpMs + (rtp - this.report.rtp) * 1000 / OPUS_RATE - this.outputLatencyMs;
  }
}

// three-vrm refuses a VRM whose humanoid lacks a body (hips, legs, arms); a face needs none of it (the server
// drives the head, neck, jaw and eye nodes itself), and eca takes a bare head: the bones it has are enough here.
class FaceHumanoidLoaderPlugin extends VRMHumanoidLoaderPlugin {
  _ensureRequiredBonesExist(humanBones) {
    return humanBones;
  }
}

function findNodes(gltf) {
  const nodes = new Map();
  const primitives = new Map();
  const associations = gltf.parser.associations;
  gltf.scene.traverse((object) => {
    const a = associations.get(object);
    if (a && a.nodes !== undefined && !nodes.has(a.nodes)) nodes.set(a.nodes, object);
  });
  gltf.scene.traverse((object) => {
    if (!object.isMesh) return;
    const a = associations.get(object);
    if (!a || a.primitives === undefined) return;
    let owner = object;
    while (owner && !(associations.get(owner) && associations.get(owner).nodes !== undefined)) owner = owner.parent;
    if (owner) primitives.set(`${associations.get(owner).nodes}:${a.primitives}`, object);
  });
  return { nodes, primitives };
}

export class BrowserFace {
  // `serverClock`: the voice comes through Janus (VoiceClock)
  constructor(canvas, description, { token = null, receiver = null, background = 0xf3efe8, serverClock = null,
                                     watchedSinceMs = null } = {}) {
    this.canvas = canvas;
    this.d = description;
    this.token = token;
    this.clock = receiver ? new VoiceClock(receiver, { serverClock, watchedSinceMs }) : null;
    this.frames = [];  // { seq, flags, timeMs, weights: Uint8Array, quats: Int16Array, arrivedMs }
    this.stats = { received: 0, bad: 0, presented: 0, lastSeq: null, firstArrival: null, lastArrival: null,
                   syncedMs: null, voiced: false };
    // for measuring (bench/web.py): when each frame was first shown as the newest (what has no sound) and as
    // the heard one (the voice's part), and when each marked frame's voice part was first shown
    this.log = { newest: [], heard: [], marks: [] };
    this.weightBytes = description.primitives.reduce((n, p) => n + p.targets, 0);
    this.frameBytes = HEADER_BYTES + this.weightBytes + 8 * description.joints.length;
    if (this.frameBytes !== description.frame_bytes) throw new Error("the face's frame layout does not add up");
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    this.renderer.setSize(description.width, description.height, false);
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(background);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8a7f74, 1.6));
    const key = new THREE.DirectionalLight(0xffffff, 1.8);
    key.position.set(0.4, 0.8, 1.2);
    this.scene.add(key);
    this.camera = new THREE.PerspectiveCamera();
    new THREE.Matrix4().fromArray(description.view).invert()
      .decompose(this.camera.position, this.camera.quaternion, this.camera.scale);
    this.camera.projectionMatrix.fromArray(description.projection);
    this.camera.projectionMatrixInverse.copy(this.camera.projectionMatrix).invert();
    this.vrm = null;
    this.targets = [];  // per described primitive: its mesh (or null)
    this.joints = [];
    this.lastRender = performance.now();
  }

  async load() {
    const loader = new GLTFLoader();
    if (this.token) loader.setRequestHeader({ "X-Eca-Token": this.token });
    if (this.d.format !== "gltf") {
      // three-vrm takes a VRM 1.0 only with the licence URL it knows; the server drew this file, so the page
      // takes the URL the file gives too (the licence itself is the operator's business, not the drawing's)
      const acceptLicenseUrls = ["https://vrm.dev/licenses/1.0/", ...(this.d.license_url ? [this.d.license_url] : [])];
      loader.register((parser) => new VRMLoaderPlugin(parser, {
        autoUpdateHumanBones: false, metaPlugin: new VRMMetaLoaderPlugin(parser, { acceptLicenseUrls }),
        humanoidPlugin: new FaceHumanoidLoaderPlugin(parser, { autoUpdateHumanBones: false }),
      }));
    }
    const gltf = await loader.loadAsync(this.d.url);
    this.vrm = gltf.userData.vrm || null;
    if (this.vrm && this.d.format === "vrm0") VRMUtils.rotateVRM0(this.vrm);  // faces +Z, as the server's model does
    const { nodes, primitives } = findNodes(gltf);
    this.targets = this.d.primitives.map((p) => {
      const mesh = primitives.get(`${p.node}:${p.primitive}`) || null;
      return mesh && mesh.morphTargetInfluences && mesh.morphTargetInfluences.length >= p.targets ? mesh : null;
    });
    this.joints = this.d.joints.map((j) => nodes.get(j.node) || null);
    this.scene.add(gltf.scene);
    this.render();
  }

  // one data-channel message for this face (already known to be its slot); false when it is not one
  push(buffer) {
    if (!(buffer instanceof ArrayBuffer) || buffer.byteLength < HEADER_BYTES) { this.stats.bad += 1; return false; }
    const view = new DataView(buffer);
    const kind = view.getUint8(2);
    if (kind === VOICE_CLOCK && buffer.byteLength === HEADER_BYTES) {
      if (this.clock && !this.clock.rebased) this.clock.onReport(view.getUint32(4, true), view.getFloat64(8, true));
      this.stats.reports = (this.stats.reports || 0) + 1;
      return true;
    }
    const count = view.getUint8(3);
    if (kind === VOICE_SPURTS && count >= 1
        && buffer.byteLength === HEADER_BYTES + SPURTS_HEAD_BYTES + count * SPURT_BYTES
        && Number.isFinite(view.getFloat64(8, true)) && view.getFloat32(HEADER_BYTES, true) >= 0
        && view.getFloat32(HEADER_BYTES, true) < 10000) {  // a time, and a way to Janus of under 10 s
      const spurts = [];
      for (let i = 0, at = HEADER_BYTES + SPURTS_HEAD_BYTES; i < count; i += 1, at += SPURT_BYTES) {
        spurts.push([view.getUint16(at, true), view.getUint32(at + 2, true)]);
      }
      if (this.clock && this.clock.rebased) {
        this.clock.onSpurts(view.getUint32(4, true), view.getFloat64(8, true), view.getFloat32(HEADER_BYTES, true),
                            view.getUint16(HEADER_BYTES + 4, true), spurts);
      }
      this.stats.reports = (this.stats.reports || 0) + 1;
      return true;
    }
    if (kind !== FRAME || buffer.byteLength !== this.frameBytes) { this.stats.bad += 1; return false; }
    const now = performance.now();
    const frame = {
      flags: view.getUint8(3), seq: view.getUint32(4, true), timeMs: view.getFloat64(8, true),
      weights: new Uint8Array(buffer, HEADER_BYTES, this.weightBytes),
      quats: new Int16Array(buffer.slice(HEADER_BYTES + this.weightBytes)),
      arrivedMs: now,
    };
    const last = this.frames[this.frames.length - 1];
    if (last && frame.seq <= last.seq) return true;  // an older frame, overtaken (the channel is unordered)
    this.frames.push(frame);
    while (this.frames.length > 2 && this.frames[0].timeMs < frame.timeMs - KEEP_MS) this.frames.shift();
    const s = this.stats;
    s.received += 1;
    s.firstArrival = s.firstArrival ?? now;
    s.lastArrival = now;
    return true;
  }

  // the frame the listener hears now (the newest until the receiver can say)
  heardFrame() {
    const newest = this.frames[this.frames.length - 1];
    const heardMs = this.clock ? this.clock.nowMs() : null;
    this.stats.syncedMs = heardMs;
    if (heardMs == null) return newest;
    let heard = null;
    for (let i = this.frames.length - 1; i >= 0; i -= 1) {
      if (this.frames[i].timeMs <= heardMs) { heard = this.frames[i]; break; }
    }
    return heard || this.frames[0];
  }

  present() {
    const newest = this.frames[this.frames.length - 1];
    if (!newest) return this.render();
    let heard = this.heardFrame();
    if (!(heard.flags & VOICED) && !(newest.flags & VOICED)) heard = newest;  // silence: nothing to wait for
    // nothing new to show (the display runs faster than the frames come): no drawing
    if (newest.seq === this.stats.presented && heard.seq === this.stats.heardSeq && !this.vrmSprings()) return;
    let at = 0;
    this.d.primitives.forEach((p, i) => {
      const mesh = this.targets[i];
      if (mesh) {
        const influences = mesh.morphTargetInfluences;
        for (let k = 0; k < p.targets; k += 1) {
          influences[k] = (p.voiced[k] ? heard : newest).weights[at + k] / 255;
        }
      }
      at += p.targets;
    });
    this.d.joints.forEach((j, i) => {
      const node = this.joints[i];
      if (!node) return;
      const q = (j.voiced ? heard : newest).quats;
      node.quaternion.set(q[4 * i] / 32767, q[4 * i + 1] / 32767, q[4 * i + 2] / 32767, q[4 * i + 3] / 32767).normalize();
    });
    const now = performance.now();
    if (newest.seq !== this.stats.presented) this.note(this.log.newest, { seq: newest.seq, arrivedMs: newest.arrivedMs, shownMs: now });
    if (heard.seq !== this.stats.heardSeq) {
      this.note(this.log.heard, { seq: heard.seq, timeMs: heard.timeMs, shownMs: now });
      // every marked frame the heard one reached or passed since the last drawing (a slow display skips frames)
      const since = this.stats.heardSeq ?? heard.seq - 1;
      for (const f of this.frames) {
        if (f.seq > since && f.seq <= heard.seq && (f.flags & MARK)) this.note(this.log.marks, { timeMs: f.timeMs, shownMs: now });
      }
    }
    this.stats.presented = newest.seq;
    this.stats.heardSeq = heard.seq;
    this.stats.voiced = !!(heard.flags & VOICED);
    this.render();
  }

  note(list, entry) {
    list.push(entry);
    if (list.length > LOG_MAX) list.splice(0, list.length - LOG_MAX);
  }

  vrmSprings() {
    return !!(this.vrm && this.vrm.springBoneManager && this.vrm.springBoneManager.joints
              && this.vrm.springBoneManager.joints.size);
  }

  render() {
    const now = performance.now();
    if (this.vrm && this.vrm.springBoneManager) this.vrm.springBoneManager.update(Math.min(0.1, (now - this.lastRender) / 1000));
    this.lastRender = now;
    this.renderer.render(this.scene, this.camera);
  }

  dispose() {
    if (this.clock) this.clock.stop();
    this.renderer.dispose();
    this.frames = [];
  }
}

