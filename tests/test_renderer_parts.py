"""The renderer's parts on their own, as a second process would use them: the frame schedule on a virtual
clock, the bus-to-scene adapter fed messages, and outputs fed drawn frames (EGL)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from eca.agent.clock import VirtualClock
from eca.protocol.bus import Received, parse_frames
from eca.protocol.codec import encode
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import (
    ALL_AGENTS,
    AgentsState,
    ClockAnchor,
    EmotionState,
    EyesState,
    EyeStates,
    FaceFrame,
    HeadState,
    Message,
    RoleState,
    Saccade,
)
from eca.protocol.topics import topic_for
from eca.services.processes.renderer.options import RendererOptions
from eca.services.processes.renderer.outputs import DrawnFrame, OffscreenCanvas, SinkOutput
from eca.services.processes.renderer.service import RendererService
from eca.services.processes.renderer.video import PngWriter
from eca.services.processes.runtime import Service
from eca.services.processes.scene import bus_scene
from eca.services.processes.scene.bus_scene import KEEP_EYE_SAMPLES, BusScenes
from eca.services.processes.scene.schedule import FrameSchedule
from tests.support.bus import BrokerThread, private_bus_config

S = 1_000_000_000

# --- the frame schedule -------------------------------------------------------------------------


def test_slot_k_is_due_at_t0_plus_k_over_fps_and_composed_a_lead_later() -> None:
    clock = VirtualClock(5 * S)
    schedule = FrameSchedule(clock, 30.0, lead_s=0.008)
    assert [schedule.slot_ns(k) - 5 * S for k in (0, 1, 2, 30)] == [0, 33_333_333, 66_666_666, S]
    assert (schedule.slot, schedule.due_ns, schedule.display_ns) == (0, 5 * S, 5 * S + 8_000_000)
    clock.set_ns(schedule.due_ns)
    assert schedule.advance() == 0
    assert (schedule.slot, schedule.due_ns, schedule.dropped) == (1, 5 * S + 33_333_333, 0)
    # a fractional rate keeps exact time: 2997 slots at 29.97 fps are 100 s
    assert FrameSchedule(VirtualClock(), 29.97).slot_ns(2997) == 100 * S


def test_slots_on_the_clocks_own_grid_start_at_the_first_at_or_after_now() -> None:
    clock = VirtualClock(7 * S + 10_000_000)  # between two slots of a 30 fps grid from 0
    schedule = FrameSchedule(clock, 30.0, t0_ns=0)
    assert schedule.due_ns == 7 * S + 33_333_333 and schedule.slot == 211
    clock.set_ns(8 * S - 5_000_000)
    assert schedule.advance() == 27  # skipped 212..238, on to slot 239: the one at or before now (8 s is 240)
    assert schedule.due_ns == schedule.slot_ns(239) and schedule.slot_ns(240) == 8 * S  # whole seconds are slots
    assert FrameSchedule(VirtualClock(4 * S), 30.0, t0_ns=0).due_ns == 4 * S  # on a slot: that one


def test_a_slot_the_loop_could_not_reach_in_time_is_skipped_and_counted() -> None:
    clock = VirtualClock()
    moved: list[int] = []
    schedule = FrameSchedule(clock, 10.0, on_advance=moved.append)
    clock.set_ns(schedule.due_ns)
    schedule.advance()  # slot 0 drawn on time
    # drawing slot 1 took until 3.5 periods: slot 2's time has passed, slot 3 is the one to draw now
    clock.set_ns(350_000_000)
    assert schedule.advance() == 1
    assert (schedule.slot, schedule.dropped) == (3, 1)
    clock.set_ns(schedule.due_ns + 99_000_000)  # late, but still within slot 3: nothing more skipped
    assert schedule.advance() == 0
    assert (schedule.slot, schedule.dropped, moved) == (4, 1, [1, 2, 1])


def test_a_slot_drawn_early_for_a_change_keeps_the_schedules_rate() -> None:
    clock = VirtualClock()
    schedule = FrameSchedule(clock, 30.0)  # slots at 0, 33.3, 66.7, ... ms
    period = schedule.period_ns
    clock.set_ns(schedule.due_ns)
    schedule.advance()  # slot 0 drawn on time
    # a change 2 ms after a frame waits for a quarter period after it; one at 20 ms is drawn at once
    assert schedule.early_due_ns(0, 0.25) == period // 4
    assert max(20_000_000, schedule.early_due_ns(0, 0.25)) == 20_000_000
    # the slot is never later than its own time, whatever the gap asked
    assert schedule.early_due_ns(0, 2.0) == schedule.due_ns
    # a flood of changes: every slot drawn as early as allowed
    frames = [0]
    while len(frames) < 31:
        clock.set_ns(max(clock.now_ns(), schedule.early_due_ns(frames[-1], 0.25)))
        frames.append(clock.now_ns())
        assert schedule.advance() == 0  # drawing early skips nothing
    assert np.diff(frames).min() >= period // 4
    # slot k drawn no sooner than slot k - 1's time: one frame a period, 31 frames in (almost) a second
    assert frames[-1] >= schedule.slot_ns(29)
    assert schedule.slot == 31 and schedule.dropped == 0


def test_a_total_number_of_slots_ends_the_schedule() -> None:
    clock = VirtualClock()
    moved: list[int] = []
    schedule = FrameSchedule(clock, 10.0, total=5, on_advance=moved.append)
    for _ in range(2):
        clock.set_ns(schedule.due_ns)
        schedule.advance()
        assert not schedule.finished
    clock.set_ns(2 * S)  # far behind: the schedule ends at its last slot, not past it
    schedule.advance()
    assert schedule.finished and schedule.slot == 5
    assert sum(moved) == 5  # a progress bar reaches its total exactly
    assert schedule.dropped == 17  # the slots skipped are counted all the same
    assert FrameSchedule(clock, 10.0).finished is False  # no total: it runs until stopped


# --- the bus-to-scene adapter (no GL) ------------------------------------------------------------


class RecordingService(Service):
    """A bare service that remembers each message it was handed to dispatch."""

    name = "parts"

    def __init__(self, config: BusConfig) -> None:
        super().__init__(config)
        self.dispatched: list[Message] = []

    def dispatch(self, got: Received) -> None:
        assert got.message is not None, got.error
        self.dispatched.append(got.message)
        super().dispatch(got)


class QueuedFrames:
    """A subscriber double: the frames waiting on the socket, read and decoded as the real one does."""

    def __init__(self, messages: list[Message]) -> None:
        self.waiting = [[topic_for(m).encode(), encode(m)] for m in messages]

    def read_frames(self, limit: int) -> list[list[bytes]]:
        taken, self.waiting = self.waiting[:limit], self.waiting[limit:]
        return taken

    def accept(self, frames: list[bytes]) -> Received:
        return parse_frames(frames)


@pytest.fixture
def config() -> Iterator[BusConfig]:
    with private_bus_config(agents=["ada", "bob"]) as config:
        yield config


def deliver(svc: Service, *messages: Message) -> None:
    for m in messages:
        svc.dispatch(Received(topic_for(m), m))


def eyes(t_ns: int, yaws: dict[str, float], mode: str = "noise") -> EyeStates:
    """A gaze tick's eye states: these agents' eyes at these yaws."""
    n = len(yaws)
    return EyeStates(agent=ALL_AGENTS, agents=list(yaws), yaw_deg=list(yaws.values()), pitch_deg=[0.0] * n,
                     lid=[0.0] * n, mode=[mode] * n, t_ns=t_ns)  # type: ignore[list-item]


def test_states_reach_each_agents_scene(config: BusConfig) -> None:
    svc = RecordingService(config)
    scenes = BusScenes(svc, ["ada", "bob"], idle_noise=False)
    ada, bob = (v.scene for v in scenes.views)
    deliver(svc,
            EmotionState(agent="bob", name="angry", intensity=0.5, transition_s=0.0, t_ns=S),
            RoleState(agent="ada", role="talking", speaker="ada", t_ns=S),
            HeadState(agent="ada", turn=0.4, nod=0.0, tilt=0.1, duration_s=0.0, t_ns=S),
            EyesState(agent="bob", mode="static", t_ns=S),
            Saccade(agent="ada", onset_ns=2 * S, from_yaw_deg=0.0, from_pitch_deg=0.0, to_yaw_deg=10.0,
                    to_pitch_deg=0.0, amplitude_deg=10.0, direction_deg=0.0, duration_s=0.05, kind="away", t_ns=S))
    assert (bob.emotion, bob.eye_mode, ada.emotion) == (("angry", 0.5), "static", ("natural", 1.0))
    assert (ada.role, ada.head, bob.role) == ("talking", (0.4, 0.0, 0.1), "listening")
    assert ada.frame_at(3 * S).values.any() and sum(svc.bad_messages.values()) == 0
    events = [f"event.{{}}.{t}" for t in ("nod", "head_gesture", "expression", "saccade", "speech_started",
                                          "speech_finished", "speech_interrupted", "speech_failed")]
    assert scenes.subscriptions() == [
        "stream.*.eye_states",
        "state.ada.", *(e.format("ada") for e in events), "stream.ada.clock_anchor", "stream.ada.mouth",
        "state.bob.", *(e.format("bob") for e in events), "stream.bob.clock_anchor", "stream.bob.mouth",
    ]


def test_every_message_a_scene_handles_is_subscribed_and_acknowledgements_are_not(config: BusConfig) -> None:
    """A scene subscribes to the events it handles one by one: an acknowledgement, one per command, does not reach
    a drawer (a flood of commands acknowledged would), and no handled message is left out."""
    svc = RecordingService(config)
    scenes = BusScenes(svc, ["ada"], idle_noise=False, follow=True)
    subs = scenes.subscriptions()
    assert set(bus_scene.HANDLERS) <= set(svc._handlers)
    for cls in bus_scene.HANDLERS:
        topic = f"{cls.CATEGORY}.{'*' if cls in (EyeStates, AgentsState) else 'ada'}.{cls.TYPE}"
        assert any(topic.startswith(p) for p in subs), (topic, subs)
    assert not any("event.ada.ack".startswith(p) for p in subs)


def test_a_tick_of_eye_states_reaches_each_drawn_agent_and_passes_the_others_by(config: BusConfig) -> None:
    svc = RecordingService(config)
    scenes = BusScenes(svc, ["ada", "bob"], idle_noise=False)
    ada, bob = (v.scene for v in scenes.views)
    deliver(svc, eyes(S, {"zed": 3.0, "bob": 0.0, "ada": 0.0}, mode="static"))
    assert (ada.eye_mode, bob.eye_mode) == ("static", "static")
    assert svc.bad_messages == {}  # zed is drawn elsewhere: its eyes are not news here, nor an error
    deliver(svc, eyes(2 * S, {"bob": 0.0}, mode="saccade"))  # a reaction's: the agent it concerns only
    assert (ada.eye_mode, bob.eye_mode) == ("static", "saccade")


def test_what_the_scenes_refuse_is_rejected_through_the_service(config: BusConfig) -> None:
    svc = RecordingService(config)
    scenes = BusScenes(svc, ["ada"], idle_noise=False)
    deliver(svc, EmotionState(agent="bob", name="angry", intensity=1.0, transition_s=0.0, t_ns=S))
    assert svc.bad_messages == {"rejected": 1}  # bob is not drawn here
    assert scenes.views[0].scene.emotion == ("natural", 1.0)
    anchor = ClockAnchor(agent="ada", request_id="u1", sample_index=0, sample_rate=16_000, dac_time_ns=S)
    deliver(svc, anchor, ClockAnchor(agent="ada", request_id="u1", sample_index=160, sample_rate=48_000,
                                     dac_time_ns=S + 10_000_000))
    assert svc.bad_messages == {"rejected": 2}  # a value the scene refuses (a changed sample rate)


def test_a_drain_decodes_the_newest_state_per_topic_and_eye_state_ticks(config: BusConfig) -> None:
    svc = RecordingService(config)
    scenes = BusScenes(svc, ["ada", "bob"], idle_noise=False)
    emotions = [EmotionState(agent="ada", name=n, intensity=1.0, transition_s=0.0, t_ns=S + i)
                for i, n in enumerate(("happy", "sad", "angry"))]
    ticks = [eyes(S + k * 1_000_000, {"ada": float(k), "bob": -float(k)}) for k in range(KEEP_EYE_SAMPLES + 3)]
    head = HeadState(agent="bob", turn=0.2, nod=0.0, tilt=0.0, duration_s=0.0, t_ns=S)
    batch: list[Message] = [emotions[0], *ticks[:4], head, emotions[1], *ticks[4:], emotions[2]]
    svc.sub = QueuedFrames(batch)  # type: ignore[assignment]
    assert scenes.drain() == len(batch)
    # the older emotions and all but the newest eye-state ticks were skipped undecoded, and counted
    assert svc.coalesced == 2 + 3
    assert svc.dispatched == [ticks[3], head, *ticks[4:], emotions[2]]  # in order
    assert scenes.views[0].scene.emotion == ("angry", 1.0) and scenes.views[1].scene.head == (0.2, 0.0, 0.0)
    assert scenes.drain() == 0 and svc.coalesced == 5


def test_a_drain_reads_a_bounded_number_of_messages_per_frame(config: BusConfig,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bus_scene, "MAX_READ_PER_FRAME", 3)
    svc = RecordingService(config)
    scenes = BusScenes(svc, ["ada"], idle_noise=False)
    saccades = [Saccade(agent="ada", onset_ns=S * k, from_yaw_deg=0.0, from_pitch_deg=0.0, to_yaw_deg=5.0,
                        to_pitch_deg=0.0, amplitude_deg=5.0, direction_deg=0.0, duration_s=0.03, kind="away",
                        t_ns=S) for k in range(1, 6)]
    svc.sub = QueuedFrames(saccades)  # type: ignore[assignment]
    assert scenes.drain() == 3 and svc.dispatched == saccades[:3]
    assert scenes.drain() == 2 and svc.dispatched == saccades  # the rest waited for the next frame, in order
    assert svc.coalesced == 0  # events are never coalesced


# --- outputs (EGL) -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def egl() -> None:
    from eca.services.processes.renderer import create_headless_context

    try:
        create_headless_context().release()
    except Exception as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL here: {exc}")


class RecordingOutput:
    """An output test double: what it was handed, through the interface alone."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, int, np.ndarray]] = []
        self.closed = 0

    def present(self, frame: DrawnFrame) -> None:
        self.frames.append((frame.index, frame.display_ns, frame.rgb()))

    def close(self) -> None:
        self.closed += 1


