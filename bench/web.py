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
import json
import random
import re
import sys
import time
import traceback
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench._web_av import av_phase, mouth_curve  # noqa: E402
from bench._web_common import (  # noqa: E402
    DRAWN_ALONE_SETTLE_S,
    DRAWN_FACE,
    FPS,
    HEARTBEAT_TIMEOUT_S,
    HUM_LEVEL,
    MAX_SAY_S,
    MOUTH_BOX,
    ONSET_LEVEL,
    ONSET_QUIET_S,
    PATCH_BOX,
    SIGNATURE_SIZE,
    VIDEO,
    Instance,
    TimeServer,
    disconnect_page,
    draw_and_encode_baselines,
    instance,
    open_page,
    progress,
    rss_mib,
)
from bench._web_drawn import drawn_av_phase, drawn_latency_phase, drawn_viewers_phase, drawn_windows, open_drawn_page  # noqa: E402
from bench._web_latency import latency_phase  # noqa: E402
from bench._web_page import PAGE_JS  # noqa: E402
from bench._web_viewers import run_load, viewers_phase  # noqa: E402
from bench.report import Report, run_guarded  # noqa: E402

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
                   f"compose + draw + yuv on the GPU + read-back, {VIDEO.width}x{VIDEO.height}; "
                   f"p95 {baselines['draw_p95_ms']:.2f}")
        report.add("baseline: VP8 encode per frame (bench)", round(baselines["encode_ms"], 2), "-", None, "ms",
                   f"the service's encoder, {VIDEO.width}x{VIDEO.height}; p95 {baselines['encode_p95_ms']:.2f}")
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
    parser.add_argument("--size", type=parse_size, default=(VIDEO.width, VIDEO.height),
                        help=f"the server-drawn video every phase asks for, WxH "
                             f"(default {VIDEO.width}x{VIDEO.height}): "
                             f"the markers' reference too; a smaller one leaves a machine without a GPU more room to "
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
    VIDEO.width, VIDEO.height = args.size  # the phases read the picture's size from here
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
    header = done.header("web front-end", f"headless Chromium, {VIDEO.width}x{VIDEO.height} at {FPS:g} fps")
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
