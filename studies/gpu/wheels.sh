#!/usr/bin/env bash
# Builds the wheels the lent GPU machine lacks, at the versions in this project's uv.lock, into two folders of at
# most ~60 MiB each (one command sent there carries 64 MiB): .gpu/whl1 and .gpu/whl2, plus the Vulkan loader debs in .gpu/gl.
# Run from the project root on a machine that reaches the package index (the GPU machine does not).
# Usage: bash studies/gpu/wheels.sh [EXTRA_PACKAGE ...]    (extra names go into whl2, versions from uv.lock)
set -euo pipefail
root=$(git rev-parse --show-toplevel); cd "$root"
grep -qx '/.gpu/' .git/info/exclude 2>/dev/null || echo '/.gpu/' >> .git/info/exclude
rm -rf .gpu/whl1 .gpu/whl2 .gpu/dl; mkdir -p .gpu/whl1 .gpu/whl2 .gpu/dl .gpu/gl
# The GPU image already has torch, torchvision, numpy, pandas, pyarrow, huggingface-hub, scipy, pillow, opencv, matplotlib,
# safetensors, einops, tqdm, rich, protobuf, fsspec, requests, packaging, pyyaml, jinja2, h5py... (studies/gpu/README.md).
# Group 1: simulation and geometry. Group 2: LeRobot, datasets, video, logs, MuJoCo (mink's model) and the project's own wheels.
G1="sapien example-robot-data mink qpsolvers daqp trimesh shapely fast-simplification transforms3d importlib-resources pyperclip"
G2="lerobot draccus mergedeep toml termcolor gymnasium farama-notifications datasets dill multiprocess av jsonlines mcap lz4 zstandard mcap-protobuf-support foxglove-schemas-protobuf mujoco mujoco-core ${*:-}"
version() {  # the locked version of a package (names compared with - and _ alike)
  awk -v n="$1" 'BEGIN{gsub(/_/,"-",n)} /^name = /{gsub(/"/,"",$3); x=$3; gsub(/_/,"-",x)} /^version = /{if (x==n) {gsub(/"/,"",$3); print $3; exit}}' uv.lock
}
get() {  # get NAME DEST
  local v; v=$(version "$1"); [ -n "$v" ] || { echo "wheels.sh: $1 is not in uv.lock" >&2; exit 1; }
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_24_x86_64 \
    --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform manylinux_2_5_x86_64 \
    --platform manylinux1_x86_64 -d "$2" "$1==$v"
}
for p in $G1; do get "$p" .gpu/dl; done
# example-robot-data ships ~130 MB of robots: keep only those named in KEEP_ROBOTS (default: the Panda), e.g.
# KEEP_ROBOTS="panda_description so_arm_description" bash wheels.sh   (watch the 62 MiB line printed at the end)
KEEP_ROBOTS="${KEEP_ROBOTS:-panda_description}" python3 - <<'PY'
import base64, csv, glob, hashlib, io, os, zipfile
src = glob.glob(".gpu/dl/example_robot_data-*.whl")[0]
robots = os.environ["KEEP_ROBOTS"].split()
keep = lambda n: "/robots/" not in n or any(f"/robots/{r}/" in n for r in robots)
out = io.BytesIO(); rows = []
with zipfile.ZipFile(src) as z, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as w:
    record = [n for n in z.namelist() if n.endswith(".dist-info/RECORD")][0]
    for n in z.namelist():
        if n == record or not keep(n):
            continue
        data = z.read(n); w.writestr(z.getinfo(n), data)
        h = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
        rows.append((n, f"sha256={h}", str(len(data))))
    buf = io.StringIO(); csv.writer(buf, lineterminator="\n").writerows(rows + [(record, "", "")]); w.writestr(record, buf.getvalue())
open(src, "wb").write(out.getvalue())
PY
mv .gpu/dl/*.whl .gpu/whl1/
for p in $G2; do get "$p" .gpu/whl2; done
# the project and its LeRobot plugin, as they are in this checkout
python3 -m pip wheel -q --no-deps -w .gpu/whl2 . ./integrations/lerobot_env_kitbench
# Vulkan/GL loaders for SAPIEN on the NVIDIA driver
o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
mkdir -p /tmp/amd64/partial; apt-get $o update -qq >/dev/null
(cd .gpu/gl && apt-get $o download -qq libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 >/dev/null)
cp "$(dirname "$(readlink -f "$0")")/device.sh" .gpu/
du -sh .gpu/whl1 .gpu/whl2 .gpu/gl
for d in .gpu/whl1 .gpu/whl2; do
  [ "$(du -sm "$d" | cut -f1)" -le 62 ] || echo "wheels.sh: $d is over 62 MiB: move a wheel to the other folder" >&2
done
