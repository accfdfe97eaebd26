"""The face's LLM tools (services/pipecat/tools.py): their schemas in pipecat's format, and their handlers
against real eca services (a face in a running pipeline on a private instance): applied commands come back
as applied, refused ones with eca's own reason. And the package's boundaries: without pipecat, importing it
says how to install it; nothing outside it imports pipecat.
"""

from __future__ import annotations

import asyncio
import re
import subprocess
import sys
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

pytest.importorskip("pipecat.frames.frames", reason="pipecat is not installed: pip install 'eca-face[pipecat]'")

from pipecat.adapters.llm.services.open_ai_adapter import OpenAILLMAdapter  # noqa: E402
from pipecat.frames.frames import EndFrame  # noqa: E402
from pipecat.pipeline.pipeline import Pipeline  # noqa: E402
from pipecat.pipeline.worker import PipelineWorker  # noqa: E402
from pipecat.workers.runner import WorkerRunner  # noqa: E402

from eca.agent.face.emotions import load_emotion_table  # noqa: E402
from eca.protocol.client import AgentClient  # noqa: E402
from eca.protocol.messages import ALL_AGENTS, AgentsState, EmotionState, HeadState  # noqa: E402
from eca.services.pipecat import EcaFaceParams, EcaTools, EcaVideoService  # noqa: E402
from eca.services.processes.dialogue import DialogueService  # noqa: E402
from eca.services.tools.child_processes import subprocess_env  # noqa: E402
from tests.support.bus import (  # noqa: E402
    REPO_ROOT,  # noqa: E402
    BrokerThread,
    ServiceThread,
    private_bus_config,
)

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")  # pipecat's own


def test_the_schemas_offer_the_known_emotions_and_the_head_axes_in_pipecats_format() -> None:
    tools = EcaTools(EcaVideoService(EcaFaceParams(video=False)))
    set_emotion, move_head = tools.schemas
    assert set_emotion.name == "set_emotion" and set_emotion.required == ["name"]
    assert set_emotion.properties["name"]["enum"] == list(load_emotion_table().names)
    assert {"happy", "surprised", "half-angry"} <= set(set_emotion.properties["name"]["enum"])
    assert set_emotion.properties["intensity"] == {**set_emotion.properties["intensity"], "type": "number",
                                                   "minimum": 0.0, "maximum": 1.0}
    assert move_head.name == "move_head" and move_head.required == []
    for axis in ("turn", "nod", "tilt"):
        assert move_head.properties[axis]["type"] == "number"
        assert (move_head.properties[axis]["minimum"], move_head.properties[axis]["maximum"]) == (-1.0, 1.0)
    # What an OpenAI model is given: standard function tools with JSON-schema parameters.
    given = OpenAILLMAdapter().to_provider_tools_format(tools.tools_schema())
    assert [t["function"]["name"] for t in given] == ["set_emotion", "move_head"]
    assert given[0]["type"] == "function"
    assert given[0]["function"]["parameters"]["properties"]["name"]["enum"] == list(load_emotion_table().names)


@asynccontextmanager
async def running(face: EcaVideoService) -> AsyncIterator[None]:
    """The face in a running pipeline until the block ends (then an EndFrame, and the pipeline's end)."""
    worker = PipelineWorker(Pipeline([face]), cancel_on_idle_timeout=False)
    started = asyncio.Event()

    @worker.event_handler("on_pipeline_started")
    async def on_started(worker: PipelineWorker, frame: Any) -> None:
        started.set()

    runner = WorkerRunner(handle_sigint=False)
    await runner.add_workers(worker)
    task = asyncio.create_task(runner.run())
    try:
        await asyncio.wait_for(started.wait(), 20.0)
        yield
    finally:
        await worker.queue_frame(EndFrame())
        await asyncio.wait_for(task, 20.0)


