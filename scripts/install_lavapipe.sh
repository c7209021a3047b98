#!/usr/bin/env bash
# Fetch Mesa's lavapipe (a software Vulkan driver new enough for SAPIEN) into a project folder,
# without root and without touching the system: `apt-get download` from Debian 12's
# bookworm-backports suite with a private source list, then `dpkg -x`.
#
#   bash scripts/install_lavapipe.sh [DIR]      (default .renderer; `make renderer` runs this)
#
# DIR/lvp_icd.json is then a Vulkan ICD manifest with an absolute library path, which
# sb3_memret.common.rendering hands to SAPIEN for render_backend="cpu". Debian 12's own lavapipe
# (Mesa 22.3) lacks VK_KHR_external_semaphore_fd, which SAPIEN needs; Mesa 25.0.7 has it.
set -euo pipefail

dir=$(realpath -m "${1:-.renderer}")
mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
keyring=/usr/share/keyrings/debian-archive-keyring.gpg
arch=$(dpkg --print-architecture 2>/dev/null || echo none)

if [ -f "$dir/lvp_icd.json" ]; then
  echo "lavapipe already in $dir"
  exit 0
fi
if ! command -v apt-get >/dev/null || [ ! -f "$keyring" ] || [ "$arch" != amd64 ]; then
  echo "error: fetching lavapipe needs a Debian 12 amd64 machine (apt-get, dpkg and $keyring); elsewhere" \
       "install a Mesa >= 24.3 Vulkan driver and set VK_ICD_FILENAMES to its lvp_icd.*.json" >&2
  exit 1
fi

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/lists/partial" "$work/debs"
cat > "$work/sources.list" <<EOF
deb [signed-by=$keyring] $mirror bookworm main
deb [signed-by=$keyring] $mirror bookworm-backports main
EOF
apt_opts=(-q -o "Dir::Etc::SourceList=$work/sources.list" -o Dir::Etc::SourceParts=/dev/null
          -o "Dir::State::Lists=$work/lists" -o "Dir::Cache=$work" -o Debug::NoLocking=1
          -o APT::Sandbox::User=root)
apt-get "${apt_opts[@]}" update >/dev/null

packages=(mesa-vulkan-drivers/bookworm-backports libdrm2/bookworm-backports libdrm-amdgpu1/bookworm-backports)
# lavapipe links libLLVM-15; take Debian's package when the system does not have it.
ldconfig -p | grep -q 'libLLVM-15\.so\.1 ' || packages+=(libllvm15/bookworm)
(cd "$work/debs" && apt-get "${apt_opts[@]}" download "${packages[@]}" >/dev/null)

mkdir -p "$dir"
rm -rf "$dir/root"
for deb in "$work"/debs/*.deb; do dpkg -x "$deb" "$dir/root"; done
lib=$dir/root/usr/lib/x86_64-linux-gnu
[ -f "$lib/libvulkan_lvp.so" ] || { echo "error: no libvulkan_lvp.so in the downloaded packages" >&2; exit 1; }
cat > "$dir/lvp_icd.json" <<EOF
{
    "file_format_version": "1.0.0",
    "ICD": {"library_path": "$lib/libvulkan_lvp.so", "api_version": "1.4.305"}
}
EOF
echo "lavapipe ($(ls "$work"/debs | sed -n 's/^mesa-vulkan-drivers_\([^_]*\)_.*/\1/p')) in $dir"
