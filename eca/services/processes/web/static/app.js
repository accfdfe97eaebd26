// The eca page: the agents' faces and voices over WebRTC, the user's microphone back, a status line and
// a developer panel. Standard WebRTC and media APIs, and three.js with three-vrm (static/vendor/) for the faces
// the page draws itself (face3d.js); no build step.
//
// Who draws a face: with WebGL, the page draws each agent whose face is a 3D model (the server sends its voice
// and the face frames on a data channel); the server draws the others (the 2D face), and every face for a page
// without WebGL or with draw=server, as video.
//
// URL parameters: token (when the server wants one), agents=ada,bob (default: the instance's first),
// width, height, fps (within the server's limits), mic=0 (start without the microphone), draw=server (video),
// sfu=0 (peer with eca even when it publishes through Janus).
//
// With an SFU (GET /config's "sfu"), the page watches each agent through Janus (janus_watch.js) instead of peering
// with eca: its video and voice, or its voice and face frames for a face drawn here; no microphone then (that
// needs the direct connection).
"use strict";

const params = new URLSearchParams(location.search);
const token = params.get("token");
const withToken = (path) => (token ? `${path}?token=${encodeURIComponent(token)}` : path);
const $ = (id) => document.getElementById(id);

const eca = {  // what the page knows, also for tests driving it
  pc: null, state: "not connected", faces: {}, agents: [], answer: null, error: null, drawn: {}, channel: null,
  voices: {},
  stats: { rttMs: null, fps: null, avOffsetMs: null, width: null, height: null },
};
window.eca = eca;

function setStatus(text, isError = false) {
  const el = $("status");
  el.textContent = text;
  el.classList.toggle("error", isError);
}

function showStats() {
  if (eca.state !== "connected") return setStatus(eca.state, eca.state.startsWith("error"));
  const s = eca.stats;
  const part = (v, unit, digits = 0) => (v == null ? "–" : `${v.toFixed(digits)} ${unit}`);
  if (Object.keys(eca.drawn).length && !Object.values(eca.faces).some((e) => e.tagName === "VIDEO")) {
    // the mouth is shown when its sound plays: held back behind the newest frame by the voice's playout delay
    const mouth = s.voiceWaitMs == null ? "mouth in step with the voice"
      : `mouth in step with the voice (held ${s.voiceWaitMs.toFixed(0)} ms for it)`;
    return setStatus(`connected · rtt ${part(s.rttMs, "ms")} · drawn here, ${part(s.drawnFps, "fps")} · ${mouth}`);
  }
  setStatus(`connected · rtt ${part(s.rttMs, "ms")} · ${part(s.fps, "fps")} · A/V offset ${part(s.avOffsetMs, "ms")}`
            + (s.avOffsetMs == null ? "" : s.avOffsetMs >= 0 ? " (audio late)" : " (audio early)"));
}

// the element that shows an agent: a <video> the server draws, or a <canvas> this page draws (with a hidden
// <audio> for its voice)
function faceFor(agent, drawnHere = false) {
  if (!eca.faces[agent]) {
    const figure = document.createElement("figure");
    const media = document.createElement(drawnHere ? "audio" : "video");
    media.autoplay = true;
    media.dataset.agent = agent;
    if (!drawnHere) media.playsInline = true;
    const caption = document.createElement("figcaption");
    caption.textContent = agent;
    if (drawnHere) {
      const canvas = document.createElement("canvas");
      canvas.dataset.agent = agent;
      figure.append(canvas, media, caption);
    } else {
      figure.append(media, caption);
    }
    $("faces").append(figure);
    eca.faces[agent] = media;
  }
  return eca.faces[agent];
}

let face3d = null;  // the module, loaded when a face is drawn here
async function drawingModule() {
  if (!face3d) face3d = await import("./face3d.js");
  return face3d;
}

function animate() {
  for (const face of Object.values(eca.drawn)) face.present();
  if (Object.keys(eca.drawn).length) requestAnimationFrame(animate);
}

function onFaceFrame(event) {
  const data = event.data;
  if (!(data instanceof ArrayBuffer) || data.byteLength < 2) return;
  const slot = new DataView(data).getUint16(0, true);
  const face = Object.values(eca.drawn).find((f) => f.d.slot === slot);
  if (face) face.push(data);
  else eca.unplaced = (eca.unplaced || 0) + 1;  // before its face has loaded, or not a face of this page
}

