"""Bench part for bench/web.py: the scripts the bench injects into the product page (selenium's execute_script);
the page itself is not changed."""

PAGE_JS = """
if (!window.ecaBench) {
  const B = window.ecaBench = {frames: {}, onsets: {}, ctx: null, marked: {}, drawn: {}, signature: false,
                               paused: false, mouthBox: arguments[0], signatureSize: arguments[1],
                               onset: arguments[2], patchBox: arguments[3]};
  const canvases = {};
  function pixels(purpose, video, x0, y0, x1, y1, w, h) {
    // the part [x0, x1) x [y0, y1) of the frame (fractions of the picture), drawn at w x h
    const vw = video.videoWidth, vh = video.videoHeight;
    const sx = Math.round(x0 * vw), sy = Math.round(y0 * vh);
    const sw = Math.round((x1 - x0) * vw), sh = Math.round((y1 - y0) * vh);
    w = w || sw; h = h || sh;
    let c = canvases[purpose];
    if (!c || c.width !== w || c.height !== h) {
      const canvas = document.createElement("canvas");
      canvas.width = w; canvas.height = h;
      c = canvases[purpose] = canvas;
      c.g = canvas.getContext("2d", {willReadFrequently: true});
    }
    c.g.drawImage(video, sx, sy, sw, sh, 0, 0, w, h);
    return c.g.getImageData(0, 0, w, h).data;
  }
  function openMouth(video) {  // the dark red of the open mouth's inside
    const [x0, y0, x1, y1] = B.mouthBox;
    const d = pixels("mouth", video, x0, y0, x1, y1);
    let n = 0;
    for (let i = 0; i < d.length; i += 4) {
      const r = d[i], g = d[i + 1], b = d[i + 2];
      if (r > 60 && r < 200 && g < 70 && b < 90 && r - g > 50) n++;
    }
    return n;
  }
  function patchLuma(video) {  // the reference's flashing patch
    const [x0, y0, x1, y1] = B.patchBox;
    const d = pixels("patch", video, x0, y0, x1, y1);
    let s = 0;
    for (let i = 0; i < d.length; i += 4) s += d[i] + d[i + 1] + d[i + 2];
    return s / (3 * d.length / 4);
  }
  function thumbnail(video) {
    const [w, h] = B.signatureSize;
    const d = pixels("thumbnail", video, 0, 0, 1, 1, w, h);
    const out = new Array(w * h);
    for (let i = 0; i < w * h; i++) out[i] = Math.round((d[4 * i] + d[4 * i + 1] + d[4 * i + 2]) / 3);
    return out;
  }
  B.watch = (name, video, kind) => {
    B.frames[name] = [];
    const onFrame = (now, m) => {
      if (!B.paused && video.videoWidth) {
        const f = {e: m.expectedDisplayTime, p: m.presentationTime, r: m.receiveTime ?? null,
                   rtp: m.rtpTimestamp ?? null, w: m.width, h: m.height};
        if (kind !== "patch") f.mouth = openMouth(video);  // "patch": the markers only (a face the bench does not read)
        if (kind === "face" && B.signature) f.sig = thumbnail(video);
        if (kind === "marked" || kind === "patch") f.luma = patchLuma(video);
        B.frames[name].push(f);
      }
      video.requestVideoFrameCallback(onFrame);
    };
    video.requestVideoFrameCallback(onFrame);
  };
  const WORKLET = `
    class Onsets extends AudioWorkletProcessor {
      constructor(options) {
        super();
        this.level = options.processorOptions.level;
        this.quietFrames = Math.round(options.processorOptions.quietS * sampleRate);
        this.quiet = 0;
      }
      process(inputs) {
        const channel = inputs[0] && inputs[0][0];
        if (!channel) return true;
        for (let i = 0; i < channel.length; i++) {
          if (Math.abs(channel[i]) >= this.level) {
            if (this.quiet >= this.quietFrames) this.port.postMessage({frame: currentFrame + i});
            this.quiet = 0;
          } else {
            this.quiet++;
          }
        }
        return true;
      }
    }
    registerProcessor("eca-onsets", Onsets);`;
  B.startAudio = async () => {
    if (B.ctx) return;
    const ctx = new AudioContext();
    await ctx.audioWorklet.addModule(URL.createObjectURL(new Blob([WORKLET], {type: "text/javascript"})));
    await ctx.resume();
    B.silent = ctx.createGain();
    B.silent.gain.value = 0;  // the worklet must be pulled by the destination; nothing is added to the output
    B.silent.connect(ctx.destination);
    B.ctx = ctx;
  };
  B.listened = {};
  B.listen = (name, stream) => {
    const ctx = B.ctx;
    B.listened[name] = stream;
    if (!B.onsets[name]) B.onsets[name] = [];
    const node = new AudioWorkletNode(ctx, "eca-onsets", {processorOptions: {level: B.onset[0], quietS: B.onset[1]}});
    node.port.onmessage = (event) => {
      // when the onset's sample is at the output, on the page's clock
      const ts = ctx.getOutputTimestamp();
      const heard = ts.performanceTime + (event.data.frame / ctx.sampleRate - ts.contextTime) * 1000;
      if (!B.paused) B.onsets[name].push(heard);
    };
    ctx.createMediaStreamSource(stream).connect(node);
    node.connect(B.silent);
  };
  B.restartAudio = async () => {  // a fresh context and taps: whatever the old ones had buffered is gone
    const listened = B.listened;
    const old = B.ctx;
    B.ctx = null;
    await B.startAudio();
    B.listened = {};
    for (const [name, stream] of Object.entries(listened)) B.listen(name, stream);
    await old.close();
  };
}
"""

