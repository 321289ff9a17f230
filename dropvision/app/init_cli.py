"""`dropvision init FOLDER`: write the sequence.json of a folder of images (`dropvision.io.describe`).

The library is imported when the command runs, so that ``dropvision --help`` stays fast.
"""

from __future__ import annotations

import argparse

from dropvision.app.options import (
    add_metadata_args, captured_warnings, overrides_from_args, print_warnings, warning_lines,
)


def _run(args: argparse.Namespace) -> int:
    from dropvision.io.describe import init_sequence

    overrides, labels = overrides_from_args(args)
    with captured_warnings() as caught:
        try:
            desc = init_sequence(args.folder, overrides, labels, overwrite=args.overwrite)
        finally:
            print_warnings("dropvision init", warning_lines(caught, args), args)
    if args.quiet:
        return 0
    print("\n".join(desc.lines))
    print(f"wrote {desc.folder / 'sequence.json'}"
          + ("" if not desc.to_give else "; the values marked TO GIVE are null in it"))
    if "pixel_size_um" not in desc.doc or desc.doc.get("pixel_size_um") is not None:
        print(f"next: dropvision measure {desc.folder} --out {desc.folder.name}-result")
    else:
        print(f"next: dropvision measure {desc.folder} --out {desc.folder.name}-result --pixel-size-um UM "
              "(or write pixel_size_um into the file)")
    return 0


def register(subparsers) -> None:
    """Add the ``init`` sub-command."""
    p = subparsers.add_parser("init", help="look at a folder of images and write its sequence.json")
    p.add_argument("folder", help="folder of images from a drop watcher or a camera")
    p.add_argument("--overwrite", action="store_true", help="replace an existing sequence.json (never without it)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    add_metadata_args(p)
    p.set_defaults(func=_run)
