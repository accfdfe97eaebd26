"""Web front-end: A/V offset as the browser presents it, command -> frame latency, and cost per viewer, for
the face the server draws (video) and, side by side, the face the page draws itself (face frames).

Starts `eca up --web` (dialogue, gaze, audio and the web service; no renderer) on a private instance and
a free port, and drives a real headless Chromium (tests/support/browser.py; WebGL through SwiftShader) on
the product page. What the bench measures in the page it injects (selenium's execute_script); the page
itself is not changed. Phases 1-3 measure the 2D face, which only the server draws, sent as video; phases
4-6 the same on a second instance, `eca up --web --face head`, whose agent's face is the default 3D head,
which a page with WebGL draws itself. The instances' supervisor waits 10 s instead of 1.5 s for a silent
service: on a loaded machine the web service's loop stalled longer than 1.5 s, and a web service restarted
on port 0 serves on another port, which ends the run; the longest gap between its heartbeats on the bus
(its loop's longest stall) is a figure of each instance.

1. A/V offset as the browser presents it. One page receives the agent twice: on the page's own
   connection (640x480 at 30 fps), and on a second connection whose offer asks for the web service's
   calibration mode (services/processes/web/calibration.py): the same face and voice with markers on them, a
   patch on the picture that flashes white on the frame for each whole second of the master clock and a
   click added to the audio at exactly that time. The markers are the source-aligned reference, and they
   travel with the face on one connection: a browser settles each connection's A/V sync on its own and
   leaves differences under about 30 ms alone (libwebrtc's stream synchronization), so a reference on a
   connection of its own, as this bench once had, settled up to 33 ms away from the face's for reasons of
   its own. The agent says loud vowel bursts (250 ms of /a/), one a second, each onset drawn from the
   seeded generator 0.36-0.40 s after a whole second: between the clicks, and at every phase of the frame
   slots (a full-size silent say, interrupted once it starts, tells ahead when the say's first sample
   reaches the output). The lip-sync opens the mouth on each.
   Video: `requestVideoFrameCallback` on each <video>; each presented frame is drawn into a canvas and
   measured (the dark red pixels of the open mouth in a box around it; on the marked connection also the
   luma of the patch); its time is the callback's `expectedDisplayTime`. The mouth opens at the first
   frame whose jaw is half its peak in the burst (the peak from the mouth keys on the bus), found by its
   count: the count is no linear measure of the jaw (none shows until the lips part, about a quarter
   open), so the bench draws the face in its own process at jaw weights 0..1 with the service's renderer
   and sets the threshold where the count of half the peak lies between the page's closed and open
   levels.
   Audio: each stream goes into one AudioContext (MediaStreamAudioSourceNode) and an AudioWorklet that
   finds onsets sample-exactly (the first sample over 0.05 of full scale after 0.2 s below it; an
   AnalyserNode shows only the newest window when polled, so an onset's sample is lost); on the marked
   connection each onset is the burst's or the click's, whichever left the source last before it. The
   onset's context time is mapped to the page's clock with `AudioContext.getOutputTimestamp()` (the
   context time now at the output, and the `performance.now()` when it is there): when the onset is heard.
   The context and its taps are made afresh half a second before measuring: a tap's buffer grows by a
   block at each glitch of a loaded machine and never shrinks (seen as every connection's offset stepping
   +10 ms at once), a delay of the measuring tap, not of what the browser plays.
   Offset = audio onset - mouth opening (flash), ms; positive = audio late. The browser aligns each
   connection's streams in steps during the first 20-40 s: the figures come from `--measure-s` after
   `--settle-s`. Targets: the face's offset within +-15 ms of the markers' on the same connection, and
   the face's offset on the page's own connection within ATSC IS-191 (audio at most 15 ms early, 45 ms
   late). The WebAudio path of the page can differ from the <video> element's own audio output by a
   constant, which the difference cancels. Also shown: the lip-sync's own timing at the source (the mouth
   keys on the bus), how far apart the browser left the face on its two connections, each offset per 10 s
   since connecting, the browser's own estimate (getStats estimatedPlayoutTimestamp), and each path from
   the master clock to heard or shown.
2. Command -> first frame presented that shows it, on a fresh page and connection (after the A/V phase,
   whose load would otherwise linger in the browser's jitter buffers) once it has settled for
   `--settle-s`: `--trials` set_emotion commands (surprised / angry, transition 0) at seeded pauses;
   the page keeps a small grey thumbnail of every presented frame; the
   first frame after a command nearer the new expression than the old is the one. The page's clock and
   this host's monotonic clock are tied by GETs of a tiny server of the bench (the browser's time at the
   middle of the fastest round trip; its half-length is the uncertainty). Parts: bus (command -> the
   dialogue's state, its t_ns), state -> frame received by the browser (rVFC receiveTime), received ->
   presented (presentationTime), presented -> displayed (expectedDisplayTime), all measured per command;
   within them, estimated: draw and VP8 encode per frame (timed in the bench process on the service's
   renderer and encoder, before the instance starts), network (half the ICE round trip), jitter buffer and
   decode (getStats averages over the phase), the wait for the frame slot (the rest). Target p95 <= 100 ms.
3. Cost per viewer: CPU (share of one core, /proc/<pid>/stat utime+stime over a window) and RSS of the
   web service with 0 viewers, then 1, 2, 4, 8 (`--viewers`) of one agent at 640x480/30 fps: the first is
   the Chromium page (it measures the frame rate it receives, getStats framesDecoded), the others are
   aiortc clients in a helper process that receive but do not decode (the server's work is the same),
   then all leave. Targets: <= 10 % of a core per additional viewer, >= 28 fps received with 8 viewers,
   RSS back within 10 % of its 0-viewer level after all leave. The service does not report its draw
   time; the bench's own draw of the face (the baseline) stands for it.

4. A/V offset of the face drawn in the page (the second instance). One fresh page (not connected itself) makes
   a connection that draws the face itself, made as app.js connect() makes it (the "eca-face" data channel
   before the offer, only an audio section for the agent, `draw_here`) with `calibration: true`, so its voice
   carries the clicks; the page's canvas is a face3d.js BrowserFace fed the channel's messages and presented
   at every animation frame. The face is measured alone first (from 10 s after connecting, for `--measure-s`:
   the service draws nothing); then the page adds the markers' reference as in 1 (the head drawn by the
   service, with the flashing patch, and the voice with the clicks), and after `--settle-s` for it the face is
   measured beside it ("the first minute", the targets' comparison; the service now draws video too, and
   composes the pages' face frames in the same loop). With `--long-s 600`, one more window of `--measure-s`
   beside the markers after 10 minutes of talking. A face frame whose time is a whole second of the master
   clock carries the MARK flag (the clicks' instants); with `--hum-level 0` there is no tone, so the voice to the
   page pauses in silence (tracks.py) and every click and burst begins a talk spurt; a mark counts as drawn
   at the first drawing whose heard frame reached or passed it (its shownMs in face3d.js `log.heard`,
   performance.now() in present();
   `log.marks` has only the marked frames drawn themselves, and animation frames rarer than the face frames
   skip over most). The agent talks throughout: 4 s of a quiet tone alone, whose start at the output tells
   where what follows starts, then says of 60 s queued back to back (the player plays a queue without gaps;
   each planned to start where the one before ends, and checked against when it did) of the same vowel bursts
   between the clicks over the quiet tone (0.008 of full scale, 150 Hz: under the onset level and the
   lip-sync's speech gate), which keeps every frame "voiced", so the page shows the voice's part of a frame
   when its sound plays (in silence it shows the newest frame as it arrives, a mark too). Audio onsets as in
   1; each click is paired with the mark drawn nearest to it. Offset = click heard - mark drawn, ms; + = audio
   late. Targets: the offset within ATSC IS-191, and beside the markers within +-15 ms of theirs (each
   second's click - mark less the markers' click - flash of that second). Also shown: the offset to the
   animation frame after the drawing (by then the frame drawn is on the screen; SwiftShader on 2 cores draws
   the head a few times a second, not at 60 Hz); the offset at the page's voice clock (the click less when the
   voice clock, at the drawing, said the mark's time played: the wait for the animation frame taken out, which
   leaves the clock's own error); the drawn mouth against the bursts (the first heard frame whose largest
   voiced weight is half way to its peak in the burst); the share of heard frames flagged voiced; face frames
   received and animation frames drawn a second; each offset per 10 s (per minute for a long run); the paths
   from the master clock to heard and drawn; the voice clock's reports. With `--no-webgl-draw` the page's
   BrowserFace chooses and logs its frames at every animation frame but draws nothing: animation frames then
   come at the display's rate, as on a machine with a GPU, and the figures are those of the face's timing, not
   of SwiftShader's drawing. With `--browser-gl egl` the page draws through the system's EGL instead of
   SwiftShader (Mesa's llvmpipe on a machine without a GPU: the head about 19 times a second on 2 cores instead
   of 4-7), and the page's WebGL renderer is printed; `--size 320x240` makes the server's video (the markers'
   reference) smaller, which leaves such a machine more room to draw the page's face beside it.
5. Command -> face drawn in the page, on a fresh page with a fresh drawing connection (no markers), the
   agent silent: `--trials` set_emotion commands as in 2. The bench notes, for each frame first drawn as the
   newest (face3d.js `log.newest`: arrivedMs, shownMs), the weights of the targets the voice does not move
   (brows, eyes, cheeks); the first frame after a command nearer the new expression than the old is the
   one (as in 2). Parts: bus, state -> frame arrived on the data channel, arrived -> drawn. Target p95 <=
   60 ms; the server-drawn path's figure of 2 is printed beside it.
6. Cost per viewer that draws the face itself: the web service's CPU and RSS as in 3, with 0, then 1, 2, 4,
   8 aiortc viewers in the helper process, each as tests/support/web_client.py FaceClient (the data
   channel, the voice only, `draw_here`; the voice not decoded); the face frames each receives a second.
   Targets as in 3; the video figures of 3 beside them (the 2D face there, the head here).

Figures are printed one per line against their target (met / MISSED / info); the bench always exits 0.
With --json the table goes to stderr and one JSON object to stdout. Progress lines go to stderr.

    python bench/web.py [--settle-s 40] [--measure-s 30] [--trials 40] [--viewers 1,2,4,8] [--seed 0]
                        [--draw both|server|browser] [--long-s 0] [--hum-level 0.008] [--no-webgl-draw] [--skip-av]
                        [--browser-gl swiftshader|egl] [--size 640x480] [--skip-latency] [--skip-viewers] [--json]

A full run takes about 8-9 minutes on 2 cores (the server-drawn face: start and baselines 10 s, A/V 75 s,
latency 75 s, viewers 60 s; the browser-drawn face: start 10 s, A/V 110 s, latency 40 s, viewers 60 s);
`--long-s 600` makes the browser-drawn A/V phase 630 s.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import random
import re
import signal
import statistics
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bench.procs import cpu_seconds  # noqa: E402
from bench.report import Report, percentile, run_guarded, wait_until_ns  # noqa: E402
from eca.services.processes.web.calibration import PATCH  # noqa: E402 (after the path is set)
from eca.services.tools.child_processes import subprocess_env  # noqa: E402

AGENT = "ada"
WIDTH, HEIGHT, FPS = 640, 480, 30.0
READY_TIMEOUT_S = 90.0
HEARTBEAT_TIMEOUT_S = 10.0  # the bench's instances' supervisor (the product's default: 1.5 s; see instance())
CONNECT_TIMEOUT_S = 30.0

# A/V
BURST_S = 0.25
# a burst a second, its onset drawn from this span after the whole second of the master clock (a frame
# slot): onsets at every phase of the slots, and each burst and click with ONSET_QUIET_S of quiet before it
BURST_AFTER_SECOND_S = (0.36, 0.40)
CLEAR_AFTER_CLICK_S = (0.22, 0.54)  # a burst with its onset outside this (a say that started late) nears a click
SAY_RATE_HZ = 16_000
ONSET_LEVEL = 0.05  # of full scale: the first sample over it after ONSET_QUIET_S below it is an onset
ONSET_QUIET_S = 0.2
PAIR_WINDOW_MS = 300.0  # an audio onset and a mouth opening (flash) this close belong together
MOUTH_BOX = (0.34, 0.58, 0.66, 0.92)  # x0, y0, x1, y1 of the picture, around the mouth at 640x480
# inside a reference's flashing patch, clear of its edges (which the encoder blurs into the face)
PATCH_BOX = tuple(a + (b - a) * f for a, b, f in zip(PATCH[:2] * 2, PATCH[2:] * 2, (0.2, 0.2, 0.8, 0.8), strict=True))
MAX_SAY_S = 100.0  # the say's inline PCM (16 kHz, 16 bit) stays well under the bus's 4 MiB message cap
TRAJECTORY_WINDOW_S = 10.0
MARKED = "marked"  # the connection of the agent with the calibration markers on it (flashes and clicks)

# the face drawn in the browser (a second instance, its agent's face the default 3D head)
DRAWN_FACE = "head"
DRAWN = "drawn"  # the page's connection that draws the face itself, with the clicks on its voice
# A quiet tone under the bursts keeps the voice sounding at every frame (the service's "voiced" flag: a sample
# over 64 of 32767 within 10 ms), so the page shows a frame's voice part when its sound plays, at the marked
# seconds too, not as it arrives (face3d.js present(): in silence the newest frame is shown). Far under
# ONSET_LEVEL, and under the lip-sync's speech gate (30 dB below the bursts): it opens no mouth.
HUM_LEVEL = 0.008
HUM_HZ = 150.0
SAY_PART_S = 60.0  # the talk: says of this length, queued back to back (the player plays a queue without gaps)
LEAD_IN_S = 4.0  # the talk's first say, the hum alone: when it starts tells where the bursts that follow go
QUEUE_AHEAD_S = 15.0  # the next say is sent when the queued talk ends within this
DRAWN_SETTLE_S = 5.0  # latency: the browser-drawn face's frames flow this long before the first command
DRAWN_ALONE_SETTLE_S = 10.0  # A/V: the face alone is measured from this long after connecting

# latency
EMOTIONS = ("surprised", "angry")  # brows, eyes and mouth all move: far apart in a thumbnail
PAUSE_S = (0.6, 0.9)  # between commands, drawn per command: commands land at every phase of the slots
SIGNATURE_SIZE = (32, 24)

# viewers
VIEWER_SETTLE_S = 3.0
VIEWER_WINDOW_S = 6.0
AFTER_LEAVING_S = 5.0

# Targets
TARGET_AV_DIFF_MS = 15.0
ATSC_EARLY_MS, ATSC_LATE_MS = 15.0, 45.0
TARGET_LATENCY_P95_MS = 100.0
TARGET_DRAWN_LATENCY_P95_MS = 60.0
TARGET_CPU_PER_VIEWER = 10.0  # % of one core
TARGET_FPS_MIN = 28.0
TARGET_RSS_RETURN = 0.10


def progress(line: str) -> None:
    print(f"[web-bench] {line}", file=sys.stderr, flush=True)


def spread(values: list[float]) -> dict[str, float]:
    if not values:
        return {"n": 0}
    return {"n": len(values), "median": round(statistics.median(values), 2), "p10": round(percentile(values, 0.1), 2),
            "p90": round(percentile(values, 0.9), 2), "p95": round(percentile(values, 0.95), 2),
            "mean": round(statistics.fmean(values), 2)}


# --- what the bench injects into the page ----------------------------------------------------------

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


# --- the page's clock against this host's monotonic clock -----------------------------------------


class TimeServer:
    """A tiny HTTP server answering each GET with this host's monotonic time (ns), for the page."""

    def __init__(self) -> None:
        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 (http.server's name)
                body = str(time.monotonic_ns()).encode()
                self.send_response(200)
                self.send_header("Access-Control-Allow-Origin", "*")  # the page is another origin (port)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/now"
        self._thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.1},
                                        daemon=True, name="time-server")

    def __enter__(self) -> TimeServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.shutdown()
        self.server.server_close()
        self._thread.join(timeout=5)