# what the page measured since the last take (the arrays are emptied in place: the callbacks keep filling them)
TAKE_JS = """
const B = window.ecaBench;
const out = {frames: {}, onsets: {}, drawn: {}, now: performance.now()};
for (const k of Object.keys(B.frames)) { out.frames[k] = B.frames[k].splice(0); }
for (const k of Object.keys(B.onsets)) { out.onsets[k] = B.onsets[k].splice(0); }
// a drawn face's entries of the last animation frame wait for the next (DRAWN_JS: nextMs)
const settled = (a) => a.splice(0, a.length && a[a.length - 1].nextMs === undefined ? a.length - 1 : a.length);
for (const [k, r] of Object.entries(B.drawn || {})) {
  if (!r.face) continue;
  const log = r.face.log;
  out.drawn[k] = {newest: settled(log.newest), heard: log.heard.splice(0), marks: settled(log.marks),
                  passed: settled(r.passed),
                  stats: {...r.face.stats}, ticks: r.ticks, messages: r.messages, unplaced: r.unplaced};
}
return out;
"""

CALIBRATION_JS = """
const [name, agent, width, height, fps, done] = arguments;
(async () => {
  const B = window.ecaBench;
  const pc = new RTCPeerConnection();
  const video = pc.addTransceiver("video", {direction: "recvonly"});
  const audio = pc.addTransceiver("audio", {direction: "recvonly"});
  const element = document.createElement("video");
  element.autoplay = true;
  element.playsInline = true;
  // in view, so the browser composites (and presents) its frames
  element.style.cssText = "position: fixed; right: 0; bottom: 0; width: 160px; height: 120px; z-index: 10";
  const stream = new MediaStream();
  element.srcObject = stream;
  document.body.append(element);
  pc.ontrack = (event) => stream.addTrack(event.track);
  await pc.setLocalDescription(await pc.createOffer());
  if (pc.iceGatheringState !== "complete") {
    await new Promise((resolve) => pc.addEventListener("icegatheringstatechange",
      () => { if (pc.iceGatheringState === "complete") resolve(); }));
  }
  const body = {type: "offer", sdp: pc.localDescription.sdp, agents: [agent], video: {width, height, fps},
                streams: [{mid: video.mid, agent, kind: "video"}, {mid: audio.mid, agent, kind: "audio"}],
                mic_mid: null, calibration: true};
  const response = await fetch("/offer", {method: "POST", headers: {"Content-Type": "application/json"},
                                          body: JSON.stringify(body)});
  const answer = await response.json();
  if (!response.ok) throw new Error(answer.error || `the server answered ${response.status}`);
  await pc.setRemoteDescription({type: "answer", sdp: answer.sdp});
  B.marked[name] = {pc, element, stream};
  return "ok";
})().then(done, (error) => done(`error: ${error.message || error}`));
"""

