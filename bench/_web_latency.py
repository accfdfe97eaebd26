"""Bench part for bench/web.py, phase 2: command -> the first frame the browser presents that shows it (the face the
server draws; see bench/web.py's docstring)."""

from __future__ import annotations

import argparse
import random
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bench._web_common import (
    AGENT,
    EMOTIONS,
    MOUTH_BOX,
    ONSET_LEVEL,
    ONSET_QUIET_S,
    PATCH_BOX,
    PAUSE_S,
    SIGNATURE_SIZE,
    TARGET_LATENCY_P95_MS,
    ClockTie,
    EmotionStates,
    Instance,
    TimeServer,
    combined_tie,
    progress,
    spread,
    tie_clocks,
    video_stats,
)
from bench._web_page import PAGE_JS, TAKE_JS
from bench.report import Report, wait_until_ns


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
            commands += emotion_commands(
                client, driver, args.trials, rng, listen,
                lambda: frames.extend(driver.execute_script(TAKE_JS)["frames"].get("face", [])))
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
    details["frames_decoded_in_phase"] = delta(after, before, "framesDecoded")
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


def emotion_commands(client: Any, driver: Any, trials: int, rng: random.Random, listen: Callable[[float], None],
                     take: Callable[[], None]) -> list[tuple[int, str]]:
    """`trials` set_emotion commands (transition 0), EMOTIONS in turn at seeded pauses (`listen` takes the states
    meanwhile), after one that sets the face apart from the first; `take` collects what the page logged, every 8
    commands and at the end. (send time, emotion) of each."""
    commands: list[tuple[int, str]] = []
    client.set_emotion(EMOTIONS[1], 1.0, transition_s=0.0)
    wait_until_ns(time.monotonic_ns() + 1_000_000_000, listen)
    driver.execute_script(TAKE_JS)  # what came before the first command
    for i in range(trials):
        name = EMOTIONS[i % 2]
        sent = client.set_emotion(name, 1.0, transition_s=0.0)
        commands.append((sent.t_ns, name))
        wait_until_ns(sent.t_ns + int(rng.uniform(*PAUSE_S) * 1e9), listen)
        if i % 8 == 7:
            take()
    take()
    return commands


def delta(after: dict[str, Any], before: dict[str, Any], key: str) -> float | None:
    a, b = after.get(key), before.get(key)
    return None if a is None or b is None else float(a) - float(b)


def _per(after: dict[str, Any], before: dict[str, Any], total: str, count: str) -> float | None:
    t, n = delta(after, before, total), delta(after, before, count)
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