def test_the_handlers_apply_commands_and_return_ecas_reason_when_it_refuses() -> None:
    results: dict[str, dict[str, Any]] = {}

    async def calls(face: EcaVideoService) -> None:
        tools = EcaTools(face)
        async with running(face):
            async def handled(name: str, arguments: dict[str, Any]) -> dict[str, Any]:
                got: list[dict[str, Any]] = []

                async def result_callback(result: dict[str, Any], **_: Any) -> None:
                    got.append(result)

                # The handler as pipecat's LLM service calls it (only these fields of FunctionCallParams are read).
                await tools.handle(SimpleNamespace(function_name=name, arguments=arguments,  # type: ignore[arg-type]
                                                   result_callback=result_callback))
                assert len(got) == 1
                return got[0]

            results["happy"] = await handled("set_emotion", {"name": "happy", "intensity": 0.8})
            results["gleeful"] = await handled("set_emotion", {"name": "gleeful"})
            results["too_much"] = await handled("set_emotion", {"name": "happy", "intensity": 3})
            results["words"] = await handled("set_emotion", {"name": "happy", "intensity": "very"})
            results["no_name"] = await handled("set_emotion", {"intensity": 0.5})
            results["extra"] = await handled("set_emotion", {"name": "happy", "colour": "red"})
            results["head"] = await handled("move_head", {"turn": 0.5, "nod": -0.25})
            results["dance"] = await handled("dance", {})
        results["after"] = await tools.set_emotion("happy")

    with private_bus_config(services=["dialogue"]) as config, BrokerThread(config), \
            ServiceThread(DialogueService(config)), AgentClient(config) as client:
        face = EcaVideoService(EcaFaceParams(instance=config.instance, config_path=config.config_path, video=False))
        asyncio.run(calls(face))
        emotion = client.wait_for(lambda m: isinstance(m, EmotionState) and m.name == "happy", 5.0)
        head = client.wait_for(lambda m: isinstance(m, HeadState) and m.turn == 0.5, 5.0)
    assert results["happy"] == {"ok": True, "applied": "set_emotion", "emotion": "happy", "intensity": 0.8}
    assert isinstance(emotion, EmotionState) and emotion.intensity == 0.8
    assert results["gleeful"]["ok"] is False
    assert results["gleeful"]["error"].startswith("unknown emotion 'gleeful'; known: natural, happy")
    assert results["too_much"] == {"ok": False, "error": "field 'intensity': 3.0 is above the maximum 1.0"}
    assert results["words"] == {"ok": False, "error": "intensity must be a number, got 'very'"}
    assert results["no_name"] == {"ok": False, "error": "set_emotion needs a name"}
    assert "unknown argument(s): colour" in results["extra"]["error"]
    assert results["head"] == {"ok": True, "applied": "move_head", "turn": 0.5, "nod": -0.25, "tilt": 0.0}
    assert isinstance(head, HeadState) and (head.nod, head.tilt) == (-0.25, 0.0)
    assert results["dance"]["ok"] is False and "set_emotion, move_head" in results["dance"]["error"]
    assert results["after"] == {"ok": False, "error": f"{face} has ended: the pipeline is over", "retry": False}


def test_a_tool_called_before_the_pipeline_starts_waits_for_the_face() -> None:
    """A bot may call the tools at once (a greeting's emotion): the call waits for the face's connection, made
    when the pipeline starts, and is applied; one that the face cannot serve in time says to try again."""
    results: dict[str, dict[str, Any]] = {}

    async def calls(face: EcaVideoService, idle: EcaVideoService) -> None:
        tools = EcaTools(face)
        early = asyncio.create_task(tools.set_emotion("surprised", 0.6))
        await asyncio.sleep(0)  # the call is waiting before the pipeline exists
        assert not early.done()
        async with running(face):
            results["early"] = await asyncio.wait_for(early, 20.0)
        results["never"] = await EcaTools(idle).set_emotion("happy")  # its pipeline never starts

    with private_bus_config(services=["dialogue"]) as config, BrokerThread(config), \
            ServiceThread(DialogueService(config)), AgentClient(config) as client:
        face = EcaVideoService(EcaFaceParams(instance=config.instance, config_path=config.config_path, video=False))
        idle = EcaVideoService(EcaFaceParams(instance=config.instance, config_path=config.config_path, video=False,
                                             connect_timeout_s=0.2))
        asyncio.run(calls(face, idle))
        emotion = client.wait_for(lambda m: isinstance(m, EmotionState) and m.name == "surprised", 5.0)
    assert results["early"] == {"ok": True, "applied": "set_emotion", "emotion": "surprised", "intensity": 0.6}
    assert isinstance(emotion, EmotionState) and emotion.intensity == 0.6
    assert results["never"]["ok"] is False and results["never"]["retry"] is True
    assert "not connected to eca yet" in results["never"]["error"]