# a connection that draws the agent's face in the page, as app.js connect() does: the "eca-face" data channel
# made before the offer, only an audio section for the agent, `draw_here`; a face3d.js BrowserFace fed the
# channel's messages of its slot and presented at every animation frame. The bench adds to the entries of the
# face's own log (face3d.js `log`) what the frame showed: its flags; for each heard frame the largest weight
# of a target the voice moves ("jaw", 0..1); with B.signature, for each newest frame the weights (0..255) of
# the targets the voice does not move (brows, eyes, cheeks: an expression).
DRAWN_JS = """
const [name, agent, width, height, fps, calibration, draw, done] = arguments;
(async () => {
  const B = window.ecaBench;
  const m = await import("/static/face3d.js");
  if (!m.webglAvailable()) throw new Error("this browser has no WebGL");
  const pc = new RTCPeerConnection();
  const channel = pc.createDataChannel("eca-face", {ordered: false, maxRetransmits: 0});
  channel.binaryType = "arraybuffer";
  const audio = pc.addTransceiver("audio", {direction: "recvonly"});
  const element = document.createElement("audio");
  element.autoplay = true;
  const stream = new MediaStream();
  element.srcObject = stream;
  const canvas = document.createElement("canvas");
  // in view, as the page's own canvas is
  canvas.style.cssText = "position: fixed; left: 0; bottom: 0; width: 160px; height: 120px; z-index: 10";
  document.body.append(element, canvas);
  const r = {pc, channel, element, stream, canvas, face: null, ticks: 0, messages: 0, unplaced: 0, closed: false,
             passed: []};
  B.drawn[name] = r;
  pc.ontrack = (event) => stream.addTrack(event.track);
  channel.onmessage = (event) => {
    const data = event.data;
    r.messages++;
    if (!(data instanceof ArrayBuffer) || data.byteLength < 2) return;
    if (r.face && new DataView(data).getUint16(0, true) === r.face.d.slot) r.face.push(data);
    else r.unplaced++;  // before the face has loaded
  };
  await pc.setLocalDescription(await pc.createOffer());
  if (pc.iceGatheringState !== "complete") {
    await new Promise((resolve) => pc.addEventListener("icegatheringstatechange",
      () => { if (pc.iceGatheringState === "complete") resolve(); }));
  }
  const body = {type: "offer", sdp: pc.localDescription.sdp, agents: [agent], video: {width, height, fps},
                streams: [{mid: audio.mid, agent, kind: "audio"}], mic_mid: null, calibration, draw_here: [agent]};
  const response = await fetch("/offer", {method: "POST", headers: {"Content-Type": "application/json"},
                                          body: JSON.stringify(body)});
  const answer = await response.json();
  if (!response.ok) throw new Error(answer.error || `the server answered ${response.status}`);
  await pc.setRemoteDescription({type: "answer", sdp: answer.sdp});
  const description = answer.faces && answer.faces[agent];
  if (!description) throw new Error(`the answer describes no face of ${agent} to draw`);
  const face = new m.BrowserFace(canvas, description, {receiver: audio.receiver});
  await face.load();
  if (!draw) face.render = () => {};  // --no-webgl-draw: present() chooses and logs its frames, draws nothing
  const voiced = [], still = [];
  let at = 0;
  for (const p of description.primitives) {
    for (let k = 0; k < p.targets; k++) (p.voiced[k] ? voiced : still).push(at + k);
    at += p.targets;
  }
  const find = (seq) => {
    for (let i = face.frames.length - 1; i >= 0; i--) if (face.frames[i].seq === seq) return face.frames[i];
    return null;
  };
  let drawnLast = [];  // the entries noted at the last animation frame
  let lastHeard = -1;  // the newest seq the heard frame has reached
  const tick = () => {
    if (r.closed) return;
    const start = performance.now();
    for (const e of drawnLast) e.nextMs = start;  // the next animation frame: the one drawn has been shown by then
    drawnLast = [];
    face.present();
    r.ticks++;
    const log = face.log;
    const n = log.newest[log.newest.length - 1];
    if (n && n.flags === undefined) {
      const f = find(n.seq);
      n.flags = f ? f.flags : null;
      if (B.signature && f) n.sig = still.map((i) => f.weights[i]);
      drawnLast.push(n);
    }
    const h = log.heard[log.heard.length - 1];
    if (h && h.flags === undefined) {
      const f = find(h.seq);
      h.flags = f ? f.flags : null;
      let jaw = 0;
      if (f) for (const i of voiced) jaw = Math.max(jaw, f.weights[i]);
      h.jaw = f ? jaw / 255 : null;
      h.syncedMs = face.stats.syncedMs;  // what the voice played then, on the sender's clock
    }
    const k = log.marks[log.marks.length - 1];
    if (k && k.flags === undefined) {
      k.flags = h ? h.flags : null;
      k.syncedMs = face.stats.syncedMs;
      drawnLast.push(k);
    }
    // every marked frame the heard frame reached or passed at this drawing: log.marks has only the marked frames
    // drawn themselves, and an animation frame rarer than the face frames skips over most
    const heardSeq = face.stats.heardSeq;
    if (heardSeq != null && heardSeq !== lastHeard) {
      const shownMs = h && h.seq === heardSeq ? h.shownMs : performance.now();
      for (const f of face.frames) {
        if ((f.flags & 2) && f.seq > lastHeard && f.seq <= heardSeq) {
          const e = {seq: f.seq, timeMs: f.timeMs, flags: f.flags, shownMs, syncedMs: face.stats.syncedMs,
                     drawn: f.seq === heardSeq};
          r.passed.push(e);
          drawnLast.push(e);
        }
      }
      if (heardSeq > lastHeard) lastHeard = heardSeq;
    }
    requestAnimationFrame(tick);
  };
  r.face = face;
  requestAnimationFrame(tick);
  return {slot: description.slot, url: description.url, frameBytes: description.frame_bytes,
          width: description.width, height: description.height, voicedTargets: voiced.length,
          stillTargets: still.length, joints: description.joints.length};
})().then(done, (error) => done(`error: ${error.message || error}`));
"""

