"""`eca warm-up`: compile the face's drawing code now, so that no first start pays for it."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("warm-up", help="compile the face's drawing code now (else the first face drawn does)",
                       description="The renderer's per-frame code is compiled with numba on first use and cached "
                       "beside the installed package. Run this once after installing (setup does) so that no "
                       "window, video, web page or pipecat bot waits for the compile.")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from eca.services.processes.renderer.kernels import warm_up  # numba loads only here

    print(f"eca warm-up: the face's drawing code is ready ({warm_up():.1f} s)")
    return 0
