// Watching an agent through Janus (its Streaming plugin) instead of peering with eca: the web service publishes each
// face once into a mountpoint (eca/services/processes/web/sfu.py) and GET /config says where ({"sfu": {"url",
// "mountpoints": {agent: id}}}). Janus's own HTTP API, spoken directly (no janus.js): a session, a handle on
// janus.plugin.streaming, "watch" the mountpoint, answer Janus's offer with "start", trickle this page's ICE
// candidates, and long-poll the session for Janus's events (its offer, its candidates); the long poll also keeps the
// session alive (Janus drops one after 60 s without a request). Janus must allow this page's origin (its HTTP
// transport's cors allow_origin). The server-drawn video, the voice and, for a face the page draws itself, its face
// frames (a mountpoint's data section, relayed to the page's data channel) come this way; the microphone stays on a
// direct connection with eca.
"use strict";

const transaction = () => Math.random().toString(36).slice(2, 14);

// A request that never reached Janus (fetch's network error: a keep-alive connection Janus closed as the request
// went out, a moment without a route) is sent again, three times at most, after 0.25, 0.5 and 1 s; an answer, even
// an error, is final. A "create" or "attach" that did reach Janus and whose answer was lost leaves a session Janus
// drops by itself (its session timeout).
const RETRY_MS = [250, 500, 1000];

async function janusPost(url, body) {
  const init = { method: "POST", headers: { "Content-Type": "application/json" },
                 body: JSON.stringify({ ...body, transaction: transaction() }) };
  let response = null;
  for (let attempt = 0; response === null; attempt += 1) {
    try {
      response = await fetch(url, init);
    } catch (error) {
      if (!(error instanceof TypeError) || attempt >= RETRY_MS.length) throw error;
      await new Promise((resolve) => setTimeout(resolve, RETRY_MS[attempt]));
    }
  }
  const answer = await response.json();
  if (answer.janus === "error") throw new Error(`Janus: ${answer.error ? answer.error.reason : "an error"}`);
  const data = answer.plugindata && answer.plugindata.data;
  if (data && data.error) throw new Error(`Janus streaming: ${data.error}`);
  return answer;
}

export class JanusWatch {
  // `iceServers`: STUN/TURN servers for the page's side of the connection (RTCPeerConnection's iceServers)
  constructor(url, mountpoint, iceServers = []) {
    this.url = url.replace(/\/+$/, "");
    this.mountpoint = mountpoint;
    this.iceServers = iceServers;
    this.pc = null;
    this.session = null;
    this.handle = null;
    this.closed = false;
    this.offers = [];  // Janus's offers (jsep) not yet taken, and who waits for one
    this.waiting = null;
    this.candidates = [];  // Janus's candidates that came before its offer was taken
  }

  get handleUrl() { return `${this.url}/${this.session}/${this.handle}`; }

  // Watch the mountpoint; `onTrack` gets each received track's event (as RTCPeerConnection.ontrack), `onData` (if
  // given) each message of the mountpoint's data section; `media`: the mids to watch (null: all of them).
  async start(onTrack, timeoutMs = 20000, onData = null, media = null) {
    this.session = (await janusPost(this.url, { janus: "create" })).data.id;
    this.handle = (await janusPost(`${this.url}/${this.session}`,
                                   { janus: "attach", plugin: "janus.plugin.streaming" })).data.id;
    this.poll();
    const watch = { request: "watch", id: this.mountpoint, ...(media ? { media } : {}) };
    await janusPost(this.handleUrl, { janus: "message", body: watch });
    const offer = await this.nextOffer(timeoutMs);
    const pc = new RTCPeerConnection({ iceServers: this.iceServers });
    this.pc = pc;
    pc.ontrack = onTrack;
    pc.onicecandidate = (event) => {
      const candidate = event.candidate
        ? { candidate: event.candidate.candidate, sdpMid: event.candidate.sdpMid,
            sdpMLineIndex: event.candidate.sdpMLineIndex }
        : { completed: true };
      if (!this.closed) janusPost(this.handleUrl, { janus: "trickle", candidate }).catch(() => {});
    };
    await pc.setRemoteDescription(offer);
    if (onData && offer.sdp.includes("m=application")) {
      // Janus relays a mountpoint's data once the viewer's data channel is open: the page opens it, under the label
      // Janus sends on when its plugin names none (as janus.js does)
      this.channel = pc.createDataChannel("JanusDataChannel");
      this.channel.binaryType = "arraybuffer";
      this.channel.onmessage = onData;
    }
    for (const c of this.candidates.splice(0)) await pc.addIceCandidate(c.completed ? null : c).catch(() => {});
    await pc.setLocalDescription(await pc.createAnswer());
    await janusPost(this.handleUrl, { janus: "message", body: { request: "start" },
                                      jsep: { type: "answer", sdp: pc.localDescription.sdp } });
    return pc;
  }

  nextOffer(timeoutMs) {
    if (this.offers.length) return Promise.resolve(this.offers.shift());
    return new Promise((resolve, reject) => {
      const timer = setTimeout(() => reject(new Error("Janus sent no offer for the mountpoint")), timeoutMs);
      this.waiting = (jsep) => { clearTimeout(timer); resolve(jsep); };
    });
  }

  async poll() {
    while (!this.closed) {
      let events;
      try {
        const response = await fetch(`${this.url}/${this.session}?maxev=10&rid=${Date.now()}`);
        events = await response.json();
      } catch (error) {
        await new Promise((resolve) => setTimeout(resolve, 1000));  // Janus away for a moment: ask again
        continue;
      }
      for (const event of Array.isArray(events) ? events : [events]) this.onEvent(event);
    }
  }

  onEvent(event) {
    if (event.janus === "error" && event.error && event.error.code === 458) this.closed = true;  // session gone
    if (event.jsep && event.jsep.type === "offer") {
      if (this.waiting) { const w = this.waiting; this.waiting = null; w(event.jsep); } else this.offers.push(event.jsep);
    }
    if (event.janus === "trickle") {
      const c = event.candidate || {};
      if (this.pc && this.pc.remoteDescription) this.pc.addIceCandidate(c.completed ? null : c).catch(() => {});
      else this.candidates.push(c);
    }
    if (event.janus === "hangup" && this.onhangup) this.onhangup(event.reason);
  }

  // The page is going away (its tab closed, a reload, another page): Janus is told to drop this viewer now, in a
  // request the browser still sends once the page is gone (keepalive; a text body, which Janus reads as JSON and which
  // needs no CORS preflight), instead of relaying to a page that is not there until the session times out (60 s)
  leave() {
    if (this.closed || !this.session) return;
    this.closed = true;
    fetch(`${this.url}/${this.session}`, { method: "POST", keepalive: true,
                                            body: JSON.stringify({ janus: "destroy", transaction: transaction() }) })
      .catch(() => {});
  }

  async close() {
    this.closed = true;
    if (this.pc) this.pc.close();
    if (this.session) await janusPost(`${this.url}/${this.session}`, { janus: "destroy" }).catch(() => {});
  }
}
