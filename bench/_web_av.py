"""Bench part for bench/web.py, phase 1: the A/V offset of the face the server draws, as the browser presents it (see
bench/web.py's docstring)."""

from __future__ import annotations

import argparse
import json
import math
import random
import statistics
import time
from typing import Any

import numpy as np

from bench._web_common import (
    AGENT,
    ATSC_EARLY_MS,
    ATSC_LATE_MS,
    BURST_AFTER_SECOND_S,
    BURST_S,
    CLEAR_AFTER_CLICK_S,
    CONNECT_TIMEOUT_S,
    FPS,
    HUM_HZ,
    MARKED,
    MAX_SAY_S,
    MOUTH_BOX,
    PAIR_WINDOW_MS,
    SAY_RATE_HZ,
    TARGET_AV_DIFF_MS,
    TRAJECTORY_WINDOW_S,
    VIDEO,
    ClockTie,
    Instance,
    TimeServer,
    combined_tie,
    progress,
    spread,
    tie_clocks,
)
from bench._web_page import (
    CALIBRATION_JS,
    CLOSE_CALIBRATION_JS,
    RESTART_AUDIO_JS,
    START_MEASURING_JS,
    STREAMS_READY_JS,
    SYNC_JS,
    TAKE_JS,
)
from bench.report import Report, percentile, wait_until_ns


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
        renderer = Renderer(ctx, (VIDEO.width, VIDEO.height))
        fbo = ctx.simple_framebuffer((VIDEO.width, VIDEO.height))
        model = FaceModel(seed=1)
        weights = [i / steps for i in range(steps + 1)]
        counts = []
        for weight in weights:
            model.set_mouth({"say_ah": weight})
            renderer.render(model.frame_at(0).values, target=fbo)
            rgb = np.frombuffer(fbo.read(components=3), np.uint8).reshape(VIDEO.height, VIDEO.width, 3)[::-1]
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
    answer = driver.execute_async_script(CALIBRATION_JS, MARKED, AGENT, VIDEO.width, VIDEO.height, FPS)
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