// The offer goes whole (no trickle), so it waits for the candidates: until gathering completes, or GATHER_LIMIT_MS at
// most. A STUN or TURN server that one of the browser's networks cannot reach (a VPN, a second card) holds
// gathering up for tens of seconds; what was gathered by then is offered.
const GATHER_LIMIT_MS = 3000;

async function gatheringDone(pc) {
  if (pc.iceGatheringState === "complete") return;
  await new Promise((resolve) => {
    const done = () => { pc.removeEventListener("icegatheringstatechange", check); clearTimeout(timer); resolve(); };
    const check = () => { if (pc.iceGatheringState === "complete") done(); };
    const timer = setTimeout(done, GATHER_LIMIT_MS);
    pc.addEventListener("icegatheringstatechange", check);
  });
}

async function connectThroughJanus(sfu, agents, iceServers) {
  const { JanusWatch } = await import("./janus_watch.js");
  eca.agents = agents;
  eca.janus = [];
  const faces = sfu.faces || {};
  let drawHere = [];
  if (params.get("draw") !== "server" && agents.some((a) => faces[a])) {
    const module = await drawingModule();
    if (module.webglAvailable()) drawHere = agents.filter((a) => faces[a]);
  }
  if (sfu.video === false && drawHere.length !== agents.length) {
    throw new Error("this server sends no video (draw = browser) and this browser has no WebGL");
  }
  for (const agent of agents) {
    const mountpoint = sfu.mountpoints[agent];
    if (mountpoint == null) throw new Error(`the SFU carries no mountpoint for ${agent}`);
    const watch = new JanusWatch(sfu.url, mountpoint, iceServers);
    eca.janus.push(watch);
    const here = drawHere.includes(agent);
    const element = faceFor(agent, here);
    let receiver = null;
    // what this page takes of the mountpoint: the voice and face frames of a face it draws, the voice and video of
    // one it is shown (Janus then sends nothing else)
    const mids = sfu.mids;
    const media = !mids ? null : here ? [mids.audio, mids.data] : [mids.audio, mids.video];
    const watchedSinceMs = performance.timeOrigin + performance.now();  // no voice Janus relays here left before
    const pc = await watch.start((event) => {
      if (here && event.track.kind !== "audio") return;  // a face drawn here needs only the voice
      if (event.track.kind === "audio") receiver = event.receiver;
      if (!element.srcObject) element.srcObject = new MediaStream();
      element.srcObject.addTrack(event.track);
    }, 20000, here ? onFaceFrame : null, media);
    if (!eca.pc) {
      eca.pc = pc;  // the status line's figures: the first agent's connection
      const onState = () => {
        eca.state = pc.connectionState === "connected" ? "connected" : pc.connectionState;
        showStats();
      };
      pc.onconnectionstatechange = onState;
      onState();  // it may have connected already
    }
    if (here) {
      // Janus numbers the voice's RTP timestamps from the first packet it relays here (face3d.js VoiceClock)
      const description = faces[agent];
      const canvas = eca.faces[agent].parentElement.querySelector("canvas");
      const url = token ? `${description.url}?token=${encodeURIComponent(token)}` : description.url;
      receiver = receiver || pc.getReceivers().find((r) => r.track.kind === "audio");
      const serverClock = () => face3d.askServerClock(withToken("/clock"));
      const face = new face3d.BrowserFace(canvas, { ...description, url },
                                          { token, receiver, serverClock, watchedSinceMs });
      await face.load();
      eca.drawn[agent] = face;
    }
  }
  if (Object.keys(eca.drawn).length) requestAnimationFrame(animate);
}