def test_bots_share_one_eca_each_with_an_agent_of_its_own() -> None:
    """Two bots' faces on one running eca, with `create_agent`: each makes its agent when it connects, its tools
    command only that one, and each agent goes when its pipeline ends."""
    results: dict[str, dict[str, Any]] = {}
    listed: dict[str, list[str]] = {}

    async def bots(first: EcaVideoService, second: EcaVideoService, client: AgentClient) -> None:
        async with running(first), running(second):
            listed["during"] = list(client.wait_for(lambda m: isinstance(m, AgentsState) and len(m.created) == 2,
                                                    10.0).agents)  # type: ignore[attr-defined]
            results["first"] = await EcaTools(first).set_emotion("happy", 0.7)
            results["second"] = await EcaTools(second).move_head(turn=-0.5)

    with private_bus_config(services=["dialogue"]) as config, BrokerThread(config), \
            ServiceThread(DialogueService(config)), AgentClient(config, agent=ALL_AGENTS) as client:
        client.sub.subscribe("state.bot-")
        faces = [EcaVideoService(EcaFaceParams(agent=name, instance=config.instance, config_path=config.config_path,
                                               video=False, create_agent=True)) for name in ("bot-1", "bot-2")]
        asyncio.run(bots(faces[0], faces[1], client))
        seen: list[Any] = []

        def noted(match: Callable[[Any], bool]) -> Callable[[Any], bool]:
            return lambda m: seen.append(m) is None and match(m)  # every message the client looks at is kept

        client.wait_for(noted(lambda m: isinstance(m, EmotionState) and m.agent == "bot-1" and m.name == "happy"), 5.0)
        client.wait_for(noted(lambda m: isinstance(m, HeadState) and m.agent == "bot-2" and m.turn == -0.5), 5.0)
        after = client.wait_for(noted(lambda m: isinstance(m, AgentsState) and not m.created), 10.0)
    assert listed["during"] == ["ada", "bot-1", "bot-2"]
    assert results["first"]["ok"] is True and results["second"]["ok"] is True, results
    assert isinstance(after, AgentsState) and after.agents == ["ada"]
    emotions = [m for m in seen if isinstance(m, EmotionState) and m.name == "happy"]
    heads = [m for m in seen if isinstance(m, HeadState) and m.turn == -0.5]
    assert {m.agent for m in emotions} <= {"bot-1"} and {m.agent for m in heads} <= {"bot-2"}


def test_without_pipecat_the_import_says_how_to_install_it() -> None:
    blocked = (
        "import sys\n"
        "class NoPipecat:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'pipecat' or name.startswith('pipecat.'):\n"
        "            raise ModuleNotFoundError(f'No module named {name!r}')\n"
        "sys.meta_path.insert(0, NoPipecat())\n"
        "import eca.protocol.client, eca.services.processes.web.service  # eca itself needs no pipecat\n"
        "try:\n"
        "    import eca.services.pipecat\n"
        "except ImportError as exc:\n"
        "    print('ImportError:', exc)\n"
    )
    done = subprocess.run([sys.executable, "-c", blocked], capture_output=True, text=True, env=subprocess_env(),
                          cwd=REPO_ROOT, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "ImportError:" in done.stdout and "pip install 'eca-face[pipecat]'" in done.stdout


def test_nothing_outside_the_package_imports_pipecat() -> None:
    importing = re.compile(r"^\s*(from|import)\s+pipecat\b", re.MULTILINE)
    package = REPO_ROOT / "eca"
    outside = [p for p in package.rglob("*.py") if Path("services", "pipecat") not in p.relative_to(package).parents
               and p.relative_to(package) != Path("pipecat.py")]
    assert outside and not [str(p) for p in outside if importing.search(p.read_text(encoding="utf-8"))]
