"""A scheduled BML block as eca's own messages, each stamped with its time on the master clock.

What the face can do ahead of time goes out at once with its times (the voice as a say with `start_ns`, facial
behaviours as `expression`s, head behaviours as `head_gesture`s), so the faces, the rig and the browsers
place them within a frame of their schedule whatever the bus's delay. What is a state (the gaze target, the
head's direction, the emotion, the role) goes out when its time comes (`Timed`), through the dialogue service
like any client's command. docs/bml.md lists what maps to what.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from eca.agent.bml import (
    BlinkParams,
    Block,
    EmotionParams,
    FaceParams,
    GazeParams,
    HeadDirectionParams,
    HeadParams,
    RoleParams,
    SpeechParams,
    Timeline,
)
from eca.protocol.messages import (
    Expression,
    GazeTargetState,
    HeadGesture,
    HeadState,
    Message,
    MoveHead,
    Say,
    SetEmotion,
    SetGazeTarget,
    SetRole,
)
from eca.services.processes.bml.speech import SpeechAudio

NS = 1_000_000_000
FOREVER_NS = 2**62  # a faceShift holds until the next one replaces it
SHIFT_ID = "faceShift"  # one rest expression per agent: each faceShift replaces the one before
BLINK_FLEXORS = {"blink_l": 1.0, "blink_r": 1.0}


@dataclass(frozen=True)
class Timed:
    """A command due at `at_ns` on the master clock (a state: it applies when it is sent)."""

    at_ns: int
    block: str
    message: Message
    restore: bool = False  # puts back what the block changed (a gaze's end): sent at once if the block is cut


@dataclass
class Realization:
    """What one block sends: now (stamped with their times), later (`timed`), and what undoes it if the block
    is interrupted (`cut`: the expressions and gestures ended at once; `says` interrupted)."""

    now: list[Message]
    timed: list[Timed]
    says: dict[str, str]  # speech behaviour -> say request id
    expressions: list[Expression]
    gestures: list[HeadGesture]


Direction = Callable[[str, str], tuple[float, float] | None]  # (agent, target) -> (yaw, pitch) degrees


@dataclass(frozen=True)
class HeadAim:
    """How a gaze or a head direction turns the head: flexor units in degrees (configs/flexor_units.toml), and
    the share of a gaze's direction the head takes with influence HEAD or wider (configs/conversation.toml [head]
    share: the eyes do the rest, as in the gaze model's own turns)."""

    turn_deg: float
    nod_deg: float
    gaze_share: float

    def toward(self, yaw_deg: float, pitch_deg: float, share: float = 1.0) -> tuple[float, float]:
        """(turn, nod) in flexor units, within [-1, 1]."""
        return _clip(share * yaw_deg / self.turn_deg, 1), _clip(share * pitch_deg / self.nod_deg, 1)


