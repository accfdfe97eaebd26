"""`eca up`: start the broker and the services, watch them, stop them all on Ctrl-C."""

from __future__ import annotations

import argparse
import sys

from eca.protocol.endpoints import BusConfig, BusConfigError, load_bus_config
from eca.services.processes.realtime import realtime_settings
from eca.services.processes.rig.options import add_arguments as add_rig_arguments
from eca.services.processes.run import KNOWN
from eca.services.processes.web.options import add_arguments as add_web_arguments
from eca.services.processes.web.options import worker_of, worker_service_name
from eca.services.tools import cli_args
from eca.services.tools.up import choose_services, run_up


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("up", help="run the broker and the services of one instance")
    p.add_argument("--config", default=None, help="runtime config (default configs/default.toml)")
    p.add_argument("--instance", default=None, help="bus instance name (default from the config)")
    p.add_argument("--only", action="append", default=[], metavar="SERVICE", help="start only these")
    p.add_argument("--without", action="append", default=[], metavar="SERVICE", help="do not start these")
    p.add_argument("--quiet", action="store_true", help="no periodic bus summary")
    p.add_argument("--seconds", type=cli_args.seconds, default=None, help="stop by itself after this long")
    p.add_argument("--face", default=None, metavar="FACE",
                   help="every agent's face in the window, video and web page: flexor (the paper's 2D face), head "
                        "(eca's 3D head) or a .glb/.gltf/.vrm file (default: the config's [faces], else flexor)")
    p.add_argument("--silent-audio", action="store_true",
                   help="open no sound card: the voice is heard elsewhere (a pipecat transport, the web page)")
    face = p.add_argument_group("renderer", "passed to the renderer (it picks a window where a display exists)")
    face.add_argument("--headless", action="store_true", help="render offscreen (EGL) even where a display exists")
    face.add_argument("--window", action="store_true", help="require a window (fail without a display)")
    face.add_argument("--video", default=None, metavar="PATH", help="headless: write the face as an H.264 MP4")
    face.add_argument("--png", default=None, metavar="DIR", help="headless: write PNG frames")
    face.add_argument("--size", default=None, metavar="WxH", help="window or image size")
    face.add_argument("--fps", type=float, default=None, help="frames per second")
    face.add_argument("--view", choices=("full", "upper"), default=None, help="full face or upper face only")
    p.add_argument("--bml", action="store_true",
                   help="also start the BML realizer: BML 1.0 blocks on cmd.<agent>.bml, feedback on "
                        "event.<agent>.bml_feedback (docs/bml.md)")
    web = p.add_argument_group("web", "the web front-end: the agents in a browser over WebRTC")
    web.add_argument("--web", action="store_true", help="also serve the agents to browsers (the web service)")
    add_web_arguments(web)
    rig = p.add_argument_group("rig", "the rig service: the agents' faces as ARKit/VRM weights and head and eye angles "
                                      "for avatar programs (any --rig-... option starts it)")
    rig.add_argument("--rig", action="store_true", help="also start the rig service (on the bus only, unless sent on)")
    add_rig_arguments(rig, prefix="rig-")
    p.set_defaults(func=run)


def renderer_args(args: argparse.Namespace) -> list[str]:
    """The renderer's command-line arguments among `eca up`'s."""
    argv = [f"--{flag}" for flag in ("headless", "window") if getattr(args, flag)]
    for name in ("video", "png", "size", "fps", "view"):
        value = getattr(args, name)
        if value is not None:
            argv += [f"--{name}", str(value)]
    return argv


def web_args(args: argparse.Namespace) -> list[str]:
    """The web service's command-line arguments among `eca up`'s."""
    argv = []
    for name in ("web_host", "web_port", "web_token", "web_token_file", "web_face", "web_draw", "web_sfu",
                 "web_workers"):
        value = getattr(args, name)
        if value is not None:
            argv += [f"--{name.replace('_', '-')}", str(value)]
    if getattr(args, "per_visitor", None):
        argv.append("--per-visitor")
    return argv


def rig_args(args: argparse.Namespace, config: BusConfig, services: list[str]) -> list[str]:
    """The rig service's command-line arguments among `eca up`'s, checked (the receivers' hosts resolved) before
    anything starts; the rig service joins `services` when asked for. A bad option raises RigOptionsError."""
    from eca.services.processes.rig.options import argv_from, flag_names, given, options_from, plan

    cli = given(args, prefix="rig_")
    if not (args.rig or cli or "rig" in services):
        return []
    if "rig" in args.without:
        raise ValueError("rig options given, but --without rig")
    options = options_from(dict(config.raw.get("rig", {})), cli, prefix="rig-")
    plan(options, config.agents, flag_names(cli, "rig-", f"{config.config_path} [rig]"))  # bad ones fail here
    if "rig" not in services:
        services.append("rig")
    return argv_from(cli)


def run(args: argparse.Namespace) -> int:
    face_argv = renderer_args(args)
    site_argv = web_args(args)
    try:
        config = load_bus_config(args.config, args.instance)
        realtime_settings(config, KNOWN)  # bad ones fail here, not in each service as it starts
        services = choose_services(config, args.only, args.without)
        if site_argv and not args.web:
            raise ValueError(f"web options ({' '.join(site_argv)}) given without --web")
        if args.web:
            from eca.services.processes.web.options import options_from as web_options_from

            parser = argparse.ArgumentParser(add_help=False)
            add_web_arguments(parser)
            # bad ones fail here, before anything starts
            web_options = web_options_from(dict(config.raw.get("web", {})), parser.parse_args(site_argv))
            if "web" not in services:
                services.append("web")
            web_workers = [worker_service_name(i) for i in range(2, web_options.workers + 1)]
            services += [w for w in web_workers if w not in services]
            from eca.services.processes.renderer.display import display_available  # no GL library: the env

            if not face_argv and "renderer" in services and not display_available():
                services.remove("renderer")  # headless, the page is the face: no second drawing loop
        if args.bml and "bml" not in services:
            services.append("bml")
        rig_argv = rig_args(args, config, services)
        if args.face is not None or config.raw.get("faces"):
            from eca.services.processes.renderer.faces import agent_faces  # no GL or drawing code: names only

            agent_faces(config.raw, config.agents, args.face, f"{config.config_path} [faces]")  # bad ones fail here
        if args.face is not None:
            face_argv = [*face_argv, "--face", args.face] if "renderer" in services else face_argv
            site_argv = [*site_argv, "--web-face", args.face] if "web" in services else site_argv
        if face_argv:
            if "renderer" not in services:
                raise ValueError(f"renderer options ({' '.join(face_argv)}) given, but the renderer is not started")
            from eca.services.processes.renderer.options import options_from  # no GL, video or drawing code

            options_from(config, face_argv)  # bad options fail here, before anything starts
    except (BusConfigError, ValueError) as exc:  # a WebOptionsError or RigOptionsError too
        print(f"eca up: {exc}", file=sys.stderr)
        return 2
    extra_args = {"renderer": face_argv, "web": site_argv, "rig": rig_argv,
                  "audio": ["--silent"] if args.silent_audio else []}
    extra_args |= {name: site_argv for name in services if name != "web" and worker_of(name) is not None}
    return run_up(config, services, view=not args.quiet, duration_s=args.seconds, extra_args=extra_args)