DRAWN_READY_JS = """
const B = window.ecaBench;
const drawn = Object.values(B.drawn), marked = Object.values(B.marked);
return Boolean(drawn.length && drawn.every((r) => r.pc.connectionState === "connected" && r.face
                                           && r.face.stats.received >= 5 && r.stream.getAudioTracks().length)
               && marked.every((r) => r.pc.connectionState === "connected" && r.stream.getVideoTracks().length > 0
                                      && r.stream.getAudioTracks().length > 0));
"""

# (again for a connection made later: what is watched and listened to already stays as it is)
START_DRAWN_MEASURING_JS = """
const done = arguments[arguments.length - 1];
const B = window.ecaBench;
B.startAudio().then(() => {
  for (const [name, r] of Object.entries(B.marked)) {
    if (!B.frames[name]) B.watch(name, r.element, "patch");
    if (!B.listened[name]) B.listen(name, r.stream);
  }
  for (const [name, r] of Object.entries(B.drawn)) if (!B.listened[name]) B.listen(name, r.stream);
  done({sampleRate: B.ctx.sampleRate, baseLatency: B.ctx.baseLatency, outputLatency: B.ctx.outputLatency});
}, (error) => done({error: String(error.message || error)}));
"""

CLOSE_DRAWN_JS = """
const D = window.ecaBench;  // (D: it follows CLOSE_CALIBRATION_JS in one script)
if (D) {
  for (const r of Object.values(D.drawn)) {
    r.closed = true;
    r.pc.close();
    r.element.remove();
    r.canvas.remove();
    if (r.face) r.face.dispose();
  }
  D.drawn = {};
}
"""

STREAMS_READY_JS = """
const B = window.ecaBench, face = window.eca && window.eca.faces[AGENT];
const ready = (s) => s && s.getVideoTracks().length > 0 && s.getAudioTracks().length > 0;
const marked = Object.values(B.marked);
return Boolean(window.eca.state === "connected" && face && ready(face.srcObject) && marked.length
               && marked.every((r) => r.pc.connectionState === "connected" && ready(r.stream)));
"""