@dataclass(frozen=True)
class ClockTie:
    """host monotonic ms = page ms + offset_ms, to within +-uncertainty_ms."""

    offset_ms: float
    uncertainty_ms: float

    def host_ms(self, page_ms: float) -> float:
        return page_ms + self.offset_ms



class EmotionStates:
    """The agent's emotion states as the bus publishes them, (t_ns, name) each, read while the bench waits."""

    def __init__(self, ctx: Any, config: Any) -> None:
        from eca.protocol.bus import Subscriber

        self.sub = Subscriber(ctx, config, [f"state.{AGENT}.emotion"])
        self.sub.wait_ready()
        self.seen: list[tuple[int, str]] = []

    def listen(self, left_s: float) -> None:
        from eca.protocol.messages import EmotionState

        got = self.sub.recv(left_s)
        while got is not None:
            if isinstance(got.message, EmotionState):
                self.seen.append((got.message.t_ns, got.message.name))
            got = self.sub.recv(0.0)

    def close(self) -> None:
        self.sub.close()

def tie_clocks(driver: Any, server: TimeServer, round_trips: int = 40) -> ClockTie:
    """The browser's time at the middle of the fastest of `round_trips` GETs, against the host's."""
    got = driver.execute_async_script(CLOCK_JS, server.url, round_trips)
    if isinstance(got, dict):
        raise RuntimeError(f"the page could not reach the bench's clock: {got['error']}")
    t0, t1, host = min(got, key=lambda r: r[1] - r[0])
    return ClockTie(int(host) / 1e6 - (t0 + t1) / 2, (t1 - t0) / 2)


def combined_tie(ties: list[ClockTie]) -> tuple[ClockTie, float]:
    """One tie from several (the mean; the uncertainty covers each and their spread), and the drift seen."""
    offsets = [t.offset_ms for t in ties]
    drift = max(offsets) - min(offsets)
    return ClockTie(statistics.fmean(offsets), max(t.uncertainty_ms for t in ties) + drift / 2), drift


# --- the instance ----------------------------------------------------------------------------------


class HeartbeatWatch:
    """The heartbeats of one service on the bus, in a thread: the longest silence between two."""

    def __init__(self, config: Any, service: str) -> None:
        self.config, self.service = config, service
        self.longest_s = 0.0
        self.longest_at = 0.0  # when that silence ended (monotonic s)
        self.beats = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True, name="heartbeat-watch")

    def _watch(self) -> None:
        import zmq

        from eca.protocol.bus import Subscriber
        from eca.protocol.messages import Heartbeat

        ctx = zmq.Context()
        sub = Subscriber(ctx, self.config, ["sys."])
        last: float | None = None
        try:
            while not self._stop.is_set():
                got = sub.recv(0.2)
                if got is None or not isinstance(got.message, Heartbeat) or got.message.service != self.service:
                    continue
                now = time.monotonic()
                if last is not None and now - last > self.longest_s:
                    self.longest_s, self.longest_at = now - last, now
                last = now
                self.beats += 1
        finally:
            sub.close()
            ctx.term()

    def __enter__(self) -> HeartbeatWatch:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


@dataclass
class Instance:
    config: Any
    reader: Any
    url: str
    web_pid: int
    beats: HeartbeatWatch

    def viewers_watching(self, since: int = 0) -> int | None:
        """How many viewers the web service says watch, from its latest 'left' line from line `since` on
        (None: none)."""
        for line in reversed(self.reader.lines[since:]):
            m = re.search(r"\[web\] INFO viewer \d+ left \((\d+) watching\)", line)
            if m:
                return int(m.group(1))
        return None


@contextmanager
def instance(face: str | None = None) -> Iterator[Instance]:
    """`eca up --web` on a private instance and a free port; with `face`, every agent's face (`--face`)."""
    from tests.support.bus import eca_command, private_bus_config, running

    # The supervisor restarts a service whose loop is silent for [heartbeat] timeout_s (1.5 s); on a loaded machine
    # the web service's loop stalled longer (the figure "loop: longest stall"), and a web service restarted on
    # port 0 serves on another port, which ends the run: the bench's instances wait HEARTBEAT_TIMEOUT_S.
    with private_bus_config(services=["dialogue", "gaze", "audio"],
                            extra=f"[heartbeat]\ninterval_s = 0.25\ntimeout_s = {HEARTBEAT_TIMEOUT_S:g}\n") as config:
        # The product's own viewer watchdog runs (silent_timeout_s): the bench's connections last minutes,
        # so a healthy page closed as silent shows in the figures below.
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--web", "--web-port", "0", *(("--face", face) if face else ()))
        progress(f"starting eca up --web{f' --face {face}' if face else ''} (instance {config.instance})")
        with running(argv, stop_timeout_s=10.0) as (proc, reader):
            try:
                reader.wait_for("[up] ready in", READY_TIMEOUT_S)
            except TimeoutError:
                said = [line for line in reader.lines if re.search(r"ERROR|Error|not restarted", line)]
                raise RuntimeError(f"eca up was not ready within {READY_TIMEOUT_S:g} s: "
                                   f"{' | '.join(said[-3:]) or 'no error printed'}") from None
            line = reader.lines[reader.wait_for("[web] INFO serving http://", 10.0)]
            url = re.search(r"(http://\S+/)", line)
            ready = reader.lines[reader.wait_for("[web] INFO ready (pid", 10.0)]
            pid = re.search(r"ready \(pid (\d+)\)", ready)
            assert url is not None and pid is not None
            with HeartbeatWatch(config, "web") as beats:
                yield Instance(config, reader, url.group(1), int(pid.group(1)), beats)


def open_page(driver: Any, url: str) -> None:
    driver.get(f"{url}?mic=0&width={WIDTH}&height={HEIGHT}&fps={FPS:g}")
    connect_page(driver)


def connect_page(driver: Any) -> None:
    from tests.support.browser import wait_for

    driver.find_element("id", "connect").click()
    wait_for(driver, "return window.eca.state", CONNECT_TIMEOUT_S, "the page connecting", lambda s: s == "connected")


def video_stats(driver: Any, which: str = "face") -> dict[str, Any]:
    got = driver.execute_async_script(VIDEO_STATS_JS, which)
    return got or {}


# --- in-process baselines: the face drawn once, and its VP8 encode ------------------------------


