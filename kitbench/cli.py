"""The `kitbench` command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _doctor(args) -> int:
    from kitbench.doctor import run_doctor

    return run_doctor()


def _demo(args) -> int:
    from kitbench.demo import render_task_frames

    paths = render_task_frames(Path(args.out), seed=args.seed)
    print("rendered:")
    for p in paths:
        print(f"  {p}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="kitbench", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    doctor = sub.add_parser("doctor", help="check Python, packages, the Vulkan device and video decoding")
    doctor.set_defaults(func=_doctor)
    demo = sub.add_parser("demo", help="render each task's scene to PNG files")
    demo.add_argument("--out", default="outputs/demo", help="output folder (default: outputs/demo)")
    demo.add_argument("--seed", type=int, default=0)
    demo.set_defaults(func=_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
