"""LLM tools that let the bot's model drive the face: `set_emotion(name, intensity)` and
`move_head(turn, nod, tilt)`, as pipecat function schemas with handlers that send the command on eca's
bus and return what happened to the model.

    face = EcaVideoService(EcaFaceParams(start_eca=True))
    tools = EcaTools(face)
    context = LLMContext(messages, tools=tools.tools_schema())   # the schemas carry their handler
    # or, for an LLM service that wants them registered by name: tools.register(llm)

A call's result is a small JSON object for the model: `{"ok": true, ...the values applied}` once eca's
dialogue service acknowledged the command, or `{"ok": false, "error": "<the reason>"}`: eca's own
reason when it refused it (an unknown emotion lists the known ones, so the model can correct itself),
the codec's when an argument is out of range, or a timeout's. The emotion names are those of
configs/emotions.toml (the schema lists them as an enum).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from pipecat.adapters.llm.schemas.function_schema import FunctionSchema
from pipecat.adapters.llm.schemas.tools_schema import ToolsSchema

from eca.agent.face.emotions import load_emotion_table
from eca.protocol.codec import ProtocolError
from eca.protocol.messages import Ack, Error, Message, MoveHead, SetEmotion
from eca.services.pipecat.face import FaceNotReady

if TYPE_CHECKING:
    from pipecat.services.llm_service import FunctionCallParams

    from eca.services.pipecat.face import EcaVideoService

SET_EMOTION = "set_emotion"
MOVE_HEAD = "move_head"


def emotion_names() -> tuple[str, ...]:
    """The emotions the face knows (configs/emotions.toml)."""
    return tuple(load_emotion_table().names)


def set_emotion_schema(names: Sequence[str], handler: Any = None) -> FunctionSchema:
    """The `set_emotion(name, intensity)` schema offering `names`, with `handler` attached."""
    return FunctionSchema(
        name=SET_EMOTION,
        description=("Change the facial expression of your avatar to show how you feel. Use it when the "
                     "conversation gives you a reason to (good news: happy; a surprise: surprised)."),
        properties={
            "name": {"type": "string", "enum": list(names), "description": "the emotion to show"},
            "intensity": {"type": "number", "minimum": 0.0, "maximum": 1.0,
                          "description": "how strongly: 0 = neutral, 1 = the full expression (default 1)"},
        },
        required=["name"],
        handler=handler,
    )


def move_head_schema(handler: Any = None) -> FunctionSchema:
    """The `move_head(turn, nod, tilt)` schema, with `handler` attached."""
    axis = {"type": "number", "minimum": -1.0, "maximum": 1.0}
    return FunctionSchema(
        name=MOVE_HEAD,
        description=("Move your avatar's head: turn (left -1 .. right +1), nod (down -1 .. up +1), tilt "
                     "(toward the left shoulder -1 .. right +1). 0, 0, 0 looks straight ahead."),
        properties={
            "turn": {**axis, "description": "yaw, + = your right"},
            "nod": {**axis, "description": "pitch, + = chin up"},
            "tilt": {**axis, "description": "roll, + = toward your right shoulder"},
        },
        required=[],
        handler=handler,
    )


class EcaTools:
    """The face's tools for one `EcaVideoService`: `set_emotion` and `move_head` for the bot's model.

    The tools may be called at any time, also before the pipeline has started: a call waits until the face
    is connected to eca (`EcaVideoService.wait_connected`, at most `ready_timeout_s`), then sends the command
    and waits for eca's acknowledgement. A call that cannot be made answers `{"ok": false, "error": ...,
    "retry": true}` while the face is still connecting (the model may call again) and `"retry": false` once
    the face has failed or ended."""

    def __init__(self, face: EcaVideoService, emotions: Sequence[str] | None = None) -> None:
        """`face`: the processor whose agent the tools drive; `emotions`: the names offered to the model
        (default: every emotion of the face's table)."""
        self.face = face
        self.emotions = tuple(emotions) if emotions is not None else emotion_names()
        self.schemas = [set_emotion_schema(self.emotions, self.handle), move_head_schema(self.handle)]

    def tools_schema(self) -> ToolsSchema:
        """The tools for an `LLMContext(messages, tools=...)`; each schema carries its handler."""
        return ToolsSchema(standard_tools=self.schemas)

    def register(self, llm: Any) -> None:
        """Register the handlers with an LLM service by function name (pipecat's `register_function`)."""
        for schema in self.schemas:
            llm.register_function(schema.name, self.handle)

    async def handle(self, params: FunctionCallParams) -> None:
        """pipecat's function-call handler: run the call, give the model its result."""
        await params.result_callback(await self.call(params.function_name, params.arguments))

    async def call(self, name: str, arguments: Mapping[str, Any] | None) -> dict[str, Any]:
        """Run tool `name` with the model's `arguments`; never raises for what the model sent."""
        args = dict(arguments or {})
        if name == SET_EMOTION:
            known = {"name", "intensity"}
        elif name == MOVE_HEAD:
            known = {"turn", "nod", "tilt"}
        else:
            return _failed(f"unknown tool {name!r}; the face's tools: {SET_EMOTION}, {MOVE_HEAD}")
        unknown = sorted(set(args) - known)
        if unknown:
            return _failed(f"{name} takes {', '.join(sorted(known))}; unknown argument(s): {', '.join(unknown)}")
        try:
            if name == SET_EMOTION:
                if "name" not in args:
                    return _failed("set_emotion needs a name")
                return await self.set_emotion(args["name"], args.get("intensity", 1.0))
            return await self.move_head(args.get("turn", 0.0), args.get("nod", 0.0), args.get("tilt", 0.0))
        except (TypeError, ValueError) as exc:
            return _failed(str(exc))

    async def set_emotion(self, name: str, intensity: float = 1.0, transition_s: float = 0.5) -> dict[str, Any]:
        """Show emotion `name` at `intensity` (0..1), blending over `transition_s`; the result for the model.
        TypeError for a name or intensity that is not a string or a number."""
        if not isinstance(name, str):
            raise TypeError(f"name must be a string (one of {', '.join(self.emotions)}), got {name!r}")
        intensity = _number("intensity", intensity)
        result = await self._send(SetEmotion(agent=self.face.params.agent, name=name, intensity=intensity,
                                             transition_s=transition_s))
        if result.get("ok"):
            result.update(emotion=name, intensity=intensity)
        return result

    async def move_head(self, turn: float = 0.0, nod: float = 0.0, tilt: float = 0.0,
                        duration_s: float = 0.5) -> dict[str, Any]:
        """Turn, nod and tilt the head (each -1..1) over `duration_s`; the result for the model. TypeError for
        a value that is not a number."""
        values = {"turn": _number("turn", turn), "nod": _number("nod", nod), "tilt": _number("tilt", tilt)}
        result = await self._send(MoveHead(agent=self.face.params.agent, duration_s=duration_s, **values))
        if result.get("ok"):
            result.update(values)
        return result

    async def _send(self, msg: Message) -> dict[str, Any]:
        try:
            answer = await self.face.command(msg)
        except ProtocolError as exc:  # out of range, too long: the codec names the field
            return _failed(str(exc))
        except FaceNotReady as exc:  # not connected yet (retry), or no more
            return {**_failed(str(exc)), "retry": exc.retry}
        if isinstance(answer, Ack):
            return {"ok": True, "applied": msg.TYPE}
        if isinstance(answer, Error):
            return _failed(answer.reason)
        return _failed(f"eca did not acknowledge {msg.TYPE} within {self.face.params.command_timeout_s:g} s")


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise TypeError(f"{name} must be a number, got {value!r}")
    return float(value)


def _failed(reason: str) -> dict[str, Any]:
    return {"ok": False, "error": reason}
