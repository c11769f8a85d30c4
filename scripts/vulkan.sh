#!/usr/bin/env bash
# A Vulkan device for SAPIEN (`scripts/setup.sh` runs it; idempotent):
#   bash scripts/vulkan.sh PYTHON
# PYTHON is the interpreter with SAPIEN installed; nothing is done when SAPIEN can make a
# render system with it. Otherwise (see docs/ARCHITECTURE.md "Set-up facts"): Debian 12
# (bookworm) gets Mesa >= 25's lavapipe from bookworm-backports, added on the machine's own
# Debian mirror (from its apt sources, one-line or deb822); any other system with apt gets
# its own distribution's Mesa if that works; else the script prints exactly what to
# install. It never adds another distribution's suite to apt.
# GAUSSTAC_ETC (default /etc) is where os-release and apt's sources are read and written:
# tests/test_setup_scripts.py runs every branch against made-up systems.
set -euo pipefail
PY=${1:?usage: bash scripts/vulkan.sh PYTHON}
ETC=${GAUSSTAC_ETC:-/etc}

vulkan_ok() {
    "$PY" - <<'PYEOF' >/dev/null 2>&1
import sapien
sapien.render.RenderSystem()
PYEOF
}
if vulkan_ok; then
    echo "[setup] Vulkan device found (SAPIEN can render)"
    exit 0
fi

MESA_NEED="SAPIEN needs a Vulkan device. Without a GPU driver it runs on Mesa's lavapipe (CPU),
         from Mesa >= 25 (Mesa 22's lavapipe lacks VK_KHR_external_semaphore_fd)."
if [ "$(id -u)" = "0" ]; then
    SUDO="" CAN_ROOT=1
elif command -v sudo >/dev/null 2>&1; then
    SUDO=sudo CAN_ROOT=1
else
    SUDO="" CAN_ROOT=0
fi
ID="" VERSION_CODENAME="" PRETTY_NAME=""
# shellcheck disable=SC1091
[ -r "$ETC/os-release" ] && . "$ETC/os-release"

give_up() {  # print exactly what to install; the SAPIEN-based tests skip meanwhile
    echo "[setup] WARNING: no usable Vulkan device; SAPIEN-based tests will be skipped." >&2
    echo "         $MESA_NEED" >&2
    echo "         Install it, then run \`make setup\` again:" >&2
    printf '           %s\n' "$@" >&2
}

apt_install() {  # apt_install [apt-get install options...] packages...
    [ "$CAN_ROOT" = 1 ] || return 1
    $SUDO apt-get update -qq &&
        DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "$@" >/dev/null
}

# apt sources of this machine, one "URI SUITE" per line (one-line .list and deb822 .sources)
apt_sources() {
    local f
    for f in "$ETC"/apt/sources.list "$ETC"/apt/sources.list.d/*.list; do
        [ -r "$f" ] || continue
        sed -e 's/#.*//' -e 's/\[[^]]*\]//' "$f" | awk '$1 == "deb" { print $2, $3 }'
    done
    for f in "$ETC"/apt/sources.list.d/*.sources; do
        [ -r "$f" ] || continue
        awk 'function flush() { if (types ~ /(^| )deb( |$)/ && enabled != "no") {
                                   n = split(uris, u, " "); m = split(suites, s, " ")
                                   for (i = 1; i <= n; i++) for (j = 1; j <= m; j++) print u[i], s[j] }
                               types = uris = suites = ""; enabled = "yes" }
             BEGIN { enabled = "yes" }
             /^[ \t]*#/ { next }
             /^[ \t]*$/ { flush(); next }
             { key = tolower($1); sub(/:$/, "", key); $1 = ""; sub(/^ +/, "")
               if (key == "types") types = $0; else if (key == "uris") uris = $0
               else if (key == "suites") suites = $0; else if (key == "enabled") enabled = tolower($0) }
             END { flush() }' "$f"
    done
}

if [ "$ID" = "debian" ] && [ "$VERSION_CODENAME" = "bookworm" ]; then
    # Debian 12: its Mesa 22 is not enough; Mesa 25 comes from bookworm-backports.
    if ! apt_sources | awk '$2 == "bookworm-backports" { found = 1 } END { exit !found }'; then
        MIRROR=$(apt_sources | awk '$2 == "bookworm" && $1 !~ /security/ { print $1; exit }')
        if [ -z "$MIRROR" ]; then
            give_up "a bookworm-backports line for your Debian mirror in /etc/apt/sources.list.d/, e.g." \
                    "  deb <your Debian mirror> bookworm-backports main" \
                    "then: apt-get install -t bookworm-backports mesa-vulkan-drivers libvulkan1"
            exit 0
        fi
        if [ "$CAN_ROOT" != 1 ]; then
            give_up "echo 'deb $MIRROR bookworm-backports main' | sudo tee /etc/apt/sources.list.d/bookworm-backports.list" \
                    "sudo apt-get update && sudo apt-get install -t bookworm-backports mesa-vulkan-drivers libvulkan1"
            exit 0
        fi
        echo "[setup] adding Debian's bookworm-backports suite (mirror $MIRROR, from this machine's apt sources)"
        echo "deb $MIRROR bookworm-backports main" |
            $SUDO tee "$ETC"/apt/sources.list.d/bookworm-backports.list >/dev/null
    fi
    echo "[setup] no usable Vulkan device: installing Mesa lavapipe from bookworm-backports"
    if ! apt_install -t bookworm-backports mesa-vulkan-drivers libvulkan1; then
        give_up "sudo apt-get update && sudo apt-get install -t bookworm-backports mesa-vulkan-drivers libvulkan1"
        exit 0
    fi
elif command -v apt-get >/dev/null 2>&1; then
    # Ubuntu 22.04/24.04, Debian >= 13, ...: the distribution's own Mesa, if it is recent enough.
    echo "[setup] no usable Vulkan device: trying ${PRETTY_NAME:-this system}'s Mesa lavapipe (mesa-vulkan-drivers)"
    if ! apt_install mesa-vulkan-drivers libvulkan1; then
        give_up "sudo apt-get update && sudo apt-get install mesa-vulkan-drivers libvulkan1" \
                "(Mesa >= 25; if ${PRETTY_NAME:-your distribution} ships an older one, a GPU Vulkan driver instead)"
        exit 0
    fi
else
    give_up "your distribution's Mesa Vulkan drivers (lavapipe, Mesa >= 25) and the Vulkan loader," \
            "or a GPU Vulkan driver"
    exit 0
fi

if vulkan_ok; then
    echo "[setup] SAPIEN renders on the CPU (lavapipe)"
else
    MESA=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || echo "none")
    give_up "mesa-vulkan-drivers >= 25 (installed here: $MESA) from ${PRETTY_NAME:-your distribution}'s own" \
            "repositories, or a GPU Vulkan driver"
fi
