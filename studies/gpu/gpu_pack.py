"""Recordings made on the CPU, split into folders the lent GPU machine can be sent one command at a time.

    python studies/gpu/gpu_pack.py ak=outputs/datasets/ak_video diffusion=outputs/datasets/lpu_video [--mib 56]

One command carries at most 64 MiB with the working tree (`studies/gpu/README.md`), and a recording of 800
AssemblingKits demonstrations is larger than that. Each recording's files are hard-linked into `.gpu/data1`,
`.gpu/data2`, ... (largest first, into the first folder with room) under the name given, so that copying every
folder into one place on the machine (`studies/gpu/gpu_learn.sh receive DIR`, in the command that carried it, copies it
into DIR/data) gives back each recording whole: `DIR/data/ak`, `DIR/data/diffusion`. `--check DIR` verifies such a
merge against the manifest the packing wrote (every file, its size). Exit status 2 for a bad argument.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MANIFEST = "gpu_pack.json"


def pack(recordings: dict[str, Path], dest: Path, mib: float) -> list[Path]:
    """Hard-link every file of `recordings` into dest/data1, dest/data2, ...; returns the folders."""
    limit = int(mib * 2**20)
    files = [
        (path.stat().st_size, f"{name}/{path.relative_to(src)}", path)
        for name, src in recordings.items()
        for path in sorted(src.rglob("*"))
        if path.is_file()
    ]
    too_big = [rel for size, rel, _ in files if size > limit]
    if too_big:
        raise SystemExit(f"gpu_pack: {too_big[0]} is larger than --mib {mib:g} on its own")
    bins: list[list[tuple[int, str, Path]]] = []
    for entry in sorted(files, key=lambda f: -f[0]):
        room = next((b for b in bins if sum(f[0] for f in b) + entry[0] <= limit), None)
        if room is None:
            room = []
            bins.append(room)
        room.append(entry)
    for old in dest.glob("data*"):
        shutil.rmtree(old)
    folders = []
    for index, content in enumerate(bins, start=1):
        folder = dest / f"data{index}"
        for _, rel, path in content:
            (folder / rel).parent.mkdir(parents=True, exist_ok=True)
            try:
                os.link(path, folder / rel)
            except OSError:  # another filesystem
                shutil.copy2(path, folder / rel)
        folders.append(folder)
    manifest = {rel: size for size, rel, _ in files}
    (folders[0] / MANIFEST).write_text(json.dumps(manifest, indent=0, sort_keys=True) + "\n")
    return folders


def check(merged: Path) -> list[str]:
    """What a merge lacks or holds at another size, against the manifest packed with it."""
    manifest = json.loads((merged / MANIFEST).read_text())
    wrong = []
    for rel, size in manifest.items():
        path = merged / rel
        if not path.is_file():
            wrong.append(f"{rel} is missing")
        elif path.stat().st_size != size:
            wrong.append(f"{rel} has {path.stat().st_size} bytes, packed {size}")
    return wrong


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recordings", nargs="*", help="NAME=DIR: a kitbench recording and the name it lands under")
    parser.add_argument("--out", default=str(ROOT / ".gpu"), help="where the data1, data2, ... folders go")
    parser.add_argument("--mib", type=float, default=56.0, help="the most one folder holds (MiB)")
    parser.add_argument("--check", metavar="DIR", help="verify a merge of the folders against its manifest")
    args = parser.parse_args(argv)
    if args.check:
        wrong = check(Path(args.check))
        for line in wrong:
            print(f"gpu_pack: {line}", file=sys.stderr)
        print(f"gpu_pack: {args.check}: {'incomplete' if wrong else 'complete'}")
        return 1 if wrong else 0
    recordings = {}
    for item in args.recordings:
        name, sep, folder = item.partition("=")
        path = Path(folder)
        if not sep or not name.isidentifier():
            print(f"gpu_pack: error: {item!r} is not NAME=DIR", file=sys.stderr)
            return 2
        if not (path / "meta" / "kitbench_recording.json").is_file():
            print(
                f"gpu_pack: error: {folder!r} is not a kitbench recording (no meta/kitbench_recording.json)",
                file=sys.stderr,
            )
            return 2
        recordings[name] = path
    if not recordings:
        print("gpu_pack: error: name at least one recording as NAME=DIR", file=sys.stderr)
        return 2
    for folder in pack(recordings, Path(args.out), args.mib):
        size = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
        print(f"{folder}: {size / 2**20:.1f} MiB, {sum(1 for p in folder.rglob('*') if p.is_file())} files")
    return 0


if __name__ == "__main__":
    sys.exit(main())