async function connect() {
  const config = await (await fetch(withToken("/config"))).json();
  // drawn left to right in the instance's order, the seats its agents look at each other by
  const seat = (a) => (config.agents.indexOf(a) < 0 ? config.agents.length : config.agents.indexOf(a));
  let agents = (params.get("agents") || config.agents[0]).split(",").filter(Boolean).sort((a, b) => seat(a) - seat(b));
  // STUN/TURN servers the operator named ([web.ice]; none: host candidates only), TURN credentials minted for this page
  const iceServers = config.ice_servers || [];
  if (config.sfu && params.get("sfu") !== "0") return connectThroughJanus(config.sfu, agents, iceServers);
  eca.key = null;
  if (config.per_visitor) {
    // a conversation of this page's own: an agent made for it, which only this page (its key) watches and commands
    const response = await fetch("/conversation", { method: "POST", headers: { "Content-Type": "application/json" },
                                                    body: JSON.stringify({ token }) });
    const made = await response.json();
    if (!response.ok) throw new Error(made.error || `the server answered ${response.status}`);
    agents = [made.agent];
    eca.key = made.key;
    if (made.drawable && !config.drawable.includes(made.agent)) config.drawable.push(made.agent);
    $("agent").replaceChildren(new Option(made.agent, made.agent));
  }
  const video = {
    width: Number(params.get("width") || config.width),
    height: Number(params.get("height") || config.height),
    fps: Number(params.get("fps") || config.fps),
  };
  let drawHere = [];
  if (params.get("draw") !== "server") {
    const module = config.drawable.some((a) => agents.includes(a)) ? await drawingModule() : null;
    if (module && module.webglAvailable()) drawHere = agents.filter((a) => config.drawable.includes(a));
  }
  if (config.draw === "browser" && drawHere.length !== agents.length) {
    throw new Error("this server sends no video (draw = browser) and this browser has no WebGL");
  }
  const pc = new RTCPeerConnection({ iceServers });
  eca.pc = pc;
  eca.agents = agents;
  if (drawHere.length) {
    // the face frames: each is whole in itself, so a late one is better skipped than waited for
    eca.channel = pc.createDataChannel("eca-face", { ordered: false, maxRetransmits: 0 });
    eca.channel.binaryType = "arraybuffer";
    eca.channel.onmessage = onFaceFrame;
  }
  let mic = null;  // the microphone's section first: the server reads it best there
  if ($("mic").checked) {
    const stream = await navigator.mediaDevices.getUserMedia({ audio: true });
    mic = pc.addTransceiver(stream.getAudioTracks()[0], { direction: "sendonly" });
  }
  const sections = [];
  for (const agent of agents) {
    const here = drawHere.includes(agent);
    if (!here) sections.push({ agent, kind: "video", t: pc.addTransceiver("video", { direction: "recvonly" }) });
    sections.push({ agent, kind: "audio", t: pc.addTransceiver("audio", { direction: "recvonly" }) });
    faceFor(agent, here);
  }
  pc.ontrack = (event) => {
    const section = sections.find((s) => s.t === event.transceiver);
    if (!section) return;
    const element = faceFor(section.agent);
    if (!element.srcObject) element.srcObject = new MediaStream();
    element.srcObject.addTrack(event.track);
  };
  pc.onconnectionstatechange = () => {
    eca.state = pc.connectionState === "connected" ? "connected" : pc.connectionState;
    showStats();
  };
  await pc.setLocalDescription(await pc.createOffer());
  await gatheringDone(pc);
  const body = {
    type: "offer", sdp: pc.localDescription.sdp, token, agents, video,
    streams: sections.map((s) => ({ mid: s.t.mid, agent: s.agent, kind: s.kind })),
    mic_mid: mic ? mic.mid : null, draw_here: drawHere, key: eca.key,
  };
  const response = await fetch("/offer", { method: "POST", headers: { "Content-Type": "application/json" },
                                           body: JSON.stringify(body) });
  const answer = await response.json();
  if (!response.ok) throw new Error(answer.error || `the server answered ${response.status}`);
  eca.answer = answer;
  await pc.setRemoteDescription({ type: "answer", sdp: answer.sdp });
  for (const [agent, description] of Object.entries(answer.faces || {})) {
    const voice = sections.find((s) => s.agent === agent && s.kind === "audio");
    const canvas = eca.faces[agent].parentElement.querySelector("canvas");
    const url = token ? `${description.url}?token=${encodeURIComponent(token)}` : description.url;
    const face = new face3d.BrowserFace(canvas, { ...description, url }, { token, receiver: voice.t.receiver });
    await face.load();
    eca.drawn[agent] = face;
  }
  if (Object.keys(eca.drawn).length) requestAnimationFrame(animate);
}

async function disconnect() {
  if (eca.pc) eca.pc.close();
  eca.pc = null;
  for (const watch of eca.janus || []) await watch.close();
  eca.janus = [];
  eca.channel = null;
  for (const face of Object.values(eca.drawn)) face.dispose();
  eca.drawn = {};
  eca.state = "not connected";
  for (const video of Object.values(eca.faces)) {
    if (video.srcObject) video.srcObject.getTracks().forEach((t) => t.stop());
    video.srcObject = null;
  }
  showStats();
}

// a page that goes away while watching through Janus has Janus drop its viewers at once (JanusWatch.leave)
window.addEventListener("pagehide", () => { for (const watch of eca.janus || []) watch.leave(); });