def realize(agent: str, block: Block, timeline: Timeline, voices: Mapping[str, SpeechAudio],
            say_id: Callable[[str], str], direction: Direction, gaze_now: GazeTargetState | None,
            head_now: HeadState | None, aim: HeadAim) -> Realization:
    """The messages that realize `block` on `agent` (timeline in master-clock seconds)."""
    out = Realization([], [], {}, [], [])

    def at(behaviour: str, sync: str) -> int:
        return round(timeline.times[(behaviour, sync)] * NS)

    for beh in block.behaviours:
        key = f"{block.id}:{beh.id}"
        p = beh.params
        if isinstance(p, SpeechParams):
            audio = voices[beh.id]
            rid = say_id(beh.id)
            out.says[beh.id] = rid
            out.now.append(Say(agent=agent, request_id=rid, pcm=audio.pcm, sample_rate=audio.sample_rate,
                               audio_path=audio.audio_path, text=p.text[:10_000] or None, start_ns=at(beh.id, "start")))
        elif isinstance(p, FaceParams) or isinstance(p, BlinkParams):
            flexors = dict(p.flexors) if isinstance(p, FaceParams) else BLINK_FLEXORS
            if isinstance(p, FaceParams) and p.shift:
                start, end = at(beh.id, "start"), at(beh.id, "end")
                expression = Expression(agent=agent, id=SHIFT_ID, onset_ns=start, peak_ns=end, relax_ns=FOREVER_NS,
                                        end_ns=FOREVER_NS, flexors=flexors)
            else:
                points = dict.fromkeys(("start", "attackPeak", "relax", "end"), 0)
                for sync in points:
                    points[sync] = at(beh.id, sync) if (beh.id, sync) in timeline.times else at(beh.id, "start")
                if isinstance(p, BlinkParams):  # a blink closes and opens: its lids at full half way
                    mid = (at(beh.id, "start") + at(beh.id, "end")) // 2
                    points = {"start": at(beh.id, "start"), "attackPeak": mid, "relax": mid, "end": at(beh.id, "end")}
                expression = Expression(agent=agent, id=key, onset_ns=points["start"], peak_ns=points["attackPeak"],
                                        relax_ns=points["relax"], end_ns=points["end"], flexors=flexors)
                out.expressions.append(expression)
            out.now.append(expression)
        elif isinstance(p, HeadParams):
            # the strokes fill strokeStart .. strokeEnd (the head is still while it prepares and retracts)
            start = at(beh.id, "strokeStart") if (beh.id, "strokeStart") in timeline.times else at(beh.id, "start")
            end = at(beh.id, "strokeEnd") if (beh.id, "strokeEnd") in timeline.times else at(beh.id, "end")
            gesture = HeadGesture(agent=agent, id=key, lexeme=p.lexeme, onset_ns=start,
                                  duration_s=min(30.0, (end - start) / NS), repetitions=p.repetitions,
                                  amplitude_deg=min(30.0, p.amplitude_deg))
            out.gestures.append(gesture)
            out.now.append(gesture)
        elif isinstance(p, GazeParams):
            yaw, pitch = direction(agent, p.target) or (0.0, 0.0)
            yaw, pitch = _offset(yaw, pitch, p.offset_angle_deg, p.offset_direction)
            start = at(beh.id, "start")
            ready = at(beh.id, "ready") if (beh.id, "ready") in timeline.times else at(beh.id, "end")
            look = SetGazeTarget(agent=agent, yaw_deg=_clip(yaw, 60), pitch_deg=_clip(pitch, 45), target=p.target[:32])
            out.timed.append(Timed(start, block.id, look))
            turns_head = p.influence not in ("EYES", "")
            if turns_head:
                head_turn, head_nod = aim.toward(yaw, pitch, aim.gaze_share)
                turn = MoveHead(agent=agent, turn=head_turn, nod=head_nod,
                                duration_s=min(30.0, max(0.05, (ready - start) / NS)))
                out.timed.append(Timed(start, block.id, turn))
            if not p.shift:  # a gaze ends: back to where the gaze model looked, and its saccades go on from there
                end = at(beh.id, "end")
                if gaze_now is not None:
                    out.timed.append(Timed(end, block.id, SetGazeTarget(agent=agent, yaw_deg=gaze_now.yaw_deg,
                                                                        pitch_deg=gaze_now.pitch_deg,
                                                                        target=gaze_now.target), restore=True))
                if turns_head:
                    back = head_now or HeadState(agent=agent)
                    out.timed.append(Timed(end, block.id, MoveHead(agent=agent, turn=back.turn, nod=back.nod,
                                                                   tilt=back.tilt, duration_s=0.4), restore=True))
        elif isinstance(p, HeadDirectionParams):
            yaw, pitch = direction(agent, p.target) or (0.0, 0.0)
            start, end = at(beh.id, "start"), at(beh.id, "end")
            head_turn, head_nod = aim.toward(yaw, pitch)
            out.timed.append(Timed(start, block.id, MoveHead(agent=agent, turn=head_turn, nod=head_nod,
                                                             duration_s=min(30.0, max(0.05, (end - start) / NS)))))
        elif isinstance(p, EmotionParams):
            out.timed.append(Timed(at(beh.id, "start"), block.id, SetEmotion(
                agent=agent, name=p.name, intensity=p.intensity, transition_s=p.transition_s)))
        elif isinstance(p, RoleParams):
            out.timed.append(Timed(at(beh.id, "start"), block.id, SetRole(agent=agent, role=p.role)))
        # wait: sync points only
    out.timed.sort(key=lambda t: t.at_ns)
    return out


def cut_messages(realization: Realization, now_ns: int, release_s: float = 0.15) -> list[Message]:
    """What ends an interrupted block's face at once: its expressions relax from now (a short release, not a
    jump), its gestures stop."""
    out: list[Message] = []
    release = round(release_s * NS)
    for e in realization.expressions:
        if e.end_ns <= now_ns:
            continue
        onset = min(e.onset_ns, now_ns)
        peak = min(e.peak_ns, now_ns)
        out.append(Expression(agent=e.agent, id=e.id, onset_ns=onset, peak_ns=peak, relax_ns=now_ns,
                              end_ns=now_ns + (release if e.onset_ns < now_ns else 0), flexors=e.flexors))
    for g in realization.gestures:
        if g.onset_ns + g.duration_s * NS > now_ns:
            out.append(HeadGesture(agent=g.agent, id=g.id, lexeme=g.lexeme, onset_ns=now_ns, duration_s=0.0,
                                   repetitions=1, amplitude_deg=0.0))
    return out


_DIRECTIONS = {"NONE": (0.0, 0.0), "RIGHT": (1.0, 0.0), "LEFT": (-1.0, 0.0), "UP": (0.0, 1.0), "DOWN": (0.0, -1.0),
               "UPRIGHT": (0.7071, 0.7071), "UPLEFT": (-0.7071, 0.7071), "DOWNLEFT": (-0.7071, -0.7071),
               "DOWNRIGHT": (0.7071, -0.7071)}


def _offset(yaw: float, pitch: float, angle_deg: float, direction: str) -> tuple[float, float]:
    dx, dy = _DIRECTIONS.get(direction, (0.0, 0.0))
    return yaw + dx * angle_deg, pitch + dy * angle_deg


def _clip(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))