class PublishedFrames(RendererService):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.face_frames: list[FaceFrame] = []

    def publish(self, msg: Message, category: str | None = None) -> Message:
        if isinstance(msg, FaceFrame):
            self.face_frames.append(msg)
        return super().publish(msg, category)


@pytest.mark.gl
def test_every_output_gets_each_drawn_frame_with_its_slot_and_display_time(egl: None, tmp_path: Path) -> None:
    with private_bus_config() as config, BrokerThread(config):
        clock = VirtualClock(7 * S)
        opts = RendererOptions(mode="headless", fps=20.0, size=(64, 48), idle_noise=False, progress=False,
                               agents=("ada",), frames=8, lead_s=0.005, png_dir=str(tmp_path))
        svc = PublishedFrames(config, opts, clock=clock)
        first, second = RecordingOutput(), RecordingOutput()
        try:
            svc.connect()
            svc.outputs += [first, second]  # added beside the PNG output, the loop untouched
            assert svc.schedule is not None
            # the loop wakes for slot 3 only at 5.2 periods: it draws slot 3, then skips to slot 5
            steps = iter([50_000_000, 50_000_000, 160_000_000])
            while not svc.stopping:
                svc.run_once()
                clock.advance_ns(next(steps, 50_000_000))
        finally:
            svc.teardown()
            svc.close()
        schedule = svc.schedule
        indices = [i for i, _, _ in first.frames]
        assert indices == [0, 1, 2, 3, 5, 6, 7] and schedule.dropped == svc.dropped == 1
        assert [t for _, t, _ in first.frames] == [schedule.slot_ns(i) + 5_000_000 for i in indices]
        assert [t for _, t, _ in first.frames] == [f.frame_ns for f in svc.face_frames]
        assert (first.closed, second.closed) == (1, 1)
        for (i, _, rgb), (_, _, same) in zip(first.frames, second.frames, strict=True):
            assert same is rgb  # read back from the GPU once per frame, whatever the number of outputs
            assert rgb.shape == (48, 64, 3) and rgb.std() > 10
            assert np.array_equal(np.asarray(Image.open(tmp_path / f"frame_{i:06d}.png")), rgb)
        assert len(list(tmp_path.glob("*.png"))) == len(indices)