async function pollStats() {
  const pc = eca.pc;
  if (!pc || pc.connectionState !== "connected") return;
  const report = await pc.getStats();
  let rtt = null, fps = null, width = null, height = null, videoPlayout = null, audioPlayout = null;
  report.forEach((s) => {
    if (s.type === "candidate-pair" && s.nominated && s.currentRoundTripTime != null) rtt = s.currentRoundTripTime * 1000;
    if (s.type === "inbound-rtp" && s.kind === "video") {
      fps = s.framesPerSecond ?? fps;
      width = s.frameWidth ?? width;
      height = s.frameHeight ?? height;
      if (s.estimatedPlayoutTimestamp) videoPlayout = s.estimatedPlayoutTimestamp;
    }
    if (s.type === "inbound-rtp" && s.kind === "audio" && s.estimatedPlayoutTimestamp) audioPlayout = s.estimatedPlayoutTimestamp;
  });
  // what each track plays now, as the sender's clock saw it: video's ahead of audio's = audio late
  const offset = videoPlayout != null && audioPlayout != null ? videoPlayout - audioPlayout : null;
  eca.stats = { rttMs: rtt, fps, avOffsetMs: offset, width, height, drawnFps: null, voiceWaitMs: null };
  const drawn = Object.values(eca.drawn);
  if (drawn.length) {
    // the faces drawn here: their frames' rate, and how long the mouth waits for the voice it belongs to
    const face = drawn[0];
    const now = performance.now();
    if (face.lastPoll) eca.stats.drawnFps = (1000 * (face.stats.received - face.lastPoll.received)) / (now - face.lastPoll.at);
    face.lastPoll = { at: now, received: face.stats.received };
    const newest = face.frames[face.frames.length - 1];
    if (newest && face.stats.syncedMs != null) eca.stats.voiceWaitMs = newest.timeMs - face.stats.syncedMs;
  }
  showStats();
}

async function sendCommand(command) {
  const agent = $("agent").value;
  const response = await fetch("/command", { method: "POST", headers: { "Content-Type": "application/json" },
                                             body: JSON.stringify({ token, key: eca.key, command: { ...command, agent } }) });
  const answer = await response.json();
  $("panel-status").textContent = response.ok ? `sent ${command.type} to ${agent}` : answer.error;
  $("panel-status").classList.toggle("error", !response.ok);
}

function button(parent, label, command) {
  const b = document.createElement("button");
  b.type = "button";
  b.textContent = label;
  b.onclick = () => sendCommand(command);
  $(parent).append(b);
}

function buildPanel(agents, eyeModes) {
  for (const agent of agents) $("agent").append(new Option(agent, agent));
  for (const name of ["natural", "happy", "surprised", "arrogant", "angry", "half-angry", "disappointed",
                      "annoyed", "frightened"]) {
    button("emotions", name, { type: "set_emotion", name, intensity: 1.0, transition_s: 0.4 });
  }
  for (const role of ["talking", "listening", "silence"]) button("roles", role, { type: "set_role", role });
  for (const [label, turn, nod] of [["left", -0.5, 0], ["centre", 0, 0], ["right", 0.5, 0], ["up", 0, 0.4],
                                    ["down", 0, -0.4]]) {
    button("heads", label, { type: "move_head", turn, nod, tilt: 0, duration_s: 0.6 });
  }
  for (const mode of eyeModes) button("eyes", mode, { type: "set_eyes", mode });
}

$("connect").onclick = async () => {
  const b = $("connect");
  b.disabled = true;
  try {
    if (eca.pc) {
      await disconnect();
      b.textContent = "Connect";
      $("mute").disabled = true;
    } else {
      eca.state = "connecting";
      showStats();
      await connect();
      b.textContent = "Disconnect";
      $("mute").disabled = false;
    }
  } catch (error) {
    eca.error = String(error.message || error);
    eca.state = `error: ${eca.error}`;
    await disconnect();
    eca.state = `error: ${eca.error}`;
    showStats();
  } finally {
    b.disabled = false;
  }
};

$("mute").onclick = () => {
  const muted = !Object.values(eca.faces).every((v) => v.muted);
  for (const video of Object.values(eca.faces)) video.muted = muted;
  $("mute").textContent = muted ? "Unmute voice" : "Mute voice";
};

if (params.get("mic") === "0") $("mic").checked = false;
fetch(withToken("/config")).then((r) => r.json()).then((config) => buildPanel(config.agents, config.eye_modes)).catch(() => {});
setInterval(pollStats, 1000);
showStats();