# each connection's A/V offset as the browser reckons it: what video and audio play out now, in the
# sender's NTP time (getStats estimatedPlayoutTimestamp); + = video ahead = audio late
SYNC_JS = """
const done = arguments[arguments.length - 1];
const B = window.ecaBench;
const pcs = {face: window.eca.pc};
for (const [name, r] of Object.entries(B.marked)) pcs[name] = r.pc;
Promise.all(Object.entries(pcs).map(async ([name, pc]) => {
  if (!pc || pc.connectionState !== "connected") return [name, null];
  const playout = {};
  (await pc.getStats()).forEach((s) => {
    if (s.type === "inbound-rtp" && s.estimatedPlayoutTimestamp) playout[s.kind] = s.estimatedPlayoutTimestamp;
  });
  return [name, playout.video && playout.audio ? {at: performance.now(), offset: playout.video - playout.audio} : null];
})).then((pairs) => done(Object.fromEntries(pairs)), () => done({}));
"""

RESTART_AUDIO_JS = """
const done = arguments[arguments.length - 1];
window.ecaBench.restartAudio().then(() => done(true), (error) => done(String(error.message || error)));
"""

CLOSE_CALIBRATION_JS = """
const B = window.ecaBench;
if (B) {
  for (const r of Object.values(B.marked)) { r.pc.close(); r.element.remove(); }
  B.marked = {};
}
"""

START_MEASURING_JS = """
const [agent, done] = arguments;
const B = window.ecaBench, face = window.eca.faces[agent];
B.startAudio().then(() => {
  B.watch("face", face, "face");
  for (const [name, r] of Object.entries(B.marked)) {
    B.watch(name, r.element, "marked");
    B.listen(name, r.stream);
  }
  B.listen("face", face.srcObject);
  done({sampleRate: B.ctx.sampleRate, baseLatency: B.ctx.baseLatency, outputLatency: B.ctx.outputLatency});
}, (error) => done({error: String(error.message || error)}));
"""

# inbound video of one peer connection (the page's, or the reference's), and the ICE round trip
VIDEO_STATS_JS = """
const [which, done] = arguments;
const pc = which === "face" ? window.eca.pc : window.ecaBench.marked[which] && window.ecaBench.marked[which].pc;
if (!pc) { done(null); return; }
pc.getStats().then((report) => {
  const out = {at: performance.now()};
  report.forEach((s) => {
    if (s.type === "inbound-rtp" && s.kind === "video") Object.assign(out, {
      framesDecoded: s.framesDecoded, framesReceived: s.framesReceived, framesDropped: s.framesDropped,
      framesPerSecond: s.framesPerSecond, jitterBufferDelay: s.jitterBufferDelay,
      jitterBufferEmittedCount: s.jitterBufferEmittedCount, totalDecodeTime: s.totalDecodeTime,
      totalProcessingDelay: s.totalProcessingDelay, totalAssemblyTime: s.totalAssemblyTime,
      jitterBufferTargetDelay: s.jitterBufferTargetDelay, decoderImplementation:
      s.decoderImplementation, frameWidth: s.frameWidth, frameHeight: s.frameHeight, codecId: s.codecId});
    if (s.type === "candidate-pair" && s.nominated && s.currentRoundTripTime != null) out.rttS = s.currentRoundTripTime;
  });
  report.forEach((s) => {
    if (s.type === "inbound-rtp" && s.kind === "audio") out.audio = {jitterBufferDelay: s.jitterBufferDelay,
      jitterBufferEmittedCount: s.jitterBufferEmittedCount, jitterBufferTargetDelay: s.jitterBufferTargetDelay,
      jitter: s.jitter};
  });
  if (out.codecId) { const c = report.get(out.codecId); out.codec = c && c.mimeType; }
  done(out);
}, (error) => done({error: String(error)}));
"""

CLOCK_JS = """
const [url, n, done] = arguments;
(async () => {
  const out = [];
  for (let i = 0; i < n; i++) {
    const t0 = performance.now();
    const text = await (await fetch(url, {cache: "no-store"})).text();
    out.push([t0, performance.now(), text]);
  }
  return out;
})().then(done, (error) => done({error: String(error)}));
"""
