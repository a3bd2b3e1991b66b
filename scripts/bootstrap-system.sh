#!/usr/bin/env bash
# Installs the system pieces kitbench needs that pip cannot give: a Vulkan loader with a driver SAPIEN
# accepts (software llvmpipe from Mesa >= 25 on a CPU-only Debian 12), FFmpeg for video decoding, and a virtual
# X display with a key typist (Xvfb, xdotool) on which the tests type into the keyboard teleoperator's listener.
# Idempotent: does nothing when they are all present.
set -euo pipefail

have_vulkan_icd() {
  # A usable ICD json, other than Mesa 22.x's lavapipe that SAPIEN refuses.
  local f
  for f in /usr/share/vulkan/icd.d/*.json /etc/vulkan/icd.d/*.json; do
    [ -e "$f" ] || continue
    case "$f" in
      *lvp_icd*) mesa_ok && return 0 ;;
      *) return 0 ;;
    esac
  done
  return 1
}

mesa_ok() {
  local v
  v=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
  [ -n "$v" ] && dpkg --compare-versions "$v" ge 25
}

add_backports_suite() {
  # Reuse the mirror the machine already uses for the main suite.
  local uri
  uri=$(awk '/^URIs:/{u=$2} /^Suites:/ && / bookworm( |$)/{print u; exit}' /etc/apt/sources.list.d/*.sources 2>/dev/null || true)
  [ -n "$uri" ] || uri=$(awk '$1=="deb" && $3=="bookworm"{print $2; exit}' /etc/apt/sources.list 2>/dev/null || true)
  if [ -z "$uri" ]; then
    echo "kitbench: cannot find the Debian mirror in apt's sources to add bookworm-backports" >&2
    exit 1
  fi
  echo "deb $uri bookworm-backports main" > /etc/apt/sources.list.d/bookworm-backports.list
}

need=()
{ [ -e /usr/lib/x86_64-linux-gnu/libvulkan.so.1 ] || ldconfig -p 2>/dev/null | grep -q 'libvulkan.so.1 '; } || need+=(libvulkan1)
have_vulkan_icd || need+=(mesa-vulkan-drivers)
command -v ffmpeg >/dev/null 2>&1 || need+=(ffmpeg)
command -v Xvfb >/dev/null 2>&1 || need+=(xvfb)
command -v xdotool >/dev/null 2>&1 || need+=(xdotool)

if [ ${#need[@]} -eq 0 ]; then
  exit 0
fi

if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null 2>&1; then
  echo "kitbench: missing system packages: ${need[*]}" >&2
  echo "  Install as root: a Vulkan loader (libvulkan1), a Vulkan driver (your GPU's, or Mesa >= 25 'mesa-vulkan-drivers'" >&2
  echo "  for CPU rendering; on Debian 12 from bookworm-backports), ffmpeg, xvfb and xdotool. Then run this command" >&2
  echo "  again." >&2
  exit 1
fi

echo "kitbench: installing system packages: ${need[*]}"
export DEBIAN_FRONTEND=noninteractive
codename=$(. /etc/os-release && echo "${VERSION_CODENAME:-}")
mesa_args=(mesa-vulkan-drivers)
if [ "$codename" = bookworm ]; then
  # Debian 12's own Mesa 22.3 lavapipe lacks features SAPIEN requires; backports carries Mesa 25.
  if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
    add_backports_suite
  fi
  mesa_args=(-t bookworm-backports mesa-vulkan-drivers)
fi
apt-get update -qq
rest=()
for p in "${need[@]}"; do [ "$p" = mesa-vulkan-drivers ] || rest+=("$p"); done
if [ ${#rest[@]} -gt 0 ]; then
  apt-get install -y -qq --no-install-recommends "${rest[@]}" >/dev/null
fi
if printf '%s\n' "${need[@]}" | grep -qx mesa-vulkan-drivers; then
  apt-get install -y -qq --no-install-recommends "${mesa_args[@]}" >/dev/null
fi
echo "kitbench: system packages ready"
