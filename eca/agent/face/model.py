"""The face in one object: emotion, head, eyes and mouth in, a flexor frame out at any time.

The renderer service and the offline renderer drive this; it owns the default layer stack
(agent/face/compositor.py) and converts degrees to flexor units (configs/flexor_units.toml).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from eca.agent.clock import nanoseconds
from eca.agent.face.composed import ComposedFace, EyeAngles
from eca.agent.face.compositor import DEFAULT_LAYERS, Compositor
from eca.agent.face.emotions import (
    NATURAL,
    EmotionTable,
    canonical_emotion_name,
    check_intensity,
    load_emotion_table,
)
from eca.agent.face.expressions import Expressions
from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.face.frame import FlexorFrame, check_flexor_value, dont_care_vector
from eca.agent.face.gestures import HeadGestures, HeadLexeme
from eca.agent.face.head import HeadMotion
from eca.agent.face.idle import IdleNoise
from eca.agent.face.settings import FaceSettings, FlexorUnits, load_face_settings, load_flexor_units

MOUTH_FLEXORS: tuple[str, ...] = ("say_ah", "say_oo", "say_ee", "say_mm", "say_ff")
_LOOK_X, _LOOK_Y = FLEXOR_INDEX["look_x"], FLEXOR_INDEX["look_y"]
_HEAD = np.array([FLEXOR_INDEX["turn"], FLEXOR_INDEX["nod"]])
_LOOK = np.array([_LOOK_X, _LOOK_Y])
_BLINKS = np.array([FLEXOR_INDEX["blink_l"], FLEXOR_INDEX["blink_r"]])
_MOUTH = np.array([FLEXOR_INDEX[name] for name in MOUTH_FLEXORS])


class _Held:
    """A trajectory-layer action that holds the values it was last given for its flexors (gaze, blink, mouth;
    NaN = leave that flexor to the layers below): those inputs already arrive as per-frame trajectories, so
    they are shown without settling."""

    def __init__(self, index: np.ndarray) -> None:
        self.index = index
        self._cared: tuple[np.ndarray, np.ndarray] | None = None

    def hold(self, values: Sequence[float]) -> None:
        """The values of its flexors from now on (checked by the caller), in `index` order."""
        cared = [i for i, v in enumerate(values) if v == v]  # not NaN
        if len(cared) == len(values):
            self._cared = (self.index, np.array(values, dtype=np.float64))
        elif cared:
            self._cared = (self.index[cared], np.array([values[i] for i in cared], dtype=np.float64))
        else:
            self._cared = None

    def hold_row(self, values: np.ndarray | None) -> None:
        """hold() for a row of numbers (none NaN) in `index` order, or None for nothing cared about."""
        self._cared = None if values is None else (self.index, values)

    def values_at(self, t_ns: int) -> np.ndarray:
        vector = dont_care_vector()
        if self._cared is not None:
            vector[self._cared[0]] = self._cared[1]
        return vector

    def sparse_at(self, t_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        return self._cared


class FaceModel:
    def __init__(
        self,
        seed: int = 0,
        idle_noise: bool = True,
        emotions: EmotionTable | None = None,
        settings: FaceSettings | None = None,
        units: FlexorUnits | None = None,
        t_ns: int = 0,
    ) -> None:
        self.emotions = emotions if emotions is not None else load_emotion_table()
        self.settings = settings if settings is not None else load_face_settings()
        self.units = units if units is not None else load_flexor_units()
        self.compositor = Compositor(self.settings.settle_s, DEFAULT_LAYERS, t_ns)
        self.compositor.set_pose("base", self.emotions.pose(NATURAL), t_ns, settle_s=0.0)
        self.head = HeadMotion(t_ns=t_ns)
        self.compositor.set_action("head", self.head)
        self.attention = HeadMotion(t_ns=t_ns)
        self.compositor.set_action("attention", self.attention)
        self.gestures = HeadGestures()
        self.compositor.set_action("gesture", self.gestures)
        self.expressions = Expressions()
        self.compositor.set_action("expression", self.expressions)
        self._gaze, self._mouth, self._blink = _Held(_LOOK), _Held(_MOUTH), _Held(_BLINKS)
        self.compositor.set_action("gaze", self._gaze)
        self.compositor.set_action("mouth", self._mouth)
        self.compositor.set_action("blink", self._blink)
        self._eyes_deg: tuple[float, float] | None = None  # the gaze last set, in degrees, unclipped
        self._lid = 0.0
        self.idle = IdleNoise(self.settings.idle_amplitude, self.settings.idle_rate_hz, seed)
        self.compositor.set_action("idle", self.idle if idle_noise else None)
        self._emotion: tuple[str, float] = (NATURAL, 1.0)

    @property
    def eyes_deg(self) -> tuple[float, float] | None:
        """The gaze last set (set_eyes), in degrees, unclipped; None when it left the eyes to the layers below."""
        return self._eyes_deg

    @property
    def emotion(self) -> tuple[str, float]:
        """(name, intensity) of the emotion last set."""
        return self._emotion

    def set_emotion(self, name: str, intensity: float = 1.0, transition_s: float | None = None, t_ns: int = 0) -> None:
        """Blend toward `name` at `intensity` from t_ns; within transition_s if given, else with the
        per-flexor settle times (configs/face.toml)."""
        pose = self.emotions.pose(name, intensity)
        self.set_expression(pose, transition_s, t_ns)
        self._emotion = (canonical_emotion_name(name), check_intensity(intensity))

    def set_expression(self, pose: np.ndarray, transition_s: float | None = None, t_ns: int = 0) -> None:
        """Blend the emotion layer toward any flexor vector (NaN = do not care), e.g. a script element's
        values; the same settling as set_emotion."""
        if transition_s is not None and (not math.isfinite(transition_s) or transition_s < 0):
            raise ValueError(f"emotion transition must be a finite number of seconds >= 0, got {transition_s!r}")
        self.compositor.set_pose("emotion", pose, t_ns, settle_s=transition_s)

    def move_head(self, turn: float, nod: float, tilt: float, duration_s: float, t_ns: int) -> None:
        """Move the head to (turn, nod, tilt) in flexor units, arriving at rest after duration_s."""
        self.head.move_to((turn, nod, tilt), duration_s, t_ns)

    def move_head_deg(self, yaw_deg: float, pitch_deg: float, roll_deg: float, duration_s: float, t_ns: int) -> None:
        """Move the head to angles in degrees (yaw to the agent's right, pitch chin-up, roll to the right)."""
        u = self.units
        self.move_head(yaw_deg / u.turn_deg, pitch_deg / u.nod_deg, roll_deg / u.tilt_deg, duration_s, t_ns)

    def attend(self, yaw_deg: float, pitch_deg: float, duration_s: float, t_ns: int) -> None:
        """Turn the head toward the person attended (situated gaze, agent/gaze/situated.py): an offset in
        degrees added to the scripted head moves, reached at rest after duration_s."""
        u = self.units
        self.attention.move_to((yaw_deg / u.turn_deg, pitch_deg / u.nod_deg, 0.0), duration_s, t_ns)

    def nod(self, amplitude_deg: float, duration_s: float, t_ns: int) -> None:
        """A nod from t_ns: the chin dips by amplitude_deg and comes back within duration_s."""
        self.gestures.add("nod", t_ns, amplitude_deg / self.units.nod_deg, duration_s)

    def head_gesture(self, gesture_id: str, lexeme: HeadLexeme, amplitude_deg: float, duration_s: float,
                     repetitions: int, t_ns: int) -> None:
        """A gesture from t_ns (BML head): `repetitions` strokes of amplitude_deg within duration_s; it
        replaces the gesture of the same id (duration 0 ends that one)."""
        per_unit = {"nod": self.units.nod_deg, "shake": self.units.turn_deg, "tilt": self.units.tilt_deg}[lexeme]
        depth = min(1.0, amplitude_deg / per_unit)
        if duration_s > 0 and depth <= 0:
            return  # a gesture of no amplitude: nothing moves
        self.gestures.add(lexeme, t_ns, depth, duration_s, repetitions, gesture_id)

    def expression(self, expression_id: str, onset_ns: int, peak_ns: int, relax_ns: int, end_ns: int,
                   flexors: Mapping[str, float]) -> None:
        """Hold (or replace) a timed facial expression over the emotion (BML faceLexeme, faceFacs)."""
        self.expressions.set(expression_id, onset_ns, peak_ns, relax_ns, end_ns, flexors)

    def set_eyes(self, yaw_deg: float | None, pitch_deg: float | None, lid: float | None = None) -> None:
        """Gaze in degrees (yaw to the agent's right, pitch up; None = leave to the layers below) and lid
        closure in [0, 1] for both eyes (None = no blink layer). Angles beyond the eye's range clip."""
        look_x = self._degrees_to_flexor(yaw_deg, self.units.look_x_deg, "gaze yaw")
        look_y = self._degrees_to_flexor(pitch_deg, self.units.look_y_deg, "gaze pitch")
        if lid is None:
            closure = math.nan
        else:
            closure = check_flexor_value("blink_l", lid)
            if closure < 0:
                raise ValueError(f"lid closure must lie in [0, 1], got {lid!r}")
        self._gaze.hold((look_x, look_y))
        self._eyes_deg = None if yaw_deg is None or pitch_deg is None else (float(yaw_deg), float(pitch_deg))
        self._blink.hold((closure, closure))
        self._lid = 0.0 if lid is None else closure

    @staticmethod
    def _degrees_to_flexor(angle_deg: float | None, deg_per_unit: float, what: str) -> float:
        if angle_deg is None:
            return math.nan
        if not math.isfinite(angle_deg):
            raise ValueError(f"{what} must be a finite number of degrees, got {angle_deg!r}")
        return min(max(float(angle_deg) / deg_per_unit, -1.0), 1.0)  # plain floats: this runs every frame

    def set_mouth(self, weights: Mapping[str, float] | None) -> None:
        """Mouth-shape weights from lip-sync ({say_ah: 0.6, ...}); shapes not named are closed (0).
        None or {} hands the mouth back to the emotion."""
        vector = [math.nan] * len(MOUTH_FLEXORS)
        if weights:
            vector = [0.0] * len(MOUTH_FLEXORS)
            for name, value in weights.items():
                if name not in MOUTH_FLEXORS:
                    raise ValueError(f"unknown mouth shape {name!r}; mouth shapes: {', '.join(MOUTH_FLEXORS)}")
                vector[MOUTH_FLEXORS.index(name)] = check_flexor_value(name, value, "mouth")
        self._mouth.hold(vector)

    def set_mouth_row(self, row: np.ndarray | None) -> None:
        """set_mouth with the weights as a row in MOUTH_FLEXORS order, each already in [0, 1] (a live scene's
        lip-sync keys are clipped there when they come): what every frame of a speaking face does."""
        if row is not None and row.shape != (len(MOUTH_FLEXORS),):
            raise ValueError(f"a row of mouth weights has {len(MOUTH_FLEXORS)} values, got shape {row.shape}")
        self._mouth.hold_row(row)

    def frame_at(self, t_ns: int) -> FlexorFrame:
        return self.compositor.frame_at(t_ns)

    def compose(self, t_ns: int, role: str = "", eyes_hold_attention: bool = False) -> ComposedFace:
        """The composed face at t_ns (agent/face/composed.py): the flexor frame, and the head and eyes in
        degrees. The eyes are the gaze last set (set_eyes), unclipped.

        eyes_hold_attention: the gaze was aimed from the head turned toward the person attended (attend(),
        agent/gaze/situated.py), but the head shown differs from it: on its way there, and by what the other
        head layers add (an emotion's posture, a scripted move, a nod, idle noise). The eyes are then shown
        counter-rotated by that difference, within their range, so that eyes plus head point where the gaze
        model aims, as the vestibulo-ocular reflex holds a gaze (Freedman & Sparks 1997)."""
        frame = self.frame_at(t_ns)
        eyes = self._eyes_deg
        if eyes_hold_attention and eyes is not None:
            u = self.units
            values = frame.values.copy()
            offset = (self.attention.target[:2] - values[_HEAD]) * np.array([u.turn_deg, u.nod_deg])
            eye_range = np.array([u.look_x_deg, u.look_y_deg])
            yaw, pitch = np.clip(eyes + offset, -eye_range, eye_range)
            self.set_eyes(float(yaw), float(pitch), self._lid)
            # No layer above the gaze moves the eyes (agent/face/compositor.py), so the eyes made up for the
            # head replace those of the frame already composed: the head does not depend on them.
            values[_LOOK] = (yaw, pitch) / eye_range
            frame = FlexorFrame.composed(values, t_ns)
            eyes = (float(yaw), float(pitch))
        emotion, intensity = self._emotion
        return ComposedFace.from_frame(frame, self.units, None if eyes is None else EyeAngles(*eyes),
                                       lid=self._lid, role=role, emotion=emotion, emotion_intensity=intensity)

    def frame_at_s(self, t_s: float) -> FlexorFrame:
        return self.frame_at(nanoseconds(t_s))