def draw_and_encode_baselines(frames: int = 150) -> dict[str, float]:
    """Per frame at 640x480, in this process, as the service does them: compose + draw + yuv420p on the
    GPU + read-back (once per frame slot), and the VP8 encode of the result (once per picture for all
    the viewers of that size and rate)."""
    from eca.agent.face.model import FaceModel
    from eca.services.processes.renderer import Renderer, create_headless_context
    from eca.services.processes.renderer.yuv import YuvTarget
    from eca.services.processes.web.encoding import Vp8Encoder
    from eca.services.processes.web.feeds import Picture

    os.environ.setdefault("LP_NUM_THREADS", "1")  # as the web service draws (services/processes/web/service.py)
    ctx = create_headless_context()
    try:
        renderer = Renderer(ctx, (WIDTH, HEIGHT))
        target = YuvTarget(ctx, (WIDTH, HEIGHT))
        model = FaceModel(seed=1)
        encoder = Vp8Encoder(WIDTH, HEIGHT, FPS)
        period_ns = round(1e9 / FPS)
        draw_ms: list[float] = []
        encode_ms: list[float] = []
        for i in range(frames + 20):  # the first 20: shader variants compile, the encoder starts
            t_ns = i * period_ns
            if i % 30 == 0:
                model.set_emotion(EMOTIONS[(i // 30) % 2], 1.0, t_ns=t_ns)
            model.set_eyes(15.0 * math.sin(i * 0.11), 8.0 * math.cos(i * 0.07), 1.0 if i % 90 < 5 else None)
            model.set_mouth({"say_ah": 0.5 + 0.5 * math.sin(i * 0.4)})
            t0 = time.perf_counter()
            renderer.render(model.frame_at(t_ns).values, target=target.fbo)
            yuv = target.read()
            t1 = time.perf_counter()
            encoder.encode(Picture(t_ns, yuv, WIDTH, HEIGHT), keyframe=False)
            t2 = time.perf_counter()
            if i >= 20:
                draw_ms.append(1e3 * (t1 - t0))
                encode_ms.append(1e3 * (t2 - t1))
        target.release()
    finally:
        ctx.release()
    return {"draw_ms": statistics.median(draw_ms), "draw_p95_ms": percentile(draw_ms, 0.95),
            "encode_ms": statistics.median(encode_ms), "encode_p95_ms": percentile(encode_ms, 0.95),
            "frames": frames}


# --- 1. A/V offset ---------------------------------------------------------------------------------


def vowel_bursts(rng: random.Random, seconds: float, first_sample_ns: int,
                 hum: float = 0.0) -> tuple[bytes, list[float]]:
    """PCM (16-bit, SAY_RATE_HZ) of loud /a/ bursts, one a second, and each burst's onset (s into the say):
    for a say whose first sample is at the output at `first_sample_ns` (master clock), each onset falls
    BURST_AFTER_SECOND_S (drawn per burst) after a whole second, between the markers' clicks. With `hum` (of
    full scale), a quiet tone of HUM_HZ under it all, from the first sample to the last."""
    rate = SAY_RATE_HZ
    t = np.arange(round(BURST_S * rate)) / rate
    f0 = 140.0
    vowel = np.zeros_like(t)
    for h in range(1, int(4000 / f0)):  # harmonics shaped by the formants of /a/: the lip-sync's "open"
        f = h * f0
        gain = sum(1 / math.sqrt(1 + ((f - formant) / (bw / 2)) ** 2)
                   for formant, bw in ((750, 90), (1150, 110), (2600, 160)))
        vowel += gain * np.sin(2 * np.pi * f * t)
    ramp = round(0.002 * rate)  # 2 ms: a sharp onset without a click
    envelope = np.ones_like(t)
    envelope[:ramp] = np.linspace(0, 1, ramp)
    envelope[-ramp:] = np.linspace(1, 0, ramp)
    vowel = 0.5 * vowel / np.abs(vowel).max() * envelope
    onsets: list[float] = []
    second_ns = -(-first_sample_ns // 1_000_000_000) * 1_000_000_000  # the first whole second in the say
    while True:
        at = (second_ns - first_sample_ns) / 1e9 + rng.uniform(*BURST_AFTER_SECOND_S)
        if at + BURST_S >= seconds:
            break
        if at >= 0.5:
            onsets.append(at)
        second_ns += 1_000_000_000
    pcm = np.zeros(round(seconds * rate))
    for onset in onsets:
        i = round(onset * rate)
        pcm[i:i + len(vowel)] = vowel
    if hum:
        pcm += hum * np.sin(2 * np.pi * HUM_HZ * np.arange(len(pcm)) / rate)
    return (pcm * 32767).astype("<i2").tobytes(), onsets


def open_mouth_pixels(rgb: np.ndarray) -> int:
    """The page's count of the open mouth's dark red (PAGE_JS openMouth), of an RGB picture's mouth box."""
    h, w = rgb.shape[:2]
    x0, y0, x1, y1 = MOUTH_BOX
    box = rgb[round(y0 * h):round(y1 * h), round(x0 * w):round(x1 * w)].astype(int)
    r, g, b = box[..., 0], box[..., 1], box[..., 2]
    return int(((r > 60) & (r < 200) & (g < 70) & (b < 90) & (r - g > 50)).sum())


def mouth_curve(steps: int = 20) -> dict[str, list[float]]:
    """The open-mouth count at jaw (say_ah) weights 0..1, the face drawn at 640x480 by the service's renderer
    in this process (neutral, eyes ahead)."""
    from eca.agent.face.model import FaceModel
    from eca.services.processes.renderer import Renderer, create_headless_context

    ctx = create_headless_context()
    try:
        renderer = Renderer(ctx, (WIDTH, HEIGHT))
        fbo = ctx.simple_framebuffer((WIDTH, HEIGHT))
        model = FaceModel(seed=1)
        weights = [i / steps for i in range(steps + 1)]
        counts = []
        for weight in weights:
            model.set_mouth({"say_ah": weight})
            renderer.render(model.frame_at(0).values, target=fbo)
            rgb = np.frombuffer(fbo.read(components=3), np.uint8).reshape(HEIGHT, WIDTH, 3)[::-1]
            counts.append(float(open_mouth_pixels(rgb)))
        fbo.release()
    finally:
        ctx.release()
    return {"jaw": weights, "px": counts}


def half_jaw_share(curve: dict[str, list[float]], peak_jaw: float) -> float:
    """Where the count at half the jaw's peak lies between the counts closed and at the peak (0..1)."""
    closed, half, peak = (float(np.interp(w, curve["jaw"], curve["px"])) for w in (0.0, peak_jaw / 2, peak_jaw))
    return (half - closed) / (peak - closed) if peak > closed else 0.5


def mouth_openings(frames: list[dict[str, Any]], share: float = 0.5) -> tuple[list[float], dict[str, float]]:
    """Display times (page ms) of the frames where the open-mouth count crosses `share` of the way from the
    closed level to the open one."""
    counts = [f["mouth"] for f in frames]
    if len(counts) < 10:
        return [], {}
    closed, open_ = percentile(counts, 0.1), percentile(counts, 0.95)
    threshold = closed + share * (open_ - closed)
    levels = {"closed_px": closed, "open_px": open_, "threshold_px": threshold, "share": share}
    if open_ - closed < 200:  # the mouth never opened: no bursts seen
        return [], levels
    out = [b["e"] for a, b in zip(frames, frames[1:], strict=False) if a["mouth"] < threshold <= b["mouth"]]
    return out, levels


def flashes(frames: list[dict[str, Any]]) -> list[float]:
    """Display times (page ms) of the first white frame of each flash."""
    return [b["e"] for a, b in zip(frames, frames[1:], strict=False) if a["luma"] < 128 <= b["luma"]]


def pair_offsets(onsets: list[float], events: list[float]) -> list[tuple[float, float]]:
    """For each audio onset, (its time, onset - the nearest video event within PAIR_WINDOW_MS): + = audio late."""
    out = []
    events = sorted(events)
    for onset in onsets:
        nearest = min(events, key=lambda e: abs(onset - e), default=None)
        if nearest is not None and abs(onset - nearest) <= PAIR_WINDOW_MS:
            out.append((onset, onset - nearest))
    return out


def by_window(pairs: list[tuple[float, float]], tie: ClockTie, start_ms: float, seconds: float,
              step_s: float = TRAJECTORY_WINDOW_S) -> list[dict[str, Any]]:
    """The median offset per `step_s` since `start_ms` (host clock)."""
    out = []
    for w0 in np.arange(0.0, seconds, step_s):
        lo, hi = start_ms + 1e3 * w0, start_ms + 1e3 * (w0 + step_s)
        window = [o for t, o in pairs if lo <= tie.host_ms(t) < hi]
        out.append({"from_s": float(w0), "median_ms": round(statistics.median(window), 1) if window else None,
                    "n": len(window)})
    return out


def jaw_crossings(keys: list[Any], dac0_ms: float, onsets_ms: list[float]) -> tuple[list[float], list[float]]:
    """Per burst (its onset on the master clock, ms): when the lip-sync's jaw (say_ah) first reaches half
    its peak in the burst, minus the onset (ms), with the keys interpolated linearly as the face does;
    and the peaks."""
    times: list[float] = []
    jaw: list[float] = []
    for k in keys:
        times += [dac0_ms + 1e3 * i / k.sample_rate for i in k.sample_index]
        jaw += k.weights.get("say_ah", [0.0] * len(k.sample_index))
    t, w = np.asarray(times), np.asarray(jaw)
    out: list[float] = []
    peaks: list[float] = []
    for onset in onsets_ms:
        near = (t >= onset - 50) & (t <= onset + 1e3 * BURST_S)
        if not near.any() or w[near].max() <= 0:
            continue
        peaks.append(float(w[near].max()))
        half = peaks[-1] / 2
        idx = np.nonzero(near & (w >= half))[0][0]
        if idx == 0 or w[idx - 1] >= half:
            out.append(float(t[idx] - onset))
            continue
        frac = (half - w[idx - 1]) / (w[idx] - w[idx - 1])
        out.append(float(t[idx - 1] + frac * (t[idx] - t[idx - 1]) - onset))
    return out, peaks


def say_latency_ns(client: Any, rid: str, seconds: float) -> int:
    """How long a say of `seconds` takes from sent to its first sample at the output (a silent one of that
    size, interrupted once it starts: a long say takes longer to arrive and prepare than a short one)."""
    from eca.protocol.messages import Interrupt, Say, SpeechInterrupted, SpeechStarted

    sent_ns = time.monotonic_ns()
    client.send(Say(agent=AGENT, request_id=rid, pcm=bytes(2 * round(seconds * SAY_RATE_HZ)),
                    sample_rate=SAY_RATE_HZ, text="latency probe"))
    started = client.wait_for(lambda m: isinstance(m, SpeechStarted) and m.request_id == rid, 10.0)
    client.send(Interrupt(agent=AGENT, request_id=rid, reason="latency probe"))
    client.wait_for(lambda m: isinstance(m, SpeechInterrupted) and m.request_id == rid, 10.0)
    return int(started.dac_time_ns - sent_ns)


def split_onsets(onsets: list[float], tie: ClockTie, bursts_ms: list[float]) -> tuple[list[float], list[float]]:
    """The marked connection's audio onsets (page ms) as the voice's bursts and the markers' clicks: each is
    whichever left the source last before it was heard (a burst at its time on the master clock, a click at
    a whole second)."""
    voice: list[float] = []
    clicks: list[float] = []
    for t in onsets:
        host = tie.host_ms(t)
        burst = max((b for b in bursts_ms if b <= host), default=-math.inf)
        (voice if burst > math.floor(host / 1e3) * 1e3 else clicks).append(t)
    return voice, clicks


def av_phase(args: argparse.Namespace, inst: Instance, driver: Any, server: TimeServer, report: Report,
             rng: random.Random, curve: dict[str, list[float]]) -> None:
    import zmq

    from eca.protocol.bus import Subscriber
    from eca.protocol.client import AgentClient
    from eca.protocol.messages import MouthKeys, Say, SpeechStarted
    from tests.support.browser import wait_for

    details: dict[str, Any] = {}
    report.details["av"] = details
    answer = driver.execute_async_script(CALIBRATION_JS, MARKED, AGENT, WIDTH, HEIGHT, FPS)
    if answer != "ok":
        raise RuntimeError(f"the {MARKED} connection did not connect: {answer}")
    wait_for(driver, STREAMS_READY_JS.replace("AGENT", json.dumps(AGENT)), CONNECT_TIMEOUT_S,
             "every stream with its tracks", bool)
    details["audio_context"] = driver.execute_async_script(START_MEASURING_JS, AGENT)
    connected_ns = time.monotonic_ns()
    names = ("face", MARKED)
    frames: dict[str, list[dict[str, Any]]] = {n: [] for n in names}
    onsets: dict[str, list[float]] = {n: [] for n in names}
    # the browser's own A/V offset per connection: (page ms, estimatedPlayoutTimestamp video - audio)
    sync: dict[str, list[tuple[float, float]]] = {n: [] for n in names}

    def take() -> None:
        got = driver.execute_script(TAKE_JS)
        for name in names:
            frames[name] += got["frames"].get(name, [])
            onsets[name] += got["onsets"].get(name, [])
        for name, polled in driver.execute_async_script(SYNC_JS).items():
            if polled is not None:
                sync[name].append((polled["at"], polled["offset"]))

    measure_start_ns = connected_ns + int(args.settle_s * 1e9)
    measure_end_ns = measure_start_ns + int(args.measure_s * 1e9)
    keys: list[MouthKeys] = []
    rid = "bench-web-bursts"
    ctx = zmq.Context()
    mouth_sub = Subscriber(ctx, inst.config, [f"stream.{AGENT}.mouth"])  # the lip-sync's keys, at the source

    def pull_while_waiting(left_s: float) -> None:
        take()
        for got in mouth_sub.drain():
            if isinstance(got.message, MouthKeys) and got.message.request_id == rid:
                keys.append(got.message)
        time.sleep(min(left_s, 1.0))  # pacing; the page keeps measuring meanwhile

    try:
        mouth_sub.wait_ready()
        with AgentClient(inst.config, agent=AGENT, source="bench-web", ctx=ctx) as client:
            # bursts from the start when the say fits the bus's message cap (the face settles in view),
            # else only while measuring; the say is sent a little before the first window it covers
            whole = args.settle_s + args.measure_s <= MAX_SAY_S
            # the bursts go between the markers' clicks, so the say's first sample must be known ahead
            latency_ns = say_latency_ns(client, "bench-web-latency-probe",
                                        (measure_end_ns - (connected_ns if whole else measure_start_ns)) / 1e9)
            say_at_ns = max(time.monotonic_ns() + 200_000_000,
                            connected_ns if whole else measure_start_ns - 300_000_000)
            pcm, burst_onsets = vowel_bursts(rng, (measure_end_ns - say_at_ns) / 1e9 + 0.5, say_at_ns + latency_ns)
            progress(f"A/V: settling {args.settle_s:g} s, then measuring {args.measure_s:g} s (a vowel burst a "
                     f"second between the markers' clicks; a say reaches the output {latency_ns / 1e6:.0f} ms "
                     "after it is sent)")
            ties = [tie_clocks(driver, server)]
            wait_until_ns(say_at_ns - 300_000_000, pull_while_waiting)
            wait_until_ns(say_at_ns)  # sent on time: the bursts' places between the clicks count on it
            client.send(Say(agent=AGENT, request_id=rid, pcm=pcm, sample_rate=SAY_RATE_HZ, text="vowel bursts"))
            started = client.wait_for(lambda m: isinstance(m, SpeechStarted) and m.request_id == rid, 10.0)
            # fresh taps for the measurement: an audio tap's buffer grows by a block at each glitch of a
            # loaded machine and never shrinks (every connection's offset stepped +10 ms at once), a delay
            # of the tap, not of what the browser plays
            wait_until_ns(measure_start_ns - 500_000_000, pull_while_waiting)
            restarted = driver.execute_async_script(RESTART_AUDIO_JS)
            if restarted is not True:
                raise RuntimeError(f"the page's audio taps could not be made afresh: {restarted}")
            wait_until_ns(measure_end_ns, pull_while_waiting)
            pull_while_waiting(0.0)
            ties.append(tie_clocks(driver, server))
    finally:
        mouth_sub.close()
        ctx.term()
    driver.execute_script(CLOSE_CALIBRATION_JS)  # the marked connection is not needed any more
    tie, drift = combined_tie(ties)
    details.update(clock_offset_ms=tie.offset_ms, clock_uncertainty_ms=tie.uncertainty_ms, clock_drift_ms=drift,
                   browser_estimate=sync, say_latency_ms=latency_ns / 1e6)
    start_ms, end_ms = measure_start_ns / 1e6, measure_end_ns / 1e6
    connected_ms, total_s = connected_ns / 1e6, args.settle_s + args.measure_s

    def in_window(t_page: float) -> bool:
        return start_ms <= tie.host_ms(t_page) < end_ms

    def since_source(t_page: float) -> float:
        """For a flash or a click: ms since the whole second of the master clock it marks."""
        t = tie.host_ms(t_page)
        return t - math.floor(t / 1e3) * 1e3

    dac0_ms = started.dac_time_ns / 1e6  # type: ignore[attr-defined]
    burst_dac = [dac0_ms + 1e3 * o for o in burst_onsets]
    measured_bursts = [t for t in burst_dac if start_ms <= t < end_ms]
    lipsync, peaks = jaw_crossings(keys, dac0_ms, measured_bursts)
    details["lipsync_at_source_ms"] = spread(lipsync)
    details["mouth_curve"] = curve
    share = half_jaw_share(curve, statistics.median(peaks)) if peaks else 0.5
    # a burst that fell too near a click (the say reached the output later than its probe said) can hide
    # the click's onset or its own; how many did not is shown, to explain pairs that are missing
    clear = [t for t in measured_bursts if CLEAR_AFTER_CLICK_S[0] <= (t / 1e3) % 1.0 < CLEAR_AFTER_CLICK_S[1]]
    details["bursts"] = {"measured": len(measured_bursts), "between_clicks": len(clear),
                         "phase_after_second_ms": spread([(t % 1e3) for t in measured_bursts])}

    openings, levels = mouth_openings(frames["face"], share)
    marked_openings, marked_levels = mouth_openings(frames[MARKED], share)
    voice, clicks = split_onsets(onsets[MARKED], tie, burst_dac)
    series = {  # name: (audio onsets, video events), page ms
        "face": (onsets["face"], openings),
        "face with markers": (voice, marked_openings),
        "reference": (clicks, flashes(frames[MARKED])),
    }
    offsets: dict[str, list[float]] = {}
    timed: dict[str, list[tuple[float, float]]] = {}  # (heard, offset) of each pair in the window
    for name, (heard, shown) in series.items():
        pairs = pair_offsets(heard, shown)
        timed[name] = [(t, o) for t, o in pairs if in_window(t)]
        offsets[name] = [o for _, o in timed[name]]
        details[name] = {"offsets": spread(offsets[name]), "offsets_ms": offsets[name],
                         "by_window": by_window(pairs, tie, connected_ms, total_s),
                         "onsets": sum(map(in_window, heard)), "video_events": sum(map(in_window, shown))}
    for name, connection in (("face", "face"), ("face with markers", MARKED)):
        details[name]["frames"] = sum(in_window(f["e"]) for f in frames[connection])
    details["face"]["mouth_levels"] = {**levels, "peak_jaw": statistics.median(peaks) if peaks else None}
    details["face with markers"]["mouth_levels"] = marked_levels
    # what the plain half-way count would have given: how much the jaw's threshold moves the figure
    half_way = [o for t, o in pair_offsets(onsets["face"], mouth_openings(frames["face"])[0]) if in_window(t)]
    details["face"]["offsets_at_half_way_count"] = spread(half_way)
    # paths from the master clock at the source to heard / shown in the page (host clock)
    paths: dict[str, list[float]] = {}
    for name, (heard, shown) in series.items():
        if name == "reference":
            paths["reference: click at source -> heard"] = [since_source(t) for t in heard if in_window(t)]
            paths["reference: flash at source -> shown"] = [since_source(t) for t in shown if in_window(t)]
            continue
        paths[f"{name}: burst at source -> heard"] = [
            d for d in (nearest_after(tie.host_ms(t), burst_dac) for t in heard if in_window(t)) if d is not None]
        paths[f"{name}: burst at source -> mouth shown"] = [
            d for d in (nearest_after(tie.host_ms(t), burst_dac, early_ms=100.0) for t in shown if in_window(t))
            if d is not None]
    details["paths_ms"] = {k: spread(v) for k, v in paths.items()}

    medians = {n: statistics.median(v) for n, v in offsets.items() if v}
    if len(medians) < len(series):
        report.add("A/V: pairs measured", ", ".join(f"{n} {len(v)}" for n, v in offsets.items()), "> 0 each",
                   False, "", f"mouth levels {levels}; bursts between clicks {len(clear)} of {len(measured_bursts)}")
    if "face" in medians:
        face = offsets["face"]
        fm = medians["face"]
        report.add("A/V offset, face (audio - mouth)", round(fm, 1), f"-{ATSC_EARLY_MS:g}..+{ATSC_LATE_MS:g}",
                   -ATSC_EARLY_MS <= fm <= ATSC_LATE_MS, "ms",
                   f"ATSC IS-191, the page's own connection; + = audio late; p10 {percentile(face, 0.1):.1f}, "
                   f"p90 {percentile(face, 0.9):.1f}, n {len(face)}")
    notes = {"face with markers": "the same face and voice with the markers on them, on a connection of their own",
             "reference": "the markers: source-aligned, on that connection"}
    for name, note in notes.items():
        if name in medians:
            v = offsets[name]
            report.add(f"A/V offset, {name}", round(medians[name], 1), "-", None, "ms",
                       f"{note}; p10 {percentile(v, 0.1):.1f}, p90 {percentile(v, 0.9):.1f}, n {len(v)}")
    # each burst against the click of its own second: the browser moves a connection's sync now and then
    # (by 10-35 ms, seen mid-window), which moves both alike; medians of the two whole windows would mix
    # before and after in different shares
    each = []
    for t, o in timed["face with markers"]:
        click_t, click_o = min(timed["reference"], key=lambda c: abs(c[0] - t), default=(math.inf, 0.0))
        if abs(click_t - t) <= 1e3:
            each.append(o - click_o)
    details["face_less_reference_per_second_ms"] = spread(each)
    if each:
        diff = statistics.median(each)
        report.add("A/V offset, face - reference", round(diff, 1), f"+-{TARGET_AV_DIFF_MS:g}",
                   abs(diff) <= TARGET_AV_DIFF_MS, "ms",
                   f"on one connection, each burst less the click of its second (median of {len(each)}; the "
                   f"medians' difference {medians['face with markers'] - medians['reference']:+.1f})")
        if lipsync:
            lag = statistics.median(lipsync)
            # no frame quantization: each frame is composed for the middle of its time on screen, so the
            # mouth shows at the nearest frame (half a frame early or late, 0 on average), as a flash does
            report.add("  of which lip-sync at the source", round(-lag, 1), "-", None, "ms",
                       f"measured: the jaw half open {lag:+.1f} ms from the burst's onset (mouth keys on the bus)")
            report.add("  rest (drawing, sending, the browser)", round(diff + lag, 1), "-", None, "ms",
                       "face - reference less the lip-sync")
    if "face" in medians and "face with markers" in medians:
        report.add("A/V connections apart", round(medians["face"] - medians["face with markers"], 1), "-", None, "ms",
                   "the face on the page's connection - on the marked one: a browser settles each connection's "
                   "sync on its own, leaving up to about 30 ms")
    for name in names:
        polled = [o for t, o in sync[name] if in_window(t)]
        if polled:
            report.add(f"A/V browser's own estimate, {name} connection", round(statistics.median(polled), 1), "-",
                       None, "ms",
                       f"getStats estimatedPlayoutTimestamp video - audio; range {min(polled):g}..{max(polled):g}")
    for name in series:
        steps = [w for w in details[name]["by_window"] if w["median_ms"] is not None]
        if steps:
            report.add(f"A/V {name} while settling", " -> ".join(f"{w['median_ms']:g}" for w in steps), "-", None,
                       "", f"median ms per {TRAJECTORY_WINDOW_S:g} s since connecting")
    for label, values in details["paths_ms"].items():
        if values.get("n"):
            report.add(f"A/V {label}", values["median"], "-", None, "ms",
                       f"p10 {values['p10']}, p90 {values['p90']}, n {values['n']}")
    if peaks:
        report.add("A/V mouth opening threshold", round(share, 3), "-", None, "",
                   f"share of the way from the closed to the open count: where half the jaw's peak "
                   f"({statistics.median(peaks):.2f}) lies in the face drawn by the bench (half-way: 0.5)")
    report.add("A/V page clock tie", round(tie.uncertainty_ms, 2), "-", None, "ms",
               f"+- (GET round trips; drift between start and end {drift:.2f} ms)")


def nearest_after(t_ms: float, sources: list[float], early_ms: float = 0.0) -> float | None:
    """t - the latest source time at most `early_ms` after t (a burst's onset at the source), if within 1 s."""
    before = [s for s in sources if s - early_ms <= t_ms]
    if not before:
        return None
    d = t_ms - max(before)
    return d if d < 1e3 else None


# --- 2. command -> frame ---------------------------------------------------------------------------


def latency_phase(args: argparse.Namespace, inst: Instance, driver: Any, server: TimeServer, report: Report,
                  rng: random.Random, baselines: dict[str, float] | None, connected_ns: int) -> None:
    import zmq

    from eca.protocol.client import AgentClient

    details: dict[str, Any] = {}
    report.details["latency"] = details
    if driver.execute_script("return Boolean(window.ecaBench && window.ecaBench.frames.face)") is not True:
        driver.execute_script(PAGE_JS, list(MOUTH_BOX), list(SIGNATURE_SIZE), [ONSET_LEVEL, ONSET_QUIET_S],
                              list(PATCH_BOX))
        driver.execute_script("window.ecaBench.watch('face', window.eca.faces[arguments[0]], 'face')", AGENT)
    driver.execute_script("window.ecaBench.signature = true")
    settled_ns = connected_ns + int(args.settle_s * 1e9)
    if time.monotonic_ns() < settled_ns:  # the browser's A/V sync, which holds the video, settles first
        progress(f"latency: the page's connection settles for {(settled_ns - time.monotonic_ns()) / 1e9:.0f} s")
        wait_until_ns(settled_ns)
    frames: list[dict[str, Any]] = []
    commands: list[tuple[int, str]] = []
    ctx = zmq.Context()
    emotions = EmotionStates(ctx, inst.config)
    states, listen = emotions.seen, emotions.listen

    try:
        with AgentClient(inst.config, agent=AGENT, source="bench-web-latency", ctx=ctx) as client:
            progress(f"latency: {args.trials} set_emotion commands ({' / '.join(EMOTIONS)}, transition 0)")
            ties = [tie_clocks(driver, server)]
            before = video_stats(driver)
            client.set_emotion(EMOTIONS[1], 1.0, transition_s=0.0)
            wait_until_ns(time.monotonic_ns() + 1_000_000_000, listen)
            driver.execute_script(TAKE_JS)  # what came before the first command
            for i in range(args.trials):
                name = EMOTIONS[i % 2]
                sent = client.set_emotion(name, 1.0, transition_s=0.0)
                commands.append((sent.t_ns, name))
                wait_until_ns(sent.t_ns + int(rng.uniform(*PAUSE_S) * 1e9), listen)
                if i % 8 == 7:
                    frames += driver.execute_script(TAKE_JS)["frames"].get("face", [])
            frames += driver.execute_script(TAKE_JS)["frames"].get("face", [])
            after = video_stats(driver)
            ties.append(tie_clocks(driver, server))
            listen(0.0)
    finally:
        emotions.close()
        ctx.term()
    driver.execute_script("window.ecaBench.signature = false")
    tie, drift = combined_tie(ties)
    details.update(clock_offset_ms=tie.offset_ms, clock_uncertainty_ms=tie.uncertainty_ms, clock_drift_ms=drift,
                   stats_before=before, stats_after=after)
    trials = analyse_trials(commands, states, [f for f in frames if "sig" in f], tie)
    details["trials"] = trials
    measured = [t for t in trials if "total_ms" in t]
    totals = [t["total_ms"] for t in measured]
    if not totals:
        report.add("command -> frame shown", "none seen", f"p95 <= {TARGET_LATENCY_P95_MS:g}", False, "ms",
                   f"{len(trials)} commands; {len(frames)} frames")
        return
    s = spread(totals)
    report.add("command -> frame shown, p50", s["median"], "-", None, "ms",
               f"n {s['n']} of {len(trials)}; to the frame's expectedDisplayTime")
    report.add("command -> frame shown, p95", s["p95"], f"<= {TARGET_LATENCY_P95_MS:g}",
               bool(s["p95"] <= TARGET_LATENCY_P95_MS), "ms", f"max {max(totals):.1f}")
    parts = {k: spread([t[k] for t in measured if k in t]) for k in
             ("bus_ms", "state_to_received_ms", "received_to_presented_ms", "presented_to_displayed_ms")}
    details["parts"] = parts
    # estimated splits of the measured parts
    jitter = _per(after, before, "jitterBufferDelay", "jitterBufferEmittedCount")
    decode = _per(after, before, "totalDecodeTime", "framesDecoded")
    audio_jitter = _per(after.get("audio", {}), before.get("audio", {}), "jitterBufferDelay",
                        "jitterBufferEmittedCount")
    rtt = after.get("rttS")
    estimates: dict[str, float] = {}
    if baselines:
        estimates.update(draw_ms=baselines["draw_ms"], encode_ms=baselines["encode_ms"])
    if rtt is not None:
        estimates["network_ms"] = 1e3 * rtt / 2
    s2r = parts["state_to_received_ms"].get("median")
    if s2r is not None and {"draw_ms", "encode_ms", "network_ms"} <= estimates.keys():
        estimates["slot_wait_ms"] = s2r - estimates["draw_ms"] - estimates["encode_ms"] - estimates["network_ms"]
    if jitter is not None:
        estimates["jitter_buffer_ms"] = 1e3 * jitter
    if decode is not None:
        estimates["decode_ms"] = 1e3 * decode
    if audio_jitter is not None:
        estimates["audio_jitter_buffer_ms"] = 1e3 * audio_jitter
    details["estimates"] = estimates
    details["frames_decoded_in_phase"] = _delta(after, before, "framesDecoded")
    rows: list[tuple[str, str, list[tuple[str, str, str]]]] = [
        ("bus_ms", "bus: command -> state published", []),
        ("state_to_received_ms", "state -> frame received", [
            ("slot_wait_ms", "wait for the frame slot", "the part less the three below"),
            ("draw_ms", "draw", "the face drawn in the bench, same renderer and size"),
            ("encode_ms", "VP8 encode", "the service's encoder, in the bench"),
            ("network_ms", "network", "ICE round trip / 2, getStats")]),
        ("received_to_presented_ms", "received -> presented", [
            ("jitter_buffer_ms", "jitter buffer", "getStats mean per frame: held to play with the audio"),
            ("decode_ms", "decode", "getStats mean per frame"),
            ("audio_jitter_buffer_ms", "(audio jitter buffer)", "getStats mean per sample: what the video waits "
             f"on; interarrival jitter {1e3 * (after.get('audio', {}).get('jitter') or 0):.1f} ms")]),
        ("presented_to_displayed_ms", "presented -> displayed", []),
    ]
    for key, label, children in rows:
        p = parts[key]
        if p.get("n"):
            report.add(f"  {label}", p["median"], "-", None, "ms", f"measured, median; p95 {p['p95']}")
        for child, child_label, note in children:
            if child in estimates:
                report.add(f"    {child_label}", round(estimates[child], 2), "-", None, "ms", f"estimated: {note}")
    report.add("latency clock tie", round(tie.uncertainty_ms, 2), "-", None, "ms",
               f"+- (GET round trips; drift {drift:.2f} ms); codec {after.get('codec')}, "
               f"decoder {after.get('decoderImplementation')}")


def _delta(after: dict[str, Any], before: dict[str, Any], key: str) -> float | None:
    a, b = after.get(key), before.get(key)
    return None if a is None or b is None else float(a) - float(b)


def _per(after: dict[str, Any], before: dict[str, Any], total: str, count: str) -> float | None:
    t, n = _delta(after, before, total), _delta(after, before, count)
    return None if t is None or not n else t / n


def analyse_trials(commands: list[tuple[int, str]], states: list[tuple[int, str]], frames: list[dict[str, Any]],
                   tie: ClockTie, old_ms: float = 150.0, new_ms: float = 200.0) -> list[dict[str, Any]]:
    """Per command: the first frame shown after it that is nearer the new expression than the old (the old:
    the frames shown in the `old_ms` before the command; the new: those in the `new_ms` before the next)."""
    frames = sorted(frames, key=lambda f: f["e"])
    shown = np.array([tie.host_ms(f["e"]) for f in frames])
    sigs = np.array([f["sig"] for f in frames], dtype=float) if frames else np.zeros((0, 1))
    out = []
    for i, (sent_ns, name) in enumerate(commands):
        sent_ms = sent_ns / 1e6
        end_ms = commands[i + 1][0] / 1e6 if i + 1 < len(commands) else sent_ms + 1e3 * PAUSE_S[0]
        trial: dict[str, Any] = {"emotion": name, "sent_ms": sent_ms}
        out.append(trial)
        old = sigs[(shown >= sent_ms - old_ms) & (shown < sent_ms)]
        new = sigs[(shown >= end_ms - new_ms) & (shown < end_ms)]
        if not len(old) or not len(new):
            trial["skipped"] = "no frames before the command or before the next"
            continue
        old_mean, new_mean = old.mean(axis=0), new.mean(axis=0)
        apart = float(np.abs(old_mean - new_mean).mean())
        if apart < 2.0:  # mean grey-level change per thumbnail pixel: the expression did not change
            trial["skipped"] = f"the face did not change ({apart:.2f})"
            continue
        after = np.nonzero((shown > sent_ms) & (shown < end_ms))[0]
        hit = next((k for k in after if np.abs(sigs[k] - new_mean).mean() < np.abs(sigs[k] - old_mean).mean()), None)
        if hit is None:
            trial["skipped"] = "no frame showed it"
            continue
        f = frames[hit]
        trial["total_ms"] = shown[hit] - sent_ms
        state = next((t for t, n in states if n == name and t >= sent_ns), None)
        if state is not None:
            trial["bus_ms"] = (state - sent_ns) / 1e6
            if f.get("r") is not None:
                trial["state_to_received_ms"] = tie.host_ms(f["r"]) - state / 1e6
        if f.get("r") is not None:
            trial["received_to_presented_ms"] = f["p"] - f["r"]
        trial["presented_to_displayed_ms"] = f["e"] - f["p"]
        if f.get("next") is not None:  # a frame the page drew itself: the next animation frame
            trial["drawn_to_next_frame_ms"] = f["next"] - f["e"]
    return out


# --- 3. cost per viewer ----------------------------------------------------------------------------


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


@contextmanager
def load_process(url: str, drawn: bool = False) -> Iterator[tuple[subprocess.Popen[bytes], Any]]:
    """The helper process holding the aiortc viewers (`drawn`: viewers that draw the face themselves); killed
    (its group) afterwards."""
    from eca.services.tools.child_processes import LineReader

    argv = [sys.executable, str(Path(__file__).resolve()), "--role", "load", "--url", url,
            *(("--drawn",) if drawn else ())]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stdin=subprocess.PIPE, env=subprocess_env(), cwd=REPO,
                            start_new_session=True)
    try:
        yield proc, LineReader(proc.stdout)
    finally:
        try:
            assert proc.stdin is not None
            proc.stdin.close()  # it closes its connections and exits
            proc.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            pass
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=5)


def ask(proc: subprocess.Popen[bytes], reader: Any, line: str, timeout_s: float) -> dict[str, Any]:
    """Send a command line to the load process; its JSON answer."""
    assert proc.stdin is not None
    start = len(reader.lines)
    proc.stdin.write((line + "\n").encode())
    proc.stdin.flush()
    index = reader.wait_for("{", timeout_s, start)
    return json.loads(reader.lines[index])


def measure_window(pid: int, driver: Any | None, load: tuple[Any, Any] | None, seconds: float) -> dict[str, Any]:
    """The web service's CPU share and RSS over `seconds`; the page's and the aiortc viewers' frame rates."""
    page0 = video_stats(driver) if driver is not None else {}
    load0 = ask(*load, "stats", 10.0) if load is not None else {}
    t0, c0 = time.monotonic(), cpu_seconds(pid)
    time.sleep(seconds)  # the measuring window
    t1, c1 = time.monotonic(), cpu_seconds(pid)
    out: dict[str, Any] = {"cpu_pct": 100.0 * (c1 - c0) / (t1 - t0), "rss_mib": rss_mib(pid)}
    if driver is not None:
        page1 = video_stats(driver)
        frames = _delta(page1, page0, "framesDecoded")
        span_s = (page1.get("at", 0) - page0.get("at", 0)) / 1e3
        if frames is not None and span_s > 0:
            out["page_fps"] = frames / span_s
        out["page_fps_browser"] = page1.get("framesPerSecond")
        out["page_dropped"] = _delta(page1, page0, "framesDropped")
    if load is not None:
        load1 = ask(*load, "stats", 10.0)
        if load1.get("clients"):
            out["load_fps_each"] = (load1["frames"] - load0["frames"]) / (
                load1["t"] - load0["t"]) / load1["clients"]
        out["load_cpu_pct"] = 100.0 * (load1["cpu_s"] - load0["cpu_s"]) / (load1["t"] - load0["t"])
    return out


def wait_watching(inst: Instance, count: int, timeout_s: float, since: int) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if inst.viewers_watching(since) == count:
            return True
        time.sleep(0.1)  # polling the service's output for its line
    return False


def disconnect_page(driver: Any) -> None:
    """The page's connections closed (the bench's measuring paused): it watches nothing."""
    driver.execute_script(CLOSE_CALIBRATION_JS)
    driver.execute_script("""
      if (window.ecaBench) window.ecaBench.paused = true;
      if (window.eca && window.eca.pc) document.getElementById("connect").click();""")


def least_squares_slope(xs: list[float], ys: list[float]) -> float | None:
    if len(set(xs)) < 2:
        return None
    return float(np.polyfit(np.asarray(xs, float), np.asarray(ys, float), 1)[0])


def viewers_phase(args: argparse.Namespace, inst: Instance, driver: Any, report: Report,
                  baselines: dict[str, float] | None) -> None:
    details: dict[str, Any] = {"levels": []}
    report.details["viewers"] = details
    pid = inst.web_pid
    mark = len(inst.reader.lines)
    disconnect_page(driver)
    if not wait_watching(inst, 0, 20.0, mark):
        raise RuntimeError("the page's viewers did not leave")
    progress(f"viewers: 0 (baseline), then {', '.join(map(str, args.viewers))}; "
             f"{VIEWER_WINDOW_S:g} s windows after {VIEWER_SETTLE_S:g} s")
    time.sleep(VIEWER_SETTLE_S)  # the service lets go of its drawing
    zero = measure_window(pid, None, None, VIEWER_WINDOW_S)
    details["zero"] = zero
    levels: list[tuple[int, dict[str, Any]]] = []
    with load_process(inst.url) as load:
        ask(*load, "hello", 30.0)
        page_connected = False
        for n in args.viewers:
            if not page_connected:
                connect_page(driver)
                page_connected = True
            got = ask(*load, f"set {n - 1}", 60.0)
            if got.get("connected") != n - 1:
                raise RuntimeError(f"the aiortc viewers did not all connect: {got}")
            time.sleep(VIEWER_SETTLE_S)  # the new viewers' first frames and keyframes pass
            m = measure_window(pid, driver, load, VIEWER_WINDOW_S)
            levels.append((n, m))
            details["levels"].append({"viewers": n, **m})
            progress(f"  {n} viewer(s): web CPU {m['cpu_pct']:.0f} % of a core, RSS {m['rss_mib']:.0f} MiB, "
                     f"page {m.get('page_fps', float('nan')):.1f} fps")
        mark = len(inst.reader.lines)
        ask(*load, "set 0", 30.0)
    disconnect_page(driver)
    left = wait_watching(inst, 0, 20.0, mark)
    time.sleep(AFTER_LEAVING_S)  # what the service lets go of when the last viewer leaves
    after = measure_window(pid, None, None, VIEWER_WINDOW_S)
    details["after"] = after
    details["all_left"] = left

    report.add("viewers: web CPU with 0 viewers", round(zero["cpu_pct"], 1), "-", None, "% core",
               f"RSS {zero['rss_mib']:.0f} MiB")
    for n, m in levels:
        note = f"RSS {m['rss_mib']:.0f} MiB; page {m.get('page_fps', float('nan')):.1f} fps"
        if "load_fps_each" in m:
            note += f"; aiortc viewers {m['load_fps_each']:.1f} fps each (their process {m['load_cpu_pct']:.0f} %)"
        report.add(f"viewers: web CPU with {n}", round(m["cpu_pct"], 1), "-", None, "% core", note)
    xs = [float(n) for n, _ in levels]
    slope = least_squares_slope(xs, [m["cpu_pct"] for _, m in levels])
    if slope is not None:
        report.add("viewers: CPU per additional viewer", round(slope, 1), f"<= {TARGET_CPU_PER_VIEWER:g}",
                   slope <= TARGET_CPU_PER_VIEWER, "% core", f"least squares over {', '.join(map(str, args.viewers))}")
    if levels:
        first = levels[0][1]["cpu_pct"] - zero["cpu_pct"]
        note = "the face drawn for the first viewer (plus its encode)"
        if baselines:
            note += (f"; bench: draw {baselines['draw_ms']:.1f} ms/frame = {baselines['draw_ms'] * FPS / 10:.0f} % "
                     f"at {FPS:g} fps, encode {baselines['encode_ms']:.1f} ms = "
                     f"{baselines['encode_ms'] * FPS / 10:.0f} %")
        report.add(f"viewers: CPU 0 -> {levels[0][0]}", round(first, 1), "-", None, "% core", note)
        n_max, m_max = levels[-1]
        fps = m_max.get("page_fps")
        report.add(f"viewers: page frame rate with {n_max}", "none" if fps is None else round(fps, 1),
                   f">= {TARGET_FPS_MIN:g}", fps is not None and fps >= TARGET_FPS_MIN, "fps",
                   f"getStats framesDecoded; the browser's own figure {m_max.get('page_fps_browser')}")
    rss_slope = least_squares_slope(xs, [m["rss_mib"] for _, m in levels])
    if rss_slope is not None:
        report.add("viewers: RSS per additional viewer", round(rss_slope, 1), "-", None, "MiB")
    back = abs(after["rss_mib"] - zero["rss_mib"]) / zero["rss_mib"]
    report.add("viewers: RSS after all left vs 0 viewers", round(after["rss_mib"] - zero["rss_mib"], 1),
               f"+-{100 * TARGET_RSS_RETURN:g} %", back <= TARGET_RSS_RETURN and left, "MiB",
               f"{after['rss_mib']:.0f} vs {zero['rss_mib']:.0f} MiB ({100 * back:.1f} %); CPU after "
               f"{after['cpu_pct']:.1f} %" + ("" if left else "; the viewers did not all leave"))


# --- 4. the face drawn in the browser ----------------------------------------------------------------


@dataclass
class Talk:
    """One say of the talk."""

    rid: str
    planned_ns: int  # its first sample at the output, as planned (master clock)
    samples: int  # at SAY_RATE_HZ
    onsets: list[float]  # its bursts, s after its first sample
    started_ns: int | None = None  # its first sample at the output, as the audio service reported it


class Talker:
    """Keeps the agent talking until `until_ns`: a lead-in of the hum alone, then says of SAY_PART_S of vowel
    bursts over the hum (vowel_bursts), each sent when the talk already queued ends within QUEUE_AHEAD_S and
    planned to start where the one before ends (the player plays a queue without gaps), so that its bursts fall
    between the markers' clicks. (A silent probe of a say's latency, as the A/V phase of the 2D face takes, was
    seen 670 ms short for a say of bursts on a loaded machine: the bursts fell on the clicks.)"""

    def __init__(self, client: Any, rng: random.Random, first_sample_ns: int, until_ns: int,
                 hum: float = HUM_LEVEL) -> None:
        self.client, self.rng, self.until_ns, self.hum = client, rng, until_ns, hum
        self.talks: list[Talk] = []
        self.next_ns = first_sample_ns  # where the queued talk ends

    def send_next(self, lead_in: bool = False) -> Talk:
        """The next say, planned to start where the talk queued ends; `lead_in`: LEAD_IN_S of the hum alone."""
        from eca.protocol.messages import Say

        onsets: list[float] = []
        if lead_in:  # planned: sent now (its start less that is the say's latency)
            self.next_ns = time.monotonic_ns()
            t = np.arange(round(LEAD_IN_S * SAY_RATE_HZ)) / SAY_RATE_HZ
            pcm = (self.hum * 32767 * np.sin(2 * np.pi * HUM_HZ * t)).astype("<i2").tobytes()
        else:
            seconds = min(SAY_PART_S, (self.until_ns - self.next_ns) / 1e9 + 1.0)
            pcm, onsets = vowel_bursts(self.rng, seconds, self.next_ns, self.hum)
        talk = Talk(f"bench-web-talk-{len(self.talks)}", self.next_ns, len(pcm) // 2, onsets)
        self.client.send(Say(agent=AGENT, request_id=talk.rid, pcm=pcm, sample_rate=SAY_RATE_HZ,
                             text="vowel bursts"))
        self.talks.append(talk)
        self.next_ns += talk.samples * 1_000_000_000 // SAY_RATE_HZ
        return talk

    def started(self, rid: str, dac_ns: int) -> None:
        """A say's first sample reached the output: the ones queued after it start where it ends."""
        for i, talk in enumerate(self.talks):
            if talk.rid == rid:
                talk.started_ns = dac_ns
                self.next_ns = dac_ns + sum(t.samples for t in self.talks[i:]) * 1_000_000_000 // SAY_RATE_HZ

    def step(self) -> None:
        if self.next_ns < self.until_ns and self.next_ns - time.monotonic_ns() < QUEUE_AHEAD_S * 1e9:
            self.send_next()

    def bursts_ms(self) -> list[float]:
        """Each burst's onset at the output (master clock, ms)."""
        return [((t.started_ns or t.planned_ns) + 1e9 * o) / 1e6 for t in self.talks for o in t.onsets]

    def gaps_ms(self) -> list[float]:
        """Each say's first sample at the output less the end of the one before (0: no gap)."""
        return [(b.started_ns - a.started_ns) / 1e6 - 1e3 * a.samples / SAY_RATE_HZ
                for a, b in zip(self.talks, self.talks[1:], strict=False) if a.started_ns and b.started_ns]


class Taken:
    """What the page measured (TAKE_JS, emptied there at each take), kept here."""

    def __init__(self) -> None:
        self.frames: dict[str, list[dict[str, Any]]] = {}
        self.onsets: dict[str, list[float]] = {}
        self.logs: dict[str, dict[str, list[dict[str, Any]]]] = {}  # a drawn face's log: newest, heard, marks
        self.stats: dict[str, list[dict[str, Any]]] = {}  # a drawn face's stats at each take
        self.sync: dict[str, list[tuple[float, float]]] = {}

    def take(self, driver: Any, sync: bool = False, newest: bool = False) -> None:
        got = driver.execute_script(TAKE_JS)
        for name, frames in got["frames"].items():
            self.frames.setdefault(name, []).extend(frames)
        for name, onsets in got["onsets"].items():
            self.onsets.setdefault(name, []).extend(onsets)
        for name, d in got["drawn"].items():
            log = self.logs.setdefault(name, {"newest": [], "heard": [], "marks": [], "passed": []})
            for part in ("heard", "marks", "passed", "newest") if newest else ("heard", "marks", "passed"):
                log[part].extend(d[part])
            self.stats.setdefault(name, []).append({"at": got["now"], "ticks": d["ticks"], "messages": d["messages"],
                                                    "unplaced": d["unplaced"], **d["stats"]})
        if sync:
            for name, polled in driver.execute_async_script(SYNC_JS).items():
                if polled is not None:
                    self.sync.setdefault(name, []).append((polled["at"], polled["offset"]))


def open_drawn_page(driver: Any, url: str) -> None:
    """The product page, not connected (the bench makes its own connections), with the bench's measuring."""
    driver.get(f"{url}?mic=0&width={WIDTH}&height={HEIGHT}&fps={FPS:g}")
    driver.execute_script(PAGE_JS, list(MOUTH_BOX), list(SIGNATURE_SIZE), [ONSET_LEVEL, ONSET_QUIET_S],
                          list(PATCH_BOX))


def connect_drawn(driver: Any, calibration: bool, draw: bool = True) -> dict[str, Any]:
    """The page's connection that draws the face itself (DRAWN_JS); what the answer described. Without `draw`
    the face's present() runs at every animation frame, but draws nothing."""
    got = driver.execute_async_script(DRAWN_JS, DRAWN, AGENT, WIDTH, HEIGHT, FPS, calibration, draw)
    if not isinstance(got, dict):
        raise RuntimeError(f"the page could not draw the face itself: {got}")
    return got


def drawn_mouth_openings(onsets: list[float], heard: list[dict[str, Any]]) -> list[tuple[float, float]]:
    """For each burst heard (page ms): (its time, onset - when the face drawn in the page first showed the jaw
    half way from its level before the burst to its peak in it), from the heard frames shown; + = audio late."""
    shown = [(h["shownMs"], h["jaw"]) for h in heard if h.get("jaw") is not None]
    if not shown:
        return []
    shown.sort()
    t = np.array([s for s, _ in shown])
    jaw = np.array([j for _, j in shown])
    out = []
    for onset in onsets:
        before = jaw[(t >= onset - 250) & (t < onset - 100)]
        during = (t >= onset - 100) & (t < onset + 1e3 * BURST_S + 100)
        if not len(before) or not during.any():
            continue
        base, peak = float(np.median(before)), float(jaw[during].max())
        if peak - base < 0.1:
            continue
        first = next(i for i in np.nonzero(during)[0] if jaw[i] >= base + (peak - base) / 2)
        out.append((onset, onset - float(t[first])))
    return out


def mark_pairs(clicks: list[float], marks: list[dict[str, Any]]) -> list[tuple[float, dict[str, Any]]]:
    """Each click heard (page ms) with the mark shown nearest to it, within PAIR_WINDOW_MS."""
    out = []
    for click in clicks:
        mark = min(marks, key=lambda m: abs(click - m["shownMs"]), default=None)
        if mark is not None and abs(click - mark["shownMs"]) <= PAIR_WINDOW_MS:
            out.append((click, mark))
    return out


def per_second_differences(pairs: list[tuple[float, float]], reference: list[tuple[float, float]]) -> list[float]:
    """Each (time, offset) less the reference's of the same second (the nearest within 500 ms)."""
    out = []
    for t, o in pairs:
        ref_t, ref_o = min(reference, key=lambda r: abs(r[0] - t), default=(math.inf, 0.0))
        if abs(ref_t - t) <= 500:
            out.append(o - ref_o)
    return out


@dataclass(frozen=True)
class Window:
    label: str
    lo_s: float  # since the drawing connection connected
    hi_s: float
    reference: bool  # the markers' connection open (the service draws the head as video for it)


def drawn_windows(args: argparse.Namespace) -> list[Window]:
    """The browser-drawn A/V phase's windows: the face alone (the service draws no video), then beside the markers'
    connection after it has settled (the first minute), and with --long-s after that long."""
    alone = Window("alone", DRAWN_ALONE_SETTLE_S, DRAWN_ALONE_SETTLE_S + args.measure_s, False)
    first = alone.hi_s + args.settle_s
    out = [alone, Window("beside the markers", first, first + args.measure_s, True)]
    if args.long_s:
        out.append(Window(f"after {args.long_s / 60:g} min", args.long_s, args.long_s + args.measure_s, True))
    return out


def drawn_av_phase(args: argparse.Namespace, inst: Instance, driver: Any, server: TimeServer, report: Report,
                   rng: random.Random) -> None:
    import zmq

    from eca.protocol.bus import Subscriber
    from eca.protocol.client import AgentClient
    from eca.protocol.messages import SpeechStarted
    from tests.support.browser import wait_for

    details: dict[str, Any] = {}
    report.details["drawn_av"] = details
    details["face"] = connect_drawn(driver, calibration=True, draw=not args.no_webgl_draw)
    wait_for(driver, DRAWN_READY_JS, CONNECT_TIMEOUT_S, "the face drawn in the page", bool)
    details["audio_context"] = driver.execute_async_script(START_DRAWN_MEASURING_JS)
    connected_ns = time.monotonic_ns()
    windows = drawn_windows(args)
    reference_from_s = windows[0].hi_s  # the markers' connection, once the face alone is measured
    end_ns = connected_ns + int(windows[-1].hi_s * 1e9)
    taken = Taken()
    ctx = zmq.Context()
    events = Subscriber(ctx, inst.config, [f"event.{AGENT}.speech_started"])
    talker: Talker | None = None
    ties: list[ClockTie] = []

    def note_started(timeout_s: float = 0.0) -> None:
        got = events.recv(timeout_s) if timeout_s else None
        for received in ([got] if got is not None else []) + events.drain():
            msg = received.message
            if isinstance(msg, SpeechStarted) and talker is not None:
                talker.started(msg.request_id, msg.dac_time_ns)

    def pull_while_waiting(left_s: float) -> None:
        taken.take(driver, sync=True)
        note_started()
        if talker is not None:
            talker.step()
        time.sleep(min(left_s, 1.0))  # pacing; the page keeps measuring meanwhile

    try:
        events.wait_ready()
        with AgentClient(inst.config, agent=AGENT, source="bench-web-drawn", ctx=ctx) as client:
            talker = Talker(client, rng, time.monotonic_ns(), end_ns, args.hum_level)
            progress(f"browser-drawn A/V: the agent talks until {(end_ns - connected_ns) / 1e9:.0f} s after "
                     f"connecting; measuring {', '.join(f'{w.label} ({w.lo_s:g}-{w.hi_s:g} s)' for w in windows)}; "
                     f"the markers' connection from {reference_from_s:g} s")
            ties.append(tie_clocks(driver, server))
            lead = talker.send_next(lead_in=True)
            deadline = time.monotonic() + 10.0
            while lead.started_ns is None and time.monotonic() < deadline:
                note_started(0.5)
            if lead.started_ns is None:
                raise RuntimeError("the talk did not start within 10 s")
            talker.send_next()  # its bursts placed from where the lead-in ends
            reference_open = False
            for w in windows:
                if w.reference and not reference_open:
                    wait_until_ns(connected_ns + int(reference_from_s * 1e9), pull_while_waiting)
                    answer = driver.execute_async_script(CALIBRATION_JS, MARKED, AGENT, WIDTH, HEIGHT, FPS)
                    if answer != "ok":
                        raise RuntimeError(f"the {MARKED} connection did not connect: {answer}")
                    wait_for(driver, DRAWN_READY_JS, CONNECT_TIMEOUT_S, "the markers' streams", bool)
                    driver.execute_async_script(START_DRAWN_MEASURING_JS)
                    reference_open = True
                # fresh taps for each window (see av_phase)
                wait_until_ns(connected_ns + int((w.lo_s - 0.5) * 1e9), pull_while_waiting)
                restarted = driver.execute_async_script(RESTART_AUDIO_JS)
                if restarted is not True:
                    raise RuntimeError(f"the page's audio taps could not be made afresh: {restarted}")
                wait_until_ns(connected_ns + int(w.hi_s * 1e9), pull_while_waiting)
                ties.append(tie_clocks(driver, server))
            pull_while_waiting(0.0)
    finally:
        events.close()
        ctx.term()
    driver.execute_script(CLOSE_CALIBRATION_JS + CLOSE_DRAWN_JS)
    assert talker is not None
    tie, drift = combined_tie(ties)
    bursts = talker.bursts_ms()
    gaps = talker.gaps_ms()
    details.update(clock_offset_ms=tie.offset_ms, clock_uncertainty_ms=tie.uncertainty_ms, clock_drift_ms=drift,
                   says=len(talker.talks), say_gaps_ms=spread(gaps),
                   says_started_less_planned_ms=[None if t.started_ns is None else (t.started_ns - t.planned_ns) / 1e6
                                                 for t in talker.talks],
                   burst_phase_after_second_ms=spread([b % 1e3 for b in bursts]),
                   # each onset heard, ms after the whole second before it: the clicks' phase and the bursts'
                   onsets_after_second_ms={name: [round(since_second(tie, t), 1) for t in onsets]
                                           for name, onsets in taken.onsets.items()},
                   browser_estimate=taken.sync)
    connected_ms = connected_ns / 1e6
    # the marks: when the heard frame reached or passed each marked frame (DRAWN_JS `passed`)
    heard, marks, logged = (taken.logs.get(DRAWN, {}).get(k, []) for k in ("heard", "passed", "marks"))
    voice_d, clicks_d = split_onsets(taken.onsets.get(DRAWN, []), tie, bursts)
    voice_r, clicks_r = split_onsets(taken.onsets.get(MARKED, []), tie, bursts)
    paired = mark_pairs(clicks_d, marks)
    series = {  # name: pairs of (heard, offset), page ms, all the phase; + = audio late
        "browser-drawn": [(t, t - m["shownMs"]) for t, m in paired],
        "reference": pair_offsets(clicks_r, flashes(taken.frames.get(MARKED, []))),
        # the mark against the next animation frame (by then the frame drawn has reached the screen)
        "browser-drawn, next frame": [(t, t - m["nextMs"]) for t, m in paired if m.get("nextMs") is not None],
        # the voiced marks only (drawn when the voice clock reached them, not as they arrived)
        "browser-drawn, voiced marks": [(t, t - m["shownMs"]) for t, m in paired if (m.get("flags") or 0) & 1],
        # against the voice clock: where the click played by what the page's voice clock said when it drew the
        # (voiced) mark (its time then, less the mark's): the wait for the animation frame taken out
        "browser-drawn, voice clock": [(t, t - m["shownMs"] + m["syncedMs"] - m["timeMs"]) for t, m in paired
                                       if m.get("syncedMs") is not None and (m.get("flags") or 0) & 1],
        "browser-drawn mouth": drawn_mouth_openings(voice_d, heard),
    }
    total_s = windows[-1].hi_s
    step_s = TRAJECTORY_WINDOW_S if total_s <= 120 else 60.0
    details["trajectory_ms"] = {
        name: [w for w in by_window(pairs, tie, connected_ms, total_s, step_s) if w["n"]]
        for name, pairs in series.items()}
    details["windows"] = {}
    for win in windows:
        lo, hi = win.lo_s, win.hi_s
        label = f"{win.label} ({lo:g}-{hi:g} s)"
        lo_ms, hi_ms = connected_ms + 1e3 * lo, connected_ms + 1e3 * hi

        def in_window(t_page: float, lo_ms: float = lo_ms, hi_ms: float = hi_ms) -> bool:
            return lo_ms <= tie.host_ms(t_page) < hi_ms

        timed = {name: [(t, o) for t, o in pairs if in_window(t)] for name, pairs in series.items()}
        each = per_second_differences(timed["browser-drawn"], timed["reference"])
        window_marks = [m for m in marks if in_window(m["shownMs"])]
        seconds = len(range(math.ceil(lo_ms / 1e3), math.ceil(hi_ms / 1e3)))  # whole seconds: marks due
        voiced = sum(1 for m in window_marks if (m.get("flags") or 0) & 1)
        drawn_marks = sum(1 for m in window_marks if m.get("drawn"))
        talking = [h for h in heard if in_window(h["shownMs"]) and h.get("flags") is not None]
        voiced_share = sum(1 for h in talking if h["flags"] & 1) / len(talking) if talking else None
        late = [m["syncedMs"] - m["timeMs"] for m in window_marks if m.get("syncedMs") is not None
                and (m.get("flags") or 0) & 1]
        w = details["windows"][label] = {
            "from_s": lo, "to_s": hi, "markers_connection": win.reference,
            **{name: spread([o for _, o in pairs]) for name, pairs in timed.items()},
            "browser-drawn less reference": spread(each),
            "marks": {"shown": len(window_marks), "seconds": seconds, "voiced": voiced, "drawn_themselves": drawn_marks,
                      "in_face3d_log": sum(1 for m in logged if in_window(m["shownMs"])),
                      "voice_past_mark_ms": spread(late)},
            "heard_frames_voiced_share": voiced_share,
            "onsets": {"browser-drawn clicks": sum(map(in_window, clicks_d)),
                       "browser-drawn bursts": sum(map(in_window, voice_d)),
                       "reference clicks": sum(map(in_window, clicks_r)),
                       "reference bursts": sum(map(in_window, voice_r))},
            "paths_ms": {path: spread([since_second(tie, t) for t in times if in_window(t)]) for path, times in (
                ("browser-drawn: click at source -> heard", clicks_d),
                ("browser-drawn: mark at source -> shown", [m["shownMs"] for m in marks]),
                ("reference: click at source -> heard", clicks_r),
                ("reference: flash at source -> shown", flashes(taken.frames.get(MARKED, []))))},
            "offsets_ms": {name: [round(o, 2) for _, o in pairs] for name, pairs in timed.items()},
        }
        d = w["browser-drawn"]
        if not d.get("n"):
            report.add(f"A/V browser-drawn face, {label}", "none measured", "pairs > 0", False, "",
                       f"clicks heard {w['onsets']['browser-drawn clicks']}, marks shown {len(window_marks)}")
            continue
        median = d["median"]
        report.add(f"A/V browser-drawn face (click - mark), {label}", median,
                   f"-{ATSC_EARLY_MS:g}..+{ATSC_LATE_MS:g}", -ATSC_EARLY_MS <= median <= ATSC_LATE_MS, "ms",
                   f"ATSC IS-191; + = audio late; p10 {d['p10']}, p90 {d['p90']}, n {d['n']}; marks reached "
                   f"{len(window_marks)} of {seconds} s ({drawn_marks} drawn themselves, {voiced} voiced)")
        ref = w["reference"]
        if each:
            diff = statistics.median(each)
            report.add(f"A/V browser-drawn - reference, {label}", round(diff, 1), f"+-{TARGET_AV_DIFF_MS:g}",
                       abs(diff) <= TARGET_AV_DIFF_MS, "ms",
                       f"each second's click - mark less the markers' click - flash of that second (median of "
                       f"{len(each)}; p10 {percentile(each, 0.1):.1f}, p90 {percentile(each, 0.9):.1f})")
        if ref.get("n"):
            server_ref = report.details.get("av", {}).get("reference", {}).get("offsets", {}).get("median")
            report.add(f"A/V reference (server-drawn markers), {label}", ref["median"], "-", None, "ms",
                       f"this page, the head drawn by the server with the flashing patch, {WIDTH}x{HEIGHT}; "
                       f"p10 {ref['p10']}, p90 {ref['p90']}, n {ref['n']}"
                       + ("" if server_ref is None else f"; the 2D face's run above: {server_ref}"))
        for name, note in (("browser-drawn, voiced marks", "the marks flagged voiced only: drawn when the page's "
                             "voice clock reached them (the others as they arrived)"),
                           ("browser-drawn, next frame", "the click less the next animation frame after the one that "
                            "drew the mark (by then it is on the screen)"),
                           ("browser-drawn, voice clock", "voiced marks: the click less when the page's voice clock "
                            "said the mark's time played (at the drawing, less how far past the mark it was): the "
                            "wait for the animation frame taken out")):
            v = w[name]
            if v.get("n"):
                report.add(f"  {name}, {label}", v["median"], "-", None, "ms",
                           f"{note}; p10 {v['p10']}, p90 {v['p90']}, n {v['n']}")
        mouth = w["browser-drawn mouth"]
        if mouth.get("n"):
            report.add(f"A/V browser-drawn mouth (burst - jaw half open), {label}", mouth["median"], "-", None, "ms",
                       f"the voiced weights of the heard frames shown; lip-sync included; p10 {mouth['p10']}, "
                       f"p90 {mouth['p90']}, n {mouth['n']}")
        if voiced_share is not None:
            report.add(f"  heard frames voiced, {label}", round(100 * voiced_share, 1), "-", None, "%",
                       "the agent talks throughout (the quiet tone): a frame not voiced is drawn as it arrives")
        past = w["marks"]["voice_past_mark_ms"]
        if past.get("n"):
            report.add(f"  voice past the mark when drawn, {label}", past["median"], "-", None, "ms",
                       f"voiced marks: the voice clock's time at the drawing that reached the mark, less the mark's "
                       f"time: the wait for the animation frame; p90 {past['p90']}")
        paths = w["paths_ms"]
        for who, heard_path, shown_path in (
                ("browser-drawn", "browser-drawn: click at source -> heard", "browser-drawn: mark at source -> shown"),
                ("reference", "reference: click at source -> heard", "reference: flash at source -> shown")):
            a, b = paths[heard_path], paths[shown_path]
            if a.get("n") and b.get("n"):
                report.add(f"  {who}: click heard / mark shown, {label}", f"{a['median']:g} / {b['median']:g} ms",
                           "-", None, "", "median ms after the whole second of the master clock they mark")
        rates = window_rates(taken.stats.get(DRAWN, []), tie, lo_ms, hi_ms)
        w["rates_per_s"] = rates
        if rates:
            report.add(f"  face frames received / drawn, {label}",
                       f"{rates['received']:.1f} / {rates['ticks']:.1f} /s", "-", None, "",
                       f"face frames the page took from the channel / animation frames it drew; voice clock reports "
                       f"{rates['reports']:.1f}/s" + ("; not drawn (--no-webgl-draw)" if args.no_webgl_draw else ""))
    for name, steps in details["trajectory_ms"].items():
        if steps:
            report.add(f"A/V {name} over time", " -> ".join(f"{s['median_ms']:g}" for s in steps), "-", None, "",
                       f"median ms per {step_s:g} s since connecting")
    last = (taken.stats.get(DRAWN) or [{}])[-1]
    first_stats = (taken.stats.get(DRAWN) or [{}])[0]
    span_s = (last.get("at", 0) - first_stats.get("at", 0)) / 1e3
    reports = last.get("reports") or 0
    details["drawn_stats"] = {"first": first_stats, "last": last}
    synced = last.get("syncedMs") is not None
    rate = ((reports - (first_stats.get("reports") or 0)) / span_s) if span_s > 0 else None
    report.add("A/V browser-drawn voice clock", reports, "> 0", reports > 0 and synced, "reports",
               (f"voice clock messages received ({rate:.1f}/s)" if rate is not None else "")
               + ("" if synced else "; the face never knew what the voice plays (it showed the newest frames)")
               + f"; face messages bad {last.get('bad')}, before the face loaded {last.get('unplaced')}; "
               f"{details['face'].get('width')}x{details['face'].get('height')} canvas")
    if gaps:
        report.add("A/V talk: gaps between says", round(max(abs(g) for g in gaps), 2), "-", None, "ms",
                   f"largest of {len(gaps)} (each say's first sample less the last one's end; {len(talker.talks)} "
                   f"says of {SAY_PART_S:g} s)")
    report.add("A/V browser-drawn page clock tie", round(tie.uncertainty_ms, 2), "-", None, "ms",
               f"+- (GET round trips; drift over the phase {drift:.2f} ms)")


def window_rates(stats: list[dict[str, Any]], tie: ClockTie, lo_ms: float, hi_ms: float) -> dict[str, float]:
    """Per second within a window (host ms), from the drawn face's stats at each take: face frames received,
    animation frames drawn, voice clock reports."""
    inside = [s for s in stats if lo_ms <= tie.host_ms(s["at"]) < hi_ms]
    if len(inside) < 2:
        return {}
    a, b = inside[0], inside[-1]
    span_s = (b["at"] - a["at"]) / 1e3
    return {k: ((b.get(k) or 0) - (a.get(k) or 0)) / span_s for k in ("received", "ticks", "reports")} if span_s else {}


def since_second(tie: ClockTie, t_page: float) -> float:
    """For a click, flash or mark: ms since the whole second of the master clock it marks."""
    t = tie.host_ms(t_page)
    return t - math.floor(t / 1e3) * 1e3


def drawn_latency_phase(args: argparse.Namespace, inst: Instance, driver: Any, server: TimeServer, report: Report,
                        rng: random.Random) -> None:
    import zmq

    from eca.protocol.client import AgentClient
    from tests.support.browser import wait_for

    details: dict[str, Any] = {}
    report.details["drawn_latency"] = details
    open_drawn_page(driver, inst.url)  # a fresh page: nothing of the A/V phase lingers
    details["face"] = connect_drawn(driver, calibration=False, draw=not args.no_webgl_draw)
    wait_for(driver, DRAWN_READY_JS, CONNECT_TIMEOUT_S, "the face drawn in the page", bool)
    driver.execute_script("window.ecaBench.signature = true")
    time.sleep(DRAWN_SETTLE_S)  # the face's frames flow, its first frames drawn
    taken = Taken()
    commands: list[tuple[int, str]] = []
    ctx = zmq.Context()
    emotions = EmotionStates(ctx, inst.config)
    states, listen = emotions.seen, emotions.listen

    try:
        with AgentClient(inst.config, agent=AGENT, source="bench-web-drawn-latency", ctx=ctx) as client:
            progress(f"browser-drawn latency: {args.trials} set_emotion commands ({' / '.join(EMOTIONS)}, "
                     "transition 0)")
            ties = [tie_clocks(driver, server)]
            client.set_emotion(EMOTIONS[1], 1.0, transition_s=0.0)
            wait_until_ns(time.monotonic_ns() + 1_000_000_000, listen)
            driver.execute_script(TAKE_JS)  # what came before the first command
            for i in range(args.trials):
                name = EMOTIONS[i % 2]
                sent = client.set_emotion(name, 1.0, transition_s=0.0)
                commands.append((sent.t_ns, name))
                wait_until_ns(sent.t_ns + int(rng.uniform(*PAUSE_S) * 1e9), listen)
                if i % 8 == 7:
                    taken.take(driver, newest=True)
            taken.take(driver, newest=True)
            ties.append(tie_clocks(driver, server))
            listen(0.0)
    finally:
        emotions.close()
        ctx.term()
    driver.execute_script(CLOSE_DRAWN_JS)
    tie, drift = combined_tie(ties)
    details.update(clock_offset_ms=tie.offset_ms, clock_uncertainty_ms=tie.uncertainty_ms, clock_drift_ms=drift,
                   stats=(taken.stats.get(DRAWN) or [{}])[-1])
    # each newest frame as analyse_trials takes a presented video frame: shown (e, p) and arrived (r), page ms
    frames = [{"e": n["shownMs"], "p": n["shownMs"], "r": n["arrivedMs"], "sig": n["sig"], "next": n.get("nextMs")}
              for n in taken.logs.get(DRAWN, {}).get("newest", []) if n.get("sig")]
    # a page that draws a few times a second: the windows of the old and the new expression hold a drawing or two
    gaps = np.diff(sorted(f["e"] for f in frames)) if len(frames) > 1 else np.array([0.0])
    interval = float(np.median(gaps))
    old_ms, new_ms = max(150.0, 1.5 * interval), min(max(200.0, 1.5 * interval), 1e3 * PAUSE_S[0] / 2)
    details.update(drawing_interval_ms=interval, old_window_ms=old_ms, new_window_ms=new_ms)
    trials = analyse_trials(commands, states, frames, tie, old_ms, new_ms)
    details["trials"] = trials
    measured = [t for t in trials if "total_ms" in t]
    totals = [t["total_ms"] for t in measured]
    server_totals = [t["total_ms"] for t in report.details.get("latency", {}).get("trials", []) if "total_ms" in t]
    video = spread(server_totals) if server_totals else {}
    if not totals:
        report.add("command -> browser-drawn face shown", "none seen", f"p95 <= {TARGET_DRAWN_LATENCY_P95_MS:g}",
                   False, "ms", f"{len(trials)} commands; {len(frames)} frames shown")
        return
    s = spread(totals)
    beside = f"; server-drawn (video, 2D face) p50 {video['median']}, p95 {video['p95']} ms" if video else ""
    report.add("command -> browser-drawn face shown, p50", s["median"], "-", None, "ms",
               f"n {s['n']} of {len(trials)}; to the animation frame that drew it" + beside)
    report.add("command -> browser-drawn face shown, p95", s["p95"], f"<= {TARGET_DRAWN_LATENCY_P95_MS:g}",
               bool(s["p95"] <= TARGET_DRAWN_LATENCY_P95_MS), "ms", f"max {max(totals):.1f}" + beside)
    parts = {k: spread([t[k] for t in measured if k in t]) for k in
             ("bus_ms", "state_to_received_ms", "received_to_presented_ms", "drawn_to_next_frame_ms")}
    details["parts"] = parts
    for key, label, note in (("bus_ms", "bus: command -> state published", ""),
                             ("state_to_received_ms", "state -> face frame arrived",
                              "composed (at the frame slot, or early for a command), sent on the data channel"),
                             ("received_to_presented_ms", "arrived -> drawn", "the next animation frame"),
                             ("drawn_to_next_frame_ms", "(drawn -> the animation frame after)",
                              "not in the total: by then the frame drawn is on the screen")):
        p = parts[key]
        if p.get("n"):
            report.add(f"  {label}", p["median"], "-", None, "ms", f"measured, median; p95 {p['p95']}"
                       + (f"; {note}" if note else ""))
    report.add("browser-drawn latency clock tie", round(tie.uncertainty_ms, 2), "-", None, "ms",
               f"+- (GET round trips; drift {drift:.2f} ms)")


def close_page_connections(inst: Instance, driver: Any) -> None:
    """The bench's own connections of the page closed, and the service seen to let them go."""
    mark = len(inst.reader.lines)
    open_ = driver.execute_script("const B = window.ecaBench; "
                                  "return B ? Object.keys(B.drawn).length + Object.keys(B.marked).length : 0")
    driver.execute_script(CLOSE_CALIBRATION_JS + CLOSE_DRAWN_JS)
    if open_ and not wait_watching(inst, 0, 20.0, mark):
        raise RuntimeError("the page's viewers did not leave")


def drawn_viewers_phase(args: argparse.Namespace, inst: Instance, driver: Any, report: Report) -> None:
    details: dict[str, Any] = {"levels": []}
    report.details["drawn_viewers"] = details
    pid = inst.web_pid
    close_page_connections(inst, driver)
    progress(f"browser-drawn viewers: 0 (baseline), then {', '.join(map(str, args.viewers))} aiortc viewers drawing "
             f"the face themselves; {VIEWER_WINDOW_S:g} s windows after {VIEWER_SETTLE_S:g} s")
    time.sleep(VIEWER_SETTLE_S)  # the service lets go of its drawing
    zero = measure_window(pid, None, None, VIEWER_WINDOW_S)
    details["zero"] = zero
    levels: list[tuple[int, dict[str, Any]]] = []
    with load_process(inst.url, drawn=True) as load:
        ask(*load, "hello", 30.0)
        for n in args.viewers:
            got = ask(*load, f"set {n}", 60.0)
            if got.get("connected") != n:
                raise RuntimeError(f"the aiortc viewers did not all connect: {got}")
            time.sleep(VIEWER_SETTLE_S)  # the new viewers' first frames pass
            m = measure_window(pid, None, load, VIEWER_WINDOW_S)
            levels.append((n, m))
            details["levels"].append({"viewers": n, **m})
            progress(f"  {n} browser-drawn viewer(s): web CPU {m['cpu_pct']:.0f} % of a core, RSS "
                     f"{m['rss_mib']:.0f} MiB, {m.get('load_fps_each', float('nan')):.1f} face frames/s each")
        mark = len(inst.reader.lines)
        ask(*load, "set 0", 30.0)
    left = wait_watching(inst, 0, 20.0, mark)
    time.sleep(AFTER_LEAVING_S)
    after = measure_window(pid, None, None, VIEWER_WINDOW_S)
    details["after"] = after
    details["all_left"] = left

    video = {v["viewers"]: v for v in report.details.get("viewers", {}).get("levels", [])}
    video_zero = report.details.get("viewers", {}).get("zero")
    report.add("browser-drawn viewers: web CPU with 0 viewers", round(zero["cpu_pct"], 1), "-", None, "% core",
               f"RSS {zero['rss_mib']:.0f} MiB" + (f"; video path (2D face) {video_zero['cpu_pct']:.1f} %, RSS "
                                                   f"{video_zero['rss_mib']:.0f} MiB" if video_zero else ""))
    for n, m in levels:
        note = (f"RSS {m['rss_mib']:.0f} MiB; face frames {m.get('load_fps_each', float('nan')):.1f}/s each "
                f"(their process {m.get('load_cpu_pct', float('nan')):.0f} %)")
        if n in video:
            note += f"; video path {video[n]['cpu_pct']:.1f} %, RSS {video[n]['rss_mib']:.0f} MiB"
        report.add(f"browser-drawn viewers: web CPU with {n}", round(m["cpu_pct"], 1), "-", None, "% core", note)
    xs = [float(n) for n, _ in levels]
    slope = least_squares_slope(xs, [m["cpu_pct"] for _, m in levels])
    video_slope = least_squares_slope([float(n) for n in video], [v["cpu_pct"] for v in video.values()])
    if slope is not None:
        report.add("browser-drawn viewers: CPU per additional viewer", round(slope, 1),
                   f"<= {TARGET_CPU_PER_VIEWER:g}", slope <= TARGET_CPU_PER_VIEWER, "% core",
                   f"least squares over {', '.join(map(str, args.viewers))}"
                   + ("" if video_slope is None else f"; video path {video_slope:.1f}"))
    if levels:
        first = levels[0][1]["cpu_pct"] - zero["cpu_pct"]
        report.add(f"browser-drawn viewers: CPU 0 -> {levels[0][0]}", round(first, 1), "-", None, "% core",
                   "the face frames composed and packed, the voice encoded, for the first viewer")
        n_max, m_max = levels[-1]
        fps = m_max.get("load_fps_each")
        report.add(f"browser-drawn viewers: face frames with {n_max}", "none" if fps is None else round(fps, 1),
                   f">= {TARGET_FPS_MIN:g}", fps is not None and fps >= TARGET_FPS_MIN, "fps",
                   "received by each aiortc viewer on its data channel")
    rss_slope = least_squares_slope(xs, [m["rss_mib"] for _, m in levels])
    if rss_slope is not None:
        video_rss = least_squares_slope([float(n) for n in video], [v["rss_mib"] for v in video.values()])
        report.add("browser-drawn viewers: RSS per additional viewer", round(rss_slope, 1), "-", None, "MiB",
                   "" if video_rss is None else f"video path {video_rss:.1f}")
    back = abs(after["rss_mib"] - zero["rss_mib"]) / zero["rss_mib"]
    report.add("browser-drawn viewers: RSS after all left vs 0", round(after["rss_mib"] - zero["rss_mib"], 1),
               f"+-{100 * TARGET_RSS_RETURN:g} %", back <= TARGET_RSS_RETURN and left, "MiB",
               f"{after['rss_mib']:.0f} vs {zero['rss_mib']:.0f} MiB ({100 * back:.1f} %); CPU after "
               f"{after['cpu_pct']:.1f} %" + ("" if left else "; the viewers did not all leave"))


# --- the load process: aiortc viewers that receive but do not decode -------------------------------


class CountingNullDecoder:
    """Takes encoded frames and counts them: the server's work per viewer is the same, the load's CPU is
    not spent decoding pictures nobody looks at."""

    counts: dict[str, int] = {"video": 0, "audio": 0}

    def __init__(self, kind: str) -> None:
        self.kind = kind

    def decode(self, encoded_frame: Any) -> list[Any]:
        CountingNullDecoder.counts[self.kind] += 1
        return []


def run_load(url: str, drawn: bool = False) -> int:
    """The load process: aiortc viewers of the agent at 640x480/30 fps, as many as asked on stdin. `drawn`: each
    draws the face itself (as tests/support/web_client.py FaceClient: the "eca-face" data channel, the voice
    only, `draw_here`), and its face frames are counted; else each receives the face as video."""
    import aiohttp
    import aiortc.rtcrtpreceiver
    from aiortc import RTCPeerConnection, RTCSessionDescription

    aiortc.rtcrtpreceiver.get_decoder = (  # type: ignore[attr-defined]
        lambda codec: CountingNullDecoder(codec.mimeType.split("/")[0].lower()))
    face_frames = [0]

    def on_message(message: object) -> None:
        if isinstance(message, bytes) and len(message) > 2 and message[2] == 1:  # browser_face.py FRAME
            face_frames[0] += 1

    async def connect(session: aiohttp.ClientSession) -> RTCPeerConnection:
        pc = RTCPeerConnection()
        if drawn:
            channel = pc.createDataChannel("eca-face", ordered=False, maxRetransmits=0)
            channel.on("message", on_message)
        kinds = ("audio",) if drawn else ("video", "audio")
        sections = [(pc.addTransceiver(kind, direction="recvonly"), kind) for kind in kinds]
        await pc.setLocalDescription(await pc.createOffer())
        body = {"type": "offer", "sdp": pc.localDescription.sdp, "agents": [AGENT],
                "video": {"width": WIDTH, "height": HEIGHT, "fps": FPS},
                "streams": [{"mid": t.mid, "agent": AGENT, "kind": k} for t, k in sections], "mic_mid": None,
                "draw_here": [AGENT] if drawn else []}
        async with session.post(url + "offer", json=body) as response:
            answer = await response.json()
            if response.status != 200:
                await pc.close()
                raise RuntimeError(f"offer refused ({response.status}): {answer}")
        await pc.setRemoteDescription(RTCSessionDescription(sdp=answer["sdp"], type="answer"))
        return pc

    async def main() -> None:
        loop = asyncio.get_running_loop()
        lines: asyncio.Queue[str | None] = asyncio.Queue()

        def read_stdin() -> None:
            for line in sys.stdin:
                loop.call_soon_threadsafe(lines.put_nowait, line.strip())
            loop.call_soon_threadsafe(lines.put_nowait, None)

        threading.Thread(target=read_stdin, daemon=True).start()
        clients: list[RTCPeerConnection] = []

        def say(obj: dict[str, Any]) -> None:
            print(json.dumps(obj), flush=True)

        async with aiohttp.ClientSession() as session:
            try:
                while (line := await lines.get()) is not None:
                    if line == "hello":
                        say({"hello": True})
                    elif line.startswith("set "):
                        want = int(line.split()[1])
                        while len(clients) > want:
                            await clients.pop().close()
                        while len(clients) < want:
                            clients.append(await connect(session))
                        deadline = loop.time() + CONNECT_TIMEOUT_S
                        while loop.time() < deadline and any(c.connectionState != "connected" for c in clients):
                            await asyncio.sleep(0.05)  # polling the connection states
                        say({"connected": sum(c.connectionState == "connected" for c in clients)})
                    elif line == "stats":
                        frames = face_frames[0] if drawn else CountingNullDecoder.counts["video"]
                        say({"clients": len(clients), "frames": frames, "t": time.monotonic(),
                             "cpu_s": time.process_time()})
            finally:
                for c in clients:
                    await c.close()

    asyncio.run(main())
    return 0


# --- the run ---------------------------------------------------------------------------------------


def guarded(phase: str, report: Report, body: Callable[[], None]) -> None:
    """Run a phase; a failure of the bench itself becomes a figure, and the next phase still runs."""
    try:
        body()
    except Exception as exc:
        report.add(phase, "bench failed", "runs", False, "", f"{type(exc).__name__}: {exc}"[:200])
        report.details.setdefault("exceptions", []).append(traceback.format_exc())
        progress(f"{phase} failed: {type(exc).__name__}: {exc}")


def run(args: argparse.Namespace, report: Report) -> None:
    from tests.support.browser import browser_available

    problem = browser_available()
    if problem:
        report.add("browser", "missing", "present", False, "", problem)
        return
    if args.draw != "browser":
        run_server_drawn(args, report)
    if args.draw != "server":
        run_browser_drawn(args, report)


def notable(inst: Instance, report: Report, tag: str = "") -> None:
    """What eca up said of note (warnings, errors, restarts) and the viewers its watchdog closed."""
    said = [tag + line for line in inst.reader.lines if re.search(r"ERROR|Traceback|WARNING|restarting", line)
            and "no audio output" not in line]
    report.details.setdefault("eca_up_notable_lines", []).extend(said[:40])
    web_lines = [line for line in inst.reader.lines if line.startswith("[web]")]
    which = f", {tag.strip(' ()')}" if tag else ""
    report.details["web_lines" + which.replace(", ", "_")] = web_lines[:300]  # web_lines, web_lines_head
    silent = [line for line in web_lines if "no answer for" in line]
    report.add(f"viewers the service closed as silent{which}", len(silent), "0",
               not silent, "", "the product's watchdog, at its default silent_timeout_s")
    beats = inst.beats
    report.details["web_heartbeats" + which.replace(", ", "_")] = {"beats": beats.beats, "longest_s": beats.longest_s}
    report.add(f"web service's loop: longest stall{which}", round(beats.longest_s, 2), "-", None, "s",
               f"the longest gap between its {beats.beats} heartbeats on the bus (sent from its loop, every "
               f"{inst.config.heartbeat_interval_s:g} s); the product's supervisor restarts a service silent 1.5 s "
               f"(this instance's: {HEARTBEAT_TIMEOUT_S:g} s)")


def run_server_drawn(args: argparse.Namespace, report: Report) -> None:
    """Phases 1-3: the 2D face, drawn by the service and sent as video."""
    from tests.support.browser import chromium

    rng = random.Random(args.seed)
    baselines: dict[str, float] | None = None
    if not (args.skip_latency and args.skip_viewers):
        progress("baselines: the face drawn and VP8-encoded at 640x480 in this process")
        baselines = draw_and_encode_baselines()
        report.details["baselines"] = baselines
        report.add("baseline: face draw per frame (bench)", round(baselines["draw_ms"], 2), "-", None, "ms",
                   f"compose + draw + yuv on the GPU + read-back, {WIDTH}x{HEIGHT}; p95 {baselines['draw_p95_ms']:.2f}")
        report.add("baseline: VP8 encode per frame (bench)", round(baselines["encode_ms"], 2), "-", None, "ms",
                   f"the service's encoder, {WIDTH}x{HEIGHT}; p95 {baselines['encode_p95_ms']:.2f}")
    curve = mouth_curve() if not args.skip_av else {}
    with instance() as inst, TimeServer() as server, chromium() as driver:
        report.details["web_pid"] = inst.web_pid
        report.details["rss_at_start_mib"] = rss_mib(inst.web_pid)
        open_page(driver, inst.url)
        connected_ns = time.monotonic_ns()
        driver.execute_script(PAGE_JS, list(MOUTH_BOX), list(SIGNATURE_SIZE), [ONSET_LEVEL, ONSET_QUIET_S],
                              list(PATCH_BOX))
        if not args.skip_av:
            guarded("A/V offset", report, lambda: av_phase(args, inst, driver, server, report, rng, curve))
        if not args.skip_latency:
            if not args.skip_av:
                # a fresh connection, as a viewer has: the A/V phase's three streams and per-frame measuring
                # load both machine and browser, and the jitter buffers they grew would outlast the phase
                progress("latency: a fresh page and connection")
                disconnect_page(driver)
                open_page(driver, inst.url)
                connected_ns = time.monotonic_ns()
                driver.execute_script(PAGE_JS, list(MOUTH_BOX), list(SIGNATURE_SIZE), [ONSET_LEVEL, ONSET_QUIET_S],
                              list(PATCH_BOX))
            guarded("command -> frame", report,
                    lambda: latency_phase(args, inst, driver, server, report, rng, baselines, connected_ns))
        if not args.skip_viewers:
            guarded("cost per viewer", report, lambda: viewers_phase(args, inst, driver, report, baselines))
        notable(inst, report)


def run_browser_drawn(args: argparse.Namespace, report: Report) -> None:
    """Phases 4-6: the 3D head, drawn by the page from face frames, on an instance of its own."""
    from eca.services.processes.avatar.loader import DEFAULT_HEAD
    from tests.support.browser import chromium, webgl_renderer

    if not DEFAULT_HEAD.exists():
        report.add("browser-drawn face", "missing", "present", False, "", f"{DEFAULT_HEAD} is not baked")
        return
    rng = random.Random(f"{args.seed}-browser-drawn")  # its own: the same draws whether the server's phases run
    with instance(DRAWN_FACE) as inst, TimeServer() as server, chromium(gl=args.browser_gl) as driver:
        report.details["drawn_web_pid"] = inst.web_pid
        open_drawn_page(driver, inst.url)
        renderer = webgl_renderer(driver) or "no WebGL 2"
        report.add("browser-drawn: the page's WebGL", renderer[:60], "-", None, "",
                   f"--browser-gl {args.browser_gl}; the renderer the page draws the head with")
        if not args.skip_av:
            guarded("browser-drawn A/V offset", report, lambda: drawn_av_phase(args, inst, driver, server, report, rng))
        if not args.skip_latency:
            guarded("command -> browser-drawn face", report,
                    lambda: drawn_latency_phase(args, inst, driver, server, report, rng))
        if not args.skip_viewers:
            guarded("cost per browser-drawn viewer", report, lambda: drawn_viewers_phase(args, inst, driver, report))
        notable(inst, report, f"({DRAWN_FACE}) ")


def parse_size(text: str) -> tuple[int, int]:
    match = re.fullmatch(r"(\d{2,4})x(\d{2,4})", text.strip())
    if not match or not (64 <= int(match.group(1)) <= 1920 and 48 <= int(match.group(2)) <= 1080):
        raise argparse.ArgumentTypeError(f"--size must look like 320x240 (64x48 to 1920x1080), got {text!r}")
    return int(match.group(1)), int(match.group(2))


def parse_viewers(text: str) -> list[int]:
    try:
        counts = sorted({int(v) for v in text.split(",") if v.strip()})
    except ValueError:
        raise argparse.ArgumentTypeError(f"--viewers must look like 1,2,4,8, got {text!r}") from None
    if not counts or counts[0] < 1 or counts[-1] > 16:
        raise argparse.ArgumentTypeError("--viewers: counts from 1 to 16 (the service's max_viewers)")
    return counts


def main(argv: list[str] | None = None) -> int:
    global WIDTH, HEIGHT  # --size: the phases read the picture's size from here, as they do the rate
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--settle-s", type=float, default=40.0, help="A/V: time the browser gets to settle (s)")
    parser.add_argument("--measure-s", type=float, default=30.0, help="A/V: measuring time after it (s)")
    parser.add_argument("--trials", type=int, default=40, help="latency: commands (default 40)")
    parser.add_argument("--viewers", type=parse_viewers, default=[1, 2, 4, 8], help="viewer counts (1,2,4,8)")
    parser.add_argument("--skip-av", action="store_true", help="skip the A/V offset")
    parser.add_argument("--skip-latency", action="store_true", help="skip command -> frame")
    parser.add_argument("--skip-viewers", action="store_true", help="skip the cost per viewer")
    parser.add_argument("--draw", choices=("both", "server", "browser"), default="both",
                        help="the paths measured: the 2D face drawn by the server (video), the 3D head drawn by the "
                             "page (face frames), or both (default)")
    parser.add_argument("--no-webgl-draw", action="store_true",
                        help="browser-drawn: the page chooses and logs its frames at every animation frame but does "
                             "not draw them (SwiftShader draws the head a few times a second on 2 cores; without "
                             "drawing, animation frames come at the display's rate, as with a GPU)")
    parser.add_argument("--browser-gl", choices=("swiftshader", "egl"), default="swiftshader",
                        help="browser-drawn: the page's WebGL: Chromium's SwiftShader (default) or the system's EGL "
                             "(Mesa's llvmpipe on a machine without a GPU: it draws the head 3-4 times as often)")
    parser.add_argument("--size", type=parse_size, default=(WIDTH, HEIGHT),
                        help=f"the server-drawn video every phase asks for, WxH (default {WIDTH}x{HEIGHT}): the "
                             f"markers' reference too; a smaller one leaves a machine without a GPU more room to "
                             f"draw the page's face beside it (whose canvas is the service's configured size)")
    parser.add_argument("--long-s", type=float, default=0.0,
                        help="browser-drawn A/V: also measure --measure-s from this long after connecting, the agent "
                             "talking throughout (600: after 10 minutes; default 0: only the first minute)")
    parser.add_argument("--hum-level", type=float, default=HUM_LEVEL,
                        help="browser-drawn A/V: the quiet tone under the bursts (share of full scale; 0: none, so "
                             "the voice to the page pauses between the bursts and clicks and each mark is the "
                             "start of a talk spurt)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object (the table goes to stderr)")
    parser.add_argument("--role", choices=["load"], help=argparse.SUPPRESS)
    parser.add_argument("--url", help=argparse.SUPPRESS)
    parser.add_argument("--drawn", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    WIDTH, HEIGHT = args.size
    if args.role == "load":
        return run_load(args.url, args.drawn)
    if args.settle_s < 0 or not 5 <= args.measure_s <= MAX_SAY_S:
        parser.error(f"--settle-s must be >= 0 and --measure-s in 5..{MAX_SAY_S:g}")
    if args.trials < 2:
        parser.error("--trials must be at least 2")
    if args.long_s and args.long_s < drawn_windows(argparse.Namespace(**{**vars(args), "long_s": 0}))[-1].hi_s:
        parser.error("--long-s must be 0 or at least the browser-drawn A/V phase's first minute "
                     f"({DRAWN_ALONE_SETTLE_S:g} s + --settle-s + 2 x --measure-s)")

    done = run_guarded(lambda report: run(args, report))  # Ctrl-C or SIGTERM: eca up, the browser, helpers go
    report, host, wall_s = done.report, done.host, done.wall_s
    header = done.header("web front-end", f"headless Chromium, {WIDTH}x{HEIGHT} at {FPS:g} fps")
    report.print_table(header, sys.stderr if args.json else sys.stdout, report.details.get("eca_up_notable_lines", []),
                       "eca up said (warnings, errors, restarts):", value_width=28)
    if args.json:
        print(json.dumps({
            "bench": "web", "machine": host, "wall_s": round(wall_s, 1),
            "options": {k: v for k, v in vars(args).items() if k not in ("role", "url")},
            **report.as_json(),
        }, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