@pytest.mark.gl
def test_the_parts_draw_a_face_for_a_service_of_their_own(egl: None, tmp_path: Path) -> None:
    # The web service's way: its own scenes, schedule, stage and outputs, no renderer service.
    from eca.services.processes.renderer import Stage, make_drawer

    with private_bus_config(agents=["ada", "bob"]) as config:
        svc = Service(config)
        scenes = BusScenes(svc, ["ada", "bob"], idle_noise=False)
        deliver(svc, EmotionState(agent="bob", name="surprised", intensity=1.0, transition_s=0.0, t_ns=0))
        clock = VirtualClock()
        canvas = OffscreenCanvas((128, 48))
        try:
            stage = Stage(make_drawer(canvas.ctx, (128, 48)), scenes.views, fps=10.0)
            schedule = FrameSchedule(clock, 10.0, total=3)
            output = SinkOutput(PngWriter(tmp_path))
            while not schedule.finished:
                clock.set_ns(schedule.due_ns)
                frames = stage.compose(schedule.display_ns)
                stage.draw(frames, canvas.screen)
                output.present(DrawnFrame(canvas.screen, schedule.slot, schedule.display_ns))
                schedule.advance()
            output.close()
        finally:
            canvas.close()
    assert [v.face is not None for v in scenes.views] == [True, True]
    written = sorted(tmp_path.glob("frame_*.png"))
    assert [p.name for p in written] == ["frame_000000.png", "frame_000001.png", "frame_000002.png"]
    img = np.asarray(Image.open(written[-1])).astype(float)
    left, right = img[:, :64], img[:, 64:]
    assert left.std() > 10 and right.std() > 10  # a face in each half
    assert np.abs(left - right[:, ::-1]).mean() > 1  # two agents, each its own expression


