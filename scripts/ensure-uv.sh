#!/usr/bin/env bash
# Prints the path of a working `uv`, installing it with pip into .tools/ when none is found.
set -euo pipefail
if command -v uv >/dev/null 2>&1 && uv --version >/dev/null 2>&1; then
  command -v uv
  exit 0
fi
for candidate in "$HOME/.local/bin/uv" ".tools/bin/uv"; do
  if [ -x "$candidate" ] && "$candidate" --version >/dev/null 2>&1; then
    echo "$candidate"
    exit 0
  fi
done
echo "kitbench: installing uv with pip into .tools/" >&2
if python3 -m venv .tools >/dev/null 2>&1; then
  .tools/bin/python -m pip install --quiet --disable-pip-version-check uv >&2
else
  echo "kitbench: cannot create a virtualenv with python3; install uv (pip install uv) and retry" >&2
  exit 1
fi
echo ".tools/bin/uv"