@pytest.mark.gl
def test_the_face_as_yuv420p_from_the_gpu_matches_swscale_and_its_layout(egl: None) -> None:
    import av
    import moderngl

    from eca.agent.face.model import FaceModel
    from eca.services.processes.renderer import create_headless_context, read_rgb
    from eca.services.processes.renderer.renderer import Renderer
    from eca.services.processes.renderer.yuv import YuvTarget

    ctx = create_headless_context()
    try:
        target = YuvTarget(ctx, (160, 120))
        model = FaceModel(seed=3)
        model.set_emotion("surprised", 1.0, t_ns=0)
        Renderer(ctx, (160, 120)).render(model.frame_at(S).values, target=target.fbo)
        face = target.read()
        rgb = read_rgb(target.fbo)
        # a picture of known colours: the top half red, the bottom left quarter blue, the rest white
        target.fbo.use()
        target.fbo.clear(1.0, 1.0, 1.0, 1.0)
        target.fbo.scissor = (0, 0, 80, 60)  # GL rows run bottom up: the bottom left quarter
        target.fbo.clear(0.0, 0.0, 1.0, 1.0)
        target.fbo.scissor = (0, 60, 160, 60)
        target.fbo.clear(1.0, 0.0, 0.0, 1.0)
        target.fbo.scissor = None
        ctx.disable(moderngl.BLEND)
        blocks = target.read()
        with pytest.raises(ValueError, match="even width and height"):
            YuvTarget(ctx, (161, 120))
        target.release()
    finally:
        ctx.release()
    assert face.shape == (180, 160) and face.dtype == np.uint8
    sws = av.VideoFrame.from_ndarray(rgb, format="rgb24").reformat(format="yuv420p").to_ndarray()
    diff = np.abs(face.astype(int) - sws.astype(int))
    assert diff[:120].max() <= 1  # luma: the same BT.601 limited-range values
    assert diff[120:].mean() < 0.5 and diff[120:].max() <= 12  # chroma: both 2x2 means, filters differ at edges
    y = blocks[:120]
    u = blocks[120:150].reshape(60, 80)  # each chroma plane (h/2, w/2), packed two rows to a row
    v = blocks[150:].reshape(60, 80)
    assert (y[:60] == 81).all() and (y[60:, 80:] == 235).all() and (y[60:, :80] == 41).all()  # red, white, blue
    assert (u[:30] == 90).all() and (v[:30] == 240).all()  # red
    assert (u[30:, 40:] == 128).all() and (v[30:, 40:] == 128).all()  # white
    assert (u[30:, :40] == 240).all() and (v[30:, :40] == 110).all()  # blue
